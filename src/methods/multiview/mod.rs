//! `multiview`: depth of field by multiview synthesis from CoC-spaced depth layers (Lee,
//! Eisemann, Seidel, "Depth-of-Field Rendering with Multiview Synthesis", SIGGRAPH Asia 2009).
//! Instead of rasterizing the scene once per lens sample (`reference`), the scene is rasterized
//! once into a few layers, and lens rays are traced through them per pixel: the cost stops
//! growing with scene complexity.
//!
//! # Passes, in order (each timed as `multiview/<pass>`)
//! 1. `decompose` (sections 4.1-4.2, [`decompose`]): layers uniform in signed CoC from the
//!    nearest geometry (eq. 4, spacing delta in pixels, or a given number of layers), each with
//!    its own depth buffer ([`crate::raster::DepthLayers`]), 10% overlap between neighbours.
//! 2. `mipmap`: for cone tracing, the layers' mipmaps with coverage in alpha.
//! 3. `cull` (section 4.3, [`cull`]): per layer the minimum CoC over each pixel's window, for
//!    early layer culling (the paper's N-buffer query, computed once per pixel: see the module).
//! 4. `trace` (sections 4.3-4.5, [`trace`]): per pixel, N lens rays from the shared
//!    [`crate::lens::SampleSet`] over the shared [`Aperture`] (so the bokeh matches
//!    `reference`), traced as height-field tests layer after layer, first hit kept, averaged;
//!    cone tracing and per-pixel jitter of the sample set.
//!
//! # Where we differ from the paper, and why
//! - Each fragment goes to the layer of its own depth (the exact decomposition): the paper's
//!   triangle-to-farthest-vertex-layer assignment and copy pass are a GPU work-around for
//!   independent depth buffers that a CPU rasterizer does not need.
//! - The ray-layer test samples the segment a pixel apart, so a thin surface between the
//!   segment's ends is not jumped over (a bracket also opens where the ray has come to the
//!   previous sample's surface CoC, so a surface met over that sample's pixel is not passed
//!   either), and finds the hit between the samples around the first
//!   crossing exactly for the layer as stored (one flat surface per pixel, walked pixel by
//!   pixel) instead of by the paper's false position on a linear model of the surface, which
//!   stalls where a surface meets a slightly nearer one beside it and then took the hit from
//!   the wrong pixel: in-focus edges bled a pixel outwards (`--paper-refine` keeps it;
//!   measured in the README).
//! - Jitter picks one of 16 complete sample sets per pixel (the paper's first option) rather
//!   than rotating samples, which would turn polygonal and image apertures.
//! - Layers see through (the paper has no transparency): each keeps its three nearest surfaces
//!   per pixel (more merged into the farthest) composited, with their coverage in alpha, and a
//!   ray takes a hit's share and goes on behind it ([`crate::raster::DepthLayers`]), so a pane
//!   or an edge covering part of a pixel shows what is behind it.
//! - A surface hidden in the pinhole view more than [`crate::raster::CONTINUITY_PX`] of CoC
//!   behind an opaque one of its own layer is also written to the next layer, where a ray that
//!   passes behind the nearer one meets it (`--no-see-behind` drops it, as the paper's layers
//!   do): with layers 4 px deep, a sprig 2.8 px in front of an in-focus chart in the chart's
//!   layer had showed the layer behind (a dark wall) through its blurred edge.
//! - The input ([`crate::raster::LayeredInput`], default on, `--no-coverage` and
//!   `--no-guard-band` for the paper's): fragments with 16-sample coverage masks, textures
//!   shaded per sample, so in-focus edges are anti-aliased; and layers over the frame grown by
//!   the largest CoC in view, so rays near the border reach what lies outside it (only the
//!   frame is traced). On the Cycles railing scene at 640x360 with 64 rays: 22.7 dB against
//!   Cycles' render with the paper's input, 33.9 dB with both.
//! - Cone tracing (default; `--paper-cone` for the paper's): a ray that passes a layer in front
//!   of the focal plane without hitting it also takes the coverage its cone meets there. In
//!   the paper only a ray whose
//!   centre hits takes the surface's coverage of its cone, so an object thinner than the cones
//!   blocks the square of its share of the light: the chart behind `railing`'s bars came out
//!   1.2% too bright, and `railing` gains 1.8 dB (32 rays), Cycles' railing 0.7 dB.
//! - The cones' mipmaps (default tent; `--cone-mipmap box`, or `--paper-cone`, for the paper's
//!   2x2 box): levels filtered by the `[1 3 3 1]` tent and read for a cone `sqrt(3/5)` as wide
//!   ([`MipFilter`]), the same footprint width as the box's, but one that does not change
//!   with where a read falls among the texels. With the box it followed the guard band's width,
//!   so the near blur shifted from frame to frame in a rack focus.

