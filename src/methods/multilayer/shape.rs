//! Pass `accumulate` with bokeh in the shape of the [`Aperture`] (`--ml-bokeh shape`; not in the
//! paper, whose levels are box filters, so a small bright light far behind focus becomes a
//! square).
//!
//! A fragment at pinhole pixel `q` with signed CoC `C` is seen at `q + C v` for every lens point
//! `v` of the unit aperture, so pixel `p` gathers it when `(p - q) / C` lies in the aperture (a
//! far-field bokeh shows the aperture as defined, a near-field one turned 180 degrees, as
//! `reference` and `splat`). The levels already hold the scene box-filtered at every power of
//! two, so the gather need not visit every pixel of the disc:
//!
//! 1. Each fragment is served by the one level `S >= 1` whose box is between `1/(2 rho)` and
//!    `1/rho` of its CoC radius (`rho` = [`MIN_RADIUS_CELLS`]): level S serves
//!    `rho 2^S <= |C| < rho 2^(S+1)`, the top level every larger CoC. Pixel `p` reads the level's
//!    cells on the grid `q = p - 2^S (i, j)`: the boxes of those cells tile the plane, so each
//!    fragment near `p` is read once. At least `pi rho^2` cells fall inside the smallest bokeh a
//!    level serves.
//! 2. A fragment read from the cell at offset `d = 2^S (i, j)` is weighted by the aperture's
//!    coverage of `(d - s) / C`, `s` being where its energy lies in its cell
//!    ([`Level::centroid`]), with an edge one cell wide (the signed distance to the disc's or the
//!    polygon's edge, the same test as `splat`; curved blades and image apertures use their
//!    density), divided by the summed coverage of the whole grid at that CoC, tabulated once
//!    (`norm`): a point light keeps its energy to within 2%, sits where it is in the cell, and
//!    the weight changes continuously with depth.
//! 3. CoCs below `rho 2^1` pixels (at most a few pixels across, where shape and box differ by a
//!    pixel or two) are taken from the levels as in the paper ([`super::accumulate()`]): one cell
//!    per level, the two levels around the CoC blended to the disc's variance.
//! 4. A pixel only walks the grid of a level where some fragment the level serves can reach it:
//!    per level, 8x8-pixel tiles hold the largest CoC radius of the fragments within reach,
//!    which also bounds the radius of the walk.
//!
//! The gather is worked out per cell of the level (every cell, or every `gather_step`-th on
//! coarse levels) and each pixel reads the four gathered cells around its centre, weighted
//! bilinearly, so that the bokeh's edge is placed to within a pixel rather than on the grid of
//! cells. The fragments gathered at a pixel are then blended as in the box accumulation: those of
//! one cell within the depth threshold of each other are combined with the over operator (one
//! list occludes itself), all are sorted by depth, those within the depth threshold of each other
//! are summed (side by side, from different cells or levels) and the sums are blended front to
//! back with the over operator.

use glam::Vec2;
use rayon::prelude::*;

use super::accumulate::{level_weight, Region};
use super::filter::Level;
use super::{Borders, BoxRead};
use crate::image::{ColorImage, Rgba};
use crate::lens::Aperture;
use crate::raster::{from_half, par_concat, par_offsets};

/// `rho`: the smallest CoC radius, in cells of its level's box, that a level gathers in the
/// aperture's shape; level S serves radii from `rho 2^S` to `rho 2^(S+1)` pixels. Measured on
/// the built-in scenes at 640x360 against `reference` (README, "Bokeh shape"): 1.5 draws a
/// 6-blade bokeh of 14 px as a blocky cross (26.4 dB on `lights`), 2 loses 0.6 dB on `glass`,
/// 2.5 and 3 give the same images there, and 3 reads up to 1.6 times as many cells.
pub const MIN_RADIUS_CELLS: f32 = 2.5;

/// The first level gathered in the shape by default, [`super::Bokeh::Shape`] (level 0's box is
/// one pixel: CoCs it would serve are at most a few pixels across). [`super::Bokeh::Full`]
/// gathers from level 0.
pub const FIRST_SHAPE_LEVEL: usize = 1;

/// Side in pixels of the tiles that record which levels can reach a pixel.
pub const TILE_PX: usize = 8;

/// Width in cells of the ramp of the aperture's edge (coverage from 1 to 0), so that the weights
/// change continuously with the CoC. Half a cell, which blurs less, drew a 42 px disc with 0.82
/// IoU against `reference`'s instead of 0.85 (the steps between cells show).
const EDGE_CELLS: f32 = 1.0;

/// How far, in cells, a fragment's energy can lie from its cell's centre: half the box along
/// each axis ([`Level::centroid`]).
const MAX_SHIFT_CELLS: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// Steps per cell of the tabulated grid sums.
const NORM_STEPS_PER_CELL: f32 = 64.0;

/// The CoC radius in pixels from which fragments are gathered in the shape when the gather
/// starts at level `first`; smaller ones are taken from the box levels.
#[inline]
pub fn shape_threshold_px(first: usize) -> f32 {
    band_px(first, usize::MAX, first).0
}

/// The smallest CoC radius in pixels gathered in the shape (a bokeh 9 pixels across; level 1
/// then has at least 2.25 cells of radius). Below it the box levels are closer to `reference`:
/// from 3 px the gather's coarse grid cost `railing` 0.5 dB at 640x360 (its far wall has a
/// CoC of 3.2 px).
pub const SHAPE_FROM_PX: f32 = 4.5;

/// The range of CoC radii `[lo, hi)` in pixels that level `s` of `levels` serves, the gather
/// starting at level `first`.
#[inline]
pub fn band_px(s: usize, levels: usize, first: usize) -> (f32, f32) {
    let lo = MIN_RADIUS_CELLS * (1u64 << s) as f32;
    let hi = if s + 1 >= levels {
        f32::INFINITY
    } else {
        2.0 * lo
    };
    let lo = if s == first {
        SHAPE_FROM_PX.min(lo)
    } else {
        lo
    };
    (lo, hi)
}

