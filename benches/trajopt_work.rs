//! `trajopt_work N TASK REPS [unscaled]`: REPS cold solves of a study task on N waypoints, on the
//! study's problem before the collision model (tool point and link_7 clearances above the table,
//! `phri_benches::clearance_problem_at`), posed with the trade-off of the study's 31 waypoints
//! (weights and clearance rescaled) or, with `unscaled`, with the true weight as given.
//! benches/trajopt_work.py runs it under callgrind: instruction counts do not move with the
//! machine's load as times do.

use std::process::ExitCode;
use std::sync::Arc;

use phri_benches::{clearance_problem_at, jaco2, study_tasks};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: trajopt_work N TASK REPS [unscaled]";
    let (Some(n), Some(name), Some(reps)) = (
        args.first().and_then(|v| v.parse::<usize>().ok()).filter(|&n| n >= 3),
        args.get(1),
        args.get(2).and_then(|v| v.parse::<usize>().ok()),
    ) else {
        eprintln!("{usage}");
        return ExitCode::from(2);
    };
    let unscaled = match args.get(3).map(String::as_str) {
        None => false,
        Some("unscaled") => true,
        Some(other) => {
            eprintln!("unknown option {other}; {usage}");
            return ExitCode::from(2);
        }
    };
    let Some(task) = study_tasks().into_iter().find(|t| t.name == name) else {
        eprintln!("unknown task {name}; {usage}");
        return ExitCode::from(2);
    };
    let model = Arc::new(jaco2());
    let (mut fs, mut opt, weights) = clearance_problem_at(&model, &task, n, !unscaled);
    let mut plan = vec![0.0; n * model.nq()];
    for _ in 0..reps {
        let info = opt.solve(&mut fs, &weights, &task.start, &task.goal, None, &mut plan).expect("valid problem");
        assert!(info.converged, "{name} N={n}: {info:?}");
    }
    ExitCode::SUCCESS
}