pub mod cull;
pub mod trace;

use glam::Vec2;
use rayon::prelude::*;

use crate::image::{ColorImage, GrayImage};
use crate::lens::{Aperture, Camera, LensEffects, SampleSet, SamplerKind, ThinLens};
use crate::random::SplitMix64;
use crate::raster::{
    DepthLayers, FragmentLists, LayerSpacing, LayeredInput, PreparedScene, Reach, View,
};
use crate::scene::Scene;
use crate::timing::Timings;
use crate::{Error, Result};

use super::highlights;
use super::splat::blend::Shape;
use super::MethodOutput;
use cull::WindowMin;
pub use trace::MipFilter;
use trace::{LayerMip, TraceInput};

/// The lens effects ([`crate::lens::EFFECT_NAMES`]) this method renders; it refuses the others.
pub const EFFECTS: &[&str] = &["anamorphic", "cats-eye", "chromatic"];

/// `--timings` labels of `multiview`.
pub mod pass {
    /// World to camera space.
    pub const PREPARE: &str = "multiview/prepare";
    /// Rasterize into the depth layers.
    pub const DECOMPOSE: &str = "multiview/decompose";
    /// The layers' mipmaps, for cone tracing.
    pub const MIPMAP: &str = "multiview/mipmap";
    /// Culling windows.
    pub const CULL: &str = "multiview/cull";
    /// Lens rays through the layers.
    pub const TRACE: &str = "multiview/trace";
    /// Bright texels taken out and scattered with their rays' visibility (`highlights`).
    pub const HIGHLIGHTS: &str = "multiview/highlights";
}

/// How many layers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LayerCount {
    /// Layers `spacing_px` of CoC apart, as many as the scene's CoC range needs (at most
    /// [`MAX_LAYERS`]; the spacing grows if more would be needed).
    Spacing {
        /// The paper's delta, in pixels.
        spacing_px: f32,
    },
    /// Exactly this many layers over the scene's CoC range.
    Count(usize),
}

/// Where the spaced layers' boundaries fall (`--layer-origin`; [`LayerCount::Spacing`] only).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LayerOrigin {
    /// From the nearest surface, the spacing apart: the paper's. Where the focal plane falls
    /// in its layer then depends on the scene and the lens.
    #[default]
    Near,
    /// From the nearest surface still, but the spacing shrunk (to no less than half of it, or
    /// grown by at most half where shrinking would halve it) so that the focal plane lies at
    /// the middle of a layer: an in-focus surface is never split between two layers at a
    /// boundary. Measured in the README: up to 2 dB better at 640x360, up to 0.5 dB worse at
    /// 1280x720.
    Focus,
}

impl LayerOrigin {
    /// Parses `near` or `focus`.
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim() {
            "near" => Ok(Self::Near),
            "focus" => Ok(Self::Focus),
            other => Err(Error::Unknown {
                kind: "layer origin",
                name: other.to_string(),
                expected: "near, focus".into(),
            }),
        }
    }
}

/// Most layers.
pub const MAX_LAYERS: usize = 64;

/// Number of sample sets used by jitter.
pub const JITTER_SETS: usize = 16;

