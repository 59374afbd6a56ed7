//! One triangle rasterizer for every method, emitting fragments into sinks.
//!
//! Passes, in order, for each view:
//! 1. `setup` (`setup.rs`): project camera-space triangles with the view's (possibly sheared)
//!    projection, cull back faces of single-sided materials, clip in homogeneous space against
//!    the near and far planes (and a guard band), snap to 1/256-pixel fixed point, and build
//!    edge functions and perspective-correct attribute planes.
//! 2. `bin`: put each triangle in the list of every 64x64 tile its bounding box touches.
//! 3. `raster`: tiles in parallel (rayon); within a tile opaque and alpha-mask triangles nearest
//!    first, then blended ones in scene order (see `bin`), so the output does not depend on the
//!    thread count. Coverage uses the top-left fill rule at pixel
//!    centres, or for sinks that keep several fragments per pixel at 16 samples per pixel,
//!    each fragment carrying its coverage mask ([`BinnedView::with_coverage`]); the sink may reject a fragment by depth before it is shaded (early depth test);
//!    shading is unlit (base colour + emission, textures filtered with mipmaps) and alpha-mask
//!    materials are tested against their cutoff.
//! 4. The sink finishes each tile in parallel (e.g. sorts and composites transparent
//!    fragments), then gathers the tiles in order.
//!
//! A view is the pinhole projection through the lens centre, optionally sheared for a point on
//! the lens with the focal plane held fixed (DESIGN.md):
//! `x_ndc = (X_xy - V) / z + V / z_f` with `V = E * (v_x, -v_y, 0)`, and shifted by a sub-pixel
//! offset for anti-aliasing. It stays a projective map with `w = z`, so clipping and
//! perspective-correct interpolation work unchanged.
//!
//! Sinks: [`GBuffer`] (nearest opaque surface with transparent surfaces composited over it) and
//! [`FragmentLists`] (every fragment of a pixel, depth-sorted, capped at N) and [`DepthLayers`]
//! (the nearest surface within each of several CoC-spaced depth intervals).

mod fragments;
mod gbuffer;
pub mod gpu;
mod layers;
mod setup;
mod shade;
pub mod views;

use glam::{Vec2, Vec3, Vec4};
use rayon::prelude::*;

pub use fragments::{
    from_half, nearest_depths, to_half, FragmentLists, FragmentTile, HalfRgba, HeldFragment, Reach,
    COINCIDENT_COC_PX, MAX_FRAGMENTS_PER_PIXEL, SAME_SURFACE,
};
pub use gbuffer::{GBuffer, GBufferTile, Z_ALPHA_THRESHOLD};
pub use layers::{DepthLayers, LayerSpacing, LayersTile, CONTINUITY_PX};
pub use setup::{SetupTriangle, COVERAGE_PATTERN, COVERAGE_SAMPLES, FULL_COVERAGE};
pub use views::{
    accumulate_views, accumulate_views_clipped, render_view, sample_view, ViewPassLabels,
};

use crate::image::Rgba;
use crate::lens::ThinLens;
use crate::scene::{AlphaMode, Scene};
use crate::Result;

/// `n` copies of `value`, written by all threads: a layer stack or fragment store is tens to
/// hundreds of megabytes, and the first write to each page (the kernel clears it) is most of
/// the cost (`vec!` wrote 142 MB of `multiview`'s layers on one thread in 74 ms of its 255 ms
/// `decompose` on `railing` at 1280x720).
pub(crate) fn filled_in_parallel<T: Copy + Send + Sync>(value: T, n: usize) -> Vec<T> {
    let mut v = Vec::with_capacity(n);
    v.par_extend((0..n).into_par_iter().map(|_| value));
    v
}

/// Elements copied in parallel into a vector of their own (a serial copy of
/// `multilayer`'s levels was a stretch of its filter pass that one core ran alone).
pub(crate) fn par_copy<T: Copy + Default + Send + Sync>(src: &[T]) -> Vec<T> {
    /// Elements a task copies.
    const CHUNK: usize = 1 << 16;
    let mut out = filled_in_parallel(T::default(), src.len());
    out.par_chunks_mut(CHUNK)
        .zip(src.par_chunks(CHUNK))
        .for_each(|(d, s)| d.copy_from_slice(s));
    out
}

/// The rows `parts` one after another, copied in parallel (see [`par_copy`]).
pub(crate) fn par_concat<T: Copy + Default + Send + Sync>(parts: &[&[T]]) -> Vec<T> {
    let total = parts.iter().map(|p| p.len()).sum();
    let mut out = filled_in_parallel(T::default(), total);
    split_as(&mut out, parts)
        .into_par_iter()
        .zip(parts.par_iter())
        .for_each(|(d, s)| d.copy_from_slice(s));
    out
}

