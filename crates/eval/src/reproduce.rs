//! `reproduce-tables`: the paper's experiment matrix (Model I/II × exponential/Laplace noise ×
//! Attack I/II, tab:comprehensive_analysis1 and tab:comprehensive_analysis2) for every method and
//! seed, from runs alone, and every output derived from it: Tables I and II, raw results, ROC
//! plots, the CUSUM post-attack figure (the paper's fig:CUSUM_3_plots), the F1-versus-amplitude
//! sweep, ablations and a report.
//!
//! The stages share one output directory: datasets are cached under `datasets/`, finished runs
//! under `runs/`, so an interrupted run resumes where it stopped and a rerun with the same
//! configuration only re-renders the outputs.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use attack_inject::AmplitudeConfig;
use ekf_residue::residues::MODEL2_VO_CHANNELS;
use ekf_residue::{Detector, LabelledResidues};
use nn_toolkit::Features;
use quadformer_model::Prior;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cell::{AttackModel, Cell, NoiseModel, UavModel};
use crate::dataset::{Dataset, DatasetConfig, Split, SplitSteps, build_split, load_or_build};
use crate::io::write_text_atomic;
use crate::methods::{Method, MethodConfigs};
use crate::metrics::{MeanStd, RocCurve};
use crate::plot::{StatisticTrace, SweepSeries, f1_amplitude_plot, roc_plot, statistic_plot};
use crate::runner::{ModeMetrics, RunError, RunRecord, Splits, evaluate_split, fit, run_one, score_split};
use crate::table::{ResultRow, write_outputs};

/// Errors of `reproduce-tables`, each naming the stage and cell.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReproduceError {
    /// Building or loading a dataset failed.
    #[error("dataset {cell}: {source}")]
    Dataset {
        /// The cell.
        cell: String,
        /// The dataset error.
        source: crate::dataset::DatasetError,
    },
    /// A run failed.
    #[error(transparent)]
    Run(#[from] RunError),
    /// Writing tables failed.
    #[error(transparent)]
    Table(#[from] crate::table::TableError),
    /// Drawing a plot failed.
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// Writing a file failed.
    #[error(transparent)]
    Io(#[from] crate::io::IoError),
    /// A metric could not be computed.
    #[error("{what}: {source}")]
    Metrics {
        /// Which figure or table.
        what: String,
        /// The metric error.
        source: crate::metrics::MetricsError,
    },
    /// Bad options or config.
    #[error("{0}")]
    Config(String),
}

/// Result alias of this module.
pub type Result<T, E = ReproduceError> = std::result::Result<T, E>;

/// Which residue channels the Model II cells use; every report says which
/// (docs/decisions/003-model2-channels.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Model2Channels {
    /// The 6-D VO innovation stacked with the 3-D GPS innovation (default).
    #[default]
    VoGps,
    /// The paper's 6-D VO innovation only (the PX4 gate, which needs GPS channels, is skipped).
    Vo,
}

/// Everything `reproduce-tables` can be configured with (`--config FILE.toml`); every field has
/// a default, so a file names only what it changes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MatrixConfig {
    /// Hyper-parameters of every method.
    pub methods: MethodConfigs,
    /// Residue steps per split. Default: paper scale (83,700 / 18,700 / 18,700).
    pub steps: SplitSteps,
    /// Fraction of training flights with labels. Default 0.1 (docs/decisions/031).
    pub labelled_fraction: f64,
    /// Model II channels. Default VO + GPS.
    pub model2_channels: Model2Channels,
    /// Amplitudes of the F1-versus-amplitude sweep in GPS σ; empty switches the sweep off.
    /// Default 0.5 to 10 σ (docs/decisions/005-sweep-and-ablations.md).
    pub sweep_sigma: Vec<f64>,
    /// Label fractions of the semi-supervision ablation. Default 1%, 10%, 100% (decision 005).
    pub ablation_fractions: Vec<f64>,
    /// Candidates of the closed loop's alarm confirmation, consecutive raw alarms before an
    /// alarm stands; each fitted detector flies its validation flights at each and keeps the
    /// best, or the quietest near it with `loop_f1_tolerance`
    /// ([`crate::closed_loop::loop_setting`]). Default `[1, 2]`: every raw alarm, or two in a
    /// row (docs/decisions/091-closed-loop.md).
    pub loop_confirm: Vec<usize>,
    /// Candidates of the closed loop's score smoothing: the number of earlier scores a fitted
    /// detector's loop score averages with the newest one (`ekf_residue::TrailingMean`); each
    /// fitted detector flies its validation flights at each with each `loop_confirm` and keeps
    /// the best (as for `loop_confirm`). 0 is the detector's streaming score. Default `[0, 2]` (decision 091).
    pub loop_smooth: Vec<usize>,
    /// How far below the best validation F1 the closed loop's setting may fall to raise fewer
    /// alarm events per clean minute of the validation flights: of the candidates within it,
    /// the quietest is chosen ([`crate::closed_loop::loop_setting`]). Default none: the best
    /// F1 (docs/decisions/091-closed-loop.md).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub loop_f1_tolerance: Option<f64>,
    /// Whether the closed loop's QUADFormer attends causally (`NetConfig::causal`): every
    /// position of its training windows is a decision on the past, as every decision in the
    /// loop is. Tables I and II keep `methods.quadformer` as it is. Default `true`, chosen on
    /// the loop's validation flights (docs/decisions/092-causal-loop-quadformer.md).
    pub loop_causal: bool,
    /// The networks' input features in the closed loop (`WindowConfig::features`); Tables I
    /// and II keep those of `methods`.
    pub loop_features: LoopFeatures,
}

