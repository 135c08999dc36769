//! `drape garment` (build, import, list) and `drape warp` (the DQS warp of a template).

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use clap::{Args, Subcommand};
use sim::body::{BodyModel, ShapeParams};
use sim::garment::{Library, Template};
use sim::mesh::TriMesh;

use super::body::{ShapeArgs, load};
use super::{Context, pose_spec};

/// `drape garment`.
#[derive(Debug, Args)]
pub struct GarmentArgs {
    #[command(subcommand)]
    command: GarmentCommand,
}

#[derive(Debug, Subcommand)]
enum GarmentCommand {
    /// Build a built-in garment (tshirt, sweater, dress, jeans) from configs/garments/NAME.toml
    /// on the canonical body and cache it; write its template as OBJ and PNG. Deterministic.
    Build {
        /// tshirt, sweater, dress or jeans.
        name: String,
        /// About this many vertices (default: the definition's, 10000; 3000 is the CPU
        /// training variant).
        #[arg(long, value_name = "N", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=200_000))]
        resolution: Option<usize>,
        /// Output OBJ of the template (on the canonical body in its rest pose).
        #[arg(short = 'o', long, value_name = "FILE.obj")]
        output: Option<PathBuf>,
        /// Also render it on the canonical body.
        #[arg(long, value_name = "FILE.png")]
        png: Option<PathBuf>,
        /// Rebuild even when the cached template is current.
        #[arg(long)]
        force: bool,
    },
    /// Import your own garment: an OBJ (metres, Y up) placed on the canonical body (default
    /// shape, rest A-pose). It is checked (manifold, no degenerate faces, plausible size,
    /// around the body, not inside it), skinned from the body and stored under NAME.
    Import {
        /// The garment OBJ.
        obj: PathBuf,
        /// Name to use it by (`--garment NAME`).
        #[arg(long)]
        name: String,
        /// The fabric's friction against the body, from 0 to 2 (default: the simulator
        /// config's, 0.3); a built-in garment sets it in its definition's `[material]`.
        #[arg(long, value_name = "MU")]
        friction: Option<f32>,
        /// Replace an imported garment of the same name.
        #[arg(long)]
        force: bool,
    },
    /// List the garments: built-in ones (their sizes, own friction, substeps and crease
    /// contacts, and which resolutions are cached) and imported ones (own friction).
    List,
    /// Render a garment: the canonical body, the template on it and alone; then one row per
    /// sampled body and pose: the posed body, the DQS warp on it and the simulated drape;
    /// front and side views. Prints each sample's body, pose and drape figures.
    Gallery {
        /// Garment name.
        name: String,
        /// About this many vertices for a built-in garment (default 10000).
        #[arg(long, value_name = "N", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=200_000))]
        resolution: Option<usize>,
        /// Number of sampled bodies and poses.
        #[arg(long, default_value_t = 3, value_parser = crate::cli::at_least_one::<u64>)]
        samples: u64,
        /// Seed of the first sample (as for `drape garment check`).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Height of each picture in pixels.
        #[arg(long, default_value_t = 300)]
        cell_height: u32,
        /// Colour each drape by its strain (the largest `l / l0 - 1` of each vertex's edges,
        /// 0 to 10%, as `drape sim --strain-png`) and add the colour bar.
        #[arg(long)]
        strain: bool,
        /// Start each drape from its DQS warp with the body already posed (PBS-dagger, as
        /// `drape garment check --from-warp`) instead of morphing the body.
        #[arg(long)]
        from_warp: bool,
        /// Output PNG.
        #[arg(short = 'o', long, value_name = "FILE.png")]
        output: PathBuf,
    },
    /// Measure a garment as ground truth: drape it on sampled bodies and poses (or on the
    /// corner bodies of the shape range in the rest pose) and print, per drape and overall,
    /// convergence, penetration depth, p95 edge strain, how far the top opening came to rest
    /// below the DQS warp's (over 25 cm the garment slid down the body: a failed drape) and
    /// time; overall, edges through the body (ends outside, middle inside) and edges at
    /// double their rest length; also the share of edges the DQS warp stretches by more
    /// than 30% on the same bodies and poses.
    Check {
        /// Garment name.
        name: String,
        /// About this many vertices for a built-in garment (default 10000).
        #[arg(long, value_name = "N", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=200_000))]
        resolution: Option<usize>,
        /// Number of sampled bodies and poses (sample k uses pose random:SEED+k and the
        /// matching body of the default shape range).
        #[arg(long, default_value_t = 50, value_parser = crate::cli::at_least_one::<u64>, conflicts_with = "corners")]
        samples: u64,
        /// Seed of the first sample.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Instead of samples: the 2^6 corner bodies of the default shape range, rest pose.
        #[arg(long)]
        corners: bool,
        /// Only the DQS warps, no drapes (fast: checks the skinning weights).
        #[arg(long)]
        warp_only: bool,
        /// Start each drape from its DQS warp with the body already in the target shape and
        /// pose (the paper's PBS-dagger protocol, as `drape sim --warm-start` does) instead of
        /// morphing the body from the one the template was made for.
        #[arg(long, conflicts_with = "warp_only")]
        from_warp: bool,
        /// Drape the base size on every body, even for a garment graded in sizes (by default
        /// each body wears the size its measurements pick).
        #[arg(long)]
        one_size: bool,
        /// Simulator configuration TOML (default: configs/sim/default.toml).
        #[arg(long, value_name = "FILE.toml")]
        config: Option<PathBuf>,
        /// Also write every drape's report and the summary as JSON.
        #[arg(long, value_name = "FILE.json")]
        report: Option<PathBuf>,
    },
}

/// Loads a garment by name (built on first use) or, for a path ending in `.obj`, reads it
/// as an unskinned template.
pub fn template(
    ctx: &Context,
    name: &str,
    resolution: Option<usize>,
    model: &BodyModel,
) -> anyhow::Result<Template> {
    let lib = Library::new(&ctx.assets);
    let vertices = default_resolution(name, resolution);
    Ok(lib.get(name, vertices, model, &mut |msg| eprintln!("{msg}"))?)
}

/// The resolution asked for, or the built-in definition's (10k for others).
fn default_resolution(name: &str, resolution: Option<usize>) -> usize {
    resolution.unwrap_or_else(|| sim::garment::built_in(name).map_or(10_000, |d| d.vertices))
}

