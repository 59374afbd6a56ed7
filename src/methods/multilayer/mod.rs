//! `multilayer`: depth of field by multi-layer filtering of per-pixel fragment lists (Selgrad,
//! Reintges, Penk, Wagner, Stamminger, "Real-time Depth of Field using Multi-Layer Filtering",
//! I3D 2015). The first method here that sees behind out-of-focus geometry near the lens: the
//! lists keep the surfaces hidden in the pinhole view, and the filtered levels blur the near
//! ones over them.
//!
//! # Passes, in order (each timed as `multilayer/<pass>`)
//! 1. `collect` (section 4, [`collect()`]): rasterize the pinhole view into
//!    [`crate::raster::FragmentLists`]: every fragment of every pixel (no depth test), sorted by
//!    depth, capped at the N nearest (`fragments`, 4 by default as the paper), compacted by a
//!    prefix sum; half-precision colour and opacity, f32 depth.
//! 2. `filter` (section 5, [`mod@filter`]): the Y-map: `m` mip-mapping steps then `s` stack steps,
//!    each merging 2x2 lists (merge-sort style, fragments within the depth threshold merged:
//!    over within a list, additive across lists); level S is a box filter of width `2^S`
//!    pixels. With truncation (section 6.2) a level drops the depths it will never be asked for.
//! 3. `accumulate` (section 6.1, [`mod@accumulate`]): per pixel, each level's fragments weighted by
//!    how well the level's filter size matches their CoC (level borders of the table T, with
//!    interpolation between neighbouring levels), blended front to back. With the default
//!    [`Bokeh::Shape`] ([`mod@shape`]) CoCs from 4.5 px are instead gathered in the aperture's
//!    shape on one level's grid of cells.
//!
//! # Where we differ from the paper, and why
//! - The filter configuration defaults to `auto`: one mip step then as many stack steps as the
//!   largest CoC diameter in the frame needs (at least the paper's 1/3). The paper's fixed four
//!   steps give boxes of at most 16 px, while the near bars of `railing` have a CoC diameter of
//!   71 px at 1280x720; `--filter-steps 1/3`, `2/2` and `4/0` run the paper's configurations.
//! - The paper matches a level's fragment size to the CoC up to camera constants it leaves
//!   open (`Coc(z) = F |z - z_f|`). We match the box of width `2^S` to the disc of radius `|C|`
//!   with the same variance (`sqrt(3) |C| = 2^S`), and interpolate between the two levels
//!   around it so that the blend has the disc's variance exactly: a point light then spreads
//!   with the standard deviation of `reference`'s bokeh (matching the diameter `2|C| = 2^S`
//!   instead spreads it 30% wider; measured in the point-light test).
//! - The depth threshold is relative to depth (see [`mod@filter`]); the paper gives no value.
//! - The merged fragment's depth is the opacity-weighted mean depth of what was merged.
//! - Level interpolation: the paper says only "we interpolate accordingly"; see [`mod@accumulate`].
//! - The lists' input ([`crate::raster::LayeredInput`], default on, `--no-coverage` and
//!   `--no-guard-band` for the paper's): fragments carry 16-sample coverage masks (textures
//!   shaded per sample), so in-focus edges resolve as in an anti-aliased frame at one fragment
//!   per pixel and surface; and the lists cover the frame grown by the largest CoC in view, so
//!   the blur at the border gathers what lies outside it.
//! - `bokeh` (`--ml-bokeh`, [`Bokeh::Shape`] by default, not in the paper): the paper's levels
//!   are box filters and its Bokeh is a square (section 2: "we use a simple box ... blur"). We
//!   gather each fragment with a CoC radius of at least 4.5 px from the level whose box is
//!   1/2.5 to 1/5 of its CoC, on a grid of that level's cells weighted by the shared
//!   [`Aperture`]'s coverage ([`mod@shape`]), so the bokeh has `reference`'s shape; the filter then
//!   needs fewer stack steps. Measured against `reference` at 640x360: +3.5 dB on `lights`,
//!   +0.06 to +0.08 dB on `railing`, `glass`, `grass`; 1.02 to 1.12 times the time at 1280x720.
//!   `--ml-bokeh box` is the paper's; `--ml-bokeh full` ([`Bokeh::Full`]) gathers from 2.5 px,
//!   level 0 at every other pixel (`railing` at 640x360 +2.1 dB, for 16% more time).
//! - `box_read` (`--ml-box-read`, [`BoxRead::Bilinear`] by default, not in the paper): with the
//!   shape's bokeh, the box levels coarser than a pixel are read from the four cells around the
//!   pixel's centre, weighted bilinearly, not from the nearest cell, whose blur came in blocks
//!   of the level's cells (`railing` at 640x360 +1.0 dB, `grass` +0.8 dB).
//! - `highlights` (`--highlight-rays`, default on for fragments brighter than white; not in
//!   the paper): such fragments are scattered on their own with each lens ray's visibility past
//!   the nearer fragments ([`crate::methods::highlights`]), so a near bar's shadow crosses the
//!   bokeh of a light behind it as a stripe, where the levels' composite dims the whole disc
//!   (`traps` +11.8 dB, Cycles' railing +8.7; measured in the README).
//! - `supersample` (off by default, not in the paper): collect the lists at K x K times the
//!   resolution and mip-merge them down to the output resolution before filtering, which
//!   anti-aliases the in-focus surfaces at K^2 times the cost of `collect`.

