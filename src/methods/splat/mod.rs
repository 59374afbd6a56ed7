//! `splat`: tiled depth-of-field splatting (poster "Fast Depth of Field Rendering", Selgrad et
//! al.'s group; tiled particle accumulation after Thomas 2014). A scatter: every fragment's
//! light goes where its CoC sends it, in the aperture's shape, and each pixel blends what
//! reaches it in true depth order.
//!
//! # Passes, in order (each timed as `splat/<pass>`)
//! 0. `coc` (single layer, [`crate::methods::coc_map::coc`]) or `collect` (multi-layer, the
//!    [`crate::raster::FragmentLists`] of `multilayer`): the input fragments with their CoC.
//! 1. `build` ([`build`]): the poster's compact 16-byte fragments (16-bit colour and position,
//!    32-bit CoC), merged 2x2 or 4x4 where the blur hides it (`merge`), each entered into the
//!    list of every 16x16 tile its shape overlaps: count per tile, prefix sum, fill, in
//!    parallel with no locks.
//! 2. `sort` ([`sort`]): each tile's list by depth, a radix sort on the CoC key, tiles in
//!    parallel.
//! 3. `blend` ([`blend`]): each pixel walks its tile's list front to back, summing the
//!    fragments of one surface (CoCs within `group_px`) and blending the surfaces with the over
//!    operator.
//!
//! # Multi-layer input
//! The poster's future work: with `layers` > 1 the fragments come from the per-pixel fragment
//! lists (N per pixel) instead of the pinhole frame, so the surfaces hidden in the pinhole view
//! (the text behind `railing`'s bars) reach the pixels where the near blur reveals them.
//!
//! The lists are rasterized with coverage masks and a guard band around the frame
//! ([`crate::raster::LayeredInput`]; `--no-coverage`, `--no-guard-band`), so in-focus edges are
//! anti-aliased and fragments just outside the frame splat into it. Fragments brighter than
//! white are scattered on their own with each lens ray's visibility past the nearer fragments
//! ([`crate::methods::highlights`], `--highlight-rays`): the blend's over operator dims a light
//! behind a near bar evenly, where through the lens the bar's shadow crosses its bokeh.
//!
//! # Where we differ from the poster, and why
//! - Merging is only done where every fragment of the block has a CoC radius of at least the
//!   block size and the same surface (CoCs within `group_px`): the poster merges "spatially
//!   close fragments" without saying which; merging in-focus detail would blur it.
//! - Surfaces are summed before blending (the measured 6.5 dB); the poster blends each
//!   fragment with the over operator.

pub mod blend;
pub mod build;
pub mod sort;

use rayon::prelude::*;

use crate::image::{ColorImage, GrayImage};
use crate::lens::{Aperture, Camera, LensEffects, ThinLens};
use crate::raster::{
    render_fragment_lists_with, FragmentLists, LayeredInput, PreparedScene, Reach, View,
};
use crate::scene::Scene;
use crate::timing::Timings;
use crate::{Error, Result};

use super::coc_map;
use super::highlights;
use super::MethodOutput;

/// The lens effects ([`crate::lens::EFFECT_NAMES`]) this method renders; it refuses the others.
pub const EFFECTS: &[&str] = &["anamorphic", "chromatic"];

/// `--timings` labels of `splat`.
pub mod pass {
    /// The CoC map of a single-layer frame.
    pub const COC: &str = "splat/coc";
    /// World to camera space (multi-layer input).
    pub const PREPARE: &str = "splat/prepare";
    /// Fragment lists of the pinhole view (multi-layer input).
    pub const COLLECT: &str = "splat/collect";
    /// Compact fragments, merging, distribution into tile lists.
    pub const BUILD: &str = "splat/build";
    /// Per-tile depth sort.
    pub const SORT: &str = "splat/sort";
    /// Per-pixel front-to-back blending.
    pub const BLEND: &str = "splat/blend";
    /// Bright fragments scattered with their rays' visibility (`highlights`).
    pub const HIGHLIGHTS: &str = "splat/highlights";
}