/// `out` cut into consecutive slices as long as `parts`, one each.
fn split_as<'a, T, U>(mut out: &'a mut [T], parts: &[&[U]]) -> Vec<&'a mut [T]> {
    let mut slices = Vec::with_capacity(parts.len());
    for p in parts {
        let (head, tail) = std::mem::take(&mut out).split_at_mut(p.len());
        slices.push(head);
        out = tail;
    }
    slices
}

/// The offsets (prefix sums from 0, one more than the cells) of cells whose fragment counts
/// are `rows`, row after row, worked out in parallel.
pub(crate) fn par_offsets(rows: &[&[u32]]) -> Vec<u32> {
    let mut bases = Vec::with_capacity(rows.len());
    let mut total = 0u32;
    for r in rows {
        bases.push(total);
        total += r.iter().sum::<u32>();
    }
    let cells: usize = rows.iter().map(|r| r.len()).sum();
    let mut out = vec![0u32; cells + 1];
    split_as(&mut out[1..], rows)
        .into_par_iter()
        .zip(rows.par_iter().zip(bases.par_iter()))
        .for_each(|(out, (counts, &base))| {
            let mut at = base;
            for (o, &n) in out.iter_mut().zip(counts.iter()) {
                at += n;
                *o = at;
            }
        });
    out
}

/// The [`TILE`]-pixel tiles of a `width x height` image, row-major (the last column and row
/// of tiles cut at the image's edges): the order in which the rasterizer hands them to a
/// [`Sink`].
pub(crate) fn tile_grid(width: usize, height: usize) -> Vec<TileRect> {
    (0..height.div_ceil(TILE))
        .flat_map(|ty| {
            (0..width.div_ceil(TILE)).map(move |tx| TileRect {
                x0: tx * TILE,
                y0: ty * TILE,
                x1: ((tx + 1) * TILE).min(width),
                y1: ((ty + 1) * TILE).min(height),
            })
        })
        .collect()
}

/// Tile side in pixels. 64 rather than 32: a quarter of the per-triangle, per-tile setup
/// (shader, row runs), 3 % faster on `raster/pinhole/railing` with the same output; a tile's
/// buffers (96 KiB) still fit in L2.
pub const TILE: usize = 64;

/// Low bits of a depth's `f32` dropped to make the bands [`BinnedView`] sorts triangles by:
/// 21 leaves the exponent and two mantissa bits, four bands per doubling of depth.
const DEPTH_BAND_SHIFT: u32 = 21;

/// Steps per pixel of the fixed-point grid that vertices snap to (1/256 pixel).
pub const SUBPIXEL_STEPS: f32 = (1u32 << setup::SUBPIXEL_BITS) as f32;

/// A sub-pixel sample offset in [-0.5, 0.5) moved down onto the raster's fixed-point grid, so
/// that geometry aligned to the pixel grid (texel-aligned edges) stays on grid points after the
/// shift and is never snapped across a pixel centre: an offset just below +0.5 would otherwise
/// round onto the next pixel's boundary.
pub fn snap_pixel_offset(offset: glam::Vec2) -> glam::Vec2 {
    let q = |o: f32| {
        let k = (o * SUBPIXEL_STEPS).floor();
        k.clamp(-0.5 * SUBPIXEL_STEPS, 0.5 * SUBPIXEL_STEPS - 1.0) / SUBPIXEL_STEPS
    };
    glam::Vec2::new(q(offset.x), q(offset.y))
}

/// A screen-space fragment handed to a sink.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fragment {
    /// Pixel column.
    pub x: u32,
    /// Pixel row.
    pub y: u32,
    /// View-axis depth in metres.
    pub depth_m: f32,
    /// Linear colour and alpha of the surface (straight: the sink premultiplies when it
    /// blends). Alpha is 1 for opaque and alpha-mask surfaces.
    pub color: Rgba,
    /// True for alpha-blended (transparent) surfaces.
    pub blend: bool,
    /// Which of the pixel's [`COVERAGE_SAMPLES`] coverage samples the surface covers, one bit
    /// each ([`FULL_COVERAGE`] for views rasterized at pixel centres, where a fragment is emitted
    /// only when the centre is covered).
    pub coverage: u16,
    /// The mask keeps a share of the samples for the surface's opacity (alpha to coverage)
    /// rather than the samples its geometry covers: which samples it holds says nothing about
    /// where the surface lies in the pixel.
    pub dithered: bool,
    /// The surface is seen from its back (a double-sided material's far side: the inside of a
    /// closed mesh, or the other side of a leaf).
    pub back_facing: bool,
}

impl Fragment {
    /// The fraction of the pixel covered, from 1/16 to 1.
    #[inline]
    pub fn coverage_fraction(&self) -> f32 {
        setup::count16(self.coverage) as f32 / COVERAGE_SAMPLES as f32
    }
}

