//! The attack file `attack.csv`: one row per GPS sample with the injected offset `d_k` of
//! paper eq:fdi (`y_k = g(x_k) + v_k + d_k`) and its label (attacked when the GPS sample
//! differs from the clean one). Offsets are in metres in the local ENU frame; time stamps are
//! those of `gps.csv`, whose positions already include the offsets (the clean fix is
//! `p − d`).

use std::path::Path;

use nalgebra::Vector3;

use crate::io::atomic::write_file_atomic;
use crate::io::error::Result;
use crate::io::table::{ColumnMap, CsvIn, CsvOut};

/// Columns of `attack.csv`.
pub const ATTACK_COLUMNS: [&str; 5] = ["t", "label", "d_x", "d_y", "d_z"];

/// One row of `attack.csv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttackRecord {
    /// Time of the GPS sample in seconds.
    pub t: f64,
    /// True when the GPS sample at `t` is attacked.
    pub label: bool,
    /// Injected offset `d_k` in metres (ENU); replayed or frozen fixes carry their
    /// difference to the clean fix.
    pub d: Vector3<f64>,
}

/// Reads `attack.csv`.
///
/// # Errors
/// [`crate::io::IoError`] naming file, line and column: missing column, wrong field count, a
/// value not a number or not finite, a label not `0`/`1`, non-increasing time stamps.
pub fn read_attack(path: &Path) -> Result<Vec<AttackRecord>> {
    read_attack_mapped(path, &ColumnMap::default())
}

/// [`read_attack`] with another tool's column names renamed by `map`.
///
/// # Errors
/// As [`read_attack`].
pub(crate) fn read_attack_mapped(path: &Path, map: &ColumnMap) -> Result<Vec<AttackRecord>> {
    let mut input = CsvIn::open_mapped(path, map)?;
    let cols = input.columns(&ATTACK_COLUMNS)?;
    let mut out = Vec::new();
    let mut prev_t = None;
    while let Some(row) = input.next_row()? {
        let t = input.time(&row, cols[0], prev_t)?;
        let label = input.label(&row, cols[1])?;
        let d = input.vec3(&row, &cols[2..5])?;
        out.push(AttackRecord { t, label, d });
        prev_t = Some(t);
    }
    Ok(out)
}

/// Writes `attack.csv` atomically.
///
/// # Errors
/// [`crate::io::IoError::Unwritable`] for a non-finite value, [`crate::io::IoError::Fs`] on
/// file-system failure; nothing is left at `path` on error.
pub fn write_attack(path: &Path, records: &[AttackRecord]) -> Result<()> {
    write_file_atomic(path, |file| {
        let mut out = CsvOut::new(path, file, ATTACK_COLUMNS.iter().map(|s| (*s).to_owned()).collect())?;
        for r in records {
            out.f64(r.t)?;
            out.label(r.label);
            out.vec3(&r.d)?;
            out.end_row()?;
        }
        out.finish()
    })
}

/// Tolerance in seconds for matching a residue step to a GPS sample: 1 ms, far below any GPS
/// period (≥ 20 ms at 50 Hz) and far above the rounding of time stamps printed in shortest
/// round-trip form or computed as `k·Δt`.
pub const TIME_MATCH_TOL_S: f64 = 1e-3;

/// Label of every residue step: the label of the GPS sample at the same time (within
/// [`TIME_MATCH_TOL_S`]); a residue step with no GPS sample at its time is clean (the rule of
/// the dataset builder, docs/datasets.md). Both inputs must be sorted by time.
pub fn labels_at(residue_t: &[f64], attack: &[AttackRecord]) -> Vec<bool> {
    let fix_t: Vec<f64> = attack.iter().map(|a| a.t).collect();
    let fix_labels: Vec<bool> = attack.iter().map(|a| a.label).collect();
    align_labels(residue_t, &fix_t, &fix_labels)
}

/// Label of each residue step: the label of the GPS fix at the same time (within
/// [`TIME_MATCH_TOL_S`]), `false` when no fix is there. Both time lists must be sorted.
#[must_use]
pub fn align_labels(residue_t: &[f64], fix_t: &[f64], fix_labels: &[bool]) -> Vec<bool> {
    let mut j = 0;
    residue_t
        .iter()
        .map(|&t| {
            while j < fix_t.len() && fix_t[j] < t - TIME_MATCH_TOL_S {
                j += 1;
            }
            j < fix_t.len() && (fix_t[j] - t).abs() <= TIME_MATCH_TOL_S && fix_labels.get(j).copied().unwrap_or(false)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(t: f64, label: bool) -> AttackRecord {
        AttackRecord { t, label, d: Vector3::zeros() }
    }

    #[test]
    fn labels_follow_gps_samples_and_default_to_clean() {
        let attack = [rec(0.0, false), rec(0.1, true), rec(0.2, true), rec(0.3, false)];
        // 0.05 has no GPS sample: clean; 0.1000004 matches 0.1 within the tolerance.
        let t = [0.0, 0.05, 0.1000004, 0.2, 0.3, 0.4];
        assert_eq!(labels_at(&t, &attack), vec![false, false, true, true, false, false]);
    }
}
