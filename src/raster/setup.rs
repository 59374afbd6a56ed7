//! Passes `setup` (clip, cull, snap, edge functions, attribute planes) and `raster`
//! (coverage, early depth test, shading) for one triangle.

use glam::{Vec2, Vec3, Vec4};

use super::{shade, Fragment, TileRect, TileSink};
use crate::lens::ThinLens;
use crate::scene::texture::BATCH;
use crate::scene::Scene;

/// Sub-pixel precision: 1/256 pixel.
pub(crate) const SUBPIXEL_BITS: u32 = 8;
const ONE: i64 = 1 << SUBPIXEL_BITS;
const HALF: i64 = ONE / 2;
/// Guard band in pixels around the image: triangles are clipped to it so fixed-point
/// coordinates stay small (products of two coordinates fit in i64 with room to spare).
const GUARD_PX: f32 = 8192.0;

/// Coverage samples per pixel when a triangle is rasterized with coverage masks (one bit each
/// of [`super::Fragment::coverage`]).
pub const COVERAGE_SAMPLES: u32 = 16;

/// The sample positions of coverage rasterization, in 1/32 pixel from the pixel centre (odd
/// numbers: the centres of the cells of a 16x16 grid over the pixel): 16 points, one in each
/// row and each column of the grid (n-rooks), so that an edge of any slope splits them about in
/// proportion to the area it cuts. The arrangement is the 16-sample pattern that graphics APIs
/// fix for multisampling, moved by half a cell so that its mean is the pixel centre.
pub const COVERAGE_PATTERN: [(i8, i8); COVERAGE_SAMPLES as usize] = [
    (3, 3),
    (-1, -5),
    (-5, 5),
    (9, -1),
    (-9, -3),
    (5, 11),
    (11, 7),
    (7, -9),
    (-3, 13),
    (1, -13),
    (-7, -11),
    (-11, 9),
    (-15, 1),
    (15, -7),
    (13, 15),
    (-13, -15),
];

/// A triangle ready for rasterization: fixed-point edge functions and perspective-correct
/// attribute planes.
#[derive(Clone, Debug)]
pub struct SetupTriangle {
    /// Inclusive pixel bounding box (x0, y0, x1, y1), clamped to the image: the pixels whose
    /// centres it may cover, or with coverage masks every pixel it may touch.
    pub bbox: (u32, u32, u32, u32),
    /// Fixed-point vertices (x, y), 1/256 pixel, ordered so the area is positive.
    v: [(i64, i64); 3],
    /// Edge bias for the top-left rule: 0 for top/left edges, -1 otherwise.
    bias: [i64; 3],
    /// Plane origin in pixels (vertex 0).
    origin: Vec2,
    /// Planes [value at origin, d/dx, d/dy] for 1/w, u/w, v/w.
    planes: [[f32; 3]; 3],
    /// Material index.
    pub material: u32,
    /// Alpha-blended material.
    pub blend: bool,
    /// Seen from its back (a double-sided material's far side).
    pub back_facing: bool,
    /// View depth of the nearest vertex, in metres.
    pub nearest_m: f32,
    /// View depth of the farthest vertex, in metres.
    pub farthest_m: f32,
}

#[derive(Clone, Copy, Debug)]
struct ClipVertex {
    h: Vec3,
    uv: Vec2,
}

fn lerp(a: ClipVertex, b: ClipVertex, t: f32) -> ClipVertex {
    ClipVertex {
        h: a.h + (b.h - a.h) * t,
        uv: a.uv + (b.uv - a.uv) * t,
    }
}