/// The number of levels the shape accumulation needs for a largest CoC radius of `max_coc_px`:
/// the first shape level (`first`, at least 1), and enough levels that the top one's box is at
/// least `1/(2 rho)` of it (larger CoCs are served by the top level with more cells).
pub fn levels_needed(max_coc_px: f32, first: usize) -> usize {
    let mut s = first.max(FIRST_SHAPE_LEVEL);
    while band_px(s, usize::MAX, first).1 <= max_coc_px && s < super::MAX_FILTER_STEPS {
        s += 1;
    }
    s + 1
}

/// How the aperture's edge is tested.
#[derive(Clone, Debug)]
enum Edge {
    /// Disc and straight-bladed polygons: signed distance to the edge, in units of the aperture
    /// radius along the outward edge normals (`apothem` from the centre; 1 for the disc).
    Distance { apothem: f32 },
    /// Curved blades and images: the density at `d / C`.
    Density(Aperture),
}

/// One cell offset `(i, j)` of the gather grid (in cells), with what its coverage needs.
#[derive(Clone, Copy, Debug)]
struct Offset {
    i: i32,
    j: i32,
    /// `|(i, j)|`.
    r: f32,
    /// Disc and polygon: the largest `n_k . (i, j)` over the edge normals (far field), and of
    /// `n_k . -(i, j)` (near field, the bokeh turned 180 degrees).
    far: f32,
    near: f32,
    /// The normals that give `far` and `near` (the disc: `(i, j) / r` and its opposite; zero at
    /// the centre): how they change when the fragment sits off its cell's centre.
    far_normal: Vec2,
    near_normal: Vec2,
    /// The runners-up of polygons: the second largest `n_k . (i, j)` and `n_k . -(i, j)` and
    /// their normals (the disc: the same as the first), so that a shift toward a corner is
    /// measured against both of its edges.
    far2: f32,
    near2: f32,
    far_normal2: Vec2,
    near_normal2: Vec2,
}

/// The aperture prepared for the gather: the cell offsets sorted by distance and the grid's
/// summed coverage as a function of the CoC radius in cells.
#[derive(Clone, Debug)]
pub struct GatherShape {
    edge: Edge,
    /// How far the shape reaches, in units of the aperture radius (1, or `sqrt 2` for images).
    extent: f32,
    offsets: Vec<Offset>,
    /// `1 / (summed coverage)` at CoC radius `k / NORM_STEPS_PER_CELL` cells.
    norm: Vec<f32>,
}

impl GatherShape {
    /// Prepares `aperture` for CoC radii up to `max_cells` cells of a level.
    pub fn new(aperture: &Aperture, max_cells: f32) -> Self {
        let (edge, normals) = match aperture {
            Aperture::Disc => (Edge::Distance { apothem: 1.0 }, Vec::new()),
            Aperture::Polygon {
                blade_radius: None, ..
            } => {
                let v = aperture.vertices();
                let n = v.len();
                let mids: Vec<Vec2> = (0..n).map(|k| (v[k] + v[(k + 1) % n]) * 0.5).collect();
                let apothem = mids[0].length();
                let normals = mids.iter().map(|m| m.normalize()).collect();
                (Edge::Distance { apothem }, normals)
            }
            other => (Edge::Density(other.clone()), Vec::new()),
        };
        let extent = if matches!(aperture, Aperture::Image(_)) {
            std::f32::consts::SQRT_2
        } else {
            1.0
        };
        let mut shape = Self {
            edge,
            extent,
            offsets: Vec::new(),
            norm: Vec::new(),
        };
        let max_cells = max_cells.max(1.0);
        let n = shape.reach_cells(max_cells).ceil() as i32 + 1;
        for j in -n..=n {
            for i in -n..=n {
                let d = Vec2::new(i as f32, j as f32);
                // The two largest `n_k . v` and their normals, the first found kept on ties.
                let best2 = |v: Vec2| {
                    let mut top = [(f32::MIN, Vec2::ZERO); 2];
                    for nk in &normals {
                        let x = nk.dot(v);
                        if x > top[0].0 {
                            top = [(x, *nk), top[0]];
                        } else if x > top[1].0 {
                            top[1] = (x, *nk);
                        }
                    }
                    top
                };
                let ([far, far2], [near, near2]) = if normals.is_empty() {
                    let n = d.normalize_or_zero();
                    let r = d.length();
                    ([(r, n); 2], [(r, -n); 2])
                } else {
                    (best2(d), best2(-d))
                };
                shape.offsets.push(Offset {
                    i,
                    j,
                    r: d.length(),
                    far: far.0,
                    near: near.0,
                    far_normal: far.1,
                    near_normal: near.1,
                    far2: far2.0,
                    near2: near2.0,
                    far_normal2: far2.1,
                    near_normal2: near2.1,
                });
            }
        }
        // By distance, then row, then column: a fixed order, the same on every machine.
        shape
            .offsets
            .sort_by(|a, b| a.r.total_cmp(&b.r).then(a.j.cmp(&b.j)).then(a.i.cmp(&b.i)));
        let steps = (max_cells * NORM_STEPS_PER_CELL).ceil() as usize + 2;
        shape.norm = (0..steps)
            .map(|k| {
                let t = k as f32 / NORM_STEPS_PER_CELL;
                let sum = shape.grid_sum(t);
                if sum > 0.0 {
                    1.0 / sum
                } else {
                    0.0
                }
            })
            .collect();
        shape
    }

    /// The distance in cells beyond which no cell is covered at CoC radius `t` cells (by a
    /// fragment anywhere in its cell).
    #[inline]
    fn reach_cells(&self, t: f32) -> f32 {
        match self.edge {
            Edge::Distance { apothem } => t + 0.5 * EDGE_CELLS / apothem + MAX_SHIFT_CELLS,
            Edge::Density(_) => t * self.extent + 0.5 + MAX_SHIFT_CELLS,
        }
    }

