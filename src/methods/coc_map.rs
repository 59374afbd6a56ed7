//! The CoC map pass shared by every gather (`hammon` has its own near/far CoC of the chapter):
//! checks a colour + depth frame against the lens, turns depth into the signed thin-lens CoC
//! radius in pixels ([`crate::lens::ThinLens::coc_px`]), clamps it to the method's limit, and
//! quantises radii into the levels that the separable gathers keep one tap table for.
//!
//! Each method times this pass under its own name (`poisson/coc`, `lowrank/coc`,
//! `gaussian/coc`); the code is this one function, [`coc`].

use rayon::prelude::*;

use crate::image::{ColorImage, GrayImage};
use crate::lens::ThinLens;
use crate::{Error, Result};

/// Largest CoC radius in pixels any post-process method accepts as a clamp.
pub const MAX_COC_LIMIT_PX: f32 = 512.0;

/// Checks that colour, depth and lens describe the same frame size.
pub fn check_frame(color: &ColorImage, depth: &GrayImage, lens: &ThinLens) -> Result<()> {
    if !color.same_size(depth) {
        return Err(Error::Mismatch(format!(
            "colour image is {}x{} but depth is {}x{}",
            color.width(),
            color.height(),
            depth.width(),
            depth.height()
        )));
    }
    if (color.width(), color.height()) != (lens.width_px, lens.height_px) {
        return Err(Error::Mismatch(format!(
            "colour image is {}x{} but the camera is {}x{}",
            color.width(),
            color.height(),
            lens.width_px,
            lens.height_px
        )));
    }
    if color.width() == 0 || color.height() == 0 {
        return Err(Error::invalid(
            "image size",
            "0 pixels: expected at least 1x1",
        ));
    }
    Ok(())
}

/// Checks a CoC limit: finite, > 0, at most [`MAX_COC_LIMIT_PX`].
pub fn check_max_coc(max_coc_px: f32) -> Result<()> {
    if max_coc_px.is_finite() && max_coc_px > 0.0 && max_coc_px <= MAX_COC_LIMIT_PX {
        Ok(())
    } else {
        Err(Error::invalid(
            "max CoC",
            format!("{max_coc_px} px: expected a radius in (0, {MAX_COC_LIMIT_PX}] pixels"),
        ))
    }
}

/// Pass `coc`: the signed CoC radius in pixels of every pixel, `C(z)` of
/// [`ThinLens::coc_px`] clamped to `[-max_coc_px, max_coc_px]`.
///
/// Fails naming the first pixel (row order) whose depth is NaN, zero or negative; +inf is the
/// far limit.
pub fn coc(depth: &GrayImage, lens: &ThinLens, max_coc_px: f32) -> Result<GrayImage> {
    check_max_coc(max_coc_px)?;
    let w = depth.width();
    let coc = |z: f32| lens.coc_px(z).clamp(-max_coc_px, max_coc_px);
    match map_checked(depth.pixels(), |z| z > 0.0, coc) {
        Some(pixels) => GrayImage::from_vec(w, depth.height(), pixels),
        None => Err(bad_depth(depth, first_failing(depth.pixels(), |z| z > 0.0))),
    }
}

/// The error of pass [`coc`] for the depth at index `i` (row order) of `depth`, which is NaN,
/// zero or negative: the GPU twin reports the same.
pub(crate) fn bad_depth(depth: &GrayImage, i: usize) -> Error {
    let w = depth.width().max(1);
    Error::invalid(
        "depth",
        format!(
            "{} at pixel ({}, {}): expected a view-axis depth greater than 0 m (+inf for sky)",
            depth.pixels()[i],
            i % w,
            i / w
        ),
    )
}

/// The error of a GPU `coc` pass that recorded pixel `failed` of `depth` as failing: the CPU's
/// ([`bad_depth`]), or, for an index beyond the frame, one naming `what` ran.
pub(crate) fn gpu_bad_depth(depth: &GrayImage, failed: u32, what: &str) -> Error {
    if (failed as usize) < depth.pixels().len() {
        bad_depth(depth, failed as usize)
    } else {
        Error::Gpu(format!(
            "{what}: the coc pass reported pixel {failed} of {}",
            depth.pixels().len()
        ))
    }
}

/// Values per parallel block of [`map_checked`], [`max_abs`] and the per-pixel passes like them:
/// 64 KB, big enough that the threads' hand-offs cost nothing next to the block.
pub(crate) const MAP_BLOCK: usize = 1 << 14;

