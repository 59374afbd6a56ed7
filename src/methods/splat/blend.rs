//! Pass `blend`: each pixel of a tile walks the tile's depth-sorted list front to back and
//! blends every fragment that covers it (the poster's point: true depth order, unlike a
//! gather).
//!
//! A fragment with signed CoC `C` centred at `p0` covers pixel `p` when `v = (p - p0) / C` lies
//! in the unit aperture (a far-field bokeh shows the aperture as defined, a near-field one turned
//! 180 degrees, as `reference`), with an edge one pixel soft (a merged fragment's as wide as its
//! block) for the disc and straight-bladed polygons (coverage `clamp(1/2 - d, 0, 1)` with `d` the signed distance to the edge in
//! pixels); curved blades and image apertures use their density. The radius is at least half
//! a pixel, so an in-focus fragment covers exactly its own pixel. Its weight is the coverage
//! times `1 / area`, the area of its footprint in pixels (summed exactly over the pixel grid
//! below 4 px of radius, `area * C^2` above), so a point light keeps its energy.
//!
//! Fragments of one surface lie side by side, not in front of each other: consecutive
//! fragments of a tile's sorted list whose CoCs are within `group_px` of the first of their run
//! are one surface and are summed (a batch); the batches are blended front to back with the over
//! operator. A batch is linear, so a fragment adds its fully covered span of each row through a
//! difference array (constant work per row) and only its soft edge pixel by pixel; the batch is
//! resolved over its bounding box when the next surface starts. A tile whose pixels are all
//! opaque stops walking its list.
//!
//! Tiles are independent and run in parallel; within a tile fragments are taken in list order,
//! so the result does not depend on the thread count.

use glam::Vec2;
use rayon::prelude::*;

use super::build::{reach_px, SplatFragment, TileLists, TILE_PX};
use crate::image::{ColorImage, Rgba};
use crate::lens::Aperture;

/// The aperture, prepared for coverage tests.
#[derive(Clone, Debug)]
pub struct Shape {
    kind: ShapeKind,
    /// Area of the unit aperture (pi for the disc).
    area: f32,
    /// The anamorphic squeeze of the aperture's axes ([`crate::lens::LensEffects::squeeze`]):
    /// the footprint is the shape stretched by `squeeze.x` across and `squeeze.y` down, its
    /// soft edge at most `soft_px` wide. `(1, 1)` for the ideal lens.
    squeeze: Vec2,
}

#[derive(Clone, Debug)]
enum ShapeKind {
    Disc,
    /// Outward unit normals of the edges and the apothem (distance of the edges from the
    /// centre), in units of the aperture radius.
    Polygon {
        normals: Vec<Vec2>,
        apothem: f32,
    },
    /// Curved blades or an image: the density, no soft edge.
    Density(Aperture),
}

impl Shape {
    /// Prepares `aperture`.
    pub fn new(aperture: &Aperture) -> Self {
        let kind = match aperture {
            Aperture::Disc => ShapeKind::Disc,
            Aperture::Polygon {
                blade_radius: None, ..
            } => {
                let v = aperture.vertices();
                let n = v.len();
                let normals: Vec<Vec2> = (0..n)
                    .map(|k| {
                        let mid = (v[k] + v[(k + 1) % n]) * 0.5;
                        mid.normalize()
                    })
                    .collect();
                let apothem = ((v[0] + v[1 % n]) * 0.5).length();
                ShapeKind::Polygon { normals, apothem }
            }
            other => ShapeKind::Density(other.clone()),
        };
        Self {
            kind,
            area: aperture.area(),
            squeeze: Vec2::ONE,
        }
    }

    /// The shape with the anamorphic squeeze of `effects` (its other effects are not drawn
    /// here: the registry refuses them for `splat`).
    pub fn with_effects(mut self, effects: &crate::lens::LensEffects) -> Self {
        self.squeeze = effects.squeeze(Vec2::ONE);
        self
    }

    /// How far the footprint reaches beyond the CoC radius along its longer axis.
    #[inline]
    pub fn stretch(&self) -> f32 {
        self.squeeze.x.max(self.squeeze.y)
    }

    /// The squeeze a fragment of CoC radius `coc_px` is drawn with: the aperture's, except
    /// that neither axis of its footprint falls below the half pixel every fragment is drawn
    /// with ([`draw_radius`]). An in-focus point seen through an anamorphic lens stays one
    /// pixel; squeezing its half-pixel draw radius spread it over the rows above and below
    /// (`splat --layers 4 --anamorphic 0.5` blurred `traps`' in-focus chart: 31.9 dB against
    /// `reference` with the same squeeze, 37.6 with a round aperture). The ideal lens's is 1.
    #[inline]
    pub fn squeeze_for(&self, coc_px: f32) -> Vec2 {
        if self.squeeze == Vec2::ONE {
            return Vec2::ONE;
        }
        let r = draw_radius(coc_px).abs();
        (self.squeeze * coc_px.abs()).max(Vec2::splat(0.5)) / r
    }