    /// Coverage of offset `o` by a fragment of CoC radius `t` cells, behind focus (`far`) or in
    /// front of it, whose energy lies `shift` cells from its cell's centre. The gathering cell
    /// sees it at `(i, j) - shift`; the edge distance is the larger of the two edges nearest
    /// `(i, j)`, each moved by `shift` along its normal: exact for polygons of up to 8 blades
    /// wherever the coverage is not 1 (a third edge cannot overtake them within a shift of
    /// `MAX_SHIFT_CELLS` at the radii a level serves), and for the disc (the distance moved
    /// along `(i, j) / r`) off by at most `|shift|^2 / (2 r)`, at most 0.11 cells.
    #[inline(always)]
    fn coverage(&self, o: &Offset, t: f32, far: bool, shift: [f32; 2]) -> f32 {
        match &self.edge {
            Edge::Distance { apothem } => {
                let along = |n: Vec2| n.x * shift[0] + n.y * shift[1];
                let m = if far {
                    (o.far - along(o.far_normal)).max(o.far2 - along(o.far_normal2))
                } else {
                    (o.near + along(o.near_normal)).max(o.near2 + along(o.near_normal2))
                };
                (0.5 - (m - apothem * t) * (1.0 / EDGE_CELLS)).clamp(0.0, 1.0)
            }
            Edge::Density(a) => {
                let v = Vec2::new(o.i as f32 - shift[0], o.j as f32 - shift[1]) / t;
                a.density(if far { v } else { -v })
            }
        }
    }

    /// Summed coverage of the whole grid at CoC radius `t` cells (the same in front of focus:
    /// the grid is symmetric).
    fn grid_sum(&self, t: f32) -> f32 {
        if t <= 0.0 {
            return 0.0;
        }
        let reach = self.reach_cells(t);
        self.offsets
            .iter()
            .take_while(|o| o.r <= reach)
            .map(|o| self.coverage(o, t, true, [0.0; 2]))
            .sum()
    }

    /// `1 / (summed coverage)` at CoC radius `t` cells, interpolated in the table (computed
    /// directly beyond it).
    #[inline(always)]
    fn norm(&self, t: f32) -> f32 {
        let x = t * NORM_STEPS_PER_CELL;
        let k = x as usize;
        if k + 1 < self.norm.len() {
            let f = x - k as f32;
            return (1.0 - f) * self.norm[k] + f * self.norm[k + 1];
        }
        let sum = self.grid_sum(t);
        if sum > 0.0 {
            1.0 / sum
        } else {
            0.0
        }
    }
}

/// Per level gathered in the shape: which tiles some fragment it serves can reach, and the
/// largest CoC radius there.
#[derive(Clone, Debug)]
struct Reach {
    /// Largest CoC radius in pixels of the level's fragments that can reach each tile (0:
    /// none).
    tiles: Vec<f32>,
    tiles_x: usize,
}

/// One fragment of a level's band: what the gather reads of it, side by side (one cache line
/// holds it, where separate arrays took one line each).
#[derive(Clone, Copy, Debug, Default)]
struct BandFragment {
    /// CoC radius in cells, and the normalisation of the gather grid at that radius: worked
    /// out once per fragment, not once per cell that reads it.
    t: f32,
    norm: f32,
    /// Where the fragment's energy lies, in cells from its cell's centre.
    shift: [f32; 2],
    /// Signed CoC in pixels.
    coc: f32,
    depth: f32,
    /// Full-precision colour.
    color: Rgba,
}

/// The fragments of a level with CoC radius in the level's band: what the gather reads.
#[derive(Clone, Debug, Default)]
struct BandLevel {
    offsets: Vec<u32>,
    fragments: Vec<BandFragment>,
}

impl BandLevel {
    /// The fragments of `level` with CoC radius in `[lo, hi)`.
    fn new(level: &Level, borders: &Borders, shape: &GatherShape, (lo, hi): (f32, f32)) -> Self {
        let rows: Vec<(Vec<u32>, Vec<BandFragment>)> = (0..level.height)
            .into_par_iter()
            .map(|cy| {
                let mut counts = Vec::with_capacity(level.width);
                let mut b = Vec::new();
                let inv_b = 1.0 / level.footprint_px;
                for cx in 0..level.width {
                    let (depths, colors) = level.cell(cx, cy);
                    let centroids = level.cell_centroids(cx, cy);
                    let before = b.len();
                    for (k, (&z, c)) in depths.iter().zip(colors).enumerate() {
                        let coc = borders.lens.coc_px(z);
                        let r = coc.abs();
                        if r >= lo && r < hi {
                            let at = centroids.get(k).copied().unwrap_or([0.0; 2]);
                            b.push(BandFragment {
                                t: r * inv_b,
                                norm: shape.norm(r * inv_b),
                                shift: [at[0] * inv_b, at[1] * inv_b],
                                coc,
                                depth: z,
                                color: from_half(c),
                            });
                        }
                    }
                    counts.push((b.len() - before) as u32);
                }
                (counts, b)
            })
            .collect();
        BandLevel {
            offsets: par_offsets(&rows.iter().map(|r| &r.0[..]).collect::<Vec<_>>()),
            fragments: par_concat(&rows.iter().map(|r| &r.1[..]).collect::<Vec<_>>()),
        }
    }
}

