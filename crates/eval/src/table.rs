//! Tables I and II of the paper (tab:comprehensive_analysis1 for Model I,
//! tab:comprehensive_analysis2 for Model II) regenerated from runs, in the paper's layout, as
//! Markdown and LaTeX; and the raw results as CSV and JSON, one row per (cell, method, seed).
//!
//! Layout: rows are the methods of the registry ([`crate::methods`]) in its order, grouped
//! Traditional (CUSUM, SPRT, BHT) / Learning-based (SVM, CNN, LSTM) / Ours (QUADFormer), then
//! the methods that are no row of the paper (chi-squared, the PX4-style gate, the GLR drift
//! test) in a separate "Extra" group; columns are noise (exponential, Laplace) × attack
//! (I, II) × per-step precision, recall, F1 (eq:precision, eq:recall, eq:F1); each cell is
//! `mean ± std` over seeds with the sample standard deviation (divisor `n − 1`). The paper's
//! published numbers follow in a separate, labelled block, for comparison only.
//!
//! Output is deterministic: rows are sorted by cell, method rank and seed; numbers in tables
//! have fixed decimals; CSV and JSON print `f64` in shortest round-trip form. Wall-clock
//! timings vary between runs, so they go to `timings.csv`, never into `results.csv` or
//! `results.json` (docs/decisions/061-results-files.md).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::cell::{AttackModel, Cell, NoiseModel, TABLE_COLUMNS, UavModel};
use crate::io::{IoError, write_text_atomic};
use crate::methods::{Method, MethodGroup, by_name};
use crate::metrics::{MeanStd, MetricsError};

/// Version of the `results.json` layout; bump it when a field changes.
pub const RESULTS_FORMAT_VERSION: u32 = 1;

/// A table could not be built or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TableError {
    /// Two results for the same (cell, method, seed).
    #[error("duplicate result for {cell} / {method} / seed {seed}")]
    Duplicate {
        /// The cell.
        cell: Cell,
        /// The method.
        method: Method,
        /// The seed.
        seed: u64,
    },
    /// A result holds a value outside its range (NaN, infinite, a rate outside [0, 1]).
    #[error("{cell} / {method} / seed {seed}: field `{field}` = {value} is out of range")]
    Value {
        /// The cell.
        cell: Cell,
        /// The method.
        method: Method,
        /// The seed.
        seed: u64,
        /// The field name.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A results file has another format version than this build reads.
    #[error("{}: results format version {got}, this build reads {expected}", path.display())]
    Version {
        /// The file.
        path: PathBuf,
        /// Version this build reads.
        expected: u32,
        /// Version found.
        got: u32,
    },
    /// A results file could not be parsed.
    #[error("{}: {msg}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong (with line and field where the parser knows them).
        msg: String,
    },
    /// Summarising over seeds failed.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
    /// Writing an output file failed.
    #[error(transparent)]
    Io(#[from] IoError),
}

/// Result alias of this module.
pub type Result<T, E = TableError> = std::result::Result<T, E>;

// ---------------------------------------------------------------------------------------------
// Method order.

/// Sort key of a method: its position in the registry's table order ([`Method::ALL`]), which
/// keeps every group together.
fn method_key(method: Method) -> usize {
    method.rank()
}

// ---------------------------------------------------------------------------------------------
// The paper's numbers.

/// One row of a published table: `values[c] = [P, R, F1]` for column `c` of [`TABLE_COLUMNS`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperRow {
    /// The method.
    pub method: Method,
    /// Precision, recall, F1 per column.
    pub values: [[f64; 3]; 4],
}