/// A rectangle of pixels: `[x0, x1) x [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileRect {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// One past the last column.
    pub x1: usize,
    /// One past the last row.
    pub y1: usize,
}

impl TileRect {
    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.x1 - self.x0
    }
    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.y1 - self.y0
    }
}

/// Receives the fragments of one tile. Created by a [`Sink`], filled by one thread.
pub trait TileSink: Send {
    /// True when an opaque fragment at this depth would certainly be hidden, so the rasterizer
    /// can skip shading it. The default never rejects.
    #[inline]
    fn occluded(&self, _x: u32, _y: u32, _depth_m: f32) -> bool {
        false
    }
    /// The same test for a run of pixels `xa..xb` of row `y` at once, when the sink keeps one
    /// depth per pixel: `row[x - xa]` such that `occluded(x, y, d)` is `d >= row[x - xa]`. The
    /// rasterizer then tests a run without working out each pixel's place in the tile. The
    /// default is `None`: pixel by pixel with [`Self::occluded`].
    #[inline]
    fn occlusion_row(&self, _y: u32, _xa: u32, _xb: u32) -> Option<&[f32]> {
        None
    }
    /// Takes one fragment.
    fn fragment(&mut self, fragment: &Fragment);
    /// Called once after the last fragment, still in parallel with other tiles.
    fn finish(&mut self) {}
}

/// Where fragments go. The rasterizer asks for one [`TileSink`] per tile, fills the tiles in
/// parallel, then hands them back in tile order with [`Sink::end_tile`].
pub trait Sink: Sync {
    /// Per-tile state.
    type Tile: TileSink;
    /// A fresh tile.
    fn begin_tile(&self, rect: TileRect) -> Self::Tile;
    /// Takes a finished tile back (sequentially, in row-major tile order).
    fn end_tile(&mut self, rect: TileRect, tile: Self::Tile);
    /// Takes back every tile of a pass, in row-major tile order. The default hands them to
    /// [`Sink::end_tile`] one by one; a sink whose tiles write disjoint pixels may take them
    /// in parallel (as [`GBuffer`] does, a band of tile rows per task).
    fn end_tiles(&mut self, tiles: Vec<(TileRect, Self::Tile)>) {
        for (rect, tile) in tiles {
            self.end_tile(rect, tile);
        }
    }
}

/// One view: the camera's thin lens seen from a point on the lens, sampled at an offset inside
/// each pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// The shared thin-lens constants.
    pub lens: ThinLens,
    /// Point in the unit aperture, image axes (x right, y down); zero for the pinhole view.
    pub lens_point: Vec2,
    /// Sample position relative to the pixel centre, in pixels.
    pub pixel_offset: Vec2,
    /// Added to the texture level of detail: `-0.5 * log2(N)` when each pixel is the mean of N
    /// views, so each view filters textures over its share of the pixel.
    pub lod_bias: f32,
}

impl View {
    /// The pinhole view through the lens centre, sampled at pixel centres.
    pub fn pinhole(lens: ThinLens) -> Self {
        Self {
            lens,
            lens_point: Vec2::ZERO,
            pixel_offset: Vec2::ZERO,
            lod_bias: 0.0,
        }
    }

    /// Homogeneous raster coordinates `(x*w, y*w, w)` of a camera-space point, `w = z` the view
    /// depth. Linear in the point, so clipping and interpolation can be done on it.
    #[inline]
    pub fn clip_from_camera(&self, p: Vec3) -> Vec3 {
        let l = &self.lens;
        let z = -p.z;
        let (cx, cy) = l.centre_px();
        // Lens point in camera space (y up).
        let vx = l.lens_radius_m * self.lens_point.x;
        let vy = -l.lens_radius_m * self.lens_point.y;
        let f = l.f_px;
        let hx = (cx - self.pixel_offset.x + f * vx / l.focus_m) * z + f * (p.x - vx);
        let hy = (cy - self.pixel_offset.y - f * vy / l.focus_m) * z - f * (p.y - vy);
        Vec3::new(hx, hy, z)
    }
}

/// A scene transformed to camera space and flattened for rasterization, reused for every view
/// of a frame.
#[derive(Clone, Debug)]
pub struct PreparedScene<'a> {
    scene: &'a Scene,
    positions: Vec<Vec3>,
    uvs: Vec<Vec2>,
    triangles: Vec<PreparedTriangle>,
}

#[derive(Clone, Copy, Debug)]
struct PreparedTriangle {
    v: [u32; 3],
    material: u32,
}