/// The input features of the learning methods in the closed loop (`MatrixConfig::loop_features`).
///
/// Defaults chosen on the loop's validation flights: QUADFormer and the LSTM read the
/// absorbed-offset channels (docs/decisions/095-absorbed-offset-channels.md), the CNN the
/// per-step features (docs/decisions/094-drift-channel.md).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopFeatures {
    /// QUADFormer's. Default `WhitenedLogDriftAbsorbed`.
    pub quadformer: Features,
    /// The CNN's. Default `WhitenedLog`.
    pub cnn: Features,
    /// The LSTM's. Default `WhitenedLogDriftAbsorbed`.
    pub lstm: Features,
}

impl Default for LoopFeatures {
    fn default() -> Self {
        Self {
            quadformer: Features::WhitenedLogDriftAbsorbed,
            cnn: Features::WhitenedLog,
            lstm: Features::WhitenedLogDriftAbsorbed,
        }
    }
}

impl Default for MatrixConfig {
    fn default() -> Self {
        Self {
            methods: MethodConfigs::full(),
            steps: SplitSteps::PAPER,
            labelled_fraction: 0.1,
            model2_channels: Model2Channels::VoGps,
            sweep_sigma: vec![0.5, 1.0, 2.0, 3.0, 5.0, 10.0],
            ablation_fractions: vec![0.01, 0.1, 1.0],
            loop_confirm: vec![1, 2],
            loop_smooth: vec![0, 2],
            loop_f1_tolerance: None,
            loop_causal: true,
            loop_features: LoopFeatures::default(),
        }
    }
}

impl MatrixConfig {
    /// The `--quick` configuration: CI-sized data and small models; a smoke test of the
    /// pipeline whose numbers are not results.
    pub fn quick() -> Self {
        Self {
            methods: MethodConfigs::quick(),
            steps: SplitSteps::QUICK,
            sweep_sigma: vec![1.0, 5.0],
            ablation_fractions: vec![0.1, 1.0],
            // The quick networks read the per-step features, in the loop too (decision 094).
            loop_features: LoopFeatures {
                quadformer: Features::WhitenedLog,
                cnn: Features::WhitenedLog,
                lstm: Features::WhitenedLog,
            },
            ..Self::default()
        }
    }

    /// Reads a TOML file whose keys override `base` (nested tables key by key, see
    /// [`crate::io::merge_over`]), so a file names only what it changes.
    ///
    /// # Errors
    /// [`ReproduceError::Config`] naming the file and the offending field.
    pub fn from_toml_file(path: &Path, base: &Self) -> Result<Self> {
        let err = |msg: String| ReproduceError::Config(format!("{}: {msg}", path.display()));
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("cannot read: {e}")))?;
        let user: toml::Table = text.parse().map_err(|e: toml::de::Error| err(e.to_string()))?;
        let mut merged = toml::Table::try_from(base).map_err(|e| err(e.to_string()))?;
        crate::io::merge_over(&mut merged, user);
        let cfg: Self = merged.try_into().map_err(|e: toml::de::Error| err(e.message().trim().to_owned()))?;
        cfg.check_loop().map_err(err)?;
        Ok(cfg)
    }

    /// Checks the closed loop's candidates before any work starts: at least one confirmation
    /// and one smoothing candidate, no confirmation of 0 raw alarms, and an F1 tolerance that
    /// is finite and at least 0.
    ///
    /// # Errors
    /// A message naming the field.
    pub fn check_loop(&self) -> std::result::Result<(), String> {
        if self.loop_confirm.is_empty() || self.loop_confirm.contains(&0) {
            return Err(format!("loop_confirm: needs candidates of at least 1 raw alarm, got {:?}", self.loop_confirm));
        }
        if self.loop_smooth.is_empty() {
            return Err("loop_smooth: needs at least one candidate".into());
        }
        if let Some(tol) = self.loop_f1_tolerance.filter(|t| !(t.is_finite() && *t >= 0.0)) {
            return Err(format!("loop_f1_tolerance: must be finite and at least 0, got {tol}"));
        }
        Ok(())
    }
}

/// Options of one `reproduce-tables` invocation.
#[derive(Debug, Clone, PartialEq)]
pub struct Options {
    /// The configuration.
    pub config: MatrixConfig,
    /// Quick mode (changes dataset sizes for cells and the flight length).
    pub quick: bool,
    /// Number of seeds (0, 1, …, seeds − 1).
    pub seeds: u64,
    /// Cells to run.
    pub cells: Vec<Cell>,
    /// Methods to run.
    pub methods: Vec<Method>,
    /// Output directory.
    pub out: PathBuf,
    /// Show progress bars.
    pub progress: bool,
    /// Which experiments run.
    pub stages: Stages,
}

/// Which experiments `reproduce-tables` runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Stages {
    /// Tables I and II with their studies, then the closed loop (Table III).
    #[default]
    All,
    /// Tables I and II with their studies only.
    Tables,
    /// The closed loop (Table III) only.
    ClosedLoop,
}