/// The template a command drapes or warps: the base size (`size` None), the size the
/// measurements of a body of `shape` pick (`auto`), or a named size of a graded garment;
/// with the size's name when one was asked for. Errors name the sizes there are.
pub fn sized_template(
    ctx: &Context,
    name: &str,
    resolution: Option<usize>,
    model: &BodyModel,
    size: Option<&str>,
    shape: &ShapeParams,
) -> anyhow::Result<(Template, Option<String>)> {
    let Some(wanted) = size else {
        return Ok((template(ctx, name, resolution, model)?, None));
    };
    if name.ends_with(".obj") || name == "tube" {
        anyhow::bail!("--size: {name} comes in one size only");
    }
    let mut wardrobe = Wardrobe::new(ctx, name, resolution, model, false)?;
    let sizes = wardrobe.sizes();
    if sizes.is_empty() {
        anyhow::bail!("--size: garment {name} is not graded in sizes");
    }
    let size = if wanted == "auto" {
        wardrobe.size_for(shape)?
    } else if sizes.iter().any(|s| s == wanted) {
        wanted.to_string()
    } else {
        anyhow::bail!(
            "--size {wanted}: garment {name} comes in {} (or auto)",
            sizes.join(", ")
        );
    };
    let t = wardrobe.get(&size)?.clone();
    Ok((t, Some(size)))
}

/// The sizes of a garment as a command uses them: a graded built-in garment's size chart,
/// with each size's template loaded (or graded and cached) on first use; a garment that is
/// not graded, or `one_size`, has just its template.
pub struct Wardrobe<'m> {
    library: Library,
    name: String,
    vertices: usize,
    model: &'m BodyModel,
    chart: Option<sim::garment::SizeChart>,
    base: String,
    templates: std::collections::BTreeMap<String, Template>,
}

impl<'m> Wardrobe<'m> {
    /// The wardrobe of garment `name` at `resolution` (default: the definition's).
    pub fn new(
        ctx: &Context,
        name: &str,
        resolution: Option<usize>,
        model: &'m BodyModel,
        one_size: bool,
    ) -> anyhow::Result<Self> {
        let library = Library::new(&ctx.assets);
        let vertices = default_resolution(name, resolution);
        let base = sim::garment::built_in(name).map_or_else(
            || sim::garment::def::DEFAULT_BASE_SIZE.to_string(),
            |d| d.base_size().to_string(),
        );
        let chart = if one_size {
            None
        } else {
            library.size_chart(name, model)?
        };
        Ok(Self {
            library,
            name: name.to_string(),
            vertices,
            model,
            chart,
            base,
            templates: Default::default(),
        })
    }

    /// Whether the garment comes in sizes here.
    pub fn graded(&self) -> bool {
        self.chart.is_some()
    }

    /// The base size (the garment on the canonical body).
    pub fn base(&self) -> &str {
        &self.base
    }

    /// The size names of the chart (none for a one-size garment).
    pub fn sizes(&self) -> Vec<String> {
        self.chart
            .as_ref()
            .map(|c| c.sizes.iter().map(|(n, _)| n.clone()).collect())
            .unwrap_or_default()
    }

    /// The size a body of `shape` wears (the base for a one-size garment).
    pub fn size_for(&self, shape: &ShapeParams) -> anyhow::Result<String> {
        Ok(match &self.chart {
            None => self.base.clone(),
            Some(c) => c.pick(&self.model.shape(shape)?)?.0,
        })
    }

    /// The template of a size.
    pub fn get(&mut self, size: &str) -> anyhow::Result<&Template> {
        if !self.templates.contains_key(size) {
            let t = if self.chart.is_some() {
                self.library
                    .get_size(&self.name, self.vertices, size, self.model, &mut |msg| {
                        eprintln!("{msg}")
                    })?
            } else {
                self.library
                    .get(&self.name, self.vertices, self.model, &mut |msg| {
                        eprintln!("{msg}")
                    })?
            };
            self.templates.insert(size.to_string(), t);
        }
        Ok(&self.templates[size])
    }

    /// The template of a size already loaded by [`Self::get`].
    pub fn loaded(&self, size: &str) -> &Template {
        &self.templates[size]
    }
}

/// Renders meshes over a body, front and side.
pub fn render(
    body: &[glam::Vec3],
    model: &BodyModel,
    garment: &TriMesh,
) -> anyhow::Result<Vec<u8>> {
    Ok(eval::render::render_png(
        &[
            eval::render::Layer::new(body, &model.triangles, eval::render::BODY_COLOUR),
            eval::render::Layer::new(
                &garment.vertices,
                &garment.triangles,
                eval::render::GARMENT_COLOUR,
            ),
        ],
        &eval::render::RenderOptions::default(),
    )?)
}

pub fn write_outputs(
    mesh: &TriMesh,
    header: &str,
    output: Option<&Path>,
    png: Option<(&Path, Vec<u8>)>,
) -> anyhow::Result<()> {
    let obj = mesh.to_obj(header);
    let mut files: Vec<(&Path, &[u8])> = Vec::new();
    if let Some(o) = output {
        files.push((o, obj.as_bytes()));
    }
    if let Some((p, bytes)) = &png {
        files.push((p, bytes));
    }
    sim::io::write_all_or_nothing(&files)?;
    Ok(())
}

