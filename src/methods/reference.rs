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

use crate::image::{ColorImage, Rgba};
use crate::lens::{Aperture, Camera, SampleSet, SamplerKind};
use std::sync::Mutex;

use crate::raster::{BinnedView, GBuffer, GBufferTile, PreparedScene, Sink, TileRect, View};
use crate::scene::Scene;
use crate::timing::Timings;
use crate::Result;

use super::MethodOutput;

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
        }
    }
}

/// Accumulates premultiplied colour of many views.
struct Accumulator {
    width: usize,
    sum: Vec<Rgba>,
    /// Finished tiles kept for reuse, so views do not reallocate (and page-fault) tile memory.
    pool: Mutex<Vec<GBufferTile>>,
}

impl Sink for Accumulator {
    type Tile = <GBuffer as Sink>::Tile;

    fn begin_tile(&self, rect: TileRect) -> Self::Tile {
        // The accumulator uses the G-buffer's tiles: same depth test and blending.
        let recycled = self.pool.lock().ok().and_then(|mut p| p.pop());
        match recycled {
            Some(mut tile) => {
                tile.reset(rect);
                tile
            }
            None => GBuffer::tile(rect),
        }
    }

    fn end_tile(&mut self, rect: TileRect, tile: Self::Tile) {
        let w = rect.width();
        let colors = tile.color();
        for (row, y) in (rect.y0..rect.y1).enumerate() {
            let dst = &mut self.sum[y * self.width + rect.x0..][..w];
            for (d, s) in dst.iter_mut().zip(&colors[row * w..(row + 1) * w]) {
                for k in 0..4 {
                    d[k] += s[k];
                }
            }
        }
        if let Ok(mut pool) = self.pool.lock() {
            pool.push(tile);
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
    let method = if settings.use_lens {
        "reference"
    } else {
        "pinhole"
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
    }
    let prepared = timings.time(&format!("{method}/prepare"), || {
        PreparedScene::new(scene, &camera.camera_from_world)
    })?;
    let total = set.samples.len();
    let (w, h) = (lens.width_px, lens.height_px);

    let mut depth = None;
    let image = if total == 1 {
        let view = View::pinhole(lens);
        let binned = timings.time(&format!("{method}/setup"), || {
            BinnedView::new(&prepared, &view)
        });
        let mut g = GBuffer::new(w, h);
        timings.time(&format!("{method}/raster"), || {
            binned.rasterize(&prepared, &mut g)
        });
        progress(1, 1);
        if settings.with_depth {
            depth = Some(g.depth.clone());
        }
        g.color
    } else {
        let mut acc = Accumulator {
            width: w,
            sum: vec![[0.0; 4]; w * h],
            pool: Mutex::new(Vec::new()),
        };
        for (i, s) in set.samples.iter().enumerate() {
            let view = View {
                lens,
                lens_point: s.lens,
                pixel_offset: crate::raster::snap_pixel_offset(s.pixel_offset),
                lod_bias: -0.5 * (total as f32).log2(),
            };
            let binned = timings.time(&format!("{method}/setup"), || {
                BinnedView::new(&prepared, &view)
            });
            timings.time(&format!("{method}/raster"), || {
                binned.rasterize(&prepared, &mut acc)
            });
            progress(i + 1, total);
        }
        if settings.with_depth {
            let view = View::pinhole(lens);
            let binned = BinnedView::new(&prepared, &view);
            let mut g = GBuffer::new(w, h);
            timings.time(&format!("{method}/depth"), || {
                binned.rasterize(&prepared, &mut g)
            });
            depth = Some(g.depth);
        }
        timings.time(&format!("{method}/resolve"), || {
            let inv_n = 1.0 / total as f32;
            let data = acc.sum.iter().map(|s| s.map(|v| v * inv_n)).collect();
            ColorImage::from_vec(w, h, data)
        })?
    };
    Ok(MethodOutput {
        image,
        depth,
        timings,
    })
}