/// `f` of every value of `src`, in one pass of parallel blocks whose loops the compiler
/// vectorises, or `None` when `valid` is false for any value. (A check first and a map after
/// would read the image twice; a parallel search for the first failure splits the image into
/// pieces too small to pay for their threads.)
fn map_checked(
    src: &[f32],
    valid: impl Fn(f32) -> bool + Sync,
    f: impl Fn(f32) -> f32 + Sync,
) -> Option<Vec<f32>> {
    let mut out = vec![0.0f32; src.len()];
    let ok = out
        .par_chunks_mut(MAP_BLOCK)
        .zip(src.par_chunks(MAP_BLOCK))
        .map(|(o, s)| {
            let mut ok = true;
            for (o, &v) in o.iter_mut().zip(s) {
                ok &= valid(v);
                *o = f(v);
            }
            ok
        })
        .reduce(|| true, |a, b| a & b);
    ok.then_some(out)
}

/// Index of the first value of `src` for which `valid` is false (0 if there is none): the
/// pixel an error names, looked for only once [`map_checked`] has failed.
fn first_failing(src: &[f32], valid: impl Fn(f32) -> bool) -> usize {
    src.iter().position(|&v| !valid(v)).unwrap_or(0)
}

/// The largest |value| of `src` (0 for an empty or all-zero slice; the values are finite), in
/// parallel blocks of comparisons the compiler vectorises.
pub fn max_abs(src: &[f32]) -> f32 {
    let biggest = |a: f32, b: f32| if a > b { a } else { b };
    src.par_chunks(MAP_BLOCK)
        .map(|s| s.iter().fold(0.0f32, |m, &v| biggest(m, v.abs())))
        .reduce(|| 0.0, biggest)
}

/// Validates a given CoC map (finite values, in pixels) and clamps it to `±max_coc_px`: the
/// `coc` pass for inputs that come with a CoC instead of depth (tilt-shift).
pub fn clamp_coc(coc_px: &GrayImage, max_coc_px: f32) -> Result<GrayImage> {
    check_max_coc(max_coc_px)?;
    let w = coc_px.width().max(1);
    let clamp = |c: f32| c.clamp(-max_coc_px, max_coc_px);
    match map_checked(coc_px.pixels(), f32::is_finite, clamp) {
        Some(pixels) => GrayImage::from_vec(coc_px.width(), coc_px.height(), pixels),
        None => {
            let i = first_failing(coc_px.pixels(), f32::is_finite);
            Err(Error::invalid(
                "CoC map",
                format!(
                    "{} at pixel ({}, {}): expected finite radii in pixels",
                    coc_px.pixels()[i],
                    i % w,
                    i / w
                ),
            ))
        }
    }
}

/// CoC radii are quantised to steps of 1 / `LEVELS_PER_PX` pixel.
pub const LEVELS_PER_PX: f32 = 4.0;

/// Number of taps on each side of the centre for a kernel of radius `radius_px`: the taps whose
/// footprint `[d - 1/2, d + 1/2]` overlaps `(-R, R)`.
pub fn half_taps(radius_px: f32) -> usize {
    if radius_px <= 0.5 {
        0
    } else {
        (radius_px + 0.5).ceil() as usize - 1
    }
}

/// Number of quantised radius levels needed for radii up to `max_radius_px`.
pub fn level_count(max_radius_px: f32) -> usize {
    (max_radius_px.max(0.0) * LEVELS_PER_PX).ceil() as usize + 1
}

/// Level of a CoC radius `|coc_px|` (0 to `levels - 1`): `|coc_px| LEVELS_PER_PX` rounded half
/// away from zero, as `f32::round` does, without its library call (the fraction `v - trunc v`
/// is exact in f32, so the comparison with 1/2 is too; NaN gives level 0).
#[inline]
pub fn level_of(coc_px: f32, levels: usize) -> usize {
    let v = coc_px.abs() * LEVELS_PER_PX;
    let t = v as usize;
    let rounded = if v - t as f32 >= 0.5 {
        t.saturating_add(1)
    } else {
        t
    };
    rounded.min(levels - 1)
}

/// Radius in pixels of level `level`.
#[inline]
pub fn level_radius_px(level: usize) -> f32 {
    level as f32 / LEVELS_PER_PX
}
