//! Paired differences between two evaluations of the same drapes (`drape compare`): two
//! networks, or a network and a baseline, matched sample by sample. On the same test
//! drapes the per-drape errors of two runs are strongly correlated, so the standard error
//! of the per-drape differences is far smaller than either run's spread: a gap of 0.02 cm
//! between two means of 1.7 ± 0.4 cm can be 3 standard errors.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::evaluate::EvalError;
use crate::metrics::mean_std;
use crate::repro::record::DataSummary;

/// The per-sample figures compared: key in the evaluation's rows, label, factor to the
/// label's unit.
pub const FIGURES: [(&str, &str, f64); 7] = [
    ("edist_cm", "Edist (cm)", 1.0),
    ("enorm_deg", "Enorm (degrees)", 1.0),
    ("interpenetration", "vertices inside the body (%)", 100.0),
    ("l_mc", "L_MC", 1.0),
    ("strain_j", "strain energy (J)", 1.0),
    ("bending_j", "bending energy (J)", 1.0),
    ("gravity_j", "gravity energy (J)", 1.0),
];

/// One method's per-sample figures in an evaluation: sample id to figure key to value.
pub type PerSample = BTreeMap<i64, BTreeMap<String, f64>>;

/// The evaluation file of `path`: a report folder's `metrics.json`, or `path` itself.
fn metrics_file(path: &Path) -> Result<PathBuf, EvalError> {
    if path.is_dir() {
        let f = path.join("metrics.json");
        if f.is_file() {
            Ok(f)
        } else {
            Err(EvalError::Invalid(format!(
                "{} holds no metrics.json: give a report folder of `drape eval` or a metrics JSON file",
                path.display()
            )))
        }
    } else if path.is_file() {
        Ok(path.to_path_buf())
    } else {
        Err(EvalError::Invalid(format!(
            "{}: no such report folder or file",
            path.display()
        )))
    }
}

/// An evaluation's metrics file ([`metrics_file`]) and its JSON.
fn read_metrics(path: &Path) -> Result<(PathBuf, serde_json::Value), EvalError> {
    let file = metrics_file(path)?;
    let bytes = std::fs::read(&file)
        .map_err(|e| EvalError::Invalid(format!("cannot read {}: {e}", file.display())))?;
    let v = serde_json::from_slice(&bytes)
        .map_err(|e| EvalError::Invalid(format!("{}: not JSON: {e}", file.display())))?;
    Ok((file, v))
}

/// The drapes an evaluation was made on, from the provenance `drape eval` writes into its
/// `metrics.json`.
struct EvaluatedOn {
    /// The dataset manifest's sha256.
    manifest: String,
    /// The split.
    split: String,
    /// The data folder it named.
    data: Option<PathBuf>,
    /// The drapes' identity (`Manifest::drapes_sha256`; absent in evaluations made before
    /// session 71).
    drapes: Option<String>,
}

/// [`EvaluatedOn`] of an evaluation, `None` for a file without a provenance (the run
/// records in `docs/eval/`).
fn evaluated_on(path: &Path) -> Result<Option<EvaluatedOn>, EvalError> {
    let (_, v) = read_metrics(path)?;
    let p = &v["provenance"];
    Ok(p["manifest_sha256"]
        .as_str()
        .zip(p["split"].as_str())
        .map(|(m, s)| EvaluatedOn {
            manifest: m.to_string(),
            split: s.to_string(),
            data: p["data"].as_str().map(PathBuf::from),
            drapes: p["drapes_sha256"].as_str().map(str::to_string),
        }))
}

/// Which dataset manifests hold the same drapes, from a `drape reproduce` record folder
/// (`docs/reproduction-record/PLAN`): each of its `data/KEY.json` names the manifest of the
/// drapes its runs were evaluated on, under `same_drapes` the manifests of the same
/// drapes made again (one binary drapes the same bytes from one config; the manifests
/// differ only in the timings they record) and, since session 72, the drapes sha256,
/// which any making of the same drapes has. Without a record, only equal manifests (or
/// drapes sha256, [`check_same_drapes`]) match.
#[derive(Debug, Default)]
pub struct SameDrapes {
    /// The recorded datasets.
    recorded: Vec<DataSummary>,
}

impl SameDrapes {
    /// The datasets recorded in the record folder `dir` (its `data/*.json`).
    pub fn from_record(dir: &Path) -> Result<Self, EvalError> {
        if !dir.join("data").is_dir() {
            return Err(EvalError::Invalid(format!(
                "{}: not a record folder of `drape reproduce` (it has no data/ folder)",
                dir.display()
            )));
        }
        let recorded = DataSummary::all_recorded(dir)?;
        if recorded.is_empty() {
            return Err(EvalError::Invalid(format!(
                "{} records no dataset",
                dir.join("data").display()
            )));
        }
        Ok(Self { recorded })
    }

