//! Pass `coc` (section 28.5.3, fig. 28-6): view-axis depth to a signed blur amount.
//!
//! Reads the full-resolution depth; writes `s` in [-1, 1] per pixel: `-near` where the pixel is
//! in front of the in-focus range, `+min(far * far_to_near_ratio, 1)` behind it, 0 in focus and
//! for sky (depth > `sky_depth_m`). A blur amount of 1 is the large blur level. The chapter
//! computes the near amount in its downsample shader (Listing 28-1, `saturate(dofEqWorld.x *
//! depth + dofEqWorld.y)`) and the far amount in the final shader (Listing 28-4, `dofEqFar`);
//! here both come from this one pass.

use rayon::prelude::*;

use super::{saturate, Constants, Curve};
use crate::image::GrayImage;
use crate::{Error, Result};

/// Fills one row of signed blur amounts from one row of depths, with `near_far(z)` giving the
/// unclamped near and far amounts. Returns true if some depth is not > 0 (or NaN).
#[inline(always)]
fn fill_row(
    out: &mut [f32],
    depth: &[f32],
    k: &Constants,
    near_far: impl Fn(f32) -> (f32, f32),
) -> bool {
    let mut bad = false;
    for (o, &z) in out.iter_mut().zip(depth) {
        bad |= z.is_nan() | (z <= 0.0);
        let (near, far) = near_far(z);
        // `saturate` maps NaN (0 * inf for a disabled artist side at infinite depth) to 0.
        let far = if z > k.sky_depth_m {
            0.0
        } else {
            saturate(saturate(far) * k.far_to_near_ratio)
        };
        // The artist ranges are ordered and the lens CoC has one sign, so one of them is 0.
        *o = far - saturate(near);
    }
    bad
}

/// Fills one row for the frame's curve. Compiled for several instruction sets and chosen at
/// run time ([`multiversion`]); the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn row(out: &mut [f32], depth: &[f32], k: &Constants) -> bool {
    match k.curve {
        Curve::Physical {
            lens,
            inv_large_blur_coc_px,
        } => fill_row(out, depth, k, |z| {
            let t = lens.coc_px(z) * inv_large_blur_coc_px;
            (-t, t)
        }),
        Curve::Artist {
            near_scale,
            near_bias,
            far_scale,
            far_bias,
        } => fill_row(out, depth, k, |z| {
            (near_scale * z + near_bias, far_scale * z + far_bias)
        }),
    }
}

/// Converts `depth` (view-axis metres, > 0, +inf for sky) to signed blur amounts.
///
/// Fails with [`Error::Mismatch`] if `depth` is not the frame size of `k`, and with
/// [`Error::Invalid`] naming the first pixel (in row order) whose depth is NaN, zero or negative.
pub fn coc(depth: &GrayImage, k: &Constants) -> Result<GrayImage> {
    let (w, h) = (depth.width(), depth.height());
    if (w, h) != (k.width(), k.height()) {
        return Err(Error::Mismatch(format!(
            "depth is {w}x{h} but the constants are for {}x{}",
            k.width(),
            k.height()
        )));
    }
    let mut out = vec![0.0f32; w * h];
    let bad_rows: Vec<bool> = out
        .par_chunks_mut(w)
        .zip(depth.pixels().par_chunks(w))
        .map(|(o, d)| row(o, d, k))
        .collect();
    if let Some(y) = bad_rows.iter().position(|&b| b) {
        let row = depth.row(y);
        let x = row
            .iter()
            .position(|&z| z.is_nan() || z <= 0.0)
            .unwrap_or(0);
        return Err(Error::invalid(
            "depth",
            format!(
                "pixel ({x}, {y}) has depth {} m: expected a view-axis distance in metres \
                 greater than 0 (+inf for sky)",
                row[x]
            ),
        ));
    }
    GrayImage::from_vec(w, h, out)
}
