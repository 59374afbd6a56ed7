//! Rank-r decomposition of a kernel by the singular value decomposition (McGraw section 3,
//! eqs. 1-4).
//!
//! `k = U S V^T` (eq. 2), computed by nalgebra in f64. With the scaled singular vectors
//! `u'_i = sqrt(s_i) u_i` (column `i` of U, length = kernel height, the vertical filter) and
//! `v'_i = sqrt(s_i) v_i` (column `i` of V, length = kernel width, the horizontal filter), the
//! rank-r approximation is `k_r = sum_{i<r} u'_i v'_i^T` (eq. 1), the nearest rank-r matrix in
//! the Frobenius norm, and its relative error is (eq. 4)
//!
//! `e_r = ||k - k_r||_F / ||k||_F = sqrt(s_{r+1}^2 + ... + s_m^2) / sqrt(s_1^2 + ... + s_m^2)`.
//!
//! Eq. 3 as printed gives the tail sum of squares without the square root, i.e. the squared
//! norm; we use the norm, so that eq. 4 is a ratio of norms.
//!
//! The sign of each pair (u_i, v_i) is arbitrary in an SVD; we fix it so that `v'_i` sums to a
//! non-negative value (then `u'_1` and `v'_1` of a non-negative kernel are non-negative).

use nalgebra::DMatrix;

use super::kernel::MAX_KERNEL_PX;
use crate::image::GrayImage;
use crate::{Error, Result};

/// A kernel's singular values and scaled singular vectors.
#[derive(Clone, Debug, PartialEq)]
pub struct LowRank {
    width: usize,
    height: usize,
    singular_values: Vec<f64>,
    /// `u'_i`, each of length `height`.
    vertical: Vec<Vec<f64>>,
    /// `v'_i`, each of length `width`.
    horizontal: Vec<Vec<f64>>,
}

/// Decomposes `kernel` (any size up to [`MAX_KERNEL_PX`] a side, finite values, not all zero).
///
/// Row `j`, column `i` of the kernel is the matrix entry `k[j][i]`: `u'` filters vertically
/// (along columns), `v'` horizontally (along rows).
pub fn decompose(kernel: &GrayImage) -> Result<LowRank> {
    let (w, h) = (kernel.width(), kernel.height());
    if w == 0 || h == 0 || w > MAX_KERNEL_PX || h > MAX_KERNEL_PX {
        return Err(Error::invalid(
            "kernel",
            format!("{w}x{h}: expected 1 to {MAX_KERNEL_PX} pixels a side"),
        ));
    }
    if let Some(v) = kernel.pixels().iter().find(|v| !v.is_finite()) {
        return Err(Error::invalid(
            "kernel",
            format!("value {v}: expected finite values"),
        ));
    }
    if kernel.pixels().iter().all(|&v| v == 0.0) {
        return Err(Error::invalid(
            "kernel",
            "all values are 0: nothing to decompose",
        ));
    }
    let m = DMatrix::<f64>::from_fn(h, w, |j, i| kernel.get(i, j) as f64);
    let svd = m
        .try_svd(true, true, f64::EPSILON, 1000 * (w + h))
        .ok_or_else(|| Error::invalid("kernel", "the SVD did not converge"))?;
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(Error::invalid(
            "kernel",
            "the SVD returned no singular vectors",
        ));
    };
    // Sorted by nalgebra in descending order; sort again so we do not depend on it.
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let mut singular_values = Vec::with_capacity(order.len());
    let mut vertical = Vec::with_capacity(order.len());
    let mut horizontal = Vec::with_capacity(order.len());
    for &k in &order {
        let s = svd.singular_values[k].max(0.0);
        let root = s.sqrt();
        let mut col: Vec<f64> = (0..h).map(|j| u[(j, k)] * root).collect();
        let mut row: Vec<f64> = (0..w).map(|i| v_t[(k, i)] * root).collect();
        if row.iter().sum::<f64>() < 0.0 {
            col.iter_mut().for_each(|x| *x = -*x);
            row.iter_mut().for_each(|x| *x = -*x);
        }
        singular_values.push(s);
        vertical.push(col);
        horizontal.push(row);
    }
    Ok(LowRank {
        width: w,
        height: h,
        singular_values,
        vertical,
        horizontal,
    })
}