impl<'a> PreparedScene<'a> {
    /// Bytes a prepared `scene` takes: its vertices' positions and texture coordinates (20
    /// bytes each) and its triangles (16).
    pub fn bytes_for(scene: &Scene) -> u64 {
        scene.vertex_count() as u64
            * (std::mem::size_of::<Vec3>() + std::mem::size_of::<Vec2>()) as u64
            + scene.triangle_count() as u64 * std::mem::size_of::<PreparedTriangle>() as u64
    }

    /// Transforms `scene` into the camera space of `camera_from_world` and validates it.
    pub fn new(scene: &'a Scene, camera_from_world: &glam::Affine3A) -> Result<Self> {
        scene.validate()?;
        let mut positions =
            Vec::with_capacity(scene.meshes.iter().map(|m| m.positions.len()).sum());
        let mut uvs = Vec::with_capacity(positions.capacity());
        let mut triangles = Vec::with_capacity(scene.triangle_count());
        for mesh in &scene.meshes {
            let base = positions.len() as u32;
            positions.extend(
                mesh.positions
                    .iter()
                    .map(|&p| camera_from_world.transform_point3(p)),
            );
            if mesh.uvs.is_empty() {
                uvs.resize(uvs.len() + mesh.positions.len(), Vec2::ZERO);
            } else {
                uvs.extend_from_slice(&mesh.uvs);
            }
            triangles.extend(mesh.indices.iter().map(|t| PreparedTriangle {
                v: [t[0] + base, t[1] + base, t[2] + base],
                material: mesh.material as u32,
            }));
        }
        // The bounds of the early alpha test for cut-out textures, made here, texture by
        // texture in parallel, rather than by the first tile that meets each.
        let mut cut_out: Vec<usize> = scene
            .materials
            .iter()
            .filter(|m| shade::early_alpha_cutoff(m, &scene.textures).is_some())
            .filter_map(|m| m.base_color_texture.as_ref().map(|b| b.texture))
            .collect();
        cut_out.sort_unstable();
        cut_out.dedup();
        cut_out
            .par_iter()
            .for_each(|&t| scene.textures[t].prepare_alpha_bounds());
        Ok(Self {
            scene,
            positions,
            uvs,
            triangles,
        })
    }

    /// The scene this was prepared from.
    pub fn scene(&self) -> &Scene {
        self.scene
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Vertex positions in camera space (metres).
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }

    /// The signed CoC range, in pixels, of the geometry in view of `lens`: the nearest and
    /// farthest depth of every triangle clipped to the near and far planes and to a generous
    /// window (the frame grown by its own size on every side), so a rail whose vertices all
    /// lie far outside the frame still counts where it crosses it. `(0, 1)` when there is none.
    pub fn coc_range(&self, lens: &ThinLens) -> (f32, f32) {
        let (w, h) = (lens.width_px as f32, lens.height_px as f32);
        let (cx, cy) = lens.centre_px();
        let f = lens.f_px;
        // Each plane as a linear function of (x, y, depth) that is >= 0 inside.
        let planes: [Vec4; 6] = [
            Vec4::new(0.0, 0.0, 1.0, -lens.near_m),
            Vec4::new(0.0, 0.0, -1.0, lens.far_m),
            Vec4::new(f, 0.0, cx + w, 0.0),
            Vec4::new(-f, 0.0, 2.0 * w - cx, 0.0),
            Vec4::new(0.0, -f, cy + h, 0.0),
            Vec4::new(0.0, f, 2.0 * h - cy, 0.0),
        ];
        let dist = |k: usize, p: Vec3| planes[k].dot(p.extend(1.0));
        let (mut near, mut far) = (f32::INFINITY, f32::NEG_INFINITY);
        let mut poly: Vec<Vec3> = Vec::with_capacity(9);
        let mut next: Vec<Vec3> = Vec::with_capacity(9);
        for t in &self.triangles {
            // (x, y, depth) with depth positive in front of the lens.
            let v = t.v.map(|i| {
                let p = self.positions[i as usize];
                Vec3::new(p.x, p.y, -p.z)
            });
            poly.clear();
            poly.extend_from_slice(&v);
            for k in 0..planes.len() {
                if poly.iter().all(|&p| dist(k, p) >= 0.0) {
                    continue;
                }
                next.clear();
                for i in 0..poly.len() {
                    let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                    let (da, db) = (dist(k, a), dist(k, b));
                    if da >= 0.0 {
                        next.push(a);
                    }
                    if (da >= 0.0) != (db >= 0.0) {
                        next.push(a + (b - a) * (da / (da - db)));
                    }
                }
                std::mem::swap(&mut poly, &mut next);
                if poly.is_empty() {
                    break;
                }
            }
            for p in &poly {
                near = near.min(p.z);
                far = far.max(p.z);
            }
        }
        if !(near.is_finite() && far.is_finite()) {
            return (0.0, 1.0);
        }
        let (lo, hi) = (lens.coc_px(near.max(lens.near_m)), lens.coc_px(far));
        (lo, hi.max(lo + 1e-3))
    }

