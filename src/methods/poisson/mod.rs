//! `poisson`: a gather with Poisson-disc taps scaled by each pixel's CoC, with depth rejection
//! (after Scheuermann, "Advanced Depth of Field", GDC 2004; the baseline of McGraw section 3.2,
//! fig. 12, and the full DoF solution McGraw uses on masked pixels, section 4).
//!
//! # Passes, in order (each timed as `poisson/<pass>`)
//! 1. [`coc`](super::coc_map::coc()) (`poisson/coc`, the shared pass of [`super::coc_map`]): reads depth; writes the signed CoC radius in pixels from
//!    [`ThinLens::coc_px`] (the one CoC function), clamped to `±max_coc_px`. Validates the depth
//!    (NaN, zero or negative is an error; +inf is allowed, the far limit). `lowrank` and
//!    `gaussian` use this pass too.
//! 2. [`gather`] (`poisson/gather`): reads colour and CoC; writes the output. At pixel `p` with
//!    CoC `C_p`, each tap `v` of the unit aperture reads the pixel `q` nearest to
//!    `p - C_p v` (clamped to the image), so the bokeh of a far point is the aperture as
//!    defined and that of a near point is turned 180 degrees, as in `reference`. Tap weights are
//!    the aperture density (times the aberration profile, for `lowrank`) times the depth
//!    rejection term below; the sum is divided by the sum of weights.
//!
//! # Depth rejection (Scheuermann's leakage guard, in CoC units)
//! A tap behind the centre pixel or at its depth (`C_q >= C_p`: the signed CoC grows with depth)
//! counts fully. A tap in front of it counts by its own blur relative to the centre's,
//! `min(1, |C_q| / |C_p|)`: a sharp object in front does not leak into the blurred background
//! around it, while a blurrier foreground still spreads over it. Scheuermann weights by the tap's
//! blur normalised to a global maximum; the ratio makes the guard independent of that constant.
//!
//! # Taps
//! The tap set is a best-candidate (Mitchell) approximation of a Poisson-disc set in the
//! aperture: the centre first (Scheuermann's centre tap), then each next tap the farthest of
//! [`CANDIDATES`] random points inside the aperture from the taps so far. Seeded, so the output
//! is deterministic; pixels are independent, so it does not depend on the thread count.
//!
//! Pixels with `|C| < 0.5` (the blur stays inside the pixel) are copied unchanged.
//!
//! [`gpu`] runs the same two passes as WGSL compute shaders, under the same names.

pub mod gpu;

use glam::Vec2;
use rayon::prelude::*;

use super::coc_map::{check_frame, coc};
use super::MethodOutput;
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::lens::{Aperture, LensEffects, ThinLens};
pub use crate::lens::{Taps, CANDIDATES, MAX_TAPS};
use crate::timing::Timings;
use crate::Result;

/// The lens effects ([`crate::lens::EFFECT_NAMES`]) this method renders; it refuses the others.
pub const EFFECTS: &[&str] = &["anamorphic", "cats-eye", "chromatic"];

/// Settings of the `poisson` gather.
#[derive(Clone, Debug, PartialEq)]
pub struct PoissonSettings {
    /// Aperture shape (the taps fill it). Default [`Aperture::Disc`].
    pub aperture: Aperture,
    /// Number of taps per pixel, centre included; 1 to [`MAX_TAPS`]. Default 32 (more taps,
    /// less noise, proportionally slower).
    pub taps: usize,
    /// Seed of the tap positions. Default 0.
    pub seed: u64,
    /// Largest CoC radius in pixels; larger blurs are clamped to it. Default 64.
    pub max_coc_px: f32,
    /// The real lens's departures from the ideal one: the anamorphic squeeze stretches the
    /// taps, so the gather's footprint, and a far light's bokeh, is the squeezed aperture; with
    /// a cat's eye each pixel keeps only the taps (lens points) that pass its view of the
    /// barrel; with chromatic aberration each channel is gathered with its own channel's CoCs
    /// (a gather per channel, as `reference` renders a pass per channel). Default: the ideal
    /// lens.
    pub effects: LensEffects,
}

impl Default for PoissonSettings {
    fn default() -> Self {
        Self {
            aperture: Aperture::Disc,
            taps: 32,
            seed: 0,
            max_coc_px: 64.0,
            effects: LensEffects::default(),
        }
    }
}

/// Renders depth of field from a pinhole colour image and its view-axis depth (metres).
pub fn render(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &PoissonSettings,
) -> Result<MethodOutput> {
    check_frame(color, depth, lens)?;
    if settings.effects.is_chromatic() {
        settings.effects.check_supported("poisson", EFFECTS)?;
        let mono = PoissonSettings {
            effects: settings.effects.without_colour(),
            ..settings.clone()
        };
        return super::per_channel_lens(&settings.effects, lens, |channel| {
            render(color, depth, channel, &mono)
        });
    }
    let mut timings = Timings::default();
    let mut taps = Taps::poisson_disc(&settings.aperture, settings.taps, settings.seed, 0.0)?;
    let effects = settings.effects;
    effects.check_supported("poisson", EFFECTS)?;
    for p in &mut taps.points {
        *p = effects.squeeze(*p);
    }
    let coc_px = timings.time("poisson/coc", || coc(depth, lens, settings.max_coc_px))?;
    let image = timings.time("poisson/gather", || {
        if effects.has_cats_eye() {
            gather_clipped(color, &coc_px, &taps, &effects, lens)
        } else {
            gather(color, &coc_px, &taps)
        }
    });
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
        memory_bytes: None,
    })
}

