//! Element-wise `exp`, `ln` and `erf`, and the sum, of `f32` slices, eight lanes at a time with
//! the `wide` crate, for the kernels of [`crate::fused`] and [`crate::js`].
//!
//! The standard library's `f32::exp`/`ln` call the C library one element at a time, and
//! candle's `erf` is `libm::erff`; together they were about a fifth of a training step
//! (perf, `examples/profile.rs train`). `wide`'s `f32x8::exp` and `ln` (Cephes-style
//! polynomials, within a few units in the last place of `f32`) compile to SIMD instructions.
//! `erf` has no `wide` version; it is Abramowitz & Stegun 7.1.26,
//! `erf(x) = 1 − (a₁t + a₂t² + a₃t³ + a₄t⁴ + a₅t⁵) e^{−x²}`, `t = 1/(1 + p|x|)`, odd in `x`,
//! with an absolute error below `1.5·10⁻⁷` (Handbook of Mathematical Functions, 1964, §7.1.26);
//! evaluated in `f32` it stays below `5·10⁻⁷` (tested), a few units of `f32` resolution near 1,
//! which is where GELU adds it.

use wide::f32x8;

/// Applies `f` to `xs` in place, eight elements at a time (the tail padded with `pad`).
fn map_in_place(xs: &mut [f32], pad: f32, f: impl Fn(f32x8) -> f32x8) {
    let mut chunks = xs.chunks_exact_mut(8);
    for c in &mut chunks {
        let mut lanes = [0f32; 8];
        lanes.copy_from_slice(c);
        c.copy_from_slice(&f(f32x8::from(lanes)).to_array());
    }
    let tail = chunks.into_remainder();
    if !tail.is_empty() {
        let mut lanes = [pad; 8];
        lanes[..tail.len()].copy_from_slice(tail);
        let out = f(f32x8::from(lanes)).to_array();
        tail.copy_from_slice(&out[..tail.len()]);
    }
}

/// `Σᵢ xᵢ`, summed in eight interleaved partial sums (which the compiler vectorises; a plain
/// running sum is one dependent addition per element).
pub fn sum(xs: &[f32]) -> f32 {
    let mut acc = f32x8::ZERO;
    let mut chunks = xs.chunks_exact(8);
    for c in &mut chunks {
        let mut lanes = [0f32; 8];
        lanes.copy_from_slice(c);
        acc += f32x8::from(lanes);
    }
    acc.reduce_add() + chunks.remainder().iter().sum::<f32>()
}

/// `Σᵢ aᵢ bᵢ` over the common length, summed as [`sum`].
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let mut acc = f32x8::ZERO;
    let (mut ca, mut cb) = (a[..n].chunks_exact(8), b[..n].chunks_exact(8));
    for (x, y) in (&mut ca).zip(&mut cb) {
        let (mut lx, mut ly) = ([0f32; 8], [0f32; 8]);
        lx.copy_from_slice(x);
        ly.copy_from_slice(y);
        acc += f32x8::from(lx) * f32x8::from(ly);
    }
    acc.reduce_add() + ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum::<f32>()
}

/// `xᵢ ← e^{xᵢ}`.
pub fn exp_in_place(xs: &mut [f32]) {
    map_in_place(xs, 0.0, f32x8::exp);
}

/// `xᵢ ← ln xᵢ`.
pub fn ln_in_place(xs: &mut [f32]) {
    map_in_place(xs, 1.0, f32x8::ln);
}

/// `xᵢ ← erf xᵢ` (Abramowitz & Stegun 7.1.26, module docs).
pub fn erf_in_place(xs: &mut [f32]) {
    map_in_place(xs, 0.0, erf_x8);
}

fn erf_x8(x: f32x8) -> f32x8 {
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [0.254_829_6, -0.284_496_74, 1.421_413_8, -1.453_152, 1.061_405_4];
    let ax = x.abs();
    let t = f32x8::ONE / (f32x8::splat(P) * ax + f32x8::ONE);
    let poly = (((f32x8::splat(A[4]) * t + A[3]) * t + A[2]) * t + A[1]) * t + A[0];
    let tail = poly * t * (-(ax * ax)).exp();
    let magnitude = f32x8::ONE - tail;
    // erf is odd.
    x.is_sign_negative().select(-magnitude, magnitude)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn grid(lo: f32, hi: f32, n: usize) -> Vec<f32> {
        (0..n).map(|i| lo + (hi - lo) * i as f32 / (n - 1) as f32).collect()
    }

    #[test]
    fn exp_and_ln_match_the_standard_library() {
        let xs = grid(-87.0, 88.0, 10_001);
        let mut e = xs.clone();
        exp_in_place(&mut e);
        for (x, y) in xs.iter().zip(&e) {
            let want = x.exp();
            assert!((y - want).abs() <= 4.0 * f32::EPSILON * want, "exp({x}) = {y}, want {want}");
        }
        let xs: Vec<f32> = grid(-30.0, 30.0, 10_001).iter().map(|v| v.exp()).chain([1e-8, 1.0, 2.0]).collect();
        let mut l = xs.clone();
        ln_in_place(&mut l);
        for (x, y) in xs.iter().zip(&l) {
            let want = x.ln();
            assert!((y - want).abs() <= 4.0 * f32::EPSILON * want.abs().max(1.0), "ln({x}) = {y}, want {want}");
        }
    }

    #[test]
    fn erf_is_within_the_published_bound_and_odd() {
        let xs = grid(-6.0, 6.0, 12_001);
        let mut e = xs.clone();
        erf_in_place(&mut e);
        let worst =
            xs.iter().zip(&e).map(|(x, y)| (f64::from(*y) - libm::erf(f64::from(*x))).abs()).fold(0.0, f64::max);
        // 1.5e-7 (A&S) plus the rounding of its evaluation in f32.
        assert!(worst < 5e-7, "largest error {worst}");
        let (mut a, mut b) = (vec![0.7f32, 3.0], vec![-0.7f32, -3.0]);
        erf_in_place(&mut a);
        erf_in_place(&mut b);
        assert_eq!(a, b.iter().map(|v| -v).collect::<Vec<_>>());
    }

    proptest! {
        #[test]
        fn every_length_is_handled(xs in proptest::collection::vec(-10f32..10.0, 0..40)) {
            let plain: f64 = xs.iter().map(|&v| f64::from(v)).sum();
            prop_assert!((f64::from(sum(&xs)) - plain).abs() < 1e-4);
            let squares: f64 = xs.iter().map(|&v| f64::from(v) * f64::from(v)).sum();
            prop_assert!((f64::from(dot(&xs, &xs)) - squares).abs() < 1e-4 * (1.0 + squares));
            let mut e = xs.clone();
            exp_in_place(&mut e);
            for (x, y) in xs.iter().zip(&e) {
                prop_assert!((y - x.exp()).abs() <= 4.0 * f32::EPSILON * x.exp());
            }
        }
    }
}