    /// The guard band, in pixels on each side, that the layered methods rasterize around the
    /// frame of `lens` (DESIGN.md, evaluation protocol): the largest CoC radius of the
    /// geometry in view ([`Self::coc_range`]), so a blur at the border gathers what lies just
    /// outside the frame as `reference`'s views see it; capped at
    /// [`GUARD_BAND_MAX_FRACTION`] of the frame's longer side, which bounds its cost.
    pub fn guard_band_px(&self, lens: &ThinLens) -> usize {
        let (lo, hi) = self.coc_range(lens);
        let cap = (GUARD_BAND_MAX_FRACTION * lens.width_px.max(lens.height_px) as f32).ceil();
        lo.abs().max(hi.abs()).ceil().clamp(0.0, cap) as usize
    }
}

/// How the layered methods (`multilayer`, `splat` with several layers, `multiview`) rasterize
/// their input. The papers sample each pixel once over the frame only; the default anti-aliases
/// and widens it, as DESIGN.md's evaluation protocol asks (measured in the README).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LayeredInput {
    /// Fragments carry their coverage of the pixel ([`BinnedView::with_coverage`]); false:
    /// sampled at pixel centres, as the papers.
    pub coverage: bool,
    /// Rasterize a guard band around the frame ([`PreparedScene::guard_band_px`]); false: the
    /// frame only, as the papers.
    pub guard_band: bool,
    /// With coverage: where a texture is minified (a pixel spans more than a texel) on a
    /// surface nearly in focus (CoC radius at most [`SAMPLE_SHADING_MAX_COC_PX`]), every
    /// covered sample takes its own lookup (sixteen, each at a sixteenth of the footprint),
    /// so the pixel is the texture's mean over its covered area, as `reference`'s many views
    /// make it; false: one lookup a quadrant, whose mip filter is wider than the quadrant and
    /// blurs the texture's edges along the less minified axis. Sharper in focus, at up to
    /// twice the rasterization's time where much of the frame is such a texture (measured in
    /// the README). Default false; `multiview` takes true ([`LayeredInput::SAMPLE_SHADED`]).
    pub sample_shading: bool,
}

impl Default for LayeredInput {
    fn default() -> Self {
        Self {
            coverage: true,
            guard_band: true,
            sample_shading: false,
        }
    }
}

impl LayeredInput {
    /// The default input with minified textures looked up at every covered sample
    /// ([`LayeredInput::sample_shading`]): `multiview`'s default.
    pub const SAMPLE_SHADED: Self = Self {
        coverage: true,
        guard_band: true,
        sample_shading: true,
    };

    /// The papers' input: pixel centres, the frame only.
    pub const PAPER: Self = Self {
        coverage: false,
        guard_band: false,
        sample_shading: false,
    };

    /// The guard band in pixels for `lens` (0 when off).
    pub fn guard_band_px(&self, prepared: &PreparedScene, lens: &ThinLens) -> usize {
        if self.guard_band {
            prepared.guard_band_px(lens)
        } else {
            0
        }
    }

    /// The binned pinhole view of `lens`, with coverage masks when on; refused when its tile
    /// lists would pass the memory budget ([`BinnedView::new`]).
    pub fn bin(&self, prepared: &PreparedScene, view: &View) -> Result<BinnedView> {
        Ok(match (self.coverage, self.sample_shading) {
            (true, true) => BinnedView::with_coverage(prepared, view)?,
            (true, false) => BinnedView::with_coverage(prepared, view)?.with_quadrant_shading(),
            (false, _) => BinnedView::new(prepared, view)?,
        })
    }
}

/// The CoC radius in pixels up to which [`LayeredInput::sample_shading`] looks a minified
/// texture up at every sample. Beyond it the defocus blur hides the difference: a quadrant's
/// lookup widens the pixel's filter by a fraction of a pixel, and a disc of radius 2 px has
/// already cut the frequencies where the two filters differ (its transfer function's first
/// zero is at 0.3 cycles a pixel); the blurred image changes by under 5% of the blur's width.
pub const SAMPLE_SHADING_MAX_COC_PX: f32 = 2.0;

/// The view depths in metres (nearest, farthest) whose CoC radius under `lens` is at most
/// [`SAMPLE_SHADING_MAX_COC_PX`].
fn sample_shading_depths(lens: &ThinLens) -> (f32, f32) {
    let c = SAMPLE_SHADING_MAX_COC_PX;
    (lens.depth_for_coc_px(-c), lens.depth_for_coc_px(c))
}

