//! `lowrank`: bokeh by low-rank linear filters.
//!
//! Tim McGraw, "Fast Bokeh Effects Using Low-Rank Linear Filters" (`../shared/papers/002`):
//! section 3 (a kernel as a sum of `r` separable filters from its SVD, eqs. 1-4, fig. 2),
//! section 3.1 (kernel shapes, orientation, spherical aberration, curved blades, custom
//! shapes), section 4 (tilt-shift; depth of field with a depth-discontinuity mask and a full 2D
//! solution on the masked pixels, fig. 15).
//!
//! # Building blocks (spatially invariant, section 3)
//! - [`kernel`]: [`kernel_image`] rasterizes the shared [`Aperture`] (with aberration) into a
//!   kernel image summing to 1; [`CustomShape`] makes star, heart and ring apertures.
//! - [`svd`]: [`decompose`] gives the singular values and the scaled vectors `u'_i`, `v'_i`;
//!   [`LowRank::relative_error`] is eq. 4.
//! - [`filter`]: [`filter_separable`] (fig. 2) and [`filter_full_2d`] (the 2D convolution it
//!   approximates).
//!
//! # Depth of field: passes, in order (each timed as `lowrank/<pass>`)
//! 1. `coc` ([`crate::methods::coc_map::coc`]): reads depth; writes the signed CoC radius in
//!    pixels from [`ThinLens::coc_px`], clamped to `max_coc_px`. [`render_coc`] takes a CoC map
//!    instead (tilt-shift, [`tilt_shift_coc`]) and only validates and clamps it.
//! 2. `kernel` ([`kernel_image`], [`decompose`], [`dof::KernelBank`]): rasterizes the base
//!    kernel (odd size `2 ceil(max |C|) + 1` unless given), decomposes it, and tabulates the
//!    horizontal and vertical taps of every CoC radius in steps of 1/4 px, both orientations.
//! 3. `edges` ([`dof::edges`]): reads the CoC; writes 1 where it jumps by more than
//!    `edge_threshold_px` to a 4-neighbour (fig. 15, centre).
//! 4. `separable` ([`dof::filter`]): for every rank, the horizontal pass (reads colour, edges
//!    and CoC; each pixel uses the taps of its own CoC) into the intermediate rows `U_i`, and the
//!    vertical pass from them (accumulated into the output colour and the filtered edge image,
//!    no `V_i` stored). They run band by band ([`filter::Schedule::Banded`]): a window of `U_i`
//!    rows slides down each thread's slab of the image, so no intermediate image is stored and
//!    eight output rows sharing a kernel are filtered at once ([`filter::filter_rows`]); each
//!    pixel's sums are fig. 2's, in its order, so the image is the same bit for bit as with
//!    [`dof::filter_with_schedule`] and [`filter::Schedule::Fig2`] (one rank after the other
//!    over the whole image, timed as `horizontal` and `vertical`; tested). A last step restores
//!    in-focus pixels exactly and clamps negative ringing. An opaque frame (every alpha 1, as
//!    rendered scenes are) carries only its three colour channels, a quarter fewer floats, and
//!    gets alpha 1 back; the colour is bit for bit that of the four-channel passes (tested).
//! 5. `fallback` ([`crate::methods::poisson::gather_into`]): where the filtered edge image exceeds
//!    `mask_threshold` (fig. 15, right), the pixel is recomputed by the Scheuermann-style
//!    gather with depth rejection, with `fallback_taps` Poisson-disc taps in the same aperture
//!    and aberration profile.
//!
//! # Where the paper leaves a choice, and what we chose
//! - Kernel size per pixel: the paper sets the filter width from the CoC diameter. We scale one
//!   decomposed kernel to each pixel's radius by integrating its singular vectors over each
//!   tap's footprint (see [`dof`]), so the bokeh has diameter `2|C|` as in `reference`, stays
//!   anti-aliased, and a negative CoC gives the aperture turned 180 degrees.
//! - Gather: each pixel uses its own kernel in both passes (as a fragment shader does), and the
//!   rank-r kernel is renormalised to sum 1 so a constant image stays constant.
//! - The edge image is thresholded on CoC differences (pixels) rather than depth (metres) and
//!   filtered by the same low-rank passes as the colour (the paper: "blurring the edge image at
//!   the same time as the color image"), as an extra channel; the mask is "more than
//!   `mask_threshold` of my kernel's weight lies on edge pixels".
//! - Spherical aberration: the paper shows kernels for -1..1 without a formula; ours is the
//!   brightness `max(0, 1 + a (2 |v|^2 - 1))`, +1 a bright rim ([`KernelSpec::aberration`]).
//! - Eq. 3 as printed lacks a square root; we use the Frobenius norm itself.
//! - Colour is linear premultiplied RGBA with HDR values, filtered before any tone mapping (the
//!   paper filtered tone-mapped images and notes the colour shift of its bokeh). HDR exposes
//!   the negative lobes of the SVD approximation as dark dots at the vertices of bright bokeh;
//!   the vertical pass clamps negative results to 0 (measured on a disc at rank 3: +0.8% energy).
//!
//! # Measured (1280x720, 2 shared cores; criterion medians in `benches/lowrank.rs`)
//! - Kernel analysis (65 px kernels, 8x8 samples per pixel, rotation 0): full ranks 28, 18, 19
//!   and 20 for 5, 6 and 8 blades and the disc (the paper: 55, 36, 38, 39, about twice ours:
//!   our kernels are exactly mirror-symmetric about the middle row, which halves the number of
//!   independent rows; turned 7 degrees off that axis they rise to 44, 45, 42). Rank-3 relative
//!   errors 0.180, 0.139, 0.167, 0.120, 0.159 for 5 to 9 blades and 0.156 for the disc; 8 blades
//!   have the lowest error for every rank from 2 to 10 and even blade counts beat their odd
//!   neighbours, as the paper states. Fig. 9 reproduces too: a brighter centre (aberration -1)
//!   lowers the error, straighter blades raise it for odd and lower it for even blade counts.
//! - Against `reference` (256 lens samples) at 640x360, linear MSE: `lights` (6 blades) 0.0127
//!   vs 0.0139 for `gaussian` (-9%), `railing` 0.0062 vs 0.0066 (-6%); the paper reports -31%
//!   on its scenes. On `lights` the mask costs MSE (0.0048 with, 0.0040 without at 1280x720):
//!   64 Poisson taps are noisy on small HDR lights, although the mask removes the halo that the
//!   in-focus card leaks into the wall. On `railing` 29% of the pixels are masked (thin near
//!   bars whose kernels span their width) and the fallback is the slowest pass.
//! - Speed (criterion medians, 1280x720, disc kernels; the 2D convolution skips zero taps):
//!   65 px: 2D 430 ms, rank 1/2/3/4 27/54/75/109 ms (rank 3: 5.7x faster; 1920x1080: 1316 ms
//!   vs 193 ms, 6.8x); 33 px: 145 ms vs 20/38/55/57 ms; 17 px: 52 ms vs 12/21/33/45 ms. A
//!   rank-3, 65 px kernel does 8.6x fewer multiply-adds than the 2D kernel (390 vs 3340 per
//!   pixel); the separable passes also write and read one intermediate image per rank, which on
//!   this machine costs more than the taps at small sizes. Rasterizing and decomposing a 65 px
//!   kernel takes 1.2 ms. DoF: `railing` 222 ms (67 ms without the mask: the 2D gather on 29%
//!   of the pixels dominates), `lights` 81 ms (53 ms without); `gaussian` 91 and 108 ms.
//! - How the filters got there: each row filter ([`filter::filter_span`]) keeps a block of 8
//!   pixels in registers over all taps (applying each tap to a whole row, `acc += w * src`, was
//!   load/store bound and twice as slow); the vertical passes walk blocks of 32 rows in strips of
//!   128 px so their source rows stay in L2 (without strips, rank 3 at 65 px was only 2.5x
//!   faster than the 2D convolution); the ranks run one after the other through one
//!   intermediate image, as fig. 2 draws it (keeping all `U_i` at once cost more in first-touch
//!   page faults than in taps: rank 3 at 65 px went from 105 to 75 ms).