    /// The recorded datasets whose drapes an evaluation on manifest `m` holds (their
    /// recorded manifests): those that list `m` (as theirs or under `same_drapes`), those
    /// that record the evaluation's drapes sha256 `drapes` as theirs, and, if
    /// the data folder `data` the evaluation named still holds manifest `m`, those whose
    /// config and program its manifest records (a working folder made again after the
    /// record was written: [`DataSummary::same_drapes_as`]). Beside them, why
    /// the data folder did not count, for the error message.
    fn recorded_as(
        &self,
        m: &str,
        drapes: Option<&str>,
        data: Option<&Path>,
    ) -> Result<(BTreeSet<String>, Option<String>), EvalError> {
        let mut out: BTreeSet<String> = self
            .recorded
            .iter()
            .filter(|r| {
                r.manifest_sha256 == m
                    || r.same_drapes.iter().any(|s| s == m)
                    || r.names_drapes(drapes)
            })
            .map(|r| r.manifest_sha256.clone())
            .collect();
        let Some(data) = data.filter(|_| !self.recorded.is_empty()) else {
            return Ok((out, None));
        };
        let file = data.join("manifest.json");
        let why = match DataSummary::read("", &file)? {
            None => Some(format!("{} is gone", file.display())),
            Some(live) if live.manifest_sha256 != m => Some(format!(
                "{} is no longer the manifest evaluated",
                file.display()
            )),
            Some(live) => {
                let same: Vec<&DataSummary> = self
                    .recorded
                    .iter()
                    .filter(|r| live.same_drapes_as(r))
                    .collect();
                out.extend(same.iter().map(|r| r.manifest_sha256.clone()));
                same.is_empty().then(|| {
                    // Where the record names the drapes' identity, it decided.
                    let named: Vec<String> = self
                        .recorded
                        .iter()
                        .filter_map(|r| r.drapes_sha256.as_deref())
                        .map(|d| format!("{}...", dataset::manifest::short_hex(d)))
                        .collect();
                    match &live.drapes_sha256 {
                        Some(d) if !named.is_empty() => format!(
                            "{} holds drapes {}..., the record names {}",
                            file.display(),
                            dataset::manifest::short_hex(d),
                            named.join(", ")
                        ),
                        _ => format!(
                            "{} records no program and config the record does",
                            file.display()
                        ),
                    }
                })
            }
        };
        Ok((out, why))
    }
}

/// Refuses to pair two evaluations whose provenance names different drapes: another
/// dataset (its manifest's sha256; `same` says which manifests hold the same drapes) or
/// another split. Sample ids repeat across datasets and splits, so matching ids alone do
/// not make the drapes the same. Evaluations without a provenance pass.
pub fn check_same_drapes(a: &Path, b: &Path, same: &SameDrapes) -> Result<(), EvalError> {
    let (Some(ea), Some(eb)) = (evaluated_on(a)?, evaluated_on(b)?) else {
        return Ok(());
    };
    let (ma, sa, da) = (ea.manifest, ea.split, ea.data);
    let (mb, sb, db) = (eb.manifest, eb.split, eb.data);
    if sa == sb && ma == mb {
        return Ok(());
    }
    // The same drapes made again: their identities match where the manifests differ.
    // Where both record one and they differ, the drapes differ, whatever a record says.
    if let (Some(da_id), Some(db_id)) = (&ea.drapes, &eb.drapes) {
        if sa == sb && da_id == db_id {
            return Ok(());
        }
        return Err(EvalError::Invalid(format!(
            "{} was evaluated on the {sa} split of drapes {}... (dataset manifest {}...), {} on the {sb} split of drapes {}... (manifest {}...): these are different drapes; compare evaluations of the same split of the same drapes",
            a.display(),
            dataset::manifest::short_hex(da_id),
            dataset::manifest::short_hex(&ma),
            b.display(),
            dataset::manifest::short_hex(db_id),
            dataset::manifest::short_hex(&mb),
        )));
    }
    let (ra, why_a) = same.recorded_as(&ma, ea.drapes.as_deref(), da.as_deref())?;
    let (rb, why_b) = same.recorded_as(&mb, eb.drapes.as_deref(), db.as_deref())?;
    if sa == sb && !ra.is_disjoint(&rb) {
        return Ok(());
    }
    let hint = if same.recorded.is_empty() {
        " (a dataset made again by the same binary from the same config has the same drapes under another manifest sha256, as its manifest records timings: an evaluation made since session 71 records its drapes sha256, and two such pair on it; where one of them is older, `--record DIR` pairs evaluations on the manifests a `drape reproduce` record lists as the same drapes, on the drapes sha256 it names (records written since session 72), and on a data folder made again by the program and config it records)".to_string()
    } else {
        let whys: Vec<String> = [why_a, why_b].into_iter().flatten().collect();
        if whys.is_empty() {
            " (the record lists them as no one dataset)".to_string()
        } else {
            format!(
                " (the record lists them as no one dataset; {})",
                whys.join("; ")
            )
        }
    };
    Err(EvalError::Invalid(format!(
        "{} was evaluated on the {sa} split of the dataset with manifest sha256 {}..., {} on the {sb} split of {}...: these are different drapes; compare evaluations of the same split of the same dataset{hint}",
        a.display(),
        dataset::manifest::short_hex(&ma),
        b.display(),
        dataset::manifest::short_hex(&mb),
    )))
}