/// The paper's numbers, for comparison only: Table I (Model I), copied from
/// tab:comprehensive_analysis1 of the paper's LaTeX source. Never used as results.
pub const PAPER_TABLE_I: [PaperRow; 7] = [
    PaperRow {
        method: Method::Cusum,
        values: [[0.69, 0.64, 0.66], [0.71, 0.59, 0.64], [0.70, 0.62, 0.66], [0.71, 0.58, 0.64]],
    },
    PaperRow {
        method: Method::Sprt,
        values: [[0.69, 0.67, 0.69], [0.68, 0.68, 0.67], [0.69, 0.67, 0.68], [0.68, 0.67, 0.67]],
    },
    PaperRow {
        method: Method::Bht,
        values: [[0.62, 0.65, 0.64], [0.68, 0.60, 0.65], [0.66, 0.59, 0.62], [0.70, 0.60, 0.65]],
    },
    PaperRow {
        method: Method::Svm,
        values: [[0.88, 0.82, 0.85], [0.75, 0.69, 0.72], [0.88, 0.82, 0.85], [0.75, 0.69, 0.72]],
    },
    PaperRow {
        method: Method::Cnn,
        values: [[0.89, 0.81, 0.85], [0.90, 0.78, 0.84], [0.90, 0.84, 0.87], [0.90, 0.78, 0.84]],
    },
    PaperRow {
        method: Method::Lstm,
        values: [[0.88, 0.78, 0.83], [0.78, 0.86, 0.82], [0.86, 0.84, 0.85], [0.81, 0.85, 0.83]],
    },
    PaperRow {
        method: Method::QuadFormer,
        values: [[0.92, 0.93, 0.93], [0.89, 0.95, 0.92], [0.92, 0.94, 0.93], [0.89, 0.95, 0.92]],
    },
];

/// The paper's numbers, for comparison only: Table II (Model II), copied from
/// tab:comprehensive_analysis2 of the paper's LaTeX source. Never used as results.
pub const PAPER_TABLE_II: [PaperRow; 7] = [
    PaperRow {
        method: Method::Cusum,
        values: [[0.75, 0.76, 0.76], [0.73, 0.70, 0.72], [0.73, 0.69, 0.71], [0.72, 0.69, 0.71]],
    },
    PaperRow {
        method: Method::Sprt,
        values: [[0.75, 0.77, 0.76], [0.74, 0.77, 0.74], [0.74, 0.73, 0.73], [0.73, 0.70, 0.71]],
    },
    PaperRow {
        method: Method::Bht,
        values: [[0.70, 0.72, 0.72], [0.75, 0.71, 0.73], [0.75, 0.70, 0.72], [0.69, 0.72, 0.71]],
    },
    PaperRow {
        method: Method::Svm,
        values: [[0.94, 0.76, 0.84], [0.94, 0.61, 0.74], [0.94, 0.75, 0.83], [0.93, 0.61, 0.74]],
    },
    PaperRow {
        method: Method::Cnn,
        values: [[0.93, 0.73, 0.82], [0.94, 0.70, 0.80], [0.96, 0.67, 0.79], [0.85, 0.72, 0.78]],
    },
    PaperRow {
        method: Method::Lstm,
        values: [[0.89, 0.80, 0.84], [0.90, 0.75, 0.82], [0.81, 0.83, 0.82], [0.89, 0.74, 0.81]],
    },
    PaperRow {
        method: Method::QuadFormer,
        values: [[0.92, 0.97, 0.94], [0.89, 0.94, 0.91], [0.91, 0.96, 0.94], [0.89, 0.97, 0.93]],
    },
];

fn paper_rows(model: UavModel) -> &'static [PaperRow; 7] {
    match model {
        UavModel::I => &PAPER_TABLE_I,
        UavModel::II => &PAPER_TABLE_II,
    }
}

// ---------------------------------------------------------------------------------------------
// Results.

/// Every deterministic metric of one (cell, method, seed) run: one row of `results.csv` and
/// `results.json`, and the result of a cached run (whose wall-clock times sit beside it, in
/// [`TimingRow`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResultRow {
    /// UAV model of the cell.
    pub model: UavModel,
    /// Noise shape of the cell.
    pub noise: NoiseModel,
    /// Attack model of the cell.
    pub attack: AttackModel,
    /// The method, written by its table name.
    #[serde(with = "by_name")]
    pub method: Method,
    /// Experiment seed.
    pub seed: u64,
    /// Per-step precision on the test split (eq:precision).
    pub precision: f64,
    /// Per-step recall on the test split (eq:recall).
    pub recall: f64,
    /// Per-step F1 on the test split (eq:F1).
    pub f1: f64,
    /// ROC AUC of the scores on the test split.
    pub roc_auc: f64,
    /// PR AUC (average precision) of the scores on the test split.
    pub pr_auc: f64,
    /// Median detection delay over detected attack intervals in seconds; empty when none.
    pub delay_median_s: Option<f64>,
    /// 90th-percentile detection delay in seconds; empty when no interval was detected.
    pub delay_p90_s: Option<f64>,
    /// Number of attack intervals in the test split.
    pub n_intervals: u64,
    /// Attack intervals without any alarm.
    pub n_missed: u64,
    /// False-alarm events per minute of clean flight.
    pub false_alarms_per_min: f64,
    /// Number of test residue steps.
    pub n_test_steps: u64,
    /// Streaming per-step precision (each step scored by the window that ends at it, at the
    /// streaming threshold chosen on validation); learning methods only.
    #[serde(default)]
    pub stream_precision: Option<f64>,
    /// Streaming per-step recall; learning methods only.
    #[serde(default)]
    pub stream_recall: Option<f64>,
    /// Streaming per-step F1; learning methods only.
    #[serde(default)]
    pub stream_f1: Option<f64>,
}

