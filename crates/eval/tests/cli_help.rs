//! `--help` of the `quadformer` subcommands owned by the file-format layer, as snapshots
//! (update with `UPDATE_EXPECT=1 cargo test -p eval --test cli_help`).

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::process::Command;

use expect_test::{Expect, expect};

fn check(args: &[&str], expect: Expect) {
    let o = Command::new(env!("CARGO_BIN_EXE_quadformer")).args(args).env("COLUMNS", "100").output().unwrap();
    assert!(o.status.success());
    expect.assert_eq(&String::from_utf8(o.stdout).unwrap());
}

#[test]
fn top_level_help_lists_the_commands() {
    let o = Command::new(env!("CARGO_BIN_EXE_quadformer")).arg("--help").output().unwrap();
    let text = String::from_utf8(o.stdout).unwrap();
    for cmd in ["simulate", "residues"] {
        assert!(text.lines().any(|l| l.trim_start().starts_with(cmd)), "{text}");
    }
}

#[test]
fn simulate_help() {
    check(
        &["simulate", "-h"],
        expect![[r#"
            Simulate a flight from a TOML config and write its sensor streams, truth and attack labels as a flight directory

            Usage: quadformer simulate [OPTIONS]

            Options:
                  --config <FILE.toml>    Flight config (TOML; docs/data-format.md "Flight config"). Keys left out keep their defaults; an empty file is a clean eight-shape flight
                  --out <DIR>             Output flight directory (created atomically; must not exist or be empty unless --force)
                  --seed <SEED>           Override the config's master seed (at most 2^63 − 1: the seed is written to config.toml, whose integers are signed 64-bit)
                  --force                 Replace DIR if it exists (the old directory is removed only after the new one is complete)
                  --no-truth              Do not write truth.csv (e.g. to keep a committed fixture small)
                  --print-default-config  Print the default config with every field explicit, and exit
              -h, --help                  Print help
              -V, --version               Print version
        "#]],
    );
}

#[test]
fn residues_help() {
    check(
        &["residues", "-h"],
        expect![[r#"
            Run the Model I or Model II EKF on a flight directory (simulated or your own log) or a PX4 ULog and write the residue sequence r_k, S_k, NIS (and labels, if known) as CSV

            Usage: quadformer residues [OPTIONS] --model <MODEL> --in <DIR|LOG.ulg> --out <FILE.csv>

            Options:
                  --model <MODEL>              EKF model: I (GPS + attitude) or II (VO + GPS, keyframe cloning) [possible values: I, II]
                  --in <DIR|LOG.ulg>           Flight directory (imu.csv plus the streams the model needs: I: gps.csv and attitude.csv; II: vo.csv, with gps.csv and attitude.csv used when present; truth.csv, attack.csv and filter.toml are optional), or a PX4 ULog file (.ulg)
                  --out <FILE.csv>             Output residue CSV (written atomically); the filter used goes beside it, as FILE.filter.toml
                  --covariance <COVARIANCE>    How to store S_k [default: upper] [possible values: upper, full]
                  --filter-config <FILE.toml>  Filter settings (TOML, `ekf_residue::residues::FilterConfig` fields: imu, meas, init, cov_update, guard, pair_tolerance_s); keys left out keep the base values
                  --estimates <FILE.csv>       Also write the posterior state estimate after each residue step (truth.csv columns)
                  --no-labels                  Do not write a label column even if attack.csv exists
                  --estimate-noise             Estimate the measurement σ from the flight's first clean stretch (covariance matching) and use them; the figures used are printed and written to FILE.filter.toml
                  --gps-min-fix <N>            ULog input: drop GNSS fixes whose fix_type is below this (3 = 3-D fix, 0 keeps all) [default: 3]
                  --columns <MAP|FILE.toml>    Flight directory from another tool: its CSV column names mapped to the project's, as THEIRS=OURS pairs (`gx=gyro_x,gy=gyro_y`) or a TOML file of `THEIRS = "OURS"` lines
              -h, --help                       Print help (see more with '--help')
              -V, --version                    Print version
        "#]],
    );
}