/// The largest CoC radius in pixels, per tile of `tiles_x` x `tiles_y`, of the fragments of
/// `band` (on the cells of `level`) that can reach a pixel of the tile.
fn reach_of(
    level: &Level,
    band: &BandLevel,
    shape: &GatherShape,
    (tiles_x, tiles_y): (usize, usize),
) -> Option<Reach> {
    if band.fragments.is_empty() {
        return None;
    }
    let tile = TILE_PX as f32;
    let tile_of = |p: f32, n: usize| ((p / tile).max(0.0) as usize).min(n - 1);
    let rows: Vec<Vec<(usize, f32)>> = (0..level.height)
        .into_par_iter()
        .map(|cy| {
            let ty = tile_of(level.origin_px + level.stride_px * cy as f32, tiles_y);
            let mut found = Vec::new();
            for cx in 0..level.width {
                let i = cy * level.width + cx;
                let (a, e) = (band.offsets[i] as usize, band.offsets[i + 1] as usize);
                let m = band.fragments[a..e]
                    .iter()
                    .fold(0.0f32, |m, f| m.max(f.coc.abs()));
                if m > 0.0 {
                    let tx = tile_of(level.origin_px + level.stride_px * cx as f32, tiles_x);
                    found.push((ty * tiles_x + tx, m));
                }
            }
            found
        })
        .collect();
    let mut src = vec![0.0f32; tiles_x * tiles_y];
    let mut max_c = 0.0f32;
    for (t, m) in rows.into_iter().flatten() {
        src[t] = src[t].max(m);
        max_c = max_c.max(m);
    }
    if max_c <= 0.0 {
        return None;
    }
    // A fragment reaches `reach` pixels from its cell's centre, whose tile is found from its
    // centre (cells are up to a stride off the pixel that reads them).
    let b = level.footprint_px;
    let reach_px = shape.reach_cells(max_c / b) * b + level.stride_px + 1.0;
    let r = (reach_px / tile).ceil() as usize;
    // Separable square max filter of radius r tiles.
    let mut across = vec![0.0f32; src.len()];
    for ty in 0..tiles_y {
        for tx in 0..tiles_x {
            let (a, e) = (tx.saturating_sub(r), (tx + r).min(tiles_x - 1));
            across[ty * tiles_x + tx] = src[ty * tiles_x + a..=ty * tiles_x + e]
                .iter()
                .fold(0.0, |m: f32, &v| m.max(v));
        }
    }
    let mut tiles = vec![0.0f32; src.len()];
    for ty in 0..tiles_y {
        let (a, e) = (ty.saturating_sub(r), (ty + r).min(tiles_y - 1));
        for tx in 0..tiles_x {
            tiles[ty * tiles_x + tx] = (a..=e)
                .map(|k| across[k * tiles_x + tx])
                .fold(0.0, f32::max);
        }
    }
    Some(Reach { tiles, tiles_x })
}

/// A level gathered in the aperture's shape: per cell of its level, the fragments that reach
/// the pixels reading that cell, weighted, summed within the depth threshold, depth-sorted.
#[derive(Clone, Debug, Default)]
struct Gathered {
    offsets: Vec<u32>,
    depth: Vec<f32>,
    color: Vec<Rgba>,
    /// Only every `step`-th cell along each axis is gathered ([`gather_step`]).
    step: usize,
}

/// Gathered cells per box of a level, along each axis. The coverage changes over an edge ramp a
/// box wide ([`EDGE_CELLS`]), and pixels interpolate linearly between gathered cells, so levels
/// whose box spans more than two strides need not be gathered at every cell: at 1280x720 the
/// images of `lights`, `railing` and `traps` stay within 51-69 dB of gathering every cell (4 per
/// box gave the same), and `railing`'s gather takes 15% less.
const GATHER_SAMPLES_PER_BOX: f32 = 2.0;

/// Every how many cells of `level` its gather is computed. Level 0 (a box of one pixel, read
/// by [`super::Bokeh::Full`]) at every other pixel along each axis: its CoCs are at least 2.5 px
/// in radius, and the pixels between read the gathered ones bilinearly, as on the coarse levels
/// (a quarter of the cost of every pixel, for two thirds of its gain on `railing` at 640x360).
fn gather_step(level: &Level) -> usize {
    if level.footprint_px <= 1.0 {
        return 2;
    }
    ((level.footprint_px / (GATHER_SAMPLES_PER_BOX * level.stride_px)).floor() as usize).max(1)
}

/// What every cell row of a level's gather reads.
struct GatherInputs<'a> {
    level: &'a Level,
    /// The level's fragments in its band.
    band: &'a BandLevel,
    reach: &'a Reach,
    shape: &'a GatherShape,
    /// The first and last cell column read (others are left empty).
    columns: (usize, usize),
    /// Only columns that are multiples of it are gathered.
    step: usize,
    epsilon: f32,
}

/// One row of a level's gather: per cell the count, then the fragments.
type GatherRow = (Vec<u32>, Vec<f32>, Vec<Rgba>);

/// What every pixel row of the shape accumulation reads.
struct RowInputs<'a> {
    levels: &'a [Level],
    /// Per level from `first` (index `s - first`): its gather, if any fragment it serves is in
    /// view.
    gathered: &'a [Option<Gathered>],
    /// The first level gathered in the shape.
    first: usize,
    /// The box levels that serve CoCs below the shape threshold.
    box_levels: usize,
    /// Per box level, each fragment's weight there: 0 at or above the shape threshold, else
    /// its level weight (worked out once per fragment, not once per pixel that reads it).
    box_weights: &'a [Vec<f32>],
    /// How a pixel reads the box levels coarser than a pixel.
    box_read: BoxRead,
    epsilon: f32,
}

/// The row functions of the shape accumulation (run-time dispatched or baseline).
struct RowFns<G, P> {
    gather: G,
    pixels: P,
}

/// Blends the levels into the output image of `region` with bokeh in the shape of `aperture`
/// (premultiplied linear RGBA).
pub fn accumulate_shape(
    levels: &[Level],
    borders: &Borders,
    aperture: &Aperture,
    (epsilon, first, box_read): (f32, usize, BoxRead),
    region: Region,
) -> ColorImage {
    accumulate_shape_with(
        levels,
        borders,
        aperture,
        (epsilon, first, box_read),
        region,
        RowFns {
            gather: gather_row,
            pixels: shape_row,
        },
    )
}

