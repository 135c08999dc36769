//! Building a garment template from its definition, deterministically:
//!
//! 1. each part: the helper mesh (quads split along the shorter diagonal), one step of Loop
//!    subdivision (a smooth surface to cut and remesh), the cuts in order, the largest piece
//!    kept, then ease: every vertex moved out along its normal;
//! 2. two parts: stitched along the join plane (their openings there zipped together);
//! 3. isotropic remeshing to the edge length that gives the requested vertex count;
//! 4. clearance: vertices closer to the canonical body than `clearance` moved out;
//! 5. relaxation: the simulator drapes it on the canonical body in its rest pose until it is
//!    at rest ([`RELAX_SUBSTEPS`] substeps per frame); those positions are the template.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

use glam::Vec3;

use super::GarmentError;
use super::cut::{self, Plane};
use super::def::{Direction, GarmentDef, PlaneDef};
use crate::body::ShapedBody;
use crate::cloth::collision::BodyCollider;
use crate::cloth::drape::{self, StaticBody};
use crate::cloth::{ClothModel, SimConfig};
use crate::mesh::{TriMesh, remesh};

/// Substeps per frame of the relaxation, at least. One constraint sweep per substep leaves a
/// hanging garment stretched by about `g h^2 N^2` (N edges below its support): at 10
/// substeps the jeans (about 100 edges from waist to hem) stretch over the hips and fall to
/// the feet; at 30 they hang from the hips.
pub const RELAX_SUBSTEPS: u32 = 30;

/// Velocity damping of the relaxation, at least (1/s). Only the rest state of the relaxation
/// matters, and from about 30 substeps a frame particles in or near contact keep jittering
/// by 0.5 to 1 mm a frame under the default damping (2/s): friction's stick and slip at
/// tiny substeps (the 3k dress and sweater never met the rest test; with 6/s they rest
/// within 200 frames). See `docs/solver.md`.
pub const RELAX_DAMPING: f32 = 6.0;

/// Settling frames of the relaxation, at most: a garment that creeps slowly on the body
/// (the sweater's sleeves) may need more than a drape's 600.
pub const RELAX_MAX_FRAMES: u32 = 1_500;

/// A helper mesh as read from the helpers OBJ: positions and quads.
#[derive(Debug, Clone, PartialEq)]
pub struct Helper {
    /// Positions on the canonical body (m).
    pub vertices: Vec<Vec3>,
    /// Quads.
    pub quads: Vec<[u32; 4]>,
}

/// Reads the helpers OBJ written by `drape body import`: `v` lines, `g` groups, quads with
/// global indices.
pub fn read_helpers(path: &Path) -> Result<BTreeMap<String, Helper>, GarmentError> {
    let text = std::fs::read_to_string(path).map_err(|source| GarmentError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |line: usize, what: &str| GarmentError::Source {
        path: path.to_path_buf(),
        reason: format!("line {line}: {what}"),
    };
    let mut all: Vec<Vec3> = Vec::new();
    let mut groups: BTreeMap<String, Vec<[u32; 4]>> = BTreeMap::new();
    let mut group = String::new();
    for (n, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f32> = it.filter_map(|s| s.parse().ok()).collect();
                if c.len() != 3 || c.iter().any(|x| !x.is_finite()) {
                    return Err(bad(n + 1, "bad vertex"));
                }
                all.push(Vec3::new(c[0], c[1], c[2]));
            }
            Some("g") => group = it.next().unwrap_or_default().to_string(),
            Some("f") => {
                let idx: Vec<u32> = it
                    .filter_map(|s| s.parse::<u32>().ok()?.checked_sub(1))
                    .collect();
                if idx.len() != 4 || idx.iter().any(|&i| i as usize >= all.len()) {
                    return Err(bad(n + 1, "faces must be quads of earlier vertices"));
                }
                groups
                    .entry(group.clone())
                    .or_default()
                    .push([idx[0], idx[1], idx[2], idx[3]]);
            }
            _ => {}
        }
    }
    Ok(groups
        .into_iter()
        .map(|(name, quads)| {
            // Renumber the group's vertices from zero in first-use order.
            let mut map: BTreeMap<u32, u32> = BTreeMap::new();
            let mut vertices = Vec::new();
            let quads = quads
                .iter()
                .map(|q| {
                    q.map(|i| {
                        *map.entry(i).or_insert_with(|| {
                            vertices.push(all[i as usize]);
                            vertices.len() as u32 - 1
                        })
                    })
                })
                .collect();
            (name, Helper { vertices, quads })
        })
        .collect())
}

/// A plane on the canonical body.
pub fn place(def: &PlaneDef, body: &ShapedBody<'_>) -> Result<Plane, GarmentError> {
    let (head, tail) = bone_ends(&def.bone, body)?;
    let normal = match def.normal {
        Direction::Bone => (tail - head).normalize(),
        Direction::Up => Vec3::Y,
        Direction::Down => -Vec3::Y,
    };
    Ok(Plane {
        point: head + (tail - head) * def.at + normal * def.offset,
        normal,
    })
}