/// Settings of `splat`.
#[derive(Clone, Debug, PartialEq)]
pub struct SplatSettings {
    /// Aperture shape (the same value as `reference`'s, so the bokeh match). Default disc.
    pub aperture: Aperture,
    /// Merge `merge x merge` fragments before distribution: 1 (none), 2 or 4. Default 1.
    pub merge: usize,
    /// Fragments per pixel: 1 splats the pinhole frame; N > 1 (up to 16) splats the N nearest
    /// fragments of every pixel from the scene's fragment lists. Default 1.
    pub layers: usize,
    /// Fragments whose CoCs differ by at most this many pixels are one surface (summed, not
    /// blended over each other). Default 2.
    pub group_px: f32,
    /// Largest CoC radius in pixels; larger blurs are clamped to it. Default 64.
    pub max_coc_px: f32,
    /// Coverage masks and guard band of the fragment lists (`layers` > 1; default both on;
    /// off: the input sampled at pixel centres over the frame).
    pub input: LayeredInput,
    /// The real lens's departures from the ideal one: the anamorphic squeeze stretches every
    /// fragment's footprint (an ellipse, a squeezed polygon), as `reference`'s lens samples;
    /// with chromatic aberration each channel is splatted with its own channel's CoCs (a run
    /// per channel, as `reference` renders a pass per channel). The cat's eye is refused.
    /// Default: the ideal lens.
    pub effects: LensEffects,
    /// With `layers` > 1: fragments brighter than this (linear luminance over coverage) are
    /// scattered on their own with each lens ray's visibility past the nearer surfaces
    /// ([`crate::methods::highlights`]); `None`: blended as every fragment (the poster's).
    /// Default 1 (brighter than white; measured in the README).
    pub highlights: Option<f32>,
}

impl Default for SplatSettings {
    fn default() -> Self {
        Self {
            aperture: Aperture::Disc,
            merge: 1,
            layers: 1,
            group_px: 2.0,
            max_coc_px: 64.0,
            input: LayeredInput::default(),
            effects: LensEffects::default(),
            highlights: Some(1.0),
        }
    }
}

impl SplatSettings {
    /// Checks every field's range.
    pub fn validate(&self) -> Result<()> {
        if ![1, 2, 4].contains(&self.merge) {
            return Err(Error::invalid(
                "merge",
                format!("{}: expected 1, 2 or 4", self.merge),
            ));
        }
        if !(1..=crate::raster::MAX_FRAGMENTS_PER_PIXEL).contains(&self.layers) {
            return Err(Error::invalid(
                "layers",
                format!(
                    "{}: expected 1 to {} fragments per pixel",
                    self.layers,
                    crate::raster::MAX_FRAGMENTS_PER_PIXEL
                ),
            ));
        }
        if !(self.group_px.is_finite() && self.group_px >= 0.0) {
            return Err(Error::invalid(
                "group",
                format!(
                    "{} px: expected a CoC difference of 0 px or more",
                    self.group_px
                ),
            ));
        }
        coc_map::check_max_coc(self.max_coc_px)?;
        crate::methods::highlights::check_threshold(self.highlights)?;
        self.aperture.validate()
    }
}

/// Figures of one run, for reports and benchmarks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplatStats {
    /// Fragments distributed (after merging).
    pub fragments: usize,
    /// Mean number of entries in a tile's list.
    pub mean_list_length: f64,
}

/// Bytes a pixel of the splatted frame takes in pass `blend`: each tile's pixels, then the
/// image they are copied into.
const BLEND_BYTES_PER_PIXEL: u64 = 2 * std::mem::size_of::<crate::image::Rgba>() as u64;

/// Bytes one input fragment can take in pass `build`: its splat fragment twice (the rows'
/// and the joined copy) and its norm.
const FRAGMENT_BYTES: u64 = 2 * std::mem::size_of::<build::SplatFragment>() as u64 + 4;

/// Bytes a pixel of a single-layer run holds besides what [`splat`] counts: the colour image,
/// the depth and the CoC map.
const FRAME_BYTES_PER_PIXEL: u64 = 16 + 4 + 4;

/// What [`splat`]'s budget checks say to lower.
const LOWER: &str = "--max-coc, raise --merge, or lower the resolution";

