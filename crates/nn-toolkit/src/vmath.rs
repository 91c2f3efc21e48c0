//! Element-wise `exp`, `ln` and `erf` of `f32` written for the compiler's vectoriser, the sums
//! of the kernels of [`crate::fused`] and `quadformer_model::js`, and [`vectorized`], which runs a loop
//! with the widest vector instructions the processor has.
//!
//! The standard library's `f32::exp`/`ln` call the C library one element at a time, and
//! candle's `erf` is `libm::erff`; together they were about a fifth of a training step
//! (perf, `examples/profile.rs train`). The functions here have no branches and no calls, so
//! a loop over a slice compiles to SIMD instructions:
//!
//! - `exp` and `ln` are the Cephes single-precision polynomials (S. L. Moshier, Cephes Math
//!   Library, `expf.c` and `logf.c`), within a few units in the last place (tested against
//!   the standard library); `exp` of arguments below `−87.3` (results below the smallest
//!   normal `f32`) is 0, so no denormal is ever produced.
//! - `ln_fast` replaces the Cephes polynomial by one division and a cubic in `s²`
//!   (`ln m = 2 atanh s`, `s = (m − 1)/(m + 1)`): about four fifths of the time of `ln`, within
//!   1.4 units in the last place of the exact value (`ln`: 0.7; both measured over the positive
//!   `f32` range). The streaming engine's TCD uses it (`quadformer_model::streaming`); training and batch
//!   scoring use `ln`.
//! - `erf` is Abramowitz & Stegun 7.1.26,
//!   `erf(x) = 1 − (a₁t + a₂t² + a₃t³ + a₄t⁴ + a₅t⁵) e^{−x²}`, `t = 1/(1 + p|x|)`, odd in `x`,
//!   with an absolute error below `1.5·10⁻⁷` (Handbook of Mathematical Functions, 1964,
//!   §7.1.26); evaluated in `f32` it stays below `5·10⁻⁷` (tested).
//!
//! [`vectorized`] compiles its closure a second time for AVX2 with FMA (x86-64-v3) and picks
//! that version at run time when the processor has it (`pulp::Arch`, the dispatch candle's
//! matrix products use). The portable x86-64 build has only 4-wide SSE2. Nothing here
//! contracts `a·b + c` into a fused multiply-add, so both versions round identically: these
//! functions give the same bits on every x86-64 processor (a test checks it). candle's matrix
//! products, which use FMA where the processor has it, are not bit-identical across processors.

/// Runs `f` compiled for the best instruction set the processor has (module docs). Loops in
/// `f` over the functions of this module vectorise with it. Mark the closure
/// `#[inline(always)]`: a closure the compiler keeps out of line is compiled for the portable
/// target only.
#[inline(always)]
pub fn vectorized<R>(f: impl FnOnce() -> R) -> R {
    pulp::Arch::new().dispatch(f)
}

/// `ln 2` split in a part exact in a few bits and the rest (Cody–Waite reduction).
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;

/// `e^x` (Cephes `expf`; 0 below `−87.34`, `+∞` above `88.38` (the exact result overflows at
/// 88.72), NaN stays NaN).
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    // 1.5·2²³: adding it rounds to an integer, which its low mantissa bits then hold.
    const ROUND: f32 = 12_582_912.0;
    const LO: f32 = -87.336_55; // ln of the smallest normal f32
    const HI: f32 = 88.376_26; // ln(2¹²⁷·(2 − 2⁻²³)) rounded down, so 2ⁿ stays finite
    let xc = x.clamp(LO, HI);
    let t = xc * LOG2E + ROUND;
    let n = t - ROUND;
    // n in two's complement (wrapping: a NaN argument gives bits, not an overflow).
    let k = t.to_bits().wrapping_sub(ROUND.to_bits());
    let r = (xc - n * LN2_HI) - n * LN2_LO;
    // Cephes's last coefficient, 5.0000001201e−1, is 0.5 in f32.
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r + 1.666_666_5e-1)
        * r
        + 0.5;
    let er = p * (r * r) + r + 1.0;
    let y = er * f32::from_bits(k.wrapping_add(127) << 23);
    if x < LO {
        0.0
    } else if x > HI {
        f32::INFINITY
    } else {
        y
    }
}