fn bone_ends(name: &str, body: &ShapedBody<'_>) -> Result<(Vec3, Vec3), GarmentError> {
    body.rest_bone_ends(name)
        .map_err(|_| GarmentError::Definition(format!("no bone named {name}")))
}

/// Moves every vertex out along its area-weighted normal by `ease`.
fn add_ease(mesh: &mut TriMesh, ease: f32) {
    if ease == 0.0 {
        return;
    }
    let n = mesh.vertex_normals();
    for (p, n) in mesh.vertices.iter_mut().zip(n) {
        *p += n * ease;
    }
}

/// Moves every vertex horizontally away from the vertical axis through `centre` by `flare`
/// times its depth below the mesh's highest vertex.
fn add_flare(mesh: &mut TriMesh, flare: f32, centre: Vec3) {
    let top = mesh.vertices.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    for p in &mut mesh.vertices {
        let out = Vec3::new(p.x - centre.x, 0.0, p.z - centre.z).normalize_or_zero();
        *p += out * (flare * (top - p.y));
    }
}

/// One part, cut and eased (steps 1 of the module docs).
fn part(
    def: &super::def::PartDef,
    helpers: &BTreeMap<String, Helper>,
    body: &ShapedBody<'_>,
) -> Result<TriMesh, GarmentError> {
    let h = helpers.get(&def.source).ok_or_else(|| {
        GarmentError::Definition(format!(
            "no helper mesh {} (have: {})",
            def.source,
            helpers.keys().cloned().collect::<Vec<_>>().join(", ")
        ))
    })?;
    let coarse = TriMesh::new(
        h.vertices.clone(),
        remesh::triangulate_quads(&h.vertices, &h.quads),
    );
    let mut mesh = remesh::loop_subdivide(&coarse);
    for c in &def.cuts {
        let plane = place(&c.plane(), body)?;
        let (seed, _) = bone_ends(&c.seed, body)?;
        let within = match c.radius {
            None => None,
            Some(r) => {
                let (head, tail) = bone_ends(&c.bone, body)?;
                Some((head, (tail - head).normalize(), r))
            }
        };
        mesh = cut::cut(&mesh, cut::Region { plane, within }, seed);
    }
    let mut mesh = cut::largest_piece(&mesh);
    add_ease(&mut mesh, def.ease);
    if def.flare != 0.0 {
        let (centre, _) = bone_ends("Hips", body)?;
        add_flare(&mut mesh, def.flare, centre);
    }
    Ok(mesh)
}

/// Which part each vertex belongs to: with a join, part 1 lies beyond its plane.
pub fn part_of(
    def: &GarmentDef,
    body: &ShapedBody<'_>,
    x: &[Vec3],
) -> Result<Vec<u8>, GarmentError> {
    Ok(match &def.join {
        None => vec![0; x.len()],
        Some(j) => {
            let plane = place(j, body)?;
            x.iter()
                .map(|&p| u8::from(plane.distance(p) > 0.0))
                .collect()
        }
    })
}

/// A built template's geometry and how it was made.
#[derive(Debug, Clone)]
pub struct Built {
    /// The relaxed template on the canonical body (its rest shape).
    pub mesh: TriMesh,
    /// Target edge length of the remeshing (m).
    pub edge: f32,
    /// Minimum-angle statistics of the remeshed triangles.
    pub angles: remesh::AngleStats,
    /// Frames the relaxation took, and whether it came to rest.
    pub relax_frames: u32,
    /// Whether the relaxation converged.
    pub relaxed: bool,
    /// p95 edge strain of the relaxed template against the remeshed shape.
    pub relax_strain_p95: f32,
    /// Wall time of the whole build (s).
    pub seconds: f64,
}

