//! The xtask command line (clap derive). The forwarding subcommands declare the eval binary's
//! flags so that `--help` documents them and typos fail early; the arguments themselves are
//! forwarded verbatim (see `main::forwarded_args`).

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};

/// Developer and user tasks for QUADFormer-rs.
#[derive(Debug, Parser)]
#[command(name = "xtask", bin_name = "cargo xtask", version, about)]
pub(crate) struct Xtask {
    /// The task to run.
    #[command(subcommand)]
    pub(crate) cmd: Cmd,
}

/// The tasks.
#[derive(Debug, Subcommand)]
pub(crate) enum Cmd {
    /// Runs the paper's experiment matrix and regenerates Tables I and II, raw results and the
    /// ROC plots (forwards to `quadformer reproduce-tables`, release build).
    ReproduceTables(ReproduceTables),
    /// Regenerates the figures from cached results and scenario flights (forwards to
    /// `quadformer figures`, release build).
    Figures(Figures),
    /// Runs every CI check, cheapest first: fmt, clippy, doc, tests, reproduce-tables --quick.
    Ci(Ci),
    /// Checks layering, candle reachability, `//!` file docs and docs/ARCHITECTURE.md.
    Tidy,
}

/// Options of `reproduce-tables`; forwarded verbatim to the eval binary.
#[derive(Debug, Args)]
pub(crate) struct ReproduceTables {
    /// Small data and one seed (about a minute; used by CI).
    #[arg(long)]
    pub(crate) quick: bool,
    /// Number of seeds per (cell, method). Default 3.
    #[arg(long, value_name = "N")]
    pub(crate) seeds: Option<u32>,
    /// Only these cells (comma-separated, e.g. `m1-exponential-a1`).
    #[arg(long, value_name = "CELLS", value_delimiter = ',')]
    pub(crate) cells: Vec<String>,
    /// Only these methods (comma-separated, e.g. `QUADFormer,CUSUM`).
    #[arg(long, value_name = "METHODS", value_delimiter = ',')]
    pub(crate) methods: Vec<String>,
    /// Output directory. Default `results/`.
    #[arg(long, value_name = "DIR")]
    pub(crate) out: Option<PathBuf>,
    /// Experiment configuration file (TOML).
    #[arg(long, value_name = "FILE")]
    pub(crate) config: Option<PathBuf>,
    /// Further arguments for the eval binary, after `--`.
    #[arg(last = true, value_name = "EXTRA")]
    pub(crate) extra: Vec<String>,
}

/// Options of `figures`; forwarded verbatim to the eval binary.
#[derive(Debug, Args)]
pub(crate) struct Figures {
    /// Small data (as `reproduce-tables --quick`).
    #[arg(long)]
    pub(crate) quick: bool,
    /// Output directory. Default `results/`.
    #[arg(long, value_name = "DIR")]
    pub(crate) out: Option<PathBuf>,
    /// Experiment configuration file (TOML).
    #[arg(long, value_name = "FILE")]
    pub(crate) config: Option<PathBuf>,
    /// Further arguments for the eval binary, after `--`.
    #[arg(last = true, value_name = "EXTRA")]
    pub(crate) extra: Vec<String>,
}

/// Options of `ci`.
#[derive(Debug, Args)]
pub(crate) struct Ci {
    /// Skip the `reproduce-tables --quick` end-to-end run.
    #[arg(long)]
    pub(crate) skip_reproduce: bool,
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory as _;

    use super::*;

    #[test]
    fn cli_is_consistent_and_parses_the_documented_flags() {
        Xtask::command().debug_assert();
        let x = Xtask::try_parse_from([
            "xtask",
            "reproduce-tables",
            "--quick",
            "--seeds",
            "2",
            "--cells",
            "m1-exponential-a1,m2-laplace-a2",
            "--out",
            "r",
        ])
        .unwrap();
        match x.cmd {
            Cmd::ReproduceTables(r) => {
                assert!(r.quick);
                assert_eq!(r.seeds, Some(2));
                assert_eq!(r.cells, ["m1-exponential-a1", "m2-laplace-a2"]);
                assert_eq!(r.out, Some(PathBuf::from("r")));
            }
            other => panic!("unexpected {other:?}"),
        }
        assert!(Xtask::try_parse_from(["xtask", "reproduce-tables", "--seeds", "x"]).is_err());
    }
}
