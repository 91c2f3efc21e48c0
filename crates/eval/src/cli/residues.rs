//! `quadformer residues`: flight directory → residue CSV (paper alg:alg1; docs/data-format.md).

use std::path::PathBuf;

use crate::cli::CliError;
use crate::io::CovarianceLayout;

/// Which EKF model to run (paper sec:residue_generator).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelArg {
    /// Model I: 15 states, GPS position + attitude measurement (eq:model1f, eq:model1g).
    #[value(name = "I", alias = "1", alias = "i")]
    One,
    /// Model II: 21 states with a keyframe clone, VO relative pose (+ GPS) (eq:model2f, eq:model2g).
    #[value(name = "II", alias = "2", alias = "ii")]
    Two,
}

/// Storage of S_k in the residue file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum LayoutArg {
    /// Upper triangle, m(m+1)/2 columns.
    #[default]
    Upper,
    /// All m² entries.
    Full,
}

impl From<LayoutArg> for CovarianceLayout {
    fn from(l: LayoutArg) -> Self {
        match l {
            LayoutArg::Upper => Self::Upper,
            LayoutArg::Full => Self::Full,
        }
    }
}

/// Arguments of `quadformer residues`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// EKF model: I (GPS + attitude) or II (VO + GPS, keyframe cloning).
    #[arg(long, value_enum)]
    pub model: ModelArg,
    /// Flight directory: imu.csv plus the streams the model needs (I: gps.csv, attitude.csv;
    /// II: vo.csv, gps.csv); truth.csv and attack.csv are optional.
    #[arg(long = "in", value_name = "DIR")]
    pub input: PathBuf,
    /// Output residue CSV (written atomically).
    #[arg(long, value_name = "FILE.csv")]
    pub out: PathBuf,
    /// How to store S_k.
    #[arg(long, value_enum, default_value_t = LayoutArg::Upper)]
    pub covariance: LayoutArg,
    /// Do not write a label column even if attack.csv exists.
    #[arg(long)]
    pub no_labels: bool,
}

/// Runs `quadformer residues`.
///
/// # Errors
/// [`CliError`] naming the file, line and column of bad input, or the step where the EKF failed.
pub fn run(args: &Args) -> Result<(), CliError> {
    let _ = args;
    Err(CliError::Input { path: args.input.clone(), msg: "not available yet".into() })
}