    /// Coverage in [0, 1] of the pixel at offset `d_px` from a fragment's centre, for its
    /// signed CoC radius `c` (drawn at least half a pixel wide, [`draw_radius`]) and an edge
    /// `soft_px` pixels wide (1, or the block size of a merged fragment: the footprint of a
    /// block is its disc widened by the block).
    #[inline]
    pub fn coverage(&self, d_px: Vec2, c: f32, soft_px: f32) -> f32 {
        let squeeze = self.squeeze_for(c);
        let c = draw_radius(c);
        let (d_px, soft_px) = (d_px / squeeze, soft_px / squeeze.x.max(squeeze.y));
        let r = c.abs();
        let v = d_px / c;
        let inv = 1.0 / soft_px;
        match &self.kind {
            ShapeKind::Disc => (0.5 - (v.length() - 1.0) * r * inv).clamp(0.0, 1.0),
            ShapeKind::Polygon { normals, apothem } => {
                let mut m = f32::MIN;
                for n in normals {
                    m = m.max(n.dot(v));
                }
                (0.5 - (m - apothem) * r * inv).clamp(0.0, 1.0)
            }
            ShapeKind::Density(a) => a.density(v),
        }
    }

    /// `1 / (summed coverage)`: the weight that makes a fragment's footprint sum to 1.
    pub fn norm(&self, centre: Vec2, c: f32, soft_px: f32) -> f32 {
        let r = draw_radius(c).abs();
        if r >= 4.0 {
            let squeeze = self.squeeze_for(c);
            return 1.0 / (self.area * r * r * squeeze.x * squeeze.y);
        }
        let reach = reach_px(c, soft_px, self.stretch());
        let (x0, x1) = (
            (centre.x - reach).floor() as i64,
            (centre.x + reach).ceil() as i64,
        );
        let (y0, y1) = (
            (centre.y - reach).floor() as i64,
            (centre.y + reach).ceil() as i64,
        );
        let mut sum = 0.0f32;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let d = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - centre;
                sum += self.coverage(d, c, soft_px);
            }
        }
        if sum > 0.0 {
            1.0 / sum
        } else {
            0.0
        }
    }
}

/// The signed radius a fragment is drawn with: its CoC, at least half a pixel.
#[inline]
pub fn draw_radius(coc_px: f32) -> f32 {
    if coc_px.abs() < 0.5 {
        0.5
    } else {
        coc_px
    }
}

/// What the blend pass reads besides the tile lists.
pub struct BlendInput<'a> {
    /// The fragments.
    pub fragments: &'a [SplatFragment],
    /// `norms[i]`: fragment i's weight normalisation ([`Shape::norm`]).
    pub norms: &'a [f32],
    /// The aperture.
    pub shape: &'a Shape,
    /// CoC difference in pixels within which fragments are one surface.
    pub group_px: f32,
    /// Block size of merged fragments.
    pub merge: usize,
}

/// Most polygon blades handled by the fast row spans (more fall back to per-pixel density).
const MAX_BLADES: usize = 16;

/// One fragment's footprint, prepared for its rows: the shape at signed radius `c` with an
/// edge `soft` pixels wide, in pixel units.
struct Footprint<'a> {
    shape: &'a Shape,
    /// The fragment's CoC radius, and the radius it is drawn with ([`draw_radius`]).
    coc: f32,
    r: f32,
    /// The edge width in the unsqueezed frame, and the pixel one.
    soft: f32,
    soft_px: f32,
    /// The squeeze: rows and columns are walked in pixels, tested in the unsqueezed frame
    /// (multiplied by `1 / squeeze`, worked out once: a division per pixel cost `grass` 4% of
    /// its blend; exact, so unchanged, for the ideal lens's squeeze of 1).
    squeeze: Vec2,
    inv_squeeze: Vec2,
    inv_soft: f32,
    /// Disc: squared radii of the outer (coverage above 0) and inner (coverage 1) discs.
    outer2: f32,
    inner2: f32,
    /// Polygon: the edges' outward normals in pixel space (turned for a negative CoC), their
    /// distance from the centre in pixels, and `1 / normal.x`.
    blades: usize,
    nx: [f32; MAX_BLADES],
    ny: [f32; MAX_BLADES],
    inv_nx: [f32; MAX_BLADES],
    dist: f32,
}

