//! How the closed-form maps improve with training data (`drape data curve`): would more
//! drapes buy a lower Edist, and how many?
//!
//! For each share of the training bodies (the first bodies by index, all their drapes) two
//! maps from the sample's shape and pose to the displacement `G - M` are fitted and
//! measured on the test split (the validation split picks their strengths):
//!
//! - the linear map of `drape eval` ([`learn::linear`]: ridge regression on the shape and
//!   the bones' rotation matrices, its strength picked on the validation split);
//! - the same plus an RBF kernel ridge regression of what the linear map leaves (the
//!   linear fit's training residual), on the standardised features ([`learn::kernel`]): a
//!   smooth nonlinear map whose error keeps falling with data where the linear map's levels
//!   off. Its kernel width and strength are picked on the validation split from
//!   [`learn::kernel::WIDTHS`] x [`learn::kernel::LAMBDAS`].
//!
//! Training Edist beside held-out Edist tells a map that has stopped improving (the two
//! meet) from one that more data would still help.

use std::collections::BTreeSet;

use dataset::config::Split;
use dataset::reader::Dataset;
use glam::Vec3;
use learn::kernel::{Fit, Row};
use learn::linear::{features, read_split};
use serde::Serialize;

use crate::evaluate::EvalError;
use crate::metrics::{edist_cm, mean};

/// One point of the curve.
#[derive(Debug, Clone, Serialize)]
pub struct CurvePoint {
    /// Share of the training bodies asked for.
    pub share: f64,
    /// Training bodies used.
    pub bodies: usize,
    /// Their drapes.
    pub drapes: usize,
    /// The linear map's ridge strength (picked on validation).
    pub linear_lambda: f64,
    /// The linear map's Edist on its own training drapes (cm).
    pub linear_train_cm: f64,
    /// The linear map's Edist on the held-out split (cm).
    pub linear_cm: f64,
    /// The kernel's width factor `c` and strength (picked on validation).
    pub kernel_width: f64,
    /// See `kernel_width`.
    pub kernel_lambda: f64,
    /// Linear plus kernel, Edist on the held-out split (cm).
    pub kernel_cm: f64,
}

/// The whole curve.
#[derive(Debug, Clone, Serialize)]
pub struct Curve {
    /// Dataset name and manifest checksum.
    pub dataset: String,
    /// See `dataset`.
    pub manifest_sha256: String,
    /// The split measured (test).
    pub split: String,
    /// Its drapes.
    pub held_out: usize,
    /// The DQS warp's Edist on it (cm).
    pub dqs_cm: f64,
    /// One point per share, in the order asked.
    pub points: Vec<CurvePoint>,
}

