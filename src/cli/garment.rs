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
        #[arg(long, value_name = "N")]
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
    },
    /// List the garments: built-in ones (and whether they are cached) and imported ones.
    List,
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
    let vertices = resolution.unwrap_or_else(|| {
        sim::garment::built_in(name).map_or(10_000, |d| d.vertices)
    });
    Ok(lib.get(name, vertices, model, &mut |msg| eprintln!("{msg}"))?)
}

/// Renders meshes over a body, front and side.
pub fn render(body: &[glam::Vec3], model: &BodyModel, garment: &TriMesh) -> anyhow::Result<Vec<u8>> {
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

fn write_outputs(
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
            let _ = &model;
            for (name, _) in sim::garment::def::BUILT_IN {
                let def = sim::garment::built_in(name).expect("built-in");
                let cached: Vec<String> = [def.vertices, sim::garment::LOW_RESOLUTION]
                    .iter()
                    .filter(|&&n| lib.built_path(name, n).exists())
                    .map(|n| n.to_string())
                    .collect();
                println!(
                    "{name:8} built-in  {}{}",
                    def.description,
                    if cached.is_empty() {
                        String::new()
                    } else {
                        format!(" [cached: {} vertices]", cached.join(", "))
                    }
                );
            }
            for name in lib.user_names() {
                println!("{name:8} imported  {}", lib.user_path(&name).display());
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
                    std::fs::remove_file(&p).with_context(|| format!("cannot remove {}", p.display()))?;
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
        GarmentCommand::Import { obj, name } => {
            let (model, _) = load(ctx)?;
            let (t, path) = lib.import(&obj, &name, &model)?;
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
    #[arg(long, value_name = "N")]
    resolution: Option<usize>,
    #[command(flatten)]
    shape: ShapeArgs,
    /// Target pose (as for `drape body --pose`).
    #[arg(long, default_value = "rest", value_name = "SPEC")]
    pose: String,
    /// Output OBJ of the warped garment.
    #[arg(short = 'o', long, value_name = "FILE.obj")]
    output: PathBuf,
    /// Also render it on the posed body.
    #[arg(long, value_name = "FILE.png")]
    png: Option<PathBuf>,
}

/// Runs `drape warp`: `M = dqs(M0, body)`.
pub fn warp(args: WarpArgs, ctx: &Context) -> anyhow::Result<()> {
    let params = args.shape.params()?;
    let (model, library) = load(ctx)?;
    let canonical = model.shape(&ShapeParams::default())?;
    let target = model.shape(&params)?;
    let resolved = pose_spec::resolve(&args.pose, &target, &library)?;
    let t = template(ctx, &args.garment, args.resolution, &model)?;
    let posed = target.pose(&resolved.pose);
    let warped = TriMesh::new(t.warp(&canonical, &target, &posed), t.mesh.triangles.clone());
    let image = match &args.png {
        Some(p) => Some((p.as_path(), render(&posed.vertices, &model, &warped)?)),
        None => None,
    };
    let header = format!(
        "drape warp: garment {} (DQS), pose {}",
        args.garment, resolved.description
    );
    write_outputs(&warped, &header, Some(&args.output), image)?;
    println!(
        "{}: {} vertices warped to pose {} -> {}",
        args.garment,
        warped.vertices.len(),
        resolved.description,
        args.output.display()
    );
    Ok(())
}