/// Settings of `multiview`.
#[derive(Clone, Debug, PartialEq)]
pub struct MultiviewSettings {
    /// Aperture shape (the same value as `reference`'s). Default disc.
    pub aperture: Aperture,
    /// Lens samples per pixel, 1 to 4096 (paper: 32 to 64 suffice). Default 32.
    pub samples: usize,
    /// Lens sampler. Default Halton.
    pub sampler: SamplerKind,
    /// Seed of the samplers and the noise tile. Default 0.
    pub seed: u64,
    /// Layers. Default a spacing of 4 px of CoC (the paper: 3 px at 800x600 is safe, 16 layers
    /// usually enough).
    pub layers: LayerCount,
    /// Overlap of neighbouring layers as a fraction of the spacing. Default 0.1 (the paper).
    pub overlap: f32,
    /// Where spaced layers' boundaries fall. Default [`LayerOrigin::Near`] (the paper's).
    pub layer_origin: LayerOrigin,
    /// Approximate cone tracing (section 4.4). Default on.
    pub cone: bool,
    /// With cone tracing, a ray that passes a layer in front of the focal plane without hitting
    /// it also takes the coverage its cone meets there (`trace::graze`); false: only rays whose
    /// centre hits a surface
    /// take its coverage, as the paper, which lets thin objects block too little light.
    /// Default on (measured in the README).
    pub graze: bool,
    /// Where a ray crosses a layer's surface: by default the first point at or behind it, the
    /// layer read as stored (one flat surface per pixel, walked pixel by pixel between the
    /// samples around the crossing); true: the paper's false-position refinement of a linear
    /// model of the surface, whose hit can stall on the neighbouring pixel at an in-focus edge
    /// (measured in the README). Default false.
    pub paper_refine: bool,
    /// Texels brighter than this (linear luminance over coverage) are scattered with each lens
    /// ray's visibility through the layers instead of being met by the rays, whose few samples
    /// of a small light are noisy ([`crate::methods::highlights`]; not with a cat's eye);
    /// `None`: traced as every texel (the paper's). Default 1 (measured in the README).
    pub highlights: Option<f32>,
    /// How the cones' mipmaps are filtered: the paper's 2x2 box, or a `[1 3 3 1]` tent whose
    /// footprint does not follow the texels' phase (measured in the README). Default tent.
    pub mip_filter: MipFilter,
    /// Per-pixel jitter of the sample set (section 4.5). Default on.
    pub jitter: bool,
    /// Early layer culling (section 4.3; the N-buffer query as a window minimum per pixel,
    /// [`cull`]). Default on.
    pub culling: bool,
    /// Coverage masks and guard band of the layers (default both on; off: pixel centres over
    /// the frame, as the paper).
    pub input: LayeredInput,
    /// A surface hidden in the pinhole view more than [`crate::raster::CONTINUITY_PX`] of CoC
    /// behind another of its layer is written to the next layer too, where a ray that passes
    /// behind the nearer one finds it ([`DepthLayers::seeing_behind`]; not in the paper).
    /// Default on (measured in the README).
    pub see_behind: bool,
    /// The real lens's departures from the ideal one: the anamorphic squeeze stretches every
    /// lens sample, as in `reference`; with a cat's eye each pixel keeps only the rays whose
    /// lens point passes its view of the barrel (per ray, as `reference` per view); with
    /// chromatic aberration each channel is a run of its own through its channel's lens, as
    /// `reference`. Default: the ideal lens.
    pub effects: LensEffects,
}

impl Default for MultiviewSettings {
    fn default() -> Self {
        Self {
            aperture: Aperture::Disc,
            samples: 32,
            sampler: SamplerKind::Halton,
            seed: 0,
            layers: LayerCount::Spacing { spacing_px: 4.0 },
            overlap: 0.1,
            layer_origin: LayerOrigin::Near,
            cone: true,
            graze: true,
            paper_refine: false,
            highlights: Some(1.0),
            mip_filter: MipFilter::Tent,
            jitter: true,
            culling: true,
            input: LayeredInput::SAMPLE_SHADED,
            see_behind: true,
            effects: LensEffects::default(),
        }
    }
}

