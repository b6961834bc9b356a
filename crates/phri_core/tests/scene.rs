//! The scene type (validation, lookup, geometry) and features built from specifications.

mod common;

use std::sync::Arc;

use common::study::{feature_spec, study_scene};
use common::{deg, jaco2};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector2, Vector3};
use phri_core::features::{Feature, FeatureParams, FeatureSet, FeatureSpec, Keepout, KeepoutSpec};
use phri_core::scene::{ObjectKind, Scene, SceneObject, Shape};
use phri_core::PhriError;

fn at(x: f64, y: f64, z: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
}

fn keepout(name: &str, object: &str, offset: [f64; 2]) -> FeatureSpec {
    FeatureSpec {
        name: name.into(),
        params: FeatureParams::Keepout(KeepoutSpec { keep_out: object.into(), radius: 0.4, offset, samples: 4 }),
    }
}

fn plain(name: &str) -> FeatureSpec {
    FeatureSpec { name: name.into(), params: FeatureParams::None }
}

#[test]
fn objects_are_validated_and_name_the_argument() {
    let bad = |shape: Shape, pose: Isometry3<f64>, margin: f64| {
        SceneObject::new("x", shape, pose, margin, ObjectKind::Furniture).unwrap_err()
    };
    let arg = |e: PhriError| match e {
        PhriError::InvalidParameter { arg, .. } | PhriError::NonFinite { arg, .. } => arg,
        other => panic!("unexpected {other:?}"),
    };
    assert_eq!(arg(bad(Shape::Box { size: Vector3::new(1.0, 0.0, 1.0) }, at(0.0, 0.0, 0.0), 0.0)), "size");
    assert_eq!(arg(bad(Shape::Sphere { radius: f64::NAN }, at(0.0, 0.0, 0.0), 0.0)), "radius");
    assert_eq!(arg(bad(Shape::Cylinder { radius: 0.1, length: -1.0 }, at(0.0, 0.0, 0.0), 0.0)), "length");
    assert_eq!(arg(bad(Shape::Plane, at(f64::INFINITY, 0.0, 0.0), 0.0)), "position");
    assert_eq!(arg(bad(Shape::Plane, at(0.0, 0.0, 0.0), -0.01)), "margin");
    assert!(SceneObject::new("", Shape::Plane, at(0.0, 0.0, 0.0), 0.0, ObjectKind::Furniture).is_err());
    let table = study_scene().objects()[0].clone();
    let e = Scene::new(vec![table.clone(), table]).unwrap_err();
    assert!(e.to_string().contains("'table' twice"), "{e}");
}

#[test]
fn lookup_lists_the_known_objects() {
    let scene = study_scene();
    assert_eq!(scene.names(), ["table", "laptop", "person"]);
    assert_eq!(scene.get("person").unwrap().kind(), ObjectKind::Person);
    let e = scene.require("keep_out", "lamp").unwrap_err();
    assert_eq!(e.to_string(), "keep_out: unknown scene object 'lamp'; known: table, laptop, person");
    assert!(ObjectKind::from_name("robot").is_err());
}

#[test]
fn top_is_the_highest_point() {
    let scene = study_scene();
    // Upright objects: centre plus half the height, to rounding.
    assert!((scene.get("table").unwrap().top().unwrap() + 0.1016).abs() < 1e-15);
    assert_eq!(scene.get("laptop").unwrap().top(), Some(-0.1016 + 0.025));
    let ball = SceneObject::new("b", Shape::Sphere { radius: 0.1 }, at(0.0, 0.0, 1.0), 0.0, ObjectKind::Furniture).unwrap();
    assert_eq!(ball.top(), Some(1.1));
    let floor = SceneObject::new("f", Shape::Plane, at(0.0, 0.0, -0.7), 0.0, ObjectKind::Furniture).unwrap();
    assert_eq!(floor.top(), Some(-0.7));
    let tilted = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::from_euler_angles(0.3, 0.0, 0.0));
    assert_eq!(SceneObject::new("w", Shape::Plane, tilted, 0.0, ObjectKind::Furniture).unwrap().top(), None);
    // A cylinder on its side: its radius above the axis.
    let side = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.5),
        UnitQuaternion::from_euler_angles(std::f64::consts::FRAC_PI_2, 0.0, 0.0),
    );
    let log = SceneObject::new("log", Shape::Cylinder { radius: 0.1, length: 2.0 }, side, 0.0, ObjectKind::Furniture).unwrap();
    assert!((log.top().unwrap() - 0.6).abs() < 1e-12);
}

