//! Image quality metrics, following the evaluation protocol of `DESIGN.md`.
//!
//! 1. [`mse_linear`]: mean squared error over R, G, B in linear light, unclamped (HDR errors
//!    count in full).
//! 2. [`psnr_srgb`] and [`ssim_srgb_luma`] measure what a viewer sees: each linear value is
//!    clamped to [0, 1] and sRGB-encoded ([`srgb_encode`]) first. PSNR is over R, G, B with
//!    peak 1. SSIM is Wang et al. 2004 on the luma Y = 0.299 R' + 0.587 G' + 0.114 B' (Rec. 601
//!    weights on encoded values), with an 11x11 Gaussian window of sigma 1.5, K1 = 0.01,
//!    K2 = 0.03, L = 1 and population (1/N) statistics, averaged over the windows that lie wholly
//!    inside the image. This equals scikit-image's `structural_similarity(x, y,
//!    gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1)` on the same
//!    luma arrays (checked in the tests).
//! 3. [`error_map`]: a false-colour picture of where two images differ.
//!
//! The alpha channel is ignored by every metric. Non-finite input values give NaN results (they
//! are not hidden).
//!
//! SSIM is computed with separable filtering: the five moment images x, y, x², y², xy are
//! filtered along rows, then along columns, rows in parallel. Sums run in a fixed order, so the
//! result does not depend on the thread count. The tests keep a direct windowed version from the
//! paper's equations and check that both agree.

use rayon::prelude::*;
use serde::Serialize;

use crate::image::{srgb_decode, srgb_encode, ColorImage, GrayImage};
use crate::{Error, Result};

/// Half width of the SSIM window in pixels: the window is 2 * 5 + 1 = 11 pixels wide.
pub const SSIM_WINDOW_RADIUS: usize = 5;
/// Standard deviation of the SSIM Gaussian window, in pixels.
pub const SSIM_SIGMA: f64 = 1.5;
/// SSIM stabilising constant for the means: C1 = (K1 L)², L = 1.
pub const SSIM_K1: f64 = 0.01;
/// SSIM stabilising constant for the (co)variances: C2 = (K2 L)², L = 1.
pub const SSIM_K2: f64 = 0.03;

/// Dynamic range L of the encoded values.
const DATA_RANGE: f64 = 1.0;

/// Luma weights (Rec. 601) applied to sRGB-encoded R, G, B before SSIM.
pub const LUMA_WEIGHTS: [f64; 3] = [0.299, 0.587, 0.114];

/// Fraction of pixels below the top of the [`error_map`] colour ramp (the 99th percentile).
pub const ERROR_MAP_PERCENTILE: f64 = 0.99;
/// Smallest sRGB difference mapped to the top of the [`error_map`] ramp, so that near-identical
/// images look dark instead of having their noise stretched to full scale.
pub const ERROR_MAP_MIN_TOP: f32 = 0.1;

/// The figures reported for a pair of images: see the module documentation for definitions.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Metrics {
    /// Mean squared error over R, G, B in linear light, unclamped.
    pub mse_linear: f64,
    /// PSNR in dB over sRGB-encoded R, G, B clamped to [0, 1], peak 1; infinite when the encoded
    /// images are identical (serialised as `null` by JSON writers).
    pub psnr_db: f64,
    /// Mean SSIM of the sRGB-encoded luma, in [-1, 1], 1 for identical images.
    pub ssim: f64,
}

/// Computes all of [`Metrics`] for `a` against `b` (symmetric). Refused, before its scratch
/// is allocated, when the two images and the scratch ([`compare_peak_bytes`]) exceed the
/// memory budget ([`crate::budget`]).
pub fn compare(a: &ColorImage, b: &ColorImage) -> Result<Metrics> {
    crate::budget::check(
        compare_peak_bytes(a.width(), a.height()),
        &format!("comparing {}x{} images", a.width(), a.height()),
        "the images' size",
    )?;
    Ok(Metrics {
        mse_linear: mse_linear(a, b)?,
        psnr_db: psnr_srgb(a, b)?,
        ssim: ssim_srgb_luma(a, b)?,
    })
}

/// Scratch bytes a pixel of [`compare`] can take besides the two images: the SSIM's luma
/// planes (2 x 8), its row-filtered moments (5 x 8) and its map (8), in double precision.
const COMPARE_BYTES_PER_PIXEL: u64 = 64;

/// Peak bytes of [`compare`] on two `width` x `height` images: the images (RGBA, 16 bytes a
/// pixel each) and the scratch. An [`error_map`] of them takes less (its difference, a copy
/// of it for the percentile and the map: 24 bytes a pixel).
pub fn compare_peak_bytes(width: usize, height: usize) -> u64 {
    (width * height) as u64
        * (2 * std::mem::size_of::<crate::image::Rgba>() as u64 + COMPARE_BYTES_PER_PIXEL)
}