pub mod accumulate;
pub mod filter;
pub mod gpu;
pub mod shape;

use rayon::prelude::*;

use crate::image::{ColorImage, GrayImage};
use crate::lens::{Aperture, Camera, ThinLens};
use crate::raster::{
    render_fragment_lists_with, FragmentLists, LayeredInput, PreparedScene, Reach, View,
};
use crate::scene::Scene;
use crate::timing::Timings;
use crate::{Error, Result};

pub use accumulate::accumulate;
use filter::{Level, Step};

use super::highlights;
use super::splat::blend::Shape;
use super::MethodOutput;

/// `--timings` labels of `multilayer`.
pub mod pass {
    /// World to camera space.
    pub const PREPARE: &str = "multilayer/prepare";
    /// Rasterize the fragment lists (section 4).
    pub const COLLECT: &str = "multilayer/collect";
    /// Build the filtered levels (section 5).
    pub const FILTER: &str = "multilayer/filter";
    /// Blend the levels into the image (section 6.1).
    pub const ACCUMULATE: &str = "multilayer/accumulate";
    /// Bright fragments scattered with their rays' visibility (`highlights`).
    pub const HIGHLIGHTS: &str = "multilayer/highlights";
}

/// The filter configuration: mip-mapping then stack-filtering steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterSteps {
    /// One mip step, then stack steps until the largest CoC diameter in the frame is covered
    /// (at least three: the paper's `1/3`).
    Auto,
    /// Exactly `mip` mip steps, then `stack` stack steps.
    Fixed {
        /// Mip-mapping (resolution-halving) steps.
        mip: usize,
        /// Stack-filtering steps.
        stack: usize,
    },
}

impl FilterSteps {
    /// Parses `auto` or `M/S`.
    pub fn parse(s: &str) -> Result<Self> {
        let s = s.trim();
        if s == "auto" {
            return Ok(Self::Auto);
        }
        let bad = || {
            Error::invalid(
                "filter steps",
                format!("'{s}': expected auto or M/S (mip steps / stack steps, e.g. 1/3)"),
            )
        };
        let (m, st) = s.split_once('/').ok_or_else(bad)?;
        let mip = m.trim().parse().map_err(|_| bad())?;
        let stack = st.trim().parse().map_err(|_| bad())?;
        let f = Self::Fixed { mip, stack };
        f.validate()?;
        Ok(f)
    }

    fn validate(&self) -> Result<()> {
        if let Self::Fixed { mip, stack } = *self {
            if mip + stack == 0 {
                return Err(Error::invalid(
                    "filter steps",
                    format!("{mip}/{stack}: expected at least one step (no step blurs nothing)"),
                ));
            }
            if mip + stack > MAX_FILTER_STEPS {
                return Err(Error::invalid(
                    "filter steps",
                    format!("{mip}/{stack}: expected at most {MAX_FILTER_STEPS} steps in all"),
                ));
            }
        }
        Ok(())
    }
}

