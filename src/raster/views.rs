//! The multi-view loop: rasterize a prepared scene through many lens points and sub-pixel
//! offsets and average the views (Haeberli & Akeley's accumulation buffer). `reference` (views
//! over the lens), supersampled `pinhole` (views through the lens centre) and the tests of the
//! layered methods use this one implementation.
//!
//! Views are accumulated one after another in sample order and each view's tiles are added in
//! tile order, so the sum is bit-identical whatever the number of threads.

use std::sync::Mutex;

use super::{BinnedView, GBuffer, GBufferTile, PreparedScene, Sink, TileRect, View};
use crate::image::{ColorImage, Rgba};
use crate::lens::{LensSample, ThinLens};
use crate::timing::Timings;
use crate::Result;

/// The `--timings` labels of the passes of [`accumulate_views`], given by the method that runs
/// it (`reference/setup` or `pinhole/setup`, ...).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ViewPassLabels {
    /// Per view: projection with the view's shear, clipping, culling (pass `setup`).
    pub setup: &'static str,
    /// Per view: triangles into the tile lists (pass `bin`).
    pub bin: &'static str,
    /// Per view: rasterize into G-buffer tiles and add them to the sum (pass `raster`).
    pub raster: &'static str,
    /// Once: divide the sum by the number of views (pass `resolve`).
    pub resolve: &'static str,
}

/// Sums the premultiplied colour of many views.
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

    /// Adds the tiles to the sum, a band of tile rows per task.
    fn end_tiles(&mut self, tiles: Vec<(TileRect, Self::Tile)>) {
        let width = self.width;
        super::for_each_tile_band(&mut self.sum, width, &tiles, |band, tiles| {
            for (rect, tile) in tiles {
                let w = rect.width();
                let colors = tile.color();
                for row in 0..rect.height() {
                    // Rows of the band are relative to its first tile's top.
                    let dst = &mut band[(rect.y0 % super::TILE + row) * width + rect.x0..][..w];
                    for (d, s) in dst.iter_mut().zip(&colors[row * w..(row + 1) * w]) {
                        for k in 0..4 {
                            d[k] += s[k];
                        }
                    }
                }
            }
        });
        if let Ok(mut pool) = self.pool.lock() {
            pool.extend(tiles.into_iter().map(|(_, tile)| tile));
        }
    }
}

/// The view of one lens sample: its lens point, its sub-pixel offset snapped onto the raster
/// grid, and the texture LOD bias of a pixel that is the mean of `views` views.
pub fn sample_view(lens: ThinLens, sample: &LensSample, views: usize) -> View {
    View {
        lens,
        lens_point: sample.lens,
        pixel_offset: super::snap_pixel_offset(sample.pixel_offset),
        lod_bias: -0.5 * (views.max(1) as f32).log2(),
    }
}

/// Renders one view of `prepared` into a G-buffer, timing its passes under `labels`.
pub fn render_view(
    prepared: &PreparedScene,
    view: &View,
    labels: &ViewPassLabels,
    timings: &mut Timings,
) -> GBuffer {
    let binned = BinnedView::new_timed(prepared, view, labels, timings);
    let mut g = GBuffer::new(view.lens.width_px, view.lens.height_px);
    timings.time(labels.raster, || binned.rasterize(prepared, &mut g));
    g
}

/// The mean of the views of `samples` (premultiplied linear RGBA). `progress(done, total)` is
/// called after each view. One sample at the lens centre and the pixel centre gives the plain
/// pinhole image exactly.
pub fn accumulate_views(
    prepared: &PreparedScene,
    lens: ThinLens,
    samples: &[LensSample],
    labels: &ViewPassLabels,
    timings: &mut Timings,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ColorImage> {
    let (w, h) = (lens.width_px, lens.height_px);
    let total = samples.len();
    let mut acc = Accumulator {
        width: w,
        sum: vec![[0.0; 4]; w * h],
        pool: Mutex::new(Vec::new()),
    };
    for (i, s) in samples.iter().enumerate() {
        let view = sample_view(lens, s, total);
        let binned = BinnedView::new_timed(prepared, &view, labels, timings);
        timings.time(labels.raster, || binned.rasterize(prepared, &mut acc));
        progress(i + 1, total);
    }
    timings.time(labels.resolve, || {
        let inv_n = 1.0 / total.max(1) as f32;
        let data = acc.sum.iter().map(|s| s.map(|v| v * inv_n)).collect();
        ColorImage::from_vec(w, h, data)
    })
}
