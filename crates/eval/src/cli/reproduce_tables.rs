//! `quadformer reproduce-tables`: runs the paper's experiment matrix and writes Tables I and II,
//! raw results, ROC plots, the CUSUM post-attack figure, the amplitude sweep, ablations and a
//! report (see [`crate::reproduce`]).

use std::path::PathBuf;

use crate::cli::CliError;
use crate::reproduce::{MatrixConfig, Options, parse_cell, reproduce, table_cells};
use crate::runner::Method;

/// Options of `reproduce-tables`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Small data, small models and one seed: a one-minute smoke test of the whole pipeline
    /// (used by CI); its numbers are not results.
    #[arg(long)]
    pub quick: bool,
    /// Number of seeds per (cell, method); results are mean ± std over them. Default 3 (1 with
    /// `--quick`).
    #[arg(long, value_name = "N")]
    pub seeds: Option<u64>,
    /// Only these cells (comma-separated slugs such as `m1-exponential-a1`, `m2-laplace-a2`).
    #[arg(long, value_name = "CELLS", value_delimiter = ',')]
    pub cells: Vec<String>,
    /// Only these methods (comma-separated, e.g. `quadformer,cusum,px4-gate`).
    #[arg(long, value_name = "METHODS", value_delimiter = ',')]
    pub methods: Vec<String>,
    /// Output directory (datasets and finished runs are cached inside it).
    #[arg(long, value_name = "DIR", default_value = "results")]
    pub out: PathBuf,
    /// Experiment configuration (TOML; every key optional, merged over the defaults of the
    /// chosen mode; see docs/cli.md).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Hide the progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

/// Runs the matrix and prints the files written.
///
/// # Errors
/// [`CliError::Input`] for a bad option or config; [`CliError::Run`] for a failing stage.
pub fn run(args: &Args) -> Result<(), CliError> {
    let input = |msg: String| CliError::Input { path: args.out.clone(), msg };
    let base = if args.quick { MatrixConfig::quick() } else { MatrixConfig::default() };
    let config = match &args.config {
        Some(path) => MatrixConfig::from_toml_file(path, &base)
            .map_err(|e| CliError::Config { path: path.clone(), msg: e.to_string() })?,
        None => base,
    };
    let cells = if args.cells.is_empty() {
        table_cells()
    } else {
        args.cells.iter().map(|c| parse_cell(c)).collect::<Result<_, _>>().map_err(|e| input(e.to_string()))?
    };
    let methods = if args.methods.is_empty() {
        Method::ALL.to_vec()
    } else {
        args.methods.iter().map(|m| Method::parse(m)).collect::<Result<_, _>>().map_err(|e| input(e.to_string()))?
    };
    let seeds = args.seeds.unwrap_or(if args.quick { 1 } else { 3 });
    if seeds == 0 {
        return Err(input("--seeds must be at least 1".into()));
    }
    let opts = Options {
        config,
        quick: args.quick,
        seeds,
        cells,
        methods,
        out: args.out.clone(),
        progress: !args.no_progress,
    };
    let files = reproduce(&opts).map_err(|e| CliError::Run(e.to_string()))?;
    for f in files {
        println!("{}", f.display());
    }
    Ok(())
}