impl<'a> Footprint<'a> {
    #[inline]
    fn new(shape: &'a Shape, coc: f32, soft_px: f32) -> Self {
        let squeeze = shape.squeeze_for(coc);
        let c = draw_radius(coc);
        let soft = soft_px / squeeze.x.max(squeeze.y);
        let r = c.abs();
        let (o, i) = (r + 0.5 * soft, r - 0.5 * soft);
        let mut fp = Self {
            shape,
            coc,
            r,
            soft,
            soft_px,
            squeeze,
            inv_squeeze: Vec2::ONE / squeeze,
            inv_soft: 1.0 / soft,
            outer2: o * o,
            inner2: if i > 0.0 { i * i } else { -1.0 },
            blades: 0,
            nx: [0.0; MAX_BLADES],
            ny: [0.0; MAX_BLADES],
            inv_nx: [0.0; MAX_BLADES],
            dist: 0.0,
        };
        if let ShapeKind::Polygon { normals, apothem } = &shape.kind {
            if normals.len() <= MAX_BLADES {
                let sign = c.signum();
                fp.blades = normals.len();
                for (k, n) in normals.iter().enumerate() {
                    fp.nx[k] = sign * n.x;
                    fp.ny[k] = sign * n.y;
                    fp.inv_nx[k] = if fp.nx[k].abs() < 1e-6 {
                        0.0
                    } else {
                        1.0 / fp.nx[k]
                    };
                }
                fp.dist = apothem * r;
            }
        }
        fp
    }

    /// The outer and inner spans of row offset `dy` (pixel offsets from the centre where the
    /// coverage is above 0, and exactly 1); `None` when the row misses; an outer `None` inside
    /// `Some` means "evaluate every pixel" (density shapes).
    #[inline]
    #[expect(clippy::type_complexity, reason = "two optional intervals, read once")]
    fn spans(&self, dy: f32) -> Option<(Option<(f32, f32)>, Option<(f32, f32)>)> {
        let (outer, inner) = self.spans_unsqueezed(dy * self.inv_squeeze.y)?;
        let sx = self.squeeze.x;
        Some((
            outer.map(|(a, b)| (a * sx, b * sx)),
            inner.map(|(a, b)| (a * sx, b * sx)),
        ))
    }

    /// [`Footprint::spans`] of the unsqueezed row offset `dy`, in unsqueezed offsets.
    #[inline]
    #[expect(clippy::type_complexity, reason = "two optional intervals, read once")]
    fn spans_unsqueezed(&self, dy: f32) -> Option<(Option<(f32, f32)>, Option<(f32, f32)>)> {
        match self.shape.kind {
            ShapeKind::Disc => {
                let d2 = dy * dy;
                let o = self.outer2 - d2;
                if o < 0.0 {
                    return None;
                }
                let ho = o.sqrt();
                let i = self.inner2 - d2;
                let inner = (self.inner2 >= 0.0 && i >= 0.0).then(|| {
                    let hi = i.sqrt();
                    (-hi, hi)
                });
                Some((Some((-ho, ho)), inner))
            }
            ShapeKind::Polygon { .. } if self.blades > 0 => {
                // Edge k keeps nx dx <= dist + grow - ny dy.
                let g = 0.5 * self.soft;
                let (mut olo, mut ohi) = (f32::NEG_INFINITY, f32::INFINITY);
                let (mut ilo, mut ihi) = (f32::NEG_INFINITY, f32::INFINITY);
                for k in 0..self.blades {
                    let base = self.dist - self.ny[k] * dy;
                    let (to, ti) = (base + g, base - g);
                    let inv = self.inv_nx[k];
                    if inv == 0.0 {
                        if to < 0.0 {
                            return None;
                        }
                        if ti < 0.0 {
                            ilo = f32::INFINITY;
                        }
                    } else if inv > 0.0 {
                        let (a, b) = (to * inv, ti * inv);
                        if a < ohi {
                            ohi = a;
                        }
                        if b < ihi {
                            ihi = b;
                        }
                    } else {
                        let (a, b) = (to * inv, ti * inv);
                        if a > olo {
                            olo = a;
                        }
                        if b > ilo {
                            ilo = b;
                        }
                    }
                }
                if olo > ohi {
                    return None;
                }
                Some((Some((olo, ohi)), (ilo <= ihi).then_some((ilo, ihi))))
            }
            _ => Some((None, None)),
        }
    }

    /// Whether the footprint is convex (the disc, straight-bladed polygons), so that full
    /// coverage at a rectangle's corners means full coverage inside it.
    #[inline]
    fn convex(&self) -> bool {
        match self.shape.kind {
            ShapeKind::Disc => true,
            ShapeKind::Polygon { .. } => self.blades > 0,
            ShapeKind::Density(_) => false,
        }
    }

