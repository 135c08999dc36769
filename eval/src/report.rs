//! The report folder of `drape eval`: `report.md` (tables, plots, renders), `metrics.json`
//! (every figure with its provenance), `samples.csv`, the average-precision curves as CSV
//! and PNG, and renders of the best, median and worst samples with their error maps (PNG
//! and EXR).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use dataset::config::Split;
use dataset::reader::Dataset;
use glam::Vec3;
use learn::predict::Predictor;
use serde::Serialize;

use crate::evaluate::{EvalError, Evaluation, Figures, METHODS, SampleEval, method_title, rows_of};
use crate::metrics::{mean_std, vertex_errors};
use crate::plot::{Chart, PALETTE, Series, colour_bar, line_chart};
use crate::render::{
    BODY_COLOUR, GARMENT_COLOUR, Image, Layer, RenderOptions, encode_png, error_colour, grid,
    render, render_values, stack,
};

/// Error (cm) shown as the top colour of the error maps.
pub const ERROR_SCALE_CM: f32 = 4.0;

/// Mean and standard deviation of each figure over the samples.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Summary {
    /// Edist (cm).
    pub edist_cm: (f64, f64),
    /// Enorm (degrees).
    pub enorm_deg: (f64, f64),
    /// L_MC.
    pub l_mc: (f64, f64),
    /// L_RQ^8, L_RQ^16, L_RQ^32.
    pub l_rq: [(f64, f64); 3],
    /// Strain energy (J).
    pub strain_j: (f64, f64),
    /// Bending energy (J).
    pub bending_j: (f64, f64),
    /// Gravity energy (J).
    pub gravity_j: (f64, f64),
    /// Interpenetration ratio.
    pub interpenetration: (f64, f64),
}

impl Summary {
    fn of<'a>(figs: impl Iterator<Item = &'a Figures> + Clone) -> Self {
        let col = |f: &dyn Fn(&Figures) -> f64| mean_std(&figs.clone().map(f).collect::<Vec<_>>());
        Self {
            edist_cm: col(&|f| f.edist_cm),
            enorm_deg: col(&|f| f.enorm_deg),
            l_mc: col(&|f| f.l_mc),
            l_rq: [0, 1, 2].map(|k| col(&|f| f.l_rq[k])),
            strain_j: col(&|f| f.strain_j),
            bending_j: col(&|f| f.bending_j),
            gravity_j: col(&|f| f.gravity_j),
            interpenetration: col(&|f| f.interpenetration),
        }
    }
}

/// Summaries per method and of the simulator.
pub fn summaries(ev: &Evaluation) -> BTreeMap<String, Summary> {
    let mut out: BTreeMap<String, Summary> = METHODS
        .iter()
        .map(|m| {
            (
                m.to_string(),
                Summary::of(ev.samples.iter().map(|s| &s.methods[*m])),
            )
        })
        .collect();
    out.insert(
        "simulator".into(),
        Summary::of(ev.samples.iter().map(|s| &s.simulator)),
    );
    out
}

/// The sentence under the curvature table: each method's median L_MC over the samples,
/// which no single sample can carry, and the largest sample's share of the network's mean.
/// None without samples or with a zero mean.
fn curvature_weights(samples: &[SampleEval], title: &dyn Fn(&str) -> String) -> Option<String> {
    let (id, share) = crate::metrics::largest_share(
        samples
            .iter()
            .filter_map(|s| Some((s.id, s.methods.get("network")?.l_mc))),
    )?;
    let medians: Vec<String> = METHODS
        .iter()
        .filter_map(|m| {
            let median = crate::metrics::median_of(
                samples
                    .iter()
                    .filter_map(|s| Some(s.methods.get(*m)?.l_mc))
                    .collect(),
            )?;
            Some(format!("{} {median:.4e}", title(m)))
        })
        .collect();
    Some(format!(
        "Medians over samples of L_MC, which no single sample can carry: {}. The largest sample carries {:.0}% of the network's mean L_MC (sample {id}): L_MC squares the mean-curvature normal, which is very large where a drape crushes a few triangles thin (`drape data info` counts such drapes).",
        medians.join(", "),
        share
    ))
}