/// Runs `drape garment`.
pub fn run(args: GarmentArgs, ctx: &Context) -> anyhow::Result<()> {
    let lib = Library::new(&ctx.assets);
    match args.command {
        GarmentCommand::List => {
            let (model, _) = load(ctx)?;
            for (name, _) in sim::garment::def::BUILT_IN {
                let def = sim::garment::built_in(name).expect("built-in");
                let dir = lib.built_path(name, 0);
                let mut sizes: Vec<usize> = std::fs::read_dir(dir.parent().expect("in a folder"))
                    .into_iter()
                    .flatten()
                    .flatten()
                    .filter_map(|e| {
                        let f = e.file_name().to_str()?.to_string();
                        f.strip_prefix(&format!("{name}-"))?
                            .strip_suffix(".safetensors")?
                            .parse()
                            .ok()
                    })
                    .collect();
                sizes.sort_unstable();
                let (current, stale): (Vec<usize>, Vec<usize>) = sizes
                    .iter()
                    .partition(|&&v| lib.is_current(name, v, &model));
                let cached: Vec<String> = current.iter().map(usize::to_string).collect();
                let stale: Vec<String> = stale.iter().map(usize::to_string).collect();
                let graded = def.grading.as_ref().map_or_else(
                    || "one size".to_string(),
                    |g| format!("{} sizes by {}", g.sizes.len() + 1, g.by.join(", ")),
                );
                let friction = def
                    .friction()
                    .map_or_else(String::new, |mu| format!(", friction {mu}"))
                    + &def
                        .below_band()
                        .map_or_else(String::new, |b| format!(" ({})", b.describe()))
                    + &def
                        .substeps()
                        .map_or_else(String::new, |n| format!(", {n} substeps"))
                    + if def.crease_contacts() {
                        ", crease contacts"
                    } else {
                        ""
                    }
                    + &def.split().map_or_else(String::new, |sp| {
                        format!(
                            ", weights of {} and {} split over {} m",
                            sp.bones[0], sp.bones[1], sp.reach
                        )
                    });
                println!(
                    "{name:8} built-in  {} [{graded}{friction}]{}",
                    def.description,
                    if cached.is_empty() {
                        String::new()
                    } else {
                        format!(" [cached: {} vertices]", cached.join(", "))
                    } + &if stale.is_empty() {
                        String::new()
                    } else {
                        format!(
                            " [out of date, rebuilt on next use: {} vertices]",
                            stale.join(", ")
                        )
                    }
                );
            }
            let users = lib.user_names();
            let model = if users.is_empty() {
                None
            } else {
                Some(load(ctx)?.0)
            };
            for name in &users {
                let model = model.as_ref().expect("loaded for imported garments");
                let friction = Template::load(
                    &lib.user_path(name),
                    model.triangles.len(),
                    model.skeleton.len(),
                )
                .ok()
                .and_then(|t| t.meta.friction)
                .map_or_else(String::new, |mu| format!(" [friction {mu}]"));
                println!(
                    "{name:8} imported  {}{friction}",
                    lib.user_path(name).display()
                );
            }
            Ok(())
        }
        GarmentCommand::Build {
            name,
            resolution,
            output,
            png,
            force,
        } => {
            let (model, _) = load(ctx)?;
            let def = sim::garment::built_in(&name).ok_or_else(|| {
                anyhow::anyhow!("no built-in garment {name:?}: tshirt, sweater, dress or jeans")
            })?;
            let vertices = resolution.unwrap_or(def.vertices);
            if !(100..=200_000).contains(&vertices) {
                anyhow::bail!("--resolution {vertices}: use 100 to 200000 vertices");
            }
            if force {
                let p = lib.built_path(&name, vertices);
                if p.exists() {
                    std::fs::remove_file(&p)
                        .with_context(|| format!("cannot remove {}", p.display()))?;
                }
            }
            let t = lib.get(&name, vertices, &model, &mut |msg| eprintln!("{msg}"))?;
            let canonical = model.shape(&ShapeParams::default())?;
            let image = match &png {
                Some(p) => Some((p.as_path(), render(&canonical.vertices, &model, &t.mesh)?)),
                None => None,
            };
            let header = format!(
                "drape garment {name} ({} vertices, {} triangles), template on the canonical body\n{}",
                t.len(),
                t.mesh.triangles.len(),
                t.meta.build
            );
            write_outputs(&t.mesh, &header, output.as_deref(), image)?;
            let b = &t.meta.build;
            println!(
                "{name}: {} vertices, {} triangles, edge {:.1} mm, min angle {:.1} deg ({:.2}% of triangles below 20 deg), relaxed in {} frames, built in {:.1} s",
                t.len(),
                t.mesh.triangles.len(),
                b["target_edge_m"].as_f64().unwrap_or(0.0) * 1e3,
                b["min_angle_deg"].as_f64().unwrap_or(0.0),
                b["share_below_20_deg"].as_f64().unwrap_or(0.0) * 100.0,
                b["relax_frames"],
                b["seconds"].as_f64().unwrap_or(0.0),
            );
            Ok(())
        }
        GarmentCommand::Check {
            name,
            resolution,
            samples,
            seed,
            corners,
            warp_only,
            from_warp,
            one_size,
            config,
            report,
        } => check(
            ctx,
            &name,
            resolution,
            samples,
            seed,
            corners,
            if warp_only {
                CheckMode::WarpOnly
            } else if from_warp {
                CheckMode::FromWarp
            } else {
                CheckMode::Morph
            },
            one_size,
            config,
            report,
        ),
        GarmentCommand::Gallery {
            name,
            resolution,
            samples,
            seed,
            cell_height,
            strain,
            from_warp,
            output,
        } => gallery(
            ctx,
            &name,
            resolution,
            Rows {
                samples,
                seed,
                cell_height,
                strain,
                from_warp,
            },
            &output,
        ),
        GarmentCommand::Import {
            obj,
            name,
            friction,
            force,
        } => {
            let (model, _) = load(ctx)?;
            let (t, path) = lib.import(&obj, &name, friction, &model, force)?;
            println!(
                "imported {} as {name}: {} vertices, {} triangles -> {}",
                obj.display(),
                t.len(),
                t.mesh.triangles.len(),
                path.display()
            );
            Ok(())
        }
    }
}

/// `drape warp`.
#[derive(Debug, Args)]
pub struct WarpArgs {
    /// Garment: tshirt, sweater, dress, jeans or an imported name.
    #[arg(long)]
    garment: String,
    /// About this many vertices for a built-in garment (default 10000).
    #[arg(long, value_name = "N", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=200_000))]
    resolution: Option<usize>,
    /// Size of a garment graded in sizes: `auto` for the size the body's measurements pick,
    /// or a size's name. Default: the base size M, the network's input.
    #[arg(long, value_name = "auto|NAME")]
    size: Option<String>,
    /// Also render the warp on the posed body with each vertex coloured by the largest
    /// stretch of its edges against the template (0 to 60%, red beyond; the trousers' bar
    /// counts edges stretched by over 30%), with a colour bar.
    #[arg(long, value_name = "FILE.png")]
    stretch_png: Option<PathBuf>,
    #[command(flatten)]
    target: BodyOutputArgs,
}

/// The scale of `drape warp --stretch-png`: 0 to 60% (the trousers' bar counts edges
/// stretched by over 30%).
const WARP_STRETCH_SCALE: super::simulate::Scale = super::simulate::Scale {
    max_percent: 60.0,
    label: "largest edge stretch of the DQS warp at each vertex (%)",
};

/// A shaped, posed body and the files a garment on it goes to (`drape warp`, `drape
/// predict`).
#[derive(Debug, Args)]
pub struct BodyOutputArgs {
    #[command(flatten)]
    pub shape: ShapeArgs,
    /// Target pose (as for `drape body --pose`).
    #[arg(long, default_value = "rest", value_name = "SPEC")]
    pub pose: String,
    /// Output OBJ of the garment.
    #[arg(short = 'o', long, value_name = "FILE.obj")]
    pub output: PathBuf,
    /// Also render it on the posed body.
    #[arg(long, value_name = "FILE.png")]
    pub png: Option<PathBuf>,
}