/// The dataset configuration of `cell` at `seed`.
pub fn dataset_config(cell: Cell, seed: u64, cfg: &MatrixConfig, quick: bool) -> DatasetConfig {
    let (model, noise, attack) = (cell.model.kind(), cell.noise.shape(), cell.attack.kind());
    let base =
        if quick { DatasetConfig::quick(model, noise, attack) } else { DatasetConfig::paper(model, noise, attack) };
    DatasetConfig { steps: cfg.steps, labelled_fraction: cfg.labelled_fraction, seed, ..base }
}

/// The three splits of a loaded dataset, restricted to the channels of the experiment.
pub struct CellSplits {
    /// Training split.
    pub train: LabelledResidues,
    /// Validation split.
    pub valid: LabelledResidues,
    /// Test split.
    pub test: LabelledResidues,
}

impl CellSplits {
    fn from_dataset(cell: Cell, data: &Dataset, cfg: &MatrixConfig, fraction: f64) -> Result<Self> {
        let err = |source| ReproduceError::Dataset { cell: cell.slug(), source };
        let mut s = Self {
            train: data.train_with_labelled_fraction(fraction).map_err(err)?,
            valid: data.valid().map_err(err)?,
            test: data.test().map_err(err)?,
        };
        if cell.model == UavModel::II && cfg.model2_channels == Model2Channels::Vo {
            let pick = |split: &LabelledResidues| {
                split.select_channels(&MODEL2_VO_CHANNELS).map_err(|e| ReproduceError::Config(format!("{cell}: {e}")))
            };
            s = Self { train: pick(&s.train)?, valid: pick(&s.valid)?, test: pick(&s.test)? };
        }
        Ok(s)
    }

    /// The identity of the training data for run caching: dataset key, labelled fraction and
    /// channels.
    fn data_key(data: &Dataset, cfg: &MatrixConfig, fraction: f64) -> String {
        format!("{}/labelled={fraction}/model2={:?}", data.key(), cfg.model2_channels)
    }

    fn splits(&self) -> Splits<'_> {
        Splits { train: &self.train, valid: &self.valid, test: &self.test }
    }
}

/// Loads (or builds and caches) the dataset of `cell` at `seed`.
///
/// # Errors
/// [`ReproduceError::Dataset`].
pub fn load_cell(cell: Cell, seed: u64, opts: &Options) -> Result<Dataset> {
    let cfg = dataset_config(cell, seed, &opts.config, opts.quick);
    let err = |source| ReproduceError::Dataset { cell: cell.slug(), source };
    let valid = cfg.check().map_err(err)?;
    let (data, _) = load_or_build(&valid, &opts.out.join("datasets")).map_err(err)?;
    Ok(data)
}

/// Whether `method` can run on `cell` with this configuration.
fn applicable(method: Method, cell: Cell, cfg: &MatrixConfig) -> bool {
    !(method.needs_gps() && cell.model == UavModel::II && cfg.model2_channels == Model2Channels::Vo)
}

/// Fitted detectors kept from the matrix for the studies, by method.
pub type KeptFits = Vec<(Method, Box<dyn Detector>)>;

/// Runs every `(seed, cell, method)` of the options (cached runs are reused), in parallel over
/// `(seed, cell)` units, and returns the records sorted by cell, method and seed.
///
/// # Errors
/// The first failing stage.
pub fn run_matrix(opts: &Options) -> Result<Vec<RunRecord>> {
    run_matrix_keeping(opts, None).map(|(records, _)| records)
}

/// [`run_matrix`], also returning the detectors fitted (not loaded from the cache) for the unit
/// `keep = (cell, seed)`, so that the amplitude sweep scores with the matrix's own fits.
///
/// # Errors
/// The first failing stage.
pub fn run_matrix_keeping(opts: &Options, keep: Option<(Cell, u64)>) -> Result<(Vec<RunRecord>, KeptFits)> {
    let units: Vec<(u64, Cell)> = (0..opts.seeds).flat_map(|s| opts.cells.iter().map(move |c| (s, *c))).collect();
    let n_runs = units.len() * opts.methods.len();
    let bar = crate::progress::Progress::new(n_runs as u64, opts.progress, "runs");
    let cache_dir = opts.out.join("runs");
    let kept = std::sync::Mutex::new(KeptFits::new());
    let records: Vec<Vec<RunRecord>> = units
        .par_iter()
        .map(|&(seed, cell)| {
            bar.set_message(format!("{} seed {seed}: dataset", cell.slug()));
            let data = load_cell(cell, seed, opts)?;
            let splits = CellSplits::from_dataset(cell, &data, &opts.config, opts.config.labelled_fraction)?;
            let data_key = CellSplits::data_key(&data, &opts.config, opts.config.labelled_fraction);
            let mut out = Vec::new();
            for &method in &opts.methods {
                if !applicable(method, cell, &opts.config) {
                    bar.finish_unit(&format!("{} seed {seed}: {} does not apply", cell.slug(), method.name()));
                    continue;
                }
                bar.set_message(format!("{} seed {seed}: {}", cell.slug(), method.name()));
                let (rec, fitted) =
                    run_one(&cache_dir, &data_key, cell, method, seed, &opts.config.methods, splits.splits())?;
                if let Some(det) = fitted
                    && keep == Some((cell, seed))
                    && let Ok(mut kept) = kept.lock()
                {
                    kept.push((method, det));
                }
                bar.finish_unit(&format!("{} seed {seed}: {}", cell.slug(), method.name()));
                out.push(rec);
            }
            Ok(out)
        })
        .collect::<Result<_>>()?;
    bar.finish();
    let mut records: Vec<RunRecord> = records.into_iter().flatten().collect();
    // By cell, method name and seed (the order of the ROC curves in each figure).
    records.sort_by(|a, b| {
        (a.result.cell(), a.result.method.name(), a.result.seed).cmp(&(
            b.result.cell(),
            b.result.method.name(),
            b.result.seed,
        ))
    });
    let kept = kept.into_inner().unwrap_or_default();
    Ok((records, kept))
}