impl ResultRow {
    /// The cell of this result.
    pub fn cell(&self) -> Cell {
        Cell { model: self.model, noise: self.noise, attack: self.attack }
    }

    /// Checks that rates are in [0, 1] and every number is finite and non-negative.
    ///
    /// # Errors
    /// [`TableError::Value`] naming the first bad field.
    pub fn check(&self) -> Result<()> {
        for (field, v) in [
            ("precision", self.precision),
            ("recall", self.recall),
            ("f1", self.f1),
            ("roc_auc", self.roc_auc),
            ("pr_auc", self.pr_auc),
            ("stream_precision", self.stream_precision.unwrap_or(0.0)),
            ("stream_recall", self.stream_recall.unwrap_or(0.0)),
            ("stream_f1", self.stream_f1.unwrap_or(0.0)),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(self.bad(field, v));
            }
        }
        for (field, v) in [
            ("delay_median_s", self.delay_median_s.unwrap_or(0.0)),
            ("delay_p90_s", self.delay_p90_s.unwrap_or(0.0)),
            ("false_alarms_per_min", self.false_alarms_per_min),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(self.bad(field, v));
            }
        }
        Ok(())
    }

    fn bad(&self, field: &'static str, value: f64) -> TableError {
        TableError::Value { cell: self.cell(), method: self.method, seed: self.seed, field, value }
    }

    fn sort_key(&self) -> (Cell, usize, u64) {
        (self.cell(), method_key(self.method), self.seed)
    }
}

/// One row of `timings.csv`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingRow {
    /// UAV model.
    pub model: UavModel,
    /// Noise shape.
    pub noise: NoiseModel,
    /// Attack model.
    pub attack: AttackModel,
    /// The method, by its table name.
    #[serde(with = "by_name")]
    pub method: Method,
    /// Experiment seed.
    pub seed: u64,
    /// Training wall time in seconds.
    pub train_s: f64,
    /// Scoring wall time in seconds.
    pub score_s: f64,
}

impl TimingRow {
    /// The timings of the run whose result is `r`.
    #[must_use]
    pub fn of(r: &ResultRow, train_s: f64, score_s: f64) -> Self {
        Self { model: r.model, noise: r.noise, attack: r.attack, method: r.method, seed: r.seed, train_s, score_s }
    }

    /// Checks that both times are finite and non-negative.
    ///
    /// # Errors
    /// [`TableError::Value`] naming the bad field.
    pub fn check(&self) -> Result<()> {
        for (field, value) in [("train_s", self.train_s), ("score_s", self.score_s)] {
            if !(value.is_finite() && value >= 0.0) {
                let cell = Cell { model: self.model, noise: self.noise, attack: self.attack };
                return Err(TableError::Value { cell, method: self.method, seed: self.seed, field, value });
            }
        }
        Ok(())
    }
}

/// The `results.json` file: a versioned list of rows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResultsFile {
    /// [`RESULTS_FORMAT_VERSION`] of the writer.
    pub format_version: u32,
    /// Rows in table order.
    pub results: Vec<ResultRow>,
}

/// Checks every result, rejects duplicates and returns them in table order (cell, method
/// rank, seed).
///
/// # Errors
/// [`TableError::Value`] or [`TableError::Duplicate`].
pub fn sorted(results: &[ResultRow]) -> Result<Vec<&ResultRow>> {
    for r in results {
        r.check()?;
    }
    let mut out: Vec<&ResultRow> = results.iter().collect();
    out.sort_by_key(|r| r.sort_key());
    for w in out.windows(2) {
        if w[0].sort_key() == w[1].sort_key() {
            return Err(TableError::Duplicate { cell: w[0].cell(), method: w[0].method, seed: w[0].seed });
        }
    }
    Ok(out)
}

