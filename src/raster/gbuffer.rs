//! The `GBuffer` sink: nearest opaque surface per pixel, with alpha-blended surfaces in front
//! of it composited back to front. The depth is a renderer's Z pass with an alpha threshold (see
//! [`GBuffer::depth`]): a post-process method blurs a mostly opaque blended surface by its own
//! depth, sees through faint ones, however many are stacked, to what is behind them, and keeps
//! the depth of a glass standing in front of nothing at all.

use rayon::prelude::*;

use super::{Fragment, Sink, TileRect, TileSink};
use crate::image::{ColorImage, GrayImage, Rgba};

/// The opacity from which a blended surface gives the depth pass its depth ([`GBuffer::depth`]):
/// Blender Cycles' default alpha threshold of its Z pass.
pub const Z_ALPHA_THRESHOLD: f32 = 0.5;

/// Colour (linear, premultiplied alpha; transparent black where nothing was drawn) and view
/// depth in metres of the surface that contributes most to the pixel (`f32::INFINITY` where
/// there is none).
#[derive(Clone, Debug, PartialEq)]
pub struct GBuffer {
    /// Linear premultiplied RGBA: opaque surface with transparent surfaces in front composited
    /// over it.
    pub color: ColorImage,
    /// View-axis depth in metres of the nearest surface at least [`Z_ALPHA_THRESHOLD`]
    /// opaque by itself (an opaque surface always is), as a renderer's Z pass with Blender
    /// Cycles' default alpha threshold: three stacked panes of alpha 0.3-0.46 before a chart
    /// give the chart's depth, which a compositor's `blur` of that renderer's frame and Z uses.
    /// Where no surface is that opaque (faint ones before nothing), the surface with the
    /// largest weight in the composite: its alpha times the transmittance `prod (1 - alpha)`
    /// of the blended surfaces in front of it, ties to the nearer (the empty background weighs
    /// nothing), so that a glass standing in front of nothing keeps its depth.
    pub depth: GrayImage,
}

impl GBuffer {
    /// A fresh tile for `rect`, as [`Sink::begin_tile`] gives; other sinks that need the
    /// G-buffer's depth test and blending reuse it.
    pub fn tile(rect: TileRect) -> GBufferTile {
        let n = rect.width() * rect.height();
        GBufferTile {
            rect,
            color: vec![[0.0; 4]; n],
            depth: vec![f32::INFINITY; n],
            blended: Vec::new(),
        }
    }

    /// An empty buffer: transparent black at infinite depth.
    pub fn new(width: usize, height: usize) -> Self {
        // Filled in parallel: a frame is megabytes, and rasterizing overwrites it anyway.
        let n = width * height;
        let color = super::filled_in_parallel([0.0; 4], n);
        let depth = super::filled_in_parallel(f32::INFINITY, n);
        Self {
            color: ColorImage::from_vec(width, height, color).expect("size matches"),
            depth: GrayImage::from_vec(width, height, depth).expect("size matches"),
        }
    }
}

/// Per-tile state of [`GBuffer`].
pub struct GBufferTile {
    rect: TileRect,
    color: Vec<Rgba>,
    depth: Vec<f32>,
    /// Transparent fragments: (pixel index in tile, depth, colour).
    blended: Vec<(u32, f32, Rgba)>,
}

impl GBufferTile {
    /// Clears the tile for reuse at `rect`, keeping its allocations.
    pub fn reset(&mut self, rect: TileRect) {
        let n = rect.width() * rect.height();
        self.rect = rect;
        self.color.clear();
        self.color.resize(n, [0.0; 4]);
        self.depth.clear();
        self.depth.resize(n, f32::INFINITY);
        self.blended.clear();
    }

    #[inline]
    fn index(&self, x: u32, y: u32) -> usize {
        (y as usize - self.rect.y0) * self.rect.width() + (x as usize - self.rect.x0)
    }

    /// Colour of the tile, row-major.
    pub fn color(&self) -> &[Rgba] {
        &self.color
    }

    /// Depth of the tile, row-major.
    pub fn depth(&self) -> &[f32] {
        &self.depth
    }
}