    /// Coverage of the pixel at offset `(dx, dy)`.
    #[inline]
    fn coverage(&self, dx: f32, dy: f32) -> f32 {
        if let ShapeKind::Density(_) = self.shape.kind {
            return self
                .shape
                .coverage(Vec2::new(dx, dy), self.coc, self.soft_px);
        }
        let (dx, dy) = (dx * self.inv_squeeze.x, dy * self.inv_squeeze.y);
        match self.shape.kind {
            ShapeKind::Disc => {
                let d = (dx * dx + dy * dy).sqrt();
                (0.5 - (d - self.r) * self.inv_soft).clamp(0.0, 1.0)
            }
            ShapeKind::Polygon { .. } if self.blades > 0 => {
                let mut m = f32::NEG_INFINITY;
                for k in 0..self.blades {
                    let v = self.nx[k] * dx + self.ny[k] * dy;
                    if v > m {
                        m = v;
                    }
                }
                (0.5 - (m - self.dist) * self.inv_soft).clamp(0.0, 1.0)
            }
            _ => self
                .shape
                .coverage(Vec2::new(dx, dy) * self.squeeze, self.coc, self.soft_px),
        }
    }
}

/// Per-tile blending state: the output, the transmittance, and the current batch (one surface)
/// as a per-row difference array for fully covered spans plus direct sums for edge pixels.
struct TileState {
    w: usize,
    out: Vec<Rgba>,
    transmit: Vec<f32>,
    /// `w + 1` entries per row.
    diff: Vec<Rgba>,
    edge: Vec<Rgba>,
    /// Bounding box of what the batch touched: x0, x1 (exclusive), y0, y1 (exclusive).
    touched: (usize, usize, usize, usize),
    /// Pixels not yet opaque.
    open: usize,
    /// What the batch adds to every pixel of the tile: the fragments whose footprint covers
    /// the whole tile at full coverage.
    full: Rgba,
}

impl TileState {
    fn new(w: usize, h: usize) -> Self {
        Self {
            w,
            out: vec![[0.0; 4]; w * h],
            transmit: vec![1.0; w * h],
            diff: vec![[0.0; 4]; (w + 1) * h],
            edge: vec![[0.0; 4]; w * h],
            touched: (usize::MAX, 0, usize::MAX, 0),
            open: w * h,
            full: [0.0; 4],
        }
    }

    /// Adds `wcol` to every pixel of the tile's batch.
    #[inline]
    fn cover(&mut self, wcol: &Rgba) {
        for (f, v) in self.full.iter_mut().zip(wcol) {
            *f += v;
        }
        let h = self.transmit.len() / self.w;
        self.touched = (0, self.w, 0, h);
    }

    #[inline]
    fn touch(&mut self, x0: usize, x1: usize, y: usize) {
        let t = &mut self.touched;
        t.0 = t.0.min(x0);
        t.1 = t.1.max(x1);
        t.2 = t.2.min(y);
        t.3 = t.3.max(y + 1);
    }

    /// Blends the batch over what is behind... in front of it: the batch is behind everything
    /// blended so far, so it is seen through the transmittance.
    fn flush(&mut self) {
        let (x0, x1, y0, y1) = self.touched;
        if x0 >= x1 {
            return;
        }
        let w = self.w;
        for y in y0..y1 {
            let mut run = [0.0f32; 4];
            for x in x0..x1 {
                let d = &mut self.diff[y * (w + 1) + x];
                for k in 0..4 {
                    run[k] += d[k];
                }
                *d = [0.0; 4];
                let i = y * w + x;
                let e = std::mem::take(&mut self.edge[i]);
                let f = &self.full;
                let g: Rgba = std::array::from_fn(|k| run[k] + e[k] + f[k]);
                if g[3] <= 0.0 && g[0] == 0.0 && g[1] == 0.0 && g[2] == 0.0 {
                    continue;
                }
                let t = self.transmit[i];
                if t < OPAQUE {
                    continue;
                }
                let scale = if g[3] > 1.0 { 1.0 / g[3] } else { 1.0 };
                let a = (g[3] * scale).clamp(0.0, 1.0);
                let o = &mut self.out[i];
                for k in 0..3 {
                    o[k] += t * g[k] * scale;
                }
                o[3] += t * a;
                let nt = t * (1.0 - a);
                if nt < OPAQUE {
                    self.open -= 1;
                }
                self.transmit[i] = nt;
            }
            self.diff[y * (w + 1) + x1] = [0.0; 4];
        }
        self.touched = (usize::MAX, 0, usize::MAX, 0);
        self.full = [0.0; 4];
    }
}

/// `floor` without a libm call (the x86-64 baseline has no rounding instruction), for values
/// well inside the `i32` range, as pixel coordinates are.
#[inline]
fn floor_px(v: f32) -> f32 {
    let t = v as i32 as f32;
    if t > v {
        t - 1.0
    } else {
        t
    }
}

