//! `reference`: ground truth by accumulation over the lens (Haeberli & Akeley 1990, "The
//! accumulation buffer", section on depth of field).
//!
//! For each of N lens samples `v` (from [`SampleSet`], covering the [`Aperture`] evenly) the scene
//! is rasterized through that lens point with the sheared projection that keeps the focal plane
//! fixed ([`View::clip_from_camera`]), at a sub-pixel offset (box filter, as a path tracer), and
//! the views are averaged.
//!
//! Passes, timed as `reference/<pass>`:
//! 1. `prepare`: world to camera space, once per frame.
//! 2. `setup`: per view, project with the view's shear, clip, cull and bin triangles.
//! 3. `raster`: per view, rasterize into G-buffer tiles (nearest opaque surface, transparent
//!    surfaces composited over it) and add the tiles (premultiplied colour) to the accumulation buffer.
//! 4. `resolve`: divide by the accumulated coverage.
//!
//! Views are accumulated one after another in sample order and each view's tiles are added in
//! tile order, so the result is bit-identical whatever the number of threads. With one sample the
//! view is the plain pinhole image at pixel centres, returned exactly.

use crate::gpu::GpuContext;
use crate::image::GrayImage;
use crate::lens::{Aperture, Camera, LensEffects, SampleSet, SamplerKind};
use crate::raster::{
    accumulate_views_clipped, gpu, render_view, PreparedScene, View, ViewPassLabels,
};
use crate::scene::Scene;
use crate::timing::Timings;
use crate::Result;

use super::MethodOutput;

/// `--timings` labels of `reference`.
pub mod pass {
    /// World to camera space, once per frame.
    pub const PREPARE: &str = "reference/prepare";
    /// Per view: projection, clipping, culling.
    pub const SETUP: &str = "reference/setup";
    /// Per view: triangles into tile lists.
    pub const BIN: &str = "reference/bin";
    /// Per view: rasterize and accumulate.
    pub const RASTER: &str = "reference/raster";
    /// Divide by the number of views.
    pub const RESOLVE: &str = "reference/resolve";
    /// The pinhole depth at pixel centres (with `with_depth`).
    pub const DEPTH: &str = "reference/depth";
}

/// `--timings` labels of `pinhole` (the same loop with the lens closed).
pub mod pinhole_pass {
    /// World to camera space, once per frame.
    pub const PREPARE: &str = "pinhole/prepare";
    /// Per view: projection, clipping, culling.
    pub const SETUP: &str = "pinhole/setup";
    /// Per view: triangles into tile lists.
    pub const BIN: &str = "pinhole/bin";
    /// Per view: rasterize and accumulate.
    pub const RASTER: &str = "pinhole/raster";
    /// Divide by the number of samples.
    pub const RESOLVE: &str = "pinhole/resolve";
    /// The depth at pixel centres (with `with_depth` and more than one sample).
    pub const DEPTH: &str = "pinhole/depth";
}

/// Settings of the reference renderer.
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceSettings {
    /// Number of lens samples (views). 256 or more for ground truth.
    pub samples: usize,
    /// How lens and pixel positions are chosen.
    pub sampler: SamplerKind,
    /// Seed of the sampler (same seed, same image).
    pub seed: u64,
    /// Aperture shape.
    pub aperture: Aperture,
    /// When false, the lens is closed (every view through the lens centre): a supersampled
    /// pinhole image. This is the `pinhole` method with `--samples N`.
    pub use_lens: bool,
    /// Also return the pinhole depth at pixel centres.
    pub with_depth: bool,
    /// The real lens's departures from the ideal one (anamorphic aperture, cat's eye); the
    /// ideal lens by default. Exact here: each lens point is squeezed, and each pixel takes
    /// only the lens points that reach it through the barrel.
    pub effects: LensEffects,
}

impl Default for ReferenceSettings {
    fn default() -> Self {
        Self {
            samples: 256,
            sampler: SamplerKind::Halton,
            seed: 0,
            aperture: Aperture::Disc,
            use_lens: true,
            with_depth: false,
            effects: LensEffects::default(),
        }
    }
}

