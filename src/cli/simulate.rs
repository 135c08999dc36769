//! `drape sim`: drape a garment on a shaped, posed body with the cloth simulator.

use std::path::{Path, PathBuf};

use anyhow::bail;
use clap::Args;
use sim::body::ShapeParams;
use sim::cloth::drape::{self, BodyMorph};
use sim::cloth::{BodyCollider, ClothModel, SimConfig};
use sim::mesh::TriMesh;

use super::body::{ShapeArgs, load};
use super::{Context, pose_spec};

/// `drape sim`.
#[derive(Debug, Args)]
pub struct SimArgs {
    /// Garment: tshirt, sweater, dress, jeans, an imported name (`drape garment import`),
    /// an OBJ on the canonical body (default shape, rest A-pose), or `tube` for the
    /// garment-like test tube around the torso (10,112 vertices).
    #[arg(long, value_name = "NAME|FILE.obj|tube")]
    garment: String,
    /// About this many vertices for a built-in garment (default 10000; 3000 for CPU
    /// training).
    #[arg(long, value_name = "N", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=200_000))]
    resolution: Option<usize>,
    #[command(flatten)]
    shape: ShapeArgs,
    /// Target pose (as for `drape body --pose`).
    #[arg(long, default_value = "rest", value_name = "SPEC")]
    pose: String,
    /// Simulator configuration TOML (default: configs/sim/default.toml); fields left out
    /// keep their defaults.
    #[arg(long, value_name = "FILE.toml")]
    config: Option<PathBuf>,
    /// Output OBJ of the draped garment.
    #[arg(short = 'o', long, value_name = "FILE.obj")]
    output: PathBuf,
    /// Also render the drape on the body (front and side) to this PNG.
    #[arg(long, value_name = "FILE.png")]
    png: Option<PathBuf>,
    /// Also render a strain map to this PNG: each vertex coloured by the largest strain
    /// `l / l0 - 1` of its edges, 0 to 10% (the colour bar's scale; more is red).
    #[arg(long, value_name = "FILE.png")]
    strain_png: Option<PathBuf>,
    /// Also write the drape report (quality, timings) as JSON.
    #[arg(long, value_name = "FILE.json")]
    report: Option<PathBuf>,
    /// Warm start (the paper's PBS-dagger protocol): start the cloth from this state (an
    /// OBJ with the template's faces, e.g. a DQS warp or an earlier drape) with the body
    /// already in its target shape and pose, instead of morphing from the canonical body.
    #[arg(long, value_name = "FILE.obj")]
    warm_start: Option<PathBuf>,
    /// Size of a garment graded in sizes: `auto` for the size the body's measurements pick
    /// (as `drape garment check` and datasets with `sizes = true` do), or a size's name (an
    /// unknown one is refused with the list). Default: the base size M on every body. The
    /// drape starts on the size's reference body, which morphs to the target.
    #[arg(long, value_name = "auto|NAME")]
    size: Option<String>,
    /// Threads for contact detection and collision (default: all cores).
    #[arg(long, value_name = "N")]
    threads: Option<usize>,
}

/// The garment mesh and its cloth (a garment brings its own friction): a garment name, an
/// OBJ file or the test tube.
pub fn garment(
    spec: &str,
    resolution: Option<usize>,
    ctx: &Context,
    canonical: &sim::body::ShapedBody<'_>,
    config: &SimConfig,
) -> anyhow::Result<(TriMesh, ClothModel)> {
    if !spec.ends_with(".obj") && spec != "tube" {
        let t = super::garment::template(ctx, spec, resolution, canonical.model)?;
        let cloth = t.cloth(config)?;
        return Ok((t.mesh, cloth));
    }
    let mesh = if spec == "tube" {
        // Numbered as an OBJ of it reads back, so that its drapes can warm-start it.
        sim::cloth::scene::torso_tube(canonical, 128, 78, 0.015).in_first_use_order()
    } else {
        let path = Path::new(spec);
        if !path.exists() {
            bail!("garment {spec:?}: no such file (give a garment name, an OBJ path, or `tube`)");
        }
        TriMesh::read_obj(path)?
    };
    let cloth = ClothModel::new(&mesh, config, &[])?;
    Ok((mesh, cloth))
}