/// Builds the garment at about `vertices` vertices (steps 1 to 5 of the module docs).
pub fn build(
    def: &GarmentDef,
    helpers: &BTreeMap<String, Helper>,
    body: &ShapedBody<'_>,
    config: &SimConfig,
    vertices: usize,
    relax: bool,
) -> Result<Built, GarmentError> {
    let t0 = Instant::now();
    let mut parts = def
        .parts
        .iter()
        .map(|p| part(p, helpers, body))
        .collect::<Result<Vec<_>, _>>()?;
    let joined = if let Some(j) = &def.join {
        let plane = place(j, body)?;
        let bottom = parts.pop().expect("two parts");
        let top = parts.pop().expect("two parts");
        let on_plane = |m: &TriMesh| -> Result<Vec<u32>, GarmentError> {
            cut::directed_boundary_loops(m)
                .into_iter()
                .min_by(|a, b| {
                    let off = |l: &Vec<u32>| {
                        l.iter()
                            .map(|&i| plane.distance(m.vertices[i as usize]).abs())
                            .sum::<f32>()
                            / l.len() as f32
                    };
                    off(a).total_cmp(&off(b))
                })
                .ok_or_else(|| GarmentError::Definition("a part has no opening to join".into()))
        };
        let (la, lb) = (on_plane(&top)?, on_plane(&bottom)?);
        cut::bridge(&top, &la, &bottom, &lb)
    } else {
        parts.pop().expect("one part")
    };

    let edge = remesh::target_edge_for_vertices(remesh::area(&joined), vertices);
    let mut mesh = remesh::remesh(
        &joined,
        &remesh::RemeshOptions {
            target_edge: edge,
            ..Default::default()
        },
    )?;
    let angles = remesh::angle_stats(&mesh);

    let relaxed = settle(
        &mut mesh,
        body,
        def.clearance,
        config,
        relax,
        false,
        &def.name,
    )?;
    Ok(Built {
        mesh,
        edge,
        angles,
        relax_frames: relaxed.frames,
        relaxed: relaxed.converged,
        relax_strain_p95: relaxed.strain_p95,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// How deep inside the body a vertex may start and still be moved out by [`settle`] (m).
pub const DEEP_REACH: f32 = 0.1;

/// What [`settle`]'s relaxation did.
#[derive(Debug, Clone, Copy)]
pub struct Relaxed {
    /// Frames it took (0 when not relaxed).
    pub frames: u32,
    /// Whether it came to rest.
    pub converged: bool,
    /// p95 edge strain of the result against the mesh it started from.
    pub strain_p95: f32,
}

/// Steps 4 and 5 of the module docs on a mesh placed around `body` (rest pose): vertices
/// closer than `clearance` to the body moved out to it, then (if `relax`) the simulator lets
/// it come to rest there under gravity, with the mesh as given as its rest shape. A
/// relaxation that reaches its frame cap is an error unless `allow_unrested`.
pub fn settle(
    mesh: &mut TriMesh,
    body: &ShapedBody<'_>,
    clearance: f32,
    config: &SimConfig,
    relax: bool,
    allow_unrested: bool,
    name: &str,
) -> Result<Relaxed, GarmentError> {
    // Clearance from the body.
    let collider = BodyCollider::new(&body.vertices, &body.model.triangles, config.margin);
    for p in &mut mesh.vertices {
        if let Some(hit) = collider.closest(*p, clearance) {
            if hit.distance < clearance {
                *p = hit.point + hit.normal * clearance;
            }
        } else if collider.inside(*p) {
            // Deeper inside (a size graded to a heavier body): out along the closest point.
            if let Some(hit) = collider.closest(*p, DEEP_REACH) {
                *p = hit.point + hit.normal * clearance;
                continue;
            }
            return Err(GarmentError::Definition(format!(
                "{}: a vertex lies deep inside the body at {p}; more ease is needed",
                name
            )));
        }
    }

    if !relax {
        return Ok(Relaxed {
            frames: 0,
            converged: false,
            strain_p95: 0.0,
        });
    }
    // Relaxation on the body in its rest pose.
    let still = StaticBody {
        vertices: body.vertices.clone(),
        triangles: body.model.triangles.clone(),
    };
    let relax_substeps = config.substeps.max(RELAX_SUBSTEPS);
    let relax_config = SimConfig {
        substeps: relax_substeps,
        // The body stands still: the whole relaxation runs at the settling's substeps.
        settle_substeps: relax_substeps,
        // The push-out the templates were relaxed with (an inelastic one left the 10k jeans
        // jittering at 0.5 to 0.6 mm a frame: `SimConfig::elastic_pushout`).
        elastic_pushout: true,
        shear_bend_substeps: None,
        // The templates were relaxed with one stretch sweep per substep; their 30 substeps
        // already remove the sag.
        stretch_iterations: 1,
        // Templates are relaxed as before the strain polish (session 24).
        polish_sweeps: 0,
        // And without edge contacts on thin parts (session 25).
        thin_part_thickness: 0.0,
        // And with the nearest surface as each particle's only contact (session 45).
        crease_contacts: Some(false),
        max_frames: config.max_frames.max(RELAX_MAX_FRAMES),
        damping: config.damping.max(RELAX_DAMPING),
        ..config.clone()
    };
    let model = ClothModel::new(mesh, &relax_config, &[])?;
    let d = drape::drape(
        &model,
        &mesh.vertices,
        &still,
        &relax_config,
        true,
        &mut |_| {},
    );
    // A graded size whose relaxation ends just above the rest threshold keeps its positions
    // (`converged` false in its metadata); a built template must come to rest.
    let unrested = matches!(d.report.failure, Some(drape::Failure::NoConvergence { .. }));
    if let Some(f) = d
        .report
        .failure
        .as_ref()
        .filter(|_| !(unrested && allow_unrested))
    {
        return Err(GarmentError::Definition(format!(
            "{}: relaxing the template on the body failed: {f}",
            name
        )));
    }
    let strain = drape::strain(&model, &d.positions);
    mesh.vertices = d.positions;
    Ok(Relaxed {
        frames: d.report.settle_frames,
        converged: d.report.converged,
        strain_p95: strain.p95,
    })
}