/// [`accumulate_shape`] built for the portable baseline only (no run-time dispatch): the twin
/// the dispatched versions are tested against, bit for bit.
pub fn accumulate_shape_baseline(
    levels: &[Level],
    borders: &Borders,
    aperture: &Aperture,
    (epsilon, first, box_read): (f32, usize, BoxRead),
    region: Region,
) -> ColorImage {
    accumulate_shape_with(
        levels,
        borders,
        aperture,
        (epsilon, first, box_read),
        region,
        RowFns {
            gather: gather_row_inner,
            pixels: shape_row_inner,
        },
    )
}

fn accumulate_shape_with<G, P>(
    levels: &[Level],
    borders: &Borders,
    aperture: &Aperture,
    (epsilon, first, box_read): (f32, usize, BoxRead),
    region: Region,
    fns: RowFns<G, P>,
) -> ColorImage
where
    G: Fn(&GatherInputs, usize) -> GatherRow + Sync,
    P: Fn(&RowInputs, usize, usize, &mut [Rgba]) + Sync,
{
    let Region {
        x0,
        y0,
        width,
        height,
    } = region;
    let n = levels.len();
    let threshold_px = if n > first {
        shape_threshold_px(first)
    } else {
        f32::INFINITY
    };
    // Box levels with a weight for some CoC below the threshold.
    let box_levels = if threshold_px.is_finite() {
        let lambda = super::lambda_of_radius(threshold_px);
        (lambda.floor() as usize + 2).min(n)
    } else {
        n
    };
    // Tiles of the levels' whole frame: fragments outside the region gather into it.
    let tiles = (
        borders.lens.width_px.div_ceil(TILE_PX).max(1),
        borders.lens.height_px.div_ceil(TILE_PX).max(1),
    );
    // The largest CoC radius in cells any level is asked for: the top band's fragments.
    let max_coc = levels
        .last()
        .map(|l| l.depth.iter())
        .into_iter()
        .flatten()
        .map(|&z| borders.lens.coc_px(z).abs())
        .filter(|c| c.is_finite())
        .fold(0.0f32, f32::max);
    let top_cells = levels
        .last()
        .map_or(1.0, |l| max_coc / l.footprint_px)
        .max(2.0 * MIN_RADIUS_CELLS);
    let shape = GatherShape::new(aperture, top_cells);
    let gathered: Vec<Option<Gathered>> = (first..n)
        .map(|s| {
            let level = &levels[s];
            let band = BandLevel::new(level, borders, &shape, band_px(s, n, first));
            let reach = reach_of(level, &band, &shape, tiles)?;
            // Only the cells the region's pixels read are gathered (with the cells around
            // them, which they read between).
            let (cx0, cy0) = level.cell_of_pixel(x0, y0);
            let (cx1, cy1) = level.cell_of_pixel(x0 + width.max(1) - 1, y0 + height.max(1) - 1);
            let step = gather_step(level);
            let below = |c: usize| c / step * step;
            let above = |c: usize, n: usize| (c.div_ceil(step) * step).min(below(n - 1));
            let (cx0, cy0) = (below(cx0.saturating_sub(1)), below(cy0.saturating_sub(1)));
            let (cx1, cy1) = (above(cx1 + 1, level.width), above(cy1 + 1, level.height));
            let inputs = GatherInputs {
                level,
                band: &band,
                reach: &reach,
                shape: &shape,
                columns: (cx0, cx1),
                step,
                epsilon,
            };
            let rows: Vec<GatherRow> = (0..level.height)
                .into_par_iter()
                .map(|cy| {
                    if (cy0..=cy1).contains(&cy) && cy % step == 0 {
                        (fns.gather)(&inputs, cy)
                    } else {
                        (vec![0; level.width], Vec::new(), Vec::new())
                    }
                })
                .collect();
            Some(Gathered {
                offsets: par_offsets(&rows.iter().map(|r| &r.0[..]).collect::<Vec<_>>()),
                depth: par_concat(&rows.iter().map(|r| &r.1[..]).collect::<Vec<_>>()),
                color: par_concat(&rows.iter().map(|r| &r.2[..]).collect::<Vec<_>>()),
                step,
            })
        })
        .collect();
    // Worked out only for the rows of cells the region reads (the guard band's rows above and
    // below it are never read at a pixel).
    let box_weights: Vec<Vec<f32>> = levels
        .iter()
        .take(box_levels)
        .enumerate()
        .map(|(s, level)| {
            let (_, cy0) = level.cell_of_pixel(x0, y0);
            let (_, cy1) = level.cell_of_pixel(x0, y0 + height.max(1) - 1);
            let a = level.offsets[cy0 * level.width] as usize;
            let e = level.offsets[(cy1 + 1) * level.width] as usize;
            let mut weights = vec![0.0f32; level.depth.len()];
            weights[a..e]
                .par_iter_mut()
                .zip(level.depth[a..e].par_iter())
                .for_each(|(w, &z)| {
                    let r = borders.lens.coc_px(z).abs();
                    if r < threshold_px {
                        *w = level_weight(super::lambda_of_radius(r), s, n);
                    }
                });
            weights
        })
        .collect();
    let inputs = RowInputs {
        levels,
        gathered: &gathered,
        first,
        box_levels,
        box_weights: &box_weights,
        box_read,
        epsilon,
    };
    let mut data = vec![[0.0f32; 4]; width * height];
    data.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, row)| (fns.pixels)(&inputs, x0, y0 + y, row));
    ColorImage::from_vec(width, height, data).expect("sizes agree by construction")
}

/// Fragments of one cell list, combined with the over operator while they lie within the
/// depth threshold of the first (one list occludes itself), then pushed as one weighted entry.
struct Run {
    depth_m: f32,
    limit_m: f32,
    p: [f32; 4],
    transmit: f32,
    open: bool,
}

impl Run {
    #[inline(always)]
    fn new() -> Self {
        Self {
            depth_m: 0.0,
            limit_m: 0.0,
            p: [0.0; 4],
            transmit: 1.0,
            open: false,
        }
    }