impl MultiviewSettings {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<()> {
        highlights::check_threshold(self.highlights)?;
        if !(1..=4096).contains(&self.samples) {
            return Err(Error::invalid(
                "samples",
                format!(
                    "{}: expected 1 to 4096 lens samples per pixel",
                    self.samples
                ),
            ));
        }
        match self.layers {
            LayerCount::Spacing { spacing_px } => {
                if !(spacing_px.is_finite() && (0.25..=1024.0).contains(&spacing_px)) {
                    return Err(Error::invalid(
                        "layer spacing",
                        format!("{spacing_px} px: expected 0.25 to 1024 pixels of CoC"),
                    ));
                }
            }
            LayerCount::Count(n) => {
                if !(1..=MAX_LAYERS).contains(&n) {
                    return Err(Error::invalid(
                        "layers",
                        format!("{n}: expected 1 to {MAX_LAYERS} layers"),
                    ));
                }
            }
        }
        if !(self.overlap.is_finite() && (0.0..=0.5).contains(&self.overlap)) {
            return Err(Error::invalid(
                "layer overlap",
                format!("{}: expected a fraction from 0 to 0.5", self.overlap),
            ));
        }
        self.aperture.validate()
    }
}

/// The signed CoC range of the scene's geometry in view (see [`PreparedScene::coc_range`]).
pub fn coc_range(prepared: &PreparedScene, lens: &ThinLens) -> (f32, f32) {
    prepared.coc_range(lens)
}

/// The layer spacing of `settings` for CoCs in `[lo, hi]`.
pub fn spacing_for(
    lens: ThinLens,
    settings: &MultiviewSettings,
    (lo, hi): (f32, f32),
) -> LayerSpacing {
    let range = (hi - lo).max(1e-3);
    let (delta, layers) = match settings.layers {
        LayerCount::Count(n) => (range / n as f32 * (1.0 + 1e-4), n),
        LayerCount::Spacing { spacing_px } => {
            let n = (range / spacing_px).ceil().max(1.0) as usize;
            if n > MAX_LAYERS {
                (range / MAX_LAYERS as f32 * (1.0 + 1e-4), MAX_LAYERS)
            } else if n == 1 {
                // All the geometry within one spacing: one layer as deep as it, so rays do not
                // walk a layer of 4 px of CoC over a scene of a fraction of a pixel (almost a
                // pinhole, `--fstop 500`: the refined hits landed on neighbouring pixels and
                // the in-focus chart of `traps` came out blurred, 33.7 dB against the pinhole
                // frame; now 41.7, as `multilayer`).
                (range * (1.0 + 1e-4), 1)
            } else {
                match settings.layer_origin {
                    LayerOrigin::Near => (spacing_px, n),
                    LayerOrigin::Focus => focus_centred(spacing_px, (lo, hi)),
                }
            }
        }
    };
    LayerSpacing {
        lens,
        coc_near_px: lo,
        delta_px: delta,
        layers,
        overlap: settings.overlap,
    }
}

/// [`LayerOrigin::Focus`]: the spacing and layer count for layers from `lo` with the focal
/// plane (CoC 0) at the middle of layer `j`: `spacing = -lo / (j + 0.5)`, `j` the least for
/// which it is at most `spacing_px`, or one less where that would take it under half of
/// `spacing_px`. Where the focal plane lies in the first half of the first layer, or outside
/// the range, nothing in front of it or no surface near it can be split: the plain spacing.
fn focus_centred(spacing_px: f32, (lo, hi): (f32, f32)) -> (f32, usize) {
    let plain = (
        spacing_px,
        ((hi - lo) / spacing_px).ceil().max(1.0) as usize,
    );
    let x = -lo / spacing_px;
    if x <= 0.5 || hi <= 0.0 {
        return plain;
    }
    let mut j = (x - 0.5).ceil();
    if x / (j + 0.5) < 0.5 {
        j -= 1.0;
    }
    let delta = -lo / (j + 0.5);
    let n = ((hi - lo) / delta).ceil().max(1.0) as usize;
    if n > MAX_LAYERS {
        return plain;
    }
    (delta, n)
}

/// Pass `decompose`: the depth layers of the pinhole view.
pub fn decompose(
    prepared: &PreparedScene,
    lens: ThinLens,
    settings: &MultiviewSettings,
) -> Result<DepthLayers> {
    decompose_with_band(prepared, lens, settings, None)
}

/// How far from a pixel of the frame the trace reads a layer, per axis, in the layer's CoC
/// radii: the rays' offsets `|C v|` (`longest` the longest `|v|` of the sample sets), and the
/// pixels the cones' mipmap reads draw on, up to [`MipFilter::reach`] times the cone's
/// diameter `lambda |C|` away.
fn read_radii(longest: f32, lambda: f32, filter: MipFilter) -> f32 {
    longest + filter.reach() * lambda
}