/// The shape of the bokeh that the accumulation gives.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Bokeh {
    /// The paper's: each fragment from the box-filtered level whose variance matches its CoC
    /// (a point light becomes a soft square).
    Box,
    /// The [`Aperture`]'s shape: a gather on each level's grid weighted by the aperture's
    /// coverage ([`mod@shape`]), for CoC radii from 4.5 px (smaller ones as [`Bokeh::Box`]).
    #[default]
    Shape,
    /// [`Bokeh::Shape`] for CoC radii from 2.5 px: level 0 (the pixel grid) gathered too, at
    /// every other pixel. Closer to `reference` where much of a frame has a blur of a few pixels
    /// (small frames, a background just out of focus), for 10-30% more time.
    Full,
}

impl Bokeh {
    /// Parses `box`, `shape` or `full`.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "box" => Ok(Self::Box),
            "shape" => Ok(Self::Shape),
            "full" => Ok(Self::Full),
            other => Err(Error::Unknown {
                kind: "bokeh",
                name: other.to_string(),
                expected: "box, shape, full".into(),
            }),
        }
    }

    /// The name [`Bokeh::parse`] reads.
    pub fn name(self) -> &'static str {
        match self {
            Self::Box => "box",
            Self::Shape => "shape",
            Self::Full => "full",
        }
    }

    /// The first level gathered in the aperture's shape; `None` for the box.
    pub fn first_shape_level(self) -> Option<usize> {
        match self {
            Self::Box => None,
            Self::Shape => Some(shape::FIRST_SHAPE_LEVEL),
            Self::Full => Some(0),
        }
    }
}

/// Most filter steps (a box of 2^10 = 1024 pixels).
pub const MAX_FILTER_STEPS: usize = 10;

/// How a pixel reads a box level whose cells are coarser than a pixel (the levels serving
/// CoCs below the shape threshold, [`Bokeh::Shape`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BoxRead {
    /// The cell whose centre is nearest, as the paper: a level of 2^k px cells draws its
    /// blur in blocks of 2^k px (an alpha-cut sprig of CoC 2.8 px came out in 2 px squares).
    Nearest,
    /// The four cells around the pixel's centre, weighted bilinearly, one surface seen from
    /// several cells merged into one entry (not in the paper; as the shape levels are read).
    #[default]
    Bilinear,
}

impl BoxRead {
    /// Parses `nearest` or `bilinear`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "nearest" => Ok(Self::Nearest),
            "bilinear" => Ok(Self::Bilinear),
            other => Err(Error::invalid(
                "box read",
                format!("{other:?}: expected nearest or bilinear"),
            )),
        }
    }
}

/// Settings of `multilayer`.
#[derive(Clone, Debug, PartialEq)]
pub struct MultilayerSettings {
    /// N: fragments kept per pixel, 1 to 16 (paper: 3 or 4). Default 4.
    pub fragments: usize,
    /// Depth threshold of merging, relative to depth (0.05 merges fragments within 5% of the
    /// nearer one's depth). Default 0.05.
    pub epsilon: f32,
    /// Filter configuration. Default [`FilterSteps::Auto`].
    pub filter_steps: FilterSteps,
    /// List truncation while filtering (section 6.2). Default on.
    pub truncation: bool,
    /// K: collect the lists at K x K samples per pixel and mip-merge them to the output
    /// resolution (1, 2 or 4; not in the paper). Default 1.
    pub supersample: usize,
    /// Coverage masks and guard band of the lists (default both on; off: the paper's input).
    pub input: LayeredInput,
    /// Bokeh in the paper's box or in the aperture's shape (not in the paper). Default
    /// [`Bokeh::Shape`]: closer to `reference` on every built-in scene (README, "Bokeh shape").
    pub bokeh: Bokeh,
    /// The aperture of [`Bokeh::Shape`] (the same value `reference` takes). Default the disc.
    pub aperture: Aperture,
    /// Fragments brighter than this (linear luminance over coverage) are scattered on their
    /// own with each lens ray's visibility past the nearer surfaces
    /// ([`crate::methods::highlights`]); `None`: filtered as every fragment (the paper's).
    /// Default 1 (brighter than white; measured in the README).
    pub highlights: Option<f32>,
    /// How a pixel reads the box levels coarser than a pixel, with [`Bokeh::Shape`]: the
    /// nearest cell (the paper's) or the four around it weighted bilinearly (not in the
    /// paper). Default [`BoxRead::Bilinear`] (measured in the README). `Bokeh::Box` reads as
    /// the paper.
    pub box_read: BoxRead,
}