/// Clips the polygon against `dist >= 0` (Sutherland-Hodgman), in place via `scratch`.
fn clip_plane(
    poly: &mut Vec<ClipVertex>,
    scratch: &mut Vec<ClipVertex>,
    dist: impl Fn(Vec3) -> f32,
) {
    scratch.clear();
    let n = poly.len();
    for i in 0..n {
        let a = poly[i];
        let b = poly[(i + 1) % n];
        let da = dist(a.h);
        let db = dist(b.h);
        if da >= 0.0 {
            scratch.push(a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            let t = da / (da - db);
            scratch.push(lerp(a, b, t));
        }
    }
    std::mem::swap(poly, scratch);
}

/// Sets up one triangle given homogeneous raster coordinates `(x*w, y*w, w)` and UVs, appending
/// zero or more [`SetupTriangle`]s (clipping may split it).
pub(crate) fn setup_triangle(
    verts: &[(Vec3, Vec2); 3],
    material: u32,
    double_sided: bool,
    blend: bool,
    lens: &ThinLens,
    coverage: bool,
    out: &mut Vec<SetupTriangle>,
) {
    let (w, h) = (lens.width_px as f32, lens.height_px as f32);
    let planes: [&dyn Fn(Vec3) -> f32; 6] = [
        &|p: Vec3| p.z - lens.near_m,
        &|p: Vec3| lens.far_m - p.z,
        &|p: Vec3| p.x + GUARD_PX * p.z,
        &|p: Vec3| (w + GUARD_PX) * p.z - p.x,
        &|p: Vec3| p.y + GUARD_PX * p.z,
        &|p: Vec3| (h + GUARD_PX) * p.z - p.y,
    ];
    // Trivial reject and "needs clipping" test per plane. The near-plane test comes first, so
    // the side planes are only evaluated with w > 0 once clipping is needed.
    let mut needs = [false; 6];
    for (k, plane) in planes.iter().enumerate() {
        let d = verts.map(|v| plane(v.0));
        if d.iter().all(|&d| d < 0.0) {
            return;
        }
        needs[k] = d.iter().any(|&d| d < 0.0);
    }
    // Quick reject of triangles entirely outside the image (common for off-screen geometry).
    if !needs[0] {
        let xs = verts.map(|v| v.0.x / v.0.z);
        let ys = verts.map(|v| v.0.y / v.0.z);
        if xs.iter().all(|&x| x < 0.0)
            || xs.iter().all(|&x| x > w)
            || ys.iter().all(|&y| y < 0.0)
            || ys.iter().all(|&y| y > h)
        {
            return;
        }
    }
    if !needs.iter().any(|&n| n) {
        setup_clipped(
            &verts.map(|(h, uv)| ClipVertex { h, uv }),
            material,
            double_sided,
            blend,
            lens,
            coverage,
            out,
        );
        return;
    }
    let mut poly: Vec<ClipVertex> = verts.iter().map(|&(h, uv)| ClipVertex { h, uv }).collect();
    let mut scratch = Vec::with_capacity(9);
    for (k, plane) in planes.iter().enumerate() {
        if needs[k] {
            clip_plane(&mut poly, &mut scratch, plane);
            if poly.len() < 3 {
                return;
            }
        }
    }
    for i in 1..poly.len() - 1 {
        setup_clipped(
            &[poly[0], poly[i], poly[i + 1]],
            material,
            double_sided,
            blend,
            lens,
            coverage,
            out,
        );
    }
}

/// `floor(a / b)` for `a >= 0` and `b > 0`, exact: a double-precision division (far cheaper
/// than a 64-bit integer one) corrected by one where rounding crossed an integer. The double
/// quotient is within a few ulps of the true one, so within one of it while the quotient is
/// below 2^50; here it is at most an edge value over a step of at least one pixel (256).
#[inline(always)]
fn div_floor(a: i64, b: i64) -> i64 {
    debug_assert!(a >= 0 && b > 0);
    let q = (a as f64 / b as f64) as i64;
    if q * b > a {
        q - 1
    } else if (q + 1) * b <= a {
        q + 1
    } else {
        q
    }
}

#[inline]
fn edge(a: (i64, i64), b: (i64, i64), p: (i64, i64)) -> i64 {
    (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0)
}

fn setup_clipped(
    verts: &[ClipVertex; 3],
    material: u32,
    double_sided: bool,
    blend: bool,
    lens: &ThinLens,
    coverage: bool,
    out: &mut Vec<SetupTriangle>,
) {
    let mut fixed = [(0i64, 0i64); 3];
    let mut inv_w = [0f32; 3];
    for (i, v) in verts.iter().enumerate() {
        if v.h.z <= 0.0 {
            return;
        }
        let iw = 1.0 / v.h.z;
        inv_w[i] = iw;
        let x = v.h.x * iw;
        let y = v.h.y * iw;
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        fixed[i] = (
            (x as f64 * ONE as f64).round() as i64,
            (y as f64 * ONE as f64).round() as i64,
        );
    }
    let mut order = [0usize, 1, 2];
    let area = edge(fixed[0], fixed[1], fixed[2]);
    if area == 0 {
        return;
    }
    // Counter-clockwise front faces (camera looking down -Z, y up) have negative area in
    // raster coordinates (y down).
    let back_facing = area > 0;
    if back_facing {
        if !double_sided {
            return;
        }
    } else {
        order.swap(1, 2);
    }
    // Now edge(v0, v1, v2) > 0 for the reordered vertices.
    let v = order.map(|i| fixed[i]);
    let area = edge(v[0], v[1], v[2]);
    debug_assert!(area > 0);
    let min_x = v.iter().map(|p| p.0).min().unwrap_or(0);
    let max_x = v.iter().map(|p| p.0).max().unwrap_or(0);
    let min_y = v.iter().map(|p| p.1).min().unwrap_or(0);
    let max_y = v.iter().map(|p| p.1).max().unwrap_or(0);
    // Pixels whose centres (i*ONE + HALF) lie in the bounding box; with coverage masks, every
    // pixel whose square [i, i+1] the box touches (the samples lie within it).
    let (px0, px1, py0, py1) = if coverage {
        (
            min_x.div_euclid(ONE),
            max_x.div_euclid(ONE),
            min_y.div_euclid(ONE),
            max_y.div_euclid(ONE),
        )
    } else {
        (
            (min_x - HALF).div_euclid(ONE) + i64::from((min_x - HALF).rem_euclid(ONE) != 0),
            (max_x - HALF).div_euclid(ONE),
            (min_y - HALF).div_euclid(ONE) + i64::from((min_y - HALF).rem_euclid(ONE) != 0),
            (max_y - HALF).div_euclid(ONE),
        )
    };
    let px0 = px0.max(0);
    let py0 = py0.max(0);
    let px1 = px1.min(lens.width_px as i64 - 1);
    let py1 = py1.min(lens.height_px as i64 - 1);
    if px0 > px1 || py0 > py1 {
        return;
    }
    // Top-left rule. With positive area (clockwise on screen, y down), a top edge runs in +x
    // with dy == 0 and a left edge runs upward (dy < 0).
    let bias = [(1, 2), (2, 0), (0, 1)].map(|(a, b)| {
        let dx = v[b].0 - v[a].0;
        let dy = v[b].1 - v[a].1;
        if dy < 0 || (dy == 0 && dx > 0) {
            0
        } else {
            -1
        }
    });
    // Attribute planes in float pixels, relative to vertex 0.
    let pos = v.map(|p| Vec2::new(p.0 as f32 / ONE as f32, p.1 as f32 / ONE as f32));
    let d1 = pos[1] - pos[0];
    let d2 = pos[2] - pos[0];
    let det = d1.x * d2.y - d2.x * d1.y;
    let attrs = |f: &dyn Fn(usize) -> f32| -> [f32; 3] {
        let a0 = f(order[0]);
        let a1 = f(order[1]) - a0;
        let a2 = f(order[2]) - a0;
        [
            a0,
            (a1 * d2.y - a2 * d1.y) / det,
            (a2 * d1.x - a1 * d2.x) / det,
        ]
    };
    let planes = [
        attrs(&|i| inv_w[i]),
        attrs(&|i| verts[i].uv.x * inv_w[i]),
        attrs(&|i| verts[i].uv.y * inv_w[i]),
    ];
    out.push(SetupTriangle {
        bbox: (px0 as u32, py0 as u32, px1 as u32, py1 as u32),
        v,
        bias,
        origin: pos[0],
        planes,
        material,
        blend,
        back_facing,
        nearest_m: 1.0 / inv_w[0].max(inv_w[1]).max(inv_w[2]),
        farthest_m: 1.0 / inv_w[0].min(inv_w[1]).min(inv_w[2]),
    });
}

/// Calls `f(y, x0, x1, fy)` for every row of `rect` that `tri` covers, with `x0..x1` the
/// pixels of the row whose centres it covers (top-left rule; one run, as the triangle is
/// convex) and `fy` the row's pixel centre relative to the triangle's plane origin.
#[inline(always)]
fn for_each_run(tri: &SetupTriangle, rect: &TileRect, f: impl FnMut(usize, usize, usize, f32)) {
    for_each_run_with_slack(tri, rect, [0; 3], f);
}

/// [`for_each_run`] with each edge function raised by `slack[k]` (fixed-point edge units): the
/// runs of pixels where a point that far inside the edges' shifted lines may lie, e.g. a
/// coverage sample off the centre.
#[inline(always)]
fn for_each_run_with_slack(
    tri: &SetupTriangle,
    rect: &TileRect,
    slack: [i64; 3],
    mut f: impl FnMut(usize, usize, usize, f32),
) {
    let x0 = (tri.bbox.0 as usize).max(rect.x0);
    let x1 = (tri.bbox.2 as usize).min(rect.x1 - 1);
    let y0 = (tri.bbox.1 as usize).max(rect.y0);
    let y1 = (tri.bbox.3 as usize).min(rect.y1 - 1);
    if x0 > x1 || y0 > y1 {
        return;
    }
    let v = &tri.v;
    let edges = [(1usize, 2usize), (2, 0), (0, 1)];
    // Per-pixel and per-row steps of each edge function.
    let step_x = edges.map(|(a, b)| -(v[b].1 - v[a].1) * ONE);
    let step_y = edges.map(|(a, b)| (v[b].0 - v[a].0) * ONE);
    let last = (x1 - x0) as i64;
    // Locals, which the sink's stores cannot alias, so they stay in registers.
    let origin = tri.origin;
    // The edge functions at the first pixel of row `y0`, stepped exactly (integers) per row.
    let p = (x0 as i64 * ONE + HALF, y0 as i64 * ONE + HALF);
    let mut w = [0, 1, 2].map(|k| edge(v[edges[k].0], v[edges[k].1], p) + tri.bias[k] + slack[k]);
    for y in y0..=y1 {
        // The covered pixels of a row are one run `x0 + lo ..= x0 + hi`: solve
        // `w[k] + step_x[k] * i >= 0` for `i` exactly, edge by edge, in integers.
        let (mut lo, mut hi) = (0i64, last);
        for k in 0..3 {
            let (w, s) = (w[k], step_x[k]);
            if s > 0 {
                if w < 0 {
                    // ceil(-w / s)
                    lo = lo.max(div_floor(-w + s - 1, s));
                }
            } else if w < 0 {
                hi = -1;
            } else if s < 0 {
                hi = hi.min(div_floor(w, -s));
            }
        }
        for k in 0..3 {
            w[k] += step_y[k];
        }
        if lo > hi {
            continue;
        }
        f(
            y,
            x0 + lo as usize,
            x0 + hi as usize + 1,
            y as f32 + 0.5 - origin.y,
        );
    }
}

/// Calls `f(x, y, fx, fy)` for every pixel of `rect` whose centre `tri` covers (top-left rule),
/// with `(fx, fy)` the pixel centre relative to the triangle's plane origin.
#[cfg(test)]
fn for_each_covered(
    tri: &SetupTriangle,
    rect: &TileRect,
    mut f: impl FnMut(usize, usize, f32, f32),
) {
    let origin_x = tri.origin.x;
    for_each_run(tri, rect, |y, xa, xb, fy| {
        // Half-open: `..=` costs a test more per pixel.
        for x in xa..xb {
            f(x, y, x as f32 + 0.5 - origin_x, fy);
        }
    });
}

/// Every bit of a full coverage mask.
pub const FULL_COVERAGE: u16 = u16::MAX;

/// Calls `f(x, y, mask, centroid)` for every pixel of `rect` where `tri` covers at least one of
/// the [`COVERAGE_PATTERN`] samples (top-left rule at each sample): `mask` has bit `s` set for
/// each covered sample `s`, and `centroid` is the mean position of the covered samples relative
/// to the pixel centre, in pixels (zero when all are covered), where the fragment is shaded so
/// that its attributes are never extrapolated past the triangle.
///
/// `f` is handed `ctx` (the sink, which both closures read). `span(ctx, y, xa, xb)` narrows
/// row `y`'s run of pixels `xa..xb` before it is walked, to those that may give a fragment
/// (see [`unhidden_span`]).
#[inline(always)]
pub(crate) fn for_each_covered_mask<C>(
    tri: &SetupTriangle,
    rect: &TileRect,
    ctx: &mut C,
    span: impl Fn(&C, usize, usize, usize) -> (usize, usize),
    mut f: impl FnMut(&mut C, usize, usize, u16, Vec2),
) {
    let v = &tri.v;
    let edges = [(1usize, 2usize), (2, 0), (0, 1)];
    // Per edge, its change from the pixel centre to each sample (fixed point: 1/32 pixel is
    // 8 steps of 1/256).
    let unit = ONE / 32;
    let deltas: [[i64; COVERAGE_SAMPLES as usize]; 3] = edges.map(|(a, b)| {
        let (ex, ey) = (v[b].0 - v[a].0, v[b].1 - v[a].1);
        COVERAGE_PATTERN.map(|(sx, sy)| ex * i64::from(sy) * unit - ey * i64::from(sx) * unit)
    });
    let lo = deltas.map(|d| d.iter().copied().min().unwrap_or(0));
    let hi = deltas.map(|d| d.iter().copied().max().unwrap_or(0));
    let step_x = edges.map(|(a, b)| -(v[b].1 - v[a].1) * ONE);
    for_each_run_with_slack(tri, rect, hi, |y, xa, xb, _fy| {
        let (xa, xb) = span(ctx, y, xa, xb);
        if xa >= xb {
            return;
        }
        let p = (xa as i64 * ONE + HALF, y as i64 * ONE + HALF);
        let mut e = [0, 1, 2].map(|k| edge(v[edges[k].0], v[edges[k].1], p) + tri.bias[k]);
        for x in xa..xb {
            let (e0, e1, e2) = (e[0], e[1], e[2]);
            for k in 0..3 {
                e[k] += step_x[k];
            }
            if e0 + lo[0] >= 0 && e1 + lo[1] >= 0 && e2 + lo[2] >= 0 {
                f(ctx, x, y, FULL_COVERAGE, Vec2::ZERO);
                continue;
            }
            let mut mask = 0u16;
            for (s, ((d0, d1), d2)) in deltas[0].iter().zip(&deltas[1]).zip(&deltas[2]).enumerate()
            {
                let inside = (e0 + d0 >= 0) & (e1 + d1 >= 0) & (e2 + d2 >= 0);
                mask |= u16::from(inside) << s;
            }
            if mask == 0 {
                continue;
            }
            f(ctx, x, y, mask, mask_centroid(mask));
        }
    });
}

/// Every pixel of a run, unnarrowed (for [`for_each_covered_mask`]).
#[cfg(test)]
fn whole_span<C>(_: &C, _: usize, xa: usize, xb: usize) -> (usize, usize) {
    (xa, xb)
}

/// The pixels `xa..xb` of row `y` without the leading and trailing ones where `tile` already
/// holds fragments nearer than all of opaque `tri` ([`visible_depth`] rejects them by their
/// first test): most of a dense scene's pixels are rejected that way (`grass` at 1280x720,
/// `multilayer`: 23 of the 50 million pixels its triangles touch), and a run's test costs a
/// comparison a pixel instead of its coverage, plane and depth test.
#[inline(always)]
fn unhidden_span<T: TileSink>(
    tile: &T,
    tri: &SetupTriangle,
    y: usize,
    xa: usize,
    xb: usize,
) -> (usize, usize) {
    if tri.blend {
        return (xa, xb);
    }
    let Some(row) = tile.occlusion_row(y as u32, xa as u32, xb as u32) else {
        return (xa, xb);
    };
    let hidden = |farthest: &&f32| tri.nearest_m >= **farthest;
    let lead = row.iter().take_while(hidden).count();
    if lead == row.len() {
        return (xb, xb);
    }
    let trail = row.iter().rev().take_while(hidden).count();
    (xa + lead, xb - trail)
}

/// Below this many pixels a batch is shaded pixel by pixel ([`shade::Shader::shade`], the same
/// result bit for bit): the batch's lane-by-lane passes cost the same for 1 pixel as for 16.
const FEW_PIXELS: usize = 4;

/// Batch buffers of [`raster_triangle`], made once per tile rather than per triangle (a
/// kilobyte to initialise, which scenes of many small triangles would pay per triangle).
pub(crate) struct RasterScratch {
    pending: PendingPixels,
    uv: shade::UvBatch,
    colors: [Option<crate::image::Rgba>; BATCH],
    /// One lane per coverage sample of a pixel (textured surfaces with coverage masks).
    sample_uv: shade::UvBatch,
    sample_colors: [Option<crate::image::Rgba>; BATCH],
}

impl RasterScratch {
    pub(crate) fn new() -> Self {
        Self {
            pending: PendingPixels {
                n: 0,
                x: [0; BATCH],
                y: [0; BATCH],
                depth_m: [0.0; BATCH],
                q: [1.0; BATCH],
                uq: [0.0; BATCH],
                vq: [0.0; BATCH],
                mask: [FULL_COVERAGE; BATCH],
            },
            uv: shade::UvBatch::default(),
            colors: [None; BATCH],
            sample_uv: shade::UvBatch::default(),
            sample_colors: [None; BATCH],
        }
    }
}

/// Covered pixels that passed the early depth test, waiting to be shaded together. Lanes past
/// `n` hold values of earlier batches: finite or not, they are computed on and never used.
struct PendingPixels {
    n: usize,
    x: [u32; BATCH],
    y: [u32; BATCH],
    depth_m: [f32; BATCH],
    /// 1/w, u/w and v/w; lanes past `n` stay finite.
    q: [f32; BATCH],
    uq: [f32; BATCH],
    vq: [f32; BATCH],
    /// Coverage mask of each pixel ([`FULL_COVERAGE`] when sampled at the centre only).
    mask: [u16; BATCH],
}

impl PendingPixels {
    /// Queues pixel (`x`, `y`) at `depth_m` with its plane values `e` (1/w, u/w, v/w); true
    /// when the batch is full.
    #[inline(always)]
    fn push(&mut self, x: usize, y: usize, depth_m: f32, e: Vec4) -> bool {
        self.push_masked(x, y, depth_m, e, FULL_COVERAGE)
    }

    /// [`Self::push`] with a coverage mask.
    #[inline(always)]
    fn push_masked(&mut self, x: usize, y: usize, depth_m: f32, e: Vec4, mask: u16) -> bool {
        let i = self.n;
        self.mask[i] = mask;
        (self.x[i], self.y[i], self.depth_m[i]) = (x as u32, y as u32, depth_m);
        (self.q[i], self.uq[i], self.vq[i]) = (e.x, e.y, e.z);
        self.n += 1;
        self.n == BATCH
    }
}

/// How the covered samples of a textured fragment are grouped for shading (one lookup a
/// group). `reference` averages many views of point-like lookups, the exact box filter of the
/// texture over the pixel; one trilinear lookup at the pixel's footprint is a wider, mip-shaped
/// filter, and a minified chart loses its edges (`railing` at 640x360, `multilayer` against
/// `reference` at 1024 samples: 31.3 dB with one lookup a pixel, 35.8 with quadrants, 36.2
/// with every sample). So a trilinear texture takes four groups (the pixel's quadrants, each
/// a lookup with a quarter of the footprint, and an alpha-mask material its own alpha test in
/// each); a texture filtered with nearest texels (a chart drawn texel for texel) varies
/// stepwise inside the pixel and takes every sample. One group is for alpha to coverage: a
/// cut-out of two-valued alpha takes its coverage from one sharper lookup
/// ([`shade::Shader::with_alpha_to_coverage`], [`A2C_BIAS`]). Measured on `grass` (alpha-cut
/// blades) at 1280x720, `multilayer/collect`: 4.4 s with every sample, 1.3 s with quadrants,
/// 0.7 s with alpha to coverage (0.3 s at pixel centres without coverage).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ShadingGroups {
    Pixel,
    Quadrants,
    Samples,
}