/// Runs `drape warp`: `M = dqs(M0, body)`.
pub fn warp(args: WarpArgs, ctx: &Context) -> anyhow::Result<()> {
    let params = args.target.shape.params()?;
    let (model, library) = load(ctx)?;
    let target = model.shape(&params)?;
    let resolved = pose_spec::resolve(&args.target.pose, &target, &library)?;
    let (t, size) = sized_template(
        ctx,
        &args.garment,
        args.resolution,
        &model,
        args.size.as_deref(),
        &params,
    )?;
    let reference = model.shape(&t.reference())?;
    let posed = target.pose(&resolved.pose);
    let warped = TriMesh::new(
        t.warp(&reference, &target, &posed),
        t.mesh.triangles.clone(),
    );
    let image = match &args.target.png {
        Some(p) => Some((p.as_path(), render(&posed.vertices, &model, &warped)?)),
        None => None,
    };
    let stretch = match &args.stretch_png {
        Some(p) => Some((
            p.as_path(),
            // The warp's stretch against the template, on the stretch scale.
            super::simulate::strain_map(
                &t.cloth(&sim::cloth::SimConfig::default())?,
                &warped,
                &WARP_STRETCH_SCALE,
                &posed.vertices,
                &model.triangles,
            )?,
        )),
        None => None,
    };
    let sized = size.map(|s| format!(", size {s}")).unwrap_or_default();
    let header = format!(
        "drape warp: garment {}{sized} (DQS), pose {}",
        args.garment, resolved.description
    );
    let obj = warped.to_obj(&header);
    let mut files: Vec<(&Path, &[u8])> = vec![(&args.target.output, obj.as_bytes())];
    for (p, bytes) in image.iter().chain(&stretch) {
        files.push((p, bytes));
    }
    sim::io::write_all_or_nothing(&files)?;
    println!(
        "{}{sized}: {} vertices warped to pose {} -> {}; {:.2}% of edges stretched by over 30%",
        args.garment,
        warped.vertices.len(),
        resolved.description,
        args.target.output.display(),
        100.0 * overstretched(&t, &warped.vertices, 0.3, &|_| true)
    );
    if let Some((p, _)) = &stretch {
        println!("stretch map -> {}", p.display());
    }
    Ok(())
}

/// Share of edges longer than `1 + limit` times their template length, among the edges
/// whose both ends pass `keep`.
fn overstretched(t: &Template, x: &[glam::Vec3], limit: f32, keep: &dyn Fn(u32) -> bool) -> f32 {
    let mut edges = t.mesh.edges();
    edges.retain(|&[a, b]| keep(a) && keep(b));
    let v = &t.mesh.vertices;
    let over = edges
        .iter()
        .filter(|&&[a, b]| {
            let l0 = v[a as usize].distance(v[b as usize]);
            x[a as usize].distance(x[b as usize]) > (1.0 + limit) * l0
        })
        .count();
    over as f32 / edges.len().max(1) as f32
}

/// Edge strains of several drapes taken together.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pooled {
    /// 95th percentile of all the drapes' edge strains.
    p95: f64,
    /// Share of all the drapes' edges stretched by more than 3%.
    over_3pct: f64,
}

/// The 95th percentile (by `strain_stats`, as each drape's own) and the share over 3% of
/// every edge strain of every drape; zeros when there are none.
fn pooled_strain(drapes: &[Vec<f32>]) -> Pooled {
    let all: Vec<f32> = drapes.iter().flatten().copied().collect();
    let over = all.iter().filter(|&&e| e > 0.03).count() as f64 / all.len().max(1) as f64;
    Pooled {
        p95: sim::cloth::drape::strain_stats(all).p95 as f64,
        over_3pct: over,
    }
}

/// Mean of the numeric `key` over the rows that have it (None if none has).
fn mean_of(rows: &[serde_json::Value], key: &str) -> Option<f64> {
    let v: Vec<f64> = rows.iter().filter_map(|r| r[key].as_f64()).collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// What `drape garment check` does on each body and pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CheckMode {
    /// The drape as datasets make it: the body morphs from the template's reference body.
    Morph,
    /// The drape from the DQS warp on the posed body (PBS-dagger).
    FromWarp,
    /// Only the DQS warp.
    WarpOnly,
}