/// Passes `build`, `sort` and `blend` on per-pixel layers `(premultiplied colour, CoC)`.
///
/// `held` is what the run holds already (the caller's frame and, with several layers, its
/// fragment lists; `layers` are counted here). Everything the passes allocate is counted
/// before it is: the fragments and norms from the number of layers (the fragments twice, while
/// the rows are joined), then the tile lists, the offsets and runs that lay them out, the
/// sort's scratch (one list per worker thread) and the blended image from the per-tile counts.
/// A run beyond the memory budget ([`crate::budget`]) is refused at the first of these checks,
/// before anything of that step is allocated.
fn splat(
    layers: &build::PixelLayers,
    (width, height): (usize, usize),
    region: (usize, usize, usize, usize),
    settings: &SplatSettings,
    held: u64,
    timings: &mut Timings,
    blend_fn: BlendFn,
) -> Result<(ColorImage, SplatStats, usize)> {
    if width > build::MAX_SIDE_PX || height > build::MAX_SIDE_PX {
        return Err(Error::invalid(
            "image size",
            format!(
                "{width}x{height}: splat addresses at most {} pixels a side",
                build::MAX_SIDE_PX
            ),
        ));
    }
    let what = |entries: Option<u64>| {
        let lists = entries.map_or(String::new(), |e| format!(", {e} tile-list entries"));
        format!(
            "splat at {width}x{height} ({} fragments{lists})",
            layers.len()
        )
    };
    let held = held + layers.bytes();
    crate::budget::check(
        held + layers.len() as u64 * FRAGMENT_BYTES,
        &what(None),
        LOWER,
    )?;
    let shape = blend::Shape::new(&settings.aperture).with_effects(&settings.effects);
    // Only the tiles of the region are blended (the guard band around it is a source).
    let window = build::TileWindow::of(width, height, region);
    let (fragments, norms, lists) = timings.time(pass::BUILD, || -> Result<_> {
        let fragments = build::fragments(layers, width, height, settings.merge, settings.group_px);
        let norms: Vec<f32> = fragments
            .par_iter()
            .map(|f| shape.norm(f.centre(), f.coc_px, f.soft_px(settings.merge)))
            .collect();
        let held = held
            + (fragments.capacity() * std::mem::size_of::<build::SplatFragment>()
                + norms.capacity() * 4) as u64;
        let counts = build::count(
            &fragments,
            settings.merge,
            shape.stretch(),
            width,
            height,
            &window,
        );
        // The lists are counted: refuse before allocating them if the run would exceed the
        // budget. Past the fill, the counts are gone and the sort's scratch or the blend's
        // image comes; the larger of the two is counted.
        let scratch = counts.longest()
            * build::ENTRY_BYTES
            * rayon::current_num_threads().min(counts.tiles()) as u64;
        let blended = (width * height) as u64 * BLEND_BYTES_PER_PIXEL;
        let lists = counts.fill_bytes();
        crate::budget::check(
            held + lists + counts.bytes().max(scratch).max(blended),
            &what(Some(counts.entries())),
            LOWER,
        )?;
        let lists = build::fill(&fragments, counts, settings.merge, shape.stretch(), &window);
        Ok((fragments, norms, lists))
    })?;
    let mut lists = lists;
    timings.time(pass::SORT, || {
        let tiles = lists.tiles_x * lists.tiles_y;
        let mut slices: Vec<&mut [(u32, u32)]> = Vec::with_capacity(tiles);
        let mut rest: &mut [(u32, u32)] = &mut lists.entries;
        for t in 0..tiles {
            let (head, tail) = rest.split_at_mut(lists.offsets[t + 1] - lists.offsets[t]);
            slices.push(head);
            rest = tail;
        }
        slices
            .into_par_iter()
            .for_each_init(Vec::new, |scratch, slice| sort::radix_sort(slice, scratch));
    });
    let image = timings.time(pass::BLEND, || {
        let input = blend::BlendInput {
            fragments: &fragments,
            norms: &norms,
            shape: &shape,
            group_px: settings.group_px,
            merge: settings.merge,
        };
        blend_fn(&input, &lists, width, height)
    });
    let stats = SplatStats {
        fragments: fragments.len(),
        mean_list_length: lists.mean_length(),
    };
    let bytes = fragments.len() * std::mem::size_of::<build::SplatFragment>()
        + norms.len() * 4
        + lists.entries.len() * 8
        + lists.offsets.len() * 8;
    Ok((image, stats, bytes))
}