/// [`decompose`] of a frame with a guard band of `band.0` pixels on each side, whose surfaces
/// are dropped (before they are shaded) where no ray of the frame reads them: farther from the
/// frame, along either axis, than `band.1` ([`read_radii`]) times the largest CoC they can be
/// traced at, plus two pixels. The trace reads the same values, so the image is the same.
fn decompose_with_band(
    prepared: &PreparedScene,
    lens: ThinLens,
    settings: &MultiviewSettings,
    band: Option<(usize, f32)>,
) -> Result<DepthLayers> {
    let spacing = spacing_for(lens, settings, coc_range(prepared, &lens));
    // The scene, its camera-space copy and the binned view are held while the layers fill.
    crate::budget::check(
        peak_bytes(&lens, spacing.layers) + super::registry::scene_peak_bytes(prepared.scene())?,
        &format!(
            "multiview at {}x{} with {} layers",
            lens.width_px, lens.height_px, spacing.layers
        ),
        "--layers, raise --layer-spacing, or lower the resolution",
    )?;
    let view = View::pinhole(lens);
    let binned = settings.input.bin(prepared, &view)?;
    let mut layers = DepthLayers::for_raster(spacing, lens.width_px, lens.height_px)
        .seeing_behind(settings.see_behind);
    if let Some((guard, radii)) = band.filter(|b| b.0 > 0) {
        // A surface of CoC C is traced in its layer, at CoCs up to a layer and the entry
        // margin beyond C, or in the layer it overlaps (within the margin of the boundary), a
        // layer and the margin beyond that.
        let beyond = (1.0 + 2.0 * spacing.overlap) * spacing.delta_px;
        layers = layers.with_reach(Reach {
            frame: (
                guard,
                guard,
                lens.width_px.saturating_sub(2 * guard),
                lens.height_px.saturating_sub(2 * guard),
            ),
            lens,
            factor: radii,
            slack_px: radii * beyond + 2.0,
            square: true,
        });
    }
    binned.rasterize(prepared, &mut layers);
    Ok(layers)
}

/// Estimated peak bytes of `multiview` with `layers` layers on a frame of `lens`: the layers
/// (12 bytes a pixel each), their culling windows (4 bytes) and mipmaps (a third of 16 bytes,
/// rounded up), and the transients of building them (a layer's colours in f32 per thread, and
/// three images of 4 bytes for a culling window) and the traced image.
pub fn peak_bytes(lens: &ThinLens, layers: usize) -> u64 {
    let px = (lens.width_px * lens.height_px) as u64;
    layers as u64 * px * (12 + 4 + 6) + px * (2 * 16 + 3 * 4 + 16)
}

/// The lens sample sets (one, or [`JITTER_SETS`] for jitter) and the noise tile.
pub fn sample_sets(settings: &MultiviewSettings) -> Result<(Vec<Vec<Vec2>>, Vec<u8>)> {
    let count = if settings.jitter { JITTER_SETS } else { 1 };
    let mut sets = Vec::with_capacity(count);
    for j in 0..count {
        let set = SampleSet::generate(
            &settings.aperture,
            settings.sampler,
            settings.samples,
            settings.seed.wrapping_add(j as u64),
        )?;
        let effects = settings.effects;
        effects.check_supported("multiview", EFFECTS)?;
        let mut points: Vec<Vec2> = set
            .samples
            .iter()
            .map(|s| effects.squeeze(s.lens))
            .collect();
        coherent_order(&mut points);
        sets.push(points);
    }
    let mut rng = SplitMix64::new(settings.seed ^ 0x6A17_7E12);
    let noise = (0..trace::NOISE_TILE * trace::NOISE_TILE)
        .map(|_| {
            if settings.jitter {
                rng.below(JITTER_SETS) as u8
            } else {
                0
            }
        })
        .collect();
    Ok((sets, noise))
}

