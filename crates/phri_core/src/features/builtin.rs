//! The built-in features by name (one of [`BUILTIN_FEATURES`]) and the parameters each takes, with
//! the keep-out features placed by the [`Scene`] object they name.
//!
//! The authors' laptop and human features (Bajcsy et al., CoRL 2017, and their published code)
//! keep the cup out of a vertical cylinder about the laptop and about the person; here the centre
//! of that circle is the named object's xy position plus an `offset` (the authors' laptop circle
//! sits 10 cm off the laptop's centre), so moving an object in a task's scene moves its feature.
//! No scene numbers live here: a task's scene places its objects.

use nalgebra::Vector2;

use super::{Coffee, CoffeeForm, DeclaredSpec, Efficiency, Feature, Keepout, Origin, Table};
use crate::error::{check_finite, PhriError, Result};
use crate::model::RobotModel;
use crate::scene::Scene;

/// Names of the built-in features, as task files and the bindings spell them.
pub const BUILTIN_FEATURES: [&str; 7] = ["efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin"];

/// Most keep-out samples per segment (the original used 4; more than this is a mistake, and would
/// make every evaluation slow).
pub const MAX_SAMPLES: usize = 1000;

/// Points per segment of a keep-out feature when its specification gives none (the authors' 4).
pub const DEFAULT_SAMPLES: usize = 4;

/// Parameters of a keep-out feature: keep the feature point out of the vertical cylinder of
/// `radius` [m] about the scene object `keep_out`, shifted by `offset` (x, y) [m].
#[derive(Debug, Clone, PartialEq)]
pub struct KeepoutSpec {
    /// Name of the scene object the feature keeps away from.
    pub keep_out: String,
    /// Radius of the keep-out circle [m].
    pub radius: f64,
    /// Centre of the circle relative to the object's xy position [m].
    pub offset: [f64; 2],
    /// Points per segment at which the feature is evaluated.
    pub samples: usize,
}

impl KeepoutSpec {
    /// The keep-out circle's centre (x, y) [m]: the named object's position plus `offset`; `arg`
    /// names the feature in an error (e.g. "features[1]").
    pub fn center(&self, arg: &str, scene: &Scene) -> Result<Vector2<f64>> {
        Ok(scene.require(&format!("{arg}.keep_out"), &self.keep_out)?.xy() + Vector2::from(self.offset))
    }
}

/// The parameters a built-in feature takes.
#[derive(Debug, Clone, PartialEq)]
pub enum FeatureParams {
    /// Efficiency, coffee, coffee_dot and origin take none.
    None,
    /// The table feature: height above `height` [m] (the authors use raw z: 0).
    Table { height: f64 },
    /// The laptop and human features.
    Keepout(KeepoutSpec),
    /// A feature of a declared kind under its own name (see [`DeclaredSpec`]).
    Declared(DeclaredSpec),
}

/// One feature of a set: its name and parameters.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureSpec {
    pub name: String,
    pub params: FeatureParams,
}

/// Names of the parameters built-in feature `name` takes (none for an unknown name).
pub fn feature_parameters(name: &str) -> &'static [&'static str] {
    match name {
        "table" => &["height"],
        "laptop" | "human" => &["keep_out", "radius", "offset", "samples"],
        _ => &[],
    }
}

fn unknown_feature(arg: &str, name: &str) -> PhriError {
    PhriError::UnknownName { arg: arg.into(), kind: "feature".into(), name: name.into(), known: BUILTIN_FEATURES.join(", ") }
}

impl FeatureSpec {
    /// Checks that the name is a built-in feature that takes these parameters, and their values
    /// (errors name `arg`, e.g. "features[2]", and the parameter).
    pub fn check(&self, arg: &str) -> Result<()> {
        if let FeatureParams::Declared(d) = &self.params {
            if self.name.is_empty() {
                return Err(PhriError::invalid(arg, format!("declares a '{}' feature without a name", d.kind())));
            }
            return d.check(arg);
        }
        if !BUILTIN_FEATURES.contains(&self.name.as_str()) {
            return Err(unknown_feature(arg, &self.name));
        }
        let params = feature_parameters(&self.name);
        let takes = match &self.params {
            FeatureParams::None => !params.contains(&"keep_out"),
            FeatureParams::Table { .. } => self.name == "table",
            FeatureParams::Keepout(_) => params.contains(&"keep_out"),
            FeatureParams::Declared(_) => false, // returned above
        };
        if !takes {
            let message = match &self.params {
                FeatureParams::None => {
                    format!("is keep-out feature '{}': it needs keep_out (a scene object's name) and radius [m]", self.name)
                }
                _ => {
                    let list = if params.is_empty() { "none".to_string() } else { params.join(", ") };
                    format!("gives parameters that feature '{}' does not take (it takes: {list})", self.name)
                }
            };
            return Err(PhriError::invalid(arg, message));
        }
        match &self.params {
            FeatureParams::None | FeatureParams::Declared(_) => Ok(()),
            FeatureParams::Table { height } => check_finite(&format!("{arg}.height"), &[*height]),
            FeatureParams::Keepout(k) => {
                if !(k.radius.is_finite() && k.radius > 0.0) {
                    return Err(PhriError::invalid(
                        &format!("{arg}.radius"),
                        format!("must be a finite distance > 0 m, got {}", k.radius),
                    ));
                }
                check_finite(&format!("{arg}.offset"), &k.offset)?;
                if k.samples == 0 || k.samples > MAX_SAMPLES {
                    return Err(PhriError::invalid(
                        &format!("{arg}.samples"),
                        format!("must be in 1..={MAX_SAMPLES} points per segment, got {}", k.samples),
                    ));
                }
                Ok(())
            }
        }
    }

    /// The feature on `model`, its keep-out circle or object placed by `scene` (errors name `arg`).
    pub fn build(&self, arg: &str, scene: Option<&Scene>, model: &RobotModel) -> Result<Box<dyn Feature>> {
        self.check(arg)?;
        Ok(match (self.name.as_str(), &self.params) {
            (name, FeatureParams::Declared(d)) => return d.build(name, arg, scene, model),
            ("efficiency", _) => Box::new(Efficiency),
            ("table", FeatureParams::Table { height }) => Box::new(Table { height: *height }),
            ("table", _) => Box::new(Table { height: 0.0 }),
            ("coffee", _) => Box::new(Coffee { form: CoffeeForm::Horizontal }),
            ("coffee_dot", _) => Box::new(Coffee { form: CoffeeForm::Dot }),
            ("origin", _) => Box::new(Origin),
            (name, FeatureParams::Keepout(k)) => {
                let scene = scene.ok_or_else(|| {
                    PhriError::invalid(
                        "scene",
                        format!("is needed by keep-out feature '{name}' ({arg}), which keeps away from '{}'", k.keep_out),
                    )
                })?;
                Box::new(Keepout::cylinder(name, k.center(arg, scene)?, k.radius, k.samples))
            }
            (name, _) => return Err(PhriError::invalid(arg, format!("gives feature '{name}' parameters it does not take"))),
        })
    }
}