/// `(e, m)` with `x = 2ᵉ m`, `m ∈ [√½, √2)`, for the logarithms (denormals are scaled by
/// `2²³` into the normal range first; meaningless for `x ≤ 0`, ∞ and NaN, which
/// [`ln_special`] handles).
#[inline(always)]
fn ln_reduce(x: f32) -> (f32, f32) {
    let tiny = x < f32::MIN_POSITIVE;
    let xs = if tiny { x * 8_388_608.0 } else { x };
    let bits = xs.to_bits();
    let e0 = ((bits >> 23) & 0xff) as i32 - 126 - if tiny { 23 } else { 0 };
    // Mantissa in [0.5, 1), doubled below √½ (exact).
    let m0 = f32::from_bits((bits & 0x807f_ffff) | 0x3f00_0000);
    let below = m0 < std::f32::consts::FRAC_1_SQRT_2;
    ((e0 - i32::from(below)) as f32, if below { m0 + m0 } else { m0 })
}

/// `ln x` from its value `r` for positive finite `x`: `x` itself for NaN and `+∞`, `−∞` at 0,
/// NaN below 0.
#[inline(always)]
fn ln_special(x: f32, r: f32) -> f32 {
    if x.is_nan() || x == f32::INFINITY {
        x
    } else if x == 0.0 {
        f32::NEG_INFINITY
    } else if x < 0.0 {
        f32::NAN
    } else {
        r
    }
}

/// `ln x` (Cephes `logf`; `−∞` at 0, NaN below 0, denormals handled).
#[inline(always)]
pub fn ln(x: f32) -> f32 {
    let (e, m) = ln_reduce(x);
    let m = m - 1.0;
    let z = m * m;
    let p = (((((((7.037_683_6e-2 * m - 1.151_461e-1) * m + 1.167_699_9e-1) * m - 1.242_014_1e-1) * m
        + 1.424_932_3e-1)
        * m
        - 1.666_805_8e-1)
        * m
        + 2.000_071_4e-1)
        * m
        - 2.499_999_4e-1)
        * m
        + 3.333_333e-1;
    let y = p * m * z + e * LN2_LO - 0.5 * z;
    ln_special(x, m + y + e * LN2_HI)
}

/// `ln x` through `atanh` (module docs): `x = 2ᵉ m` with `m ∈ [√½, √2)`,
/// `s = (m − 1)/(m + 1)`, `ln m = 2 atanh s = 2s + s z P(z)`, `z = s²`, `P` the Taylor series
/// of `atanh` to `z³` (truncation below `10⁻⁹` relative for `|s| ≤ 0.172`). `−∞` at 0, NaN
/// below 0, denormals handled.
#[inline(always)]
pub fn ln_fast(x: f32) -> f32 {
    let (e, m) = ln_reduce(x);
    let s = (m - 1.0) / (m + 1.0);
    let z = s * s;
    let p = ((0.222_222_22 * z + 0.285_714_3) * z + 0.4) * z + 0.666_666_7;
    ln_special(x, e * LN2_HI + ((s + s) + (s * z * p + e * LN2_LO)))
}

/// `erf x` (Abramowitz & Stegun 7.1.26, module docs).
#[inline(always)]
pub fn erf(x: f32) -> f32 {
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [0.254_829_6, -0.284_496_74, 1.421_413_8, -1.453_152, 1.061_405_4];
    let ax = x.abs();
    let t = 1.0 / (P * ax + 1.0);
    let poly = (((A[4] * t + A[3]) * t + A[2]) * t + A[1]) * t + A[0];
    let magnitude = 1.0 - poly * t * exp(-(ax * ax));
    // erf is odd.
    magnitude.copysign(x)
}

/// `Σᵢ xᵢ`, in eight interleaved partial sums (which vectorise; a plain running sum is one
/// dependent addition per element). The order is fixed, so the result is too.
#[inline(always)]
pub fn sum(xs: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let mut chunks = xs.chunks_exact(8);
    for c in &mut chunks {
        for (a, v) in acc.iter_mut().zip(c) {
            *a += v;
        }
    }
    reduce(acc) + chunks.remainder().iter().sum::<f32>()
}

