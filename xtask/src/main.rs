//! Developer and user tasks for QUADFormer-rs (`cargo xtask <task>`).
//!
//! One binary, one module per subcommand: `reproduce-tables` and `figures` forward to the
//! release-built `quadformer` binary of the `eval` crate (so numerics are optimised even though
//! this crate builds in debug); `ci` runs every check CI runs, cheapest first; `tidy` checks the
//! layering of the workspace and its documentation (also run by `cargo test --workspace`).

mod ci;
mod figures;
mod flags;
mod reproduce_tables;
mod tidy;

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context as _, bail};
use clap::Parser as _;

fn main() -> anyhow::Result<()> {
    let flags = flags::Xtask::parse();
    match flags.cmd {
        flags::Cmd::ReproduceTables(_) => reproduce_tables::run(&forwarded_args("reproduce-tables")),
        flags::Cmd::Figures(_) => figures::run(&forwarded_args("figures")),
        flags::Cmd::Ci(ci) => ci::run(&ci),
        flags::Cmd::Tidy => tidy::run(),
    }
}

/// The workspace root: the parent of this crate's manifest directory.
pub(crate) fn project_root() -> PathBuf {
    let manifest_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest_dir.parent().map_or_else(|| manifest_dir.to_owned(), Path::to_owned)
}

/// The `cargo` that runs this task (`$CARGO`), or `cargo` from `PATH`.
pub(crate) fn cargo() -> OsString {
    std::env::var_os("CARGO").unwrap_or_else(|| OsString::from("cargo"))
}

/// The command-line arguments after `subcommand`, verbatim, without the first lone `--`
/// (which separates extra arguments for the eval binary from the xtask's own flags).
fn forwarded_args(subcommand: &str) -> Vec<OsString> {
    split_forwarded(std::env::args_os().skip(1), subcommand)
}

fn split_forwarded(args: impl IntoIterator<Item = OsString>, subcommand: &str) -> Vec<OsString> {
    let mut rest = args.into_iter().skip_while(|a| a != subcommand).skip(1);
    let mut out = Vec::new();
    let mut dropped_separator = false;
    for a in rest.by_ref() {
        if a == "--" && !dropped_separator {
            dropped_separator = true;
            continue;
        }
        out.push(a);
    }
    out
}

/// Runs `cargo run --release -p eval --bin quadformer -- <subcommand> <args>` in the
/// workspace root and fails when it fails.
pub(crate) fn run_eval(subcommand: &str, args: &[OsString]) -> anyhow::Result<()> {
    let mut cmd = Command::new(cargo());
    cmd.current_dir(project_root())
        .args(["run", "--release", "-p", "eval", "--bin", "quadformer", "--", subcommand])
        .args(args);
    run_command(&mut cmd)
}

/// Runs `cmd`, echoing it first; an unsuccessful exit is an error naming the command.
pub(crate) fn run_command(cmd: &mut Command) -> anyhow::Result<()> {
    let shown = format!("{cmd:?}");
    eprintln!("==> {shown}");
    let status = cmd.status().with_context(|| format!("cannot start {shown}"))?;
    if !status.success() {
        bail!("{shown} failed with {status}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn os(v: &[&str]) -> Vec<OsString> {
        v.iter().map(OsString::from).collect()
    }

    #[test]
    fn arguments_are_forwarded_verbatim() {
        let got = split_forwarded(
            os(&["reproduce-tables", "--quick", "--cells", "m1-laplace-a1", "--", "--threads", "2"]),
            "reproduce-tables",
        );
        assert_eq!(got, os(&["--quick", "--cells", "m1-laplace-a1", "--threads", "2"]));
        assert!(split_forwarded(os(&["figures"]), "figures").is_empty());
        assert!(project_root().join("Cargo.toml").is_file());
    }
}