pub mod dof;
pub mod filter;
pub mod gpu;
pub mod kernel;
pub mod svd;
pub mod tiltshift;

pub use filter::{filter_full_2d, filter_separable};
pub use kernel::{kernel_image, CustomShape, KernelSpec};
pub use svd::{decompose, LowRank};
pub use tiltshift::{tilt_shift_coc, tilt_shift_coc_in_frame, TiltShift};

use super::coc_map;
use super::poisson::{self, Taps};
use super::MethodOutput;
use crate::image::{ColorImage, GrayImage};
use crate::lens::{Aperture, LensEffects, ThinLens};
use crate::timing::Timings;
use crate::{Error, Result};
use rayon::prelude::*;

/// The lens effects ([`crate::lens::EFFECT_NAMES`]) this method renders; it refuses the others.
pub const EFFECTS: &[&str] = &["anamorphic", "chromatic"];

/// Smallest base kernel chosen automatically, in pixels.
pub const MIN_AUTO_KERNEL_PX: usize = 17;

/// Largest base kernel chosen automatically, in pixels (larger blurs magnify it).
pub const MAX_AUTO_KERNEL_PX: usize = 129;

/// Every parameter of the method, with units and defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct LowRankSettings {
    /// Aperture shape, as for every method. Default [`Aperture::Disc`] (the paper's DoF
    /// figures use 6 blades, LuxRender's, and a disc, pbrt's).
    pub aperture: Aperture,
    /// Rank `r` of the approximation (1 to the kernel's size). Default 3, the paper's DoF and
    /// tilt-shift rank (its blurring figures use 4).
    pub rank: usize,
    /// Spherical aberration, -1 (bright centre) to 1 (bright rim); see
    /// [`KernelSpec::aberration`]. Default 0.
    pub aberration: f32,
    /// Side in pixels (odd) of the base kernel that is decomposed and scaled to each pixel's
    /// CoC. Default `None`: `2 ceil(max |C|) + 1` over the frame, within
    /// [[`MIN_AUTO_KERNEL_PX`], [`MAX_AUTO_KERNEL_PX`]].
    pub kernel_size_px: Option<usize>,
    /// Samples per pixel and axis when rasterizing the base kernel. Default 8.
    pub supersample: usize,
    /// Compute the depth-discontinuity mask and use the 2D gather on it (fig. 15). Default true.
    pub use_mask: bool,
    /// A pixel is on a depth edge when its CoC differs from a 4-neighbour's by more than this,
    /// in pixels (>= 0). Default 1.
    pub edge_threshold_px: f32,
    /// A pixel is masked when the edge image filtered with its own kernel (the fraction of its
    /// kernel's weight on edge pixels) exceeds this (0 to 1). Default 0.01.
    pub mask_threshold: f32,
    /// Taps of the 2D gather on masked pixels (1 to 1024). Default 64.
    pub fallback_taps: usize,
    /// Seed of the gather taps. Default 0.
    pub seed: u64,
    /// Largest CoC radius in pixels; larger blurs are clamped (0 to 512). Default 64.
    pub max_coc_px: f32,
    /// The real lens's departures from the ideal one: the anamorphic squeeze stretches every
    /// pixel's kernel (the horizontal taps of CoC radius `R` at `R sx`, the vertical ones at
    /// `R sy`) and the fallback's taps; with chromatic aberration [`render`] filters each
    /// channel with its own channel's CoCs (a run per channel, as `reference`). The cat's eye is
    /// refused. Default: the ideal lens.
    pub effects: LensEffects,
}