#[allow(clippy::too_many_arguments)]
fn check(
    ctx: &Context,
    name: &str,
    resolution: Option<usize>,
    samples: u64,
    seed: u64,
    corners: bool,
    mode: CheckMode,
    one_size: bool,
    config: Option<PathBuf>,
    report: Option<PathBuf>,
) -> anyhow::Result<()> {
    use dataset::sampling::{PosePrior, ShapeRanges};
    use rayon::prelude::*;
    use sim::cloth::SimConfig;

    super::check_outputs(&[report.as_deref()])?;
    let config = match &config {
        Some(p) => SimConfig::load(p)?,
        None => SimConfig::default(),
    };
    let (model, library) = load(ctx)?;
    let mut wardrobe = Wardrobe::new(ctx, name, resolution, &model, one_size)?;
    let canonical = model.shape(&ShapeParams::default())?;
    let prior = PosePrior::new(library);
    let ranges = ShapeRanges::default();
    let rest = sim::body::Pose::rest(model.skeleton.len());
    // (label, shape, pose)
    let cases: Vec<(String, ShapeParams, sim::body::Pose)> = if corners {
        ranges
            .corners()
            .into_iter()
            .enumerate()
            .map(|(k, p)| (format!("corner {k}"), p, rest.clone()))
            .collect()
    } else {
        (0..samples)
            .map(|k| {
                let s = seed.wrapping_add(k);
                let (shape, pose) = sample(&prior, s);
                (format!("random:{s}"), shape, pose.pose)
            })
            .collect()
    };
    // Each case's size; each size's template, cloth model (rest shapes differ) and
    // reference body.
    let sizes: Vec<String> = cases
        .iter()
        .map(|(_, shape, _)| wardrobe.size_for(shape))
        .collect::<anyhow::Result<_>>()?;
    let base = wardrobe.base().to_string();
    for size in sizes.iter().chain([&base]) {
        wardrobe.get(size)?;
    }
    let mut fitted = std::collections::BTreeMap::new();
    for size in &sizes {
        if !fitted.contains_key(size.as_str()) {
            let t = wardrobe.loaded(size);
            let cloth = t.cloth(&config)?;
            fitted.insert(size.as_str(), (t, cloth, model.shape(&t.reference())?));
        }
    }
    let t = wardrobe.loaded(&base);
    // The config the drapes run with: the garment's own substeps raise the config's, its
    // own crease contacts count where the config leaves them unset.
    let stepped = t
        .cloth(&config)?
        .drape_config(&config)
        .map_err(anyhow::Error::msg)?;
    let top = t.top_opening();
    // The second part of a two-part garment (the dress's skirt), measured on its own too
    // (sizes share the base's vertices).
    let second = match sim::garment::built_in(name) {
        Some(def) if def.join.is_some() => Some(sim::garment::build::part_of(
            &def,
            &canonical,
            &t.mesh.vertices,
        )?),
        _ => None,
    };
    let friction = t.friction(&config);
    println!(
        "{name}: {} vertices, {} drapes ({}{}), {}, {}, friction {friction}{}{}, both cores across drapes",
        t.len(),
        cases.len(),
        if corners {
            "corner bodies, rest pose"
        } else {
            "sampled bodies and poses"
        },
        if mode == CheckMode::FromWarp {
            ", each from its DQS warp"
        } else {
            ""
        },
        if wardrobe.graded() {
            format!(
                "sizes {} (by measurements)",
                fitted.keys().copied().collect::<Vec<_>>().join(", ")
            )
        } else {
            "one size".to_string()
        },
        t.stepping(&config),
        if t.meta.friction.is_some() {
            " (the garment's own)"
        } else {
            ""
        },
        t.meta
            .below_band
            .map_or_else(String::new, |b| format!(", {}", b.describe()))
    );
    let bar = indicatif::ProgressBar::new(cases.len() as u64).with_style(
        indicatif::ProgressStyle::with_template(
            "{prefix} [{bar:30}] {pos}/{len} drapes, {elapsed} (eta {eta})",
        )?
        .progress_chars("=> "),
    );
    bar.set_prefix("check");
    // Without a terminal (a log file), a line a minute instead of the bar.
    let lines = learn::run::LogLines::new(true, &bar, "check", "drapes");
    let t0 = std::time::Instant::now();
    // Each row, and (but for warps only) every edge's strain in that drape.
    let rows: Vec<anyhow::Result<(serde_json::Value, Vec<f32>)>> = cases
        .par_iter()
        .zip(&sizes)
        .map(|((label, shape, pose), size)| {
            let (t, cloth, reference) = &fitted[size.as_str()];
            let target = model.shape(shape)?;
            let posed = target.pose(pose);
            let warp = t.warp(reference, &target, &posed);
            let warp_over = overstretched(t, &warp, 0.3, &|_| true);
            if mode == CheckMode::WarpOnly {
                // The warp's vertices inside the posed body (ray parity, any depth).
                let collider =
                    sim::cloth::BodyCollider::new(&posed.vertices, &model.triangles, 0.0);
                let inside = eval::metrics::interpenetration(&collider, &warp);
                bar.inc(1);
                lines.tick(&bar);
                return Ok((
                    serde_json::json!({
                        "case": label,
                        "size": size,
                        "height_m": target.height(),
                        "warp_inside": inside,
                        "warp_edges_over_30pct": warp_over,
                        "second_part_warp_edges_over_30pct": second.as_ref().map(|p| {
                            overstretched(t, &warp, 0.3, &|v| p[v as usize] == 1)
                        }),
                    }),
                    Vec::new(),
                ));
            }
            let mut d = if mode == CheckMode::FromWarp {
                sim::cloth::drape::drape_from_state(
                    cloth,
                    &warp,
                    &posed.vertices,
                    &model.triangles,
                    &config,
                    false,
                )
            } else {
                drape_from_reference(&model, cloth, t, *shape, pose, &config, false)?
            };
            d.judge_slide(&top, &warp);
            // Where the verification's edges through the body cross it: the bone that
            // weighs most on the body triangle nearest to each edge's deepest point.
            let mut by_bone = std::collections::BTreeMap::<String, usize>::new();
            for e in &d.edges_through_body {
                *by_bone.entry(through_bone(&model, e)).or_default() += 1;
            }
            bar.inc(1);
            lines.tick(&bar);
            let r = &d.report;
            let strains = sim::cloth::drape::edge_strain_values(cloth, &d.positions);
            Ok((
                serde_json::json!({
                    "case": label,
                    "size": size,
                    "height_m": target.height(),
                    "converged": r.converged,
                    "failure": r.failure.as_ref().map(|f| f.to_string()),
                    "frames": r.morph_frames + r.settle_frames,
                    "seconds": r.wall_time,
                    "strain_p95": r.strain.p95,
                    "strain_max": r.strain.max,
                    "inside_after": r.penetration.count,
                    "deepest_mm": r.penetration.max_depth * 1e3,
                    "edges_through_body": r.edges_through_body.count,
                    "edges_through_body_by_bone": by_bone,
                    "edges_through_body_deepest_mm": r.edges_through_body.max_depth * 1e3,
                    "edges_doubled": r.strain.doubled,
                    "top_drop_cm": r.top_drop.map(|x| x * 100.0),
                    // The DQS baseline's error on this drape (Edist of the warp, cm).
                    "warp_edist_cm": eval::metrics::edist_cm(&warp, &d.positions),
                    "warp_edges_over_30pct": warp_over,
                    "polish_strain_p95_before": r.polish.map(|p| p.strain_p95_before),
                    "polish_mean_move_mm": r.polish.map(|p| p.mean_move * 1e3),
                    "polish_max_move_mm": r.polish.map(|p| p.max_move * 1e3),
                    "thin_triangles": r.thin_parts.map(|t| t.triangles),
                    "thin_edge_pushes": r.thin_parts.map(|t| t.edge_pushes),
                    "stalled": r.stalled,
                }),
                strains,
            ))
        })
        .collect();
    bar.finish_and_clear();
    lines.finish(&bar);
    let (rows, strains): (Vec<serde_json::Value>, Vec<Vec<f32>>) = rows
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?
        .into_iter()
        .unzip();
    if mode == CheckMode::WarpOnly {
        let w: Vec<f64> = rows
            .iter()
            .map(|r| r["warp_edges_over_30pct"].as_f64().unwrap_or(0.0))
            .collect();
        let n = w.len().max(1) as f64;
        let inside: Vec<f64> = rows
            .iter()
            .map(|r| r["warp_inside"].as_f64().unwrap_or(0.0))
            .collect();
        let summary = serde_json::json!({
            "garment": name,
            "vertices": t.len(),
            "warps": rows.len(),
            "warp_inside_mean": inside.iter().sum::<f64>() / n,
            "warp_inside_max": inside.iter().copied().fold(0.0, f64::max),
            "warp_edges_over_30pct_mean": w.iter().sum::<f64>() / n,
            "warp_edges_over_30pct_max": w.iter().copied().fold(0.0, f64::max),
            "warps_over_1pct": w.iter().filter(|&&x| x > 0.01).count(),
            "second_part_warp_edges_over_30pct_max": rows
                .iter()
                .filter_map(|r| r["second_part_warp_edges_over_30pct"].as_f64())
                .reduce(f64::max),
        });
        println!(
            "DQS warp on {} bodies and poses: {:.3}% of edges stretched by more than 30% on average, {:.3}% at most; {} warps above 1%",
            rows.len(),
            summary["warp_edges_over_30pct_mean"]
                .as_f64()
                .unwrap_or(0.0)
                * 100.0,
            summary["warp_edges_over_30pct_max"].as_f64().unwrap_or(0.0) * 100.0,
            summary["warps_over_1pct"]
        );
        println!(
            "vertices of the warp inside the posed body: {:.2}% on average, {:.2}% at most",
            summary["warp_inside_mean"].as_f64().unwrap_or(0.0) * 100.0,
            summary["warp_inside_max"].as_f64().unwrap_or(0.0) * 100.0
        );
        if let Some(m) = summary["second_part_warp_edges_over_30pct_max"].as_f64() {
            println!(
                "second part ({}) alone: at most {:.3}% of its edges stretched by more than 30%",
                sim::garment::built_in(name)
                    .map(|d| d.parts[1].source.clone())
                    .unwrap_or_default(),
                m * 100.0
            );
        }
        if let Some(p) = report {
            let json = serde_json::to_string_pretty(
                &serde_json::json!({"summary": summary, "warps": rows}),
            )?;
            sim::io::write_all_or_nothing(&[(&p, json.as_bytes())])?;
        }
        return Ok(());
    }
    println!(
        "case          size          height  converged  frames  time    strain p95  max      deepest  top drop  warp >30%"
    );
    for r in &rows {
        println!(
            "{:12}  {:12}  {:.2} m  {:9}  {:6}  {:5.2} s  {:8.2}%  {:6.1}%  {:5.2} mm  {:5.1} cm  {:.2}%",
            r["case"].as_str().unwrap_or(""),
            r["size"].as_str().unwrap_or(""),
            r["height_m"].as_f64().unwrap_or(0.0),
            if r["converged"] == true { "yes" } else { "NO" },
            r["frames"],
            r["seconds"].as_f64().unwrap_or(0.0),
            r["strain_p95"].as_f64().unwrap_or(0.0) * 100.0,
            r["strain_max"].as_f64().unwrap_or(0.0) * 100.0,
            r["deepest_mm"].as_f64().unwrap_or(0.0),
            r["top_drop_cm"].as_f64().unwrap_or(0.0),
            r["warp_edges_over_30pct"].as_f64().unwrap_or(0.0) * 100.0,
        );
    }
    let n = rows.len().max(1) as f64;
    let f = |k: &str| {
        rows.iter()
            .map(|r| r[k].as_f64().unwrap_or(0.0))
            .collect::<Vec<f64>>()
    };
    let p95 = f("strain_p95");
    // The drapes' edges pooled: the second reading of "p95 edge strain below 3% per garment
    // on 50 bodies" (the first, and stricter, is every drape's own p95 below 3%).
    let pooled = pooled_strain(&strains);
    // Share of the drapes with a count above zero.
    let share_nonzero = |k: &str| f(k).iter().filter(|&&x| x > 0.0).count() as f64 / n;
    let converged = rows.iter().filter(|r| r["converged"] == true).count();
    let summary = serde_json::json!({
        "garment": name,
        "vertices": t.len(),
        "drapes": rows.len(),
        "start": if mode == CheckMode::FromWarp { "dqs_warp" } else { "morph" },
        "substeps": stepped.substeps,
        "settle_substeps": stepped.settle_substeps,
        "crease_contacts": stepped.crease_contacts == Some(true),
        "friction": f32_as_written(friction),
        "below_band": t.meta.below_band.map(|b| serde_json::json!({
            "width_m": f32_as_written(b.width),
            "friction": f32_as_written(b.friction),
        })),
        "converged_share": converged as f64 / n,
        "deepest_mm": f("deepest_mm").into_iter().fold(0.0, f64::max),
        "strain_p95_mean": p95.iter().sum::<f64>() / n,
        "strain_p95_max": p95.iter().copied().fold(0.0, f64::max),
        "share_p95_below_3pct": p95.iter().filter(|&&x| x < 0.03).count() as f64 / n,
        "share_p95_below_5pct": p95.iter().filter(|&&x| x < 0.05).count() as f64 / n,
        "strain_p95_pooled": pooled.p95,
        "pooled_edges_over_3pct": pooled.over_3pct,
        "slide_threshold_cm": sim::cloth::drape::MAX_TOP_DROP * 100.0,
        "warp_edist_cm_mean": f("warp_edist_cm").iter().sum::<f64>() / n,
        "top_drop_cm_max": f("top_drop_cm").into_iter().fold(f64::NEG_INFINITY, f64::max),
        "share_slid": rows
            .iter()
            .filter(|r| r["failure"].as_str().is_some_and(|f| f.starts_with("slid down")))
            .count() as f64
            / n,
        "seconds_per_drape_mean": f("seconds").iter().sum::<f64>() / n,
        "warp_edges_over_30pct_mean": f("warp_edges_over_30pct").iter().sum::<f64>() / n,
        "warp_edges_over_30pct_max": f("warp_edges_over_30pct").into_iter().fold(0.0, f64::max),
        "share_with_edges_through_body": share_nonzero("edges_through_body"),
        "edges_through_body": f("edges_through_body").iter().sum::<f64>(),
        "edges_through_body_by_bone": through_by_bone(&rows),
        "edges_through_body_deepest_mm": f("edges_through_body_deepest_mm").into_iter().fold(0.0, f64::max),
        "share_with_edges_doubled": share_nonzero("edges_doubled"),
        "edges_doubled": f("edges_doubled").iter().sum::<f64>(),
        "polished": rows.iter().filter(|r| r["polish_mean_move_mm"].is_number()).count(),
        "polish_strain_p95_before_mean": mean_of(&rows, "polish_strain_p95_before"),
        "polish_mean_move_mm": mean_of(&rows, "polish_mean_move_mm"),
        "polish_max_move_mm": f("polish_max_move_mm").into_iter().fold(0.0, f64::max),
        "thin_triangles_mean": mean_of(&rows, "thin_triangles"),
        "share_with_thin_edge_pushes": share_nonzero("thin_edge_pushes"),
        "stalled": rows.iter().filter(|r| r["stalled"] == true).count(),
        "stalled_converged": rows
            .iter()
            .filter(|r| r["stalled"] == true && r["converged"] == true)
            .count(),
        "wall_seconds": t0.elapsed().as_secs_f64(),
    });
    println!(
        "converged {:.0}%; deepest {:.2} mm; strain p95 mean {:.2}%, max {:.2}%, below 3% in {:.0}% and below 5% in {:.0}% of drapes; all drapes' edges pooled: p95 {:.2}%, {:.2}% of edges over 3%; slid down (top opening over {:.0} cm below the warp's) in {:.0}%; {:.2} s per drape (one thread each); DQS warp {:.2} cm from the drape on average (its Edist), stretches {:.2}% of edges by >30% on average (max {:.2}%); {:.0} s in all",
        summary["converged_share"].as_f64().unwrap_or(0.0) * 100.0,
        summary["deepest_mm"].as_f64().unwrap_or(0.0),
        summary["strain_p95_mean"].as_f64().unwrap_or(0.0) * 100.0,
        summary["strain_p95_max"].as_f64().unwrap_or(0.0) * 100.0,
        summary["share_p95_below_3pct"].as_f64().unwrap_or(0.0) * 100.0,
        summary["share_p95_below_5pct"].as_f64().unwrap_or(0.0) * 100.0,
        pooled.p95 * 100.0,
        pooled.over_3pct * 100.0,
        summary["slide_threshold_cm"].as_f64().unwrap_or(0.0),
        summary["share_slid"].as_f64().unwrap_or(0.0) * 100.0,
        summary["seconds_per_drape_mean"].as_f64().unwrap_or(0.0),
        summary["warp_edist_cm_mean"].as_f64().unwrap_or(0.0),
        summary["warp_edges_over_30pct_mean"]
            .as_f64()
            .unwrap_or(0.0)
            * 100.0,
        summary["warp_edges_over_30pct_max"].as_f64().unwrap_or(0.0) * 100.0,
        summary["wall_seconds"].as_f64().unwrap_or(0.0),
    );
    if let (Some(before), Some(moved)) = (
        summary["polish_strain_p95_before_mean"].as_f64(),
        summary["polish_mean_move_mm"].as_f64(),
    ) {
        println!(
            "strain polish ({} drapes): p95 mean {:.2}% before it; particles moved {:.2} mm on average, {:.2} mm at most",
            summary["polished"],
            before * 100.0,
            moved,
            summary["polish_max_move_mm"].as_f64().unwrap_or(0.0),
        );
    }
    if summary["stalled"].as_u64().unwrap_or(0) > 0 {
        println!(
            "stalled (still moving after {} settling frames, settled on with twice the stretch sweeps): {} drapes, {} of them then at rest",
            config.stall_frames, summary["stalled"], summary["stalled_converged"],
        );
    }
    if let Some(tris) = summary["thin_triangles_mean"].as_f64() {
        println!(
            "edge contacts on thin body parts: {:.0} body triangles on average; edges pushed off them in {:.0}% of drapes",
            tris,
            summary["share_with_thin_edge_pushes"]
                .as_f64()
                .unwrap_or(0.0)
                * 100.0,
        );
    }
    if mode != CheckMode::WarpOnly {
        println!(
            "edges through the body (both ends outside, 1 mm deep or more): {:.0} in {:.0}% of drapes; edges at double their rest length or more: {:.0} in {:.0}% of drapes",
            summary["edges_through_body"].as_f64().unwrap_or(0.0),
            summary["share_with_edges_through_body"]
                .as_f64()
                .unwrap_or(0.0)
                * 100.0,
            summary["edges_doubled"].as_f64().unwrap_or(0.0),
            summary["share_with_edges_doubled"].as_f64().unwrap_or(0.0) * 100.0,
        );
        if let Some(bones) = summary["edges_through_body_by_bone"].as_array()
            && !bones.is_empty()
        {
            println!(
                "  where (the body bone nearest the deepest point: edges in drapes): {}; deepest {:.1} mm",
                bones
                    .iter()
                    .map(|b| format!(
                        "{} {} in {}",
                        b["bone"].as_str().unwrap_or(""),
                        b["edges"],
                        b["drapes"]
                    ))
                    .collect::<Vec<_>>()
                    .join(", "),
                summary["edges_through_body_deepest_mm"]
                    .as_f64()
                    .unwrap_or(0.0)
            );
        }
    }
    if let Some(p) = report {
        let json =
            serde_json::to_string_pretty(&serde_json::json!({"summary": summary, "drapes": rows}))?;
        sim::io::write_all_or_nothing(&[(&p, json.as_bytes())])?;
    }
    Ok(())
}