/// `results.csv`: a header and one row per (cell, method, seed), in table order.
///
/// # Errors
/// As [`sorted`].
pub fn results_csv(results: &[ResultRow]) -> Result<String> {
    to_csv(&sorted(results)?)
}

/// `timings.csv`: wall-clock times per (cell, method, seed), in table order.
///
/// # Errors
/// [`TableError::Value`] for a time that is not finite and non-negative.
pub fn timings_csv(timings: &[TimingRow]) -> Result<String> {
    for t in timings {
        t.check()?;
    }
    let mut rows: Vec<&TimingRow> = timings.iter().collect();
    rows.sort_by_key(|t| (Cell { model: t.model, noise: t.noise, attack: t.attack }, method_key(t.method), t.seed));
    to_csv(&rows)
}

pub(crate) fn to_csv<T: Serialize>(rows: &[T]) -> Result<String> {
    let mut w = csv::WriterBuilder::new().terminator(csv::Terminator::Any(b'\n')).from_writer(Vec::new());
    let csv_err = |e: csv::Error| TableError::Parse { path: PathBuf::from("<csv>"), msg: e.to_string() };
    for row in rows {
        w.serialize(row).map_err(csv_err)?;
    }
    let bytes = w.into_inner().map_err(|e| TableError::Parse { path: PathBuf::from("<csv>"), msg: e.to_string() })?;
    String::from_utf8(bytes).map_err(|e| TableError::Parse { path: PathBuf::from("<csv>"), msg: e.to_string() })
}

/// `results.json`: [`ResultsFile`] pretty-printed, rows in table order.
///
/// # Errors
/// As [`sorted`].
pub fn results_json(results: &[ResultRow]) -> Result<String> {
    let file = ResultsFile {
        format_version: RESULTS_FORMAT_VERSION,
        results: sorted(results)?.into_iter().cloned().collect(),
    };
    let mut s = serde_json::to_string_pretty(&file)
        .map_err(|e| TableError::Parse { path: PathBuf::from("<json>"), msg: e.to_string() })?;
    s.push('\n');
    Ok(s)
}

/// Reads a `results.json` file.
///
/// # Errors
/// [`TableError::Parse`] with line and column, [`TableError::Version`] on another format
/// version, [`TableError::Io`] when the file cannot be read.
pub fn read_results_json(path: &Path) -> Result<ResultsFile> {
    let text =
        std::fs::read_to_string(path).map_err(|source| IoError::Fs { path: path.to_owned(), op: "read", source })?;
    // Read the version first so that a newer file gives a version error, not a field error.
    #[derive(Deserialize)]
    struct Version {
        format_version: u32,
    }
    let parse_err = |e: serde_json::Error| TableError::Parse {
        path: path.to_owned(),
        msg: format!("line {} column {}: {e}", e.line(), e.column()),
    };
    let v: Version = serde_json::from_str(&text).map_err(parse_err)?;
    if v.format_version != RESULTS_FORMAT_VERSION {
        return Err(TableError::Version {
            path: path.to_owned(),
            expected: RESULTS_FORMAT_VERSION,
            got: v.format_version,
        });
    }
    serde_json::from_str(&text).map_err(parse_err)
}

/// Reads a `results.csv` file.
///
/// # Errors
/// [`TableError::Parse`] naming the line, [`TableError::Io`] when the file cannot be read.
pub fn read_results_csv(path: &Path) -> Result<Vec<ResultRow>> {
    let mut r =
        csv::Reader::from_path(path).map_err(|e| TableError::Parse { path: path.to_owned(), msg: e.to_string() })?;
    let mut rows = Vec::new();
    for row in r.deserialize() {
        rows.push(row.map_err(|e: csv::Error| TableError::Parse { path: path.to_owned(), msg: e.to_string() })?);
    }
    Ok(rows)
}

// ---------------------------------------------------------------------------------------------
// Summaries over seeds.

