//! `cargo xtask ci`: every check CI runs, cheapest first, so that local and CI runs are the
//! same: fmt, clippy `-D warnings`, rustdoc `-D warnings`, the workspace tests (which include
//! the tidy test), `reproduce-tables --quick`, and `cargo deny check` when cargo-deny is
//! installed.

use std::process::{Command, Stdio};
use std::time::Instant;

use crate::flags::Ci;
use crate::{cargo, project_root, run_command};

/// Runs the CI steps in order and stops at the first failure.
pub(crate) fn run(flags: &Ci) -> anyhow::Result<()> {
    let root = project_root();
    let start = Instant::now();
    let step = |args: &[&str], env: &[(&str, &str)]| -> anyhow::Result<()> {
        let mut cmd = Command::new(cargo());
        cmd.current_dir(&root).args(args);
        for (k, v) in env {
            cmd.env(k, v);
        }
        let t0 = Instant::now();
        run_command(&mut cmd)?;
        eprintln!("    ok in {:.1} s", t0.elapsed().as_secs_f64());
        Ok(())
    };
    step(&["fmt", "--all", "--", "--check"], &[])?;
    step(&["clippy", "--workspace", "--all-targets", "--", "-D", "warnings"], &[])?;
    step(&["doc", "--workspace", "--no-deps"], &[("RUSTDOCFLAGS", "-D warnings")])?;
    step(&["test", "--workspace"], &[])?;
    if flags.skip_reproduce {
        eprintln!("==> reproduce-tables --quick skipped (--skip-reproduce)");
    } else {
        crate::run_eval("reproduce-tables", &["--quick".into()])?;
    }
    if cargo_deny_installed() {
        step(&["deny", "check"], &[])?;
    } else {
        eprintln!("==> cargo deny check skipped: cargo-deny is not installed (`cargo install cargo-deny`)");
    }
    eprintln!("ci passed in {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}

fn cargo_deny_installed() -> bool {
    Command::new(cargo())
        .args(["deny", "--version"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}
