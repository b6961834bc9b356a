//! The built-in features by name, and the scene numbers they take.

use nalgebra::Vector2;

use super::{Coffee, CoffeeForm, Efficiency, Feature, Keepout, Origin, Table};
use crate::error::{check_finite, PhriError, Result};

/// Scene numbers the built-in features use (defaults: the scene of the authors' published code).
#[derive(Debug, Clone)]
pub struct SceneParams {
    /// Subtracted from the table feature's height [m]; 0 gives the original raw z.
    pub table_height: f64,
    /// Laptop feature centre (x, y) [m].
    pub laptop_center: [f64; 2],
    /// Human feature centre (x, y) [m].
    pub human_center: [f64; 2],
    /// Keep-out radius of the laptop feature [m].
    pub laptop_radius: f64,
    /// Keep-out radius of the human feature [m].
    pub human_radius: f64,
    /// Points per segment of the keep-out features.
    pub samples: usize,
}

impl Default for SceneParams {
    fn default() -> Self {
        SceneParams {
            table_height: 0.0,
            laptop_center: [-0.7929, -0.1],
            human_center: [0.0, 0.2],
            laptop_radius: 0.4,
            human_radius: 0.4,
            samples: 4,
        }
    }
}

/// Most keep-out samples per segment (the original used 4; more than this is a mistake, and would
/// make every evaluation slow).
pub const MAX_SAMPLES: usize = 1000;

/// Names accepted by [`builtin`].
pub const BUILTIN_FEATURES: [&str; 7] = ["efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin"];

/// A built-in feature by name.
pub fn builtin(name: &str, scene: &SceneParams) -> Result<Box<dyn Feature>> {
    for (arg, radius) in [("laptop_radius", scene.laptop_radius), ("human_radius", scene.human_radius)] {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(PhriError::invalid(arg, format!("must be a finite distance > 0 m, got {radius}")));
        }
    }
    if scene.samples == 0 || scene.samples > MAX_SAMPLES {
        return Err(PhriError::invalid(
            "samples",
            format!("must be 1 to {MAX_SAMPLES} points per segment, got {}", scene.samples),
        ));
    }
    check_finite("table_height", &[scene.table_height])?;
    check_finite("laptop_center", &scene.laptop_center)?;
    check_finite("human_center", &scene.human_center)?;
    let keepout = |name: &str, c: [f64; 2], radius: f64| Keepout {
        name: name.into(),
        center: Vector2::from(c),
        radius,
        samples: scene.samples,
    };
    Ok(match name {
        "efficiency" => Box::new(Efficiency),
        "table" => Box::new(Table { height: scene.table_height }),
        "coffee" => Box::new(Coffee { form: CoffeeForm::Horizontal }),
        "coffee_dot" => Box::new(Coffee { form: CoffeeForm::Dot }),
        "laptop" => Box::new(keepout("laptop", scene.laptop_center, scene.laptop_radius)),
        "human" => Box::new(keepout("human", scene.human_center, scene.human_radius)),
        "origin" => Box::new(Origin),
        other => {
            return Err(PhriError::UnknownName {
                arg: "features".into(),
                kind: "feature".into(),
                name: other.into(),
                known: BUILTIN_FEATURES.join(", "),
            })
        }
    })
}