/// Where the figures came from.
#[derive(Debug, Clone, Serialize)]
pub struct Provenance {
    /// The run folder.
    pub run: PathBuf,
    /// sha256 of the run's resolved config (`config.toml`).
    pub run_config_sha256: String,
    /// The dataset folder, name and manifest sha256.
    pub data: PathBuf,
    /// Dataset name.
    pub dataset: String,
    /// sha256 of `manifest.json`.
    pub manifest_sha256: String,
    /// The drapes' identity (`Manifest::drapes_sha256`): the same for the same drapes made
    /// again, whose manifests differ.
    pub drapes_sha256: String,
    /// The split evaluated.
    pub split: String,
    /// Git revision of the program.
    pub git_revision: String,
    /// Program version.
    pub program_version: String,
    /// Datasets whose training drapes the network trained on besides the evaluated
    /// dataset's (`drape train --more-data`); the baselines fit on the evaluated dataset's
    /// training drapes only.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub more_data: Vec<learn::train::MoreData>,
}

fn sha256_file(path: &Path) -> Result<String, EvalError> {
    let bytes = std::fs::read(path).map_err(|e| EvalError::Read {
        path: path.to_path_buf(),
        source: e,
    })?;
    Ok(dataset::generate::sha256(&bytes))
}

/// Body, simulator garment | body, another garment (the network's) coloured by its
/// distance to the simulator's, with a colour bar titled `label`; and the error image (cm)
/// of the right view.
pub fn sample_render(
    body: &[Vec3],
    body_triangles: &[[u32; 3]],
    garment_triangles: &[[u32; 3]],
    truth: &[Vec3],
    pred: &[Vec3],
    label: &str,
) -> Result<(Image, crate::render::Values), EvalError> {
    let opts = RenderOptions {
        height: 420,
        ..RenderOptions::default()
    };
    let sim_img = render(
        &[
            Layer::new(body, body_triangles, BODY_COLOUR),
            Layer::new(truth, garment_triangles, GARMENT_COLOUR),
        ],
        &opts,
    )?;
    let err_cm: Vec<f32> = vertex_errors(pred, truth)
        .iter()
        .map(|e| e * 100.0)
        .collect();
    let colours: Vec<[u8; 3]> = err_cm
        .iter()
        .map(|e| error_colour(e / ERROR_SCALE_CM))
        .collect();
    let (net_img, values) = render_values(
        &[
            Layer::new(body, body_triangles, BODY_COLOUR),
            Layer::new(pred, garment_triangles, GARMENT_COLOUR)
                .with_vertex_colours(&colours, &err_cm),
        ],
        &opts,
    )?;
    let top = grid(&[sim_img, net_img], 2, [242, 242, 242]);
    let bar = colour_bar(ERROR_SCALE_CM as f64, label, top.width.min(700));
    Ok((stack(&[top, bar], [255, 255, 255]), values))
}

/// The colour bar's title under a network's render.
pub const NETWORK_LABEL: &str = "network error (cm): right pair; simulator: left pair";

/// The colour bar's title under the linear baseline's render.
pub const LINEAR_LABEL: &str = "linear baseline error (cm): right pair; simulator: left pair";

fn fmt_ms(v: (f64, f64), digits: usize) -> String {
    format!("{:.digits$} ± {:.digits$}", v.0, v.1)
}

