//! The `quadformer` command-line interface (docs/cli.md): one module per subcommand, each with
//! a clap `Args` struct and a `run` function returning [`CliError`].
//!
//! Subcommands so far: `simulate` (config TOML → flight directory) and `residues` (flight
//! directory → residue CSV, paper alg:alg1). To add one (`train`, `detect`, `fuse`,
//! `reproduce-tables`, `figures`): write `cli/<name>.rs` with `pub struct Args` (clap
//! derive, doc comments become `--help`) and `pub fn run(args: &Args) -> Result<(), CliError>`,
//! add a variant to [`Command`] and a line to [`run`], and, if needed, a [`CliError`] variant.
//!
//! Every subcommand keeps docs/cli.md "Safety rules": it checks its outputs against its inputs
//! with [`crate::io::check_outputs`] before any work, and writes only through
//! `crate::io::atomic`.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

use crate::io::IoError;

pub mod dataset;
pub mod detect;
pub mod figures;
pub mod fuse;
pub mod inject;
pub mod reproduce_tables;
pub mod residues;
pub mod simulate;
pub mod train;

/// QUADFormer-rs: simulate quadrotor flights, attack their GPS, compute EKF residues and
/// detect attacks (paper: "QUADFormer: Learning-based Detection of Cyber Attacks in Quadrotor
/// UAVs"). File formats: docs/data-format.md.
#[derive(Debug, Parser)]
#[command(name = "quadformer", version, propagate_version = true)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Simulate a flight from a TOML config and write its sensor streams, truth and attack
    /// labels as a flight directory.
    Simulate(simulate::Args),
    /// Run the Model I or Model II EKF on a flight directory (simulated or your own log) or a
    /// PX4 ULog and write the residue sequence r_k, S_k, NIS (and labels, if known) as CSV.
    Residues(residues::Args),
    /// Inject one GPS attack (bias, sparse, ramp, oscillating, replay, freeze) into a recorded
    /// flight (a PX4 ULog or a flight directory) and write a labelled flight directory.
    Inject(inject::Args),
    /// Run the paper's experiment matrix (Model I/II × exponential/Laplace noise × Attack I/II)
    /// for every method and write Tables I and II, ROC plots, sweeps, ablations and a report.
    ReproduceTables(reproduce_tables::Args),
    /// Build (or load from a cache) one labelled dataset cell and write its train, valid and
    /// test flights as residue CSV files.
    Dataset(dataset::Args),
    /// Fit a detection method on residue CSV files (thresholds chosen on the validation files)
    /// and save a model directory.
    Train(train::Args),
    /// Score a residue CSV with a trained model directory and write per-step scores and alarms.
    Detect(detect::Args),
    /// Fly the paper's closed-loop scenarios (no attack; attack without and with detection,
    /// Alg. 3) and write a metrics table and top-view plots.
    Fuse(fuse::Args),
    /// Run `fuse` for every scenario with the NIS gate and QUADFormer at 1 s and zero latency
    /// and write the combined table and plots under OUT/scenarios.
    Figures(figures::Args),
}

/// How a recorded flight is read, for every command that reads one (`residues`, `inject`,
/// `fuse --in`).
#[derive(Debug, Clone, clap::Args)]
pub struct FlightReadArgs {
    /// ULog input: drop GNSS fixes whose fix_type is below this (3 = 3-D fix, 0 keeps all).
    #[arg(long, value_name = "N", default_value_t = crate::io::DEFAULT_MIN_FIX_TYPE)]
    pub gps_min_fix: u8,
    /// Flight directory from another tool: its CSV column names mapped to the project's, as
    /// THEIRS=OURS pairs (`gx=gyro_x,gy=gyro_y`) or a TOML file of `THEIRS = "OURS"` lines.
    #[arg(long, value_name = "MAP|FILE.toml")]
    pub columns: Option<String>,
}