/// Runs `drape sim`.
pub fn run(args: SimArgs, ctx: &Context) -> anyhow::Result<()> {
    let params = args.shape.params()?;
    let config = match &args.config {
        Some(p) => SimConfig::load(p)?,
        None => SimConfig::default(),
    };
    let (model, library) = load(ctx)?;
    let canonical = model.shape(&ShapeParams::default())?;
    let target = model.shape(&params)?;
    let resolved = pose_spec::resolve(&args.pose, &target, &library)?;
    // The size: the base template on the canonical body, or a size on its reference body.
    let (mesh, cloth, size, reference) = match &args.size {
        None => {
            let (mesh, cloth) = garment(&args.garment, args.resolution, ctx, &canonical, &config)?;
            (mesh, cloth, None, ShapeParams::default())
        }
        Some(wanted) => {
            let (t, size) = super::garment::sized_template(
                ctx,
                &args.garment,
                args.resolution,
                &model,
                Some(wanted),
                &params,
            )?;
            let (cloth, reference) = (t.cloth(&config)?, t.reference());
            (t.mesh, cloth, size, reference)
        }
    };
    if let Some(size) = &size {
        println!("{}: size {size}", args.garment);
    }
    let morph;
    let still;
    let (start, motion): (Vec<_>, &(dyn drape::BodyMotion + Sync)) = match &args.warm_start {
        None => {
            let start_shape = model.shape(&reference)?;
            let start_body =
                BodyCollider::new(&start_shape.vertices, &model.triangles, config.margin);
            drape::check_placement(&start_body, &mesh.vertices)?;
            morph = BodyMorph::new(&model, reference, params, resolved.pose.clone(), &config)?;
            (mesh.vertices.clone(), &morph)
        }
        Some(path) => {
            let read = TriMesh::read_obj(path)?;
            let Some(state) = mesh.positions_in_my_order(&read) else {
                bail!(
                    "warm start {}: its faces differ from the garment template's ({} and {} triangles, {} and {} vertices); it must be a state of the same mesh",
                    path.display(),
                    read.triangles.len(),
                    mesh.triangles.len(),
                    read.vertices.len(),
                    mesh.vertices.len()
                );
            };
            let posed = target.pose(&resolved.pose).vertices;
            let body = BodyCollider::new(&posed, &model.triangles, config.margin);
            drape::check_placement(&body, &state)?;
            still = drape::StaticBody {
                vertices: posed,
                triangles: model.triangles.clone(),
            };
            (state, &still)
        }
    };

    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads.unwrap_or(0))
        .build()?;
    let bar = indicatif::ProgressBar::new(motion.frames() as u64 + config.max_frames as u64)
        .with_style(
            indicatif::ProgressStyle::with_template(
                "{prefix} [{bar:30}] frame {pos} {msg} ({elapsed})",
            )?
            .progress_chars("=> "),
        );
    bar.set_prefix("drape");
    let result = pool.install(|| {
        drape::drape(&cloth, &start, motion, &config, true, &mut |p| {
            bar.set_position(p.frame as u64);
            bar.set_message(format!(
                "{}, kinetic energy {:.2e} J, largest move {:.2} mm",
                if p.morphing { "morphing" } else { "settling" },
                p.kinetic_energy,
                p.max_displacement * 1e3
            ));
        })
    });
    bar.finish_and_clear();
    let r = &result.report;

    let draped = TriMesh::new(result.positions.clone(), mesh.triangles.clone());
    let header = format!(
        "drape sim {}: garment {}{}, pose {}\n{}",
        env!("CARGO_PKG_VERSION"),
        args.garment,
        size.as_ref()
            .map(|s| format!(", size {s}"))
            .unwrap_or_default(),
        resolved.description,
        match &r.failure {
            None => "converged".to_string(),
            Some(f) => format!("FAILED: {f}"),
        }
    );
    let obj = draped.to_obj(&header);
    let posed = (args.png.is_some() || args.strain_png.is_some())
        .then(|| target.pose(&resolved.pose).vertices);
    let png = match (&args.png, &posed) {
        (Some(_), Some(body)) => Some(super::garment::render(body, &model, &draped)?),
        _ => None,
    };
    let strain_png = match (&args.strain_png, &posed) {
        (Some(_), Some(body)) => Some(strain_map(
            &cloth,
            &draped,
            &STRAIN_SCALE,
            body,
            &model.triangles,
        )?),
        _ => None,
    };
    let mut json = serde_json::to_value(r)?;
    if let Some(size) = &size {
        json["size"] = serde_json::Value::from(size.as_str());
    }
    let json = serde_json::to_string_pretty(&json)?;
    let mut files: Vec<(&Path, &[u8])> = vec![(&args.output, obj.as_bytes())];
    if let (Some(p), Some(b)) = (&args.png, &png) {
        files.push((p, b));
    }
    if let (Some(p), Some(b)) = (&args.strain_png, &strain_png) {
        files.push((p, b));
    }
    if let Some(p) = &args.report {
        files.push((p, json.as_bytes()));
    }
    sim::io::write_all_or_nothing(&files)?;
    println!(
        "{} particles, {} + {} frames ({} substeps) in {:.2} s; strain p95 {:.2}% max {:.2}%; inside the body: {} particles before the final push-out, {} after (deepest {:.2} mm)",
        r.particles,
        r.morph_frames,
        r.settle_frames,
        r.substeps,
        r.wall_time,
        r.strain.p95 * 100.0,
        r.strain.max * 100.0,
        r.penetration_before_pushout.count,
        r.penetration.count,
        r.penetration.max_depth * 1e3,
    );
    if let Some(p) = &r.polish {
        println!(
            "strain polish: {} sweeps, {} of {} particles held at the body; p95 strain {:.2}% before; particles moved {:.2} mm on average, {:.2} mm at most; {:.3} s",
            p.sweeps,
            p.held,
            r.particles,
            p.strain_p95_before * 100.0,
            p.mean_move * 1e3,
            p.max_move * 1e3,
            p.time,
        );
    }
    if !result.edges_through_body.is_empty() {
        // Where (as `drape garment check` names them), deepest first.
        let mut by_bone = std::collections::BTreeMap::<String, (usize, f32)>::new();
        for e in &result.edges_through_body {
            let entry = by_bone
                .entry(super::garment::through_bone(&model, e))
                .or_default();
            entry.0 += 1;
            entry.1 = entry.1.max(e.depth);
        }
        let mut list: Vec<_> = by_bone.into_iter().collect();
        list.sort_by(|a, b| b.1.1.total_cmp(&a.1.1));
        println!(
            "edges through the body (both ends outside, {:.0} mm deep or more), by the nearest bone: {}",
            config.max_penetration * 1e3,
            list.iter()
                .map(|(bone, (n, d))| format!("{bone} {n} ({:.1} mm)", d * 1e3))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if let Some(t) = &r.thin_parts {
        println!(
            "edge contacts on thin body parts: {} body triangles thinner than {:.0} mm; {} edge midpoints pushed out",
            t.triangles,
            config.thin_part_thickness * 1e3,
            t.edge_pushes,
        );
    }
    match &r.failure {
        None => {
            println!("converged -> {}", args.output.display());
            Ok(())
        }
        Some(f) => bail!(
            "the drape FAILED: {f} (outputs written for inspection: {})",
            args.output.display()
        ),
    }
}

/// A colour scale of a map: 0 at blue, `max_percent` and more at red, and its bar's label.
pub(crate) struct Scale {
    /// The value at the red end (percent).
    pub max_percent: f32,
    /// What the colour bar says.
    pub label: &'static str,
}

impl Scale {
    /// The scale's colour bar, `width` pixels wide.
    pub(crate) fn bar(&self, width: u32) -> eval::render::Image {
        eval::plot::colour_bar(f64::from(self.max_percent), self.label, width)
    }
}

/// The strain maps' scale: 0 to 10% edge strain.
pub(crate) const STRAIN_SCALE: Scale = Scale {
    max_percent: 10.0,
    label: "largest edge strain at each vertex (%)",
};

/// The garment `x` (faces `triangles`) on the body, front and side, each garment vertex
/// coloured by its value in `percent` on `scale` (no colour bar).
pub(crate) fn coloured_picture(
    x: &[glam::Vec3],
    triangles: &[[u32; 3]],
    percent: &[f32],
    scale: &Scale,
    body: &[glam::Vec3],
    body_triangles: &[[u32; 3]],
    opts: &eval::render::RenderOptions,
) -> anyhow::Result<eval::render::Image> {
    use eval::render::{BODY_COLOUR, GARMENT_COLOUR, Layer};
    let colours: Vec<[u8; 3]> = percent
        .iter()
        .map(|p| eval::render::error_colour(p / scale.max_percent))
        .collect();
    Ok(eval::render::render(
        &[
            Layer::new(body, body_triangles, BODY_COLOUR),
            Layer::new(x, triangles, GARMENT_COLOUR).with_vertex_colours(&colours, percent),
        ],
        opts,
    )?)
}

/// [`coloured_picture`] of `garment` with the default views and `scale`'s colour bar below,
/// as a PNG.
fn coloured_map(
    garment: &TriMesh,
    percent: &[f32],
    scale: &Scale,
    body: &[glam::Vec3],
    body_triangles: &[[u32; 3]],
) -> anyhow::Result<Vec<u8>> {
    let img = coloured_picture(
        &garment.vertices,
        &garment.triangles,
        percent,
        scale,
        body,
        body_triangles,
        &eval::render::RenderOptions::default(),
    )?;
    let bar = scale.bar(img.width.min(700));
    Ok(eval::render::encode_png(&eval::render::stack(
        &[img, bar],
        [255, 255, 255],
    ))?)
}

/// Each vertex's largest edge strain `l / l0 - 1` against `cloth`'s rest shape, in percent.
fn strain_percent(cloth: &ClothModel, x: &[glam::Vec3]) -> Vec<f32> {
    drape::vertex_strain(cloth, x)
        .iter()
        .map(|s| s * 100.0)
        .collect()
}

/// The drape `x` (faces `triangles`) on the body, front and side, each garment vertex
/// coloured by the largest strain of its edges on [`STRAIN_SCALE`] (no colour bar).
pub(crate) fn strain_picture(
    cloth: &ClothModel,
    x: &[glam::Vec3],
    triangles: &[[u32; 3]],
    body: &[glam::Vec3],
    body_triangles: &[[u32; 3]],
    opts: &eval::render::RenderOptions,
) -> anyhow::Result<eval::render::Image> {
    let percent = strain_percent(cloth, x);
    coloured_picture(
        x,
        triangles,
        &percent,
        &STRAIN_SCALE,
        body,
        body_triangles,
        opts,
    )
}

/// `garment` on the body, front and side, each vertex coloured by the largest strain of its
/// edges against `cloth`'s rest shape on `scale`, with its colour bar in percent: `drape sim
/// --strain-png` (the drape) and `drape warp --stretch-png` (the warp).
pub(crate) fn strain_map(
    cloth: &ClothModel,
    garment: &TriMesh,
    scale: &Scale,
    body: &[glam::Vec3],
    body_triangles: &[[u32; 3]],
) -> anyhow::Result<Vec<u8>> {
    let percent = strain_percent(cloth, &garment.vertices);
    coloured_map(garment, &percent, scale, body, body_triangles)
}
