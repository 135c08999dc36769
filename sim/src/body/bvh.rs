//! CMU motion capture in BVH, retargeted to the `cmu_mb` rig.
//!
//! CMU's BVH files use the rig's bone names except `LeftHandIndex1` / `RightHandIndex1`
//! for `LeftHandFinger1` / `RightHandFinger1`. Their rest pose (all channels zero) is a
//! T-pose, Y up, the character's left towards +X and face towards +Z, which are drape's
//! world axes. Retargeting puts the rig in its own T-pose and transfers per-bone world
//! rotation deltas: with `G_j` the BVH joint's world rotation at the frame and `W_T(b)` the
//! bone's world rotation in the rig's T-pose, the bone's posed world rotation is
//! `W_b = G_j * W_T(b)`, from which the local rotation follows through the parent's posed
//! frame. Bones without a BVH joint follow their parent rigidly.
//!
//! Root motion: the horizontal travel is dropped (a drape is static); the height of the
//! hips is kept, scaled by the ratio of the body's hip height to the BVH skeleton's, so a
//! crouch lowers the body.

use std::path::{Path, PathBuf};

use glam::{Quat, Vec3};

use super::pose::Pose;
use super::{BodyError, ShapedBody};

/// One channel of a BVH joint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    /// Translation along X.
    XPosition,
    /// Translation along Y.
    YPosition,
    /// Translation along Z.
    ZPosition,
    /// Rotation about X (degrees).
    XRotation,
    /// Rotation about Y (degrees).
    YRotation,
    /// Rotation about Z (degrees).
    ZRotation,
}

/// A joint of the BVH hierarchy.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    /// Joint name.
    pub name: String,
    /// Parent joint, `None` for the root.
    pub parent: Option<usize>,
    /// Offset from the parent in the rest pose (BVH units).
    pub offset: Vec3,
    /// Its channels, in file order.
    pub channels: Vec<Channel>,
    /// Offset of its `End Site`, if it has one.
    pub end_site: Option<Vec3>,
}

/// A parsed BVH file.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// The file it came from.
    pub path: PathBuf,
    /// Joints in file order (parents first).
    pub joints: Vec<Joint>,
    /// Seconds per frame.
    pub frame_time: f32,
    /// Channel values per frame, in joint and channel order.
    pub frames: Vec<Vec<f32>>,
}

/// Rig bones whose CMU BVH joint has another name.
const ALIASES: [(&str, &str); 2] = [
    ("LeftHandFinger1", "LeftHandIndex1"),
    ("RightHandFinger1", "RightHandIndex1"),
];

/// CMU's BVH length unit, about 5.6444 cm.
pub const CMU_UNIT: f32 = 0.056_444;

/// BVH name of a rig bone.
fn bvh_name(rig: &str) -> &str {
    ALIASES
        .iter()
        .find(|(r, _)| *r == rig)
        .map_or(rig, |(_, b)| b)
}

/// One frame to write: the root position (BVH units) and `(rig bone, [z, y, x] degrees)`
/// rotations; bones left out are at zero.
pub type CmuFrame<'a> = (Vec3, Vec<(&'a str, [f32; 3])>);

