//! CMU BVH: a file written here, with the CMU hierarchy and bone names, goes through the
//! loader and poses the body as expected.

use glam::{Quat, Vec3};
use sim::body::bvh::{CMU_UNIT, Motion, write_cmu};
use sim::body::{BodyModel, ShapeParams, ShapedBody};

fn bone_dir(body: &ShapedBody<'_>, posed: &sim::body::PosedBody, name: &str) -> Vec3 {
    let (h, t) = body.bone_ends(posed, body.model.skeleton.index(name).unwrap());
    (t - h).normalize()
}

#[test]
fn bvh_written_here_poses_the_body_as_expected() {
    let model = BodyModel::load_default().unwrap();
    let body = model
        .shape(&ShapeParams {
            gender: 0.7,
            height: 0.6,
            ..Default::default()
        })
        .unwrap();
    let probe = write_cmu(&body, &[(Vec3::ZERO, vec![])]).1;
    let frames = vec![
        // 0: the BVH rest pose, standing.
        (Vec3::new(0.0, probe, 0.0), vec![]),
        // 1: left forearm turned to point forward (world rotation of -90 degrees about y).
        (
            Vec3::new(0.0, probe, 0.0),
            vec![("LeftForeArm", [0.0, -90.0, 0.0])],
        ),
        // 2: the whole body turned a quarter left and the hips 10% lower.
        (
            Vec3::new(3.0, probe * 0.9, -7.0),
            vec![("Hips", [0.0, 90.0, 0.0])],
        ),
    ];
    let (text, _) = write_cmu(&body, &frames);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("test.bvh");
    std::fs::write(&path, &text).unwrap();
    let motion = Motion::load(&path).unwrap();
    assert_eq!(motion.len(), 3);
    assert_eq!(motion.joints.len(), 31);

    // Frame 0 is the rig's T-pose.
    let t_pose = body.pose(&model.t_pose);
    let p0 = motion.retarget(&body, 0).unwrap();
    let b0 = body.pose(&p0);
    let worst = b0
        .vertices
        .iter()
        .zip(&t_pose.vertices)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f32::max);
    assert!(worst < 1e-3, "frame 0 is {worst} m from the T-pose");

    // Frame 1: the left forearm points forward, the upper arm has not moved.
    let b1 = body.pose(&motion.retarget(&body, 1).unwrap());
    // The rig's T-pose forearm points 5.7 degrees forward of +x; BVH's rotation turns that.
    let fore = bone_dir(&body, &b1, "LeftForeArm");
    let expected = Quat::from_rotation_y(-std::f32::consts::FRAC_PI_2)
        * bone_dir(&body, &t_pose, "LeftForeArm");
    assert!(
        fore.angle_between(expected).to_degrees() < 0.5,
        "forearm points {fore}, expected {expected}"
    );
    assert!(fore.angle_between(Vec3::Z).to_degrees() < 10.0);
    let upper = bone_dir(&body, &b1, "LeftArm");
    assert!(
        upper
            .angle_between(bone_dir(&body, &t_pose, "LeftArm"))
            .to_degrees()
            < 0.1
    );
    // The hand's joint has no rotation of its own: it turns with the forearm.
    let hand = bone_dir(&body, &b1, "LeftHand");
    let expected =
        Quat::from_rotation_y(-std::f32::consts::FRAC_PI_2) * bone_dir(&body, &t_pose, "LeftHand");
    assert!(
        hand.angle_between(expected).to_degrees() < 0.5,
        "the hand points {hand}, expected {expected}"
    );

    // Frame 2: a quarter turn about the hips, hips 10% lower, no horizontal travel.
    let p2 = motion.retarget(&body, 2).unwrap();
    let b2 = body.pose(&p2);
    let hips = body.joints[model.skeleton.bones[0].head];
    // The hips' height in the BVH, in metres, is the rig's T-pose hip height: 10% of it.
    let drop = 0.1 * probe * CMU_UNIT;
    let expected = Vec3::new(0.0, -drop, 0.0);
    assert!(
        (p2.root_translation - expected).length() < 1e-4,
        "{}",
        p2.root_translation
    );
    let turn = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
    let worst = b2
        .vertices
        .iter()
        .zip(&t_pose.vertices)
        .map(|(v, t)| v.distance(turn * (*t - hips) + hips - Vec3::new(0.0, drop, 0.0)))
        .fold(0.0, f32::max);
    assert!(worst < 3e-3, "turned body is off by {worst} m");
}