impl TileSink for GBufferTile {
    #[inline]
    fn occluded(&self, x: u32, y: u32, depth_m: f32) -> bool {
        depth_m >= self.depth[self.index(x, y)]
    }

    #[inline]
    fn occlusion_row(&self, y: u32, xa: u32, xb: u32) -> Option<&[f32]> {
        self.depth.get(self.index(xa, y)..self.index(xb, y))
    }

    #[inline]
    fn fragment(&mut self, f: &Fragment) {
        let i = self.index(f.x, f.y);
        if f.blend {
            self.blended.push((i as u32, f.depth_m, f.color));
        } else if f.depth_m < self.depth[i] {
            self.depth[i] = f.depth_m;
            self.color[i] = f.color;
        }
    }

    fn finish(&mut self) {
        if self.blended.is_empty() {
            return;
        }
        let depth = &self.depth;
        self.blended.retain(|&(i, z, _)| z < depth[i as usize]);
        // Per pixel, far to near; stable, so equal depths keep scene order.
        self.blended
            .sort_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)));
        // Weight, relative to the blended surfaces not yet composited in front, of the surface
        // whose depth the pixel currently has (1 for an opaque surface, 0 for the background),
        // and whether that surface passes the alpha threshold.
        let mut pixel = u32::MAX;
        let mut best_weight = 0.0f32;
        let mut passed = false;
        for &(i, z, src) in &self.blended {
            if i != pixel {
                pixel = i;
                passed = self.depth[i as usize].is_finite();
                best_weight = if passed { 1.0 } else { 0.0 };
            }
            // `over` with premultiplied colour: the fragment's colour is straight.
            let dst = &mut self.color[i as usize];
            let a = src[3];
            for k in 0..3 {
                dst[k] = src[k] * a + dst[k] * (1.0 - a);
            }
            dst[3] = a + dst[3] * (1.0 - a);
            // Far to near: everything behind is now seen through this surface.
            best_weight *= 1.0 - a;
            if a >= Z_ALPHA_THRESHOLD || (!passed && a > 0.0 && a >= best_weight) {
                passed |= a >= Z_ALPHA_THRESHOLD;
                best_weight = a;
                self.depth[i as usize] = z;
            }
        }
        self.blended.clear();
    }
}

impl Sink for GBuffer {
    type Tile = GBufferTile;

    fn begin_tile(&self, rect: TileRect) -> GBufferTile {
        GBuffer::tile(rect)
    }

    fn end_tile(&mut self, rect: TileRect, tile: GBufferTile) {
        let w = rect.width();
        for (row, y) in (rect.y0..rect.y1).enumerate() {
            let dst = y * self.color.width() + rect.x0;
            self.color.pixels_mut()[dst..dst + w]
                .copy_from_slice(&tile.color[row * w..(row + 1) * w]);
            self.depth.pixels_mut()[dst..dst + w]
                .copy_from_slice(&tile.depth[row * w..(row + 1) * w]);
        }
    }

    /// Copies the tiles into the image, a band of tile rows per task.
    fn end_tiles(&mut self, tiles: Vec<(TileRect, GBufferTile)>) {
        let width = self.color.width();
        let mut bands: Vec<(&mut [Rgba], &mut [f32])> = self
            .color
            .pixels_mut()
            .chunks_mut(super::TILE * width)
            .zip(self.depth.pixels_mut().chunks_mut(super::TILE * width))
            .collect();
        let tiles_x = width.div_ceil(super::TILE).max(1);
        bands
            .par_iter_mut()
            .zip(tiles.par_chunks(tiles_x))
            .for_each(|((color, depth), tiles)| {
                for (rect, tile) in tiles {
                    let w = rect.width();
                    for row in 0..rect.height() {
                        // Rows of the band are relative to its first tile's top.
                        let dst = (rect.y0 % super::TILE + row) * width + rect.x0;
                        let src = row * w..(row + 1) * w;
                        color[dst..dst + w].copy_from_slice(&tile.color[src.clone()]);
                        depth[dst..dst + w].copy_from_slice(&tile.depth[src]);
                    }
                }
            });
    }
}