/// Single layer: splats a pinhole colour image with its view-axis depth (metres).
pub fn render(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &SplatSettings,
) -> Result<MethodOutput> {
    render_detailed(color, depth, lens, settings).map(|(o, _)| o)
}

/// [`render`] with the blend pass built for the portable baseline only
/// ([`blend::blend_baseline`]): the twin the run-time dispatched build is tested against.
pub fn render_baseline(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &SplatSettings,
) -> Result<MethodOutput> {
    render_detailed_with(color, depth, lens, settings, blend::blend_baseline).map(|(o, _)| o)
}

/// The blend pass's signature (see [`blend::blend`]).
type BlendFn = fn(&blend::BlendInput, &build::TileLists, usize, usize) -> ColorImage;

/// [`render`], also returning the run's figures.
pub fn render_detailed(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &SplatSettings,
) -> Result<(MethodOutput, SplatStats)> {
    render_detailed_with(color, depth, lens, settings, blend::blend)
}

fn render_detailed_with(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &SplatSettings,
    blend_fn: BlendFn,
) -> Result<(MethodOutput, SplatStats)> {
    settings.validate()?;
    settings.effects.check_supported("splat", EFFECTS)?;
    coc_map::check_frame(color, depth, lens)?;
    if settings.effects.is_chromatic() {
        return per_channel(settings, lens.focus_m, |mono, focus_m, scale| {
            let channel = ThinLens {
                focus_m,
                lens_radius_m: lens.lens_radius_m * scale,
                ..*lens
            };
            render_detailed_with(color, depth, &channel, mono, blend_fn)
        });
    }
    let mut timings = Timings::default();
    let coc_px = timings.time(pass::COC, || coc_map::coc(depth, lens, settings.max_coc_px))?;
    let layers = build::from_frame(color, &coc_px);
    let held =
        super::registry::FIXED_PEAK_BYTES + color.pixels().len() as u64 * FRAME_BYTES_PER_PIXEL;
    let (image, stats, bytes) = splat(
        &layers,
        (color.width(), color.height()),
        (0, 0, color.width(), color.height()),
        settings,
        held,
        &mut timings,
        blend_fn,
    )?;
    Ok((
        MethodOutput {
            image,
            depth: None,
            timings,
            memory_bytes: Some(bytes),
        },
        stats,
    ))
}

/// Multi-layer: splats the `settings.layers` nearest fragments of every pixel of `scene`'s
/// pinhole view.
pub fn render_scene(
    scene: &Scene,
    camera: &Camera,
    settings: &SplatSettings,
) -> Result<(MethodOutput, SplatStats)> {
    settings.validate()?;
    settings.effects.check_supported("splat", EFFECTS)?;
    if settings.effects.is_chromatic() {
        return per_channel(settings, camera.focus_m, |mono, focus_m, scale| {
            let channel = Camera {
                focus_m,
                fstop: camera.fstop / scale,
                ..camera.clone()
            };
            render_scene(scene, &channel, mono)
        });
    }
    let frame = camera.thin_lens()?;
    let check = |lens: &ThinLens| {
        let px = (lens.width_px * lens.height_px) as u64;
        crate::budget::check(
            px * settings.layers as u64 * (12 + 16 + 4) + px * 32,
            &format!(
                "splat at {}x{} with {} layers",
                frame.width_px, frame.height_px, settings.layers
            ),
            "--layers or the resolution",
        )
    };
    check(&frame)?;
    let mut timings = Timings::default();
    let prepared = timings.time(pass::PREPARE, || {
        PreparedScene::new(scene, &camera.camera_from_world)
    })?;
    // Fragments of the guard band around the frame splat into it too (cut back at the end).
    // The band is as wide as the largest CoC; a squeezed aperture reaches `stretch` times
    // farther along its long axis.
    let stretch = blend::Shape::new(&settings.aperture)
        .with_effects(&settings.effects)
        .stretch();
    let guard = (settings.input.guard_band_px(&prepared, &frame) as f32 * stretch).ceil() as usize;
    let lens = frame.with_guard_band(guard);
    check(&lens)?;
    let lists = timings.time(pass::COLLECT, || collect(&prepared, lens, guard, settings))?;
    from_lists(lists, lens, guard, settings, timings)
}