impl Default for MultilayerSettings {
    fn default() -> Self {
        Self {
            fragments: 4,
            epsilon: 0.05,
            filter_steps: FilterSteps::Auto,
            truncation: true,
            supersample: 1,
            input: LayeredInput::default(),
            bokeh: Bokeh::default(),
            aperture: Aperture::Disc,
            highlights: Some(1.0),
            box_read: BoxRead::default(),
        }
    }
}

impl MultilayerSettings {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<()> {
        if !(1..=crate::raster::MAX_FRAGMENTS_PER_PIXEL).contains(&self.fragments) {
            return Err(Error::invalid(
                "fragments",
                format!(
                    "{}: expected 1 to {} fragments per pixel",
                    self.fragments,
                    crate::raster::MAX_FRAGMENTS_PER_PIXEL
                ),
            ));
        }
        if !(self.epsilon.is_finite() && (0.0..=1.0).contains(&self.epsilon)) {
            return Err(Error::invalid(
                "epsilon",
                format!(
                    "{}: expected a relative depth threshold from 0 to 1",
                    self.epsilon
                ),
            ));
        }
        if ![1, 2, 4].contains(&self.supersample) {
            return Err(Error::invalid(
                "supersample",
                format!("{}: expected 1, 2 or 4", self.supersample),
            ));
        }
        self.aperture.validate()?;
        crate::methods::highlights::check_threshold(self.highlights)?;
        self.filter_steps.validate()
    }
}

/// Level borders (section 6.1): the level coordinate of a depth, and the paper's table T.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Borders {
    lens: ThinLens,
}

impl Borders {
    /// The borders of `lens`.
    pub fn new(lens: ThinLens) -> Self {
        Self { lens }
    }

    /// The level coordinate of depth `z_m`: `log2(sqrt(3) |C(z)|)`, the `log2` of the width of
    /// the box filter with the same variance as the disc of radius `|C|` (a box of width `w` has
    /// variance `w^2 / 12` per axis, the disc `C^2 / 4`). Level S (a box of `2^S` pixels)
    /// matches the CoC where this equals S; -inf on the focal plane.
    #[inline(always)]
    pub fn lambda(&self, z_m: f32) -> f32 {
        lambda_of_radius(self.lens.coc_px(z_m).abs())
    }

    /// `z_N,S`: the depth in front of the focal plane where the CoC matches level S
    /// (`sqrt(3) |C| = 2^S` pixels).
    pub fn near_m(&self, s: usize) -> f32 {
        self.near_at(s as f32)
    }

    /// The depth in front of the focal plane where `lambda(z) = t` (t may be fractional).
    pub fn near_at(&self, t: f32) -> f32 {
        let r = t.exp2() / 3f32.sqrt();
        1.0 / (1.0 / self.lens.focus_m + r / (self.lens.f_px * self.lens.lens_radius_m))
    }

    /// The depth behind the focal plane where `lambda(z) = t`, +inf when there is none.
    pub fn far_at(&self, t: f32) -> f32 {
        let r = t.exp2() / 3f32.sqrt();
        let inv = 1.0 / self.lens.focus_m - r / (self.lens.f_px * self.lens.lens_radius_m);
        if inv > 0.0 {
            1.0 / inv
        } else {
            f32::INFINITY
        }
    }

    /// `z_F,S`: the depth behind the focal plane where the CoC matches level S, +inf when the
    /// CoC never grows that large.
    pub fn far_m(&self, s: usize) -> f32 {
        self.far_at(s as f32)
    }