impl Default for LowRankSettings {
    fn default() -> Self {
        Self {
            aperture: Aperture::Disc,
            rank: 3,
            aberration: 0.0,
            kernel_size_px: None,
            supersample: 8,
            use_mask: true,
            edge_threshold_px: 1.0,
            mask_threshold: 0.01,
            fallback_taps: 64,
            seed: 0,
            max_coc_px: 64.0,
            effects: LensEffects::default(),
        }
    }
}

impl LowRankSettings {
    /// Checks the fields that do not depend on the frame (see their documentation).
    pub fn validate(&self) -> Result<()> {
        self.aperture.validate()?;
        kernel::check_aberration(self.aberration)?;
        coc_map::check_max_coc(self.max_coc_px)?;
        if self.rank == 0 {
            return Err(Error::invalid("rank", "0: expected at least 1"));
        }
        // A kernel of n px has at most n separable terms; the largest kernel a run can use is
        // the one for the largest CoC (--max-coc), or --kernel-size.
        let largest_px = self.kernel_spec(self.max_coc_px).size_px;
        if self.rank > largest_px {
            return Err(Error::invalid(
                "rank",
                format!(
                    "{}: expected at most {largest_px}, the terms of the largest kernel this run \
                     can use ({largest_px} px, from --max-coc {} or --kernel-size)",
                    self.rank, self.max_coc_px
                ),
            ));
        }
        if !(self.edge_threshold_px.is_finite() && self.edge_threshold_px >= 0.0) {
            return Err(Error::invalid(
                "edge threshold",
                format!(
                    "{} px: expected a CoC difference >= 0 pixels",
                    self.edge_threshold_px
                ),
            ));
        }
        if !(self.mask_threshold.is_finite() && (0.0..=1.0).contains(&self.mask_threshold)) {
            return Err(Error::invalid(
                "mask threshold",
                format!("{}: expected a fraction from 0 to 1", self.mask_threshold),
            ));
        }
        // Checked here, not only where the fallback first runs: a frame without depth edges
        // never builds its taps.
        if !(1..=crate::lens::MAX_TAPS).contains(&self.fallback_taps) {
            return Err(Error::invalid(
                "fallback taps",
                format!(
                    "{}: expected 1 to {} taps",
                    self.fallback_taps,
                    crate::lens::MAX_TAPS
                ),
            ));
        }
        Ok(())
    }