/// Draws one ROC figure per cell from the seed-0 runs.
///
/// # Errors
/// [`ReproduceError::Plot`].
pub fn write_roc_plots(out: &Path, records: &[RunRecord]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let mut cells: Vec<Cell> = records.iter().map(|r| r.result.cell()).collect();
    cells.dedup();
    for cell in cells {
        let runs: Vec<&RunRecord> = records.iter().filter(|r| r.result.cell() == cell && r.result.seed == 0).collect();
        let curves: Vec<(String, RocCurve)> = runs
            .iter()
            .filter_map(|r| {
                RocCurve::from_fpr_tpr(&r.roc, r.result.roc_auc, r.result.pr_auc)
                    .ok()
                    .map(|c| (r.result.method.name().to_owned(), c))
            })
            .collect();
        if curves.is_empty() {
            continue;
        }
        let refs: Vec<(&str, &RocCurve)> = curves.iter().map(|(n, c)| (n.as_str(), c)).collect();
        let stem = out.join("figures").join(format!("roc-{}", cell.slug()));
        files.extend(roc_plot(&stem, &format!("ROC, {cell} (test split, seed 0)"), &refs)?);
    }
    Ok(files)
}

/// The paper's fig:CUSUM_3_plots effect, measured: CUSUM fitted on the Model I, Attack II
/// (persistent) cell at seed 0, run over the test flight with the longest constant-bias attack;
/// returns the figure files and the number of alarm steps within 20 s after attacks end.
///
/// # Errors
/// Any stage's error.
pub fn cusum_post_attack(opts: &Options) -> Result<(Vec<PathBuf>, String)> {
    let cell = Cell { model: UavModel::I, noise: NoiseModel::Exponential, attack: AttackModel::II };
    let data = load_cell(cell, 0, opts)?;
    let splits = CellSplits::from_dataset(cell, &data, &opts.config, opts.config.labelled_fraction)?;
    let cfgs = opts.config.methods.seeded(0);
    let fitted = fit(Method::Cusum, &cfgs, &splits.train, &splits.valid)?;
    // The test flight with the most attacked steps shows the effect best.
    let Some(flight) =
        splits.test.flights().iter().max_by_key(|f| f.labels().map_or(0, |l| l.iter().filter(|&&a| a).count()))
    else {
        return Err(ReproduceError::Config("Model I Attack II test split is empty".into()));
    };
    let labels = flight.labels().unwrap_or_default();
    let series = flight.series();
    let stat = fitted.detector.score(series).map_err(|source| RunError::Score { method: "CUSUM", source })?;
    let threshold = fitted.detector.threshold();
    let t = series.t();
    // Alarms in the 20 s after each attack interval ends.
    let mut post_alarms = 0usize;
    let mut post_steps = 0usize;
    let mut last_end: Option<f64> = None;
    for k in 0..labels.len() {
        if k > 0 && labels[k - 1] && !labels[k] {
            last_end = Some(t[k]);
        }
        if let Some(end) = last_end
            && !labels[k]
            && t[k] - end <= 20.0
        {
            post_steps += 1;
            if stat[k] > threshold {
                post_alarms += 1;
            }
        }
    }
    let alarms: Vec<bool> = stat.iter().map(|&v| v > threshold).collect();
    let stem = opts.out.join("figures").join("cusum-post-attack");
    let files = statistic_plot(
        &stem,
        "CUSUM statistic, Model I, persistent GPS attack (test flight, seed 0)",
        "CUSUM S_k",
        StatisticTrace { t, statistic: &stat, threshold, attacks: &attack_spans(t, labels), alarms: Some(&alarms) },
    )?;
    let note = format!(
        "CUSUM alarmed on {post_alarms} of the {post_steps} clean steps within 20 s after an attack ended \
         (threshold {threshold:.3}, chosen on validation)."
    );
    Ok((files, note))
}

/// Attack intervals `[start_s, end_s)` of per-step labels (the end is the first clean step's time,
/// or the last step's time for an attack running to the end).
fn attack_spans(t: &[f64], labels: &[bool]) -> Vec<(f64, f64)> {
    crate::metrics::attack_intervals(labels)
        .into_iter()
        .map(|iv| (t[iv.start], t.get(iv.end).copied().unwrap_or_else(|| t[t.len() - 1])))
        .collect()
}

