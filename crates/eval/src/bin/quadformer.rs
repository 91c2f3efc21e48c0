//! The `quadformer` binary: parses the command line (clap) and runs the subcommand from
//! `eval::cli`; errors are printed with their context and give exit status 1 (2 for usage
//! errors, as clap does).

use std::process::ExitCode;

use clap::Parser;
use eval::cli::{Cli, run};

fn main() -> ExitCode {
    // SAFETY: first thing in `main`, before any other thread exists.
    #[allow(unsafe_code)]
    unsafe {
        eval::runtime::init_cpu_runtime();
    }
    let cli = Cli::parse();
    match run(&cli).map_err(anyhow::Error::from) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
