//! Features a task declares by kind, with its own name, frame, scene object and parameters, and
//! analytic derivatives: the height of a frame above an object, its distance from an object
//! (hinged at a radius, like the keep-outs), the alignment of one of its axes with a world
//! direction, the joint-space distance from a pose, and the speed of a frame.
//!
//! Each acts on the origin or axes of `frame` (None: the feature set's frame). Per-waypoint kinds
//! (height, alignment, joint distance) sum over q_1 … q_{N-1} as the built-ins do; `distance`
//! samples each segment as the keep-outs do; `speed` sums the squared step of the frame's origin
//! between consecutive waypoints, as efficiency sums the joints'.

use nalgebra::Vector3;

use super::{Feature, Keepout, Segment, SegmentGrad, MAX_SAMPLES};
use crate::error::{check_finite, PhriError, Result};
use crate::model::{FrameId, RobotModel};
use crate::scene::Scene;

/// The kinds a task file may declare, as it spells them.
pub const DECLARED_KINDS: [&str; 5] = ["height", "distance", "alignment", "joint_distance", "speed"];

/// Names of the parameters declared kind `kind` takes (none for an unknown kind).
pub fn declared_parameters(kind: &str) -> &'static [&'static str] {
    match kind {
        "height" => &["frame", "object", "offset"],
        "distance" => &["frame", "object", "radius", "offset", "samples", "shape"],
        "alignment" => &["frame", "axis", "direction"],
        "joint_distance" => &["pose"],
        "speed" => &["frame"],
        _ => &[],
    }
}

/// A declared feature's kind and parameters. Frames and objects are named; [`DeclaredSpec::build`]
/// resolves them against the robot and the scene.
#[derive(Debug, Clone, PartialEq)]
pub enum DeclaredSpec {
    /// φ = z − (top of `object` + `offset`) of the frame's origin at each waypoint [m]; without
    /// an object, z − `offset`.
    Height { frame: Option<String>, object: Option<String>, offset: f64 },
    /// φ = Σ_k max(0, `radius` − d(s_k)) over `samples` points per segment [m], d the frame
    /// origin's distance from `object`'s position + `offset` (x, y, z) [m]: horizontal (a vertical
    /// cylinder, as the keep-outs) or, with `sphere`, in 3D (a ball).
    Distance { frame: Option<String>, object: String, radius: f64, offset: [f64; 3], samples: usize, sphere: bool },
    /// φ = 1 − a·d at each waypoint: a the frame's axis `axis` (0 = x, 1 = y, 2 = z), d the unit
    /// world `direction` (normalised here); 0 aligned, 2 opposite. The cup's `coffee_dot` is x
    /// against +z.
    Alignment { frame: Option<String>, axis: usize, direction: [f64; 3] },
    /// φ = ‖q_i − `pose`‖² at each waypoint [rad²].
    JointDistance { pose: Vec<f64> },
    /// φ = ‖p(q_i) − p(q_{i-1})‖² per segment [m²], p the frame's origin: the squared Cartesian
    /// step, which a plan of fixed duration makes the frame's squared speed times the step time².
    Speed { frame: Option<String> },
}