/// Largest guard band as a fraction of the frame's longer side: at 1/8 the frame grows to at
/// most 1.25 x 1.44 (16:9) of its pixels.
pub const GUARD_BAND_MAX_FRACTION: f32 = 0.125;

/// Triangles of a view after setup and binning, ready to rasterize into any sink.
pub struct BinnedView {
    triangles: Vec<SetupTriangle>,
    bins: Vec<Vec<u32>>,
    width: usize,
    height: usize,
    lod_bias: f32,
    coverage: bool,
    /// With coverage: the view depths in metres (nearest, farthest) within which a minified
    /// texture is looked up at every covered sample instead of once a quadrant
    /// ([`sample_shading_depths`]; `None`: [`BinnedView::with_quadrant_shading`]).
    sample_shading: Option<(f32, f32)>,
}

/// Bytes a pixel of a run that rasterizes views holds besides the views themselves, counted
/// with the scene when a view's tile lists are checked against the memory budget: the sum of
/// the views and the image (16 bytes each).
const HELD_BYTES_PER_PIXEL: u64 = 32;

/// What a run holds while it bins a view of `prepared` at `lens`'s size: the program (64
/// MiB, as the methods' estimates count it), the scene, its camera-space copy and the frame
/// ([`HELD_BYTES_PER_PIXEL`]).
fn held_bytes(prepared: &PreparedScene, lens: &ThinLens) -> u64 {
    (64 << 20)
        + prepared.scene.bytes()
        + PreparedScene::bytes_for(prepared.scene)
        + (lens.width_px * lens.height_px) as u64 * HELD_BYTES_PER_PIXEL
}

impl BinnedView {
    /// Sets up and bins every triangle of `prepared` for `view` (passes `setup` and `bin`).
    /// Refused, before the tile lists are allocated, when they and what the run holds (the
    /// scene, its copy, the frame) would pass the memory budget: a triangle is entered in
    /// every tile its bounding box touches, so large triangles take many entries each.
    pub fn new(prepared: &PreparedScene, view: &View) -> Result<Self> {
        Self::bin(
            Self::setup(prepared, view, false),
            view,
            false,
            held_bytes(prepared, &view.lens),
        )
    }

    /// [`BinnedView::new`] for rasterizing with coverage masks: every pixel a triangle touches
    /// gets a fragment whose [`Fragment::coverage`] says which of the pixel's
    /// [`COVERAGE_SAMPLES`] samples it covers (shaded once, at the covered samples' centroid),
    /// as an A-buffer does (Carpenter 1984). For sinks that keep several fragments per pixel:
    /// a surface's edge then covers its share of a pixel instead of all or nothing.
    pub fn with_coverage(prepared: &PreparedScene, view: &View) -> Result<Self> {
        Self::bin(
            Self::setup(prepared, view, true),
            view,
            true,
            held_bytes(prepared, &view.lens),
        )
    }

    /// [`BinnedView::new`], timing `setup` and `bin` under the labels given, with `views`
    /// bytes of other binned views held beside it.
    pub fn new_timed(
        prepared: &PreparedScene,
        view: &View,
        labels: &views::ViewPassLabels,
        timings: &mut crate::timing::Timings,
        views: u64,
    ) -> Result<Self> {
        let triangles = timings.time(labels.setup, || Self::setup(prepared, view, false));
        let held = held_bytes(prepared, &view.lens) + views;
        timings.time(labels.bin, || Self::bin(triangles, view, false, held))
    }

    /// Bytes the view holds: its set-up triangles and its tiles' lists.
    pub fn bytes(&self) -> u64 {
        (self.triangles.capacity() * std::mem::size_of::<SetupTriangle>()
            + self
                .bins
                .iter()
                .map(|b| b.capacity() * 4 + 24)
                .sum::<usize>()) as u64
    }

    /// Pass `setup`: project, clip and cull every triangle for `view` (keeping those that touch
    /// a pixel without covering its centre when `coverage`).
    fn setup(prepared: &PreparedScene, view: &View, coverage: bool) -> Vec<SetupTriangle> {
        let materials = &prepared.scene.materials;
        prepared
            .triangles
            .par_chunks(1024)
            .flat_map_iter(|chunk| {
                let mut out = Vec::new();
                for t in chunk {
                    let material = &materials[t.material as usize];
                    let verts = t.v.map(|i| {
                        (
                            view.clip_from_camera(prepared.positions[i as usize]),
                            prepared.uvs[i as usize],
                        )
                    });
                    setup::setup_triangle(
                        &verts,
                        t.material,
                        material.double_sided,
                        matches!(material.alpha_mode, AlphaMode::Blend),
                        &view.lens,
                        coverage,
                        &mut out,
                    );
                }
                out
            })
            .collect()
    }