/// Where an edge through the body crosses it: the bone that weighs most on the body
/// triangle nearest its deepest point.
pub(super) fn through_bone(model: &BodyModel, e: &sim::cloth::drape::EdgeThrough) -> String {
    e.tri.map_or("(deeper than 5 cm)".to_string(), |tri| {
        dominant_bone(model, model.triangles[tri as usize][0])
    })
}

/// The name of the bone that weighs most on body vertex `v`.
fn dominant_bone(model: &BodyModel, v: u32) -> String {
    let (bones, weights) = (model.skin.bones[v as usize], model.skin.weights[v as usize]);
    let i = (0..4)
        .max_by(|&a, &b| weights[a].total_cmp(&weights[b]))
        .unwrap_or(0);
    model.skeleton.bones[bones[i] as usize].name.clone()
}

/// Edges through the body per bone over all drapes, most first: `{bone, edges, drapes}`.
fn through_by_bone(rows: &[serde_json::Value]) -> serde_json::Value {
    let mut total = std::collections::BTreeMap::<String, (u64, u64)>::new();
    for r in rows {
        if let Some(m) = r["edges_through_body_by_bone"].as_object() {
            for (bone, n) in m {
                let e = total.entry(bone.clone()).or_default();
                e.0 += n.as_u64().unwrap_or(0);
                e.1 += 1;
            }
        }
    }
    let mut v: Vec<_> = total.into_iter().collect();
    v.sort_by(|a, b| b.1.0.cmp(&a.1.0).then(a.0.cmp(&b.0)));
    v.into_iter()
        .map(|(bone, (edges, drapes))| serde_json::json!({"bone": bone, "edges": edges, "drapes": drapes}))
        .collect()
}

