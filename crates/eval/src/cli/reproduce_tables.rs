//! `quadformer reproduce-tables`: runs the paper's experiment matrix and writes Tables I and II,
//! raw results, ROC plots, the CUSUM post-attack figure, the amplitude sweep, ablations and a
//! report (see [`crate::reproduce`]).

use std::path::PathBuf;

use crate::cell::Cell;
use crate::cli::CliError;
use crate::io::IoError;
use crate::methods::Method;
use crate::reproduce::{MatrixConfig, Options, Stages, reproduce};

/// Most seeds one invocation accepts: every seed simulates its own paper-scale datasets and
/// trains every method again (about 10 minutes and 0.5 GB of dataset cache per seed on 2 cores).
pub const MAX_SEEDS: u64 = 100;

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
    /// Which experiments run: `all` (Tables I and II with their studies, then the closed loop
    /// of Table III), `tables` or `closed-loop`.
    #[arg(long, value_enum, default_value = "all")]
    pub stages: Stages,
}

/// The cells, methods and seed count the options select, checked before any work starts:
/// every name known, none given twice, `1 ≤ --seeds ≤` [`MAX_SEEDS`].
fn selection(args: &Args) -> Result<(Vec<Cell>, Vec<Method>, u64), String> {
    let cells: Vec<Cell> = if args.cells.is_empty() {
        Cell::table_cells()
    } else {
        args.cells.iter().map(|c| Cell::parse(c)).collect::<Result<_, _>>().map_err(|e| e.to_string())?
    };
    let methods: Vec<Method> = if args.methods.is_empty() {
        Method::ALL.to_vec()
    } else {
        args.methods.iter().map(|m| Method::parse(m)).collect::<Result<_, _>>().map_err(|e| e.to_string())?
    };
    if let Some((i, c)) = cells.iter().enumerate().find(|(i, c)| cells[..*i].contains(c)) {
        return Err(format!("--cells names {} twice ({})", c.slug(), args.cells.get(i).map_or("", String::as_str)));
    }
    if let Some((i, m)) = methods.iter().enumerate().find(|(i, m)| methods[..*i].contains(m)) {
        return Err(format!("--methods names {} twice ({})", m.name(), args.methods.get(i).map_or("", String::as_str)));
    }
    let seeds = args.seeds.unwrap_or(if args.quick { 1 } else { 3 });
    if !(1..=MAX_SEEDS).contains(&seeds) {
        return Err(format!("--seeds must be between 1 and {MAX_SEEDS}, got {seeds}"));
    }
    Ok((cells, methods, seeds))
}

/// Runs the matrix and prints the files written.
///
/// # Errors
/// [`CliError::Input`] for a bad option or config; [`CliError::Run`] for a failing stage.
pub fn run(args: &Args) -> Result<(), CliError> {
    let input = |msg: String| CliError::Input { path: args.out.clone(), msg };
    let base = if args.quick { MatrixConfig::quick() } else { MatrixConfig::default() };
    let config = match &args.config {
        // Checked as a regular file within the text budget before the experiment code reads it;
        // its errors name the file themselves.
        Some(path) => {
            crate::io::open_input(path, crate::io::MAX_TEXT_BYTES)?;
            MatrixConfig::from_toml_file(path, &base).map_err(|e| CliError::Run(e.to_string()))?
        }
        None => base,
    };
    let (cells, methods, seeds) = selection(args).map_err(input)?;
    // Results are written into OUT (not replacing it): it must be a directory or absent.
    if std::fs::metadata(&args.out).is_ok_and(|m| !m.is_dir()) {
        return Err(CliError::Io(IoError::Unsafe {
            path: args.out.clone(),
            msg: "--out is not a directory; results are written into a directory".into(),
        }));
    }
    let opts = Options {
        config,
        quick: args.quick,
        seeds,
        cells,
        methods,
        out: args.out.clone(),
        progress: !args.no_progress,
        stages: args.stages,
    };
    let files = reproduce(&opts).map_err(|e| CliError::Run(e.to_string()))?;
    for f in files {
        println!("{}", f.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(cells: &[&str], methods: &[&str], seeds: Option<u64>) -> Args {
        Args {
            quick: false,
            seeds,
            cells: cells.iter().map(|s| (*s).to_owned()).collect(),
            methods: methods.iter().map(|s| (*s).to_owned()).collect(),
            out: PathBuf::from("unused"),
            config: None,
            no_progress: true,
            stages: Stages::All,
        }
    }

    #[test]
    fn the_selection_is_checked_before_any_work() {
        let (cells, methods, seeds) = selection(&args(&["m1-exponential-a1"], &["cusum", "quadformer"], None)).unwrap();
        assert_eq!((cells.len(), methods, seeds), (1, vec![Method::Cusum, Method::QuadFormer], 3));
        let e = selection(&args(&["m1-exponential-a1", "m1-exponential-a1"], &[], None)).unwrap_err();
        assert!(e.contains("--cells names m1-exponential-a1 twice"), "{e}");
        let e = selection(&args(&[], &["cusum", "CUSUM"], None)).unwrap_err();
        assert!(e.contains("--methods names CUSUM twice (CUSUM)"), "{e}");
        for bad in [0, MAX_SEEDS + 1, 4_294_967_296] {
            let e = selection(&args(&[], &[], Some(bad))).unwrap_err();
            assert!(e.contains("--seeds must be between 1 and 100"), "{e}");
        }
    }
}