impl ShadingGroups {
    fn of(material: &crate::scene::Material) -> Self {
        use crate::scene::texture::FilterMode;
        let nearest = [&material.base_color_texture, &material.emissive_texture]
            .into_iter()
            .flatten()
            .any(|b| {
                b.sampler.mag_filter == FilterMode::Nearest
                    || b.sampler.min_filter == FilterMode::Nearest
            });
        if nearest {
            Self::Samples
        } else {
            Self::Quadrants
        }
    }

    fn lanes_per_pixel(self) -> usize {
        match self {
            Self::Pixel => 1,
            Self::Quadrants => 4,
            Self::Samples => COVERAGE_SAMPLES as usize,
        }
    }

    /// How many groups `mask` has (lanes it takes).
    #[inline(always)]
    fn count(self, mask: u16) -> usize {
        match self {
            Self::Pixel => 1,
            Self::Quadrants => QUADRANT_MASKS
                .iter()
                .map(|&q| usize::from(mask & q != 0))
                .sum(),
            Self::Samples => count16(mask) as usize,
        }
    }

    /// Calls `f(samples, centroid)` for each group of `mask`, its centroid relative to the
    /// pixel centre in pixels; `centroid` is the whole mask's.
    #[inline(always)]
    fn for_each(self, mask: u16, centroid: Vec2, mut f: impl FnMut(u16, Vec2)) {
        match self {
            Self::Pixel => f(mask, centroid),
            Self::Quadrants => {
                for quadrant in QUADRANT_MASKS {
                    let bits = mask & quadrant;
                    if bits != 0 {
                        f(bits, mask_centroid(bits));
                    }
                }
            }
            Self::Samples => {
                let mut rest = mask;
                while rest != 0 {
                    let s = rest.trailing_zeros() as usize;
                    rest &= rest - 1;
                    f(1 << s, SAMPLE_OFFSETS[s]);
                }
            }
        }
    }
}