/// One point of the amplitude sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepPoint {
    /// Method name.
    pub method: String,
    /// Amplitude in GPS σ.
    pub sigma: f64,
    /// Per-step F1 on the sweep's test split.
    pub f1: f64,
}

/// The cell of the amplitude sweep and the ablations: Model I, exponential noise, Attack I
/// (their dataset is [`STUDY_CELL`] at seed 0, loaded once by [`reproduce`]).
pub const STUDY_CELL: Cell = Cell { model: UavModel::I, noise: NoiseModel::Exponential, attack: AttackModel::I };

/// F1 against attack amplitude: every method fitted once on `data` ([`STUDY_CELL`] at seed 0;
/// thresholds from its validation split) scores test splits whose attacks all have one fixed
/// amplitude (`sigma` × GPS σ); no refitting per amplitude. The matrix's own fits of that unit
/// are used where given in `fitted` (the others are fitted here). Each amplitude's test split
/// is the cell's test flights attacked at that amplitude, built alone ([`build_split`]).
///
/// # Errors
/// Any stage's error.
pub fn amplitude_sweep(opts: &Options, data: &Dataset, fitted: KeptFits) -> Result<(Vec<SweepPoint>, Vec<PathBuf>)> {
    let cell = STUDY_CELL;
    let splits = CellSplits::from_dataset(cell, data, &opts.config, opts.config.labelled_fraction)?;
    let cfgs = opts.config.methods.seeded(0);
    let missing: Vec<Method> = opts
        .methods
        .iter()
        .copied()
        .filter(|m| applicable(*m, cell, &opts.config) && !fitted.iter().any(|(f, _)| f == m))
        .collect();
    // Fit the missing methods and build every amplitude's test split, in parallel.
    let fits = missing.par_iter().map(|&m| Ok((m, fit(m, &cfgs, &splits.train, &splits.valid)?.detector)));
    let tests = opts.config.sweep_sigma.par_iter().map(|&sigma| -> Result<(f64, LabelledResidues)> {
        let mut cfg = dataset_config(cell, 0, &opts.config, opts.quick);
        cfg.attack.amplitude = AmplitudeConfig::Fixed { sigma_multiple: sigma };
        let err = |source| ReproduceError::Dataset { cell: format!("{} at {sigma} sigma", cell.slug()), source };
        let valid_cfg = cfg.check().map_err(err)?;
        Ok((sigma, build_split(&valid_cfg, Split::Test).map_err(err)?))
    });
    let (fits, tests): (Result<KeptFits>, Result<Vec<_>>) = rayon::join(|| fits.collect(), || tests.collect());
    let (mut fitted, tests) = (fitted, tests?);
    fitted.extend(fits?);
    fitted.sort_by_key(|(m, _)| opts.methods.iter().position(|o| o == m));
    let pairs: Vec<(usize, usize)> = (0..tests.len()).flat_map(|t| (0..fitted.len()).map(move |f| (t, f))).collect();
    let points = pairs
        .par_iter()
        .map(|&(t, f)| {
            let ((sigma, test), (method, det)) = (&tests[t], &fitted[f]);
            let scored = score_split(*method, det.as_ref(), test)?;
            let e = evaluate_split(test, &scored.scores, &scored.alarms, method.name(), cell)?;
            Ok(SweepPoint { method: method.name().to_owned(), sigma: *sigma, f1: e.f1() })
        })
        .collect::<Result<Vec<_>>>()?;
    let mut series: Vec<(String, Vec<(f64, MeanStd)>)> = Vec::new();
    for (method, _) in &fitted {
        let pts = points
            .iter()
            .filter(|p| p.method == method.name())
            .map(|p| MeanStd::new("F1", &[p.f1]).map(|m| (p.sigma, m)))
            .collect::<Result<_, _>>()
            .map_err(|source| ReproduceError::Metrics { what: "sweep".into(), source })?;
        series.push((method.name().to_owned(), pts));
    }
    let refs: Vec<SweepSeries<'_>> = series.iter().map(|(l, p)| SweepSeries { label: l, points: p }).collect();
    let stem = opts.out.join("figures").join("f1-vs-amplitude");
    // An empty `sweep_sigma` switches the sweep off: nothing to draw.
    let files = if points.is_empty() {
        Vec::new()
    } else {
        f1_amplitude_plot(
            &stem,
            "F1 against attack amplitude (Model I, exponential noise, Attack I; test split, seed 0)",
            "attack amplitude (GPS sigma)",
            &refs,
        )?
    };
    Ok((points, files))
}