impl DeclaredSpec {
    /// The kind, as task files spell it.
    pub fn kind(&self) -> &'static str {
        match self {
            DeclaredSpec::Height { .. } => "height",
            DeclaredSpec::Distance { .. } => "distance",
            DeclaredSpec::Alignment { .. } => "alignment",
            DeclaredSpec::JointDistance { .. } => "joint_distance",
            DeclaredSpec::Speed { .. } => "speed",
        }
    }

    /// Checks the parameters' values (errors name `arg`, e.g. "features[2]", and the parameter).
    pub fn check(&self, arg: &str) -> Result<()> {
        match self {
            DeclaredSpec::Height { offset, .. } => check_finite(&format!("{arg}.offset"), &[*offset]),
            DeclaredSpec::Distance { radius, offset, samples, .. } => {
                if !(radius.is_finite() && *radius > 0.0) {
                    return Err(PhriError::invalid(
                        &format!("{arg}.radius"),
                        format!("must be a finite distance > 0 m, got {radius}"),
                    ));
                }
                check_finite(&format!("{arg}.offset"), offset)?;
                if *samples == 0 || *samples > MAX_SAMPLES {
                    return Err(PhriError::invalid(
                        &format!("{arg}.samples"),
                        format!("must be in 1..={MAX_SAMPLES} points per segment, got {samples}"),
                    ));
                }
                Ok(())
            }
            DeclaredSpec::Alignment { axis, direction, .. } => {
                if *axis > 2 {
                    return Err(PhriError::invalid(&format!("{arg}.axis"), format!("must be x, y or z (0, 1 or 2), got {axis}")));
                }
                check_finite(&format!("{arg}.direction"), direction)?;
                let norm = Vector3::from(*direction).norm();
                if !(norm > 1e-9 && norm.is_finite()) {
                    return Err(PhriError::invalid(&format!("{arg}.direction"), "must be a nonzero vector (x, y, z)"));
                }
                Ok(())
            }
            DeclaredSpec::JointDistance { pose } => check_finite(&format!("{arg}.pose"), pose),
            DeclaredSpec::Speed { .. } => Ok(()),
        }
    }

    /// The feature `name` on `model`, its object placed by `scene` (errors name `arg`).
    pub fn build(&self, name: &str, arg: &str, scene: Option<&Scene>, model: &RobotModel) -> Result<Box<dyn Feature>> {
        self.check(arg)?;
        let frame = |f: &Option<String>| -> Result<Option<FrameId>> {
            f.as_deref()
                .map(|f| {
                    model.frame_id(f).map_err(|_| PhriError::UnknownName {
                        arg: format!("{arg}.frame"),
                        kind: "frame".into(),
                        name: f.into(),
                        known: model.frames.iter().map(|fr| fr.name.as_str()).collect::<Vec<_>>().join(", "),
                    })
                })
                .transpose()
        };
        let object = |object: &str| {
            let scene = scene.ok_or_else(|| {
                PhriError::invalid("scene", format!("is needed by feature '{name}' ({arg}), which names object '{object}'"))
            })?;
            scene.require(&format!("{arg}.object"), object)
        };
        Ok(match self {
            DeclaredSpec::Height { frame: f, object: o, offset } => {
                let base = match o {
                    None => 0.0,
                    Some(o) => object(o)?.top().ok_or_else(|| {
                        PhriError::invalid(&format!("{arg}.object"), format!("'{o}' has no top (a plane that is not horizontal)"))
                    })?,
                };
                Box::new(Height { name: name.into(), frame: frame(f)?, height: base + offset })
            }
            DeclaredSpec::Distance { frame: f, object: o, radius, offset, samples, sphere } => {
                let c = object(o)?.position() + Vector3::from(*offset);
                let mut k = Keepout::cylinder(name, c.xy(), *radius, *samples);
                k.frame = frame(f)?;
                k.height = sphere.then_some(c.z);
                Box::new(k)
            }
            DeclaredSpec::Alignment { frame: f, axis, direction } => Box::new(Alignment {
                name: name.into(),
                frame: frame(f)?,
                axis: *axis,
                direction: Vector3::from(*direction).normalize(),
            }),
            DeclaredSpec::JointDistance { pose } => {
                if pose.len() != model.nq() {
                    return Err(PhriError::shape(
                        &format!("{arg}.pose"),
                        format!("({},)", model.nq()),
                        format!("({},)", pose.len()),
                    ));
                }
                Box::new(JointDistance { name: name.into(), pose: pose.clone() })
            }
            DeclaredSpec::Speed { frame: f } => Box::new(Speed { name: name.into(), frame: frame(f)? }),
        })
    }
}

/// Height of a frame's origin above `height` [m] at q_i (see [`DeclaredSpec::Height`]).
#[derive(Debug, Clone)]
pub struct Height {
    pub name: String,
    pub frame: Option<FrameId>,
    /// The reference height [m].
    pub height: f64,
}

impl Feature for Height {
    fn name(&self) -> &str {
        &self.name
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let value = seg.point_of(self.frame, 1.0).position.z - self.height;
        if let Some(g) = grad {
            let jac = seg.jacobian_of(self.frame, 1.0);
            for j in 0..g.this.len() {
                g.this[j] += g.scale * jac[(2, j)];
            }
            if let Some(h) = g.hessian {
                if h.kinematic() {
                    seg.add_position_curvature_of(self.frame, 1.0, &Vector3::z(), g.scale, h);
                }
            }
        }
        value
    }
}

