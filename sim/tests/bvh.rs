//! CMU BVH: a file written here, with the CMU hierarchy and bone names, goes through the
//! loader and poses the body as expected.

use std::fmt::Write as _;

use glam::{Quat, Vec3};
use sim::body::bvh::Motion;
use sim::body::{BodyModel, ShapeParams, ShapedBody};

/// CMU's BVH unit is about 5.6444 cm; writing the file at that scale checks that the
/// loader does not care.
const CMU_UNIT: f32 = 0.056_444;

/// BVH name of a rig bone.
fn bvh_name(rig: &str) -> &str {
    match rig {
        "LeftHandFinger1" => "LeftHandIndex1",
        "RightHandFinger1" => "RightHandIndex1",
        other => other,
    }
}

/// One frame: root position (BVH units) and `(bone, [z, y, x] degrees)` rotations.
type Frame<'a> = (Vec3, Vec<(&'a str, [f32; 3])>);

/// A BVH file whose rest pose is the rig's T-pose on `body`, with the given frames
/// (`(bone, [z, y, x] degrees)` rotations plus the root position) in CMU channel order.
fn write_bvh(body: &ShapedBody<'_>, frames: &[Frame<'_>]) -> (String, f32) {
    let m = body.model;
    let posed = body.pose(&m.t_pose);
    let head = |b: usize| body.bone_ends(&posed, b).0 / CMU_UNIT;
    let tail = |b: usize| body.bone_ends(&posed, b).1 / CMU_UNIT;
    let bones = &m.skeleton.bones;
    let mut text = String::from("HIERARCHY\n");
    fn emit(
        text: &mut String,
        b: usize,
        depth: usize,
        bones: &[sim::body::skeleton::Bone],
        head: &dyn Fn(usize) -> Vec3,
        tail: &dyn Fn(usize) -> Vec3,
    ) {
        let pad = "  ".repeat(depth);
        let offset = match bones[b].parent {
            Some(p) => head(b) - head(p),
            None => Vec3::ZERO,
        };
        let kind = if depth == 0 { "ROOT" } else { "JOINT" };
        let _ = writeln!(text, "{pad}{kind} {}\n{pad}{{", bvh_name(&bones[b].name));
        let _ = writeln!(
            text,
            "{pad}  OFFSET {:.6} {:.6} {:.6}",
            offset.x, offset.y, offset.z
        );
        if depth == 0 {
            let _ = writeln!(
                text,
                "{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation"
            );
        } else {
            let _ = writeln!(text, "{pad}  CHANNELS 3 Zrotation Yrotation Xrotation");
        }
        let children: Vec<usize> = (0..bones.len())
            .filter(|&c| bones[c].parent == Some(b))
            .collect();
        for c in &children {
            emit(text, *c, depth + 1, bones, head, tail);
        }
        if children.is_empty() {
            let e = tail(b) - head(b);
            let _ = writeln!(
                text,
                "{pad}  End Site\n{pad}  {{\n{pad}    OFFSET {:.6} {:.6} {:.6}\n{pad}  }}",
                e.x, e.y, e.z
            );
        }
        let _ = writeln!(text, "{pad}}}");
    }
    emit(&mut text, 0, 0, bones, &head, &tail);
    // File order of the joints: depth first, as written.
    let mut order = Vec::new();
    fn walk(b: usize, bones: &[sim::body::skeleton::Bone], order: &mut Vec<usize>) {
        order.push(b);
        for c in (0..bones.len()).filter(|&c| bones[c].parent == Some(b)) {
            walk(c, bones, order);
        }
    }
    walk(0, bones, &mut order);
    let _ = writeln!(
        text,
        "MOTION\nFrames: {}\nFrame Time: 0.008333",
        frames.len()
    );
    for (root, rotations) in frames {
        let mut line = format!("{:.6} {:.6} {:.6}", root.x, root.y, root.z);
        for &b in &order {
            let r = rotations
                .iter()
                .find(|(n, _)| *n == bones[b].name)
                .map_or([0.0; 3], |x| x.1);
            let _ = write!(line, " {} {} {}", r[0], r[1], r[2]);
        }
        let _ = writeln!(text, "{line}");
    }
    // Height of the hips above the lowest point of the BVH skeleton.
    let lowest = (0..bones.len())
        .map(|b| head(b).y.min(tail(b).y))
        .fold(f32::MAX, f32::min);
    (text, head(0).y - lowest)
}

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
    let probe = write_bvh(&body, &[(Vec3::ZERO, vec![])]).1;
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
    let (text, _) = write_bvh(&body, &frames);
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
    let probe = write_bvh(&body, &[(Vec3::ZERO, vec![])]).1;
    let (z, y, x) = (30.0f32, 20.0f32, 40.0f32);
    let frame = (Vec3::new(0.0, probe, 0.0), vec![("LeftArm", [z, y, x])]);
    let (text, _) = write_bvh(&body, &[frame]);
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
    let (text, h) = write_bvh(&body, &[(Vec3::ZERO, vec![])]);
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