impl FlightReadArgs {
    /// Reads the flight at `path` (a flight directory or a PX4 ULog, `crate::io::read_flight`)
    /// and prints what its conversion reported.
    ///
    /// # Errors
    /// [`CliError`] naming the file, field or `--columns` entry.
    pub fn read(&self, path: &std::path::Path) -> Result<crate::io::FlightDir, CliError> {
        let ulog = crate::io::UlogOptions { min_fix_type: self.gps_min_fix };
        let loaded = crate::io::read_flight(path, &ulog, &column_map(self.columns.as_deref())?)?;
        for note in &loaded.notes {
            eprintln!("{}: {note}", path.display());
        }
        Ok(loaded.flight)
    }
}

/// The column map of a `--columns` value: a TOML file (`THEIRS = "OURS"` lines) when the value
/// names one, else `THEIRS=OURS` pairs separated by commas; empty without the flag.
///
/// # Errors
/// [`CliError::Input`] naming `--columns` or the file and the bad entry.
pub fn column_map(arg: Option<&str>) -> Result<crate::io::ColumnMap, CliError> {
    let Some(arg) = arg else { return Ok(crate::io::ColumnMap::default()) };
    let path = std::path::Path::new(arg);
    if std::path::Path::new(arg).extension().is_some_and(|e| e == "toml") {
        let text = crate::io::read_text(path)?;
        return crate::io::ColumnMap::parse_toml(&text)
            .map_err(|msg| CliError::Input { path: path.to_owned(), msg: format!("column map: {msg}") });
    }
    crate::io::ColumnMap::parse_pairs(arg).map_err(|msg| CliError::Input { path: PathBuf::from("--columns"), msg })
}

/// Runs a parsed command line.
///
/// # Errors
/// Whatever the subcommand reports; see [`CliError`].
pub fn run(cli: &Cli) -> Result<(), CliError> {
    match &cli.command {
        Command::Simulate(args) => simulate::run(args),
        Command::Residues(args) => residues::run(args),
        Command::Inject(args) => inject::run(args),
        Command::ReproduceTables(args) => reproduce_tables::run(args),
        Command::Dataset(args) => dataset::run(args),
        Command::Train(args) => train::run(args),
        Command::Detect(args) => detect::run(args),
        Command::Fuse(args) => fuse::run(args),
        Command::Figures(args) => figures::run(args),
    }
}

impl From<crate::model_dir::ModelDirError> for CliError {
    fn from(e: crate::model_dir::ModelDirError) -> Self {
        match e {
            crate::model_dir::ModelDirError::Io(e) => Self::Io(e),
            crate::model_dir::ModelDirError::Invalid { path, msg } => Self::Input { path, msg },
        }
    }
}

impl From<crate::scenarios::ScenarioError> for CliError {
    fn from(e: crate::scenarios::ScenarioError) -> Self {
        Self::Run(e.to_string())
    }
}

/// Errors of the command-line subcommands; each names the file or field concerned.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CliError {
    /// Reading or writing a file failed.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A config value is invalid.
    #[error("{}: {msg}", path.display())]
    Config {
        /// The config file.
        path: PathBuf,
        /// What is wrong, naming the field.
        msg: String,
    },
    /// The simulator failed.
    #[error("simulation failed: {0}")]
    Sim(#[from] uav_dynamics::Error),
    /// Attack planning or injection failed.
    #[error("attack injection failed: {0}")]
    Attack(#[from] attack_inject::AttackError),
    /// The input does not suit the requested operation (e.g. a stream the model needs is
    /// missing).
    #[error("{}: {msg}", path.display())]
    Input {
        /// The input file or directory.
        path: PathBuf,
        /// What is missing or wrong.
        msg: String,
    },
    /// An experiment stage failed (dataset, fit, scoring, metrics or output).
    #[error("{0}")]
    Run(String),
    /// The EKF failed on the input.
    #[error("{}: EKF failed: {msg}", path.display())]
    Filter {
        /// The flight directory.
        path: PathBuf,
        /// The filter's error, with step and time.
        msg: String,
    },
}
