mod common;

use common::study::{task_file, task_scene, TASK_FILES};
use phri_core::collision::{CollisionChecker, ProximityScratch, SELF_MARGIN};

fn pose(task: &str, key: &str) -> Vec<f64> {
    let doc = task_file(task);
    let a = doc[key].as_array().unwrap();
    let v: Vec<f64> = a.iter().map(|v| v.as_float().unwrap_or_else(|| v.as_integer().unwrap() as f64)).collect();
    common::deg(v.try_into().unwrap())
}

#[test]
fn explore() {
    let model = common::jaco2_with_cup();
    for b in model.collision().bodies() {
        println!("{} {} spheres {:?}", b.name, b.spheres.len(), b.spheres.iter().map(|s| s.radius).collect::<Vec<_>>());
    }
    for (task, _) in TASK_FILES {
        let scene = task_scene(task);
        let checker = CollisionChecker::new(&model, &scene, Some(SELF_MARGIN)).unwrap();
        println!("{task}: {} pairs, excluded {:?}", checker.len(), checker.excluded());
        let mut data = model.data();
        let mut scratch = ProximityScratch::default();
        for key in ["start", "goal"] {
            model.forward_kinematics(&pose(task, key), &mut data).unwrap();
            println!("  {key}: {:?}", checker.worst(&model, &data, &mut scratch));
        }
    }
}

#[test]
fn explore_person() {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};
    use phri_core::scene::{ObjectKind, Scene, SceneObject, Shape};
    let model = common::jaco2_with_cup();
    for (x, y) in [(0.0, 0.35), (0.0, 0.45), (0.1, 0.45), (-0.2, 0.5), (0.0, 0.55)] {
        let person = SceneObject::new(
            "person",
            Shape::Cylinder { radius: 0.15, length: 1.7 },
            Isometry3::from_parts(Translation3::new(x, y, 0.7484), UnitQuaternion::identity()),
            0.02,
            ObjectKind::Person,
        )
        .unwrap();
        let scene = Scene::new(vec![person]).unwrap();
        let checker = CollisionChecker::new(&model, &scene, None).unwrap();
        let mut data = model.data();
        let mut scratch = ProximityScratch::default();
        let mut out = vec![];
        for (task, _) in TASK_FILES {
            for key in ["start", "goal"] {
                let (s, g) = (pose(task, "start"), pose(task, "goal"));
                let q = if key == "start" { s } else { g };
                model.forward_kinematics(&q, &mut data).unwrap();
                out.push(format!("{task}/{key} {:.3}", checker.worst(&model, &data, &mut scratch).unwrap().distance));
            }
        }
        println!("({x},{y}) excluded {:?}: {}", checker.excluded(), out.join(" "));
    }
}

#[test]
fn explore_plans() {
    use phri_core::trajopt::{CollisionParams, TrajectoryOptimizer, TrajoptParams};
    use std::sync::Arc;
    let model = Arc::new(common::jaco2_with_cup());
    let l7 = model.frame_id("j2s7s300_link_7").unwrap();
    let tasks = [("human", 10.0), ("coffee", 1.0), ("table", 1.0), ("laptop", 10.0)];
    for (task, w) in tasks {
        let scene = task_scene(task);
        let fs0 = common::study::study_features(model.clone(), l7, &["efficiency", task]);
        let mut fs = fs0;
        let checker = Arc::new(CollisionChecker::new(&model, &scene, Some(SELF_MARGIN)).unwrap());
        let spacing = 15.0 / 30.0;
        let params = TrajoptParams {
            collision: Some(CollisionParams::new(checker)),
            max_step: model.velocity_limits().iter().map(|v| 0.5 * v * spacing).collect(),
            ..Default::default()
        };
        let mut opt = TrajectoryOptimizer::new(&fs, 31, params).unwrap();
        let (s, g) = (pose(task, "start"), pose(task, "goal"));
        let mut out = vec![0.0; 31 * 7];
        let t = std::time::Instant::now();
        let info = opt.solve(&mut fs, &[1.0, w], &s, &g, None, &mut out).unwrap();
        let el = t.elapsed();
        println!("{task}: {:?} {:?} {:?}", el, info, opt.closest_pair());
        let info0 = opt.solve(&mut fs, &[1.0, 0.0], &s, &g, None, &mut out).unwrap();
        println!("  w=0: {:?} {:?}", info0, opt.closest_pair());
    }
}