#[test]
fn channel_order_follows_the_file() {
    // Rotations on all three axes of one joint: the file says Z, Y, X, so the joint's
    // rotation is Rz * Ry * Rx, which nalgebra's from_euler_angles(x, y, z) gives
    // independently of drape's code.
    let model = BodyModel::load_default().unwrap();
    let body = model.shape(&ShapeParams::default()).unwrap();
    let probe = write_cmu(&body, &[(Vec3::ZERO, vec![])]).1;
    let (z, y, x) = (30.0f32, 20.0f32, 40.0f32);
    let frame = (Vec3::new(0.0, probe, 0.0), vec![("LeftArm", [z, y, x])]);
    let (text, _) = write_cmu(&body, &[frame]);
    let motion = Motion::parse(&text, "order.bvh".as_ref()).unwrap();
    let posed = body.pose(&motion.retarget(&body, 0).unwrap());
    let t_pose = body.pose(&model.t_pose);
    let reference =
        nalgebra::UnitQuaternion::from_euler_angles(x.to_radians(), y.to_radians(), z.to_radians());
    for bone in ["LeftArm", "LeftForeArm", "LeftHand"] {
        let d0 = bone_dir(&body, &t_pose, bone);
        let r = reference * nalgebra::Vector3::new(d0.x, d0.y, d0.z);
        let got = bone_dir(&body, &posed, bone);
        let angle = got.angle_between(Vec3::new(r.x, r.y, r.z)).to_degrees();
        assert!(angle < 0.3, "{bone} is {angle:.2} degrees off");
    }
    // The other side did not move.
    let moved = bone_dir(&body, &posed, "RightForeArm").angle_between(bone_dir(
        &body,
        &t_pose,
        "RightForeArm",
    ));
    assert!(moved.to_degrees() < 0.01);
}

#[test]
fn absurd_counts_are_errors_not_crashes() {
    let path = std::path::Path::new("huge.bvh");
    let head = "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n";
    let frames = format!(
        "{head} CHANNELS 3 Xposition Yposition Zposition\n}}\nMOTION\nFrames: 1000000000000\nFrame Time: 0.1\n1 2 3\n"
    );
    let e = Motion::parse(&frames, path).unwrap_err().to_string();
    assert!(e.contains("the file has 3"), "{e}");
    let channels = format!("{head} CHANNELS 99999999999 Xposition\n}}\n");
    let e = Motion::parse(&channels, path).unwrap_err().to_string();
    assert!(e.contains("at most 6"), "{e}");
}

#[test]
fn malformed_bvh_files_are_rejected_with_a_line_number() {
    let path = std::path::Path::new("bad.bvh");
    let cases = [
        ("", "expected HIERARCHY"),
        ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 zero\n", "line 4"),
        (
            "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 1 Wrotation\n}\n",
            "line 5: unknown channel",
        ),
        (
            "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n1 2 3\n4 5\n",
            "need 6 values, the file has 5",
        ),
    ];
    for (text, expect) in cases {
        let e = Motion::parse(text, path).unwrap_err().to_string();
        assert!(
            e.contains("bad.bvh") && e.contains(expect),
            "{e:?} should mention {expect:?}"
        );
    }
}

#[test]
fn frame_out_of_range_and_foreign_skeletons_are_rejected() {
    let model = BodyModel::load_default().unwrap();
    let body = model.shape(&ShapeParams::default()).unwrap();
    let (text, h) = write_cmu(&body, &[(Vec3::ZERO, vec![])]);
    let motion = Motion::parse(
        &text.replace("0.000000 0.000000 0.000000 0", &format!("0 {h} 0 0")),
        "x.bvh".as_ref(),
    )
    .unwrap();
    let e = motion.retarget(&body, 5).unwrap_err().to_string();
    assert!(e.contains("frame 5") && e.contains("has 1"), "{e}");
    let foreign = "HIERARCHY\nROOT pelvis\n{\n OFFSET 0 0 0\n CHANNELS 3 Zrotation Yrotation Xrotation\n End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n0 0 0\n";
    let e = Motion::parse(foreign, "f.bvh".as_ref())
        .unwrap()
        .retarget(&body, 0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("Hips"), "{e}");
}