/// Reads `method`'s per-sample figures from an evaluation: a report folder of `drape eval`
/// (its `metrics.json`), or a JSON file with the same `samples` rows (a `metrics.json`,
/// the run records in `docs/eval/` that kept per-drape figures). `simulator` reads the
/// simulator's own figures (energies, interpenetration). Rows without the method are
/// skipped; figures that are not finite numbers (a diverged prediction's) are left out
/// are kept as NaN; [`compare`] counts and leaves them out.
pub fn load(path: &Path, method: &str) -> Result<PerSample, EvalError> {
    let (file, v) = read_metrics(path)?;
    let rows = v["samples"].as_array().ok_or_else(|| {
        EvalError::Invalid(format!(
            "{} has no per-sample rows (`samples`): only reports of `drape eval` and records that kept per-drape figures can be paired",
            file.display()
        ))
    })?;
    let mut out = PerSample::new();
    let mut methods = BTreeSet::new();
    for row in rows {
        let Some(id) = row["id"].as_i64() else {
            continue;
        };
        if let Some(m) = row["methods"].as_object() {
            methods.extend(m.keys().cloned());
        }
        if row["simulator"].is_object() {
            methods.insert("simulator".to_string());
        }
        let fig = if method == "simulator" {
            row["simulator"].as_object()
        } else {
            row["methods"][method].as_object()
        };
        let Some(fig) = fig else {
            continue;
        };
        // Numbers, and the nulls a non-finite figure is written as, as NaN.
        let values = fig
            .iter()
            .filter(|(_, x)| x.is_number() || x.is_null())
            .map(|(k, x)| (k.clone(), x.as_f64().unwrap_or(f64::NAN)))
            .collect();
        if out.insert(id, values).is_some() {
            return Err(EvalError::Invalid(format!(
                "{} has sample id {id} twice",
                file.display()
            )));
        }
    }
    if out.is_empty() {
        let have: Vec<_> = methods.into_iter().collect();
        return Err(EvalError::Invalid(format!(
            "{} has no per-sample figures of method `{method}`{}",
            file.display(),
            if have.is_empty() {
                String::new()
            } else {
                format!("; it has: {}", have.join(", "))
            }
        )));
    }
    Ok(out)
}

/// One figure's paired differences, A minus B, over the samples where both have it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Paired {
    /// The figure's key (`edist_cm`, ...).
    pub figure: String,
    /// Samples paired.
    pub samples: usize,
    /// A's mean over those samples, in the figure's key's unit.
    pub mean_a: f64,
    /// B's mean.
    pub mean_b: f64,
    /// The mean of the per-sample differences A - B.
    pub mean_difference: f64,
    /// Its standard error: the differences' sample standard deviation / sqrt(n).
    pub standard_error: f64,
    /// Samples on which A is lower.
    pub a_lower: usize,
    /// Samples on which B is lower.
    pub b_lower: usize,
    /// Shared samples left out because A's or B's value is not finite (a diverged
    /// prediction).
    pub non_finite: usize,
}

/// The paired differences of `(a, b)` value pairs (finite); None for fewer than two pairs.
pub fn paired(figure: &str, pairs: &[(f64, f64)]) -> Option<Paired> {
    let n = pairs.len();
    if n < 2 {
        return None;
    }
    let d: Vec<f64> = pairs.iter().map(|(a, b)| a - b).collect();
    // Population deviation s / sqrt(n - 1) is the sample deviation / sqrt(n).
    let (mean, std) = mean_std(&d);
    let avg = |f: fn(&(f64, f64)) -> f64| pairs.iter().map(f).sum::<f64>() / n as f64;
    Some(Paired {
        figure: figure.to_string(),
        samples: n,
        mean_a: avg(|p| p.0),
        mean_b: avg(|p| p.1),
        mean_difference: mean,
        standard_error: std / ((n - 1) as f64).sqrt(),
        a_lower: pairs.iter().filter(|(a, b)| a < b).count(),
        b_lower: pairs.iter().filter(|(a, b)| b < a).count(),
        non_finite: 0,
    })
}