    /// The kernel specification for a frame whose largest CoC radius is `max_radius_px`.
    pub fn kernel_spec(&self, max_radius_px: f32) -> KernelSpec {
        let size_px = self.kernel_size_px.unwrap_or_else(|| {
            let n = 2 * max_radius_px.max(0.0).ceil() as usize + 1;
            n.clamp(MIN_AUTO_KERNEL_PX, MAX_AUTO_KERNEL_PX)
        });
        KernelSpec {
            aperture: self.aperture.clone(),
            size_px,
            aberration: self.aberration,
            supersample: self.supersample,
        }
    }
}

/// Everything a DoF run produces, for inspection (fig. 15).
#[derive(Clone, Debug)]
pub struct Detailed {
    /// The image and timings.
    pub output: MethodOutput,
    /// Signed CoC radius in pixels per pixel, after clamping.
    pub coc_px: GrayImage,
    /// The depth-edge image (1 on edges), when the mask is used.
    pub edges: Option<GrayImage>,
    /// The mask (1 where the 2D gather replaced the low-rank result), when used.
    pub mask: Option<GrayImage>,
}

/// Renders depth of field from a pinhole colour image and its view-axis depth in metres
/// (NaN, zero or negative depth is an error; +inf is the far limit).
pub fn render(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &LowRankSettings,
) -> Result<MethodOutput> {
    if settings.effects.is_chromatic() {
        // A run per channel through its own lens, as `reference`.
        settings.effects.check_supported("lowrank", EFFECTS)?;
        let mono = LowRankSettings {
            effects: settings.effects.without_colour(),
            ..settings.clone()
        };
        return super::per_channel_lens(&settings.effects, lens, |channel| {
            render(color, depth, channel, &mono)
        });
    }
    render_with(color, depth, lens, settings, false).map(|d| d.output)
}

