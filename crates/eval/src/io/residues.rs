//! The residue file: one row per residue step of paper alg:alg1, with the innovation
//! `r_k = y_k − g(x̂_{k|k−1})` and its covariance `S_k` (eq:ekf_update) and the normalised
//! innovation squared `NIS_k = r_kᵀ S_k⁻¹ r_k`.
//!
//! Columns, for channels `c_1 … c_m` (e.g. `gps_x … att_yaw` for Model I):
//! `t` (s), `r_<c_i>` (the channel's unit: m or rad) in channel order, `s_<c_i>_<c_j>` for
//! `i ≤ j` (the upper triangle, row by row) or for all `i, j` (full), `nis`, and optionally
//! `label` (`1` = attacked). On reading, channels are the `r_` columns in file order; the lower
//! triangle may stand in for the upper one; `nis` is recomputed from `r` and `S` and, when the
//! file has it, checked against it.

use std::path::Path;

use ekf_residue::{LabelledSeries, ResidueSeries};

use crate::io::atomic::{Staged, stage_file};
use crate::io::error::{IoError, Result};
use crate::io::table::{CsvIn, CsvOut};

/// Relative tolerance when checking a file's `nis` column against the recomputed NIS: the
/// writer prints shortest round-trip digits, so only the Cholesky solve's rounding (≈1e-12
/// relative for well-conditioned `S_k`) separates them; 1e-6 leaves room for other writers
/// that print fewer digits.
const NIS_RTOL: f64 = 1e-6;

/// Which entries of `S_k` a residue file stores.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CovarianceLayout {
    /// `s_<c_i>_<c_j>` for `i ≤ j`: `m(m+1)/2` columns (the default; `S_k` is symmetric).
    #[default]
    Upper,
    /// All `m²` entries, row-major.
    Full,
}

/// Column name of residue channel `c`.
pub fn r_column(channel: &str) -> String {
    format!("r_{channel}")
}

/// Column name of covariance entry `(c_i, c_j)`.
pub fn s_column(c_i: &str, c_j: &str) -> String {
    format!("s_{c_i}_{c_j}")
}

/// Writes a residue series (and optionally per-step labels) to `path` atomically.
///
/// # Errors
/// [`IoError::Inconsistent`] if `labels` has another length than the series;
/// [`IoError::Fs`] on file-system failure; nothing is left at `path` on error.
pub fn write_residues(
    path: &Path,
    series: &ResidueSeries,
    labels: Option<&[bool]>,
    layout: CovarianceLayout,
) -> Result<()> {
    stage_residues(path, series, labels, layout)?.commit()
}

/// Writes the residue file of [`write_residues`] into its temporary, to be committed with the
/// other outputs of a command (`crate::io::commit_all`).
///
/// # Errors
/// As [`write_residues`].
pub fn stage_residues(
    path: &Path,
    series: &ResidueSeries,
    labels: Option<&[bool]>,
    layout: CovarianceLayout,
) -> Result<Staged> {
    if let Some(l) = labels
        && l.len() != series.len()
    {
        return Err(IoError::Inconsistent {
            path: path.to_owned(),
            msg: format!("{} labels for {} residue steps", l.len(), series.len()),
        });
    }
    let ch = series.channels();
    let m = ch.len();
    let pairs: Vec<(usize, usize)> = match layout {
        CovarianceLayout::Upper => (0..m).flat_map(|i| (i..m).map(move |j| (i, j))).collect(),
        CovarianceLayout::Full => (0..m).flat_map(|i| (0..m).map(move |j| (i, j))).collect(),
    };
    let mut header = vec!["t".to_owned()];
    header.extend(ch.iter().map(|c| r_column(c)));
    header.extend(pairs.iter().map(|&(i, j)| s_column(&ch[i], &ch[j])));
    header.push("nis".into());
    if labels.is_some() {
        header.push("label".into());
    }
    stage_file(path, |file| {
        let mut out = CsvOut::new(path, file, header)?;
        for (k, step) in series.steps().enumerate() {
            out.f64(step.t)?;
            for &r in step.r_k {
                out.f64(r)?;
            }
            for &(i, j) in &pairs {
                out.f64(step.s_k[i * m + j])?;
            }
            out.f64(step.nis)?;
            if let Some(l) = labels {
                out.label(l.get(k).copied().unwrap_or(false));
            }
            out.end_row()?;
        }
        out.finish()
    })
}

