//! `drape quickstart`: the T-shirt draped on one body by the simulator and by the committed
//! GarNet-Local weights, side by side, with both times, the speed-up, Edist and Enorm.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use dataset::config::{DatasetConfig, Split};
use dataset::plan::{Poser, SamplePlan};
use learn::predict::Predictor;
use serde::{Deserialize, Serialize};
use sim::body::ShapeParams;
use sim::cloth::drape::{self, BodyMorph};
use sim::mesh::TriMesh;

use super::Context;

/// `drape quickstart`.
#[derive(Debug, Args)]
pub struct QuickstartArgs {
    /// Output folder: body.obj, simulator.obj, network.obj, dqs.obj, quickstart.png.
    #[arg(short, long, default_value = "quickstart", value_name = "DIR")]
    output: PathBuf,
    /// Seed of the body's shape and pose, drawn from the training data's shape ranges and
    /// pose prior (seeds of their own, not those of any dataset sample).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Run folder of the network (default: the committed weights in
    /// assets/quickstart/tshirt-local). Bodies, poses and the simulator come from the
    /// dataset config it was trained on: its data folder's, or the built-in config of
    /// that name when the folder is not here.
    #[arg(long = "model", value_name = "RUN_DIR")]
    run: Option<PathBuf>,
    /// Instead: redrape the first 10 test samples of the network's dataset config with
    /// the simulator, predict them, and write their Edist to this JSON file (how
    /// assets/quickstart/tshirt-local/reference.json is made; a test compares the two).
    #[arg(long, value_name = "FILE.json")]
    reference: Option<PathBuf>,
}

/// The committed quick-start run folder.
pub fn default_run(ctx: &Context) -> PathBuf {
    ctx.assets.join("quickstart").join("tshirt-local")
}

/// Edist of the network on known test samples (reference.json).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Reference {
    /// Dataset config name.
    pub dataset: String,
    /// sha256 of the resolved dataset config.
    pub config_sha256: String,
    /// Per sample: id, network Edist (cm), DQS Edist (cm).
    pub samples: Vec<(u64, f64, f64)>,
}

