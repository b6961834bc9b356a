//! The run-time virtual wall: a repulsive torque in the control law that keeps every collision
//! body of the arm at least a margin from the furniture, whatever the reference says and however
//! the person pushes (on the table task the person pushes the cup down toward the table).
//!
//! The closest sphere pair of each body–furniture pair within margin + band gets a normal force
//! F = k·x + c·min(1, x / band)·max(0, −ḋ) [N], x = margin + band − d, along the distance's
//! gradient, applied as the torque F·∂d/∂q. The damping grows with the depth across the band, as in
//! Hunt and Crossley's contact model (1975), and is c from the margin inward: the force starts from
//! zero at the band's edge, so an arm that the person pushes into the band at speed is not struck by
//! a step of c·|ḋ| (a kick that could spin the light wrist past its velocity limit). The person is
//! not a wall: their hand touching the arm is the point of the interaction, and plans keep clear of
//! their body.

use std::sync::Arc;

use crate::collision::{CollisionChecker, ProximityScratch};
use crate::data::RobotData;
use crate::error::{PhriError, Result};
use crate::model::RobotModel;
use crate::scene::{ObjectKind, Scene};

/// The wall's settings; `Default` gives the documented defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallParams {
    /// Least distance kept from the furniture while the arm runs [m] (default 5 mm).
    pub margin: f64,
    /// The wall starts acting this much farther out [m] (default 1 cm).
    pub band: f64,
    /// Its stiffness k [N/m] (default 8000: 80 N per body at the margin, against a firm push of 30–40 N).
    pub stiffness: f64,
    /// Its damping c on approach from the margin inward [N·s/m] (default 200: about critical for a
    /// link of 1 kg); across the band it grows in proportion to the depth from zero at its edge.
    pub damping: f64,
}

/// The documented defaults of [`WallParams`].
pub const DEFAULT_WALL: WallParams = WallParams { margin: 0.005, band: 0.01, stiffness: 8000.0, damping: 200.0 };

impl Default for WallParams {
    fn default() -> Self {
        DEFAULT_WALL
    }
}

/// The accepted ranges of [`WallParams`]: margin and band within 1 m [m] (the wall acts near the
/// furniture), stiffness up to 10⁶ N/m and damping up to 10⁵ N·s/m (beyond them the force of a
/// millimetre is a hard impact, and the torque can overflow).
pub const WALL_RANGES: [(&str, f64); 4] =
    [("wall_margin", 1.0), ("wall_band", 1.0), ("wall_stiffness", 1e6), ("wall_damping", 1e5)];

impl WallParams {
    /// Checks every parameter against [`WALL_RANGES`], naming the first outside.
    pub fn check(&self) -> Result<()> {
        let values = [self.margin, self.band, self.stiffness, self.damping];
        for ((arg, top), v) in WALL_RANGES.iter().zip(values) {
            if !(v >= 0.0 && v <= *top) {
                return Err(PhriError::invalid(arg, format!("must be in [0, {top:e}], got {v}")));
            }
        }
        if !(self.band > 0.0 && self.stiffness > 0.0) {
            return Err(PhriError::invalid("wall_stiffness", "and wall_band must be > 0"));
        }
        Ok(())
    }
}

/// What the wall did in one control step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallStatus {
    /// Sum of the wall's normal forces [N] (0: it did not act).
    pub force: f64,
    /// Smallest distance of a body to the furniture within the wall's reach [m] (∞ beyond it).
    pub distance: f64,
}

impl Default for WallStatus {
    fn default() -> Self {
        WallStatus { force: 0.0, distance: f64::INFINITY }
    }
}

/// A virtual wall around the furniture of a scene, for one robot.
#[derive(Debug, Clone)]
pub struct VirtualWall {
    params: WallParams,
    checker: Arc<CollisionChecker>,
    data: RobotData,
    scratch: ProximityScratch,
    /// The gradient of the closest sphere pair of the pair being visited.
    closest: Vec<f64>,
}

impl VirtualWall {
    /// The wall around `scene`'s furniture for `robot` (which needs a complete collision model).
    pub fn new(robot: &RobotModel, scene: &Scene, params: WallParams) -> Result<Self> {
        params.check()?;
        let furniture: Vec<_> = scene.objects().iter().filter(|o| o.kind() == ObjectKind::Furniture).cloned().collect();
        let checker = CollisionChecker::new(robot, &Scene::new(furniture)?, None)?;
        Ok(VirtualWall {
            params,
            checker: Arc::new(checker),
            data: robot.data(),
            scratch: ProximityScratch::for_robot(robot),
            closest: vec![0.0; robot.nq()],
        })
    }

    /// An error unless the wall was made for `robot` (its name and collision bodies).
    pub fn check_robot(&self, robot: &RobotModel) -> Result<()> {
        if self.checker.robot_name() != robot.name || self.checker.body_count() != robot.collision().bodies().len() {
            return Err(PhriError::invalid("wall", "was made for another robot (or its collision model changed)"));
        }
        Ok(())
    }

    pub fn params(&self) -> &WallParams {
        &self.params
    }

    /// Adds the wall's torque at (q [rad], q̇ [rad/s]) to `tau` [N·m]: for each body–furniture pair
    /// within reach, a force at its closest sphere pair (one per pair, so that a body's several
    /// spheres do not add up to a force its joints cannot give).
    pub fn add_torque(&mut self, robot: &RobotModel, q: &[f64], qd: &[f64], tau: &mut [f64]) -> WallStatus {
        robot.forward_kinematics_unchecked(q, &mut self.data);
        let p = self.params;
        let reach = p.margin + p.band;
        let mut status = WallStatus { force: 0.0, distance: f64::INFINITY };
        let n = robot.nq();
        self.closest.resize(n, 0.0);
        let (closest, mut pair, mut nearest) = (&mut self.closest, usize::MAX, f64::INFINITY);
        let mut apply = |distance: f64, g: &[f64], status: &mut WallStatus| {
            if distance >= reach {
                return;
            }
            status.distance = status.distance.min(distance);
            let rate: f64 = g.iter().zip(qd).map(|(g, v)| g * v).sum();
            let depth = reach - distance;
            let force = p.stiffness * depth + p.damping * (depth / p.band).min(1.0) * (-rate).max(0.0);
            status.force += force;
            for (t, g) in tau.iter_mut().zip(g) {
                *t += force * g;
            }
        };
        // The checker measures from each object's planning margin + band; the wall, from its reach.
        self.checker.for_each_near(robot, &self.data, &mut self.scratch, reach, |near, g| {
            if near.pair != pair {
                if pair != usize::MAX {
                    apply(nearest, closest, &mut status);
                }
                (pair, nearest) = (near.pair, f64::INFINITY);
            }
            if near.distance < nearest {
                nearest = near.distance;
                closest.copy_from_slice(g);
            }
        });
        if pair != usize::MAX {
            apply(nearest, closest, &mut status);
        }
        status
    }
}