/// The semi-supervision ablation: learning methods retrained with each of the configured
/// fractions (1%, 10% and 100%) of the training flights labelled, on `data` ([`STUDY_CELL`] at
/// seed 0); returns `(fraction, result)` rows. The matrix's own labelled fraction is skipped
/// unless `with_matrix_fraction`: the matrix already runs it ([`reproduce`] takes its rows).
///
/// # Errors
/// Any stage's error.
pub fn label_fraction_ablation(
    opts: &Options,
    data: &Dataset,
    with_matrix_fraction: bool,
) -> Result<Vec<(f64, ResultRow)>> {
    let cell = STUDY_CELL;
    let cache = opts.out.join("runs");
    let splits = opts
        .config
        .ablation_fractions
        .iter()
        .filter(|&&f| with_matrix_fraction || f != opts.config.labelled_fraction)
        .map(|&f| {
            Ok((f, CellSplits::from_dataset(cell, data, &opts.config, f)?, CellSplits::data_key(data, &opts.config, f)))
        })
        .collect::<Result<Vec<_>>>()?;
    let jobs: Vec<(&(f64, CellSplits, String), Method)> =
        splits.iter().flat_map(|s| opts.methods.iter().filter(|m| m.is_learning()).map(move |&m| (s, m))).collect();
    jobs.par_iter()
        .map(|((fraction, splits, data_key), m)| {
            let (rec, _) = run_one(&cache, data_key, cell, *m, 0, &opts.config.methods, splits.splits())?;
            Ok((*fraction, rec.result))
        })
        .collect()
}

/// The variants of the QUADFormer architecture ablation: `(name, TPC on, DCM on)`.
const ARCHITECTURES: [(&str, bool, bool); 3] = [("full", true, true), ("no TPC", false, true), ("no DCM", true, false)];

/// The QUADFormer architecture ablation: TPC prior and DCM cross-layer attention switched off
/// in turn, on `data` ([`STUDY_CELL`] at seed 0). The full network is the matrix's own run and
/// is skipped unless `with_full`.
///
/// # Errors
/// Any stage's error.
pub fn architecture_ablation(opts: &Options, data: &Dataset, with_full: bool) -> Result<Vec<(String, ResultRow)>> {
    let cell = STUDY_CELL;
    let splits = CellSplits::from_dataset(cell, data, &opts.config, opts.config.labelled_fraction)?;
    let cache = opts.out.join("runs");
    let data_key = CellSplits::data_key(data, &opts.config, opts.config.labelled_fraction);
    ARCHITECTURES
        .par_iter()
        .filter(|(_, tpc, dcm)| with_full || !(*tpc && *dcm))
        .map(|&(name, tpc, dcm)| {
            let mut cfgs = opts.config.methods.clone();
            cfgs.quadformer.net.prior = if tpc { Prior::Tpc } else { Prior::Gaussian };
            cfgs.quadformer.net.dcm = dcm;
            let (rec, _) = run_one(&cache, &data_key, cell, Method::QuadFormer, 0, &cfgs, splits.splits())?;
            Ok((name.to_owned(), rec.result))
        })
        .collect()
}

/// Runs everything and writes every output; returns the paths written.
///
/// The label-fraction and architecture ablations run alongside the matrix, sharing its
/// thread pool, so that neither waits for the other's last job. When the matrix includes the
/// study unit ([`STUDY_CELL`] at seed 0), the ablations take its rows for the default labelled
/// fraction and the full network, and the amplitude sweep scores with its fitted detectors,
/// instead of repeating those fits.
///
/// # Errors
/// The first failing stage.
pub fn reproduce(opts: &Options) -> Result<Vec<PathBuf>> {
    nn_toolkit::tune_allocator();
    let start = Instant::now();
    std::fs::create_dir_all(&opts.out)
        .map_err(|e| ReproduceError::Config(format!("{}: cannot create: {e}", opts.out.display())))?;
    if opts.stages == Stages::ClosedLoop {
        return crate::closed_loop::closed_loop(opts).map(|(_, files)| files);
    }
    let matrix_has_study_unit = opts.cells.contains(&STUDY_CELL) && opts.seeds >= 1;
    let keep = (matrix_has_study_unit && !opts.config.sweep_sigma.is_empty()).then_some((STUDY_CELL, 0));
    let study_data = load_cell(STUDY_CELL, 0, opts)?;
    let with_own = !matrix_has_study_unit;
    let (matrix, (fractions, arch)) = rayon::join(
        || run_matrix_keeping(opts, keep),
        || {
            rayon::join(
                || label_fraction_ablation(opts, &study_data, with_own),
                || {
                    if opts.methods.contains(&Method::QuadFormer) {
                        architecture_ablation(opts, &study_data, with_own)
                    } else {
                        Ok(Vec::new())
                    }
                },
            )
        },
    );
    let (records, kept) = matrix?;
    let (mut fractions, mut arch) = (fractions?, arch?);
    let study_records: Vec<&RunRecord> =
        records.iter().filter(|r| r.result.cell() == STUDY_CELL && r.result.seed == 0).collect();
    if matrix_has_study_unit {
        let learning = |r: &&&RunRecord| r.result.method.is_learning() && opts.methods.contains(&r.result.method);
        if opts.config.ablation_fractions.contains(&opts.config.labelled_fraction) {
            fractions.extend(
                study_records.iter().filter(learning).map(|r| (opts.config.labelled_fraction, r.result.clone())),
            );
        }
        if let Some(qf) = study_records.iter().find(|r| r.result.method == Method::QuadFormer) {
            arch.push((ARCHITECTURES[0].0.to_owned(), qf.result.clone()));
        }
    }
    let method_rank = |m: Method| opts.methods.iter().position(|o| *o == m);
    fractions.sort_by(|a, b| a.0.total_cmp(&b.0).then(method_rank(a.1.method).cmp(&method_rank(b.1.method))));
    arch.sort_by_key(|(name, _)| ARCHITECTURES.iter().position(|(n, _, _)| n == name));

    let results: Vec<ResultRow> = records.iter().map(|r| r.result.clone()).collect();
    let timings: Vec<_> = records.iter().map(RunRecord::timing).collect();
    let mut files = write_outputs(&opts.out, &results, &timings)?;
    files.extend(write_roc_plots(&opts.out, &records)?);
    let mut report = String::new();
    let (cusum_files, cusum_note) = cusum_post_attack(opts)?;
    files.extend(cusum_files);
    let (sweep, sweep_files) = amplitude_sweep(opts, &study_data, kept)?;
    files.extend(sweep_files);
    let modes: &[ModeMetrics] =
        study_records.iter().find(|r| r.result.method == Method::QuadFormer).map_or(&[], |r| &r.modes);
    let closed = if opts.stages == Stages::All {
        let (rows, loop_files) = crate::closed_loop::closed_loop(opts)?;
        files.extend(loop_files);
        Some(rows)
    } else {
        None
    };
    let wall_s = start.elapsed().as_secs_f64();

    write_report(&mut report, opts, &records, &cusum_note, &sweep, modes, &fractions, &arch, wall_s);
    if let Some(rows) = &closed {
        crate::closed_loop::write_report_section(&mut report, rows);
    }
    let report_path = opts.out.join("report.md");
    write_text_atomic(&report_path, &report)?;
    files.push(report_path);
    Ok(files)
}