/// Splats fragment lists that do not come from a scene (a frame decomposed into layers,
/// [`crate::methods::fill`]): `lists` cover exactly the frame of `lens`, at its resolution,
/// and every fragment of a pixel is splatted (the lists hold what `layers` would keep).
/// Passes `highlights`, `build`, `sort` and `blend`, as [`render_scene`] after its `collect`.
pub fn render_lists(
    lists: FragmentLists,
    lens: &ThinLens,
    settings: &SplatSettings,
) -> Result<(MethodOutput, SplatStats)> {
    settings.validate()?;
    settings.effects.check_supported("splat", EFFECTS)?;
    if settings.effects.is_chromatic() {
        return Err(Error::invalid(
            "chromatic aberration",
            "each channel needs its own CoCs: splat renders it from a scene or a frame, not \
             from given fragment lists",
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
    // The run's whole memory is checked by the splat pass itself, before it allocates.
    from_lists(lists, *lens, 0, settings, Timings::default())
}

/// Passes `highlights`, `build`, `sort` and `blend` of `lists` covering `lens`'s frame and its
/// guard band of `guard` pixels.
fn from_lists(
    mut lists: FragmentLists,
    lens: ThinLens,
    guard: usize,
    settings: &SplatSettings,
    mut timings: Timings,
) -> Result<(MethodOutput, SplatStats)> {
    let (w, h) = (lens.width_px - 2 * guard, lens.height_px - 2 * guard);
    let highlights = settings.highlights.map(|threshold| {
        timings.time(pass::HIGHLIGHTS, || {
            highlights::take(&mut lists, &lens, 1.0, threshold, settings.max_coc_px)
        })
    });
    let held = super::registry::FIXED_PEAK_BYTES + lists.bytes() as u64;
    let (mut image, stats, bytes) = splat_lists(&lists, lens, guard, settings, held, &mut timings)?;
    if let Some(highlights) = highlights {
        let shape = blend::Shape::new(&settings.aperture).with_effects(&settings.effects);
        let seen = timings.time(pass::HIGHLIGHTS, || {
            highlights::scatter(
                &highlights,
                &lists,
                &lens,
                &shape,
                1.0,
                (guard, guard, w, h),
            )
        });
        highlights::add_into(&mut image, &seen);
    }
    let depth = GrayImage::from_vec(lens.width_px, lens.height_px, lists.nearest_depth())?
        .crop(guard, guard, w, h);
    Ok((
        MethodOutput {
            image,
            depth: Some(depth),
            timings,
            memory_bytes: Some(bytes + lists.bytes()),
        },
        stats,
    ))
}

/// The frame within `lens`'s guard band of `guard` pixels, splatted from `lists` (their CoCs
/// clamped to the settings' limit): the image, the statistics and the bytes the splat held.
/// `held` is what the run holds besides (see [`splat`]).
fn splat_lists(
    lists: &FragmentLists,
    lens: ThinLens,
    guard: usize,
    settings: &SplatSettings,
    held: u64,
    timings: &mut Timings,
) -> Result<(ColorImage, SplatStats, usize)> {
    let max = settings.max_coc_px;
    let mut layers = build::from_lists(lists, &lens, settings.group_px);
    for f in layers.items_mut() {
        f.1 = f.1.clamp(-max, max);
    }
    let (w, h) = (lens.width_px - 2 * guard, lens.height_px - 2 * guard);
    let (image, stats, bytes) = splat(
        &layers,
        (lens.width_px, lens.height_px),
        (guard, guard, w, h),
        settings,
        held,
        timings,
        blend::blend,
    )?;
    Ok((image.crop(guard, guard, w, h), stats, bytes))
}

/// Pass `collect`: the fragment lists of the pinhole view of `lens`, whose `guard` pixels on
/// each side are a guard band around the frame; there only the fragments that can enter the
/// list of a tile holding frame pixels are kept ([`Reach`], with the distance to those tiles
/// measured as `distribute` tests a fragment's bounding square).
///
/// A fragment enters a list when its square of half-side `stretch max(|C|, 1/2) + soft_px`
/// ([`build::reach_px`]) overlaps the tile, and the lists keep every fragment within `stretch
/// |C| + stretch group_px + 2` pixels of those tiles: the tiles' lists, and so the image, are
/// the same as with every fragment of the band (tested). Not with merging (`merge` > 1): a block
/// merges only where all its pixels hold as many surfaces, so a far fragment dropped beside a
/// near one would change how the near one is drawn.
fn collect(
    prepared: &PreparedScene,
    lens: ThinLens,
    guard: usize,
    settings: &SplatSettings,
) -> Result<FragmentLists> {
    let stretch = blend::Shape::new(&settings.aperture)
        .with_effects(&settings.effects)
        .stretch();
    let reach = (guard > 0 && settings.merge == 1).then(|| {
        let (w, h) = (lens.width_px, lens.height_px);
        let window = build::TileWindow::of(w, h, (guard, guard, w - 2 * guard, h - 2 * guard));
        let (x0, y0) = (window.x.0 * build::TILE_PX, window.y.0 * build::TILE_PX);
        let x1 = ((window.x.1 + 1) * build::TILE_PX).min(w);
        let y1 = ((window.y.1 + 1) * build::TILE_PX).min(h);
        Reach {
            frame: (x0, y0, x1 - x0, y1 - y0),
            lens,
            factor: stretch,
            slack_px: stretch * settings.group_px + 2.0,
            square: true,
        }
    });
    render_fragment_lists_with(
        prepared,
        &View::pinhole(lens),
        settings.layers,
        settings.input,
        reach,
        settings.highlights,
    )
}

/// Chromatic aberration: `run(settings without colour, focus_m, radius_scale)` once per
/// channel ([`super::per_channel`]), with green's figures.
fn per_channel(
    settings: &SplatSettings,
    focus_m: f32,
    mut run: impl FnMut(&SplatSettings, f32, f32) -> Result<(MethodOutput, SplatStats)>,
) -> Result<(MethodOutput, SplatStats)> {
    let mono = SplatSettings {
        effects: settings.effects.without_colour(),
        ..settings.clone()
    };
    let mut stats = SplatStats {
        fragments: 0,
        mean_list_length: 0.0,
    };
    let out = super::per_channel(&settings.effects, focus_m, |c, focus_m, scale| {
        let (out, s) = run(&mono, focus_m, scale)?;
        if c == 1 {
            stats = s;
        }
        Ok(out)
    })?;
    Ok((out, stats))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The guard band's fragments that [`Reach`] drops change nothing in the frame: the image
    /// of `traps` (a railing crossing the borders at a CoC of tens of pixels, lights far
    /// behind), `grass` and `railing` is the same bit for bit with and without them, while some
    /// are dropped.
    #[test]
    fn dropping_the_guard_fragments_that_cannot_reach_the_frame_changes_nothing() {
        for name in ["traps", "grass", "railing"] {
            let scene = crate::scene::builtin::load(name).unwrap();
            let mut camera = scene.defaults.clone().unwrap().camera;
            camera.width_px = 320;
            camera.height_px = 180;
            let settings = SplatSettings {
                aperture: scene.defaults.clone().unwrap().aperture,
                layers: 4,
                ..SplatSettings::default()
            };
            let frame = camera.thin_lens().unwrap();
            let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
            let guard = settings.input.guard_band_px(&prepared, &frame);
            assert!(guard > 0, "{name}");
            let lens = frame.with_guard_band(guard);
            let image = |lists: &FragmentLists| {
                let mut timings = Timings::default();
                splat_lists(lists, lens, guard, &settings, 0, &mut timings)
                    .unwrap()
                    .0
            };
            let trimmed = collect(&prepared, lens, guard, &settings).unwrap();
            let full = crate::raster::render_fragment_lists(
                &prepared,
                &View::pinhole(lens),
                settings.layers,
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