    /// The table T for `levels` levels: `(z_N,n-1, n-1), ..., (z_N,0, 0), (z_F,0, 1), ...,
    /// (z_F,n-1, n)` with `n = levels - 1`: from the front, the depth at which the traversal
    /// switches to each level.
    pub fn table(&self, levels: usize) -> Vec<(f32, usize)> {
        let n = levels.saturating_sub(1);
        let mut t: Vec<(f32, usize)> = (0..n).rev().map(|s| (self.near_m(s), s)).collect();
        t.extend((0..n).map(|s| (self.far_m(s), s + 1)));
        t
    }
}

/// Estimated peak bytes of `multilayer` on a frame of `lens` with `settings`: the lists at
/// full occupancy (12 bytes a fragment, N per pixel, times the supersampling), the tiles'
/// slots while collecting, level 0, and the filtered levels (about as much again as level 0:
/// merging keeps them short), checked against [`crate::budget`].
pub fn peak_bytes(lens: &ThinLens, settings: &MultilayerSettings) -> u64 {
    let k = settings.supersample as u64;
    let px = (lens.width_px * lens.height_px) as u64;
    let lists = px * k * k * settings.fragments as u64 * 12;
    let level0 = px * settings.fragments as u64 * 12;
    2 * lists + 2 * level0 + px * 16
}

/// Refuses a run whose lists and levels ([`peak_bytes`]) and what it holds beside them,
/// `held` (the scene and its camera-space copy, or the frame the lists were made from), pass
/// the memory budget.
fn check_memory(lens: &ThinLens, settings: &MultilayerSettings, held: u64) -> Result<()> {
    crate::budget::check(
        peak_bytes(lens, settings) + held,
        &format!(
            "multilayer at {}x{} with {} fragments per pixel",
            lens.width_px, lens.height_px, settings.fragments
        ),
        "--fragments, --ml-supersample or the resolution",
    )
}

/// How far a fragment's blur reaches in multilayer, in CoC radii: the shape gather reads cells
/// up to the aperture's extent (at most `sqrt 2` radii, for image apertures) plus half its edge
/// ramp of one cell, half a cell's box, the fragment's centroid up to `sqrt 2 / 2` cells from
/// its cell's centre, and pixels read gathered cells up to half a box away, cells being at most
/// 1/2.5 of the radius (0.88 radii in all, 2.3 with the extent); the paper's box levels reach
/// `sqrt 3` radii. With a margin.
const REACH_RADII: f32 = 2.5;

/// And in pixels besides (small CoCs, whose box levels are a few pixels wide).
const REACH_SLACK_PX: f32 = 4.0;

/// Pass `collect`: the fragment lists of the pinhole view (at `supersample` x `supersample`
/// times the resolution when asked). `guard` pixels on each side are a guard band around the
/// frame: there only the fragments whose blur can reach the frame are kept ([`Reach`]).
pub fn collect(
    prepared: &PreparedScene,
    lens: ThinLens,
    guard: usize,
    settings: &MultilayerSettings,
) -> Result<FragmentLists> {
    let k = settings.supersample;
    let mut big = lens;
    big.width_px *= k;
    big.height_px *= k;
    big.f_px *= k as f32;
    let reach = (guard > 0).then(|| Reach {
        frame: (
            guard * k,
            guard * k,
            big.width_px - 2 * guard * k,
            big.height_px - 2 * guard * k,
        ),
        lens: big,
        factor: REACH_RADII,
        slack_px: REACH_SLACK_PX * k as f32,
        square: false,
    });
    render_fragment_lists_with(
        prepared,
        &View::pinhole(big),
        settings.fragments,
        settings.input,
        reach,
        settings.highlights,
    )
}

/// The filter steps for a frame whose largest CoC diameter is `max_diameter_px`.
pub fn steps_for(settings: &MultilayerSettings, max_diameter_px: f32) -> (usize, usize) {
    match settings.filter_steps {
        FilterSteps::Fixed { mip, stack } => (mip, stack),
        FilterSteps::Auto => {
            let need = match settings.bokeh.first_shape_level() {
                // The largest level must reach the equal-variance box of the largest CoC.
                None => (0.5 * 3f32.sqrt() * max_diameter_px).max(1.0).log2().ceil() as usize,
                // The top level's box must be at least 1 / (2 rho) of the largest CoC radius.
                Some(first) => shape::levels_needed(0.5 * max_diameter_px, first) - 1,
            };
            let total = need.clamp(4, MAX_FILTER_STEPS);
            (1, total - 1)
        }
    }
}