/// Measures the curve on `data`: training on the first `shares` of its training bodies,
/// picking on its validation split, measuring on its test split. `progress` gets a line per
/// step.
pub fn measure(
    data: &Dataset,
    shares: &[f64],
    progress: &mut dyn FnMut(&str),
) -> Result<Curve, EvalError> {
    let bad = |m: String| Err(EvalError::Invalid(m));
    if shares.is_empty() || shares.iter().any(|s| !(*s > 0.0 && *s <= 1.0)) {
        return bad(format!("shares must lie in (0, 1]: {shares:?}"));
    }
    let split = Split::Test;
    progress("reading the training split");
    let train: Vec<Row> = data
        .samples(Split::Train)
        .map(|s| {
            let s = s?;
            Ok(Row {
                body: s.record.plan.body,
                x: features(&s.row.shape, &s.row.pose),
                d: s.row.displacement(),
            })
        })
        .collect::<Result<_, EvalError>>()?;
    let validation = read_split(data, Split::Val)?;
    let held = read_split(data, split)?;
    if train.is_empty() || validation.is_empty() || held.is_empty() {
        return bad(format!(
            "{} needs training, validation and {} drapes (it has {}, {} and {})",
            data.dir.display(),
            split.name(),
            train.len(),
            validation.len(),
            held.len()
        ));
    }
    let bodies: Vec<u64> = train
        .iter()
        .map(|t| t.body)
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let dqs_cm = mean(held.iter().map(|(_, m, g)| edist_cm(m, g)));
    let mut points = Vec::new();
    for &share in shares {
        let count = ((bodies.len() as f64 * share).round() as usize).clamp(1, bodies.len());
        let kept: BTreeSet<u64> = bodies[..count].iter().copied().collect();
        let used: Vec<&Row> = train.iter().filter(|t| kept.contains(&t.body)).collect();
        progress(&format!(
            "{count} bodies ({} drapes): linear map",
            used.len()
        ));
        let fit = Fit::new(&used, &validation, None, &mut |m| {
            progress(&format!("{count} bodies: {m}"))
        });
        let Some(fit) = fit else {
            return bad("the linear or kernel system cannot be solved".into());
        };
        let xs: Vec<&[f64]> = held.iter().map(|(x, _, _)| x.as_slice()).collect();
        let on_held = |d: &dyn Fn(usize) -> Vec<Vec3>| {
            mean(held.iter().enumerate().map(|(i, (_, m, g))| {
                let p: Vec<Vec3> = m.iter().zip(d(i)).map(|(m, d)| *m + d).collect();
                edist_cm(&p, g)
            }))
        };
        let linear_cm = on_held(&|i| fit.linear.displacement(xs[i]));
        let kernel = fit.displacements(&xs);
        let kernel_cm = on_held(&|i| kernel[i].clone());
        let picks = fit.picks();
        points.push(CurvePoint {
            share,
            bodies: count,
            drapes: used.len(),
            linear_lambda: picks.linear_lambda,
            linear_train_cm: fit.linear_train_cm,
            linear_cm,
            kernel_width: picks.width,
            kernel_lambda: picks.lambda,
            kernel_cm,
        });
    }
    Ok(Curve {
        dataset: data.manifest.name.clone(),
        manifest_sha256: learn::run::manifest_sha256(&data.dir)?,
        split: split.name().to_string(),
        held_out: held.len(),
        dqs_cm,
        points,
    })
}

/// The curve as a chart: Edist against log2 of the training drapes, the linear map on its
/// training drapes and held out, the kernel map held out, and the 1 cm line.
pub fn chart(c: &Curve) -> crate::plot::Chart {
    use crate::plot::{Chart, PALETTE, Series};
    let x = |p: &CurvePoint| (p.drapes.max(1) as f64).log2();
    let line = |label: &str, k: usize, f: &dyn Fn(&CurvePoint) -> f64| Series {
        label: label.to_string(),
        points: c.points.iter().map(|p| (x(p), f(p))).collect(),
        colour: PALETTE[k],
    };
    let xs: Vec<f64> = c.points.iter().map(x).collect();
    let (x0, x1) = (
        xs.iter().cloned().fold(f64::MAX, f64::min).floor(),
        xs.iter().cloned().fold(f64::MIN, f64::max).ceil(),
    );
    let x1 = if x1 > x0 { x1 } else { x0 + 1.0 };
    let ys = c
        .points
        .iter()
        .flat_map(|p| [p.linear_train_cm, p.linear_cm, p.kernel_cm]);
    let (lo, hi) = ys.fold((1.0f64, 1.0f64), |(a, b), y| (a.min(y), b.max(y)));
    Chart {
        title: format!("{}: Edist on {} {} drapes", c.dataset, c.held_out, c.split),
        x_label: "log2 of the training drapes (10 = 1,024; 12 = 4,096)".into(),
        y_label: "Edist (cm)".into(),
        x_range: (x0, x1),
        y_range: ((lo * 10.0).floor() / 10.0, (hi * 10.0).ceil() / 10.0),
        series: vec![
            line("linear, held out", 0, &|p| p.linear_cm),
            line("linear, its training drapes", 2, &|p| p.linear_train_cm),
            line("linear + kernel, held out", 1, &|p| p.kernel_cm),
            Series {
                label: "1 cm".into(),
                points: vec![(x0, 1.0), (x1, 1.0)],
                colour: [150, 150, 150],
            },
        ],
    }
}