/// Checks, from the headers of the image files `a` and `b` (no pixel decoded), that they have
/// one size and that reading them (`b` beside `a`) and comparing them ([`compare_peak_bytes`])
/// fit the memory budget ([`crate::budget`]); errors name the files and the budget. A header
/// that does not read is left to the read itself, whose error says what is wrong.
pub fn check_files(a: &std::path::Path, b: &std::path::Path) -> Result<()> {
    use crate::error::shown;
    use crate::image::io::{read_peak_bytes, ReadAs};
    let (Ok((read_a, (wa, ha))), Ok((read_b, (wb, hb)))) = (
        read_peak_bytes(a, ReadAs::Color),
        read_peak_bytes(b, ReadAs::Color),
    ) else {
        return Ok(());
    };
    if (wa, ha) != (wb, hb) {
        return Err(Error::Mismatch(format!(
            "{} is {wa}x{ha} but {} is {wb}x{hb}",
            shown(&a),
            shown(&b)
        )));
    }
    let check = |bytes: u64, what: String| crate::budget::check(bytes, &what, "the images' size");
    check(read_a, format!("decoding {} ({wa}x{ha})", shown(&a)))?;
    let image_bytes = (wa * ha) as u64 * std::mem::size_of::<crate::image::Rgba>() as u64;
    check(
        image_bytes + read_b,
        format!("decoding {} ({wb}x{hb}) beside {}", shown(&b), shown(&a)),
    )?;
    check(
        compare_peak_bytes(wa, ha),
        format!("comparing {} and {} ({wa}x{ha})", shown(&a), shown(&b)),
    )
}

/// Fails with [`Error::Mismatch`] naming both sizes unless the images have the same size, and
/// with [`Error::Invalid`] if they are empty.
fn check_same_size(a: &ColorImage, b: &ColorImage) -> Result<()> {
    if !a.same_size(b) {
        return Err(Error::Mismatch(format!(
            "cannot compare images of different sizes: {}x{} and {}x{}",
            a.width(),
            a.height(),
            b.width(),
            b.height()
        )));
    }
    if a.pixels().is_empty() {
        return Err(Error::invalid(
            "image size",
            format!(
                "cannot compare empty {}x{} images: expected at least one pixel",
                a.width(),
                a.height()
            ),
        ));
    }
    Ok(())
}

/// Mean over pixels and R, G, B of `f(a value, b value)`. Rows are summed in parallel and the row
/// sums added in order, so the result does not depend on the thread count.
fn mean_over_rgb(a: &ColorImage, b: &ColorImage, f: impl Fn(f32, f32) -> f64 + Sync) -> f64 {
    let w = a.width();
    let row_sums: Vec<f64> = a
        .pixels()
        .par_chunks(w)
        .zip(b.pixels().par_chunks(w))
        .map(|(ra, rb)| {
            ra.iter()
                .zip(rb)
                .map(|(p, q)| f(p[0], q[0]) + f(p[1], q[1]) + f(p[2], q[2]))
                .sum::<f64>()
        })
        .collect();
    row_sums.iter().sum::<f64>() / (3 * a.pixels().len()) as f64
}

/// Fails naming the image (`first` or `second`), pixel, channel and value when a colour value
/// is NaN or infinite: a metric over it would claim a perfect or a meaningless match.
fn check_finite(a: &ColorImage, b: &ColorImage) -> Result<()> {
    for (which, img) in [("first", a), ("second", b)] {
        if let Some((i, p)) = img
            .pixels()
            .iter()
            .enumerate()
            .find(|(_, p)| p.iter().any(|v| !v.is_finite()))
        {
            let k = p.iter().position(|v| !v.is_finite()).unwrap_or(0);
            return Err(Error::invalid(
                "image value",
                format!(
                    "the {which} image has {} in channel {} at pixel ({}, {}): metrics need finite values",
                    p[k],
                    ["R", "G", "B", "A"][k],
                    i % img.width().max(1),
                    i / img.width().max(1)
                ),
            ));
        }
    }
    Ok(())
}

/// Mean squared difference over R, G, B in linear light, no clamping. Fails on NaN or
/// infinite values.
pub fn mse_linear(a: &ColorImage, b: &ColorImage) -> Result<f64> {
    check_same_size(a, b)?;
    check_finite(a, b)?;
    Ok(mean_over_rgb(a, b, |p, q| {
        let d = p as f64 - q as f64;
        d * d
    }))
}