impl LowRank {
    /// Singular values `s_1 >= s_2 >= ... >= s_m >= 0`, `m = min(width, height)`.
    pub fn singular_values(&self) -> &[f64] {
        &self.singular_values
    }

    /// Kernel width in pixels (length of the horizontal vectors).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Kernel height in pixels (length of the vertical vectors).
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of singular pairs, `min(width, height)`: the largest usable rank.
    pub fn len(&self) -> usize {
        self.singular_values.len()
    }

    /// Always false: a decomposition has at least one singular pair.
    pub fn is_empty(&self) -> bool {
        self.singular_values.is_empty()
    }

    /// Scaled vertical vector `u'_i = sqrt(s_i) u_i` (length `height`), `i` from 0; `None` past
    /// the last pair.
    pub fn vertical(&self, i: usize) -> Option<&[f64]> {
        self.vertical.get(i).map(Vec::as_slice)
    }

    /// Scaled horizontal vector `v'_i = sqrt(s_i) v_i` (length `width`), `i` from 0; `None`
    /// past the last pair.
    pub fn horizontal(&self, i: usize) -> Option<&[f64]> {
        self.horizontal.get(i).map(Vec::as_slice)
    }

    /// Relative Frobenius error of the rank-`rank` approximation (eq. 4): 1 for rank 0, 0 from
    /// the full rank on.
    pub fn relative_error(&self, rank: usize) -> f64 {
        let total: f64 = self.singular_values.iter().map(|s| s * s).sum();
        let tail: f64 = self.singular_values.iter().skip(rank).map(|s| s * s).sum();
        if total > 0.0 {
            (tail / total).sqrt()
        } else {
            0.0
        }
    }

    /// Numerical rank: the number of singular values above `s_1 * max(width, height) * eps`
    /// (f64 epsilon), the usual tolerance (MATLAB's `rank`, NumPy's `matrix_rank`).
    pub fn full_rank(&self) -> usize {
        self.rank_above(self.tolerance())
    }

    /// The tolerance used by [`LowRank::full_rank`].
    pub fn tolerance(&self) -> f64 {
        let s1 = self.singular_values.first().copied().unwrap_or(0.0);
        s1 * self.width.max(self.height) as f64 * f64::EPSILON
    }

    /// Number of singular values strictly above `tolerance`.
    pub fn rank_above(&self, tolerance: f64) -> usize {
        self.singular_values
            .iter()
            .filter(|&&s| s > tolerance)
            .count()
    }

    /// Sum of the entries of the rank-`rank` approximation: `sum_i (sum u'_i)(sum v'_i)`.
    pub fn approximation_sum(&self, rank: usize) -> f64 {
        self.vertical
            .iter()
            .zip(&self.horizontal)
            .take(rank)
            .map(|(u, v)| u.iter().sum::<f64>() * v.iter().sum::<f64>())
            .sum()
    }

    /// The rank-`rank` approximation `sum_{i<rank} u'_i v'_i^T` as an image (`rank` is capped
    /// at [`LowRank::len`]; rank 0 gives zeros).
    pub fn approximation(&self, rank: usize) -> GrayImage {
        let (w, h) = (self.width, self.height);
        let mut acc = vec![0.0f64; w * h];
        for (u, v) in self.vertical.iter().zip(&self.horizontal).take(rank) {
            for (j, &uj) in u.iter().enumerate() {
                for (a, &vi) in acc[j * w..(j + 1) * w].iter_mut().zip(v) {
                    *a += uj * vi;
                }
            }
        }
        let mut image = GrayImage::new(w, h, 0.0);
        for (p, &a) in image.pixels_mut().iter_mut().zip(&acc) {
            *p = a as f32;
        }
        image
    }
}