/// Pass `filter`: level 0 (the lists, mip-merged down to the output resolution first when
/// supersampled) and the levels of the Y-map. Returns the levels and the peak bytes held.
pub fn filter(
    lists: &FragmentLists,
    borders: &Borders,
    settings: &MultilayerSettings,
) -> (Vec<Level>, usize) {
    filter_with(lists, borders, settings, filter::step)
}

/// A step of the filter pass (see [`filter::step`]).
type StepFn = fn(&Level, Step, f32, &(dyn Fn(f32) -> bool + Sync), bool) -> Level;

fn filter_with(
    lists: &FragmentLists,
    borders: &Borders,
    settings: &MultilayerSettings,
    step_fn: StepFn,
) -> (Vec<Level>, usize) {
    let eps = settings.epsilon;
    let mut base = Level::base(lists);
    let mut peak = lists.bytes();
    let keep_all = |_: f32| true;
    let mut k = settings.supersample;
    while k > 1 {
        base = step_fn(&base, Step::Mip, eps, &keep_all, false);
        peak = peak.max(lists.bytes() + base.bytes());
        k /= 2;
    }
    // From here on positions are in output pixels, and level 0 is a 1-pixel box.
    let k = settings.supersample as f32;
    base.stride_px /= k;
    base.origin_px /= k;
    base.footprint_px = 1.0;
    let max_d = lists
        .depths()
        .par_iter()
        .map(|&z| 2.0 * borders.lens.coc_px(z).abs())
        .filter(|d| d.is_finite())
        .reduce(|| 0.0f32, f32::max);
    let (mip, stack) = steps_for(settings, max_d);
    let mut levels = vec![base];
    let mut total = peak.max(levels[0].bytes());
    for (i, st) in filter::y_map(mip, stack).into_iter().enumerate() {
        let s = i + 1;
        let truncate = settings.truncation;
        // With bokeh in the shape, CoCs from the threshold are read only by the gather of the
        // level whose band holds them, so a level keeps those at or above its band; smaller
        // ones go to the box levels, truncated as in the paper.
        let first = settings.bokeh.first_shape_level();
        let shaped = first.is_some_and(|f| s >= f);
        let first = first.unwrap_or(shape::FIRST_SHAPE_LEVEL);
        let (threshold, band_lo) = (
            shape::shape_threshold_px(first),
            shape::band_px(s, usize::MAX, first).0,
        );
        let keep = move |z: f32| {
            if !truncate {
                return true;
            }
            let r = borders.lens.coc_px(z).abs();
            if shaped && r >= threshold {
                r >= band_lo
            } else {
                lambda_of_radius(r) > s as f32 - 1.0
            }
        };
        // Only the levels gathered in the aperture's shape read where a fragment's energy lies.
        let centroids = shaped;
        let next = step_fn(&levels[i], st, eps, &keep, centroids);
        levels.push(next);
        total = total.max(levels.iter().map(Level::bytes).sum::<usize>());
    }
    (levels, total)
}

/// The level coordinate of a CoC radius `r` pixels ([`Borders::lambda`]).
#[inline(always)]
pub fn lambda_of_radius(r: f32) -> f32 {
    (3f32.sqrt() * r).log2()
}

/// Renders `scene` through `camera` with multi-layer filtering.
pub fn render(
    scene: &Scene,
    camera: &Camera,
    settings: &MultilayerSettings,
) -> Result<MethodOutput> {
    render_with(scene, camera, settings, accumulate_for, filter::step)
}

/// [`render`] with the filter and accumulate passes built for the portable baseline only
/// ([`filter::step_baseline`], [`accumulate_for_baseline`]): the twin the run-time
/// dispatched build is tested against.
pub fn render_baseline(
    scene: &Scene,
    camera: &Camera,
    settings: &MultilayerSettings,
) -> Result<MethodOutput> {
    render_with(
        scene,
        camera,
        settings,
        accumulate_for_baseline,
        filter::step_baseline,
    )
}

