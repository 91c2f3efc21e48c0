//! Bounds-checked matrix products on strided `f32` views of slices, for the streaming engines
//! (`quadformer_model::streaming`, `baselines::lstm_online`): the `gemm` crate's kernel (the one
//! candle's CPU `matmul` calls) writing into a caller-owned buffer, so that a streaming decision
//! allocates and zero-fills nothing. Called with the shapes candle's `matmul` gives the
//! kernel, and the same strides wherever the kernel reads them, it computes candle's product
//! bit for bit (`products_are_candles_bit_for_bit`).
//!
//! `gemm::gemm` takes raw pointers and strides. [`matmul`] accepts only views whose every
//! element lies inside its slice ([`MatRef::new`], [`MatMut::new`]) and whose shapes agree; the
//! borrow checker keeps the destination apart from the inputs. Those are the whole of the
//! kernel's safety requirements, and the one `unsafe` block of this module relies on them.

use crate::error::{NnError, Result};

/// Checks that a `rows × cols` view with strides `rs`, `cs` fits in `len` elements.
fn fits(what: &str, len: usize, rows: usize, cols: usize, rs: usize, cs: usize) -> Result<()> {
    if rows == 0 || cols == 0 {
        return Err(NnError::Data { msg: format!("matmul: empty {what} view {rows} × {cols}") });
    }
    let last = (rows - 1).checked_mul(rs).zip((cols - 1).checked_mul(cs)).and_then(|(a, b)| a.checked_add(b));
    match last {
        Some(i) if i < len && isize::try_from(rs.max(cs)).is_ok() => Ok(()),
        _ => Err(NnError::Data {
            msg: format!("matmul: {what} view {rows} × {cols} (strides {rs}, {cs}) overruns its {len} elements"),
        }),
    }
}

/// A read-only `rows × cols` matrix whose element `(i, j)` is `data[i·rs + j·cs]`.
#[derive(Debug, Clone, Copy)]
pub struct MatRef<'a> {
    data: &'a [f32],
    rows: usize,
    cols: usize,
    rs: usize,
    cs: usize,
}

impl<'a> MatRef<'a> {
    /// A strided view.
    ///
    /// # Errors
    /// [`NnError::Data`] when the view is empty or reaches past `data`.
    pub fn new(data: &'a [f32], rows: usize, cols: usize, rs: usize, cs: usize) -> Result<Self> {
        fits("input", data.len(), rows, cols, rs, cs)?;
        Ok(Self { data, rows, cols, rs, cs })
    }

    /// The row-major matrix `rows × cols` at the start of `data`.
    ///
    /// # Errors
    /// As [`MatRef::new`].
    pub fn rows(data: &'a [f32], rows: usize, cols: usize) -> Result<Self> {
        Self::new(data, rows, cols, cols, 1)
    }

    /// The transpose (no copy).
    pub fn t(self) -> Self {
        Self { rows: self.cols, cols: self.rows, rs: self.cs, cs: self.rs, ..self }
    }
}

/// A writable `rows × cols` matrix whose element `(i, j)` is `data[i·rs + j·cs]`.
#[derive(Debug)]
pub struct MatMut<'a> {
    data: &'a mut [f32],
    rows: usize,
    cols: usize,
    rs: usize,
    cs: usize,
}

impl<'a> MatMut<'a> {
    /// A strided view.
    ///
    /// # Errors
    /// [`NnError::Data`] when the view is empty or reaches past `data`.
    pub fn new(data: &'a mut [f32], rows: usize, cols: usize, rs: usize, cs: usize) -> Result<Self> {
        fits("output", data.len(), rows, cols, rs, cs)?;
        Ok(Self { data, rows, cols, rs, cs })
    }

    /// The row-major matrix `rows × cols` at the start of `data`.
    ///
    /// # Errors
    /// As [`MatMut::new`].
    pub fn rows(data: &'a mut [f32], rows: usize, cols: usize) -> Result<Self> {
        Self::new(data, rows, cols, cols, 1)
    }
}