/// An f32 as its shortest decimal reads (0.3, not the 0.30000001192092896 a cast to f64
/// gives), for JSON written through `serde_json::Value`.
fn f32_as_written(x: f32) -> f64 {
    x.to_string().parse().unwrap_or(f64::NAN)
}

/// Sample `k` of the checks and galleries: the body of the default shape range and the pose
/// random:SEED+k of the prior.
fn sample(
    prior: &dataset::sampling::PosePrior,
    s: u64,
) -> (ShapeParams, dataset::sampling::SampledPose) {
    use dataset::sampling::{ShapeRanges, rng, shape_seed};
    (
        ShapeRanges::default().sample(&mut rng(shape_seed(s))),
        prior.sample_seeded(s),
    )
}

/// What a gallery shows: how many sampled rows from which seed, at what size, whether
/// the drapes are coloured by strain and whether they start from the DQS warp.
struct Rows {
    samples: u64,
    seed: u64,
    cell_height: u32,
    strain: bool,
    from_warp: bool,
}

fn gallery(
    ctx: &Context,
    name: &str,
    resolution: Option<usize>,
    rows: Rows,
    output: &Path,
) -> anyhow::Result<()> {
    let Rows {
        samples,
        seed,
        cell_height,
        strain,
        from_warp,
    } = rows;
    use eval::render::{BODY_COLOUR, GARMENT_COLOUR, Layer, RenderOptions};
    use sim::cloth::SimConfig;

    let (model, library) = load(ctx)?;
    let mut wardrobe = Wardrobe::new(ctx, name, resolution, &model, false)?;
    let base = wardrobe.base().to_string();
    let t = wardrobe.get(&base)?.clone();
    let config = SimConfig::default();
    let canonical = model.shape(&ShapeParams::default())?;
    let prior = dataset::sampling::PosePrior::new(library);
    let opts = RenderOptions {
        height: cell_height,
        ..Default::default()
    };
    let picture = |body: &[glam::Vec3], x: &[glam::Vec3]| {
        eval::render::render(
            &[
                Layer::new(body, &model.triangles, BODY_COLOUR),
                Layer::new(x, &t.mesh.triangles, GARMENT_COLOUR),
            ],
            &opts,
        )
    };
    let mut images = vec![
        eval::render::render(
            &[Layer::new(
                &canonical.vertices,
                &model.triangles,
                BODY_COLOUR,
            )],
            &opts,
        )?,
        picture(&canonical.vertices, &t.mesh.vertices)?,
        eval::render::render(
            &[Layer::new(
                &t.mesh.vertices,
                &t.mesh.triangles,
                GARMENT_COLOUR,
            )],
            &opts,
        )?,
    ];
    let top = t.top_opening();
    println!(
        "row 0: the canonical body, the template on it ({} vertices), the template alone",
        t.len()
    );
    for k in 0..samples {
        let s = seed.wrapping_add(k);
        let (shape, pose) = sample(&prior, s);
        let size = wardrobe.size_for(&shape)?;
        let sized = wardrobe.get(&size)?;
        let cloth = sized.cloth(&config)?;
        let reference = model.shape(&sized.reference())?;
        let target = model.shape(&shape)?;
        let posed = target.pose(&pose.pose);
        let warp = sized.warp(&reference, &target, &posed);
        let mut d = if from_warp {
            sim::cloth::drape::drape_from_state(
                &cloth,
                &warp,
                &posed.vertices,
                &model.triangles,
                &config,
                true,
            )
        } else {
            drape_from_reference(&model, &cloth, sized, shape, &pose.pose, &config, true)?
        };
        d.judge_slide(&top, &warp);
        let r = &d.report;
        println!(
            "row {}: random:{s}, body {:.2} m (gender {:.2}, weight {:.2}), size {size}, pose {}; DQS warp, then the drape: {}, strain p95 {:.1}%, top opening {:.1} cm below the warp's, {:.1} s",
            k + 1,
            target.height(),
            shape.gender,
            shape.weight,
            pose.describe(),
            match &r.failure {
                None => "converged".to_string(),
                Some(f) => format!("FAILED ({f})"),
            },
            r.strain.p95 * 100.0,
            r.top_drop.unwrap_or(0.0) * 100.0,
            r.wall_time
        );
        images.push(eval::render::render(
            &[Layer::new(&posed.vertices, &model.triangles, BODY_COLOUR)],
            &opts,
        )?);
        images.push(picture(&posed.vertices, &warp)?);
        images.push(if strain {
            super::simulate::strain_picture(
                &cloth,
                &d.positions,
                &t.mesh.triangles,
                &posed.vertices,
                &model.triangles,
                &opts,
            )?
        } else {
            picture(&posed.vertices, &d.positions)?
        });
    }
    let mut grid = eval::render::grid(&images, 3, opts.background);
    if strain {
        let bar = super::simulate::STRAIN_SCALE.bar(grid.width.min(700));
        grid = eval::render::stack(&[grid, bar], [255, 255, 255]);
    }
    sim::io::write_all_or_nothing(&[(output, &eval::render::encode_png(&grid)?)])?;
    println!(
        "{}: {} x {} pixels -> {}",
        name,
        grid.width,
        grid.height,
        output.display()
    );
    Ok(())
}