    #[inline(always)]
    fn add(&mut self, z: f32, weight: f32, c: Rgba, epsilon: f32, out: &mut Vec<(f32, Rgba)>) {
        if self.open && z > self.limit_m {
            self.flush(out);
        }
        if !self.open {
            *self = Self {
                depth_m: z,
                limit_m: z + epsilon * z.abs(),
                p: [0.0; 4],
                transmit: 1.0,
                open: true,
            };
        }
        for (pk, ck) in self.p.iter_mut().zip(c) {
            *pk += self.transmit * weight * ck;
        }
        self.transmit *= 1.0 - c[3];
    }

    #[inline(always)]
    fn flush(&mut self, out: &mut Vec<(f32, Rgba)>) {
        if self.open && self.p[3] > 0.0 {
            out.push((self.depth_m, self.p));
        }
        self.open = false;
    }
}

/// Fragments of one surface gathered for one cell: summed, with their opacity-weighted depth.
struct Group {
    first_m: f32,
    limit_m: f32,
    p: Rgba,
    dw: f32,
    ds: f32,
}

impl Group {
    #[inline(always)]
    fn new(z: f32, c: Rgba, epsilon: f32) -> Self {
        Self {
            first_m: z,
            limit_m: z + epsilon * z.abs(),
            p: c,
            dw: c[3],
            ds: c[3] * z,
        }
    }

    #[inline(always)]
    fn add(&mut self, z: f32, c: Rgba) {
        for (pk, ck) in self.p.iter_mut().zip(c) {
            *pk += ck;
        }
        self.dw += c[3];
        self.ds += c[3] * z;
    }
}

/// Adds a weighted fragment to the surface within the depth threshold of it, or opens one.
#[inline(always)]
fn add_to_groups(groups: &mut Vec<Group>, z: f32, p: Rgba, epsilon: f32) {
    match groups
        .iter_mut()
        .find(|g| z <= g.limit_m && z * (1.0 + epsilon) >= g.first_m)
    {
        Some(g) => g.add(z, p),
        None => groups.push(Group::new(z, p, epsilon)),
    }
}

/// One cell row of a level's gather, compiled for several instruction sets and chosen at run
/// time ([`multiversion`]); the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn gather_row(inputs: &GatherInputs, cy: usize) -> GatherRow {
    gather_row_inner(inputs, cy)
}

#[inline(always)]
fn gather_row_inner(inputs: &GatherInputs, cy: usize) -> GatherRow {
    let GatherInputs {
        level,
        band,
        reach,
        shape,
        columns,
        step,
        epsilon,
    } = *inputs;
    let (w, h) = (level.width as isize, level.height as isize);
    let b = level.footprint_px;
    let inv_b = 1.0 / b;
    // Grid offsets are whole boxes: `k` cells of the level.
    let k = ((b / level.stride_px).round() as isize).max(1);
    let tile_of = |c: usize, n: usize| {
        (((level.origin_px + level.stride_px * c as f32) / TILE_PX as f32).max(0.0) as usize)
            .min(n - 1)
    };
    let tiles_y = reach.tiles.len() / reach.tiles_x;
    let ty = tile_of(cy, tiles_y);
    // How far in memory the cell at each offset lies behind the gathering one.
    let deltas: Vec<isize> = shape
        .offsets
        .iter()
        .map(|o| k * (o.j as isize * w + o.i as isize))
        .collect();
    let mut counts = Vec::with_capacity(level.width);
    let mut depth = Vec::new();
    let mut color = Vec::new();
    let mut entries: Vec<(f32, Rgba)> = Vec::new();
    let mut groups: Vec<Group> = Vec::new();
    for cx in 0..level.width {
        let r_px = reach.tiles[ty * reach.tiles_x + tile_of(cx, reach.tiles_x)];
        if r_px <= 0.0 || cx < columns.0 || cx > columns.1 || cx % step != 0 {
            counts.push(0);
            continue;
        }
        groups.clear();
        let limit = shape.reach_cells(r_px * inv_b);
        // Away from the level's edges no offset within the limit leaves it: each cell is read
        // at a fixed distance in memory from this one, without clamping.
        let n = k * limit as isize;
        let (x, y) = (cx as isize, cy as isize);
        let inside = x >= n && x + n < w && y >= n && y + n < h;
        let centre = y * w + x;
        for (o, &delta) in shape
            .offsets
            .iter()
            .zip(&deltas)
            .take_while(|(o, _)| o.r <= limit)
        {
            let i = if inside {
                (centre - delta) as usize
            } else {
                let sx = (x - k * o.i as isize).clamp(0, w - 1) as usize;
                let sy = (y - k * o.j as isize).clamp(0, h - 1) as usize;
                sy * level.width + sx
            };
            let (a, e) = (band.offsets[i] as usize, band.offsets[i + 1] as usize);
            if e == a {
                continue;
            }
            if e == a + 1 {
                // One fragment (the usual case): straight into its surface.
                let f = &band.fragments[a];
                let cover = shape.coverage(o, f.t, f.coc > 0.0, f.shift);
                if cover > 0.0 {
                    let weight = cover * f.norm;
                    let p = f.color.map(|v| v * weight);
                    add_to_groups(&mut groups, f.depth, p, epsilon);
                }
                continue;
            }
            entries.clear();
            let mut run = Run::new();
            for f in &band.fragments[a..e] {
                let cover = shape.coverage(o, f.t, f.coc > 0.0, f.shift);
                if cover > 0.0 {
                    run.add(f.depth, cover * f.norm, f.color, epsilon, &mut entries);
                }
            }
            run.flush(&mut entries);
            for &(z, p) in &entries {
                add_to_groups(&mut groups, z, p, epsilon);
            }
        }
        groups.sort_by(|a, b| a.first_m.total_cmp(&b.first_m));
        let before = depth.len();
        for g in &groups {
            depth.push(if g.dw > 0.0 { g.ds / g.dw } else { g.first_m });
            color.push(g.p);
        }
        counts.push((depth.len() - before) as u32);
    }
    (counts, depth, color)
}