    /// Pass `bin`: each triangle into the list of every tile its bounding box touches, the
    /// opaque and alpha-mask ones nearest first (by their nearest vertex), then the blended
    /// ones in scene order. Drawn front to back, most hidden fragments fail the early depth
    /// test before they are shaded, which is cheaper than a depth pre-pass (measured: railing
    /// at 256 views 3.7 -> 3.1 s) and also covers alpha-tested surfaces, whose coverage a
    /// pre-pass cannot know without their texture. The nearest surface of each pixel is the
    /// same in any order; only which of two surfaces at exactly the same depth wins can differ
    /// from scene order.
    fn bin(triangles: Vec<SetupTriangle>, view: &View, coverage: bool, held: u64) -> Result<Self> {
        let width = view.lens.width_px;
        let height = view.lens.height_px;
        let tiles_x = width.div_ceil(TILE);
        let tiles_y = height.div_ceil(TILE);
        // Each tile's list exactly as long as it will be, counted before anything is allocated.
        let mut counts = vec![0u32; tiles_x * tiles_y];
        for t in &triangles {
            let (x0, y0, x1, y1) = t.bbox;
            for ty in y0 as usize / TILE..=y1 as usize / TILE {
                for c in &mut counts[ty * tiles_x..][x0 as usize / TILE..=x1 as usize / TILE] {
                    *c += 1;
                }
            }
        }
        let entries: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        let bytes = (triangles.capacity() * std::mem::size_of::<SetupTriangle>()) as u64
            + entries * 4
            + counts.len() as u64 * 24;
        crate::budget::check(
            held + bytes,
            &format!(
                "a view of {} triangles at {width}x{height} ({entries} tile-list entries: a \
                 triangle enters every {TILE}x{TILE} tile it touches)",
                triangles.len()
            ),
            "the scene's size or the resolution",
        )?;
        let mut bins: Vec<Vec<u32>> = counts
            .iter()
            .map(|&c| Vec::with_capacity(c as usize))
            .collect();
        // Blended triangles only collect fragments (the sink composites them once the tile is
        // done), so their place in the order does not matter.
        let mut opaque = false;
        for (i, t) in triangles.iter().enumerate() {
            let (x0, y0, x1, y1) = t.bbox;
            opaque |= !t.blend;
            // bbox is inclusive pixel range clamped to the image.
            for ty in y0 as usize / TILE..=y1 as usize / TILE {
                for tx in x0 as usize / TILE..=x1 as usize / TILE {
                    bins[ty * tiles_x + tx].push(i as u32);
                }
            }
        }
        if opaque {
            // Sort keys: the nearest depth in quarter octaves (the float's exponent and top two
            // mantissa bits, ordered as the numbers for positive floats; blended triangles get
            // the largest key) above the triangle index, so one integer sort gives the depth
            // bands nearest first, each in scene order, then the blended triangles in scene
            // order. Bands rather than exact depths keep neighbouring triangles together (their
            // vertices and texels stay in cache: sorting by exact depth made a frame of 300k
            // small triangles 12% slower than no sorting at all) and still put near surfaces
            // first.
            let depth_key: Vec<u32> = triangles
                .iter()
                .map(|t| {
                    if t.blend {
                        u32::MAX
                    } else {
                        t.nearest_m.max(0.0).to_bits() >> DEPTH_BAND_SHIFT
                    }
                })
                .collect();
            bins.par_iter_mut()
                .for_each_init(Vec::new, |keys: &mut Vec<u64>, bin| {
                    keys.clear();
                    keys.extend(
                        bin.iter()
                            .map(|&i| (u64::from(depth_key[i as usize]) << 32) | u64::from(i)),
                    );
                    keys.sort_unstable();
                    for (b, k) in bin.iter_mut().zip(keys.iter()) {
                        *b = *k as u32;
                    }
                });
        }
        Ok(Self {
            triangles,
            bins,
            width,
            height,
            lod_bias: view.lod_bias,
            coverage,
            sample_shading: coverage.then(|| sample_shading_depths(&view.lens)),
        })
    }

    /// With coverage masks, textures looked up once a quadrant of the pixel only, even where
    /// they are minified (by default every covered sample then takes its own lookup; see
    /// [`LayeredInput::sample_shading`]).
    pub fn with_quadrant_shading(self) -> Self {
        Self {
            sample_shading: None,
            ..self
        }
    }

    /// Number of triangles after clipping and culling.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The tiles of the image, row-major: the `i`th rectangle is the one [`Sink`]s receive
    /// `i`th and [`BinnedView::rasterize_tile`] takes as `i`.
    pub fn tile_rects(&self) -> Vec<TileRect> {
        tile_grid(self.width, self.height)
    }