/// Takes the texels of `layers` (made with `lens`) brighter than `threshold` out of them
/// (black, their coverage kept: rays still stop at them) as highlights, with the layers read as
/// fragment lists (a pixel's surfaces layer by layer, nearest first) for their rays'
/// visibility ([`highlights::take`]).
fn take_highlights(
    layers: &mut DepthLayers,
    lens: &ThinLens,
    threshold: f32,
) -> (Vec<highlights::Highlight>, FragmentLists) {
    let (w, h, m) = (layers.width, layers.height, layers.spacing.layers);
    let plane = w * h;
    // Most scenes have none: found first without building the lists.
    let bright = layers.color.par_iter().any(|c| {
        let c = crate::raster::from_half(c);
        c[3] > 0.0 && crate::image::luminance([c[0], c[1], c[2]]) > threshold * c[3]
    });
    if !bright {
        return (Vec::new(), FragmentLists::new(w, h, 1));
    }
    let mut offsets = Vec::with_capacity(plane + 1);
    let (mut depth, mut color, mut texel) = (Vec::new(), Vec::new(), Vec::new());
    offsets.push(0u32);
    for i in 0..plane {
        for l in 0..m {
            let c = layers.coc_px[l * plane + i];
            if c.is_finite() {
                depth.push(lens.depth_for_coc_px(c));
                color.push(layers.color[l * plane + i]);
                texel.push(l * plane + i);
            }
        }
        offsets.push(depth.len() as u32);
    }
    let mut lists = FragmentLists::from_parts(w, h, offsets, depth, color);
    let found = highlights::take_indexed(&mut lists, lens, 1.0, threshold, f32::INFINITY);
    for &(f, _) in &found {
        layers.color[texel[f]] = lists.colors()[f];
    }
    (found.into_iter().map(|(_, h)| h).collect(), lists)
}

/// Orders a pixel's lens samples so that the trace's packets of sixteen hold rays of like
/// direction: the inner quarter (by distance from the lens centre) then the rest, each by
/// angle. Rays of like direction read nearby pixels, cross the same surfaces and finish in the
/// same layer, so a packet's lanes do less work together (`railing` at 1280x720, 64 rays:
/// trace 1.49 -> 1.39 s; `grass` 5.3 -> 4.8 s). The set is the same; only the order in which
/// the rays are summed changes (a rounding).
fn coherent_order(points: &mut [Vec2]) {
    points.sort_by(|a, b| a.length().total_cmp(&b.length()));
    let inner = points.len() / 4;
    let angle = |a: &Vec2, b: &Vec2| a.y.atan2(a.x).total_cmp(&b.y.atan2(b.x));
    points[..inner].sort_by(angle);
    points[inner..].sort_by(angle);
}

/// Renders `scene` through `camera` by multiview synthesis.
pub fn render(
    scene: &Scene,
    camera: &Camera,
    settings: &MultiviewSettings,
) -> Result<MethodOutput> {
    render_with(scene, camera, settings, trace::trace, true)
}

/// [`render`] with the trace pass built for the portable baseline only
/// ([`trace::trace_baseline`]): the twin the run-time dispatched build is tested against.
pub fn render_baseline(
    scene: &Scene,
    camera: &Camera,
    settings: &MultiviewSettings,
) -> Result<MethodOutput> {
    render_with(scene, camera, settings, trace::trace_baseline, true)
}