/// Reads a residue file written by [`write_residues`] or by another tool following
/// docs/data-format.md.
///
/// # Errors
/// [`IoError`] naming the file, line and column: no `r_` column, a missing `s_` column, a
/// value not a number or not finite, non-increasing time, a label not `0`/`1`, a `nis` value
/// that disagrees with `r` and `S`, or an `S_k` that is not symmetric positive definite
/// ([`IoError::Series`] with the step's line).
pub fn read_residues(path: &Path) -> Result<LabelledSeries> {
    let mut input = CsvIn::open(path)?;
    let channels: Vec<String> = input.header().iter().filter_map(|h| h.strip_prefix("r_")).map(str::to_owned).collect();
    if channels.is_empty() {
        return Err(IoError::MissingColumn {
            path: path.to_owned(),
            column: "r_<channel> (at least one)".into(),
            found: input.header().to_vec(),
        });
    }
    let m = channels.len();
    let t_col = input.column("t")?;
    let r_cols: Vec<usize> = channels.iter().map(|c| input.column(&r_column(c))).collect::<Result<_>>()?;
    // Resolve every S entry to a column: (i, j) from `s_ci_cj`, or the mirrored column.
    let mut names = std::collections::HashMap::new();
    for i in 0..m {
        for j in 0..m {
            if let Some(prev) = names.insert(s_column(&channels[i], &channels[j]), (i, j)) {
                return Err(IoError::Header {
                    path: path.to_owned(),
                    line: input.header_line(),
                    msg: format!(
                        "channel names make covariance column `{}` ambiguous ({prev:?} and {:?})",
                        s_column(&channels[i], &channels[j]),
                        (i, j)
                    ),
                });
            }
        }
    }
    let mut s_cols = vec![0usize; m * m];
    for i in 0..m {
        for j in 0..m {
            let own = input.optional_column(&s_column(&channels[i], &channels[j]));
            let mirror = input.optional_column(&s_column(&channels[j], &channels[i]));
            s_cols[i * m + j] = match own.or(mirror) {
                Some(c) => c,
                None => input.column(&s_column(&channels[i.min(j)], &channels[i.max(j)]))?,
            };
        }
    }
    let nis_col = input.optional_column("nis");
    let label_col = input.optional_column("label");

    let mut t = Vec::new();
    let mut r = Vec::new();
    let mut s = Vec::new();
    let mut lines = Vec::new();
    let mut nis_file = Vec::new();
    let mut labels = Vec::new();
    while let Some(row) = input.next_row()? {
        let t_k = input.time(&row, t_col, t.last().copied())?;
        t.push(t_k);
        for &c in &r_cols {
            r.push(input.f64(&row, c)?);
        }
        for &c in &s_cols {
            s.push(input.f64(&row, c)?);
        }
        if let Some(c) = nis_col {
            nis_file.push((input.f64(&row, c)?, row.line(), c));
        }
        if let Some(c) = label_col {
            labels.push(input.label(&row, c)?);
        }
        lines.push(row.line());
    }
    let header_line = input.header_line();
    let series = ResidueSeries::from_flat(t, channels, r, s).map_err(|source| {
        let line = step_of(&source).and_then(|k| lines.get(k).copied()).unwrap_or(header_line);
        IoError::Series { path: path.to_owned(), line, source }
    })?;
    for (k, &(nis, line, col)) in nis_file.iter().enumerate() {
        let expect = series.nis()[k];
        if (nis - expect).abs() > NIS_RTOL * expect.abs().max(1.0) {
            return Err(IoError::Field {
                path: path.to_owned(),
                line,
                column: col + 1,
                field: "nis".into(),
                msg: format!("nis {nis:?} disagrees with r and S, which give {expect:?}"),
            });
        }
    }
    let labels = label_col.map(|_| labels);
    LabelledSeries::new(series, labels).map_err(|source| IoError::Series { path: path.to_owned(), line: 1, source })
}

/// The step index a residue validation error refers to, if any.
fn step_of(e: &ekf_residue::ResidueError) -> Option<usize> {
    use ekf_residue::ResidueError as E;
    match e {
        E::StepDim { step_idx, .. }
        | E::NonFinite { step_idx, .. }
        | E::Unordered { step_idx, .. }
        | E::NotSymmetric { step_idx }
        | E::NotPositiveDefinite { step_idx } => Some(*step_idx),
        _ => None,
    }
}
