//! The control loop's ticks on a simulated arm, one for one those of the Python
//! `phri.control.ControlLoop` over a simulator (see the module documentation of [`crate::sim`]).

use nalgebra::Matrix6xX;

use crate::error::{PhriError, Result};
use crate::impedance::ImpedanceController;
use crate::learner::Learner;
use crate::safety::{Limit, Quantity, SafetyLayer, Violation};
use crate::sim::SimulatedArm;
use crate::{FrameId, RobotData};

pub use crate::reference::GRID_TOLERANCE;

/// Most rows of a motion's log (made at the start, about 300 bytes a row for 7 joints: 300 MB; 2.8
/// hours at 100 Hz): a longer motion is refused before it starts (as the Python loop refuses it).
pub const MAX_LOG_ROWS: usize = 1_000_000;

/// How a simulated motion runs.
#[derive(Debug, Clone, Copy)]
pub struct LoopSettings {
    /// The motion's duration [s of robot time], finite and > 0.
    pub duration: f64,
    /// How long a stop holds the position [s], finite and >= 0.
    pub hold_time: f64,
    /// The log's period [s], at least the control period.
    pub log_period: f64,
    /// Control ticks between two samples of the joint-torque sensor (>= 1).
    pub sample_every: u64,
    /// The frame the person pushes (their wrench acts at its origin).
    pub hand: FrameId,
}

/// A stop of the arm: the limit crossed and the state that crossed it.
#[derive(Debug, Clone, PartialEq)]
pub struct Stop {
    pub violation: Violation,
    /// The tick's index and its robot time [s].
    pub tick: u64,
    pub t: f64,
    /// The state read [rad, rad/s, N·m] and the joint torque last computed [N·m].
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    pub tau: Vec<f64>,
    pub tau_ext: Vec<f64>,
    /// Whether the arm held its position after it (not for a state that cannot be trusted).
    pub hold: bool,
}

/// The loop's log at the log rate; per-joint series are row-major (rows × n).
#[derive(Debug, Clone, Default)]
pub struct LoopLog {
    /// Robot time [s].
    pub t: Vec<f64>,
    /// Joint positions [rad], velocities [rad/s], the reference tracked [rad] (the held position
    /// after a stop), the joint torque applied [N·m] (g(q) included), the measured torque [N·m].
    pub q: Vec<f64>,
    pub qd: Vec<f64>,
    pub q_ref: Vec<f64>,
    pub tau: Vec<f64>,
    pub tau_ext: Vec<f64>,
    /// The wall's largest total force since the previous row [N].
    pub wall_force: Vec<f64>,
    /// The person's wrench at the hand (force [N], torque [N·m], in the base frame, the study's world frame; rows × 6), zero
    /// while nobody touches it, and whether anybody did.
    pub push: Vec<f64>,
    pub touched: Vec<bool>,
}