/// Renders `scene` through `camera` by accumulating `settings.samples` views over the lens.
/// `progress(done, total)` is called after each view.
pub fn render(
    scene: &Scene,
    camera: &Camera,
    settings: &ReferenceSettings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<MethodOutput> {
    render_on(scene, camera, settings, None, progress)
}

/// [`render`] on the GPU of `gpu` (`None`: the CPU): the same views, drawn by the GPU's own
/// rasteriser ([`crate::raster::gpu`]) and added up there.
pub fn render_on(
    scene: &Scene,
    camera: &Camera,
    settings: &ReferenceSettings,
    gpu: Option<&GpuContext>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<MethodOutput> {
    if settings.use_lens && settings.effects.is_chromatic() {
        return render_chromatic(scene, camera, settings, gpu, progress);
    }
    let (prepare, labels, depth_label) = if settings.use_lens {
        (
            pass::PREPARE,
            ViewPassLabels {
                setup: pass::SETUP,
                bin: pass::BIN,
                raster: pass::RASTER,
                resolve: pass::RESOLVE,
            },
            pass::DEPTH,
        )
    } else {
        (
            pinhole_pass::PREPARE,
            ViewPassLabels {
                setup: pinhole_pass::SETUP,
                bin: pinhole_pass::BIN,
                raster: pinhole_pass::RASTER,
                resolve: pinhole_pass::RESOLVE,
            },
            pinhole_pass::DEPTH,
        )
    };
    let lens = camera.thin_lens()?;
    let mut timings = Timings::default();
    let mut set = SampleSet::generate(
        &settings.aperture,
        settings.sampler,
        settings.samples,
        settings.seed,
    )?;
    if !settings.use_lens {
        for s in &mut set.samples {
            s.lens = glam::Vec2::ZERO;
        }
    } else if !settings.effects.is_ideal() {
        settings.effects.validate()?;
        for s in &mut set.samples {
            s.lens = settings.effects.squeeze(s.lens);
        }
    }
    let prepared = timings.time(prepare, || {
        PreparedScene::new(scene, &camera.camera_from_world)
    })?;
    // One view at the lens and pixel centres is the pinhole G-buffer itself: its colour and
    // depth come from one rasterization.
    let single = set.samples.len() == 1
        && set.samples[0].lens == glam::Vec2::ZERO
        && set.samples[0].pixel_offset == glam::Vec2::ZERO;
    let (image, depth) = if single {
        let (color, depth) =
            render_one(gpu, &prepared, &View::pinhole(lens), &labels, &mut timings)?;
        progress(1, 1);
        (color, settings.with_depth.then_some(depth))
    } else {
        let clip = settings.use_lens.then_some(&settings.effects);
        let image = match gpu {
            Some(ctx) => gpu::accumulate_views(
                ctx,
                &prepared,
                lens,
                &set.samples,
                clip,
                &labels,
                &mut timings,
                progress,
            ),
            None => accumulate_views_clipped(
                &prepared,
                lens,
                &set.samples,
                clip,
                &labels,
                &mut timings,
                progress,
            ),
        }?;
        // The pinhole depth at pixel centres, as a renderer's Z pass.
        let depth = match settings.with_depth {
            true => {
                let view = View::pinhole(lens);
                let labels = depth_labels(depth_label);
                Some(render_one(gpu, &prepared, &view, &labels, &mut timings)?.1)
            }
            false => None,
        };
        (image, depth)
    };
    Ok(MethodOutput {
        image,
        depth,
        timings,
        memory_bytes: None,
    })
}

/// Chromatic aberration: each channel rendered through its own lens (its focus distance and
/// lens radius, [`LensEffects::channel_lens`]) with the same lens and pixel samples, and taken
/// from that render; alpha and depth are green's.
fn render_chromatic(
    scene: &Scene,
    camera: &Camera,
    settings: &ReferenceSettings,
    gpu: Option<&GpuContext>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<MethodOutput> {
    settings.effects.validate()?;
    let mono = ReferenceSettings {
        effects: settings.effects.without_colour(),
        ..settings.clone()
    };
    super::per_channel(&settings.effects, camera.focus_m, |c, focus_m, scale| {
        let channel_camera = Camera {
            focus_m,
            fstop: camera.fstop / scale,
            ..camera.clone()
        };
        render_on(scene, &channel_camera, &mono, gpu, &mut |done, total| {
            progress(c * total + done, 3 * total)
        })
    })
}

/// One view's G-buffer, colour and depth, on the GPU of `gpu` or on the CPU.
fn render_one(
    gpu: Option<&GpuContext>,
    prepared: &PreparedScene,
    view: &View,
    labels: &ViewPassLabels,
    timings: &mut Timings,
) -> Result<(crate::image::ColorImage, GrayImage)> {
    match gpu {
        Some(ctx) => gpu::render_view(ctx, prepared, view, labels, timings),
        None => render_view(prepared, view, labels, timings).map(|g| (g.color, g.depth)),
    }
}

/// Every pass of the pinhole depth view timed under `label`.
fn depth_labels(label: &'static str) -> ViewPassLabels {
    ViewPassLabels {
        setup: label,
        bin: label,
        raster: label,
        resolve: label,
    }
}