/// Two evaluations compared sample by sample.
#[derive(Debug, Clone, Serialize)]
pub struct Comparison {
    /// What A is (path and method).
    pub a: String,
    /// What B is.
    pub b: String,
    /// Samples both evaluated.
    pub shared: usize,
    /// Samples only A evaluated.
    pub only_a: usize,
    /// Samples only B evaluated.
    pub only_b: usize,
    /// The figures both have on at least two shared samples, in [`FIGURES`]' order.
    pub figures: Vec<Paired>,
}

/// Compares A with B on the samples both evaluated (matched by id).
pub fn compare(
    a: &PerSample,
    b: &PerSample,
    a_name: &str,
    b_name: &str,
) -> Result<Comparison, EvalError> {
    let shared: Vec<i64> = a.keys().filter(|id| b.contains_key(id)).copied().collect();
    if shared.len() < 2 {
        return Err(EvalError::Invalid(format!(
            "{a_name} and {b_name} share {} sample id(s): compare evaluations of the same split of the same dataset",
            shared.len()
        )));
    }
    let figures = FIGURES
        .iter()
        .filter_map(|(key, _, _)| {
            let both: Vec<(f64, f64)> = shared
                .iter()
                .filter_map(|id| Some((*a[id].get(*key)?, *b[id].get(*key)?)))
                .collect();
            let pairs: Vec<(f64, f64)> = both
                .iter()
                .copied()
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect();
            let mut p = paired(key, &pairs)?;
            p.non_finite = both.len() - pairs.len();
            Some(p)
        })
        .collect::<Vec<_>>();
    if figures.is_empty() {
        return Err(EvalError::Invalid(format!(
            "{a_name} and {b_name} have no figure with finite values on two shared samples"
        )));
    }
    Ok(Comparison {
        a: a_name.to_string(),
        b: b_name.to_string(),
        shared: shared.len(),
        only_a: a.len() - shared.len(),
        only_b: b.len() - shared.len(),
        figures,
    })
}

impl Comparison {
    /// The comparison as a Markdown table with a header line.
    pub fn table(&self) -> String {
        let mut s = format!(
            "A: {}\nB: {}\n{} samples in both",
            self.a, self.b, self.shared
        );
        if self.only_a + self.only_b > 0 {
            write!(
                s,
                " ({} only in A, {} only in B, left out)",
                self.only_a, self.only_b
            )
            .unwrap();
        }
        s.push_str("\n\n| figure | samples | A | B | A - B | standard error | (A - B) / s.e. | A lower on | B lower on |\n|---|---|---|---|---|---|---|---|---|\n");
        for p in &self.figures {
            let (label, scale) = FIGURES
                .iter()
                .find(|f| f.0 == p.figure)
                .map_or((p.figure.as_str(), 1.0), |f| (f.1, f.2));
            let t = if p.standard_error > 0.0 {
                format!("{:+.1}", p.mean_difference / p.standard_error)
            } else {
                "-".to_string()
            };
            let samples = if p.non_finite > 0 {
                format!("{} ({} not finite, left out)", p.samples, p.non_finite)
            } else {
                p.samples.to_string()
            };
            writeln!(
                s,
                "| {label} | {samples} | {} | {} | {} | {} | {t} | {} | {} |",
                num(p.mean_a * scale, false),
                num(p.mean_b * scale, false),
                num(p.mean_difference * scale, true),
                num(p.standard_error * scale, false),
                p.a_lower,
                p.b_lower
            )
            .unwrap();
        }
        s
    }
}