impl LoopLog {
    /// The number of rows.
    pub fn rows(&self) -> usize {
        self.t.len()
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Running,
    /// Holding the position of the stop at `t_stop` [s] until `until` [s]; `started` once the
    /// stop's own tick has run.
    Holding {
        t_stop: f64,
        until: f64,
        started: bool,
    },
    Done,
}

/// One motion of a [`SimulatedArm`] under the learner, the impedance law and the safety layer,
/// run in chunks of ticks ([`advance`](Self::advance)). Per tick it allocates nothing (a stop
/// records its state once; the log grows at the log rate).
#[derive(Debug, Clone)]
pub struct SimulatedLoop {
    arm: SimulatedArm,
    settings: LoopSettings,
    period: f64,
    k: u64,
    phase: Phase,
    q_ref: Vec<f64>,
    qd_ref: Vec<f64>,
    qdd_ref: Vec<f64>,
    tau: Vec<f64>,
    command: Vec<f64>,
    /// The sensor's measurement, held between samples [N·m].
    measured: Vec<f64>,
    /// The push's joint torque Jᵀ·w this tick [N·m].
    push_torque: Vec<f64>,
    jacobian: Matrix6xX<f64>,
    data: RobotData,
    next_row: f64,
    wall_row: f64,
    log: LoopLog,
    ticks: u64,
    held: f64,
    wall_ticks: u64,
    wall_peak_force: f64,
    replan_failures: u64,
    replan_error: Option<String>,
    stop: Option<Stop>,
}

impl SimulatedLoop {
    /// A motion of `settings.duration` seconds from `q_start` [rad], placed at rest there; the
    /// safety layer starts afresh, the first command's rate limited from g(q_start) (what an arm
    /// that does not compensate gravity applies at rest).
    pub fn new(mut arm: SimulatedArm, settings: LoopSettings, q_start: &[f64], safety: &mut SafetyLayer) -> Result<Self> {
        let n = arm.model().nq();
        let period = arm.dt();
        let LoopSettings { duration, hold_time, log_period, sample_every, hand } = settings;
        if !(duration.is_finite() && duration > 0.0) {
            return Err(PhriError::invalid("duration", format!("must be a finite time > 0 s, got {duration}")));
        }
        if !(hold_time.is_finite() && hold_time >= 0.0) {
            return Err(PhriError::invalid("hold_time", format!("must be a finite time >= 0 s, got {hold_time}")));
        }
        if !(log_period.is_finite() && log_period >= period * (1.0 - GRID_TOLERANCE)) {
            return Err(PhriError::invalid(
                "log_period",
                format!("must be a finite time >= the control period {period} s, got {log_period}"),
            ));
        }
        if sample_every == 0 {
            return Err(PhriError::invalid("sample_every", "must be >= 1 tick"));
        }
        let rows = (duration + hold_time) / log_period + 3.0;
        if !(rows <= MAX_LOG_ROWS as f64) {
            return Err(PhriError::invalid(
                "duration",
                format!(
                    "+ hold_time ({duration} s + {hold_time} s) at a log period of {log_period} s would log more than \
                     {MAX_LOG_ROWS} rows: run shorter motions or log less often"
                ),
            ));
        }
        let rows = rows as usize;
        if !fits_simulated_arm(safety) {
            return Err(PhriError::invalid(
                "safety",
                "must be made with gravity_compensated=False: the simulated arm does not compensate gravity",
            ));
        }
        if hand.0 >= arm.model().frames.len() {
            return Err(PhriError::invalid("hand", format!("is not a frame of robot '{}'", arm.model().name)));
        }
        if safety.model().nq() != n {
            return Err(PhriError::shape("safety", format!("a layer for {n} joints"), format!("{} joints", safety.model().nq())));
        }
        arm.reset(q_start).map_err(|e| rename(e, "q_start"))?;
        let mut at_rest = vec![0.0; n];
        let mut data = arm.model().data();
        safety.model().gravity_torques(q_start, &mut data, &mut at_rest)?;
        safety.reset(Some(&at_rest))?;
        let log = LoopLog {
            t: Vec::with_capacity(rows),
            q: Vec::with_capacity(rows * n),
            qd: Vec::with_capacity(rows * n),
            q_ref: Vec::with_capacity(rows * n),
            tau: Vec::with_capacity(rows * n),
            tau_ext: Vec::with_capacity(rows * n),
            wall_force: Vec::with_capacity(rows),
            push: Vec::with_capacity(rows * 6),
            touched: Vec::with_capacity(rows),
        };
        Ok(SimulatedLoop {
            jacobian: Matrix6xX::zeros(n),
            data,
            arm,
            settings,
            period,
            k: 0,
            phase: Phase::Running,
            q_ref: vec![0.0; n],
            qd_ref: vec![0.0; n],
            qdd_ref: vec![0.0; n],
            tau: vec![0.0; n],
            command: vec![0.0; n],
            measured: vec![0.0; n],
            push_torque: vec![0.0; n],
            next_row: 0.0,
            wall_row: 0.0,
            log,
            ticks: 0,
            held: 0.0,
            wall_ticks: 0,
            wall_peak_force: 0.0,
            replan_failures: 0,
            replan_error: None,
            stop: None,
        })
    }

