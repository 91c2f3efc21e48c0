//! The `quadformer` binary: parses the command line (clap) and runs the subcommand from
//! `eval::cli`; errors are printed with their causes (each once) and give exit status 1 (2 for usage
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
            eprintln!("error: {}", message(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined by `: `, leaving out a cause whose text the message already
/// contains (most errors print their source themselves).
fn message(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let c = cause.to_string();
        if !msg.contains(&c) {
            msg.push_str(": ");
            msg.push_str(&c);
        }
    }
    msg
}