/// Peak signal-to-noise ratio in dB over R, G, B, each clamped to [0, 1] and sRGB-encoded,
/// peak 1: 10 log10(1 / MSE). `f64::INFINITY` when the encoded images are identical. Fails
/// on NaN or infinite values.
pub fn psnr_srgb(a: &ColorImage, b: &ColorImage) -> Result<f64> {
    check_same_size(a, b)?;
    check_finite(a, b)?;
    let mse = mean_over_rgb(a, b, |p, q| {
        let d = srgb_encode(p) as f64 - srgb_encode(q) as f64;
        d * d
    });
    Ok(if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    })
}

/// Mean SSIM of the sRGB-encoded luma of `a` and `b` (see the module documentation).
///
/// Images narrower or shorter than 11 pixels use the largest odd window that fits, radius
/// (min(width, height) - 1) / 2, with the same sigma 1.5, truncated and renormalised; a 1-pixel
/// side gives a 1x1 window (SSIM then compares only the means of single pixels).
pub fn ssim_srgb_luma(a: &ColorImage, b: &ColorImage) -> Result<f64> {
    check_finite(a, b)?;
    let (_, _, map) = ssim_valid(a, b)?;
    // Fixed-order sum: independent of the thread count.
    Ok(map.iter().sum::<f64>() / map.len() as f64)
}

/// The SSIM map whose mean is [`ssim_srgb_luma`]: one value per window lying wholly inside the
/// image, so it is smaller than the inputs by the window radius on each side (5 pixels for
/// images of at least 11x11). Pixel (i, j) of the map is the window centred on input pixel
/// (i + r, j + r).
pub fn ssim_map(a: &ColorImage, b: &ColorImage) -> Result<GrayImage> {
    let (w, h, map) = ssim_valid(a, b)?;
    GrayImage::from_vec(w, h, map.into_iter().map(|v| v as f32).collect())
}

/// The luma Y = 0.299 R' + 0.587 G' + 0.114 B' of the clamped, sRGB-encoded image, row-major.
pub fn srgb_luma(img: &ColorImage) -> Vec<f64> {
    img.pixels()
        .par_iter()
        .map(|p| {
            (0..3)
                .map(|c| LUMA_WEIGHTS[c] * srgb_encode(p[c]) as f64)
                .sum()
        })
        .collect()
}

/// The SSIM window radius used for an image of this size (see [`ssim_srgb_luma`]).
fn window_radius(width: usize, height: usize) -> usize {
    SSIM_WINDOW_RADIUS.min((width.min(height).max(1) - 1) / 2)
}

/// Normalised 1D Gaussian weights of sigma [`SSIM_SIGMA`] over -radius..=radius.
fn gaussian_weights(radius: usize) -> Vec<f64> {
    let w: Vec<f64> = (0..=2 * radius)
        .map(|i| {
            let x = i as f64 - radius as f64;
            (-0.5 * x * x / (SSIM_SIGMA * SSIM_SIGMA)).exp()
        })
        .collect();
    let sum: f64 = w.iter().sum();
    w.into_iter().map(|v| v / sum).collect()
}

/// SSIM over the valid windows: (map width, map height, row-major values).
fn ssim_valid(a: &ColorImage, b: &ColorImage) -> Result<(usize, usize, Vec<f64>)> {
    check_same_size(a, b)?;
    let (w, h) = (a.width(), a.height());
    let x = srgb_luma(a);
    let y = srgb_luma(b);
    let r = window_radius(w, h);
    let weights = gaussian_weights(r);
    let (ow, oh) = (w - 2 * r, h - 2 * r);

    // Pass 1, along rows: the five moments filtered horizontally, `ow` values per input row.
    let mut rows = vec![[0f64; 5]; ow * h];
    rows.par_chunks_mut(ow).enumerate().for_each(|(j, out)| {
        let (xr, yr) = (&x[j * w..][..w], &y[j * w..][..w]);
        for (i, m) in out.iter_mut().enumerate() {
            let mut acc = [0f64; 5];
            for (k, &wk) in weights.iter().enumerate() {
                let (xv, yv) = (xr[i + k], yr[i + k]);
                acc[0] += wk * xv;
                acc[1] += wk * yv;
                acc[2] += wk * xv * xv;
                acc[3] += wk * yv * yv;
                acc[4] += wk * xv * yv;
            }
            *m = acc;
        }
    });

    // Pass 2, along columns, then the SSIM formula per window.
    let c1 = (SSIM_K1 * DATA_RANGE).powi(2);
    let c2 = (SSIM_K2 * DATA_RANGE).powi(2);
    let mut map = vec![0f64; ow * oh];
    map.par_chunks_mut(ow).enumerate().for_each(|(j, out)| {
        let mut acc = vec![[0f64; 5]; ow];
        for (k, &wk) in weights.iter().enumerate() {
            let row = &rows[(j + k) * ow..][..ow];
            for (sum, m) in acc.iter_mut().zip(row) {
                for (s, v) in sum.iter_mut().zip(m) {
                    *s += wk * v;
                }
            }
        }
        for (s, m) in out.iter_mut().zip(&acc) {
            *s = ssim_from_moments(m, c1, c2);
        }
    });
    Ok((ow, oh, map))
}

