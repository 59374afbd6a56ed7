//! `poisson`: a gather with Poisson-disc taps scaled by each pixel's CoC, with depth rejection
//! (after Scheuermann, "Advanced Depth of Field", GDC 2004; the baseline of McGraw section 3.2,
//! fig. 12, and the full DoF solution McGraw uses on masked pixels, section 4).
//!
//! # Passes, in order (each timed as `poisson/<pass>`)
//! 1. [`coc`] (`poisson/coc`): reads depth; writes the signed CoC radius in pixels from
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

use glam::Vec2;
use rayon::prelude::*;

use super::lowrank::kernel::{aberration_profile, check_aberration};
use super::MethodOutput;
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::lens::{Aperture, ThinLens};
use crate::timing::Timings;
use crate::{Error, Result};

/// Random candidates drawn for each new tap of the best-candidate Poisson-disc set.
pub const CANDIDATES: usize = 24;

/// Largest number of taps.
pub const MAX_TAPS: usize = 1024;

/// Largest CoC radius in pixels any post-process method accepts as a clamp.
pub const MAX_COC_LIMIT_PX: f32 = 512.0;

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
}

impl Default for PoissonSettings {
    fn default() -> Self {
        Self {
            aperture: Aperture::Disc,
            taps: 32,
            seed: 0,
            max_coc_px: 64.0,
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
    let mut timings = Timings::default();
    let taps = Taps::poisson_disc(&settings.aperture, settings.taps, settings.seed, 0.0)?;
    let coc_px = timings.time("poisson/coc", || coc(depth, lens, settings.max_coc_px))?;
    let image = timings.time("poisson/gather", || gather(color, &coc_px, &taps));
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
    })
}

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
    if let Some(i) = depth.pixels().iter().position(|&z| z.is_nan() || z <= 0.0) {
        return Err(Error::invalid(
            "depth",
            format!(
                "{} at pixel ({}, {}): expected a view-axis depth greater than 0 m (+inf for sky)",
                depth.pixels()[i],
                i % w.max(1),
                i / w.max(1)
            ),
        ));
    }
    let mut out = depth.clone();
    out.pixels_mut().par_chunks_mut(w.max(1)).for_each(|row| {
        for c in row {
            *c = lens.coc_px(*c).clamp(-max_coc_px, max_coc_px);
        }
    });
    Ok(out)
}

/// Validates a given CoC map (finite values, in pixels) and clamps it to `±max_coc_px`: the
/// `coc` pass for inputs that come with a CoC instead of depth (tilt-shift).
pub fn clamp_coc(coc_px: &GrayImage, max_coc_px: f32) -> Result<GrayImage> {
    check_max_coc(max_coc_px)?;
    let w = coc_px.width().max(1);
    if let Some(i) = coc_px.pixels().iter().position(|c| !c.is_finite()) {
        return Err(Error::invalid(
            "CoC map",
            format!(
                "{} at pixel ({}, {}): expected finite radii in pixels",
                coc_px.pixels()[i],
                i % w,
                i / w
            ),
        ));
    }
    Ok(coc_px.map(|c| c.clamp(-max_coc_px, max_coc_px)))
}

/// SplitMix64, for the tap positions.
struct Rng(u64);

impl Rng {
    fn next_f32(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}

/// A set of gather taps in the unit aperture (image axes) with their weights.
#[derive(Clone, Debug, PartialEq)]
pub struct Taps {
    /// Tap positions in the unit aperture, x right, y down; the first is the centre when the
    /// aperture passes light there.
    pub points: Vec<Vec2>,
    /// Weight of each tap: aperture density times the aberration profile.
    pub weights: Vec<f32>,
}

impl Taps {
    /// `count` best-candidate Poisson-disc taps inside `aperture` (see the module
    /// documentation), weighted by the density and the spherical-aberration profile
    /// `aberration` (-1 to 1, see [`super::lowrank::KernelSpec::aberration`]).
    pub fn poisson_disc(
        aperture: &Aperture,
        count: usize,
        seed: u64,
        aberration: f32,
    ) -> Result<Self> {
        aperture.validate()?;
        check_aberration(aberration)?;
        if !(1..=MAX_TAPS).contains(&count) {
            return Err(Error::invalid(
                "taps",
                format!("{count}: expected 1 to {MAX_TAPS} taps"),
            ));
        }
        let mut rng = Rng(seed ^ 0x5DEE_CE66_D1CE_4E5B);
        let mut points: Vec<Vec2> = Vec::with_capacity(count);
        if aperture.density(Vec2::ZERO) > 0.0 {
            points.push(Vec2::ZERO);
        }
        // Shapes covering less than 1/64 of the square are refused rather than looped on.
        let max_draws = 64 * CANDIDATES;
        while points.len() < count {
            let mut best: Option<(f32, Vec2)> = None;
            for _ in 0..CANDIDATES {
                let mut candidate = None;
                for _ in 0..max_draws {
                    let v = Vec2::new(rng.next_f32() * 2.0 - 1.0, rng.next_f32() * 2.0 - 1.0);
                    if aperture.density(v) > 0.0 {
                        candidate = Some(v);
                        break;
                    }
                }
                let Some(v) = candidate else {
                    return Err(Error::invalid(
                        "aperture",
                        "too little of the unit square passes light to place gather taps",
                    ));
                };
                let d = points
                    .iter()
                    .map(|p| p.distance_squared(v))
                    .fold(f32::INFINITY, f32::min);
                if best.map_or(true, |(bd, _)| d > bd) {
                    best = Some((d, v));
                }
            }
            if let Some((_, v)) = best {
                points.push(v);
            }
        }
        let weights = points
            .iter()
            .map(|&v| aperture.density(v) * aberration_profile(aberration, v.length_squared()))
            .collect();
        Ok(Self { points, weights })
    }
}

/// The depth-rejection weight of a tap with CoC `c_tap` for a centre pixel with CoC `c_centre`
/// (see the module documentation).
#[inline]
pub fn rejection_weight(c_centre: f32, c_tap: f32) -> f32 {
    if c_tap >= c_centre {
        1.0
    } else {
        (c_tap.abs() / c_centre.abs()).min(1.0)
    }
}

/// The gathered colour of pixel (`x`, `y`); pixels with `|C| < 0.5` and pixels whose taps all
/// have weight 0 keep their colour.
pub fn gather_pixel(
    color: &ColorImage,
    coc_px: &GrayImage,
    taps: &Taps,
    x: usize,
    y: usize,
) -> Rgba {
    let c = coc_px.get(x, y);
    if c.abs() < 0.5 {
        return color.get(x, y);
    }
    let (w, h) = (color.width() as f32, color.height() as f32);
    let mut acc = [0.0f32; 4];
    let mut total = 0.0f32;
    for (v, &base) in taps.points.iter().zip(&taps.weights) {
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
    let w = color.width().max(1);
    out.pixels_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                if mask.map_or(true, |m| m.get(y * w + x).copied().unwrap_or(false)) {
                    *o = gather_pixel(color, coc_px, taps, x, y);
                }
            }
        });
}