/// `ceil` without a libm call (see [`floor_px`]).
#[inline]
fn ceil_px(v: f32) -> f32 {
    let t = v as i32 as f32;
    if t < v {
        t + 1.0
    } else {
        t
    }
}

/// Transmittance below which a pixel counts as opaque.
const OPAQUE: f32 = 1e-5;

/// Blends every tile (see the module documentation).
pub fn blend(input: &BlendInput, lists: &TileLists, width: usize, height: usize) -> ColorImage {
    blend_with(input, lists, width, height, blend_tile)
}

/// [`blend`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn blend_baseline(
    input: &BlendInput,
    lists: &TileLists,
    width: usize,
    height: usize,
) -> ColorImage {
    blend_with(input, lists, width, height, blend_tile_baseline)
}

fn blend_with(
    input: &BlendInput,
    lists: &TileLists,
    width: usize,
    height: usize,
    tile_fn: impl Fn(&BlendInput, &TileLists, usize, usize, usize) -> Vec<Rgba> + Sync,
) -> ColorImage {
    let tiles: Vec<Vec<Rgba>> = (0..lists.tiles_x * lists.tiles_y)
        .into_par_iter()
        .map(|t| tile_fn(input, lists, width, height, t))
        .collect();
    let mut data = vec![[0.0f32; 4]; width * height];
    for (t, tile) in tiles.into_iter().enumerate() {
        let (tx, ty) = (t % lists.tiles_x, t / lists.tiles_x);
        let x0 = tx * TILE_PX;
        let y0 = ty * TILE_PX;
        let tw = (x0 + TILE_PX).min(width) - x0;
        for (row, chunk) in tile.chunks(tw.max(1)).enumerate() {
            let dst = (y0 + row) * width + x0;
            data[dst..dst + chunk.len()].copy_from_slice(chunk);
        }
    }
    ColorImage::from_vec(width, height, data).expect("sizes agree by construction")
}

/// Tile `t` of [`blend`]. Compiled for several instruction sets and chosen at run time
/// ([`multiversion`]); the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn blend_tile(
    input: &BlendInput,
    lists: &TileLists,
    width: usize,
    height: usize,
    t: usize,
) -> Vec<Rgba> {
    // Evaluated at compile time for each version: whether `floor` and `ceil` are one
    // instruction (on x86-64 with SSE4.1, which comes with AVX2; elsewhere, as on aarch64,
    // in the base instruction set).
    const ROUND: bool = if cfg!(target_arch = "x86_64") {
        multiversion::target::selected_target!().supports_feature_str("sse4.1")
    } else {
        true
    };
    blend_tile_inner::<ROUND>(input, lists, width, height, t)
}

/// [`blend_tile`] in the portable baseline build (no rounding instruction on x86-64).
fn blend_tile_baseline(
    input: &BlendInput,
    lists: &TileLists,
    width: usize,
    height: usize,
    t: usize,
) -> Vec<Rgba> {
    blend_tile_inner::<false>(input, lists, width, height, t)
}

/// `ceil(v)`, as one instruction where `ROUND`, else without a libm call ([`ceil_px`]); the
/// same value either way for pixel coordinates.
#[inline(always)]
fn ceil_r<const ROUND: bool>(v: f32) -> f32 {
    if ROUND {
        v.ceil()
    } else {
        ceil_px(v)
    }
}

/// `floor(v)` (see [`ceil_r`]).
#[inline(always)]
fn floor_r<const ROUND: bool>(v: f32) -> f32 {
    if ROUND {
        v.floor()
    } else {
        floor_px(v)
    }
}

/// The first pixel of a row inside the footprint from offset `lo` across (pixel x is inside
/// offsets `[lo, hi]` when `lo <= x + 0.5 - cx <= hi`), clamped to the pixels `bx`. One
/// expression for every build and caller (the order of the additions decides the rounding).
#[inline(always)]
fn first_px<const ROUND: bool>(cx: f32, lo: f32, bx: (f32, f32)) -> f32 {
    ceil_r::<ROUND>(cx + lo - 0.5).clamp(bx.0, bx.1)
}

/// One past the last pixel of a row inside the footprint up to offset `hi` (see [`first_px`]).
#[inline(always)]
fn end_px<const ROUND: bool>(cx: f32, hi: f32, bx: (f32, f32)) -> f32 {
    (floor_r::<ROUND>(cx + hi - 0.5) + 1.0).clamp(bx.0, bx.1)
}

/// Row offsets 0, 1, ... of a tile, as floats.
const ROW_OFFSETS: [f32; TILE_PX] = {
    let mut r = [0.0; TILE_PX];
    let mut k = 0;
    while k < TILE_PX {
        r[k] = k as f32;
        k += 1;
    }
    r
};

