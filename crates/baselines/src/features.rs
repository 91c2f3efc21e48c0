//! Windowed residue features for the SVM baseline (the paper feeds every learning method
//! residue windows, Sec. V-E, "to ensure fair comparisons").
//!
//! For step `k` the window is the last `w` steps `k−w+1..=k` (fewer at the start of a flight),
//! so the features are causal and a streaming detector needs only the last `w` steps. With the
//! normalised residue `ν_i = r_i / √(S_k)_ii` of channel `i`, the feature vector is
//!
//! ```text
//! [ mean ν_i (m values),  √mean ν_i² (m values),  ν_i at step k (m values),
//!   ln(1 + NIS_k),  ln(1 + mean NIS) ]                                  (3m + 2 values)
//! ```
//!
//! The mean captures a persistent bias, the RMS a burst of either sign, the last value the
//! onset, and the NIS terms the cross-channel Mahalanobis size under the filter's own `S_k`.

use ekf_residue::ResidueSeries;

/// Number of features for `m` channels.
pub fn n_features(m: usize) -> usize {
    3 * m + 2
}

/// Features of every step of `series` with a window of `w ≥ 1` steps, row-major
/// `n × (3m + 2)`.
pub fn window_features(series: &ResidueSeries, w: usize) -> Vec<f64> {
    let (n, m) = (series.len(), series.dim());
    let w = w.max(1);
    let d = n_features(m);
    // Normalised residues ν, row-major n × m.
    let mut nu = Vec::with_capacity(n * m);
    for step in series.steps() {
        for i in 0..m {
            nu.push(step.r_k[i] / step.s_k[i * m + i].sqrt());
        }
    }
    let nis = series.nis();
    let mut out = Vec::with_capacity(n * d);
    for k in 0..n {
        let lo = (k + 1).saturating_sub(w);
        let len = (k + 1 - lo) as f64;
        let base = out.len();
        out.resize(base + d, 0.0);
        let f = &mut out[base..];
        let mut nis_sum = 0.0;
        for j in lo..=k {
            for i in 0..m {
                let v = nu[j * m + i];
                f[i] += v;
                f[m + i] += v * v;
            }
            nis_sum += nis[j];
        }
        for i in 0..m {
            f[i] /= len;
            f[m + i] = (f[m + i] / len).sqrt();
            f[2 * m + i] = nu[k * m + i];
        }
        f[3 * m] = nis[k].ln_1p();
        f[3 * m + 1] = (nis_sum / len).ln_1p();
    }
    out
}
