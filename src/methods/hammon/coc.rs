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
    if bad_rows.contains(&true) {
        return Err(invalid_depth(depth));
    }
    GrayImage::from_vec(w, h, out)
}

/// The error for the first pixel of `depth` (in row order) whose depth is NaN, zero or
/// negative (pixel (0, 0) if there is none).
pub(crate) fn invalid_depth(depth: &GrayImage) -> Error {
    let w = depth.width();
    let i = depth
        .pixels()
        .iter()
        .position(|&z| z.is_nan() || z <= 0.0)
        .unwrap_or(0);
    let (x, y) = (i % w, i / w);
    Error::invalid(
        "depth",
        format!(
            "pixel ({x}, {y}) has depth {} m: expected a view-axis distance in metres \
             greater than 0 (+inf for sky)",
            depth.pixels()[i]
        ),
    )
}

/// Where a pass reads the signed blur amounts `s`.
#[derive(Clone, Copy, Debug)]
pub enum Amounts<'a> {
    /// Computed beforehand by [`coc`].
    Signed(&'a GrayImage),
    /// Computed from view-axis depth row by row as the pass reads them, as the chapter's
    /// downsample and final shaders do: no full-resolution image of `s` is written or read
    /// back. The depth is validated as [`coc`] does.
    Depth(&'a GrayImage, &'a Constants),
}

impl<'a> From<&'a GrayImage> for Amounts<'a> {
    fn from(s: &'a GrayImage) -> Self {
        Amounts::Signed(s)
    }
}

impl Amounts<'_> {
    /// The image the amounts come from: the CoC image or the depth.
    fn image(&self) -> &GrayImage {
        let (Amounts::Signed(image) | Amounts::Depth(image, _)) = self;
        image
    }

    /// Width and height of the image the amounts come from.
    pub fn size(&self) -> (usize, usize) {
        (self.image().width(), self.image().height())
    }

    /// Fails unless the amounts are `width` x `height` (and, from depth, the constants are for
    /// that size too).
    pub(crate) fn check_size(&self, what: &str, width: usize, height: usize) -> Result<()> {
        let (w, h) = self.size();
        let (source, k_size) = match self {
            Amounts::Signed(_) => ("CoC image", None),
            Amounts::Depth(_, k) => ("depth", Some((k.width(), k.height()))),
        };
        if (w, h) != (width, height) {
            return Err(Error::Mismatch(format!(
                "{what} is {width}x{height} but the {source} is {w}x{h}"
            )));
        }
        if let Some((kw, kh)) = k_size.filter(|&s| s != (w, h)) {
            return Err(Error::Mismatch(format!(
                "depth is {w}x{h} but the constants are for {kw}x{kh}"
            )));
        }
        Ok(())
    }

    /// Rows `y0..y1` of `s`, contiguous: a slice of the image, or computed from depth into
    /// `scratch`. The flag is true if some depth among them is not > 0 (or NaN).
    #[inline(always)]
    pub(crate) fn rows<'b>(
        &'b self,
        y0: usize,
        y1: usize,
        scratch: &'b mut [f32],
    ) -> (&'b [f32], bool) {
        let w = self.image().width();
        let range = w * y0..w * y1;
        match self {
            Amounts::Signed(s) => (&s.pixels()[range], false),
            Amounts::Depth(depth, k) => {
                let out = &mut scratch[..range.len()];
                // The dispatched function, not its body inlined into the pass: inlined into
                // the passes' row loops, the AVX2 build stayed scalar (callgrind: 22
                // instructions per pixel, against 2.7 here).
                let bad = row(out, &depth.pixels()[range], k);
                (out, bad)
            }
        }
    }

    /// The error for a pass that found bad depth (see [`Self::rows`]).
    pub(crate) fn error(&self) -> Error {
        invalid_depth(self.image())
    }
}