/// Level-of-detail bias of the alpha-to-coverage lookup: a footprint a quarter of the pixel's
/// across. The cut-out's edge stays where the alpha test puts it and is not widened by the
/// texture filter (a tent several texels wide at the pixel's own level of detail), while a
/// lookup across the edge still keeps its share. Measured on `grass` at 640x360 against
/// `reference` (1024 samples), `multilayer`: 30.6 dB at bias 0, 33.4 at -1, 34.7 at -2, 35.1
/// with four alpha tests a pixel (quadrants) at twice the collect time.
const A2C_BIAS: f32 = -2.0;

/// The samples in an order that spreads every prefix over the pixel (each next sample the
/// farthest from those before it, from the one nearest the centre): alpha to coverage keeps a
/// prefix of a mask's samples in this order.
const SPREAD_ORDER: [u8; COVERAGE_SAMPLES as usize] =
    [0, 15, 12, 13, 14, 9, 8, 11, 1, 5, 2, 3, 4, 6, 7, 10];

/// The first `share` of the samples of `mask` (rounded to whole samples) in [`SPREAD_ORDER`]:
/// the mask's bits moved to their ranks in the order, the lowest ones kept, and moved back,
/// by byte tables (the walk along the order cost 4% of `multilayer/collect` on `grass`).
#[inline]
fn keep_share(mask: u16, share: f32) -> u16 {
    let count = count16(mask);
    let left = round_to_count(share * count as f32);
    if left >= count {
        // The whole mask (an opaque footprint, the common case).
        return mask;
    }
    let bytes = |m: u16| (usize::from(m & 0xff), usize::from(m >> 8));
    let (lo, hi) = bytes(mask);
    let ranks = TO_RANKS[0][lo] | TO_RANKS[1][hi];
    let (lo, hi) = bytes(ranks);
    // `left < count <= 16`: within the low byte's ranks, or all of them and some high ones.
    let below = u32::from(MASK_SUMS[0][lo].2);
    let kept = if left <= below {
        u16::from(LOWEST8[lo][left as usize])
    } else {
        lo as u16 | u16::from(LOWEST8[hi][(left - below) as usize]) << 8
    };
    let (lo, hi) = bytes(kept);
    FROM_RANKS[0][lo] | FROM_RANKS[1][hi]
}

/// Set bits of a mask, from the per-byte counts of [`MASK_SUMS`]: x86-64's baseline has no
/// `popcnt`, and `count_ones` becomes a dozen instructions.
#[inline(always)]
pub(crate) fn count16(mask: u16) -> u32 {
    let (lo, hi) = (usize::from(mask & 0xff), usize::from(mask >> 8));
    u32::from(MASK_SUMS[0][lo].2 + MASK_SUMS[1][hi].2)
}

/// Per byte and `k <= 8`: its lowest `k` set bits (all of them when it has fewer).
const LOWEST8: [[u8; 9]; 256] = {
    let mut lowest = [[0u8; 9]; 256];
    let mut b = 0;
    while b < 256 {
        let mut k = 1;
        while k <= 8 {
            let prev = lowest[b][k - 1];
            let rest = b as u8 & !prev;
            // The next set bit above those kept, if any.
            lowest[b][k] = prev | (rest & rest.wrapping_neg());
            k += 1;
        }
        b += 1;
    }
    lowest
};

/// Per byte of a mask (samples 0-7, 8-15) and per value: its samples' bits moved to their
/// ranks in [`SPREAD_ORDER`] (bit `k` for the `k`th sample of the order).
const TO_RANKS: [[u16; 256]; 2] = {
    let mut bit_of_sample = [0u16; COVERAGE_SAMPLES as usize];
    let mut rank = 0;
    while rank < SPREAD_ORDER.len() {
        bit_of_sample[SPREAD_ORDER[rank] as usize] = 1 << rank;
        rank += 1;
    }
    byte_tables(bit_of_sample)
};

/// The inverse of [`TO_RANKS`]: per byte of a rank mask (ranks 0-7, 8-15), the samples' bits.
const FROM_RANKS: [[u16; 256]; 2] = {
    let mut bit_of_rank = [0u16; COVERAGE_SAMPLES as usize];
    let mut rank = 0;
    while rank < SPREAD_ORDER.len() {
        bit_of_rank[rank] = 1 << SPREAD_ORDER[rank];
        rank += 1;
    }
    byte_tables(bit_of_rank)
};

/// Per byte of a 16-bit mask (low, high) and per value: the union of `bit_of[i]` over its set
/// bits `i`, each value from the one with its lowest bit cleared.
const fn byte_tables(bit_of: [u16; 16]) -> [[u16; 256]; 2] {
    let mut tables = [[0u16; 256]; 2];
    let mut i = 0usize;
    while i < 512 {
        let (half, byte) = (i / 256, i % 256);
        if byte != 0 {
            let lowest = 8 * half + byte.trailing_zeros() as usize;
            tables[half][byte] = tables[half][byte & (byte - 1)] | bit_of[lowest];
        }
        i += 1;
    }
    tables
}

/// `x.round() as u32` (halves away from zero; NaN and negatives give 0) without the libm call
/// that `round` is on x86-64's baseline: the truncation and its exact remainder (`x` is a
/// share of at most 16 samples).
#[inline(always)]
fn round_to_count(x: f32) -> u32 {
    let whole = x as u32;
    whole + u32::from(x - whole as f32 >= 0.5)
}

/// The samples of each quadrant of the pixel (right of and below the centre set bits 1 and 2
/// of the quadrant's index).
const QUADRANT_MASKS: [u16; 4] = {
    let mut masks = [0u16; 4];
    let mut s = 0;
    while s < COVERAGE_PATTERN.len() {
        let (sx, sy) = COVERAGE_PATTERN[s];
        masks[(sx > 0) as usize + 2 * (sy > 0) as usize] |= 1 << s;
        s += 1;
    }
    masks
};

/// The [`COVERAGE_PATTERN`] samples' offsets from the pixel centre in pixels.
const SAMPLE_OFFSETS: [Vec2; COVERAGE_SAMPLES as usize] = {
    let mut offsets = [Vec2::ZERO; COVERAGE_SAMPLES as usize];
    let mut s = 0;
    while s < COVERAGE_PATTERN.len() {
        let (sx, sy) = COVERAGE_PATTERN[s];
        offsets[s] = Vec2::new(sx as f32 / 32.0, sy as f32 / 32.0);
        s += 1;
    }
    offsets
};

/// Per byte of a mask (low, high) and per value of that byte: the summed sample offsets
/// (1/32 px) and the count of its samples, so a mask's centroid takes two lookups.
const MASK_SUMS: [[(i16, i16, u8); 256]; 2] = {
    let mut sums = [[(0i16, 0i16, 0u8); 256]; 2];
    let mut half = 0;
    while half < 2 {
        let mut byte = 0;
        while byte < 256 {
            let mut bit = 0;
            while bit < 8 {
                if byte & (1 << bit) != 0 {
                    let (sx, sy) = COVERAGE_PATTERN[8 * half + bit];
                    let e = &mut sums[half][byte];
                    *e = (e.0 + sx as i16, e.1 + sy as i16, e.2 + 1);
                }
                bit += 1;
            }
            byte += 1;
        }
        half += 1;
    }
    sums
};

/// Centroid of the samples of a non-empty `mask`, relative to the pixel centre, in pixels.
#[inline]
fn mask_centroid(mask: u16) -> Vec2 {
    let lo = MASK_SUMS[0][usize::from(mask & 0xff)];
    let hi = MASK_SUMS[1][usize::from(mask >> 8)];
    let k = 32.0 * f32::from(lo.2 + hi.2);
    Vec2::new(f32::from(lo.0 + hi.0) / k, f32::from(lo.1 + hi.1) / k)
}