/// Mean ± std over seeds of every metric of one (cell, method).
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// The cell.
    pub cell: Cell,
    /// The method.
    pub method: Method,
    /// Number of seeds.
    pub n_seeds: usize,
    /// Per-step precision.
    pub precision: MeanStd,
    /// Per-step recall.
    pub recall: MeanStd,
    /// Per-step F1.
    pub f1: MeanStd,
    /// ROC AUC.
    pub roc_auc: MeanStd,
    /// PR AUC.
    pub pr_auc: MeanStd,
    /// Median detection delay (over seeds where some interval was detected).
    pub delay_median_s: Option<MeanStd>,
    /// 90th-percentile detection delay (idem).
    pub delay_p90_s: Option<MeanStd>,
    /// Missed intervals over all intervals, summed over seeds.
    pub missed: (u64, u64),
    /// False alarms per minute of clean flight.
    pub false_alarms_per_min: MeanStd,
    /// Streaming F1 (learning methods, over the seeds that have it).
    pub stream_f1: Option<MeanStd>,
}

/// Summaries of every (cell, method) in table order.
///
/// # Errors
/// As [`sorted`].
pub fn summarise(results: &[ResultRow]) -> Result<Vec<Summary>> {
    let mut groups: BTreeMap<(Cell, usize), Vec<&ResultRow>> = BTreeMap::new();
    for r in sorted(results)? {
        groups.entry((r.cell(), method_key(r.method))).or_default().push(r);
    }
    let mut out = Vec::with_capacity(groups.len());
    for ((cell, _), rs) in groups {
        let method = rs[0].method;
        let col = |f: fn(&ResultRow) -> f64| rs.iter().map(|r| f(r)).collect::<Vec<f64>>();
        let opt = |f: fn(&ResultRow) -> Option<f64>| -> Result<Option<MeanStd>> {
            let v: Vec<f64> = rs.iter().filter_map(|r| f(r)).collect();
            Ok(if v.is_empty() { None } else { Some(MeanStd::new("optional metric", &v)?) })
        };
        out.push(Summary {
            cell,
            method,
            n_seeds: rs.len(),
            precision: MeanStd::new("precision", &col(|r| r.precision))?,
            recall: MeanStd::new("recall", &col(|r| r.recall))?,
            f1: MeanStd::new("f1", &col(|r| r.f1))?,
            roc_auc: MeanStd::new("roc_auc", &col(|r| r.roc_auc))?,
            pr_auc: MeanStd::new("pr_auc", &col(|r| r.pr_auc))?,
            delay_median_s: opt(|r| r.delay_median_s)?,
            delay_p90_s: opt(|r| r.delay_p90_s)?,
            missed: (rs.iter().map(|r| r.n_missed).sum(), rs.iter().map(|r| r.n_intervals).sum()),
            false_alarms_per_min: MeanStd::new("false_alarms_per_min", &col(|r| r.false_alarms_per_min))?,
            stream_f1: opt(|r| r.stream_f1)?,
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Rendering.

/// Placeholder of a table cell without results.
const MISSING: &str = "–";

/// The reproduced rows of one table: method → `[P, R, F1]` summaries per column.
struct Grid<'a> {
    rows: Vec<(Method, MethodGroup, [Option<&'a Summary>; 4])>,
    seed_counts: Vec<usize>,
}

fn grid(summaries: &[Summary], model: UavModel) -> Grid<'_> {
    let mut rows: Vec<(Method, MethodGroup, [Option<&Summary>; 4])> = Vec::new();
    let mut seed_counts = Vec::new();
    let mut methods: Vec<Method> = summaries.iter().filter(|s| s.cell.model == model).map(|s| s.method).collect();
    methods.sort_by_key(|m| method_key(*m));
    methods.dedup();
    for m in methods {
        let mut cols = [None; 4];
        for (c, (noise, attack)) in TABLE_COLUMNS.iter().enumerate() {
            let cell = Cell { model, noise: *noise, attack: *attack };
            cols[c] = summaries.iter().find(|s| s.cell == cell && s.method == m);
            if let Some(s) = cols[c] {
                seed_counts.push(s.n_seeds);
            }
        }
        if cols.iter().any(Option::is_some) {
            rows.push((m, m.group(), cols));
        }
    }
    seed_counts.sort_unstable();
    seed_counts.dedup();
    Grid { rows, seed_counts }
}

fn seeds_phrase(counts: &[usize]) -> String {
    match counts {
        [] => "no runs".to_owned(),
        [1] => "1 seed (no spread)".to_owned(),
        [n] => format!("{n} seeds"),
        [lo, .., hi] => format!("{lo} to {hi} seeds (varies by cell)"),
    }
}

fn arabic(model: UavModel) -> u8 {
    match model {
        UavModel::I => 1,
        UavModel::II => 2,
    }
}

const MD_HEADER: &str = "| Group | Method | Exp A-I P | Exp A-I R | Exp A-I F1 | Exp A-II P | Exp A-II R | Exp A-II F1 \
     | Lap A-I P | Lap A-I R | Lap A-I F1 | Lap A-II P | Lap A-II R | Lap A-II F1 |\n\
     |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";

/// Table I (`UavModel::I`) or II (`UavModel::II`) as Markdown: the reproduction, then the
/// paper's numbers in a separate labelled block.
///
/// # Errors
/// As [`summarise`].
pub fn table_markdown(results: &[ResultRow], model: UavModel) -> Result<String> {
    let summaries = summarise(results)?;
    let g = grid(&summaries, model);
    let n = model.roman();
    let mut s = String::new();
    // Writing to a String cannot fail.
    let _ = writeln!(s, "## Table {n}: comparison results for Model {n}\n");
    let _ = writeln!(
        s,
        "Per-step precision (P), recall (R) and F1 on the test flights, without point adjustment; \
         mean ± sample standard deviation (n − 1) over {}.",
        seeds_phrase(&g.seed_counts)
    );
    let _ = writeln!(
        s,
        "Columns: noise (Exp = exponential, Lap = Laplace) × attack (A-I = Attack I, sparse; A-II = Attack II, persistent).\n"
    );
    s.push_str(MD_HEADER);
    let mut prev_group = None;
    for (method, group, cols) in &g.rows {
        let label = if prev_group == Some(*group) { "" } else { group.label() };
        prev_group = Some(*group);
        let _ = write!(s, "| {label} | {} |", md_escape(method.name()));
        for c in cols {
            match c {
                Some(sm) => {
                    let _ = write!(s, " {} | {} | {} |", sm.precision, sm.recall, sm.f1);
                }
                None => {
                    let _ = write!(s, " {MISSING} | {MISSING} | {MISSING} |");
                }
            }
        }
        s.push('\n');
    }
    let _ = writeln!(s, "\n### Paper's numbers (Table {n} of the paper), for comparison only\n");
    let _ = writeln!(s, "Published values, copied from the paper; not produced by this code.\n");
    s.push_str(MD_HEADER);
    let mut prev_group = None;
    for row in paper_rows(model) {
        let group = row.method.group();
        let label = if prev_group == Some(group) { "" } else { group.label() };
        prev_group = Some(group);
        let _ = write!(s, "| {label} | {} |", row.method);
        for col in &row.values {
            let _ = write!(s, " {:.2} | {:.2} | {:.2} |", col[0], col[1], col[2]);
        }
        s.push('\n');
    }
    Ok(s)
}

fn md_escape(s: &str) -> String {
    s.replace('|', "\\|")
}

fn tex_escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '%' | '&' | '#' | '$' | '_' | '{' | '}' => {
                out.push('\\');
                out.push(ch);
            }
            '\\' => out.push_str("\\textbackslash{}"),
            '~' => out.push_str("\\textasciitilde{}"),
            '^' => out.push_str("\\textasciicircum{}"),
            _ => out.push(ch),
        }
    }
    out
}

fn tex_head(s: &mut String, model: UavModel, caption: &str, label: &str) {
    let n = model.roman();
    let _ = writeln!(s, "\\begin{{table*}}[h]\n\\centering\n\\caption{{{caption}}}\n\\label{{{label}}}");
    let _ = writeln!(s, "\\bgroup\n\\renewcommand{{\\arraystretch}}{{1.5}}\n\\scriptsize");
    let _ = writeln!(
        s,
        "\\begin{{tabularx}}{{\\textwidth}}{{|c|c|*{{12}}{{>{{\\centering\\arraybackslash}}X|}}}}\n\\hline"
    );
    let _ =
        writeln!(s, "\\multirow{{3}}{{*}}{{System Model}} & UAV Model & \\multicolumn{{12}}{{c|}}{{Model {n}}} \\\\");
    let _ = writeln!(s, "\\cline{{2-14}}");
    let _ = writeln!(
        s,
        " & Noise Model & \\multicolumn{{6}}{{c|}}{{Exponential Noise}} & \\multicolumn{{6}}{{c|}}{{Laplacian Noise}} \\\\"
    );
    let _ = writeln!(s, "\\cline{{2-14}}");
    let _ = writeln!(
        s,
        " & Attack Model & \\multicolumn{{3}}{{c|}}{{Attack I}} & \\multicolumn{{3}}{{c|}}{{Attack II}} \
         & \\multicolumn{{3}}{{c|}}{{Attack I}} & \\multicolumn{{3}}{{c|}}{{Attack II}} \\\\"
    );
    let _ = writeln!(s, "\\hline");
    let _ = writeln!(s, "Performance & Metric & P & R & F1 & P & R & F1 & P & R & F1 & P & R & F1 \\\\\n\\hline");
}

fn tex_tail(s: &mut String) {
    let _ = writeln!(s, "\\end{{tabularx}}\n\\egroup\n\\end{{table*}}");
}

/// Writes grouped rows: `\multirow` group label on the first row of each group.
fn tex_rows(s: &mut String, rows: &[(MethodGroup, String, Vec<String>)]) {
    let mut i = 0;
    while i < rows.len() {
        let group = rows[i].0;
        let len = rows[i..].iter().take_while(|r| r.0 == group).count();
        for (j, (_, method, cells)) in rows[i..i + len].iter().enumerate() {
            let label =
                if j == 0 { format!("\\multirow{{{len}}}{{*}}{{{}}}", group.latex_label()) } else { String::new() };
            let _ = writeln!(s, "{label} & {method} & {} \\\\", cells.join(" & "));
            let _ = writeln!(s, "{}", if j + 1 == len { "\\hline" } else { "\\cline{2-14}" });
        }
        i += len;
    }
}

/// Table I or II as LaTeX (`tabularx`, `multirow`), in the paper's layout: the reproduction,
/// then the paper's numbers as a second, labelled table.
///
/// # Errors
/// As [`summarise`].
pub fn table_latex(results: &[ResultRow], model: UavModel) -> Result<String> {
    let summaries = summarise(results)?;
    let g = grid(&summaries, model);
    let n = model.roman();
    let mut s = String::new();
    let _ = writeln!(s, "% Table {n}, generated by eval::table from the run results; do not edit by hand.");
    let _ = writeln!(s, "% Needs \\usepackage{{multirow}} and \\usepackage{{tabularx}}.");
    let caption = format!(
        "Comparison Results for Model {n} (this reproduction; per-step P, R, F1 without point adjustment, \
         mean $\\pm$ sample std over {}).",
        seeds_phrase(&g.seed_counts)
    );
    tex_head(&mut s, model, &caption, &format!("tab:reproduced_model{}", arabic(model)));
    let fmt = |m: &MeanStd| match m.std {
        Some(sd) => format!("${:.2} \\pm {:.2}$", m.mean, sd),
        None => format!("${:.2}$", m.mean),
    };
    let rows: Vec<(MethodGroup, String, Vec<String>)> = g
        .rows
        .iter()
        .map(|(method, group, cols)| {
            let cells = cols
                .iter()
                .flat_map(|c| match c {
                    Some(sm) => [fmt(&sm.precision), fmt(&sm.recall), fmt(&sm.f1)],
                    None => ["--".to_owned(), "--".to_owned(), "--".to_owned()],
                })
                .collect();
            (*group, tex_escape(method.name()), cells)
        })
        .collect();
    tex_rows(&mut s, &rows);
    tex_tail(&mut s);
    s.push('\n');
    let caption = format!("Published numbers of the paper for Model {n} (its Table {n}), for comparison only.");
    tex_head(&mut s, model, &caption, &format!("tab:paper_model{}", arabic(model)));
    let rows: Vec<(MethodGroup, String, Vec<String>)> = paper_rows(model)
        .iter()
        .map(|row| {
            let cells = row.values.iter().flat_map(|c| c.map(|v| format!("{v:.2}"))).collect();
            (row.method.group(), row.method.name().to_owned(), cells)
        })
        .collect();
    tex_rows(&mut s, &rows);
    tex_tail(&mut s);
    Ok(s)
}

/// The other metrics (ROC AUC, PR AUC, detection delay, missed intervals, false alarms per
/// minute) of every (cell, method) as one Markdown table, mean ± std over seeds.
///
/// # Errors
/// As [`summarise`].
pub fn metrics_markdown(results: &[ResultRow]) -> Result<String> {
    let mut s = String::new();
    s.push_str(
        "| Cell | Method | ROC AUC | PR AUC | Delay median (s) | Delay p90 (s) | Missed / intervals | False alarms / min |\n\
         |---|---|---:|---:|---:|---:|---:|---:|\n",
    );
    let opt = |m: &Option<MeanStd>| m.map_or_else(|| MISSING.to_owned(), |m| m.to_string());
    for sm in summarise(results)? {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} / {} | {} |",
            sm.cell,
            md_escape(sm.method.name()),
            sm.roc_auc,
            sm.pr_auc,
            opt(&sm.delay_median_s),
            opt(&sm.delay_p90_s),
            sm.missed.0,
            sm.missed.1,
            sm.false_alarms_per_min,
        );
    }
    Ok(s)
}