/// Blends the levels into the output image of `region` with the bokeh `settings` ask for: the
/// paper's box ([`accumulate::accumulate_box`]) or the aperture's shape
/// ([`shape::accumulate_shape`]).
pub fn accumulate_for(
    levels: &[Level],
    borders: &Borders,
    settings: &MultilayerSettings,
    region: accumulate::Region,
) -> ColorImage {
    match settings.bokeh.first_shape_level() {
        None => accumulate::accumulate_box(levels, borders, settings.epsilon, region),
        Some(first) => shape::accumulate_shape(
            levels,
            borders,
            &settings.aperture,
            (settings.epsilon, first, settings.box_read),
            region,
        ),
    }
}

/// [`accumulate_for`] built for the portable baseline only: the twin the run-time dispatched
/// build is tested against.
pub fn accumulate_for_baseline(
    levels: &[Level],
    borders: &Borders,
    settings: &MultilayerSettings,
    region: accumulate::Region,
) -> ColorImage {
    match settings.bokeh.first_shape_level() {
        None => accumulate::accumulate_box_baseline(levels, borders, settings.epsilon, region),
        Some(first) => shape::accumulate_shape_baseline(
            levels,
            borders,
            &settings.aperture,
            (settings.epsilon, first, settings.box_read),
            region,
        ),
    }
}

/// The accumulate pass's signature (see [`accumulate_for`]).
type AccumulateFn = fn(&[Level], &Borders, &MultilayerSettings, accumulate::Region) -> ColorImage;

fn render_with(
    scene: &Scene,
    camera: &Camera,
    settings: &MultilayerSettings,
    accumulate_fn: AccumulateFn,
    step_fn: StepFn,
) -> Result<MethodOutput> {
    settings.validate()?;
    let frame = camera.thin_lens()?;
    // The scene, its camera-space copy and the binned view are held while the lists fill.
    let held = super::registry::scene_peak_bytes(scene)?;
    check_memory(&frame, settings, held)?;
    let mut timings = Timings::default();
    let prepared = timings.time(pass::PREPARE, || {
        PreparedScene::new(scene, &camera.camera_from_world)
    })?;
    // The lists cover the frame and its guard band, so the blur at the border gathers what
    // lies just outside; the image is cut back to the frame at the end.
    let guard = settings.input.guard_band_px(&prepared, &frame);
    let lens = frame.with_guard_band(guard);
    check_memory(&lens, settings, held)?;
    let lists = timings.time(pass::COLLECT, || collect(&prepared, lens, guard, settings))?;
    let fitted = Fitted { lens, guard, frame };
    from_lists(lists, &fitted, settings, timings, (accumulate_fn, step_fn))
}

/// Where fragment lists lie: the lens of the lists (the frame and its guard band), the band's
/// width in pixels, and the frame's own lens.
struct Fitted {
    lens: ThinLens,
    guard: usize,
    frame: ThinLens,
}

/// Filters and accumulates fragment lists that do not come from a scene (a frame decomposed
/// into layers, [`crate::methods::fill`]): `lists` cover exactly the frame of `lens` (no guard
/// band; the filter clamps at its borders), at its resolution. Passes `highlights`, `filter`
/// and `accumulate`, as [`render`] after its `collect`.
pub fn render_lists(
    lists: FragmentLists,
    lens: &ThinLens,
    settings: &MultilayerSettings,
) -> Result<MethodOutput> {
    settings.validate()?;
    if settings.supersample != 1 {
        return Err(Error::invalid(
            "supersample",
            format!(
                "{}: fragment lists given at the frame's resolution take 1 (supersampling \
                 needs a scene)",
                settings.supersample
            ),
        ));
    }
    if (lists.width(), lists.height()) != (lens.width_px, lens.height_px) {
        return Err(Error::Mismatch(format!(
            "fragment lists of {}x{} for a lens of {}x{}",
            lists.width(),
            lists.height(),
            lens.width_px,
            lens.height_px
        )));
    }
    // The lists are held, and counted at full occupancy by the estimate; the frame they were
    // made from (colour and depth) is held beside them.
    check_memory(lens, settings, (lens.width_px * lens.height_px) as u64 * 20)?;
    let fitted = Fitted {
        lens: *lens,
        guard: 0,
        frame: *lens,
    };
    from_lists(
        lists,
        &fitted,
        settings,
        Timings::default(),
        (accumulate_for, filter::step),
    )
}

