//! What the closed-loop examples (`attack_offsets`, `glr_reference`) share: their command
//! line, `[--seeds N] [--quick]`, read into the options of `reproduce-tables`' closed-loop
//! stage over every cell of the matrix.

use anyhow::{Context, Result, bail};
use eval::cell::Cell;
use eval::reproduce::{MatrixConfig, Options, Stages};

/// The closed-loop options of the process's arguments (`--seeds N`, default 3; `--quick` for
/// the `--quick` matrix); `example` names the program in the usage of an unknown option.
pub fn loop_options(example: &str) -> Result<Options> {
    let (mut seeds, mut quick) = (3u64, false);
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        match flag.as_str() {
            "--seeds" => {
                let v = args.next().context("--seeds needs a value")?;
                seeds = v.parse().with_context(|| format!("--seeds {v}"))?;
            }
            "--quick" => quick = true,
            other => bail!("unknown option {other}; usage: {example} [--seeds N] [--quick]"),
        }
    }
    Ok(Options {
        config: if quick { MatrixConfig::quick() } else { MatrixConfig::default() },
        quick,
        seeds,
        cells: Cell::table_cells(),
        methods: vec![],
        out: "results".into(),
        progress: false,
        stages: Stages::ClosedLoop,
    })
}