/// One pixel row of [`accumulate_shape`], compiled for several instruction sets and chosen at
/// run time ([`multiversion`]); the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn shape_row(inputs: &RowInputs, x0: usize, y: usize, row: &mut [Rgba]) {
    shape_row_inner(inputs, x0, y, row);
}

#[inline(always)]
fn shape_row_inner(inputs: &RowInputs, x0: usize, y: usize, row: &mut [Rgba]) {
    let RowInputs {
        levels,
        gathered,
        first,
        box_levels,
        box_weights,
        box_read,
        epsilon,
    } = *inputs;
    let mut entries: Vec<(f32, Rgba)> = Vec::new();
    // Bilinear box reads: per box level coarser than a pixel, its reads along the row ([`None`]:
    // the nearest cell).
    let mut box_between: Vec<Option<Between>> = levels
        .iter()
        .take(box_levels)
        .map(|level| {
            (box_read == BoxRead::Bilinear && level.stride_px > 1.0)
                .then(|| Between::new(level, &level.offsets, y, 1))
        })
        .collect();
    // The gathered levels' reads along the row.
    let mut gathered_between: Vec<Option<Between>> = gathered
        .iter()
        .zip(&levels[first..])
        .map(|(g, level)| {
            g.as_ref()
                .map(|g| Between::new(level, &g.offsets, y, g.step))
        })
        .collect();
    for (x, out) in (x0..).zip(row.iter_mut()) {
        entries.clear();
        // CoCs below the threshold: one cell per level, as the paper, or the four around the
        // pixel's centre weighted bilinearly ([`BoxRead`]).
        for ((level, weights), between) in levels
            .iter()
            .take(box_levels)
            .zip(box_weights)
            .zip(&mut box_between)
        {
            let cell = |i: usize, out: &mut Vec<(f32, Rgba)>| {
                cell_runs(level, weights, i, epsilon, out);
            };
            match between {
                Some(between) => between.read(level, x, epsilon, &mut entries, cell),
                None => {
                    let (cx, cy) = level.cell_of_pixel(x, y);
                    cell(cy * level.width + cx, &mut entries);
                }
            }
        }
        // Larger CoCs: the gathers of the four cells around the pixel's centre on their
        // level, weighted bilinearly (a cell's gather is exact at its centre; the pixel reads
        // between them rather than taking the nearest, which would draw the bokeh's corners on
        // the level's grid of cells).
        for ((g, level), between) in gathered
            .iter()
            .zip(&levels[first..])
            .zip(&mut gathered_between)
        {
            let (Some(g), Some(between)) = (g, between) else {
                continue;
            };
            let cell = |i: usize, out: &mut Vec<(f32, Rgba)>| {
                let (a, e) = (g.offsets[i] as usize, g.offsets[i + 1] as usize);
                out.extend(
                    g.depth[a..e]
                        .iter()
                        .copied()
                        .zip(g.color[a..e].iter().copied()),
                );
            };
            between.read(level, x, epsilon, &mut entries, cell);
        }
        entries.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        *out = composite_sum(&entries, epsilon);
    }
}

/// The runs ([`Run`]) of box level cell `i`'s fragments, each at its weight there (those of
/// weight 0 left out), appended to `out`.
#[inline(always)]
fn cell_runs(level: &Level, weights: &[f32], i: usize, epsilon: f32, out: &mut Vec<(f32, Rgba)>) {
    let (a, b) = (level.offsets[i] as usize, level.offsets[i + 1] as usize);
    let mut run = Run::new();
    for ((&z, c), &weight) in level.depth[a..b]
        .iter()
        .zip(&level.color[a..b])
        .zip(&weights[a..b])
    {
        if weight > 0.0 {
            run.add(z, weight, from_half(c), epsilon, out);
        }
    }
    run.flush(out);
}

/// One level's bilinear reads along a pixel row, between the cells whose index is a multiple
/// of `step`: the two rows of cells the row lies between and the second's weight, and the last
/// two columns of cells read, each with its two cells' entries already blended between the
/// rows. A column is blended once per row: every pixel between it and the next reads it.
struct Between {
    step: usize,
    rows: (usize, usize),
    fy: f32,
    /// Neither row has an entry: the read adds nothing.
    empty: bool,
    /// The last two columns read.
    columns: [Column; 2],
    /// One cell's entries before they are weighted (reused).
    cell: Vec<(f32, Rgba)>,
}

/// A column of a level's cells, in the two rows a pixel row reads between: their entries,
/// weighted by row and summed side by side ([`add_side_by_side`]).
#[derive(Clone)]
struct Column {
    cx: usize,
    entries: Vec<(f32, Rgba)>,
}

impl Column {
    const NONE: usize = usize::MAX;

    fn empty() -> Self {
        Self {
            cx: Self::NONE,
            entries: Vec::new(),
        }
    }
}

impl Between {
    /// The reads along pixel row `y` of a level of `offsets` (per cell, where its entries
    /// start, as [`Level::offsets`]).
    fn new(level: &Level, offsets: &[u32], y: usize, step: usize) -> Self {
        let (rows, fy) = level.between(y, level.height, step);
        let row_empty = |cy: usize| offsets[cy * level.width] == offsets[(cy + 1) * level.width];
        Self {
            step,
            rows,
            fy,
            empty: row_empty(rows.0) && row_empty(rows.1),
            columns: [Column::empty(), Column::empty()],
            cell: Vec::new(),
        }
    }

