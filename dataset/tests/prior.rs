//! The pose prior: self-intersection below 2%, every family sampled, determinism, limits.

use std::sync::OnceLock;

use dataset::prior_check;
use dataset::sampling::{PosePrior, ShapeRanges, rng};
use sim::body::intersect::SelfIntersection;
use sim::body::pose::{LIBRARY_TOML, to_euler_xyz};
use sim::body::{BodyModel, Family, Pose, PoseLibrary};

fn setup() -> &'static (BodyModel, PoseLibrary) {
    static S: OnceLock<(BodyModel, PoseLibrary)> = OnceLock::new();
    S.get_or_init(|| {
        let m = BodyModel::load_default().unwrap();
        let lib = PoseLibrary::from_toml(&m.skeleton, LIBRARY_TOML, &m.t_pose).unwrap();
        (m, lib)
    })
}

#[test]
fn fewer_than_2_percent_of_1000_sampled_poses_self_intersect() {
    let (m, lib) = setup();
    let r = prior_check::check(m, lib, 1000, 0, || {}).unwrap();
    println!("{}", r.table());
    assert_eq!(r.samples(), 1000);
    assert!(
        r.share() < 0.02,
        "{:.2}% of sampled poses self-intersect",
        100.0 * r.share()
    );
    for f in Family::ALL {
        let (n, _) = r.per_family[&f];
        assert!(n > 200, "family {} sampled {n} times of 1000", f.name());
    }
}

#[test]
fn the_check_finds_intersections_where_there_are_some() {
    // Arms swung across the chest and legs crossed must be caught, or the 2% above means
    // nothing.
    let (m, lib) = setup();
    let test = SelfIntersection::new(m);
    let body = m.shape(&Default::default()).unwrap();
    let mut pose = Pose::rest(m.skeleton.len());
    let arm = m.skeleton.index("LeftArm").unwrap();
    pose.rotations[arm] = sim::body::pose::euler_xyz(0.0, 0.0, (-70f32).to_radians());
    let hits = test.find(&body.pose(&pose).vertices, 100);
    assert!(
        !hits.is_empty(),
        "left arm swung into the torso is not detected"
    );
    let mut legs = Pose::rest(m.skeleton.len());
    legs.rotations[m.skeleton.index("LeftUpLeg").unwrap()] =
        sim::body::pose::euler_xyz(0.0, 0.0, 0.45);
    assert!(
        test.any(&body.pose(&legs).vertices),
        "crossed legs are not detected"
    );
    // Every key pose itself is free of self-intersection on the default body.
    for (name, p) in &lib.keyposes {
        let hits = test.find(&body.pose(p).vertices, 1);
        assert!(
            hits.is_empty(),
            "key pose {name} self-intersects: {:?}",
            hits[0].segments
        );
    }
}

#[test]
fn rest_pose_is_clean_on_the_64_corner_bodies() {
    let (m, _) = setup();
    let test = SelfIntersection::new(m);
    for p in ShapeRanges::default().corners() {
        let body = m.shape(&p).unwrap();
        let hits = test.find(&body.pose(&Pose::rest(m.skeleton.len())).vertices, 1);
        assert!(
            hits.is_empty(),
            "{p:?}: {:?}",
            hits.first().map(|h| h.segments)
        );
    }
}

#[test]
fn sampling_is_deterministic_and_respects_the_limits() {
    let (_, lib) = setup();
    let prior = PosePrior::new(lib.clone());
    for seed in 0..200 {
        let a = prior.sample_seeded(seed);
        let b = prior.sample_seeded(seed);
        assert_eq!(a.pose, b.pose);
        assert_eq!(a.family, b.family);
        for (q, lim) in a.pose.rotations.iter().zip(&lib.limits) {
            match lim {
                None => assert!(q.angle_between(glam::Quat::IDENTITY) < 1e-6),
                Some(l) => {
                    let e = to_euler_xyz(*q).map(f32::to_degrees);
                    for (v, r) in e.iter().zip([l.x, l.y, l.z]) {
                        assert!(*v >= r[0] - 0.01 && *v <= r[1] + 0.01, "{v} outside {r:?}");
                    }
                }
            }
        }
    }
    assert_ne!(prior.sample_seeded(1).pose, prior.sample_seeded(2).pose);
    // Shapes from the default ranges are adults of moderate height.
    let mut r = rng(7);
    for _ in 0..100 {
        let s = ShapeRanges::default().sample(&mut r);
        assert!((0.5..=0.8).contains(&s.age) && (0.35..=0.62).contains(&s.height));
    }
}

#[test]
fn a_broken_library_is_rejected() {
    let (m, _) = setup();
    let bad = LIBRARY_TOML.replace(
        "keyposes = [\"yoga-warrior\"",
        "keyposes = [\"no-such-pose\"",
    );
    let e = PoseLibrary::from_toml(&m.skeleton, &bad, &m.t_pose)
        .unwrap_err()
        .to_string();
    assert!(e.contains("no-such-pose"), "{e}");
    let bad = LIBRARY_TOML.replace(
        "[keyposes.arms-forward]\nLeftArm = [85, 0, 0]",
        "[keyposes.arms-forward]\nLeftArm = [150, 0, 0]",
    );
    let e = PoseLibrary::from_toml(&m.skeleton, &bad, &m.t_pose)
        .unwrap_err()
        .to_string();
    assert!(e.contains("arms-forward") && e.contains("LeftArm"), "{e}");
}