/// `Σᵢ aᵢ bᵢ` over the common length, summed as [`sum`].
#[inline(always)]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    let n = a.len().min(b.len());
    let mut acc = [0f32; 8];
    let (mut ca, mut cb) = (a[..n].chunks_exact(8), b[..n].chunks_exact(8));
    for (x, y) in (&mut ca).zip(&mut cb) {
        for ((s, u), v) in acc.iter_mut().zip(x).zip(y) {
            *s += u * v;
        }
    }
    reduce(acc) + ca.remainder().iter().zip(cb.remainder()).map(|(x, y)| x * y).sum::<f32>()
}

/// `maxᵢ xᵢ` (`−∞` for an empty slice; NaN elements are skipped), in eight lanes.
#[inline(always)]
pub fn max(xs: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; 8];
    let mut chunks = xs.chunks_exact(8);
    for c in &mut chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a = if v > *a { v } else { *a };
        }
    }
    acc.into_iter().chain(chunks.remainder().iter().copied()).fold(f32::NEG_INFINITY, |a, v| if v > a { v } else { a })
}

/// How many rows of `len` values to take together for their length to be a whole number of
/// eight-lane vectors (`8 / gcd(len, 8)`): a loop over the block then leaves no remainder to
/// scalar code, where a loop over each row would (4 of 100 values, at several times the cost
/// per value).
pub fn row_block(len: usize) -> usize {
    let (mut a, mut b) = (len, 8);
    while b != 0 {
        (a, b) = (b, a % b);
    }
    // `a` divides 8 (for `len` = 0 it is 8).
    8 / a.max(1)
}