#[allow(clippy::too_many_arguments)]
fn write_report(
    s: &mut String,
    opts: &Options,
    records: &[RunRecord],
    cusum_note: &str,
    sweep: &[SweepPoint],
    modes: &[ModeMetrics],
    fractions: &[(f64, ResultRow)],
    arch: &[(String, ResultRow)],
    wall_s: f64,
) {
    let _ = writeln!(s, "# QUADFormer-rs: reproduced results\n");
    let mode = if opts.quick {
        "`--quick` (smoke test: small data and models; these numbers are not results)"
    } else {
        "full"
    };
    let _ = writeln!(
        s,
        "Mode: {mode}. Seeds: {}. Runs: {}. Wall time of this invocation: {wall_s:.0} s.",
        opts.seeds,
        records.len()
    );
    let _ = writeln!(
        s,
        "Model II channels: {}. Labelled fraction of training flights: {}.\n",
        match opts.config.model2_channels {
            Model2Channels::VoGps => "VO + GPS innovation (9 channels)",
            Model2Channels::Vo => "VO innovation only (6 channels, as the paper)",
        },
        opts.config.labelled_fraction
    );
    let _ = writeln!(
        s,
        "Every number here was produced by this run; thresholds and hyper-parameters were chosen on the validation split; metrics are per step without point adjustment.\n"
    );
    let _ = writeln!(s, "## Tables\n");
    let _ = writeln!(s, "- [Table I (Model I)](table1.md), [LaTeX](table1.tex)");
    let _ = writeln!(s, "- [Table II (Model II)](table2.md), [LaTeX](table2.tex)");
    let _ = writeln!(s, "- [Streaming against offline F1 of the learning methods](streaming.md)");
    let _ = writeln!(s, "- [All metrics: ROC AUC, PR AUC, detection delay, false alarms per minute](metrics.md)");
    let _ =
        writeln!(s, "- Raw: [results.csv](results.csv), [results.json](results.json), [timings.csv](timings.csv)\n");
    let _ = writeln!(s, "## ROC curves\n");
    let mut cells: Vec<Cell> = records.iter().map(|r| r.result.cell()).collect();
    cells.dedup();
    for cell in cells {
        let _ = writeln!(s, "- {cell}: [PNG](figures/roc-{0}.png), [SVG](figures/roc-{0}.svg)", cell.slug());
    }
    let _ = writeln!(s, "\n## CUSUM after a persistent attack (the paper's Fig. 9)\n");
    let _ = writeln!(s, "![CUSUM](figures/cusum-post-attack.png)\n\n{cusum_note}\n");
    let _ = writeln!(s, "## F1 against attack amplitude\n");
    let _ = writeln!(s, "![sweep](figures/f1-vs-amplitude.png)\n");
    let mut sigmas: Vec<f64> = Vec::new();
    for p in sweep {
        if !sigmas.contains(&p.sigma) {
            sigmas.push(p.sigma);
        }
    }
    let _ = write!(s, "| method |");
    for sg in &sigmas {
        let _ = write!(s, " {sg} σ |");
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "|---|{}", "---|".repeat(sigmas.len()));
    let mut methods: Vec<&str> = Vec::new();
    for p in sweep {
        if !methods.contains(&p.method.as_str()) {
            methods.push(&p.method);
        }
    }
    for m in methods {
        let _ = write!(s, "| {m} |");
        for sg in &sigmas {
            let f1 = sweep.iter().find(|p| p.method == m && p.sigma == *sg).map_or(f64::NAN, |p| p.f1);
            let _ = write!(s, " {f1:.3} |");
        }
        let _ = writeln!(s);
    }
    let _ =
        writeln!(s, "\n## Ablation: fraction of labelled training flights (Model I, exponential, Attack I, seed 0)\n");
    let _ = writeln!(s, "| method | labelled | P | R | F1 | ROC AUC |\n|---|---|---|---|---|---|");
    for (fraction, r) in fractions {
        let _ = writeln!(
            s,
            "| {} | {:.0}% | {:.3} | {:.3} | {:.3} | {:.3} |",
            r.method,
            fraction * 100.0,
            r.precision,
            r.recall,
            r.f1,
            r.roc_auc
        );
    }
    if !modes.is_empty() {
        let _ = writeln!(s, "\n## Ablation: QUADFormer score modes (Model I, exponential, Attack I, seed 0)\n");
        let _ =
            writeln!(s, "Each mode at its own validation threshold; the mode marked * is the one validation chose.\n");
        let _ = writeln!(s, "| mode | valid F1 | test F1 | test ROC AUC |\n|---|---|---|---|");
        for m in modes {
            let star = if m.chosen { " *" } else { "" };
            let _ = writeln!(s, "| {}{star} | {:.3} | {:.3} | {:.3} |", m.mode, m.valid_f1, m.test_f1, m.test_auc);
        }
    }
    write_mode_summary(s, records);
    if !arch.is_empty() {
        let _ = writeln!(s, "\n## Ablation: QUADFormer attention (Model I, exponential, Attack I, seed 0)\n");
        let _ = writeln!(s, "| variant | P | R | F1 | ROC AUC |\n|---|---|---|---|---|");
        for (name, r) in arch {
            let _ = writeln!(s, "| {name} | {:.3} | {:.3} | {:.3} | {:.3} |", r.precision, r.recall, r.f1, r.roc_auc);
        }
    }
}