/// `dst ← scale·a·b`, or `dst ← dst + scale·a·b` when `accumulate`.
///
/// # Errors
/// [`NnError::Data`] when the shapes do not agree.
#[allow(unsafe_code)]
pub fn matmul(dst: MatMut<'_>, a: MatRef<'_>, b: MatRef<'_>, scale: f32, accumulate: bool) -> Result<()> {
    if a.cols != b.rows || dst.rows != a.rows || dst.cols != b.cols {
        return Err(NnError::Data {
            msg: format!(
                "matmul: ({} × {}) · ({} × {}) into {} × {}",
                a.rows, a.cols, b.rows, b.cols, dst.rows, dst.cols
            ),
        });
    }
    // `fits` bounded every stride by isize::MAX.
    let s = |x: usize| x as isize;
    // SAFETY: every element the kernel reads or writes, `(i, j)` at `i·rs + j·cs` for `i` below
    // `rows` and `j` below `cols`, lies inside its slice (`fits`, checked by the constructors);
    // the shapes agree (checked above); `dst` is borrowed mutably, so it overlaps neither input.
    unsafe {
        gemm::gemm(
            dst.rows,
            dst.cols,
            a.cols,
            dst.data.as_mut_ptr(),
            s(dst.cs),
            s(dst.rs),
            accumulate,
            a.data.as_ptr(),
            s(a.cs),
            s(a.rs),
            b.data.as_ptr(),
            s(b.cs),
            s(b.rs),
            1.0,
            scale,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(a: &[f32], b: &[f32], n: usize, k: usize, p: usize) -> Vec<f32> {
        let mut c = vec![0f32; n * p];
        for i in 0..n {
            for j in 0..p {
                c[i * p + j] = (0..k).map(|t| a[i * k + t] * b[t * p + j]).sum();
            }
        }
        c
    }

    fn data(n: usize, seed: usize) -> Vec<f32> {
        (0..n).map(|i| ((i * 31 + seed * 7) % 17) as f32 / 8.0 - 1.0).collect()
    }

    #[test]
    fn products_of_row_major_and_transposed_views_match_the_naive_sum() {
        let (n, k, p) = (7, 5, 3);
        let (a, b) = (data(n * k, 1), data(k * p, 2));
        let want = naive(&a, &b, n, k, p);
        let mut c = vec![0f32; n * p];
        let bt: Vec<f32> = (0..p * k).map(|i| b[(i % k) * p + i / k]).collect();
        matmul(
            MatMut::rows(&mut c, n, p).unwrap(),
            MatRef::rows(&a, n, k).unwrap(),
            MatRef::rows(&bt, p, k).unwrap().t(),
            1.0,
            false,
        )
        .unwrap();
        for (x, y) in c.iter().zip(&want) {
            assert!((x - y).abs() < 1e-5, "{x} vs {y}");
        }
        // Accumulating twice the product onto it triples it.
        let (a_view, b_view) = (MatRef::rows(&a, n, k).unwrap(), MatRef::rows(&b, k, p).unwrap());
        matmul(MatMut::rows(&mut c, n, p).unwrap(), a_view, b_view, 2.0, true).unwrap();
        for (x, y) in c.iter().zip(&want) {
            assert!((x - 3.0 * y).abs() < 1e-4, "{x} vs {}", 3.0 * y);
        }
    }

    #[test]
    fn strided_column_blocks_are_products_of_their_columns() {
        // Columns 2..4 of a 3 × 6 matrix times a 2 × 2 matrix, written to columns 1..3 of 3 × 4.
        let a = data(18, 3);
        let b = data(4, 4);
        let mut c = [9f32; 12];
        matmul(
            MatMut::new(&mut c[1..], 3, 2, 4, 1).unwrap(),
            MatRef::new(&a[2..], 3, 2, 6, 1).unwrap(),
            MatRef::rows(&b, 2, 2).unwrap(),
            1.0,
            false,
        )
        .unwrap();
        for i in 0..3 {
            assert_eq!(c[i * 4], 9.0, "column 0 untouched");
            for j in 0..2 {
                let want = a[i * 6 + 2] * b[j] + a[i * 6 + 3] * b[2 + j];
                assert!((c[i * 4 + 1 + j] - want).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn views_past_their_slice_and_mismatched_shapes_are_errors() {
        let a = vec![0f32; 6];
        assert!(MatRef::new(&a, 2, 3, 3, 1).is_ok());
        assert!(MatRef::new(&a, 2, 4, 3, 1).is_err());
        assert!(MatRef::new(&a, 3, 3, 3, 1).is_err());
        assert!(MatRef::new(&a, 0, 3, 3, 1).is_err());
        let mut c = vec![0f32; 4];
        let r = matmul(
            MatMut::rows(&mut c, 2, 2).unwrap(),
            MatRef::rows(&a, 2, 3).unwrap(),
            MatRef::rows(&a, 2, 3).unwrap(),
            1.0,
            false,
        );
        assert!(r.is_err());
    }

    /// `a · bᵀ` through [`matmul`] and through candle, for the products of the streaming
    /// engines: a row by a transposed weight, a narrowed row (row stride `2h`, as `[h | c]`
    /// holds `h`) by a transposed weight, and a block of rows by a column; with `4h` on both
    /// sides of 256, where the kernel's row-vector path ends.
    #[test]
    fn products_are_candles_bit_for_bit() {
        use candle_core::{Device, IndexOp, Tensor};
        let dev = &Device::Cpu;
        for (rows, k, p, rs) in [(1, 7, 32, 7), (1, 64, 256, 128), (1, 65, 260, 130), (1, 7, 260, 7), (30, 64, 1, 64)] {
            let a = data(rows.max(2) * rs, 3);
            let w = data(p * k, 4);
            // candle: `a` narrowed to its first k columns of rows strided rs, times Wᵀ.
            let at = Tensor::from_slice(&a[..rows * rs], (rows, rs), dev).unwrap().i((.., ..k)).unwrap();
            let wt = Tensor::from_slice(&w, (p, k), dev).unwrap().t().unwrap();
            let want = at.matmul(&wt).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let mut c = vec![0f32; rows * p];
            let a_view = MatRef::new(&a, rows, k, rs, 1).unwrap();
            matmul(MatMut::rows(&mut c, rows, p).unwrap(), a_view, MatRef::rows(&w, p, k).unwrap().t(), 1.0, false)
                .unwrap();
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&c), bits(&want), "{rows} × {k} (row stride {rs}) · {k} × {p}");
        }
    }
}
