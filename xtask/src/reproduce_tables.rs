//! `cargo xtask reproduce-tables`: forwards to `quadformer reproduce-tables` built in release
//! mode, which runs the paper's matrix (Model I/II × exponential/Laplace × Attack I/II × every
//! method × seeds) and writes Tables I and II (tab:comprehensive_analysis1,
//! tab:comprehensive_analysis2), raw results and plots.

use std::ffi::OsString;

/// Runs the eval binary's `reproduce-tables` with `args` (verbatim).
pub(crate) fn run(args: &[OsString]) -> anyhow::Result<()> {
    crate::run_eval("reproduce-tables", args)
}
