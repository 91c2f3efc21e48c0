//! The `quadformer` binary: parses the command line (clap) and runs the subcommand from
//! `eval::cli`; errors are printed with their context and give exit status 1 (2 for usage
//! errors, as clap does).

use std::process::ExitCode;

use clap::Parser;
use eval::cli::{Cli, run};

fn main() -> ExitCode {
    single_threaded_candle_elementwise();
    let cli = Cli::parse();
    match run(&cli).map_err(anyhow::Error::from) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Runs candle's element-wise kernels on the calling thread (`CANDLE_NUM_THREADS=1`) unless the
/// user chose otherwise. `reproduce-tables` trains one model per core in parallel, and there
/// candle's process-wide spinning barrier pool made two concurrent trainings slower than running
/// them one after the other (docs/decisions/064-parallel-runs-and-candle-threads.md). Matrix
/// products still use rayon. Results do not depend on it: candle's CPU results are
/// bit-identical across thread counts (shared/reference/rust-stack.md §3).
#[allow(unsafe_code)]
fn single_threaded_candle_elementwise() {
    if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
        // SAFETY: called first thing in `main`, before this process starts any other thread,
        // so no concurrent reader of the environment exists.
        unsafe { std::env::set_var("CANDLE_NUM_THREADS", "1") };
    }
}