/// Wang et al. 2004 eq. 13 from weighted moments [E x, E y, E x², E y², E xy].
#[inline]
fn ssim_from_moments(m: &[f64; 5], c1: f64, c2: f64) -> f64 {
    let [mx, my, mxx, myy, mxy] = *m;
    let vx = mxx - mx * mx;
    let vy = myy - my * my;
    let vxy = mxy - mx * my;
    ((2.0 * mx * my + c1) * (2.0 * vxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
}

/// Per-pixel mean over R, G, B of |sRGB(a) - sRGB(b)|, each value clamped to [0, 1] before
/// encoding, so the result is in [0, 1] (NaN where an input is NaN).
pub fn srgb_abs_diff(a: &ColorImage, b: &ColorImage) -> Result<GrayImage> {
    check_same_size(a, b)?;
    let diff = a
        .pixels()
        .par_iter()
        .zip(b.pixels())
        .map(|(p, q)| {
            (0..3)
                .map(|c| (srgb_encode(p[c]) - srgb_encode(q[c])).abs())
                .sum::<f32>()
                / 3.0
        })
        .collect();
    GrayImage::from_vec(a.width(), a.height(), diff)
}

/// The difference that [`error_map`] puts at the top of its ramp: the 99th percentile
/// (nearest rank) of `diff` ignoring NaN, but at least [`ERROR_MAP_MIN_TOP`].
pub fn error_map_top(diff: &GrayImage) -> f32 {
    let mut v: Vec<f32> = diff
        .pixels()
        .iter()
        .copied()
        .filter(|d| !d.is_nan())
        .collect();
    if v.is_empty() {
        return ERROR_MAP_MIN_TOP;
    }
    let rank = ((ERROR_MAP_PERCENTILE * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    let (_, p, _) = v.select_nth_unstable_by(rank, f32::total_cmp);
    p.max(ERROR_MAP_MIN_TOP)
}

/// False-colour map of where `a` and `b` differ, as a linear-light image (write it as PNG).
///
/// Each pixel shows [`srgb_abs_diff`] divided by [`error_map_top`] (the 99th percentile
/// difference, at least 0.1) through the ramp of [`error_ramp`]: black is no difference, white
/// is the top or more (and NaN). Use [`error_map_with_top`] to put several maps on one scale.
pub fn error_map(a: &ColorImage, b: &ColorImage) -> Result<ColorImage> {
    let diff = srgb_abs_diff(a, b)?;
    let top = error_map_top(&diff);
    Ok(colorize(&diff, top))
}

/// [`error_map`] with a given top of the ramp (an sRGB difference in (0, 1]), so that maps of
/// several methods share one scale.
pub fn error_map_with_top(a: &ColorImage, b: &ColorImage, top: f32) -> Result<ColorImage> {
    if !(top.is_finite() && top > 0.0) {
        return Err(Error::invalid(
            "error map top",
            format!("{top}: expected a finite sRGB difference > 0"),
        ));
    }
    Ok(colorize(&srgb_abs_diff(a, b)?, top))
}

/// Maps each difference through [`error_ramp`] with `top` at the end of the ramp.
fn colorize(diff: &GrayImage, top: f32) -> ColorImage {
    diff.map(|d| {
        let [r, g, b] = error_ramp(d / top);
        [r, g, b, 1.0]
    })
}

/// Control points of the error ramp, sRGB-encoded 8-bit: black, violet, crimson, amber, white.
/// Chosen so that relative luminance rises all along the ramp (0, 0.048, 0.175, 0.573, 1 at the
/// points, and monotonically between them), so larger errors always look brighter, in grey too.
const RAMP_SRGB8: [[f32; 3]; 5] = [
    [0.0, 0.0, 0.0],
    [60.0, 30.0, 170.0],
    [210.0, 60.0, 80.0],
    [250.0, 190.0, 40.0],
    [255.0, 255.0, 255.0],
];

/// The error-map colour for `t` in [0, 1] (clamped; NaN gives the top), as linear RGB: piecewise
/// linear between evenly spaced control points in sRGB-encoded space: black, violet, crimson,
/// amber, white.
pub fn error_ramp(t: f32) -> [f32; 3] {
    let t = if t.is_nan() { 1.0 } else { t.clamp(0.0, 1.0) };
    let s = t * (RAMP_SRGB8.len() - 1) as f32;
    let i = (s.floor() as usize).min(RAMP_SRGB8.len() - 2);
    let f = s - i as f32;
    let (p, q) = (RAMP_SRGB8[i], RAMP_SRGB8[i + 1]);
    std::array::from_fn(|c| srgb_decode((p[c] + (q[c] - p[c]) * f) / 255.0))
}