/// [`render`], also returning the CoC, the edges and the mask.
pub fn render_detailed(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &LowRankSettings,
) -> Result<Detailed> {
    render_with(color, depth, lens, settings, true)
}

/// [`render_detailed`], with the mask image made only when `detailed`.
fn render_with(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &LowRankSettings,
    detailed: bool,
) -> Result<Detailed> {
    settings.validate()?;
    coc_map::check_frame(color, depth, lens)?;
    let mut timings = Timings::default();
    let coc_px = timings.time("lowrank/coc", || {
        coc_map::coc(depth, lens, settings.max_coc_px)
    })?;
    run(color, coc_px, settings, timings, detailed)
}

/// Filters `color` with the spatially varying low-rank filter for a given CoC map (signed
/// radius in pixels per pixel, same size as `color`), e.g. from [`tilt_shift_coc`].
pub fn render_coc(
    color: &ColorImage,
    coc_px: &GrayImage,
    settings: &LowRankSettings,
) -> Result<MethodOutput> {
    render_coc_with(color, coc_px, settings, false).map(|d| d.output)
}

/// [`render_coc`], also returning the CoC, the edges and the mask.
pub fn render_coc_detailed(
    color: &ColorImage,
    coc_px: &GrayImage,
    settings: &LowRankSettings,
) -> Result<Detailed> {
    render_coc_with(color, coc_px, settings, true)
}

/// [`render_coc_detailed`], with the mask image made only when `detailed`.
fn render_coc_with(
    color: &ColorImage,
    coc_px: &GrayImage,
    settings: &LowRankSettings,
    detailed: bool,
) -> Result<Detailed> {
    settings.validate()?;
    check_coc_frame(color, coc_px, settings)?;
    let mut timings = Timings::default();
    let coc_px = timings.time("lowrank/coc", || {
        coc_map::clamp_coc(coc_px, settings.max_coc_px)
    })?;
    run(color, coc_px, settings, timings, detailed)
}

/// Passes 2 to 5 (see the module documentation); the mask image only when `detailed`.
fn run(
    color: &ColorImage,
    coc_px: GrayImage,
    settings: &LowRankSettings,
    mut timings: Timings,
    detailed: bool,
) -> Result<Detailed> {
    settings.effects.check_supported("lowrank", EFFECTS)?;
    if settings.effects.is_chromatic() {
        return Err(Error::invalid(
            "chromatic aberration",
            "each channel needs its own CoCs from a depth map (lowrank::render); one CoC map \
             (--tilt-shift, or the detailed outputs) has one lens",
        ));
    }
    let max_radius = coc_map::max_abs(coc_px.pixels());
    let bank = timings.time("lowrank/kernel", || kernel_bank(settings, max_radius))?;
    let edges = settings.use_mask.then(|| {
        timings.time("lowrank/edges", || {
            dof::edges(&coc_px, settings.edge_threshold_px)
        })
    });
    // A frame without depth edges (one plane, or a CoC that changes slowly everywhere) masks
    // no pixel: the filter skips the edge channel, and the mask is empty.
    let any_edge = edges
        .as_ref()
        .is_some_and(|e| coc_map::max_abs(e.pixels()) > 0.0);
    let (mut image, filtered_edges) = dof::filter(
        color,
        edges.as_ref().filter(|_| any_edge),
        &coc_px,
        &bank,
        &mut timings,
    );
    let mut mask_image = (detailed && edges.is_some() && !any_edge)
        .then(|| GrayImage::new(color.width(), color.height(), 0.0));
    if let Some(filtered) = filtered_edges {
        let taps = fallback_taps(settings)?;
        let threshold = settings.mask_threshold;
        let mask: Vec<bool> = timings.time("lowrank/fallback", || {
            // A pixel has taps beyond its own (`half_taps > 0`) where its radius exceeds 1/2.
            let mut mask = vec![false; filtered.pixels().len()];
            let any = mask
                .par_chunks_mut(coc_map::MAP_BLOCK)
                .zip(filtered.pixels().par_chunks(coc_map::MAP_BLOCK))
                .zip(coc_px.pixels().par_chunks(coc_map::MAP_BLOCK))
                .map(|((m, e), c)| {
                    let mut any = false;
                    for ((m, &e), &c) in m.iter_mut().zip(e).zip(c) {
                        *m = e > threshold && c.abs() > 0.5;
                        any |= *m;
                    }
                    any
                })
                .reduce(|| false, |a, b| a | b);
            if any {
                poisson::gather_into(&mut image, color, &coc_px, &taps, Some(&mask));
            }
            mask
        });
        if detailed {
            let pixels = mask.par_iter().map(|&b| f32::from(u8::from(b))).collect();
            mask_image = GrayImage::from_vec(color.width(), color.height(), pixels).ok();
        }
    }
    Ok(Detailed {
        output: MethodOutput {
            image,
            depth: None,
            timings,
            memory_bytes: None,
        },
        coc_px,
        edges,
        mask: mask_image,
    })
}