/// Runs `drape quickstart`.
pub fn run(args: QuickstartArgs, ctx: &Context) -> anyhow::Result<()> {
    let run_dir = args.run.clone().unwrap_or_else(|| default_run(ctx));
    let (config, info) = learn::run::open_run(&run_dir).map_err(|e| {
        if args.run.is_some() {
            anyhow::anyhow!("{e}\n(--model takes a run folder of `drape train`)")
        } else {
            anyhow::anyhow!("{e}\n(the quick start needs the network weights in {}; they are part of the repository)", run_dir.display())
        }
    })?;
    // The dataset config the network was trained on: from its data folder when that is
    // here and still the one trained on, else the built-in config of that name (the
    // committed weights' data is not shipped).
    let trained_on = dataset::reader::Dataset::open(&config.data)
        .ok()
        .filter(|d| {
            learn::run::manifest_sha256(&config.data)
                .is_ok_and(|m| info.trained_on(&m, &d.manifest.drapes_sha256()))
        });
    let dc = match trained_on {
        Some(d) => d.manifest.dataset_config()?,
        None => DatasetConfig::load(&info.dataset).map_err(|e| {
            anyhow::anyhow!(
                "{e}\n(the quick start draws bodies with the dataset config the network was trained on: its data folder {} is not here, and {:?} is not a built-in config)",
                config.data.display(),
                info.dataset
            )
        })?,
    };
    if let Some(out) = &args.reference {
        return reference(ctx, &run_dir, &dc, out);
    }
    let t_load = Instant::now();
    let (model, library, template) = dataset::generate::load_inputs(&dc, &ctx.assets, &mut |g| {
        eprintln!("building the {g} template (once; cached in assets/garments/built)")
    })?;
    let canonical = model.shape(&ShapeParams::default())?;
    let wardrobe =
        dataset::wardrobe::Wardrobe::new(template, &dc, &model, &ctx.assets, &mut |g| {
            eprintln!("{g}")
        })?;
    let template = &wardrobe.base;
    let statics = dataset::shard::Static::new(&template.mesh, &model, &canonical.vertices);
    let net = Predictor::open(&run_dir, &statics)?;
    let poser = Poser::new(&dc, &model, library)?;
    let plan = SamplePlan {
        id: args.seed,
        split: Split::Test,
        body: 0,
        pose_index: 0,
        shape_seed: args.seed,
        pose_seed: args.seed,
    };
    let drawn = poser.draw(&dc, &model, &plan)?;
    let shaped = model.shape(&drawn.shape)?;
    let posed = shaped.pose(&drawn.pose);
    eprintln!(
        "loaded in {:.1} s: {} ({} vertices), {} from {}",
        t_load.elapsed().as_secs_f64(),
        info.garment,
        template.mesh.vertices.len(),
        net.config.model.variant.paper_name(),
        run_dir.display()
    );
    println!(
        "body: seed {}, {} pose ({})",
        args.seed, drawn.family, drawn.pose_source
    );

    // The simulator: the dataset's protocol and config (the body's size, if the dataset
    // uses sizes), on all threads.
    let start = wardrobe.start(&shaped)?;
    if let Some(size) = start.size {
        println!("size {size} (picked from the body's measurements)");
    }
    let motion = BodyMorph::new(
        &model,
        start.reference,
        drawn.shape,
        drawn.pose.clone(),
        &dc.sim,
    )?;
    let bar = learn::run::progress(true, (motion.frames + dc.sim.max_frames) as u64);
    bar.set_message("simulator");
    let mut sim_result = drape::drape(
        start.cloth,
        &start.template.mesh.vertices,
        &motion,
        &dc.sim,
        true,
        &mut |p| bar.set_position(p.frame as u64),
    );
    bar.finish_and_clear();
    let sim_seconds = sim_result.report.wall_time;

    // The network: DQS warp, inputs, both streams; medians of 3 after a warm-up call.
    let params = learn::data::body_params(&drawn.shape.values(), &drawn.pose.rotations);
    let timed = eval::speed::network_drape(
        &net,
        template,
        &canonical,
        &shaped,
        &posed,
        drawn.pose.root_translation,
        &params,
        3,
    );
    let eval::speed::NetworkDrape {
        warped,
        prediction: pred,
        ..
    } = &timed;
    let net_seconds = timed.seconds();
    // Judged as `drape gen` judges a dataset's drape (slid down the body or not).
    sim_result.judge_slide(wardrobe.top_opening(), warped);
    if let Some(f) = &sim_result.report.failure {
        eprintln!(
            "warning: the simulator's drape failed ({f}); figures compare against its last state"
        );
    }

    let truth = &sim_result.positions;
    let tris = &template.mesh.triangles;
    let edist = eval::metrics::edist_cm(pred, truth);
    let enorm = eval::metrics::enorm_deg(pred, truth, tris);
    let dqs_edist = eval::metrics::edist_cm(warped, truth);
    let dqs_enorm = eval::metrics::enorm_deg(warped, truth, tris);

    std::fs::create_dir_all(&args.output)
        .map_err(|e| anyhow::anyhow!("cannot create {}: {e}", args.output.display()))?;
    let (img, _) = eval::report::sample_render(
        &posed.vertices,
        &model.triangles,
        tris,
        truth,
        pred,
        eval::report::NETWORK_LABEL,
    )?;
    let header = format!(
        "drape quickstart, seed {}, {} pose",
        args.seed, drawn.family
    );
    let meshes = [
        (
            "body.obj",
            TriMesh::new(posed.vertices.clone(), model.triangles.clone()),
        ),
        ("simulator.obj", TriMesh::new(truth.clone(), tris.clone())),
        ("network.obj", TriMesh::new(pred.clone(), tris.clone())),
        ("dqs.obj", TriMesh::new(warped.clone(), tris.clone())),
    ];
    let png = args.output.join("quickstart.png");
    let png_bytes = eval::render::encode_png(&img)?;
    let objs: Vec<(PathBuf, String)> = meshes
        .iter()
        .map(|(name, mesh)| {
            (
                args.output.join(name),
                mesh.to_obj(&format!("{header}: {name}")),
            )
        })
        .collect();
    let mut files: Vec<(&Path, &[u8])> = objs
        .iter()
        .map(|(p, t)| (p.as_path(), t.as_bytes()))
        .collect();
    files.push((&png, &png_bytes));
    sim::io::write_all_or_nothing(&files)?;

    println!(
        "simulator: {:.2} s ({} + {} frames, {} threads)",
        sim_seconds,
        sim_result.report.morph_frames,
        sim_result.report.settle_frames,
        rayon::current_num_threads()
    );
    println!(
        "network:   {:.1} ms (DQS warp, inputs and both streams; medians of 3 after a warm-up)",
        net_seconds * 1e3
    );
    println!("speed-up:  {:.0}x", sim_seconds / net_seconds);
    println!(
        "accuracy:  Edist {edist:.2} cm, Enorm {enorm:.1} degrees (the DQS warp alone: {dqs_edist:.2} cm, {dqs_enorm:.1} degrees)"
    );
    println!(
        "wrote body.obj, simulator.obj, network.obj, dqs.obj and {} (left: simulator; right: network coloured by its error)",
        png.display()
    );
    Ok(())
}

/// `--reference`: the network's Edist on the first 10 test samples, redraped.
fn reference(ctx: &Context, run_dir: &Path, dc: &DatasetConfig, out: &Path) -> anyhow::Result<()> {
    let first =
        dc.sample_ids().start + (dc.bodies.train + dc.bodies.val) as u64 * dc.poses_per_body as u64;
    let ids: Vec<u64> = (first..first + 10).collect();
    let t0 = Instant::now();
    let drapes = dataset::generate::redrape(dc, &ctx.assets, &ids)?;
    let (model, _, template) = dataset::generate::load_inputs(dc, &ctx.assets, &mut |_| {})?;
    let canonical = model.shape(&ShapeParams::default())?;
    let statics = dataset::shard::Static::new(&template.mesh, &model, &canonical.vertices);
    let net = Predictor::open(run_dir, &statics)?;
    let rows: Vec<dataset::shard::Row> = drapes.into_iter().filter_map(|(r, _)| r).collect();
    if rows.is_empty() {
        anyhow::bail!("none of the 10 test drapes converged: no reference to record");
    }
    let (preds, _) = net.predict_rows(&rows);
    let samples: Vec<(u64, f64, f64)> = rows
        .iter()
        .zip(&preds)
        .map(|(r, p)| {
            (
                r.id,
                eval::metrics::edist_cm(p, &r.draped),
                eval::metrics::edist_cm(&r.warped, &r.draped),
            )
        })
        .collect();
    for (id, e, d) in &samples {
        println!("sample {id}: Edist {e:.3} cm (DQS {d:.3} cm)");
    }
    let r = Reference {
        dataset: dc.name.clone(),
        config_sha256: dc.hash(),
        samples,
    };
    sim::io::write_all_or_nothing(&[(out, &serde_json::to_vec_pretty(&r)?)])?;
    println!(
        "{} of 10 test samples converged; {:.1} s -> {}",
        rows.len(),
        t0.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}