/// The eight partial sums added pairwise.
#[inline(always)]
fn reduce(a: [f32; 8]) -> f32 {
    ((a[0] + a[4]) + (a[2] + a[6])) + ((a[1] + a[5]) + (a[3] + a[7]))
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// `f` of every element of `xs`, looped inside [`vectorized`] as the kernels do.
    #[inline(always)]
    fn dispatched(xs: &[f32], f: impl Fn(f32) -> f32) -> Vec<f32> {
        let mut out = xs.to_vec();
        vectorized(
            #[inline(always)]
            || {
                for v in out.iter_mut() {
                    *v = f(*v);
                }
            },
        );
        out
    }

    fn grid(lo: f32, hi: f32, n: usize) -> Vec<f32> {
        (0..n).map(|i| lo + (hi - lo) * i as f32 / (n - 1) as f32).collect()
    }

    #[test]
    fn exp_and_ln_match_the_standard_library() {
        let xs = grid(-87.0, 88.0, 10_001);
        let e = dispatched(&xs, exp);
        for (x, y) in xs.iter().zip(&e) {
            let want = x.exp();
            assert!((y - want).abs() <= 4.0 * f32::EPSILON * want, "exp({x}) = {y}, want {want}");
        }
        let xs: Vec<f32> = grid(-30.0, 30.0, 10_001).iter().map(|v| v.exp()).chain([1e-8, 1.0, 2.0, 1e-40]).collect();
        let l = dispatched(&xs, ln);
        for (x, y) in xs.iter().zip(&l) {
            let want = x.ln();
            assert!((y - want).abs() <= 4.0 * f32::EPSILON * want.abs().max(1.0), "ln({x}) = {y}, want {want}");
        }
    }

    #[test]
    fn row_blocks_are_whole_vectors() {
        for (len, rows) in [(100, 2), (96, 1), (12, 2), (3, 8), (0, 1)] {
            assert_eq!(row_block(len), rows, "rows of {len}");
        }
    }

    #[test]
    fn ln_fast_is_within_one_and_a_half_units_in_the_last_place() {
        // Every 997th f32 from 10⁻³⁷ to 10³⁰, against the f64 logarithm.
        let xs: Vec<f32> = std::iter::successors(Some(1e-37f32), |x| Some(f32::from_bits(x.to_bits() + 997)))
            .take_while(|&x| x < 1e30)
            .collect();
        let ys = dispatched(&xs, ln_fast);
        let ulps = |x: f32, y: f32| {
            let exact = f64::from(x).ln();
            (f64::from(y) - exact).abs() / (f64::from(f32::EPSILON) * exact.abs().max(f64::from(f32::MIN_POSITIVE)))
        };
        let worst = xs.iter().zip(&ys).map(|(&x, &y)| ulps(x, y)).fold(0.0, f64::max);
        assert!(worst < 1.5, "worst {worst} ulp");
        let l = dispatched(&[0.0, -1.0, 1.0, f32::INFINITY, f32::NAN, f32::MIN_POSITIVE / 4.0], ln_fast);
        assert_eq!([l[0], l[2], l[3]], [f32::NEG_INFINITY, 0.0, f32::INFINITY]);
        assert!(l[1].is_nan() && l[4].is_nan());
        assert!((l[5] - (f32::MIN_POSITIVE / 4.0).ln()).abs() < 1e-5);
    }

    #[test]
    fn special_values_follow_the_standard_library() {
        let e = dispatched(&[-100.0, -87.5, 0.0, 89.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN], exp);
        assert_eq!(e[..6], [0.0, 0.0, 1.0, f32::INFINITY, f32::INFINITY, 0.0]);
        assert!(e[6].is_nan());
        let l = dispatched(&[0.0, -1.0, 1.0, f32::INFINITY, f32::NAN, f32::MIN_POSITIVE / 4.0], ln);
        assert_eq!([l[0], l[2], l[3]], [f32::NEG_INFINITY, 0.0, f32::INFINITY]);
        assert!(l[1].is_nan() && l[4].is_nan());
        assert!((l[5] - (f32::MIN_POSITIVE / 4.0).ln()).abs() < 1e-5);
    }

    #[test]
    fn erf_is_within_the_published_bound_and_odd() {
        let xs = grid(-6.0, 6.0, 12_001);
        let e = dispatched(&xs, erf);
        let worst =
            xs.iter().zip(&e).map(|(x, y)| (f64::from(*y) - libm::erf(f64::from(*x))).abs()).fold(0.0, f64::max);
        // 1.5e-7 (A&S) plus the rounding of its evaluation in f32.
        assert!(worst < 5e-7, "largest error {worst}");
        let (a, b) = (dispatched(&[0.7, 3.0], erf), dispatched(&[-0.7, -3.0], erf));
        assert_eq!(a, b.iter().map(|v| -v).collect::<Vec<_>>());
    }

    #[test]
    fn the_dispatched_loops_round_as_the_portable_build() {
        // `dispatched` runs through `vectorized` (AVX2 where the processor has it); the scalar
        // calls here are compiled for the portable target.
        let xs = grid(-20.0, 20.0, 4_001);
        let abs: Vec<f32> = xs.iter().map(|v| v.abs()).collect();
        let (e, f, l) = (dispatched(&xs, exp), dispatched(&xs, erf), dispatched(&abs, ln));
        let lf = dispatched(&abs, ln_fast);
        for (i, &x) in xs.iter().enumerate() {
            assert_eq!(lf[i].to_bits(), std::hint::black_box(ln_fast)(abs[i]).to_bits(), "ln_fast({})", abs[i]);
            assert_eq!(e[i].to_bits(), std::hint::black_box(exp)(x).to_bits(), "exp({x})");
            assert_eq!(f[i].to_bits(), std::hint::black_box(erf)(x).to_bits(), "erf({x})");
            assert_eq!(l[i].to_bits(), std::hint::black_box(ln)(abs[i]).to_bits(), "ln({})", abs[i]);
        }
    }

    proptest! {
        #[test]
        fn every_length_is_handled(xs in proptest::collection::vec(-10f32..10.0, 0..40)) {
            let plain: f64 = xs.iter().map(|&v| f64::from(v)).sum();
            prop_assert!((f64::from(sum(&xs)) - plain).abs() < 1e-4);
            let squares: f64 = xs.iter().map(|&v| f64::from(v) * f64::from(v)).sum();
            prop_assert!((f64::from(dot(&xs, &xs)) - squares).abs() < 1e-4 * (1.0 + squares));
            prop_assert_eq!(max(&xs), xs.iter().copied().fold(f32::NEG_INFINITY, f32::max));
            let e = dispatched(&xs, exp);
            for (x, y) in xs.iter().zip(&e) {
                prop_assert!((y - x.exp()).abs() <= 4.0 * f32::EPSILON * x.exp());
            }
        }
    }
}