/// Pass `kernel`: the base kernel for a frame whose largest CoC radius is `max_radius_px`
/// ([`LowRankSettings::kernel_spec`]), rasterized, decomposed and tabulated for every radius
/// level at the settings' rank, stretched by the anamorphic squeeze.
pub fn kernel_bank(settings: &LowRankSettings, max_radius_px: f32) -> Result<dof::KernelBank> {
    let spec = settings.kernel_spec(max_radius_px);
    let lr = decompose(&kernel_image(&spec)?)?;
    if settings.rank > lr.len() {
        return Err(Error::invalid(
            "rank",
            format!(
                "{}: expected at most {} for a {} px kernel",
                settings.rank,
                lr.len(),
                spec.size_px
            ),
        ));
    }
    let squeeze = settings.effects.squeeze(glam::Vec2::ONE);
    dof::KernelBank::with_squeeze(&lr, settings.rank, max_radius_px, squeeze.x, squeeze.y)
}

/// The taps of the fallback gather on masked pixels: `fallback_taps` Poisson-disc taps in the
/// aperture, weighted by the aberration profile, squeezed by the anamorphic aspect.
pub fn fallback_taps(settings: &LowRankSettings) -> Result<Taps> {
    let mut taps = Taps::poisson_disc(
        &settings.aperture,
        settings.fallback_taps,
        settings.seed,
        settings.aberration,
    )?;
    for p in &mut taps.points {
        *p = settings.effects.squeeze(*p);
    }
    Ok(taps)
}

/// Checks a colour image and the CoC map it is filtered with: one size, at least 1x1, and the
/// run's estimate within the memory budget, as a run from a depth map is held to.
pub fn check_coc_frame(
    color: &ColorImage,
    coc_px: &GrayImage,
    settings: &LowRankSettings,
) -> Result<()> {
    if !color.same_size(coc_px) {
        return Err(Error::Mismatch(format!(
            "colour image is {}x{} but the CoC map is {}x{}",
            color.width(),
            color.height(),
            coc_px.width(),
            coc_px.height()
        )));
    }
    if color.width() == 0 || color.height() == 0 {
        return Err(Error::invalid(
            "image size",
            "0 pixels: expected at least 1x1",
        ));
    }
    super::registry::check_budget(
        &super::registry::MethodSettings::Lowrank(settings.clone()),
        color.width(),
        color.height(),
    )
}