/// Shading lanes of several pixels waiting to be shaded together (see [`ShadingGroups`]).
struct SampleBatch {
    pixels: usize,
    lanes: usize,
    /// Per pixel: column, row, depth.
    pixel: [(u32, u32, f32); BATCH],
    /// Per lane: its pixel and its samples.
    lane: [(u8, u16); BATCH],
}

impl SampleBatch {
    fn new() -> Self {
        Self {
            pixels: 0,
            lanes: 0,
            pixel: [(0, 0, 0.0); BATCH],
            lane: [(0, 0); BATCH],
        }
    }

    /// Shades the lanes and emits one fragment per pixel with any kept sample, in pixel order.
    /// With `alpha_to_coverage` a lane's alpha is the share of its samples kept
    /// ([`shade::Shader::with_alpha_to_coverage`]).
    fn flush<T: TileSink>(
        &mut self,
        shader: &shade::Shader,
        alpha_to_coverage: bool,
        uv: &shade::UvBatch,
        colors: &mut [Option<crate::image::Rgba>; BATCH],
        (blend, back_facing): (bool, bool),
        tile: &mut T,
    ) {
        if self.pixels == 0 {
            return;
        }
        if shader.shade_batch(self.lanes, uv, colors) {
            self.resolve(alpha_to_coverage, colors, (blend, back_facing), tile);
        } else {
            // Every lane discarded (most batches of a cut-out's card): no fragment.
            self.pixels = 0;
            self.lanes = 0;
        }
    }

    /// Emits the pixels' fragments from their lanes' `colors` (`None`: discarded) and empties
    /// the batch, as [`SampleBatch::flush`] after shading.
    fn resolve<T: TileSink>(
        &mut self,
        alpha_to_coverage: bool,
        colors: &[Option<crate::image::Rgba>; BATCH],
        (blend, back_facing): (bool, bool),
        tile: &mut T,
    ) {
        if alpha_to_coverage {
            // One lane a pixel, lane `i` pixel `i` (`ShadingGroups::Pixel`): each kept lane is
            // its pixel's fragment, with the arithmetic of the general case below (`0.0 +` is
            // its sum's start, which turns a -0 into +0 there too).
            debug_assert_eq!(self.lanes, self.pixels);
            let lanes = colors[..self.lanes].iter().zip(&self.lane);
            for ((color, &(_, bits)), &(x, y, depth_m)) in lanes.zip(&self.pixel) {
                let Some(mut color) = *color else {
                    continue;
                };
                let bits = keep_share(bits, color[3]);
                if bits == 0 {
                    continue;
                }
                color[3] = 1.0;
                let w = count16(bits) as f32;
                let inv = 1.0 / w;
                tile.fragment(&Fragment {
                    x,
                    y,
                    depth_m,
                    color: color.map(|c| (0.0 + w * c) * inv),
                    blend,
                    coverage: bits,
                    dithered: true,
                    back_facing,
                });
            }
            self.pixels = 0;
            self.lanes = 0;
            return;
        }
        let mut sum = [[0.0f32; 4]; BATCH];
        let mut kept = [0u16; BATCH];
        for (color, &(p, bits)) in colors[..self.lanes].iter().zip(&self.lane) {
            if let Some(color) = *color {
                let w = count16(bits) as f32;
                for (a, b) in sum[p as usize].iter_mut().zip(color) {
                    *a += w * b;
                }
                kept[p as usize] |= bits;
            }
        }
        for (i, &(x, y, depth_m)) in self.pixel[..self.pixels].iter().enumerate() {
            if kept[i] == 0 {
                continue;
            }
            let inv = 1.0 / count16(kept[i]) as f32;
            tile.fragment(&Fragment {
                x,
                y,
                depth_m,
                color: sum[i].map(|v| v * inv),
                blend,
                coverage: kept[i],
                dithered: false,
                back_facing,
            });
        }
        self.pixels = 0;
        self.lanes = 0;
    }
}

/// A bound on `q * farthest` (rounded) at or below which `1 / q` rounds to at least
/// `farthest`, so the fragment at `1 / q` metres is hidden without dividing. With unit roundoff
/// u = 2^-24, rounded products and quotients are within a factor (1 ± u) of the exact ones: a
/// rounded product at most 1 - 8u means an exact one below 1 - 7u, so the rounded quotient is
/// at least `farthest (1 - u) / (1 - 7u)`, more than `farthest`. Holds for `farthest` = +inf
/// (the product is +inf, never below the bound) and for products that underflow.
const SURELY_BEHIND: f32 = 1.0 - 1.0 / (1u32 << 21) as f32;

/// Depth of a coverage fragment of `tri` at pixel `(x, y)` whose plane gives `q` (1 / depth),
/// kept within the triangle's depths, or `None` when `tile` hides it (opaque triangles only).
/// Most fragments tested are hidden: a product settles them before the division does (see
/// [`SURELY_BEHIND`]).
#[inline(always)]
fn visible_depth<T: TileSink>(
    tile: &T,
    tri: &SetupTriangle,
    x: usize,
    y: usize,
    q: f32,
) -> Option<f32> {
    let depth_of = |q: f32| (1.0 / q).clamp(tri.nearest_m, tri.farthest_m);
    if tri.blend {
        return Some(depth_of(q));
    }
    let (x, y) = (x as u32, y as u32);
    match tile.occlusion_row(y, x, x + 1) {
        Some(&[farthest]) => {
            // `1 / q >= farthest` and a triangle reaching `farthest` clamp to at least it.
            if tri.nearest_m >= farthest
                || (q * farthest <= SURELY_BEHIND && tri.farthest_m >= farthest)
            {
                return None;
            }
            let depth_m = depth_of(q);
            (depth_m < farthest).then_some(depth_m)
        }
        _ => {
            let depth_m = depth_of(q);
            (!tile.occluded(x, y, depth_m)).then_some(depth_m)
        }
    }
}

/// How [`raster_triangle`] samples and shades a triangle's pixels.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Sampling {
    /// Added to the texture level of detail (negative when each pixel is supersampled).
    pub(crate) lod_bias: f32,
    /// A fragment for every pixel the triangle touches, with its coverage mask, instead of
    /// the pixels whose centre it covers.
    pub(crate) coverage: bool,
    /// With coverage: the view depths in metres (nearest, farthest) within which a minified
    /// texture is looked up at every covered sample instead of once a quadrant
    /// (`LayeredInput::sample_shading`).
    pub(crate) sample_shading: Option<(f32, f32)>,
}