/// The depth-rejection weight of a tap with CoC `c_tap` for a centre pixel with CoC `c_centre`
/// (see the module documentation).
#[inline(always)]
pub fn rejection_weight(c_centre: f32, c_tap: f32) -> f32 {
    if c_tap >= c_centre {
        1.0
    } else {
        (c_tap.abs() / c_centre.abs()).min(1.0)
    }
}

/// The gathered colour of pixel (`x`, `y`); pixels with `|C| < 0.5` and pixels whose taps all
/// have weight 0 keep their colour.
#[inline(always)]
pub fn gather_pixel(
    color: &ColorImage,
    coc_px: &GrayImage,
    taps: &Taps,
    x: usize,
    y: usize,
) -> Rgba {
    gather_pixel_keeping(color, coc_px, taps, x, y, |_| true)
}

/// [`gather_pixel`] with only the taps `v` (lens points) for which `keep(v)` holds: the
/// cat's eye keeps those that pass the pixel's view of the lens barrel.
#[inline(always)]
fn gather_pixel_keeping(
    color: &ColorImage,
    coc_px: &GrayImage,
    taps: &Taps,
    x: usize,
    y: usize,
    keep: impl Fn(Vec2) -> bool,
) -> Rgba {
    let c = coc_px.get(x, y);
    if c.abs() < 0.5 {
        return color.get(x, y);
    }
    let (w, h) = (color.width() as f32, color.height() as f32);
    let mut acc = [0.0f32; 4];
    let mut total = 0.0f32;
    for (v, &base) in taps.points.iter().zip(&taps.weights) {
        if !keep(*v) {
            continue;
        }
        let sx = (x as f32 + 0.5 - c * v.x).floor().clamp(0.0, w - 1.0) as usize;
        let sy = (y as f32 + 0.5 - c * v.y).floor().clamp(0.0, h - 1.0) as usize;
        let wt = base * rejection_weight(c, coc_px.get(sx, sy));
        if wt > 0.0 {
            let p = color.get(sx, sy);
            for k in 0..4 {
                acc[k] += wt * p[k];
            }
            total += wt;
        }
    }
    if total > 0.0 {
        acc.map(|a| a / total)
    } else {
        color.get(x, y)
    }
}

/// Pass `gather` with a cat's eye: each pixel keeps only the taps that pass its view of the
/// lens barrel ([`LensEffects::barrel`]), in the frame of `lens`.
fn gather_clipped(
    color: &ColorImage,
    coc_px: &GrayImage,
    taps: &Taps,
    effects: &LensEffects,
    lens: &ThinLens,
) -> ColorImage {
    let w = color.width();
    let mut out = color.clone();
    out.pixels_mut()
        .par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let barrel = effects.barrel(lens, Vec2::new(x as f32 + 0.5, y as f32 + 0.5));
                *o = gather_pixel_keeping(color, coc_px, taps, x, y, |v| effects.passes(barrel, v));
            }
        });
    out
}

/// Pass `gather`: every pixel of `color` gathered with `taps`. `coc_px` must have the size of
/// `color`.
pub fn gather(color: &ColorImage, coc_px: &GrayImage, taps: &Taps) -> ColorImage {
    let mut out = color.clone();
    gather_into(&mut out, color, coc_px, taps, None);
    out
}

/// Writes into `out` the gathered colour of every pixel, or only of those where `mask` is true
/// (row-major, one entry per pixel); other pixels of `out` are left as they are. `out` and
/// `coc_px` must have the size of `color`.
pub fn gather_into(
    out: &mut ColorImage,
    color: &ColorImage,
    coc_px: &GrayImage,
    taps: &Taps,
    mask: Option<&[bool]>,
) {
    gather_into_with(out, color, coc_px, taps, mask, gather_row);
}

/// [`gather_into`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn gather_into_baseline(
    out: &mut ColorImage,
    color: &ColorImage,
    coc_px: &GrayImage,
    taps: &Taps,
    mask: Option<&[bool]>,
) {
    gather_into_with(out, color, coc_px, taps, mask, gather_row_inner);
}

/// What every row of [`gather_into`] reads.
struct GatherInputs<'a> {
    color: &'a ColorImage,
    coc_px: &'a GrayImage,
    taps: &'a Taps,
    mask: Option<&'a [bool]>,
}

fn gather_into_with(
    out: &mut ColorImage,
    color: &ColorImage,
    coc_px: &GrayImage,
    taps: &Taps,
    mask: Option<&[bool]>,
    row_fn: impl Fn(&GatherInputs, usize, &mut [Rgba]) + Sync,
) {
    let w = color.width().max(1);
    let inputs = GatherInputs {
        color,
        coc_px,
        taps,
        mask,
    };
    out.pixels_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| row_fn(&inputs, y, row));
}

/// One row of [`gather_into`]. Compiled for several instruction sets and chosen at run time
/// ([`multiversion`]): with SSE4.1 and later the tap's `floor` is one instruction instead of a
/// library call; the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn gather_row(inputs: &GatherInputs, y: usize, row: &mut [Rgba]) {
    gather_row_inner(inputs, y, row);
}

#[inline(always)]
fn gather_row_inner(inputs: &GatherInputs, y: usize, row: &mut [Rgba]) {
    let GatherInputs {
        color,
        coc_px,
        taps,
        mask,
    } = *inputs;
    let w = color.width().max(1);
    for (x, o) in row.iter_mut().enumerate() {
        if mask.is_none_or(|m| m.get(y * w + x).copied().unwrap_or(false)) {
            *o = gather_pixel(color, coc_px, taps, x, y);
        }
    }
}