/// [`render`] with the trace pass `trace_fn`; `trim`: the guard band's surfaces that no ray of
/// the frame reads are dropped ([`decompose_with_band`]), which must not change the image.
fn render_with(
    scene: &Scene,
    camera: &Camera,
    settings: &MultiviewSettings,
    trace_fn: fn(&TraceInput) -> ColorImage,
    trim: bool,
) -> Result<MethodOutput> {
    settings.validate()?;
    if settings.effects.is_chromatic() {
        // A run per channel through its own lens, as `reference`.
        settings.effects.check_supported("multiview", EFFECTS)?;
        let mono = MultiviewSettings {
            effects: settings.effects.without_colour(),
            ..settings.clone()
        };
        return super::per_channel(&settings.effects, camera.focus_m, |_, focus_m, scale| {
            let channel_camera = Camera {
                focus_m,
                fstop: camera.fstop / scale,
                ..camera.clone()
            };
            render_with(scene, &channel_camera, &mono, trace_fn, trim)
        });
    }
    let frame = camera.thin_lens()?;
    let mut timings = Timings::default();
    let prepared = timings.time(pass::PREPARE, || {
        PreparedScene::new(scene, &camera.camera_from_world)
    })?;
    // The layers cover the frame and its guard band, so rays near the border reach what lies
    // just outside it; only the frame is traced.
    let guard = settings.input.guard_band_px(&prepared, &frame);
    let lens = frame.with_guard_band(guard);
    let (sets, noise) = sample_sets(settings)?;
    let lambda = trace::mean_spacing(&sets[0]);
    let longest = sets
        .iter()
        .flatten()
        .map(|v| v.length())
        .fold(0.0f32, f32::max);
    let band = trim.then(|| (guard, read_radii(longest, lambda, settings.mip_filter)));
    let mut layers = timings.time(pass::DECOMPOSE, || {
        decompose_with_band(&prepared, lens, settings, band)
    })?;
    let m = layers.spacing.layers;
    let (w, h) = (layers.width, layers.height);
    // Texels brighter than the threshold are scattered with their rays' visibility through
    // the layers (read as lists) instead of met by the rays (not with a cat's eye, which the
    // scatter's footprints do not draw).
    let highlights = match settings.highlights {
        Some(threshold) if !settings.effects.has_cats_eye() => {
            Some(timings.time(pass::HIGHLIGHTS, || {
                take_highlights(&mut layers, &lens, threshold)
            }))
        }
        _ => None,
    };
    // The mipmaps and culling skip the empty layers.
    let filled: Vec<bool> = (0..m).map(|l| layers.filled(l)).collect();
    // The layers' mipmaps side by side, a layer to a task.
    let mips: Option<Vec<LayerMip>> = settings.cone.then(|| {
        timings.time(pass::MIPMAP, || {
            (0..m)
                .into_par_iter()
                .map(|l| {
                    let (a, b) = layers.spacing.bounds(l);
                    let d = lambda * settings.mip_filter.level_scale() * a.abs().max(b.abs());
                    let levels = if d > 1.0 {
                        d.log2().ceil() as usize + 1
                    } else {
                        0
                    };
                    if filled[l] {
                        LayerMip::new(&layers, l, levels, settings.mip_filter)
                    } else {
                        LayerMip::new(&layers, l, 0, settings.mip_filter)
                    }
                })
                .collect()
        })
    });
    let input = TraceInput {
        layers: &layers,
        culls: None,
        filled: &filled,
        mips: mips.as_deref(),
        mip_filter: settings.mip_filter,
        graze: settings.graze,
        paper_refine: settings.paper_refine,
        sets: &sets,
        noise: &noise,
        lambda,
        region: (guard, guard, frame.width_px, frame.height_px),
        clip: settings
            .effects
            .has_cats_eye()
            .then_some((settings.effects, frame)),
    };
    let culls: Option<Vec<Option<WindowMin>>> = settings.culling.then(|| {
        timings.time(pass::CULL, || {
            (0..m)
                .map(|l| {
                    filled[l].then(|| {
                        let plane = &layers.coc_px[l * w * h..(l + 1) * w * h];
                        WindowMin::new(plane, w, h, trace::cull_radius(&input, l))
                    })
                })
                .collect()
        })
    });
    let input = TraceInput {
        culls: culls.as_deref(),
        ..input
    };
    let mut image = timings.time(pass::TRACE, || trace_fn(&input));
    if let Some((found, lists)) = &highlights {
        let shape = Shape::new(&settings.aperture).with_effects(&settings.effects);
        let region = (guard, guard, frame.width_px, frame.height_px);
        let seen = timings.time(pass::HIGHLIGHTS, || {
            highlights::scatter(found, lists, &lens, &shape, 1.0, region)
        });
        highlights::add_into(&mut image, &seen);
    }
    let bytes = layers.bytes()
        + culls
            .iter()
            .flatten()
            .flatten()
            .map(WindowMin::bytes)
            .sum::<usize>()
        + mips.iter().flatten().map(LayerMip::bytes).sum::<usize>()
        + highlights.as_ref().map_or(0, |(_, lists)| lists.bytes());
    // The pinhole depth: the nearest layer's surface at each pixel, back from CoC to depth.
    let depth = GrayImage::from_vec(w, h, pinhole_depth(&layers))?.crop(
        guard,
        guard,
        frame.width_px,
        frame.height_px,
    );
    Ok(MethodOutput {
        image,
        depth: Some(depth),
        timings,
        memory_bytes: Some(bytes),
    })
}