/// 1 − a·d at q_i, a a frame axis and d a unit world direction (see [`DeclaredSpec::Alignment`]).
#[derive(Debug, Clone)]
pub struct Alignment {
    pub name: String,
    pub frame: Option<FrameId>,
    /// The frame's axis: 0 = x, 1 = y, 2 = z.
    pub axis: usize,
    /// Unit direction in the base frame.
    pub direction: Vector3<f64>,
}

impl Feature for Alignment {
    fn name(&self) -> &str {
        &self.name
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let a: Vector3<f64> = seg.point_of(self.frame, 1.0).rotation.column(self.axis).into();
        let value = 1.0 - a.dot(&self.direction);
        if let Some(g) = grad {
            // ∂a/∂q_j = ω_j × a, with ω_j the angular rows of the Jacobian.
            let w = -self.direction;
            let jac = seg.jacobian_of(self.frame, 1.0);
            for j in 0..g.this.len() {
                let omega = Vector3::new(jac[(3, j)], jac[(4, j)], jac[(5, j)]);
                g.this[j] += g.scale * w.dot(&omega.cross(&a));
            }
            if let Some(h) = g.hessian {
                if h.kinematic() {
                    seg.add_axis_curvature_of(self.frame, 1.0, self.axis, &w, g.scale, h);
                }
            }
        }
        value
    }
}

/// ‖q_i − pose‖² [rad²] (see [`DeclaredSpec::JointDistance`]).
#[derive(Debug, Clone)]
pub struct JointDistance {
    pub name: String,
    /// The pose [rad], one entry per joint.
    pub pose: Vec<f64>,
}

impl Feature for JointDistance {
    fn name(&self) -> &str {
        &self.name
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let value = seg.q.iter().zip(&self.pose).map(|(q, p)| (q - p) * (q - p)).sum();
        if let Some(g) = grad {
            for j in 0..g.this.len() {
                g.this[j] += 2.0 * g.scale * (seg.q[j] - self.pose[j]);
            }
            if let Some(h) = g.hessian {
                let n = h.dof();
                let scratch = h.scratch();
                scratch.fill(0.0);
                for j in 0..n {
                    scratch[j * n + j] = 2.0;
                }
                h.add_scratch_at(1.0, g.scale);
            }
        }
        value
    }
}

/// ‖p(q_i) − p(q_{i-1})‖² [m²], p a frame's origin (see [`DeclaredSpec::Speed`]).
#[derive(Debug, Clone)]
pub struct Speed {
    pub name: String,
    pub frame: Option<FrameId>,
}

impl Feature for Speed {
    fn name(&self) -> &str {
        &self.name
    }
    /// A sum of squared steps, as efficiency.
    fn resolution_exponent(&self) -> i32 {
        -1
    }
    fn segment(&self, seg: &mut Segment<'_>, grad: Option<SegmentGrad<'_>>) -> f64 {
        let d = seg.point_of(self.frame, 1.0).position - seg.point_of(self.frame, 0.0).position;
        let value = d.norm_squared();
        if let Some(g) = grad {
            let n = g.this.len();
            // 2·dᵀJ at each end (+ at q_i, − at q_{i-1}); Gauss–Newton 2·[−J₀, J₁]ᵀ[−J₀, J₁].
            let j1 = seg.jacobian_of(self.frame, 1.0).fixed_rows::<3>(0).into_owned();
            let j0 = seg.jacobian_of(self.frame, 0.0).fixed_rows::<3>(0).into_owned();
            for j in 0..n {
                g.this[j] += 2.0 * g.scale * d.dot(&j1.column(j));
                g.prev[j] -= 2.0 * g.scale * d.dot(&j0.column(j));
            }
            if let Some(h) = g.hessian {
                for c in 0..3 {
                    h.add_outer_pair(2.0 * g.scale, |j| -j0[(c, j)], |j| j1[(c, j)]);
                }
                if h.kinematic() {
                    seg.add_position_curvature_of(self.frame, 1.0, &d, 2.0 * g.scale, h);
                    seg.add_position_curvature_of(self.frame, 0.0, &(-d), 2.0 * g.scale, h);
                }
            }
        }
        value
    }
}