/// A disc's or a straight-bladed polygon's spans on every row of a tile, worked out in one
/// pass over the rows that the compiler turns into vector lanes (the square roots or edge
/// crossings and the roundings of sixteen rows side by side) instead of row by row: per row,
/// whether the footprint meets it, whether its inner part (full coverage) does, and the pixels
/// `[outer.0, outer.1)` and `[inner.0, inner.1)` as floats, each the value
/// [`Footprint::spans`] and the rounding to pixels give for that row, bit for bit.
struct RowSpans {
    outer: [bool; TILE_PX],
    inner: [bool; TILE_PX],
    spans: [[f32; 4]; TILE_PX],
}

impl RowSpans {
    /// The disc's spans (`Footprint::spans_unsqueezed` of each row, squeezed across).
    #[inline(always)]
    fn disc<const ROUND: bool>(fp: &Footprint, centre: Vec2, y0: usize, bx: (f32, f32)) -> Self {
        let (sx, inv_sy) = (fp.squeeze.x, fp.inv_squeeze.y);
        let (outer2, inner2) = (fp.outer2, fp.inner2);
        let first = |lo: f32| first_px::<ROUND>(centre.x, lo, bx);
        let last = |hi: f32| end_px::<ROUND>(centre.x, hi, bx);
        let mut rows = Self {
            outer: [false; TILE_PX],
            inner: [false; TILE_PX],
            spans: [[0.0; 4]; TILE_PX],
        };
        let y0 = y0 as f32;
        for (k, &dk) in ROW_OFFSETS.iter().enumerate() {
            // `Footprint::spans_unsqueezed` of the row's offset, and the squeeze across.
            let dy = (y0 + dk + 0.5 - centre.y) * inv_sy;
            let d2 = dy * dy;
            let (o, i) = (outer2 - d2, inner2 - d2);
            let (ho, hi) = (o.max(0.0).sqrt(), i.max(0.0).sqrt());
            rows.outer[k] = o >= 0.0;
            rows.inner[k] = inner2 >= 0.0 && i >= 0.0;
            rows.spans[k] = [
                first(-ho * sx),
                last(ho * sx),
                first(-hi * sx),
                last(hi * sx),
            ];
        }
        rows
    }

    /// The same for a straight-bladed polygon (`Footprint::spans` edge by edge), every row of
    /// the tile at once: each edge moves the rows' bounds in one loop of lanes.
    #[inline(always)]
    fn polygon<const ROUND: bool>(fp: &Footprint, centre: Vec2, y0: usize, bx: (f32, f32)) -> Self {
        let (sx, inv_sy) = (fp.squeeze.x, fp.inv_squeeze.y);
        let first = |lo: f32| first_px::<ROUND>(centre.x, lo, bx);
        let last = |hi: f32| end_px::<ROUND>(centre.x, hi, bx);
        let y0 = y0 as f32;
        let dy = ROW_OFFSETS.map(|dk| (y0 + dk + 0.5 - centre.y) * inv_sy);
        // Edge k keeps nx dx <= dist + grow - ny dy.
        let g = 0.5 * fp.soft;
        let mut miss = [false; TILE_PX];
        let (mut olo, mut ohi) = ([f32::NEG_INFINITY; TILE_PX], [f32::INFINITY; TILE_PX]);
        let (mut ilo, mut ihi) = ([f32::NEG_INFINITY; TILE_PX], [f32::INFINITY; TILE_PX]);
        for b in 0..fp.blades.min(MAX_BLADES) {
            let (ny, inv) = (fp.ny[b], fp.inv_nx[b]);
            if inv == 0.0 {
                for k in 0..TILE_PX {
                    let base = fp.dist - ny * dy[k];
                    let (to, ti) = (base + g, base - g);
                    miss[k] |= to < 0.0;
                    ilo[k] = if ti < 0.0 { f32::INFINITY } else { ilo[k] };
                }
            } else if inv > 0.0 {
                for k in 0..TILE_PX {
                    let base = fp.dist - ny * dy[k];
                    let (a, c) = ((base + g) * inv, (base - g) * inv);
                    ohi[k] = if a < ohi[k] { a } else { ohi[k] };
                    ihi[k] = if c < ihi[k] { c } else { ihi[k] };
                }
            } else {
                for k in 0..TILE_PX {
                    let base = fp.dist - ny * dy[k];
                    let (a, c) = ((base + g) * inv, (base - g) * inv);
                    olo[k] = if a > olo[k] { a } else { olo[k] };
                    ilo[k] = if c > ilo[k] { c } else { ilo[k] };
                }
            }
        }
        let mut rows = Self {
            outer: [false; TILE_PX],
            inner: [false; TILE_PX],
            spans: [[0.0; 4]; TILE_PX],
        };
        for k in 0..TILE_PX {
            // Missed where the bounds cross (as `spans`: a NaN bound is not a miss).
            let crossed = olo[k] > ohi[k];
            rows.outer[k] = !miss[k] && !crossed;
            rows.inner[k] = ilo[k] <= ihi[k];
            rows.spans[k] = [
                first(olo[k] * sx),
                last(ohi[k] * sx),
                first(ilo[k] * sx),
                last(ihi[k] * sx),
            ];
        }
        rows
    }
}