#[test]
fn the_task_files_give_the_authors_keepout_features() {
    // The keep-out features of the authors' published code, written out here as the independent
    // reference for what the task files give (the circles' values: the next test). The person's
    // torso stands at the table's side, clear of the arm and of the authors' human circle about (0, 0.2).
    let expected = [("laptop", "laptop", [0.0, -0.1]), ("human", "person", [0.2, -0.8])];
    for (name, object, offset) in expected {
        assert_eq!(feature_spec(name), keepout(name, object, offset));
    }
}

#[test]
fn features_from_the_scene_match_the_authors_values() {
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    let names = ["efficiency", "table", "coffee", "coffee_dot", "laptop", "human", "origin"];
    let specs: Vec<FeatureSpec> = names.iter().map(|&n| feature_spec(n)).collect();
    let mut from_scene = FeatureSet::from_specs(model.clone(), frame, &specs, Some(&study_scene())).unwrap();
    // The authors' circles, evaluated directly.
    let circle =
        |name: &str, x: f64, y: f64| -> Box<dyn Feature> { Box::new(Keepout::cylinder(name, Vector2::new(x, y), 0.4, 4)) };
    let mut authors = FeatureSet::new(model, frame, vec![circle("laptop", -0.7929, -0.1), circle("human", 0.0, 0.2)]).unwrap();
    let (a, b) =
        (deg([104.2, 151.6, 183.8, 101.8, 224.2, 216.9, 310.8]), deg([210.5, 118.5, 192.5, 105.4, 229.15, 245.47, 316.4]));
    let xi: Vec<f64> =
        (0..31).flat_map(|i| (0..7).map(move |j| (i, j))).map(|(i, j)| a[j] + (b[j] - a[j]) * i as f64 / 30.0).collect();
    let (mut p, mut q) = (vec![0.0; 7], vec![0.0; 2]);
    from_scene.phi(&xi, &mut p).unwrap();
    authors.phi(&xi, &mut q).unwrap();
    assert_eq!(p[4..6], q);
    assert!(p[4] > 0.0, "the path passes through the laptop circle: {p:?}");
}

#[test]
fn spec_errors_name_the_feature_and_parameter() {
    let model = Arc::new(jaco2());
    let frame = model.frame_id("j2s7s300_link_7").unwrap();
    let build = |specs: &[FeatureSpec], scene: Option<&Scene>| {
        FeatureSet::from_specs(model.clone(), frame, specs, scene).err().expect("an error").to_string()
    };
    let scene = study_scene();
    assert!(build(&[plain("table"), keepout("laptop", "laptop", [0.0, 0.0])], None).starts_with("scene is needed"));
    assert_eq!(
        build(&[plain("table"), keepout("laptop", "lamp", [0.0, 0.0])], Some(&scene)),
        "features[1].keep_out: unknown scene object 'lamp'; known: table, laptop, person"
    );
    assert!(build(&[plain("laptop")], Some(&scene)).starts_with("features[0] is keep-out feature 'laptop': it needs"));
    assert!(build(&[plain("tabel")], Some(&scene)).starts_with("features[0]: unknown feature 'tabel'"));
    assert!(build(&[keepout("table", "laptop", [0.0, 0.0])], Some(&scene)).contains("it takes: height"));
    let mut wide = keepout("laptop", "laptop", [0.0, 0.0]);
    if let FeatureParams::Keepout(k) = &mut wide.params {
        k.radius = -0.4;
    }
    assert!(build(&[wide.clone()], Some(&scene)).starts_with("features[0].radius must be"));
    if let FeatureParams::Keepout(k) = &mut wide.params {
        k.radius = 0.4;
        k.samples = 0;
    }
    assert!(build(&[wide], Some(&scene)).starts_with("features[0].samples must be"));
}