/// View depth of the nearest surface of any layer at each pixel (+inf where none).
fn pinhole_depth(layers: &DepthLayers) -> Vec<f32> {
    let (w, h) = (layers.width, layers.height);
    let lens = layers.spacing.lens;
    (0..w * h)
        .map(|i| {
            let c = (0..layers.spacing.layers)
                .map(|l| layers.coc_px[l * w * h + i])
                .fold(f32::INFINITY, f32::min);
            if c.is_finite() {
                // C = f E (1/z_f - 1/z)  =>  z = 1 / (1/z_f - C / (f E)).
                let inv = 1.0 / lens.focus_m - c / (lens.f_px * lens.lens_radius_m);
                if inv > 0.0 {
                    1.0 / inv
                } else {
                    f32::INFINITY
                }
            } else {
                f32::INFINITY
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::builtin;

    #[test]
    fn dropping_the_surfaces_no_ray_reads_changes_no_pixel() {
        // The guard band's trimming keeps whatever a ray or a cone's mipmap read draws on, for
        // either mipmap filter (the tent's reads reach farther): `traps`' railing crosses the
        // frame's border, near enough for the largest band and blur. (Checked to fail with the
        // tent's reach taken as 0.)
        let scene = builtin::load("traps").unwrap();
        let mut camera = scene.defaults.clone().unwrap().camera;
        camera.width_px = 640;
        camera.height_px = 360;
        for mip_filter in [MipFilter::Box, MipFilter::Tent] {
            let settings = MultiviewSettings {
                samples: 16,
                mip_filter,
                ..MultiviewSettings::default()
            };
            let run = |trim| render_with(&scene, &camera, &settings, trace::trace, trim).unwrap();
            let (trimmed, whole) = (run(true), run(false));
            assert!(
                trimmed.image == whole.image,
                "{mip_filter:?}: trimming changed the image"
            );
        }
    }

    #[test]
    fn focus_centred_layers_put_the_focal_plane_in_a_layers_middle() {
        // Nearest CoCs from just past half a spacing to many spacings in front of focus, and
        // spacings from 1 to 7 px: the first layer starts at the nearest CoC, CoC 0 lies at
        // the middle of a layer, the spacing is within [1/2, 3/2] of the one asked (and at
        // most it from 1.5 spacings on), and the layers reach the farthest CoC.
        for spacing in [1.0f32, 2.5, 4.0, 7.0] {
            for i in 0..400 {
                let lo = -spacing * (0.51 + i as f32 * 0.037);
                let hi = spacing * (0.3 + (i % 7) as f32);
                let (delta, n) = focus_centred(spacing, (lo, hi));
                let at = -lo / delta;
                assert!(
                    (at.fract() - 0.5).abs() < 1e-4,
                    "lo {lo} hi {hi} spacing {spacing}: CoC 0 at {at} layers"
                );
                assert!(
                    (0.5 * spacing..=1.5 * spacing).contains(&delta),
                    "lo {lo}: spacing {delta} for {spacing}"
                );
                if -lo >= 1.5 * spacing {
                    assert!(
                        delta <= spacing * (1.0 + 1e-6),
                        "lo {lo}: {delta} > {spacing}"
                    );
                }
                assert!(
                    lo + n as f32 * delta >= hi - 1e-3,
                    "lo {lo} hi {hi}: {n} x {delta}"
                );
                assert!(
                    lo + (n - 1) as f32 * delta < hi,
                    "lo {lo} hi {hi}: a layer too many"
                );
            }
        }
        // The focal plane in the first half of the first layer, or behind every surface: the
        // plain spacing.
        assert_eq!(focus_centred(4.0, (-1.5, 10.0)), (4.0, 3));
        assert_eq!(focus_centred(4.0, (-20.0, -2.0)), (4.0, 5));
    }
}