/// Offline against streaming F1 of the learning methods, both models, as one Markdown table:
/// offline is the Tables I/II figure (each step scored from windows that see past and future),
/// streaming scores each step by the window that ends at it, as `OnlineDetector` and `fuse` do.
///
/// # Errors
/// As [`summarise`].
pub fn streaming_markdown(results: &[ResultRow]) -> Result<String> {
    let summaries = summarise(results)?;
    let mut s = String::new();
    let _ = writeln!(s, "## Streaming against offline F1 of the learning methods\n");
    let _ = writeln!(
        s,
        "Per-step F1 on the test flights, offline / streaming, mean ± sample standard deviation over \
         seeds. Offline is the figure of Tables I and II; streaming scores every step as the newest of \
         its window (causal, what `OnlineDetector` and `quadformer fuse` use), at a threshold chosen on \
         the validation split's streaming scores.\n"
    );
    s.push_str("| Model | Method | Exp A-I | Exp A-II | Lap A-I | Lap A-II |\n|---|---|---|---|---|---|\n");
    for model in [UavModel::I, UavModel::II] {
        let g = grid(&summaries, model);
        for (method, _, cols) in &g.rows {
            if cols.iter().all(|c| c.is_none_or(|sm| sm.stream_f1.is_none())) {
                continue;
            }
            let _ = write!(s, "| {} | {} |", model.roman(), md_escape(method.name()));
            for c in cols {
                match c.and_then(|sm| sm.stream_f1.map(|st| (sm.f1, st))) {
                    Some((off, st)) => {
                        let _ = write!(s, " {off} / {st} |");
                    }
                    None => {
                        let _ = write!(s, " {MISSING} |");
                    }
                }
            }
            s.push('\n');
        }
    }
    Ok(s)
}

