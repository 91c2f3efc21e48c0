//! `cargo xtask figures`: forwards to `quadformer figures` built in release mode, which draws
//! the ROC curves, the F1-versus-amplitude sweep, the CUSUM post-attack plot (the paper's
//! Fig. 9) and the flight top views.

use std::ffi::OsString;

/// Runs the eval binary's `figures` with `args` (verbatim).
pub(crate) fn run(args: &[OsString]) -> anyhow::Result<()> {
    crate::run_eval("figures", args)
}