/// Writes the report folder `out` for `ev` (of `run` on `data`'s `split`). Returns the
/// summaries.
pub fn write_report(
    out: &Path,
    run: &Path,
    data: &Dataset,
    split: Split,
    ev: &Evaluation,
) -> Result<BTreeMap<String, Summary>, EvalError> {
    std::fs::create_dir_all(out).map_err(|e| EvalError::Io {
        path: out.to_path_buf(),
        source: e,
    })?;
    let sums = summaries(ev);
    // Every file of the report, written together at the end (all or none).
    let mut files: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    let title = |m: &str| method_title(m, &ev.network);
    let provenance = Provenance {
        run: run.to_path_buf(),
        run_config_sha256: sha256_file(&run.join("config.toml"))?,
        data: data.dir.clone(),
        dataset: data.manifest.name.clone(),
        manifest_sha256: learn::run::manifest_sha256(&data.dir)?,
        drapes_sha256: data.manifest.drapes_sha256(),
        split: split.name().into(),
        git_revision: dataset::manifest::GIT_REVISION.into(),
        program_version: env!("CARGO_PKG_VERSION").into(),
        more_data: learn::run::read_json::<learn::train::RunInfo>(&run.join("run.json"))
            .ok()
            .flatten()
            .map(|i| i.more_data)
            .unwrap_or_default(),
    };

    // Curves: CSV and PNG.
    for (name, curves, x_label, file) in [
        (
            "Vertices under a distance",
            &ev.distance_curves,
            "distance to the simulator's vertex (cm)",
            "ap_distance",
        ),
        (
            "Faces under a normal angle",
            &ev.angle_curves,
            "angle to the simulator's face normal (degrees)",
            "ap_angle",
        ),
    ] {
        let first = &curves[METHODS[0]];
        let mut csv = String::from("threshold");
        for m in METHODS {
            csv.push(',');
            csv.push_str(m);
        }
        csv.push('\n');
        let shares: Vec<Vec<f64>> = METHODS.iter().map(|m| curves[*m].shares()).collect();
        for (k, t) in first.thresholds.iter().enumerate() {
            write!(csv, "{t}").unwrap();
            for s in &shares {
                write!(csv, ",{:.6}", s[k]).unwrap();
            }
            csv.push('\n');
        }
        files.push((out.join(format!("{file}.csv")), csv.into_bytes()));
        let chart = Chart {
            title: name.into(),
            x_label: x_label.into(),
            y_label: "share".into(),
            x_range: (0.0, *first.thresholds.last().expect("thresholds")),
            y_range: (0.0, 1.0),
            series: METHODS
                .iter()
                .zip(&shares)
                .enumerate()
                .map(|(k, (m, s))| Series {
                    label: title(m),
                    points: first
                        .thresholds
                        .iter()
                        .copied()
                        .zip(s.iter().copied())
                        .collect(),
                    colour: PALETTE[k],
                })
                .collect(),
        };
        files.push((
            out.join(format!("{file}.png")),
            encode_png(&line_chart(&chart, 760, 480))?,
        ));
    }

    // Per-sample CSV.
    let mut csv = String::from(
        "id,family,method,edist_cm,enorm_deg,l_mc,l_rq8,l_rq16,l_rq32,strain_j,bending_j,gravity_j,interpenetration\n",
    );
    for s in &ev.samples {
        let rows = METHODS
            .iter()
            .map(|m| (*m, &s.methods[*m]))
            .chain(std::iter::once(("simulator", &s.simulator)));
        for (m, f) in rows {
            writeln!(
                csv,
                "{},{},{m},{:.5},{:.4},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6}",
                s.id,
                s.family,
                f.edist_cm,
                f.enorm_deg,
                f.l_mc,
                f.l_rq[0],
                f.l_rq[1],
                f.l_rq[2],
                f.strain_j,
                f.bending_j,
                f.gravity_j,
                f.interpenetration
            )
            .unwrap();
        }
    }
    files.push((out.join("samples.csv"), csv.into_bytes()));

    // Best, median and worst samples of the network, among finite predictions; a render
    // that fails is noted in the report instead of losing it.
    let mut order: Vec<usize> = (0..ev.samples.len())
        .filter(|&k| ev.samples[k].methods["network"].edist_cm.is_finite())
        .collect();
    let non_finite = ev.samples.len() - order.len();
    order.sort_by(|&a, &b| {
        ev.samples[a].methods["network"]
            .edist_cm
            .total_cmp(&ev.samples[b].methods["network"].edist_cm)
    });
    let picks: Vec<(&str, usize)> = if order.is_empty() {
        Vec::new()
    } else {
        vec![
            ("best", order[0]),
            ("median", order[order.len() / 2]),
            ("worst", order[order.len() - 1]),
        ]
    };
    let ids: Vec<u64> = picks.iter().map(|p| ev.samples[p.1].id).collect();
    let rows = rows_of(data, split, &ids)?;
    let mut render_notes: BTreeMap<&str, String> = BTreeMap::new();
    // The evaluated sample whose linear-baseline render was written.
    let mut linear_render: Option<usize> = None;
    if !rows.is_empty() {
        let net = Predictor::open(run, &data.statics)?;
        let (preds, _) = net.predict_rows(&rows);
        let st = &data.statics;
        for ((name, k), (row, pred)) in picks.iter().zip(rows.iter().zip(&preds)) {
            match sample_render(
                &row.body,
                &st.body_triangles,
                &st.garment_triangles,
                &row.draped,
                pred,
                NETWORK_LABEL,
            ) {
                Ok((img, values)) => {
                    files.push((out.join(format!("{name}.png")), encode_png(&img)?));
                    files.push((
                        out.join(format!("{name}-error.exr")),
                        crate::exr::encode_gray(values.width, values.height, &values.data),
                    ));
                }
                Err(e) => {
                    render_notes.insert(name, format!("render failed: {e}"));
                }
            }
            // The linear baseline on the median sample, for comparison.
            if *name == "median" {
                let x = crate::linear::features(&row.shape, &row.pose);
                let lin = ev.linear.predict(&x, &row.warped);
                if let Ok((img, _)) = sample_render(
                    &row.body,
                    &st.body_triangles,
                    &st.garment_triangles,
                    &row.draped,
                    &lin,
                    LINEAR_LABEL,
                ) {
                    files.push((out.join("median-linear.png"), encode_png(&img)?));
                    linear_render = Some(*k);
                }
            }
        }
    }

    // metrics.json.
    /// Per curve, per method, its (threshold, share) points.
    type Curves<'a> = BTreeMap<&'a str, BTreeMap<String, Vec<(f64, f64)>>>;
    #[derive(Serialize)]
    struct Json<'a> {
        provenance: &'a Provenance,
        network: &'a str,
        samples_evaluated: usize,
        vertices: usize,
        training_samples: usize,
        summaries: &'a BTreeMap<String, Summary>,
        curves: Curves<'a>,
        network_seconds_per_drape: f64,
        batch: usize,
        workers: usize,
        renders: BTreeMap<&'a str, u64>,
        non_finite_predictions: usize,
        linear_lambda: f64,
        linear_validation_edist_cm: &'a [(f64, f64)],
        kernel: learn::kernel::Picks,
        kernel_validation_edist_cm: &'a [(f64, f64, f64)],
        samples: &'a [SampleEval],
    }
    let curve_points = |c: &BTreeMap<String, crate::metrics::Curve>| {
        c.iter()
            .map(|(m, c)| {
                (
                    m.clone(),
                    c.thresholds.iter().copied().zip(c.shares()).collect(),
                )
            })
            .collect()
    };
    let json = Json {
        provenance: &provenance,
        network: &ev.network,
        samples_evaluated: ev.samples.len(),
        vertices: data.statics.garment_vertices.len(),
        training_samples: ev.train_samples,
        summaries: &sums,
        curves: BTreeMap::from([
            ("distance_cm", curve_points(&ev.distance_curves)),
            ("angle_deg", curve_points(&ev.angle_curves)),
        ]),
        network_seconds_per_drape: ev.network_seconds_per_drape,
        batch: ev.batch,
        workers: ev.workers,
        renders: picks
            .iter()
            .zip(&ids)
            .map(|((n, _), id)| (*n, *id))
            .collect(),
        non_finite_predictions: non_finite,
        linear_lambda: ev.linear.lambda,
        linear_validation_edist_cm: &ev.linear_validation,
        kernel: ev.kernel,
        kernel_validation_edist_cm: &ev.kernel_validation,
        samples: &ev.samples,
    };
    files.push((
        out.join("metrics.json"),
        serde_json::to_vec_pretty(&json).expect("metrics serialise"),
    ));

    // report.md.
    let mut md = String::new();
    let net_sum = &sums["network"];
    writeln!(
        md,
        "# Evaluation: {} on {} ({} split)\n",
        ev.network, provenance.dataset, provenance.split
    )
    .unwrap();
    writeln!(
        md,
        "{} {} samples, {} training samples for the baselines. Run `{}` (config sha256 `{}`), dataset `{}` (manifest sha256 `{}`), program {} at git `{}`. Every figure here is also in `metrics.json`; per sample in `samples.csv`.\n",
        ev.samples.len(),
        provenance.split,
        ev.train_samples,
        run.display(),
        &provenance.run_config_sha256[..12],
        data.dir.display(),
        &provenance.manifest_sha256[..12],
        provenance.program_version,
        provenance.git_revision
    )
    .unwrap();
    if !provenance.more_data.is_empty() {
        let more: Vec<String> = provenance
            .more_data
            .iter()
            .map(|m| format!("{} training drapes of `{}`", m.train_drapes, m.dataset))
            .collect();
        writeln!(
            md,
            "The network trained on {} too (`drape train --more-data`); the baselines fit on `{}`'s {} only.\n",
            more.join(" and "),
            provenance.dataset,
            ev.train_samples
        )
        .unwrap();
    }
    writeln!(md, "## Accuracy (the paper's Table 1 metrics)\n").unwrap();
    writeln!(
        md,
        "Mean ± standard deviation over samples. Edist: Eq. 17, mean vertex distance to the simulator's drape. Enorm: Eq. 18, mean angle between face normals; our garments have about {} vertices, the paper's 10k, and finer meshes have smaller face-to-face angles, so Enorm compares across resolutions only roughly.\n",
        data.statics.garment_vertices.len()
    )
    .unwrap();
    writeln!(
        md,
        "| method | Edist (cm) | Enorm (°) | vertices under 1 cm | faces under 10° |"
    )
    .unwrap();
    writeln!(md, "|---|---|---|---|---|").unwrap();
    for m in METHODS {
        let s = &sums[m];
        writeln!(
            md,
            "| {} | {} | {} | {:.1}% | {:.1}% |",
            title(m),
            fmt_ms(s.edist_cm, 2),
            fmt_ms(s.enorm_deg, 2),
            100.0 * ev.distance_curves[m].share_at(1.0),
            100.0 * ev.angle_curves[m].share_at(10.0)
        )
        .unwrap();
    }
    let dqs = sums["dqs"].edist_cm.0;
    writeln!(
        md,
        "\n{} is at {:.1}% of the DQS baseline's Edist; the mean-residual, nearest-neighbour, linear and kernel baselines at {:.1}%, {:.1}%, {:.1}% and {:.1}%.\n",
        ev.network,
        100.0 * net_sum.edist_cm.0 / dqs,
        100.0 * sums["mean-residual"].edist_cm.0 / dqs,
        100.0 * sums["nearest-neighbour"].edist_cm.0 / dqs,
        100.0 * sums["linear"].edist_cm.0 / dqs,
        100.0 * sums["kernel"].edist_cm.0 / dqs
    )
    .unwrap();
    let tried: Vec<String> = ev
        .linear_validation
        .iter()
        .map(|(l, e)| format!("{l} ({e:.2} cm)"))
        .collect();
    writeln!(
        md,
        "The linear baseline is a ridge regression of the displacement G - M on the shape parameters and the bones' rotation matrices, fitted on the training split (`learn/src/linear.rs`); its strength {} was picked by validation Edist{}.\n",
        ev.linear.lambda,
        if tried.is_empty() {
            " (no validation samples: the default)".to_string()
        } else {
            format!(" among {}", tried.join(", "))
        }
    )
    .unwrap();
    let tried: Vec<String> = ev
        .kernel_validation
        .iter()
        .map(|(c, l, e)| format!("c {c}, {l} ({e:.2} cm)"))
        .collect();
    writeln!(
        md,
        "The kernel baseline adds to it an RBF kernel ridge regression of what it leaves on the training drapes, on the standardised features (`learn/src/kernel.rs`): width factor c {} (gamma = c / 2d) and strength {}, picked by validation Edist{}.\n",
        ev.kernel.width,
        ev.kernel.lambda,
        if tried.is_empty() {
            " (no validation samples: the defaults)".to_string()
        } else {
            format!(" among {}", tried.join(", "))
        }
    )
    .unwrap();
    writeln!(
        md,
        "![vertex distances](ap_distance.png) ![face angles](ap_angle.png)\n"
    )
    .unwrap();
    writeln!(
        md,
        "Average-precision curves (the paper's Fig. 9): `ap_distance.csv`, `ap_angle.csv`.\n"
    )
    .unwrap();
    writeln!(md, "## Curvature (the paper's Table 7 metrics)\n").unwrap();
    writeln!(md, "Means over samples of L_MC (m^-2) and L_RQ^K (m^4) against the simulator's drape; the ratio column divides L_MC and L_RQ^8 by the network's.\n").unwrap();
    writeln!(
        md,
        "| method | L_MC | L_RQ^8 | L_RQ^16 | L_RQ^32 | L_MC / network | L_RQ^8 / network |"
    )
    .unwrap();
    writeln!(md, "|---|---|---|---|---|---|---|").unwrap();
    for m in METHODS {
        let s = &sums[m];
        writeln!(
            md,
            "| {} | {:.4e} | {:.4e} | {:.4e} | {:.4e} | {:.2} | {:.2} |",
            title(m),
            s.l_mc.0,
            s.l_rq[0].0,
            s.l_rq[1].0,
            s.l_rq[2].0,
            s.l_mc.0 / net_sum.l_mc.0,
            s.l_rq[0].0 / net_sum.l_rq[0].0
        )
        .unwrap();
    }
    if let Some(note) = curvature_weights(&ev.samples, &title) {
        writeln!(md, "\n{note}").unwrap();
    }
    writeln!(md, "\n## Physics (DrapeNet's metrics)\n").unwrap();
    writeln!(md, "Energies of each garment with SNUG's fabric (StVK membrane, dihedral bending with a flat rest angle, gravity above the body's lowest vertex; `eval/src/metrics.rs`), and the share of garment vertices inside the body.\n").unwrap();
    writeln!(
        md,
        "| garment | strain (J) | bending (J) | gravity (J) | vertices inside the body |"
    )
    .unwrap();
    writeln!(md, "|---|---|---|---|---|").unwrap();
    for m in ["simulator"].into_iter().chain(METHODS) {
        let s = &sums[m];
        writeln!(
            md,
            "| {} | {} | {} | {} | {:.2}% |",
            title(m),
            fmt_ms(s.strain_j, 4),
            fmt_ms(s.bending_j, 5),
            fmt_ms(s.gravity_j, 3),
            100.0 * s.interpenetration.0
        )
        .unwrap();
    }
    writeln!(md, "\n## Samples\n").unwrap();
    writeln!(md, "Left pair: the simulator's drape (front, side). Right pair: the network's, coloured by its distance to the simulator's (0 to {ERROR_SCALE_CM} cm; the same values as 32-bit floats in `*-error.exr`, NaN off the garment).\n").unwrap();
    if non_finite > 0 {
        writeln!(md, "**{non_finite} samples have non-finite predictions** (left out of the renders; their figures are NaN above).\n").unwrap();
    }
    for ((name, k), id) in picks.iter().zip(&ids) {
        let s = &ev.samples[*k];
        let picture = render_notes
            .get(name)
            .cloned()
            .unwrap_or_else(|| format!("![{name}]({name}.png)"));
        writeln!(
            md,
            "**{name}**: sample {id} ({}), Edist {:.2} cm (DQS {:.2} cm), Enorm {:.1}°\n\n{picture}\n",
            s.family, s.methods["network"].edist_cm, s.methods["dqs"].edist_cm, s.methods["network"].enorm_deg
        )
        .unwrap();
    }
    if let Some(k) = linear_render {
        writeln!(
            md,
            "**median, linear baseline**: the same sample, the linear baseline's drape coloured by its distance to the simulator's, Edist {:.2} cm, Enorm {:.1}°\n\n![median, linear](median-linear.png)\n",
            ev.samples[k].methods["linear"].edist_cm, ev.samples[k].methods["linear"].enorm_deg
        )
        .unwrap();
    }
    writeln!(
        md,
        "Network time in this evaluation: {:.1} ms per drape at batch {}, the batch's drapes shared among {} thread{} (inputs and both streams; `drape bench speedup` measures the speed-up). Evaluation wall time {:.1} s.",
        1e3 * ev.network_seconds_per_drape,
        ev.batch,
        ev.workers,
        if ev.workers == 1 { "" } else { "s" },
        ev.seconds
    )
    .unwrap();
    files.push((out.join("report.md"), md.into_bytes()));
    let refs: Vec<(&Path, &[u8])> = files
        .iter()
        .map(|(p, b)| (p.as_path(), b.as_slice()))
        .collect();
    sim::io::write_all_or_nothing(&refs).map_err(|e| EvalError::Io {
        path: e.path,
        source: e.source,
    })?;
    Ok(sums)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_curvature_sentence_gives_medians_and_the_heaviest_sample() {
        // Four samples; the network's L_MC 1, 2, 3 and 94 (sample 13 holds 94%), DQS 2.
        let samples: Vec<SampleEval> = [1.0, 2.0, 3.0, 94.0]
            .iter()
            .enumerate()
            .map(|(i, &mc)| SampleEval {
                id: 10 + i as u64,
                family: "walking".into(),
                sim_seconds: 1.0,
                methods: [
                    (
                        "network".to_string(),
                        Figures {
                            l_mc: mc,
                            ..Figures::default()
                        },
                    ),
                    (
                        "dqs".to_string(),
                        Figures {
                            l_mc: 2.0,
                            ..Figures::default()
                        },
                    ),
                ]
                .into_iter()
                .collect(),
                simulator: Figures::default(),
                neighbour: 0,
            })
            .collect();
        let title = |m: &str| method_title(m, "GarNet-Local");
        let s = curvature_weights(&samples, &title).unwrap();
        // Even count: the middle pair's mean; methods without figures left out.
        assert!(
            s.starts_with("Medians over samples of L_MC, which no single sample can carry: GarNet-Local 2.5000e0, DQS 2.0000e0. The largest sample carries 94% of the network's mean L_MC (sample 13)"),
            "{s}"
        );
        assert!(curvature_weights(&[], &title).is_none());
        assert!(curvature_weights(&samples[..0], &title).is_none());
    }
}