    /// The index of the next tick to run (its state is the arm's now); once the motion is done, the
    /// last tick's.
    pub fn tick(&self) -> u64 {
        self.k
    }

    /// The robot time of [`tick`](Self::tick) [s].
    pub fn t(&self) -> f64 {
        self.k as f64 * self.period
    }

    /// The arm (its state is the next tick's).
    pub fn arm(&self) -> &SimulatedArm {
        &self.arm
    }

    /// Whether the motion has ended (its last tick run, or a stop's hold over).
    pub fn done(&self) -> bool {
        self.phase == Phase::Done
    }

    /// Ticks run, including those holding after a stop.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// How long the arm held its position after the stop [s of robot time].
    pub fn held(&self) -> f64 {
        self.held
    }

    /// Ticks at which the wall acted, and its largest total force [N].
    pub fn wall_ticks(&self) -> u64 {
        self.wall_ticks
    }

    pub fn wall_peak_force(&self) -> f64 {
        self.wall_peak_force
    }

    /// Replans the learner's worker failed (the arm kept its plan), and the last one's message.
    pub fn replan_failures(&self) -> u64 {
        self.replan_failures
    }

    pub fn replan_error(&self) -> Option<&str> {
        self.replan_error.as_deref()
    }

    /// The stop, if the safety layer stopped the arm.
    pub fn stop(&self) -> Option<&Stop> {
        self.stop.as_ref()
    }

    /// The log so far.
    pub fn log(&self) -> &LoopLog {
        &self.log
    }

    /// The sensor samples among the ticks from the next one up to `until` (exclusive); none once
    /// the motion is done.
    pub fn samples_before(&self, until: u64) -> u64 {
        let every = self.settings.sample_every;
        if until <= self.k || self.phase == Phase::Done {
            return 0;
        }
        (until - 1) / every + 1 - self.k.div_ceil(every)
    }

    /// Runs the ticks from the next one up to tick `until` (exclusive), or to the motion's end,
    /// with the person's wrench `push` at the hand (force [N], torque [N·m], in the base frame, the study's world frame; None:
    /// nobody touches it) held throughout. `offsets` [N·m] holds the sensor's bias and noise for
    /// each sample instant among those ticks, row-major ([`samples_before`](Self::samples_before)
    /// rows of n): the measurement there is the offset plus Jᵀ·w at the hand.
    ///
    /// An error of the learner (other than a failed replan worker, which is counted and leaves the
    /// arm on its plan), of the law or of the arm's step ends the motion and is returned.
    #[allow(clippy::too_many_arguments)]
    pub fn advance(
        &mut self,
        until: u64,
        push: Option<&[f64; 6]>,
        offsets: &[f64],
        learner: &mut Learner,
        controller: &mut ImpedanceController,
        safety: &mut SafetyLayer,
    ) -> Result<()> {
        let n = self.q_ref.len();
        if self.phase == Phase::Done {
            return Ok(());
        }
        let samples = self.samples_before(until) as usize;
        if samples.checked_mul(n) != Some(offsets.len()) {
            return Err(PhriError::shape("offsets", format!("({samples}, {n})"), format!("{} values", offsets.len())));
        }
        if let Some(w) = push {
            crate::error::check_finite("push", w)?;
        }
        for (arg, nq) in
            [("learner", learner.plan().dof()), ("controller", controller.model().nq()), ("safety", safety.model().nq())]
        {
            if nq != n {
                return Err(PhriError::shape(arg, format!("a robot of {n} joints"), format!("{nq} joints")));
            }
        }
        if !controller.params().gravity_compensation {
            return Err(PhriError::invalid(
                "controller",
                "must be made with gravity_compensation=True: the simulated arm needs the law's g(q)",
            ));
        }
        if !fits_simulated_arm(safety) {
            return Err(PhriError::invalid("safety", "must be made with gravity_compensated=False"));
        }
        let mut sample = 0;
        while self.k < until && self.phase != Phase::Done {
            let result = self.run_tick(push, offsets, &mut sample, learner, controller, safety);
            if let Err(e) = result {
                self.phase = Phase::Done;
                return Err(e);
            }
        }
        Ok(())
    }