/// Writes a BVH file in CMU's layout (bone names, ZYX channels, CMU units) whose rest pose
/// is the rig's T-pose on `body`, with the given frames: a way to author motions for
/// `drape gen`'s BVH pose source and for tests. Also returns the height of the hips above
/// the skeleton's lowest point (BVH units), the root height of a standing frame.
pub fn write_cmu(body: &ShapedBody<'_>, frames: &[CmuFrame<'_>]) -> (String, f32) {
    use std::fmt::Write as _;
    let m = body.model;
    let posed = body.pose(&m.t_pose);
    let head = |b: usize| body.bone_ends(&posed, b).0 / CMU_UNIT;
    let tail = |b: usize| body.bone_ends(&posed, b).1 / CMU_UNIT;
    let bones = &m.skeleton.bones;
    let mut text = String::from("HIERARCHY\n");
    // Writes joint `b` and its subtree, and appends the joints to `order` as written
    // (depth first: the order of the motion lines' channels).
    fn emit(
        text: &mut String,
        order: &mut Vec<usize>,
        b: usize,
        depth: usize,
        bones: &[super::skeleton::Bone],
        head: &dyn Fn(usize) -> Vec3,
        tail: &dyn Fn(usize) -> Vec3,
    ) {
        order.push(b);
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
            emit(text, order, *c, depth + 1, bones, head, tail);
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
    let mut order = Vec::new();
    emit(&mut text, &mut order, 0, 0, bones, &head, &tail);
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

struct Tokens<'a> {
    items: Vec<(usize, &'a str)>,
    pos: usize,
    path: &'a Path,
}

impl<'a> Tokens<'a> {
    fn err(&self, reason: impl std::fmt::Display) -> BodyError {
        let line = self
            .items
            .get(self.pos.min(self.items.len().saturating_sub(1)))
            .map_or(0, |t| t.0);
        BodyError::Bvh {
            path: self.path.to_path_buf(),
            reason: format!("line {line}: {reason}"),
        }
    }
    fn next(&mut self) -> Result<&'a str, BodyError> {
        let t = self
            .items
            .get(self.pos)
            .map(|t| t.1)
            .ok_or_else(|| self.err("unexpected end of file"))?;
        self.pos += 1;
        Ok(t)
    }
    fn expect(&mut self, word: &str) -> Result<(), BodyError> {
        if self.pos >= self.items.len() {
            return Err(self.err(format!("expected {word}, found the end of the file")));
        }
        let t = self.next()?;
        if t.eq_ignore_ascii_case(word) {
            Ok(())
        } else {
            self.pos -= 1;
            Err(self.err(format!("expected {word}, found {t:?}")))
        }
    }
    fn number<T: std::str::FromStr>(&mut self) -> Result<T, BodyError> {
        let t = self.next()?;
        t.parse().map_err(|_| {
            self.pos -= 1;
            self.err(format!("expected a number, found {t:?}"))
        })
    }
    fn vec3(&mut self) -> Result<Vec3, BodyError> {
        Ok(Vec3::new(self.number()?, self.number()?, self.number()?))
    }
}

impl Motion {
    /// Reads a BVH file.
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let text = std::fs::read_to_string(path).map_err(|source| BodyError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses BVH text; `path` names the source in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, BodyError> {
        let items = text
            .lines()
            .enumerate()
            .flat_map(|(i, l)| l.split_whitespace().map(move |w| (i + 1, w)))
            .collect();
        let mut t = Tokens {
            items,
            pos: 0,
            path,
        };
        t.expect("HIERARCHY")?;
        t.expect("ROOT")?;
        let mut joints: Vec<Joint> = Vec::new();
        Self::parse_joint(&mut t, &mut joints, None)?;
        t.expect("MOTION")?;
        t.expect("Frames:")?;
        let n_frames: usize = t.number()?;
        t.expect("Frame")?;
        t.expect("Time:")?;
        let frame_time: f32 = t.number()?;
        let n_channels: usize = joints.iter().map(|j| j.channels.len()).sum();
        let remaining = t.items.len() - t.pos;
        if n_frames.checked_mul(n_channels) != Some(remaining) {
            return Err(t.err(format!(
                "{n_frames} frames of {n_channels} channels need {} values, the file has {remaining}",
                n_frames.saturating_mul(n_channels)
            )));
        }
        let mut frames = Vec::new();
        for _ in 0..n_frames {
            let mut f = Vec::new();
            for _ in 0..n_channels {
                let v: f32 = t.number()?;
                if !v.is_finite() {
                    t.pos -= 1;
                    return Err(t.err("non-finite channel value"));
                }
                f.push(v);
            }
            frames.push(f);
        }
        if t.pos != t.items.len() {
            return Err(t.err(format!(
                "{} values after the last of {n_frames} frames",
                t.items.len() - t.pos
            )));
        }
        if n_frames == 0 {
            return Err(t.err("the file has no frames"));
        }
        Ok(Self {
            path: path.to_path_buf(),
            joints,
            frame_time,
            frames,
        })
    }

    fn parse_joint(
        t: &mut Tokens<'_>,
        joints: &mut Vec<Joint>,
        parent: Option<usize>,
    ) -> Result<(), BodyError> {
        let name = t.next()?.to_string();
        t.expect("{")?;
        t.expect("OFFSET")?;
        let offset = t.vec3()?;
        t.expect("CHANNELS")?;
        let n: usize = t.number()?;
        if n > 6 {
            return Err(t.err(format!(
                "{n} channels on one joint; BVH joints have at most 6"
            )));
        }
        let mut channels = Vec::new();
        for _ in 0..n {
            let c = match t.next()?.to_ascii_lowercase().as_str() {
                "xposition" => Channel::XPosition,
                "yposition" => Channel::YPosition,
                "zposition" => Channel::ZPosition,
                "xrotation" => Channel::XRotation,
                "yrotation" => Channel::YRotation,
                "zrotation" => Channel::ZRotation,
                other => {
                    t.pos -= 1;
                    return Err(t.err(format!("unknown channel {other:?}")));
                }
            };
            channels.push(c);
        }
        let me = joints.len();
        joints.push(Joint {
            name,
            parent,
            offset,
            channels,
            end_site: None,
        });
        loop {
            let word = t.next()?;
            match word {
                w if w.eq_ignore_ascii_case("JOINT") => Self::parse_joint(t, joints, Some(me))?,
                w if w.eq_ignore_ascii_case("End") => {
                    t.expect("Site")?;
                    t.expect("{")?;
                    t.expect("OFFSET")?;
                    joints[me].end_site = Some(t.vec3()?);
                    t.expect("}")?;
                }
                "}" => return Ok(()),
                other => {
                    t.pos -= 1;
                    return Err(t.err(format!("expected JOINT, End Site or }}, found {other:?}")));
                }
            }
        }
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// True if there are no frames (never, for a parsed file).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// World rotation of every joint and the root position at a frame.
    fn world_rotations(&self, frame: usize) -> (Vec<Quat>, Vec3) {
        let values = &self.frames[frame];
        let mut k = 0;
        let mut world: Vec<Quat> = Vec::with_capacity(self.joints.len());
        let mut root = self.joints[0].offset;
        for j in &self.joints {
            let mut local = Quat::IDENTITY;
            for c in &j.channels {
                let v = values[k];
                k += 1;
                match c {
                    Channel::XPosition if j.parent.is_none() => root.x = v,
                    Channel::YPosition if j.parent.is_none() => root.y = v,
                    Channel::ZPosition if j.parent.is_none() => root.z = v,
                    Channel::XRotation => local *= Quat::from_rotation_x(v.to_radians()),
                    Channel::YRotation => local *= Quat::from_rotation_y(v.to_radians()),
                    Channel::ZRotation => local *= Quat::from_rotation_z(v.to_radians()),
                    _ => {}
                }
            }
            world.push(match j.parent {
                Some(p) => (world[p] * local).normalize(),
                None => local.normalize(),
            });
        }
        (world, root)
    }

    /// Height of the root above the lowest joint or end site in the rest pose.
    fn rest_root_height(&self) -> f32 {
        let mut pos: Vec<Vec3> = Vec::with_capacity(self.joints.len());
        let mut lowest = 0.0f32;
        for j in &self.joints {
            let p = j.parent.map_or(Vec3::ZERO, |p| pos[p] + j.offset);
            lowest = lowest.min(p.y);
            if let Some(e) = j.end_site {
                lowest = lowest.min(p.y + e.y);
            }
            pos.push(p);
        }
        -lowest
    }

    /// The pose of the rig at a frame, for this shaped body.
    pub fn retarget(&self, body: &ShapedBody<'_>, frame: usize) -> Result<Pose, BodyError> {
        if frame >= self.frames.len() {
            return Err(BodyError::Bvh {
                path: self.path.clone(),
                reason: format!(
                    "frame {frame} asked for, the file has {} (0 to {})",
                    self.len(),
                    self.len() - 1
                ),
            });
        }
        let skeleton = &body.model.skeleton;
        let by_name = |name: &str| self.joints.iter().position(|j| j.name == name);
        let joint_of: Vec<Option<usize>> = skeleton
            .bones
            .iter()
            .map(|b| {
                let alias = ALIASES
                    .iter()
                    .find(|(rig, _)| *rig == b.name)
                    .map(|(_, bvh)| *bvh);
                by_name(&b.name).or_else(|| alias.and_then(by_name))
            })
            .collect();
        if joint_of[0].is_none() {
            return Err(BodyError::Bvh {
                path: self.path.clone(),
                reason: format!(
                    "no joint named {} (the root of the cmu_mb rig)",
                    skeleton.bones[0].name
                ),
            });
        }
        let matched = joint_of.iter().filter(|j| j.is_some()).count();
        if matched < skeleton.len() / 2 {
            return Err(BodyError::Bvh {
                path: self.path.clone(),
                reason: format!(
                    "only {matched} of {} rig bones found: not a CMU-style skeleton",
                    skeleton.len()
                ),
            });
        }
        let rest = &body.rest_frames;
        let t_frames = skeleton.posed_frames(rest, &body.model.t_pose);
        let (g, root_pos) = self.world_rotations(frame);
        // Posed world rotation of each bone, then its local rotation from
        // W_b = W_parent * R_parent^-1 * R_b * L_b (rotation parts of the FK formula).
        let mut world: Vec<Quat> = Vec::with_capacity(skeleton.len());
        let mut pose = Pose::rest(skeleton.len());
        for (i, b) in skeleton.bones.iter().enumerate() {
            let w = match (joint_of[i], b.parent) {
                (Some(j), _) => g[j] * t_frames[i].rot,
                (None, Some(p)) => world[p] * t_frames[p].rot.conjugate() * t_frames[i].rot,
                (None, None) => t_frames[i].rot,
            };
            let before = match b.parent {
                Some(p) => world[p] * rest[p].rot.conjugate() * rest[i].rot,
                None => rest[i].rot,
            };
            pose.rotations[i] = (before.conjugate() * w).normalize();
            world.push(w);
        }
        // Hip height above the lowest joint point, in the BVH's rest pose and in the rig's
        // T-pose: their ratio scales the BVH's root height to this body.
        let t_skin = skeleton.skinning_transforms(rest, &t_frames);
        let lowest = skeleton
            .bones
            .iter()
            .zip(&t_skin)
            .flat_map(|(b, s)| {
                [
                    s.apply(body.joints[b.head]).y,
                    s.apply(body.joints[b.tail]).y,
                ]
            })
            .fold(f32::MAX, f32::min);
        let h_rig = t_skin[0].apply(body.joints[skeleton.bones[0].head]).y - lowest;
        let h_bvh = self.rest_root_height();
        if h_bvh > 0.0 {
            pose.root_translation = Vec3::new(0.0, root_pos.y * h_rig / h_bvh - h_rig, 0.0);
        }
        Ok(pose)
    }
}