/// The score-mode ablation over every QUADFormer run of the matrix: each mode's validation and
/// test F1 and test ROC AUC (mean ± std over runs), and how many runs validation chose it for.
fn write_mode_summary(s: &mut String, records: &[RunRecord]) {
    let runs: Vec<&RunRecord> = records.iter().filter(|r| !r.modes.is_empty()).collect();
    let Some(first) = runs.first() else { return };
    let _ = writeln!(s, "\n## Ablation: QUADFormer score modes over every cell and seed ({} runs)\n", runs.len());
    let _ = writeln!(
        s,
        "Mean ± std over runs, each mode at its own validation threshold (offline scores). \
         \"Chosen in\" counts the runs whose offline score validation chose the mode for, \
         \"streamed in\" those whose streaming detector it chose it for.\n"
    );
    let _ = writeln!(
        s,
        "| mode | chosen in | streamed in | valid F1 | test F1 | test ROC AUC |\n|---|---|---|---|---|---|"
    );
    for (i, m) in first.modes.iter().enumerate() {
        let of = |f: fn(&ModeMetrics) -> f64| -> Vec<f64> {
            runs.iter().filter_map(|r| r.modes.get(i)).filter(|x| x.mode == m.mode).map(f).collect()
        };
        let count = |f: fn(&ModeMetrics) -> bool| {
            runs.iter().filter(|r| r.modes.get(i).is_some_and(|x| x.mode == m.mode && f(x))).count()
        };
        let (chosen, streamed) = (count(|x| x.chosen), count(|x| x.streamed));
        let cell = |v: Vec<f64>| MeanStd::new(&m.mode, &v).map_or_else(|_| "–".to_owned(), |x| format!("{x:.3}"));
        let _ = writeln!(
            s,
            "| {} | {chosen} | {streamed} | {} | {} | {} |",
            m.mode,
            cell(of(|x| x.valid_f1)),
            cell(of(|x| x.test_f1)),
            cell(of(|x| x.test_auc))
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partial_config_file_overrides_only_its_keys() {
        let dir = std::env::temp_dir().join(format!("qf-matrix-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.toml");
        std::fs::write(&path, "labelled_fraction = 1.0\n[methods.quadformer.train]\nepochs = 7\n").unwrap();
        let c = MatrixConfig::from_toml_file(&path, &MatrixConfig::default()).unwrap();
        assert_eq!(c.labelled_fraction, 1.0);
        assert_eq!(c.methods.quadformer.train.epochs, 7);
        assert_eq!(c.methods.quadformer.window, MatrixConfig::default().methods.quadformer.window);
        std::fs::write(&path, "[methods.quadformer.train]\nepoch = 7\n").unwrap();
        let e = MatrixConfig::from_toml_file(&path, &MatrixConfig::default()).unwrap_err().to_string();
        assert!(e.contains("m.toml") && e.contains("epoch"), "{e}");
        for (text, field) in [
            ("loop_confirm = [1, 0]\n", "loop_confirm"),
            ("loop_confirm = []\n", "loop_confirm"),
            ("loop_smooth = []\n", "loop_smooth"),
            ("loop_f1_tolerance = -0.01\n", "loop_f1_tolerance"),
            ("loop_f1_tolerance = nan\n", "loop_f1_tolerance"),
        ] {
            std::fs::write(&path, text).unwrap();
            let e = MatrixConfig::from_toml_file(&path, &MatrixConfig::default()).unwrap_err().to_string();
            assert!(e.contains("m.toml") && e.contains(field), "{text}: {e}");
        }
        std::fs::write(&path, "loop_f1_tolerance = 0.02\n").unwrap();
        let c = MatrixConfig::from_toml_file(&path, &MatrixConfig::default()).unwrap();
        assert_eq!(c.loop_f1_tolerance, Some(0.02));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