#[inline(always)]
fn blend_tile_inner<const ROUND: bool>(
    input: &BlendInput,
    lists: &TileLists,
    width: usize,
    height: usize,
    t: usize,
) -> Vec<Rgba> {
    let BlendInput {
        fragments,
        norms,
        shape,
        group_px,
        merge,
    } = *input;
    let (tx, ty) = (t % lists.tiles_x, t / lists.tiles_x);
    let x0 = tx * TILE_PX;
    let y0 = ty * TILE_PX;
    let x1 = (x0 + TILE_PX).min(width);
    let y1 = (y0 + TILE_PX).min(height);
    let tw = x1 - x0;
    let mut st = TileState::new(tw, y1 - y0);
    let mut batch_coc = f32::NAN;
    for &(_, idx) in &lists.entries[lists.offsets[t]..lists.offsets[t + 1]] {
        let f = &fragments[idx as usize];
        // The list is in depth (CoC) order: a fragment beyond the batch's CoC range
        // opens the next surface.
        let same_surface = (f.coc_px - batch_coc).abs() <= group_px;
        if !same_surface {
            st.flush();
            if st.open == 0 {
                break;
            }
            batch_coc = f.coc_px;
        }
        let centre = f.centre();
        let soft = f.soft_px(merge);
        let reach = reach_px(f.coc_px, soft, shape.stretch());
        let py0 = (floor_r::<ROUND>(centre.y - reach).max(y0 as f32) as usize).max(y0);
        let py1 = (ceil_r::<ROUND>(centre.y + reach).max(0.0) as usize + 1).min(y1);
        let bx0 = (floor_r::<ROUND>(centre.x - reach).max(x0 as f32) as usize).max(x0);
        let bx1 = (ceil_r::<ROUND>(centre.x + reach).max(0.0) as usize + 1).min(x1);
        if bx0 >= bx1 || py0 >= py1 {
            continue;
        }
        let col = f.rgba();
        let norm = norms[idx as usize];
        let wcol = col.map(|v| v * norm);
        let (bx0f, bx1f) = (bx0 as f32, bx1 as f32);
        let first = |lo: f32| first_px::<ROUND>(centre.x, lo, (bx0f, bx1f)) as usize;
        let last = |hi: f32| end_px::<ROUND>(centre.x, hi, (bx0f, bx1f)) as usize;
        let fp = Footprint::new(shape, f.coc_px, soft);
        // A footprint that covers the tile's four corner pixels at full coverage covers all its
        // pixels so (the disc and the polygons are convex): added once, not row by row.
        if bx0 == x0 && bx1 == x1 && py0 == y0 && py1 == y1 && fp.convex() {
            let corners = [(x0, y0), (x1 - 1, y0), (x0, y1 - 1), (x1 - 1, y1 - 1)];
            let inside = corners.iter().all(|&(x, y)| {
                let d = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - centre;
                fp.coverage(d.x, d.y) >= 1.0
            });
            if inside {
                st.cover(&wcol);
                continue;
            }
        }
        // The spans of every row of the tile at once (see `RowSpans`); curved blades and image
        // apertures row by row.
        let rows = match shape.kind {
            ShapeKind::Disc => Some(RowSpans::disc::<ROUND>(&fp, centre, y0, (bx0f, bx1f))),
            ShapeKind::Polygon { .. } if fp.blades > 0 => {
                Some(RowSpans::polygon::<ROUND>(&fp, centre, y0, (bx0f, bx1f)))
            }
            _ => None,
        };
        for py in py0..py1 {
            let dy = py as f32 + 0.5 - centre.y;
            let row = py - y0;
            let (outer, inner) = match &rows {
                Some(d) => {
                    if !d.outer[row] {
                        continue;
                    }
                    let [a, b, c, e] = d.spans[row];
                    (
                        (a as usize, b as usize),
                        d.inner[row].then_some((c as usize, e as usize)),
                    )
                }
                None => {
                    let Some((outer, inner)) = fp.spans(dy) else {
                        continue;
                    };
                    (
                        outer.map_or((bx0, bx1), |(lo, hi)| (first(lo), last(hi))),
                        inner.map(|(lo, hi)| (first(lo), last(hi))),
                    )
                }
            };
            let (ox0, ox1) = outer;
            if ox0 >= ox1 {
                continue;
            }
            let (ix0, ix1) = match inner {
                Some((a, b)) => {
                    let (a, b) = (a.max(ox0), b.min(ox1));
                    if a < b {
                        (a, b)
                    } else {
                        (ox0, ox0)
                    }
                }
                None => (ox0, ox0),
            };
            st.touch(ox0 - x0, ox1 - x0, row);
            let edge_row = &mut st.edge[row * tw..(row + 1) * tw];
            if ix0 < ix1 {
                let base = row * (tw + 1);
                let (a, b) = (base + ix0 - x0, base + ix1 - x0);
                for (k, v) in wcol.iter().enumerate() {
                    st.diff[a][k] += v;
                    st.diff[b][k] -= v;
                }
                for px in (ox0..ix0).chain(ix1..ox1) {
                    let cov = fp.coverage(px as f32 + 0.5 - centre.x, dy);
                    let e = &mut edge_row[px - x0];
                    for k in 0..4 {
                        e[k] += cov * wcol[k];
                    }
                }
            } else {
                for px in ox0..ox1 {
                    let cov = fp.coverage(px as f32 + 0.5 - centre.x, dy);
                    let e = &mut edge_row[px - x0];
                    for k in 0..4 {
                        e[k] += cov * wcol[k];
                    }
                }
            }
        }
    }
    st.flush();
    st.out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lens::LensEffects;
    use crate::random::SplitMix64;

    /// The spans of one row as the blend worked them out before `RowSpans`: `Footprint::spans`,
    /// then rounded to the pixels inside, clamped to the fragment's box.
    fn row_by_row<const ROUND: bool>(
        fp: &Footprint,
        centre: Vec2,
        py: usize,
        (b0, b1): (f32, f32),
    ) -> Option<([f32; 2], Option<[f32; 2]>)> {
        let dy = py as f32 + 0.5 - centre.y;
        let (outer, inner) = fp.spans(dy)?;
        let first = |lo: f32| first_px::<ROUND>(centre.x, lo, (b0, b1));
        let last = |hi: f32| end_px::<ROUND>(centre.x, hi, (b0, b1));
        let (lo, hi) = outer.expect("a disc or polygon has an outer span");
        Some((
            [first(lo), last(hi)],
            inner.map(|(a, b)| [first(a), last(b)]),
        ))
    }

    fn check<const ROUND: bool>() {
        let mut rng = SplitMix64::new(7);
        let polygon = |blades, rotation_rad| Aperture::Polygon {
            blades,
            rotation_rad,
            blade_radius: None,
        };
        let apertures = [
            Aperture::Disc,
            polygon(5, 0.3),
            polygon(6, 0.0),
            polygon(4, 0.0),
            polygon(4, std::f32::consts::FRAC_PI_4),
        ];
        for (aperture, aspect) in apertures
            .iter()
            .flat_map(|a| [1.0, 0.5, 1.7].map(|s| (a, s)))
        {
            let effects = LensEffects {
                aspect,
                ..LensEffects::default()
            };
            let shape = Shape::new(aperture).with_effects(&effects);
            for _ in 0..400 {
                // Radii from in focus to a wide blur, soft edges of one pixel or a merged block,
                // centres on pixel centres and corners near and across the tile.
                let c = draw_radius((rng.next_f32() - 0.5) * 80.0);
                let soft = [1.0, 2.0, 4.0][(rng.next_u64() % 3) as usize];
                let y0 = 16 * (rng.next_u64() % 8) as usize;
                let half = |v: f32| (v * 2.0).round() * 0.5;
                let centre = Vec2::new(
                    half(64.0 + (rng.next_f32() - 0.5) * 90.0),
                    half(y0 as f32 + 8.0 + (rng.next_f32() - 0.5) * 90.0),
                );
                let b = (48.0, 64.0);
                let fp = Footprint::new(&shape, c, soft);
                let rows = match aperture {
                    Aperture::Disc => RowSpans::disc::<ROUND>(&fp, centre, y0, b),
                    _ => RowSpans::polygon::<ROUND>(&fp, centre, y0, b),
                };
                for k in 0..TILE_PX {
                    let want = row_by_row::<ROUND>(&fp, centre, y0 + k, b);
                    let at = format!("{aperture:?} aspect {aspect} c {c} soft {soft} row {k}");
                    assert_eq!(rows.outer[k], want.is_some(), "{at}");
                    let Some((outer, inner)) = want else { continue };
                    let s = rows.spans[k];
                    assert_eq!([s[0], s[1]], outer, "{at}");
                    assert_eq!(rows.inner[k], inner.is_some(), "{at}");
                    if let Some(inner) = inner {
                        assert_eq!([s[2], s[3]], inner, "{at}");
                    }
                }
            }
        }
    }

    #[test]
    fn row_spans_give_each_rows_spans_bit_for_bit() {
        check::<true>();
        check::<false>();
    }
}