    /// Rasterizes the triangles of tile `index` (at `rect`, from [`BinnedView::tile_rects`])
    /// into `tile`, in the order of its bin (see `bin`). Does not call [`TileSink::finish`].
    pub fn rasterize_tile<T: TileSink>(
        &self,
        prepared: &PreparedScene,
        index: usize,
        rect: &TileRect,
        tile: &mut T,
    ) {
        let scene = prepared.scene;
        let mut scratch = setup::RasterScratch::new();
        for &ti in &self.bins[index] {
            let tri = &self.triangles[ti as usize];
            setup::raster_triangle(
                tri,
                rect,
                scene,
                setup::Sampling {
                    lod_bias: self.lod_bias,
                    coverage: self.coverage,
                    sample_shading: self.sample_shading,
                },
                tile,
                &mut scratch,
            );
        }
    }

    /// Rasterizes into `sink` (pass `raster`), tiles in parallel.
    pub fn rasterize<S: Sink>(&self, prepared: &PreparedScene, sink: &mut S) {
        let shared: &S = sink;
        let tiles: Vec<(TileRect, S::Tile)> = self
            .tile_rects()
            .into_par_iter()
            .enumerate()
            .map(|(i, rect)| {
                let mut tile = shared.begin_tile(rect);
                self.rasterize_tile(prepared, i, &rect, &mut tile);
                tile.finish();
                (rect, tile)
            })
            .collect();
        sink.end_tiles(tiles);
    }
}

/// Collects the fragment lists of one view of `prepared`, at most `cap` per pixel, sampled as
/// `input` says ([`LayeredInput::bin`]: pixel centres, or coverage masks; its guard band is
/// the caller's, in `view`'s lens); with `reach`, without the guard band's fragments that
/// cannot reach the frame.
pub fn render_fragment_lists(
    prepared: &PreparedScene,
    view: &View,
    cap: usize,
    input: LayeredInput,
    reach: Option<Reach>,
) -> Result<FragmentLists> {
    render_fragment_lists_with(prepared, view, cap, input, reach, None)
}

/// [`render_fragment_lists`]; with `highlights`, the fragments brighter than it that a full
/// pixel would merge into a nearer one are kept apart, at their own depth
/// ([`FragmentLists::keeping_bright_overflow`]: coverage input only).
pub fn render_fragment_lists_with(
    prepared: &PreparedScene,
    view: &View,
    cap: usize,
    input: LayeredInput,
    reach: Option<Reach>,
    highlights: Option<f32>,
) -> Result<FragmentLists> {
    let binned = input.bin(prepared, view)?;
    let mut lists = FragmentLists::new(view.lens.width_px, view.lens.height_px, cap);
    if input.coverage {
        lists = lists.with_coincident_surfaces(view.lens).merging_overflow();
        if let Some(t) = highlights {
            lists = lists.keeping_bright_overflow(t);
        }
    }
    if let Some(reach) = reach {
        lists = lists.with_reach(reach);
    }
    binned.rasterize(prepared, &mut lists);
    lists.compact();
    Ok(lists)
}

/// Renders one view of `prepared` into a fresh [`GBuffer`].
pub fn render_gbuffer(prepared: &PreparedScene, view: &View) -> Result<GBuffer> {
    let binned = BinnedView::new(prepared, view)?;
    let mut g = GBuffer::new(view.lens.width_px, view.lens.height_px);
    binned.rasterize(prepared, &mut g);
    Ok(g)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::SplitMix64;

    /// Rows of random lengths (some empty, some longer than a copy task's chunk) and values.
    fn random_rows(seed: u64) -> Vec<Vec<u32>> {
        let mut rng = SplitMix64::new(seed);
        (0..40)
            .map(|_| {
                let len = match rng.next_u64() % 4 {
                    0 => 0,
                    1 => (rng.next_u64() % 8) as usize,
                    2 => (rng.next_u64() % 1000) as usize,
                    _ => 60_000 + (rng.next_u64() % 20_000) as usize,
                };
                (0..len).map(|_| (rng.next_u64() % 5) as u32).collect()
            })
            .collect()
    }

    #[test]
    fn parallel_copies_and_prefix_sums_are_the_serial_ones() {
        for seed in 0..3 {
            let rows = random_rows(seed);
            let parts: Vec<&[u32]> = rows.iter().map(|r| &r[..]).collect();
            let serial: Vec<u32> = rows.iter().flatten().copied().collect();
            assert_eq!(par_concat(&parts), serial);
            assert_eq!(par_copy(&serial), serial);
            let mut sums = vec![0u32];
            for &n in &serial {
                sums.push(sums.last().unwrap() + n);
            }
            assert_eq!(par_offsets(&parts), sums);
        }
        assert!(par_concat::<u32>(&[]).is_empty());
        assert_eq!(par_offsets(&[]), vec![0]);
    }
}