    fn run_tick(
        &mut self,
        push: Option<&[f64; 6]>,
        offsets: &[f64],
        sample: &mut usize,
        learner: &mut Learner,
        controller: &mut ImpedanceController,
        safety: &mut SafetyLayer,
    ) -> Result<()> {
        let n = self.q_ref.len();
        let t = self.k as f64 * self.period;
        // Read: the push's joint torque at this state, and the sensor's sample if one falls here.
        if let Some(w) = push {
            let model = self.arm.model();
            model.forward_kinematics(self.arm.q(), &mut self.data)?;
            model.frame_jacobian(self.settings.hand, &self.data, &mut self.jacobian)?;
            for j in 0..n {
                self.push_torque[j] = (0..6).map(|r| self.jacobian[(r, j)] * w[r]).sum();
            }
        }
        if self.k % self.settings.sample_every == 0 {
            let offset = &offsets[*sample * n..(*sample + 1) * n];
            *sample += 1;
            for j in 0..n {
                self.measured[j] = offset[j] + if push.is_some() { self.push_torque[j] } else { 0.0 };
            }
        }
        match self.phase {
            Phase::Running => {
                let status = safety.check_state(t, self.arm.q(), self.arm.qd(), &self.measured)?;
                if let Some(v) = status.violation {
                    return self.begin_stop(v, t, push, controller, safety);
                }
                // A last tick past the motion's end is observed at the end (the learner refuses later times).
                let duration = self.settings.duration;
                match learner.observe(if t <= duration { t } else { duration }, &self.measured) {
                    Ok(_) => {}
                    Err(PhriError::ReplanWorker { reason }) => {
                        self.replan_failures += 1;
                        self.replan_error = Some(reason);
                    }
                    Err(e) => return Err(e),
                }
                learner.reference(t, &mut self.q_ref, &mut self.qd_ref, &mut self.qdd_ref);
                let status = controller.torque_implicit(
                    self.arm.q(),
                    self.arm.qd(),
                    &self.q_ref,
                    &self.qd_ref,
                    self.period,
                    &mut self.tau,
                )?;
                self.wall(status.wall.force);
                let status = safety.limit_torque(self.arm.q(), &mut self.tau, &mut self.command)?;
                if let Some(v) = status.violation {
                    return self.begin_stop(v, t, push, controller, safety);
                }
                self.log_row(t, push);
                self.arm.step(&self.command, push.map(|_| &self.push_torque[..]))?;
                self.ticks = self.k + 1;
                if t >= duration - 0.5 * self.period {
                    self.phase = Phase::Done;
                } else {
                    self.k += 1;
                }
                Ok(())
            }
            Phase::Holding { started, .. } => {
                if started {
                    let status = safety.check_state(t, self.arm.q(), self.arm.qd(), &self.measured)?;
                    // Holding is the response to a limit crossed; only a state that cannot be
                    // trusted (or a stalled clock) ends it early.
                    if status.violation.is_some_and(untrusted) {
                        self.phase = Phase::Done;
                        return Ok(());
                    }
                }
                self.hold_tick(t, push, controller, safety)
            }
            Phase::Done => Ok(()),
        }
    }