/// Drapes a template from the body it is made for (the canonical body, or a size's
/// reference body) morphing to `shape` and `pose` (the paper's protocol); `parallel` lets
/// the drape use rayon's threads.
pub fn drape_from_reference(
    model: &BodyModel,
    cloth: &sim::cloth::ClothModel,
    t: &Template,
    shape: ShapeParams,
    pose: &sim::body::Pose,
    config: &sim::cloth::SimConfig,
    parallel: bool,
) -> anyhow::Result<sim::cloth::DrapeResult> {
    let motion =
        sim::cloth::drape::BodyMorph::new(model, t.reference(), shape, pose.clone(), config)?;
    Ok(sim::cloth::drape::drape(
        cloth,
        &t.mesh.vertices,
        &motion,
        config,
        parallel,
        &mut |_| {},
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pooled_strain_reads_all_drapes_edges_together() {
        // Two drapes of 100 edges: one unstretched, one with 8 edges at 5%. The second's own
        // p95 is 5% (8 of its 100 edges lie above its 95th place); pooled, 8 of 200 edges are
        // stretched, under 5%, so the pooled p95 is 0.
        let calm = vec![0.0f32; 100];
        let mut pulled = vec![0.0f32; 92];
        pulled.extend([0.05f32; 8]);
        let mut sorted = pulled.clone();
        sorted.sort_by(f32::total_cmp);
        assert_eq!(sorted[95], 0.05);
        let p = pooled_strain(&[calm.clone(), pulled.clone()]);
        assert_eq!(p.p95, 0.0);
        assert!((p.over_3pct - 0.04).abs() < 1e-12, "{}", p.over_3pct);
        // With 12 stretched edges in the second drape, 6% of the pool is over 3%: the
        // pooled p95 is then the stretched edges' 5%.
        let mut more = vec![0.0f32; 88];
        more.extend([0.05f32; 12]);
        let p = pooled_strain(&[calm, more]);
        assert!((p.p95 - 0.05).abs() < 1e-7, "{}", p.p95);
        assert!((p.over_3pct - 0.06).abs() < 1e-12);
        assert_eq!(
            pooled_strain(&[]),
            Pooled {
                p95: 0.0,
                over_3pct: 0.0
            }
        );
    }
}