    /// Column `cx` blended between the two rows, kept in slot `slot`; `cell(i, out)` appends
    /// cell `i`'s entries.
    #[inline(always)]
    fn column<F>(&mut self, width: usize, cx: usize, slot: usize, epsilon: f32, cell: &F)
    where
        F: Fn(usize, &mut Vec<(f32, Rgba)>),
    {
        if self.columns[slot].cx == cx {
            return;
        }
        // The previous pixel's right column is this one's left; at the level's last column
        // both are the same.
        if slot == 0 && self.columns[1].cx == cx {
            self.columns.swap(0, 1);
            return;
        }
        if slot == 1 && self.columns[0].cx == cx {
            self.columns[1] = self.columns[0].clone();
            return;
        }
        let (top, bottom) = self.rows;
        let Column { entries, .. } = &mut self.columns[slot];
        entries.clear();
        for (cy, wy) in [(top, 1.0 - self.fy), (bottom, self.fy)] {
            if wy <= 0.0 {
                continue;
            }
            self.cell.clear();
            cell(cy * width + cx, &mut self.cell);
            for &(z, c) in &self.cell {
                add_side_by_side(entries, 0, z, c.map(|v| v * wy), epsilon);
            }
        }
        self.columns[slot].cx = cx;
    }

    /// Adds the bilinear read of the cells around pixel `x`'s centre to `entries`: the two
    /// columns' entries times their weights, one surface seen from both summed into one entry.
    #[inline(always)]
    fn read<F>(
        &mut self,
        level: &Level,
        x: usize,
        epsilon: f32,
        entries: &mut Vec<(f32, Rgba)>,
        cell: F,
    ) where
        F: Fn(usize, &mut Vec<(f32, Rgba)>),
    {
        if self.empty {
            return;
        }
        let ((left, right), fx) = level.between(x, level.width, self.step);
        self.column(level.width, left, 0, epsilon, &cell);
        self.column(level.width, right, 1, epsilon, &cell);
        let start = entries.len();
        for (slot, wx) in [(0, 1.0 - fx), (1, fx)] {
            if wx <= 0.0 {
                continue;
            }
            for &(z, c) in &self.columns[slot].entries {
                add_side_by_side(entries, start, z, c.map(|v| v * wx), epsilon);
            }
        }
    }
}

/// Adds a surface at `z` with weighted colour `p`, read from one of several neighbouring
/// cells, to the entries from `start` on: summed into the entry of the same surface (within
/// the depth threshold either way, the nearer depth kept), as `composite_sum` would sum cells
/// side by side, so the sort stays short; else a new entry.
#[inline(always)]
fn add_side_by_side(entries: &mut Vec<(f32, Rgba)>, start: usize, z: f32, p: Rgba, epsilon: f32) {
    match entries[start..]
        .iter_mut()
        .find(|(d, _)| z <= *d + epsilon * d.abs() && *d <= z + epsilon * z.abs())
    {
        Some((d, q)) => {
            *d = d.min(z);
            for (qk, pk) in q.iter_mut().zip(p) {
                *qk += pk;
            }
        }
        None => entries.push((z, p)),
    }
}

/// Front-to-back blending of depth-sorted weighted fragments: a group opens at the nearest
/// remaining fragment and sums every fragment within the depth threshold of it (side by side:
/// different cells or levels); groups are blended with the over operator. A group whose
/// coverage exceeds 1 (rounding) is scaled back to opaque.
#[inline(always)]
pub fn composite_sum(entries: &[(f32, Rgba)], epsilon: f32) -> Rgba {
    let mut out = [0.0f32; 4];
    let mut transmit = 1.0f32;
    let mut i = 0;
    while i < entries.len() && transmit > 1e-5 {
        let z0 = entries[i].0;
        let limit = z0 + epsilon * z0.abs();
        let mut p = [0.0f32; 4];
        while i < entries.len() && entries[i].0 <= limit {
            for (pk, ck) in p.iter_mut().zip(entries[i].1) {
                *pk += ck;
            }
            i += 1;
        }
        let scale = if p[3] > 1.0 { 1.0 / p[3] } else { 1.0 };
        let a = (p[3] * scale).clamp(0.0, 1.0);
        for k in 0..3 {
            out[k] += transmit * p[k] * scale;
        }
        out[3] += transmit * a;
        transmit *= 1.0 - a;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_sum_is_the_area_of_the_shape_in_cells() {
        // The one-cell soft edge keeps the area to within a few percent once the disc spans a
        // few cells.
        for aperture in [Aperture::Disc, Aperture::parse("poly:6").unwrap()] {
            let shape = GatherShape::new(&aperture, 8.0);
            for t in [2.0f32, 3.0, 5.5, 8.0] {
                let area = aperture.area() * t * t;
                let sum = 1.0 / shape.norm(t);
                assert!(
                    (sum / area - 1.0).abs() < 0.05,
                    "{aperture:?} t {t}: {sum} vs {area}"
                );
            }
        }
    }

    #[test]
    fn near_field_coverage_is_the_far_field_turned_half_a_turn() {
        let shape = GatherShape::new(&Aperture::parse("poly:5,rot=10").unwrap(), 4.0);
        for o in &shape.offsets {
            let twin = shape
                .offsets
                .iter()
                .find(|p| p.i == -o.i && p.j == -o.j)
                .unwrap();
            for shift in [[0.0, 0.0], [0.3, -0.2]] {
                let turned = [-shift[0], -shift[1]];
                assert_eq!(
                    shape.coverage(o, 3.0, true, shift),
                    shape.coverage(twin, 3.0, false, turned)
                );
            }
        }
    }

    #[test]
    fn bands_partition_the_radii_above_the_threshold() {
        let levels = 6;
        for first in [0, FIRST_SHAPE_LEVEL] {
            let mut prev = shape_threshold_px(first);
            for s in first..levels {
                let (lo, hi) = band_px(s, levels, first);
                assert_eq!(lo, prev);
                prev = hi;
            }
            assert!(prev.is_infinite());
        }
        assert_eq!(shape_threshold_px(0), 2.5);
        assert_eq!(shape_threshold_px(FIRST_SHAPE_LEVEL), SHAPE_FROM_PX);
        // Radius 12 px: levels 1 (4.5-10 px) and 2 (10-20 px) over level 0.
        assert_eq!(levels_needed(12.0, FIRST_SHAPE_LEVEL), 3);
        assert_eq!(levels_needed(12.0, 0), 3);
    }
}
