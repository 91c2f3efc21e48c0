//! `quadformer dataset`: builds (or loads from a cache) one labelled dataset cell of the
//! experiment matrix (simulate → attack → EKF, paper alg:alg1, eq:ekf_update; split by flight,
//! decision 031) and writes it as residue CSV files, so a user sees exactly what the detectors
//! are trained, validated and tested on.
//!
//! Layout of `--out DIR` (written atomically: a temporary sibling directory renamed into place):
//! `DIR/{train,valid,test}/flight-NNN.csv` (residue files, docs/data-format.md "Residue file";
//! `NNN` is the flight's index in its split, zero-padded to three digits) and `DIR/dataset.json`
//! (cell, seed, dataset key, per-split counts and which training flights are labelled).
//! Validation and test flights carry a `label` column; of the training flights only the
//! labelled subset (`--labelled-fraction`, default 0.1, decision 031) does, the
//! others are written without one, exactly as the detectors see them (decision 080).

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::cell::Cell;
use crate::cli::CliError;
use crate::dataset::{Dataset, Split, SplitSummary, ValidDatasetConfig, build, load_or_build};
use crate::io::{
    CovarianceLayout, Input, IoError, Output, Overwrite, check_dir_output, check_outputs, write_dir_atomic,
    write_residues, write_text_atomic,
};
use crate::reproduce::{MatrixConfig, dataset_config};

/// Name of the summary file in a dataset directory.
pub const DATASET_FILE: &str = "dataset.json";

/// Arguments of `quadformer dataset`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Cell of the experiment matrix: m1|m2 - gaussian|exponential|laplace - a1|a2, e.g.
    /// `m1-exponential-a1` (UAV Model I, exponential GPS noise, Attack I).
    #[arg(long)]
    pub cell: String,
    /// CI-sized cell (3,000 / 1,000 / 1,000 residue steps, 60 s flights) instead of the
    /// paper's (83,700 / 18,700 / 18,700 steps, 150 s flights).
    #[arg(long)]
    pub quick: bool,
    /// Dataset seed (routes, sensor noise, attacks and the labelled subset derive from it).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Fraction of training flights whose labels are written (the rest have no label column).
    #[arg(long, value_name = "F", default_value_t = 0.1)]
    pub labelled_fraction: f64,
    /// Cache directory: the cell is loaded from it when a valid cache file exists, else built
    /// and cached there (the same cache `reproduce-tables` keeps under `OUT/datasets`).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Output directory (must not exist or be empty, unless `--force`).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Replace a non-empty output directory.
    #[arg(long)]
    pub force: bool,
}

/// The `dataset.json` summary written next to the residue files.
#[derive(Debug, Serialize)]
struct DatasetSummary<'a> {
    /// Cell slug, e.g. `m1-exponential-a1`.
    cell: String,
    /// Dataset seed.
    seed: u64,
    /// Whether the CI-sized configuration was used.
    quick: bool,
    /// SHA-256 key of the dataset configuration (the cache key).
    key: &'a str,
    /// Channels of every residue file.
    channels: Vec<String>,
    /// Fraction of training flights written with labels.
    labelled_fraction: f64,
    /// Indices of the training flights written with labels.
    labelled_train_flights: Vec<usize>,
    /// Per-split counts (true labels, including those of unlabelled training flights).
    train: SplitSummary,
    /// Validation counts.
    valid: SplitSummary,
    /// Test counts.
    test: SplitSummary,
}

/// File name of flight `index` of a split.
pub fn flight_file(index: usize) -> String {
    format!("flight-{index:03}.csv")
}

/// Runs `quadformer dataset`.
///
/// # Errors
/// [`CliError::Input`] for an unknown cell or a bad fraction, [`CliError::Run`] when building
/// the dataset fails (naming split and flight), [`CliError::Io`] when writing fails.
pub fn run(args: &Args) -> Result<(), CliError> {
    let input = |msg: String| CliError::Input { path: args.out.clone(), msg };
    let overwrite = if args.force { Overwrite::Replace } else { Overwrite::Refuse };
    let cache: Vec<Input<'_>> = args.cache.as_deref().map(|p| Input::new("--cache", p)).into_iter().collect();
    check_outputs(&cache, &[Output::dir("--out", &args.out)])?;
    check_dir_output(&args.out, overwrite)?;
    let cell = Cell::parse(&args.cell).map_err(|e| input(format!("--cell: {e}")))?;
    if !(args.labelled_fraction.is_finite() && (0.0..=1.0).contains(&args.labelled_fraction)) {
        return Err(input(format!("--labelled-fraction must be in [0, 1], got {}", args.labelled_fraction)));
    }
    let matrix = if args.quick { MatrixConfig::quick() } else { MatrixConfig::default() };
    let mut cfg = dataset_config(cell, args.seed, &matrix, args.quick);
    cfg.labelled_fraction = args.labelled_fraction;
    let cfg = cfg.check().map_err(|e| input(format!("dataset configuration: {e}")))?;
    let data = load(&cfg, args.cache.as_deref())?;

    let labelled = data.labelled_train_indices(args.labelled_fraction);
    write_dir_atomic(&args.out, overwrite, |dir| {
        for split in Split::ALL {
            for f in data.flights(split) {
                let keep = split != Split::Train || labelled.binary_search(&f.meta.index).is_ok();
                let path = dir.join(split.name()).join(flight_file(f.meta.index));
                write_residues(&path, f.series(), keep.then(|| f.labels()), CovarianceLayout::Upper)?;
            }
        }
        let summary = DatasetSummary {
            cell: cell.slug(),
            seed: args.seed,
            quick: args.quick,
            key: data.key(),
            channels: data.flights(Split::Valid).first().map(|f| f.series().channels().to_vec()).unwrap_or_default(),
            labelled_fraction: args.labelled_fraction,
            labelled_train_flights: labelled.clone(),
            train: data.summary(Split::Train),
            valid: data.summary(Split::Valid),
            test: data.summary(Split::Test),
        };
        let path = dir.join(DATASET_FILE);
        let json = serde_json::to_string_pretty(&summary)
            .map_err(|e| IoError::Inconsistent { path: path.clone(), msg: format!("cannot serialise: {e}") })?;
        write_text_atomic(&path, &json)
    })?;
    for split in Split::ALL {
        let s = data.summary(split);
        eprintln!(
            "{}/{}: {} flights, {} residue steps, {} attacked{}",
            args.out.display(),
            split,
            s.flights,
            s.steps,
            s.attacked,
            if split == Split::Train { format!(", {} flights labelled", labelled.len()) } else { String::new() }
        );
    }
    Ok(())
}

/// Builds the dataset, or loads it from (and caches it in) `cache`.
fn load(cfg: &ValidDatasetConfig, cache: Option<&Path>) -> Result<Dataset, CliError> {
    match cache {
        Some(dir) => {
            let (data, outcome) = load_or_build(cfg, dir).map_err(|e| CliError::Run(e.to_string()))?;
            eprintln!("dataset cache: {outcome:?}");
            Ok(data)
        }
        None => build(cfg).map_err(|e| CliError::Run(e.to_string())),
    }
}