/// Writes `table1.{md,tex}`, `table2.{md,tex}`, `streaming.md`, `metrics.md`, `results.csv`,
/// `results.json` and `timings.csv` into `out_dir` (created if missing), each atomically; returns the paths
/// in that order.
///
/// # Errors
/// As [`summarise`]; [`TableError::Io`] when a file cannot be written.
pub fn write_outputs(out_dir: &Path, results: &[ResultRow], timings: &[TimingRow]) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir).map_err(|source| IoError::Fs {
        path: out_dir.to_owned(),
        op: "create directory",
        source,
    })?;
    let files = [
        ("table1.md", table_markdown(results, UavModel::I)?),
        ("table1.tex", table_latex(results, UavModel::I)?),
        ("table2.md", table_markdown(results, UavModel::II)?),
        ("table2.tex", table_latex(results, UavModel::II)?),
        ("streaming.md", streaming_markdown(results)?),
        ("metrics.md", metrics_markdown(results)?),
        ("results.csv", results_csv(results)?),
        ("results.json", results_json(results)?),
        ("timings.csv", timings_csv(timings)?),
    ];
    let mut paths = Vec::with_capacity(files.len());
    for (name, text) in files {
        let path = out_dir.join(name);
        write_text_atomic(&path, &text)?;
        paths.push(path);
    }
    Ok(paths)
}
