//! The study's scene and feature specifications, read from the shipped task files
//! (python/phri/tasks/*.toml), so that their numbers have one home. Shared by phri_core's
//! integration tests (`common::study`) and the benchmarks (benches/lib.rs includes this file).

use std::sync::Arc;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};
use phri_core::features::{feature_parameters, FeatureParams, FeatureSet, FeatureSpec, KeepoutSpec, DEFAULT_SAMPLES};
use phri_core::scene::{ObjectKind, Scene, SceneObject, Shape, DEFAULT_MARGIN};
use phri_core::{FrameId, RobotModel};
use toml_edit::{DocumentMut, Item, Table};

/// The four task files, in the study's order: (task name, TOML text).
pub const TASK_FILES: [(&str, &str); 4] = [
    ("human", include_str!("../../../../python/phri/tasks/human.toml")),
    ("coffee", include_str!("../../../../python/phri/tasks/coffee.toml")),
    ("table", include_str!("../../../../python/phri/tasks/table.toml")),
    ("laptop", include_str!("../../../../python/phri/tasks/laptop.toml")),
];

/// The parsed task file of study task `task`.
pub fn task_file(task: &str) -> DocumentMut {
    let (_, text) = TASK_FILES.iter().find(|(name, _)| *name == task).unwrap_or_else(|| panic!("no task file '{task}'"));
    text.parse().unwrap_or_else(|e| panic!("task file '{task}': {e}"))
}

fn number(item: &Item, what: &str) -> f64 {
    item.as_float().or_else(|| item.as_integer().map(|i| i as f64)).unwrap_or_else(|| panic!("{what} must be a number"))
}

fn numbers<const N: usize>(item: &Item, what: &str) -> [f64; N] {
    let array = item.as_array().unwrap_or_else(|| panic!("{what} must be an array"));
    assert_eq!(array.len(), N, "{what} must have {N} numbers");
    let mut out = [0.0; N];
    for (o, v) in out.iter_mut().zip(array.iter()) {
        *o = v.as_float().or_else(|| v.as_integer().map(|i| i as f64)).unwrap_or_else(|| panic!("{what}: not a number"));
    }
    out
}

fn object(name: &str, t: &Table) -> SceneObject {
    let what = |key: &str| format!("scene.{name}.{key}");
    let get = |key: &str| t.get(key).unwrap_or_else(|| panic!("{} missing", what(key)));
    let shape = match t.get("shape").and_then(Item::as_str) {
        Some("plane") => Shape::Plane,
        Some("box") => Shape::Box { size: Vector3::from(numbers::<3>(get("size"), &what("size"))) },
        Some("cylinder") => {
            Shape::Cylinder { radius: number(get("radius"), &what("radius")), length: number(get("length"), &what("length")) }
        }
        Some("sphere") => Shape::Sphere { radius: number(get("radius"), &what("radius")) },
        other => panic!("{}: unknown shape {other:?}", what("shape")),
    };
    let [x, y, z] = numbers::<3>(get("position"), &what("position"));
    let [roll, pitch, yaw] = t.get("rpy").map_or([0.0; 3], |r| numbers::<3>(r, &what("rpy")));
    let pose = Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_euler_angles(roll, pitch, yaw));
    let margin = t.get("margin").map_or(DEFAULT_MARGIN, |m| number(m, &what("margin")));
    let kind = ObjectKind::from_name(t.get("kind").and_then(Item::as_str).unwrap_or("furniture")).unwrap();
    SceneObject::new(name, shape, pose, margin, kind).unwrap()
}

/// The `[scene]` of study task `task`'s file.
pub fn task_scene(task: &str) -> Scene {
    let doc = task_file(task);
    let scene = doc.get("scene").and_then(Item::as_table).unwrap_or_else(|| panic!("task '{task}' has no [scene]"));
    let objects = scene.iter().map(|(name, item)| object(name, item.as_table().expect("a [scene.<name>] table")));
    Scene::new(objects.collect()).unwrap()
}

/// The study's scene: the one every task file describes (checked).
pub fn study_scene() -> Scene {
    let scene = task_scene(TASK_FILES[0].0);
    for (task, _) in &TASK_FILES[1..] {
        assert_eq!(task_scene(task), scene, "task '{task}' describes another scene");
    }
    scene
}

/// The specification of feature `name` as the task files give it (the first file with a
/// `[features.<name>]` table; a feature no file lists takes no parameters).
pub fn feature_spec(name: &str) -> FeatureSpec {
    let docs: Vec<DocumentMut> = TASK_FILES.iter().map(|(task, _)| task_file(task)).collect();
    let table = docs.iter().find_map(|d| d.get("features").and_then(|f| f.get(name)).and_then(Item::as_table));
    let takes = feature_parameters(name);
    let params = match table {
        Some(t) if takes.contains(&"keep_out") => {
            let what = |key: &str| format!("features.{name}.{key}");
            FeatureParams::Keepout(KeepoutSpec {
                keep_out: t.get("keep_out").and_then(Item::as_str).expect("keep_out").into(),
                radius: number(t.get("radius").expect("radius"), &what("radius")),
                offset: t.get("offset").map_or([0.0; 2], |o| numbers::<2>(o, &what("offset"))),
                samples: t.get("samples").map_or(DEFAULT_SAMPLES, |s| s.as_integer().expect("samples: an integer") as usize),
            })
        }
        Some(t) if takes.contains(&"height") => {
            FeatureParams::Table { height: t.get("height").map_or(0.0, |h| number(h, &format!("features.{name}.height"))) }
        }
        _ => FeatureParams::None,
    };
    FeatureSpec { name: name.into(), params }
}

/// The built-in features `names` with the task files' parameters, placed in the study's scene.
pub fn study_features(model: Arc<RobotModel>, frame: FrameId, names: &[&str]) -> FeatureSet {
    let specs: Vec<FeatureSpec> = names.iter().map(|n| feature_spec(n)).collect();
    FeatureSet::from_specs(model, frame, &specs, Some(&study_scene())).unwrap()
}

/// Centre (x, y) [m] and radius [m] of keep-out feature `name`'s circle in the study's scene.
pub fn keepout_circle(name: &str) -> (Vector2<f64>, f64) {
    match feature_spec(name).params {
        FeatureParams::Keepout(k) => {
            let scene = study_scene();
            (scene.require("keep_out", &k.keep_out).unwrap().xy() + Vector2::from(k.offset), k.radius)
        }
        other => panic!("feature '{name}' is no keep-out feature: {other:?}"),
    }
}

/// Height of the top of the study scene's table [m].
pub fn table_top() -> f64 {
    study_scene().get("table").expect("a table").top().expect("a bounded table")
}

/// The horizontal unit vector from keep-out feature `name`'s centre towards `p` [m] (the way a
/// person pushes the cup out of the circle).
pub fn away_from_keepout(name: &str, p: &Vector3<f64>) -> Vector3<f64> {
    let (center, _) = keepout_circle(name);
    Vector3::new(p.x - center.x, p.y - center.y, 0.0).normalize()
}