/// Passes `highlights`, `filter` and `accumulate` of `lists` lying as `fitted` says.
fn from_lists(
    mut lists: FragmentLists,
    fitted: &Fitted,
    settings: &MultilayerSettings,
    mut timings: Timings,
    (accumulate_fn, step_fn): (AccumulateFn, StepFn),
) -> Result<MethodOutput> {
    let Fitted { lens, guard, frame } = *fitted;
    let k = settings.supersample;
    let fine = ThinLens {
        width_px: lens.width_px * k,
        height_px: lens.height_px * k,
        f_px: lens.f_px * k as f32,
        ..lens
    };
    let highlights = settings.highlights.map(|threshold| {
        timings.time(pass::HIGHLIGHTS, || {
            highlights::take(&mut lists, &fine, k as f32, threshold, f32::INFINITY)
        })
    });
    let borders = Borders::new(lens);
    let (levels, bytes) = timings.time(pass::FILTER, || {
        filter_with(&lists, &borders, settings, step_fn)
    });
    // Only the frame is accumulated; its guard band was needed by the filter.
    let (w, h) = (frame.width_px, frame.height_px);
    let region = accumulate::Region {
        x0: guard,
        y0: guard,
        width: w,
        height: h,
    };
    let mut image = timings.time(pass::ACCUMULATE, || {
        accumulate_fn(&levels, &borders, settings, region)
    });
    if let Some(highlights) = highlights {
        let shape = Shape::new(&settings.aperture);
        let seen = timings.time(pass::HIGHLIGHTS, || {
            highlights::scatter(
                &highlights,
                &lists,
                &fine,
                &shape,
                k as f32,
                (guard, guard, w, h),
            )
        });
        highlights::add_into(&mut image, &seen);
    }
    let depth = pinhole_depth(&levels[0]).crop(guard, guard, w, h);
    Ok(MethodOutput {
        image,
        depth: Some(depth),
        timings,
        memory_bytes: Some(bytes),
    })
}

/// Depth of the nearest fragment of each cell of level 0 (+inf where none).
fn pinhole_depth(base: &Level) -> GrayImage {
    let data = crate::raster::nearest_depths(&base.offsets, &base.depth);
    GrayImage::from_vec(base.width, base.height, data).expect("sizes agree by construction")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The guard band's fragments that [`Reach`] drops change nothing in the frame: the image
    /// of `traps` (a railing crossing the borders at a CoC of tens of pixels, lights far
    /// behind) and of `grass` is the same bit for bit with and without them, while some are
    /// dropped.
    #[test]
    fn dropping_the_guard_fragments_that_cannot_reach_the_frame_changes_nothing() {
        for name in ["traps", "grass"] {
            let scene = crate::scene::builtin::load(name).unwrap();
            let mut camera = scene.defaults.clone().unwrap().camera;
            camera.width_px = 320;
            camera.height_px = 180;
            let settings = MultilayerSettings {
                aperture: scene.defaults.clone().unwrap().aperture,
                ..MultilayerSettings::default()
            };
            let frame = camera.thin_lens().unwrap();
            let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
            let guard = settings.input.guard_band_px(&prepared, &frame);
            assert!(guard > 0, "{name}");
            let lens = frame.with_guard_band(guard);
            let image = |lists: &FragmentLists| {
                let borders = Borders::new(lens);
                let (levels, _) = filter_with(lists, &borders, &settings, filter::step);
                let region = accumulate::Region {
                    x0: guard,
                    y0: guard,
                    width: frame.width_px,
                    height: frame.height_px,
                };
                accumulate_for(&levels, &borders, &settings, region)
            };
            let trimmed = collect(&prepared, lens, guard, &settings).unwrap();
            let full = crate::raster::render_fragment_lists(
                &prepared,
                &View::pinhole(lens),
                settings.fragments,
                settings.input,
                None,
            )
            .unwrap();
            assert!(
                trimmed.depths().len() < full.depths().len(),
                "{name}: {} of {} fragments kept",
                trimmed.depths().len(),
                full.depths().len()
            );
            assert!(image(&trimmed) == image(&full), "{name}");
        }
    }
}