    /// The stop at this tick: recorded; then the hold begins with this tick, or the motion ends.
    fn begin_stop(
        &mut self,
        violation: Violation,
        t: f64,
        push: Option<&[f64; 6]>,
        controller: &mut ImpedanceController,
        safety: &mut SafetyLayer,
    ) -> Result<()> {
        let hold = !untrusted(violation);
        self.stop = Some(Stop {
            violation,
            tick: self.k,
            t,
            q: self.arm.q().to_vec(),
            qd: self.arm.qd().to_vec(),
            tau: self.tau.clone(),
            tau_ext: self.measured.clone(),
            hold,
        });
        if !hold {
            self.phase = Phase::Done;
            return Ok(());
        }
        self.q_ref.copy_from_slice(self.arm.q());
        self.qd_ref.fill(0.0);
        self.qdd_ref.fill(0.0);
        self.phase = Phase::Holding { t_stop: t, until: t + self.settings.hold_time - 0.5 * self.period, started: false };
        self.hold_tick(t, push, controller, safety)
    }

    /// One tick holding the stop's position with the impedance law.
    fn hold_tick(
        &mut self,
        t: f64,
        push: Option<&[f64; 6]>,
        controller: &mut ImpedanceController,
        safety: &mut SafetyLayer,
    ) -> Result<()> {
        let Phase::Holding { t_stop, until, .. } = self.phase else {
            return Ok(());
        };
        self.phase = Phase::Holding { t_stop, until, started: true };
        let status =
            controller.torque_implicit(self.arm.q(), self.arm.qd(), &self.q_ref, &self.qd_ref, self.period, &mut self.tau)?;
        if safety.limit_torque(self.arm.q(), &mut self.tau, &mut self.command)?.violation.is_some() {
            self.phase = Phase::Done; // a non-finite torque: nothing to hold with
            return Ok(());
        }
        self.wall(status.wall.force);
        self.log_row(t, push);
        self.arm.step(&self.command, push.map(|_| &self.push_torque[..]))?;
        self.ticks = self.k + 1;
        self.held = t - t_stop;
        if t >= until {
            self.phase = Phase::Done;
        } else {
            self.k += 1;
        }
        Ok(())
    }

    fn wall(&mut self, force: f64) {
        if force > 0.0 {
            self.wall_ticks += 1;
            self.wall_peak_force = self.wall_peak_force.max(force);
            self.wall_row = self.wall_row.max(force);
        }
    }

    /// A log row if this tick is on the log's grid.
    fn log_row(&mut self, t: f64, push: Option<&[f64; 6]>) {
        let position = t / self.settings.log_period + GRID_TOLERANCE;
        if position < self.next_row {
            return;
        }
        self.next_row = position.floor() + 1.0;
        let log = &mut self.log;
        log.t.push(t);
        log.q.extend_from_slice(self.arm.q());
        log.qd.extend_from_slice(self.arm.qd());
        log.q_ref.extend_from_slice(&self.q_ref);
        log.tau.extend_from_slice(&self.tau);
        log.tau_ext.extend_from_slice(&self.measured);
        log.wall_force.push(self.wall_row);
        log.push.extend_from_slice(push.unwrap_or(&[0.0; 6]));
        log.touched.push(push.is_some());
        self.wall_row = 0.0;
    }
}

/// Whether `safety` suits a simulated arm, which does not compensate gravity (the command is the
/// whole torque).
fn fits_simulated_arm(safety: &SafetyLayer) -> bool {
    !safety.params().gravity_compensated
}

/// Whether the state behind `v` cannot be held from: a non-finite time, position or velocity, or a
/// clock that does not advance (a hold measured on it would never end).
fn untrusted(v: Violation) -> bool {
    (v.limit == Limit::NonFinite && matches!(v.quantity, Quantity::Time | Quantity::Position | Quantity::Velocity))
        || v.limit == Limit::Clock
}

/// `e` about argument `arg` instead of the one it names.
fn rename(e: PhriError, arg: &str) -> PhriError {
    match e {
        PhriError::Shape { expected, got, .. } => PhriError::Shape { arg: arg.into(), expected, got },
        PhriError::NonFinite { index, value, .. } => PhriError::NonFinite { arg: arg.into(), index, value },
        e => e,
    }
}