/// Four significant digits, fixed-point where that reads well; `sign`: a `+` before
/// positive values.
fn num(x: f64, sign: bool) -> String {
    let a = x.abs();
    let body = if a != 0.0 && !(1e-4..1e6).contains(&a) {
        format!("{a:.3e}")
    } else {
        let mut digits = if a == 0.0 {
            4
        } else {
            (3 - a.log10().floor() as i32).clamp(0, 8) as usize
        };
        // 9.9996 rounds to 10.000 at four decimals: one digit fewer.
        let significant = format!("{a:.digits$}")
            .chars()
            .filter(char::is_ascii_digit)
            .skip_while(|&c| c == '0')
            .count();
        if digits > 0 && significant > 4 {
            digits -= 1;
        }
        format!("{a:.digits$}")
    };
    let lead = if x < 0.0 {
        "-"
    } else if sign {
        "+"
    } else {
        ""
    };
    format!("{lead}{body}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn per_sample(rows: &[(i64, f64, f64)]) -> PerSample {
        rows.iter()
            .map(|&(id, e, n)| {
                (
                    id,
                    BTreeMap::from([("edist_cm".to_string(), e), ("enorm_deg".to_string(), n)]),
                )
            })
            .collect()
    }

    /// Differences 0.1, 0.3, -0.1, 0.1 (A - B) on the four shared samples: mean 0.1, sample
    /// standard deviation sqrt(0.08 / 3), standard error that / 2; A lower on one.
    #[test]
    fn paired_differences_by_hand() {
        let a = per_sample(&[
            (1, 2.1, 10.0),
            (2, 1.3, 12.0),
            (3, 0.9, 8.0),
            (4, 1.6, 9.0),
            (9, 5.0, 1.0),
        ]);
        let b = per_sample(&[
            (4, 1.5, 9.0),
            (3, 1.0, 7.0),
            (2, 1.0, 12.0),
            (1, 2.0, 11.0),
            (7, 1.0, 1.0),
        ]);
        let c = compare(&a, &b, "a", "b").unwrap();
        assert_eq!((c.shared, c.only_a, c.only_b), (4, 1, 1));
        let e = &c.figures[0];
        assert_eq!(e.figure, "edist_cm");
        assert_eq!(e.samples, 4);
        assert!((e.mean_difference - 0.1).abs() < 1e-12);
        let se = (0.08f64 / 3.0).sqrt() / 2.0;
        assert!(
            (e.standard_error - se).abs() < 1e-12,
            "{}",
            e.standard_error
        );
        assert!((e.mean_a - 1.475).abs() < 1e-12 && (e.mean_b - 1.375).abs() < 1e-12);
        assert_eq!((e.a_lower, e.b_lower), (1, 3));
        // Enorm: differences -1, 0, 1, 0: mean 0, one lower each way, one tie.
        let n = &c.figures[1];
        assert!(n.mean_difference.abs() < 1e-12);
        assert_eq!((n.a_lower, n.b_lower), (1, 1));
        // Figures neither side has are not listed.
        assert_eq!(c.figures.len(), 2);
        let t = c.table();
        assert!(
            t.contains("| Edist (cm) | 4 | 1.475 | 1.375 | +0.1000 | 0.08165 | +1.2 | 1 | 3 |"),
            "{t}"
        );
    }

    /// A diverged prediction (NaN) is left out of its figure and counted.
    #[test]
    fn non_finite_values_are_counted_and_left_out() {
        let a = per_sample(&[(1, f64::NAN, 1.0), (2, 1.0, 1.0), (3, 2.0, 2.0)]);
        let b = per_sample(&[(1, 1.0, 1.0), (2, 1.5, 1.0), (3, 1.5, 1.0)]);
        let c = compare(&a, &b, "a", "b").unwrap();
        assert_eq!((c.figures[0].samples, c.figures[0].non_finite), (2, 1));
        assert!(c.figures[0].mean_difference.abs() < 1e-12);
        assert_eq!((c.figures[1].samples, c.figures[1].non_finite), (3, 0));
        assert!(
            c.table()
                .contains("| Edist (cm) | 2 (1 not finite, left out) | 1.500 | 1.500 | +0.0000 |"),
            "{}",
            c.table()
        );
    }

    #[test]
    fn evaluations_without_shared_samples_are_an_error() {
        let a = per_sample(&[(1, 1.0, 1.0), (2, 1.0, 1.0)]);
        let b = per_sample(&[(3, 1.0, 1.0), (2, 1.0, 1.0)]);
        let e = compare(&a, &b, "a", "b").unwrap_err().to_string();
        assert!(e.contains("share 1 sample id"), "{e}");
    }

    #[test]
    fn numbers_keep_four_significant_digits() {
        assert_eq!(num(1.73391, false), "1.734");
        assert_eq!(num(-0.01853, true), "-0.01853");
        assert_eq!(num(15.596, false), "15.60");
        assert_eq!(num(1548.47, false), "1548");
        assert_eq!(num(2.5e-7, false), "2.500e-7");
        assert_eq!(num(9.9996, false), "10.00");
        assert_eq!(num(0.099996, true), "+0.1000");
    }
}