/// Rasterizes `tri` within `rect` into `tile` (pass `raster`), sampled as `sampling` says.
///
/// Pixels are depth-tested as the rows are walked, and those that pass are shaded [`BATCH`]
/// at a time: texture coordinates, levels of detail and texture lookups lane by lane
/// ([`shade::Shader::shade_batch`]), then the fragments in pixel order. A triangle covers a
/// pixel once, so the sink sees the same calls as pixel by pixel.
#[inline(always)]
pub(crate) fn raster_triangle<T: TileSink>(
    tri: &SetupTriangle,
    rect: &TileRect,
    scene: &Scene,
    sampling: Sampling,
    tile: &mut T,
    scratch: &mut RasterScratch,
) {
    let Sampling {
        lod_bias,
        coverage,
        sample_shading,
    } = sampling;
    let RasterScratch {
        pending,
        uv,
        colors,
        sample_uv,
        sample_colors,
    } = scratch;
    pending.n = 0;
    let material = &scene.materials[tri.material as usize];
    let shader = shade::Shader::new(material, &scene.textures, lod_bias);
    let [pq, pu, pv] = &tri.planes;
    // Shading without textures is the same for every pixel.
    let flat = (!shader.needs_uv()).then(|| shader.shade(Vec2::ZERO, Vec2::ZERO, Vec2::ZERO));
    let mut shade_and_emit = |p: &mut PendingPixels, tile: &mut T| {
        let n = std::mem::take(&mut p.n);
        match flat {
            Some(color) => colors[..n].fill(color),
            None if n < FEW_PIXELS => {
                // Too few for the batch's fixed cost (small triangles): pixel by pixel, with
                // the arithmetic of the batch loop below. It is written out twice on purpose:
                // one closure shared by both stopped that loop vectorising (grass 15% slower).
                for (i, color) in colors[..n].iter_mut().enumerate() {
                    let (u, v) = (p.uq[i] / p.q[i], p.vq[i] / p.q[i]);
                    let (qx, qy) = (p.q[i] + pq[1], p.q[i] + pq[2]);
                    let du_dx = (p.uq[i] + pu[1]) / qx - u;
                    let dv_dx = (p.vq[i] + pv[1]) / qx - v;
                    let du_dy = (p.uq[i] + pu[2]) / qy - u;
                    let dv_dy = (p.vq[i] + pv[2]) / qy - v;
                    *color = shader.shade(
                        Vec2::new(u, v),
                        Vec2::new(du_dx, dv_dx),
                        Vec2::new(du_dy, dv_dy),
                    );
                }
            }
            None => {
                // uv at the pixel and one pixel right and down.
                for i in 0..BATCH {
                    let (u, v) = (p.uq[i] / p.q[i], p.vq[i] / p.q[i]);
                    let (qx, qy) = (p.q[i] + pq[1], p.q[i] + pq[2]);
                    uv.u[i] = u;
                    uv.v[i] = v;
                    uv.du_dx[i] = (p.uq[i] + pu[1]) / qx - u;
                    uv.dv_dx[i] = (p.vq[i] + pv[1]) / qx - v;
                    uv.du_dy[i] = (p.uq[i] + pu[2]) / qy - u;
                    uv.dv_dy[i] = (p.vq[i] + pv[2]) / qy - v;
                }
                shader.shade_batch(n, uv, colors);
            }
        }
        for (i, color) in colors[..n].iter().enumerate() {
            if let Some(color) = *color {
                tile.fragment(&Fragment {
                    x: p.x[i],
                    y: p.y[i],
                    depth_m: p.depth_m[i],
                    color,
                    blend: tri.blend,
                    coverage: p.mask[i],
                    dithered: false,
                    back_facing: tri.back_facing,
                });
            }
        }
    };
    // The three planes side by side, lanes (1/w, u/w, v/w, unused): one evaluation for all,
    // each lane `p[0] + p[1] dx + p[2] dy`.
    let [p0, p1, p2] = [0, 1, 2].map(|k| Vec4::new(pq[k], pu[k], pv[k], 0.0));
    let origin_x = tri.origin.x;
    let plane = |x: usize, fy: f32| p0 + p1 * (x as f32 + 0.5 - origin_x) + p2 * fy;
    if coverage {
        // Coverage masks: each touched pixel gives one fragment, its depth at the centroid of
        // its covered samples, kept within the triangle's (the plane's value there can run off
        // where the triangle is seen edge-on).
        let origin_y = tri.origin.y;
        // Rows' runs without their pixels already hidden in `tile`.
        let span = |tile: &T, y, xa, xb| unhidden_span(tile, tri, y, xa, xb);
        if flat.is_some() {
            for_each_covered_mask(tri, rect, tile, span, |tile, x, y, mask, c| {
                let e = plane(x, y as f32 + 0.5 - origin_y + c.y) + p1 * c.x;
                let Some(depth_m) = visible_depth(tile, tri, x, y, e.x) else {
                    return;
                };
                if pending.push_masked(x, y, depth_m, e, mask) {
                    shade_and_emit(pending, tile);
                }
            });
            if pending.n > 0 {
                shade_and_emit(pending, tile);
            }
        } else {
            // Textured: the covered samples are shaded in groups, one batch lane a group, at
            // the centroid of its samples with the level of detail of its share of the pixel,
            // and resolved into the fragment: its colour the groups' mean weighted by their
            // samples, its mask the samples of the groups an alpha-mask material keeps. How
            // many groups is what the material needs (`ShadingGroups`). Lanes of several
            // pixels share a batch.
            let groups = ShadingGroups::of(material);
            // An alpha-mask cut-out of two-valued alpha takes its coverage from one lookup a
            // pixel (alpha to coverage) instead of four alpha tests: the filtered alpha is the
            // share of the footprint that is opaque.
            let a2c = (groups == ShadingGroups::Quadrants)
                .then(|| {
                    shade::Shader::new(material, &scene.textures, lod_bias + A2C_BIAS)
                        .with_alpha_to_coverage(&scene.textures)
                })
                .flatten();
            let alpha_to_coverage = a2c.is_some();
            let groups = if alpha_to_coverage {
                ShadingGroups::Pixel
            } else {
                groups
            };
            let sample_bias = -0.5 * (groups.lanes_per_pixel() as f32).log2();
            let fine = a2c.unwrap_or_else(|| {
                shade::Shader::new(material, &scene.textures, lod_bias + sample_bias)
            });
            // Where the texture is minified (a pixel spans more than a texel) and the surface
            // is nearly in focus, every sample takes its own lookup (sample shading,
            // `LayeredInput::sample_shading`).
            let per_sample = sample_shading.filter(|&(near, far)| {
                groups == ShadingGroups::Quadrants && tri.farthest_m >= near && tri.nearest_m <= far
            });
            let mut batch = SampleBatch::new();
            for_each_covered_mask(tri, rect, tile, span, |tile, x, y, mask, c| {
                let fy = y as f32 + 0.5 - origin_y;
                let e = plane(x, fy + c.y) + p1 * c.x;
                let Some(depth_m) = visible_depth(tile, tri, x, y, e.x) else {
                    return;
                };
                // Texture coordinates and their derivatives at the centroid (one set of
                // divisions a pixel); each group's coordinates are carried from there along
                // the derivatives (the perspective's second-order term across a fraction of a
                // pixel is far below a texel).
                let (q, uq, vq) = (e.x, e.y, e.z);
                let (u, v) = (uq / q, vq / q);
                let (qx, qy) = (q + pq[1], q + pq[2]);
                let (du_dx, dv_dx) = ((uq + pu[1]) / qx - u, (vq + pv[1]) / qx - v);
                let (du_dy, dv_dy) = ((uq + pu[2]) / qy - u, (vq + pv[2]) / qy - v);
                let (du, dv) = (Vec2::new(du_dx, dv_dx), Vec2::new(du_dy, dv_dy));
                // Every covered sample its own lookup, all at one level of detail: a sample's
                // footprint is a quarter of a quadrant's (half the derivatives, one level
                // finer than the shader's bias). The pixel is shaded alone, after the pending
                // lanes, so fragments leave in pixel order.
                let sample_lookups = per_sample
                    .is_some_and(|(near, far)| depth_m >= near && depth_m <= far)
                    && fine.minified(du, dv);
                if sample_lookups
                    || batch.lanes + groups.count(mask) > BATCH
                    || batch.pixels == BATCH
                {
                    batch.flush(
                        &fine,
                        alpha_to_coverage,
                        sample_uv,
                        sample_colors,
                        (tri.blend, tri.back_facing),
                        tile,
                    );
                }
                let slot = batch.pixels;
                batch.pixels += 1;
                batch.pixel[slot] = (x as u32, y as u32, depth_m);
                if sample_lookups {
                    // One lane a sample; the lanes share their derivatives.
                    let mut rest = mask;
                    while rest != 0 {
                        let s = rest.trailing_zeros() as usize;
                        rest &= rest - 1;
                        let d = SAMPLE_OFFSETS[s] - c;
                        let i = batch.lanes;
                        sample_uv.u[i] = u + du_dx * d.x + du_dy * d.y;
                        sample_uv.v[i] = v + dv_dx * d.x + dv_dy * d.y;
                        batch.lane[i] = (slot as u8, 1 << s);
                        batch.lanes += 1;
                    }
                    fine.shade_shared(
                        batch.lanes,
                        &sample_uv.u,
                        &sample_uv.v,
                        (du * 0.5, dv * 0.5),
                        sample_colors,
                    );
                    batch.resolve(
                        alpha_to_coverage,
                        sample_colors,
                        (tri.blend, tri.back_facing),
                        tile,
                    );
                    return;
                }
                groups.for_each(mask, c, |bits, g| {
                    let d = g - c;
                    let i = batch.lanes;
                    sample_uv.u[i] = u + du_dx * d.x + du_dy * d.y;
                    sample_uv.v[i] = v + dv_dx * d.x + dv_dy * d.y;
                    sample_uv.du_dx[i] = du_dx;
                    sample_uv.dv_dx[i] = dv_dx;
                    sample_uv.du_dy[i] = du_dy;
                    sample_uv.dv_dy[i] = dv_dy;
                    batch.lane[i] = (slot as u8, bits);
                    batch.lanes += 1;
                });
            });
            batch.flush(
                &fine,
                alpha_to_coverage,
                sample_uv,
                sample_colors,
                (tri.blend, tri.back_facing),
                tile,
            );
        }
        return;
    }
    for_each_run(tri, rect, |y, xa, xb, fy| {
        let mut x = xa;
        // Opaque fragments against the sink's row of depths while it has one: a batch that
        // fills ends the borrow of the row, is shaded and emitted, and the run goes on.
        while !tri.blend && x < xb {
            let Some(row) = tile.occlusion_row(y as u32, x as u32, xb as u32) else {
                break;
            };
            let p = &mut *pending;
            let mut full = false;
            for (&farthest, xx) in row.iter().zip(x..) {
                let e = plane(xx, fy);
                // Most fragments tested here are hidden (nearest first): a product settles
                // them before the division does.
                if e.x * farthest <= SURELY_BEHIND {
                    continue;
                }
                let depth_m = 1.0 / e.x;
                if depth_m >= farthest {
                    continue;
                }
                if p.push(xx, y, depth_m, e) {
                    x = xx + 1;
                    full = true;
                    break;
                }
            }
            if !full {
                return;
            }
            shade_and_emit(p, tile);
        }
        for x in x..xb {
            let e = plane(x, fy);
            let depth_m = 1.0 / e.x;
            if !tri.blend && tile.occluded(x as u32, y as u32, depth_m) {
                continue;
            }
            if pending.push(x, y, depth_m, e) {
                shade_and_emit(pending, tile);
            }
        }
    });
    if pending.n > 0 {
        shade_and_emit(pending, tile);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The multiply-only early rejection never rejects a fragment the division would keep:
    /// over random depths, and pairs at and around equality where rounding decides.
    #[test]
    fn surely_behind_agrees_with_the_division() {
        let mut rng = crate::random::SplitMix64::new(5);
        for _ in 0..2_000_000 {
            let q = 10f32.powf(rng.range(-4.0, 2.0));
            let farthest = match rng.below(4) {
                // Near 1 / q, where the decision is close.
                0 | 1 => (1.0 / q) * (1.0 + rng.range(-1e-6, 1e-6)),
                2 => 10f32.powf(rng.range(-2.0, 4.0)),
                _ => f32::INFINITY,
            };
            if q * farthest <= SURELY_BEHIND {
                assert!(1.0 / q >= farthest, "q {q}, farthest {farthest}");
            }
        }
    }

    /// The plain version of [`for_each_covered`]: every pixel of the box, all three edge
    /// functions stepped along the row and tested.
    fn naive_covered(tri: &SetupTriangle, rect: &TileRect) -> Vec<(usize, usize, f32, f32)> {
        let mut out = Vec::new();
        let x0 = (tri.bbox.0 as usize).max(rect.x0);
        let x1 = (tri.bbox.2 as usize).min(rect.x1 - 1);
        let y0 = (tri.bbox.1 as usize).max(rect.y0);
        let y1 = (tri.bbox.3 as usize).min(rect.y1 - 1);
        let edges = [(1usize, 2usize), (2, 0), (0, 1)];
        for y in y0..=y1 {
            for x in x0..=x1 {
                let p = (x as i64 * ONE + HALF, y as i64 * ONE + HALF);
                let inside = (0..3)
                    .all(|k| edge(tri.v[edges[k].0], tri.v[edges[k].1], p) + tri.bias[k] >= 0);
                if inside {
                    let fx = x as f32 + 0.5 - tri.origin.x;
                    out.push((x, y, fx, y as f32 + 0.5 - tri.origin.y));
                }
            }
        }
        out
    }

    #[test]
    fn double_division_is_integer_floor_division() {
        let mut rng = crate::random::SplitMix64::new(0x9e37_79b9);
        let mut next = move || rng.next_u64();
        for i in 0..200_000 {
            // Magnitudes up to 2^50, exact multiples and their neighbours.
            let b = (next() >> (14 + i % 50)).max(1) as i64;
            let q = (next() >> (14 + (i / 7) % 50)) as i64 % (1 << 50) / b;
            for a in [
                q * b,
                q * b + 1,
                q * b - 1,
                q * b + b - 1,
                (next() >> 14) as i64,
            ] {
                if a >= 0 {
                    assert_eq!(div_floor(a, b), a / b, "{a} / {b}");
                }
            }
        }
    }

    #[test]
    fn row_runs_cover_the_same_pixels_as_testing_every_pixel() {
        let lens = ThinLens {
            width_px: 70,
            height_px: 45,
            f_px: 50.0,
            lens_radius_m: 0.0,
            focus_m: 1.0,
            near_m: 0.1,
            far_m: 10.0,
        };
        let mut state = 0x853c_49e6_748f_ea9bu64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let rects = [
            TileRect {
                x0: 0,
                y0: 0,
                x1: 70,
                y1: 45,
            },
            TileRect {
                x0: 32,
                y0: 32,
                x1: 64,
                y1: 45,
            },
            TileRect {
                x0: 5,
                y0: 7,
                x1: 6,
                y1: 8,
            },
        ];
        let mut tris = Vec::new();
        let mut covered = 0;
        for i in 0..3000 {
            // Mostly small triangles, some huge ones and some slivers; a few snapped to the grid.
            let scale = [4.0, 30.0, 300.0][i % 3];
            let c = Vec2::new(next() * 80.0 - 5.0, next() * 55.0 - 5.0);
            let mut p = [0; 3].map(|_| c + (Vec2::new(next(), next()) - 0.5) * scale);
            if i % 7 == 0 {
                p = p.map(|q| (q * 2.0).round() / 2.0);
            }
            let verts = p.map(|q| (Vec3::new(q.x, q.y, 1.0), Vec2::ZERO));
            tris.clear();
            setup_triangle(&verts, 0, true, false, &lens, false, &mut tris);
            for tri in &tris {
                for rect in &rects {
                    let mut got = Vec::new();
                    for_each_covered(tri, rect, |x, y, fx, fy| got.push((x, y, fx, fy)));
                    assert_eq!(got, naive_covered(tri, rect), "{p:?} in {rect:?}");
                    covered += got.len();
                }
            }
        }
        assert!(covered > 100_000, "only {covered} pixels covered");
    }

    fn lens_70x45() -> ThinLens {
        ThinLens {
            width_px: 70,
            height_px: 45,
            f_px: 50.0,
            lens_radius_m: 0.0,
            focus_m: 1.0,
            near_m: 0.1,
            far_m: 10.0,
        }
    }

    /// The plain version of [`for_each_covered_mask`]: every pixel of the image, every sample
    /// tested against all three edges.
    fn naive_masks(tri: &SetupTriangle, rect: &TileRect) -> Vec<(usize, usize, u16)> {
        let edges = [(1usize, 2usize), (2, 0), (0, 1)];
        let mut out = Vec::new();
        for y in rect.y0..rect.y1 {
            for x in rect.x0..rect.x1 {
                let mut mask = 0u16;
                for (s, &(sx, sy)) in COVERAGE_PATTERN.iter().enumerate() {
                    let p = (
                        x as i64 * ONE + HALF + i64::from(sx) * ONE / 32,
                        y as i64 * ONE + HALF + i64::from(sy) * ONE / 32,
                    );
                    if (0..3)
                        .all(|k| edge(tri.v[edges[k].0], tri.v[edges[k].1], p) + tri.bias[k] >= 0)
                    {
                        mask |= 1 << s;
                    }
                }
                if mask != 0 {
                    out.push((x, y, mask));
                }
            }
        }
        out
    }

    #[test]
    fn coverage_masks_match_testing_every_sample_of_every_pixel() {
        let lens = lens_70x45();
        let rect = TileRect {
            x0: 0,
            y0: 0,
            x1: 70,
            y1: 45,
        };
        let mut rng = crate::random::SplitMix64::new(11);
        let mut tris = Vec::new();
        let mut partial = 0;
        for i in 0..1500 {
            let scale = [0.7, 4.0, 30.0][i % 3];
            let c = Vec2::new(rng.range(-5.0, 75.0), rng.range(-5.0, 50.0));
            let p =
                [0; 3].map(|_| c + Vec2::new(rng.range(-0.5, 0.5), rng.range(-0.5, 0.5)) * scale);
            let verts = p.map(|q| (Vec3::new(q.x, q.y, 1.0), Vec2::ZERO));
            tris.clear();
            setup_triangle(&verts, 0, true, false, &lens, true, &mut tris);
            for tri in &tris {
                let mut got = Vec::new();
                for_each_covered_mask(tri, &rect, &mut got, whole_span, |got, x, y, m, _| {
                    got.push((x, y, m))
                });
                let want = naive_masks(tri, &rect);
                assert_eq!(got, want, "{p:?}");
                partial += got.iter().filter(|g| g.2 != FULL_COVERAGE).count();
            }
        }
        assert!(partial > 10_000, "only {partial} partly covered pixels");
    }

    /// A sink that only answers depth tests, from a farthest depth per pixel of a 70x45 image.
    struct FarthestRows(Vec<f32>);

    impl TileSink for FarthestRows {
        fn occlusion_row(&self, y: u32, xa: u32, xb: u32) -> Option<&[f32]> {
            let row = 70 * y as usize;
            self.0.get(row + xa as usize..row + xb as usize)
        }

        fn fragment(&mut self, _: &Fragment) {}
    }

    #[test]
    fn narrowed_runs_leave_out_only_pixels_the_depth_test_rejects() {
        let corners = [
            Vec2::new(3.3, 2.1),
            Vec2::new(66.2, 9.7),
            Vec2::new(20.5, 41.8),
        ];
        // Depths 1.5 to 3 m (w is the depth), so the plane is not flat.
        let depths = [1.5f32, 3.0, 2.2];
        let verts = [0, 1, 2].map(|k| {
            let (q, w) = (corners[k], depths[k]);
            (Vec3::new(q.x * w, q.y * w, w), Vec2::ZERO)
        });
        let mut rng = crate::random::SplitMix64::new(5);
        for blend in [false, true] {
            let mut tris = Vec::new();
            setup_triangle(&verts, 0, true, blend, &lens_70x45(), true, &mut tris);
            let tri = &tris[0];
            let near = tri.nearest_m;
            // Hidden (nearer than the whole triangle, or level with its nearest point), or
            // not: behind it, nothing yet, NaN.
            let hidden = [0.5 * near, near];
            let open = [2.0 * near, f32::INFINITY, f32::NAN];
            for round in 0..40 {
                // From a few hidden pixels to long hidden stretches.
                let p_hidden = round as f32 / 40.0;
                let sink = FarthestRows(
                    (0..70 * 45)
                        .map(|_| {
                            let k = rng.next_u64() as usize;
                            if rng.next_f32() < p_hidden {
                                hidden[k % 2]
                            } else {
                                open[k % 3]
                            }
                        })
                        .collect(),
                );
                for y in 0..45 {
                    for (xa, xb) in [(0, 70), (12, 50), (33, 34), (40, 40)] {
                        let (a, b) = unhidden_span(&sink, tri, y, xa, xb);
                        assert!(xa <= a && a <= b && b <= xb, "{xa}..{xb} to {a}..{b}");
                        if blend {
                            assert_eq!((a, b), (xa, xb));
                            continue;
                        }
                        for x in (xa..a).chain(b..xb) {
                            let q = 1.0 / (near * (1.0 + rng.next_f32()));
                            assert_eq!(visible_depth(&sink, tri, x, y, q), None, "{x} {y}");
                        }
                        // As narrow as that: its first and last pixels are not hidden.
                        for x in [a, b.max(a + 1) - 1] {
                            if a < b {
                                let farthest = sink.0[70 * y + x];
                                assert!(farthest > near || farthest.is_nan(), "{x} {y}");
                            }
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn two_triangles_of_a_square_split_each_pixel_sample_for_sample() {
        // A square 10.3..40.7 x 5.2..30.9 cut along a diagonal: in every pixel the two halves'
        // masks are disjoint, and together they cover exactly the samples inside the square.
        let lens = lens_70x45();
        let rect = TileRect {
            x0: 0,
            y0: 0,
            x1: 70,
            y1: 45,
        };
        let (a, b, c, d) = (
            Vec2::new(10.3, 5.2),
            Vec2::new(40.7, 5.2),
            Vec2::new(40.7, 30.9),
            Vec2::new(10.3, 30.9),
        );
        let mut masks = vec![[0u16; 2]; 70 * 45];
        for (k, t) in [[a, b, c], [a, c, d]].into_iter().enumerate() {
            let verts = t.map(|q| (Vec3::new(q.x, q.y, 1.0), Vec2::ZERO));
            let mut tris = Vec::new();
            setup_triangle(&verts, 0, true, false, &lens, true, &mut tris);
            for tri in &tris {
                for_each_covered_mask(tri, &rect, &mut masks, whole_span, |masks, x, y, m, _| {
                    masks[y * 70 + x][k] |= m
                });
            }
        }
        let mut full = 0;
        for y in 0..45 {
            for x in 0..70 {
                let [m0, m1] = masks[y * 70 + x];
                assert_eq!(m0 & m1, 0, "({x}, {y})");
                let mut inside = 0u16;
                for (s, &(sx, sy)) in COVERAGE_PATTERN.iter().enumerate() {
                    let (px, py) = (
                        x as f32 + 0.5 + f32::from(sx) / 32.0,
                        y as f32 + 0.5 + f32::from(sy) / 32.0,
                    );
                    if px >= a.x && px < b.x && py >= a.y && py < d.y {
                        inside |= 1 << s;
                    }
                }
                assert_eq!(m0 | m1, inside, "({x}, {y})");
                full += usize::from(inside == FULL_COVERAGE);
            }
        }
        assert!(full > 500);
    }

    /// Alpha to coverage keeps the share of a mask asked for, rounded, and only its samples;
    /// every prefix of the order stays near the pixel centre.
    #[test]
    fn keep_share_keeps_the_share_of_the_mask() {
        let mut order = SPREAD_ORDER.to_vec();
        order.sort_unstable();
        assert_eq!(order, (0..COVERAGE_SAMPLES as u8).collect::<Vec<_>>());
        let mut rng = crate::random::SplitMix64::new(11);
        for _ in 0..10_000 {
            let mask = (rng.next_u64() & 0xffff) as u16;
            let share = rng.next_f32();
            let kept = keep_share(mask, share);
            assert_eq!(kept & !mask, 0, "{mask:016b} {share}");
            let want = (share * mask.count_ones() as f32).round() as u32;
            assert_eq!(kept.count_ones(), want, "{mask:016b} {share}");
        }
        assert_eq!(keep_share(FULL_COVERAGE, 1.0), FULL_COVERAGE);
        assert_eq!(keep_share(FULL_COVERAGE, 0.0), 0);
        // Every mask and every whole count: the first samples of the mask along the order,
        // walked sample by sample.
        for mask in 0..=u16::MAX {
            let count = mask.count_ones();
            assert_eq!(count16(mask), count, "{mask:016b}");
            for k in 0..=count {
                let mut walked = 0u16;
                for &s in SPREAD_ORDER.iter().filter(|&&s| mask & 1 << s != 0) {
                    if walked.count_ones() < k {
                        walked |= 1 << s;
                    }
                }
                let share = k as f32 / count.max(1) as f32;
                assert_eq!(keep_share(mask, share), walked, "{mask:016b} {k}");
            }
        }
        // The rounding at and beside every half up to 16 samples, and off the range.
        for k in 0..=34 {
            let x = k as f32 * 0.5;
            let (below, above) = (
                f32::from_bits(x.to_bits().saturating_sub(1)),
                f32::from_bits(x.to_bits() + 1),
            );
            for x in [x, below, above, -x, -above, f32::NAN] {
                assert_eq!(round_to_count(x), x.round() as u32, "{x}");
            }
        }
        for k in [4usize, 8] {
            let prefix = SPREAD_ORDER[..k].iter().fold(0u16, |m, &s| m | 1 << s);
            let c = mask_centroid(prefix);
            assert!(c.length() < 0.25, "{k} samples centred at {c}");
        }
    }

    #[test]
    fn coverage_of_a_pixel_cut_by_an_edge_is_about_its_area() {
        // A line through (x0, 0.5) tilted by `angle` from the vertical cuts the unit pixel;
        // while it stays inside, the area on its left is x0. One sample per column of the
        // 16x16 grid (n-rooks) puts a vertical edge within 1/16 of its area; a tilted one
        // within 3/16 (measured worst case of this pattern: 2/16 plus a sliver).
        let mut rng = crate::random::SplitMix64::new(3);
        for i in 0..4000 {
            let angle = if i % 2 == 0 {
                0.0
            } else {
                rng.range(-0.6, 0.6)
            };
            let x0 = rng.range(0.35, 0.65);
            let (s, c) = angle.sin_cos();
            let covered = COVERAGE_PATTERN
                .iter()
                .filter(|&&(sx, sy)| {
                    let (px, py) = (0.5 + f32::from(sx) / 32.0, 0.5 + f32::from(sy) / 32.0);
                    (px - x0) * c - (py - 0.5) * s < 0.0
                })
                .count() as f32
                / 16.0;
            let tolerance = if angle == 0.0 { 1.0 / 16.0 } else { 3.0 / 16.0 };
            assert!(
                (covered - x0).abs() <= tolerance + 1e-6,
                "{covered} vs {x0} at {angle}"
            );
        }
    }
}
