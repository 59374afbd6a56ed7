//! Pass `trace` (Lee et al. sections 4.3-4.5): per pixel, N lens rays traced through the
//! layers front to back; the colours of their first hits are averaged.
//!
//! A lens ray through unit-aperture point `v` that lands on pixel `p` passes, at the depth
//! whose signed CoC is `C`, over the pinhole position `q(C) = p - C v` (eq. 3: a point seen at
//! pinhole position `q` appears through lens point `v` at `q + C v`). `q` is linear in `C` and
//! the layers are uniform in `C`, so each layer is a segment of at most `delta |v|` pixels,
//! tested against the layer as a height field of CoCs: the ray has hit when it is at or behind
//! the stored surface (`h(q(C)) <= C`). The segment is sampled a pixel apart from the front;
//! the first sample behind the surface brackets the hit with the one before, and the pixels
//! between the two are walked in order to the first point at or behind the surface as stored
//! (`refine`; the paper's false-position iteration on a linear model of the surface with
//! `--paper-refine`). Empty pixels hold +inf and are never hit. A
//! ray whose segment in a layer leaves the image is discarded, as in the paper. A layer the pixel's rays
//! cannot hit (the minimum over the window they can reach, `cull`, lies beyond the layer) is
//! skipped.
//!
//! A hit meets the layer's premultiplied colour with its coverage in alpha (partly covered
//! pixels and see-through surfaces: [`crate::raster::DepthLayers`]); the ray takes that share
//! and goes on behind with the rest of its weight, as under cone tracing.
//!
//! Cone tracing (section 4.4): at a hit at CoC `C`, the cone around the ray has diameter
//! `lambda |C|` (lambda: the mean distance between neighbouring lens samples); the layer's
//! mipmap at that footprint ([`MipFilter`]) gives a coverage `v1` and a colour `c1`; the ray
//! contributes `v1 c1` and continues behind with weight `1 - v1` (`v1 c1 + (1 - v1) c2`). By
//! default a ray that passes a layer in front of the focal plane without hitting it takes the
//! coverage its cone meets there too (`graze`; the paper's version with `--paper-cone`).
//!
//! Jitter (section 4.5): each pixel uses one of 16 sample sets (different seeds of the shared
//! sampler, so every set covers the aperture as `reference`'s does), picked from a 16x16 noise
//! tile, trading the aliasing of one shared pattern for noise.

use glam::Vec2;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

use super::cull::WindowMin;
use crate::image::{ColorImage, Rgba};
use crate::lens::{LensEffects, ThinLens};
use crate::raster::{from_half, DepthLayers};

/// How far behind the surface under it, in pixels of CoC, a ray may be at its refined hit and
/// still count as crossing it.
pub const THICKNESS_PX: f32 = 0.1;

/// Neighbouring height-field pixels whose CoCs differ by at most this many pixels are one
/// continuous surface: a ray stepping from one onto the other meets it (the layers write a
/// surface hidden farther behind another to the next layer by the same bound).
pub use crate::raster::CONTINUITY_PX;

/// Side of the jitter noise tile in pixels.
pub const NOISE_TILE: usize = 16;

/// How a layer's mipmap levels are filtered (`--cone-mipmap`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MipFilter {
    /// Each texel the mean of the 2x2 texels under it: the paper's (and GPUs') mipmaps. A cone
    /// read's footprint then depends on where the read falls among the texels, which follows
    /// the layers' origin: with the guard band, the largest CoC in view.
    Box,
    /// Each texel the `[1 3 3 1] / 8` tent over the 4x4 texels around it, separably: a
    /// smoother footprint, nearly the same wherever the read falls. Levels are read for a cone
    /// [`MipFilter::level_scale`] as wide, so the footprint is as wide as the box's.
    #[default]
    Tent,
}

impl MipFilter {
    /// Parses `box` or `tent`.
    pub fn parse(s: &str) -> crate::Result<Self> {
        match s.trim() {
            "box" => Ok(Self::Box),
            "tent" => Ok(Self::Tent),
            other => Err(crate::Error::Unknown {
                kind: "cone mipmap",
                name: other.to_string(),
                expected: "box, tent".into(),
            }),
        }
    }

    /// The factor on a cone's diameter at which its levels are chosen. A box level `k` read
    /// bilinearly weighs the pixels with a standard deviation of `2^(k-1)` (the box's
    /// `2^k / sqrt 12` and the bilinear tent's `2^k / sqrt 6`); a tent level `k` with
    /// `sqrt(5/12) 2^k` (each level adds `3/4` of the variance of the texels below it, so the
    /// levels give `(4^k - 1) / 4`, about `4^k / 4`, and the bilinear taps `4^k / 6`). The
    /// tent's levels are read `log2 sqrt(3/5)` lower, so both have the same width.
    pub fn level_scale(self) -> f32 {
        match self {
            Self::Box => 1.0,
            // sqrt(3 / 5).
            Self::Tent => 0.774_596_7,
        }
    }

    /// How far from a cone read's point, in the cone's diameters, the pixels it draws on lie:
    /// the level read is at most one above `log2` of the scaled diameter `s d`, so its texels
    /// are at most `2 s d` wide; the bilinear taps lie a texel away, and a texel draws on pixels
    /// half a texel (box) or under one and a half texels (tent: the `[1 3 3 1]` taps lie up to
    /// 1.5 texels of the level below away, whose own texels reach 1.5 of theirs) from its
    /// centre.
    pub fn reach(self) -> f32 {
        match self {
            Self::Box => 3.0,
            Self::Tent => 5.0 * self.level_scale(),
        }
    }

    /// How far from a bilinear read's point at level `k` (>= 1), in pixels per axis, the
    /// pixels it draws on lie: its taps lie within a texel (`2^k` pixels), and a texel draws on
    /// pixels half a texel from its centre (box) or `1.5 2^k - 1` pixels (tent: `2` at level 1,
    /// then the `[1 3 3 1]` taps `1.5` texels of the level below away, plus theirs).
    pub fn texel_reach(self, k: usize) -> f32 {
        let texel = (1u64 << k.min(62)) as f32;
        match self {
            Self::Box => 1.5 * texel,
            Self::Tent => 2.5 * texel - 1.0,
        }
    }
}

/// Mipmaps of a layer's colour with coverage in alpha (alpha 1 where the layer has a surface,
/// 0 where it is empty), for cone tracing. Level 0 is the layer itself.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerMip {
    /// Levels 1, 2, ...: (width, height, premultiplied RGBA).
    levels: Vec<(usize, usize, Vec<Rgba>)>,
    /// Per level kept, its width and height, for the eight-lane reads ([`cones`]).
    dims: Vec<[i32; 2]>,
    /// Where at most eight levels are kept: their widths, and their heights, eight to a row.
    sizes: Option<[[i32; 8]; 2]>,
}

impl LayerMip {
    /// The mipmap of layer `l`, down to `max_level`, by `filter`.
    pub fn new(layers: &DepthLayers, l: usize, max_level: usize, filter: MipFilter) -> Self {
        let (w, h) = (layers.width, layers.height);
        let mut levels: Vec<(usize, usize, Vec<Rgba>)> = Vec::new();
        if max_level > 0 && w * h > 0 && (w, h) != (1, 1) {
            // Level 1 from the layer's colours, a few rows at a time (converted a slice at a
            // time: F16C where the CPU has it, the same values), empty pixels transparent
            // black: the layer is never held whole in f32.
            let plane = l * w * h;
            let load = |y: usize, row: &mut [Rgba]| {
                let at = plane + y * w..plane + (y + 1) * w;
                layers.color[at.clone()]
                    .as_flattened()
                    .convert_to_f32_slice(row.as_flattened_mut());
                for (c, coc) in row.iter_mut().zip(&layers.coc_px[at]) {
                    if !coc.is_finite() {
                        *c = [0.0; 4];
                    }
                }
            };
            let first = halve(filter, w, h, load);
            // `cur` is the last level made; each level made pushes the one before it.
            let mut cur = (w.div_ceil(2), h.div_ceil(2), first);
            for _ in 1..max_level {
                let (pw, ph, ref p) = cur;
                if pw == 1 && ph == 1 {
                    break;
                }
                let next = halve(filter, pw, ph, |y, row| {
                    row.copy_from_slice(&p[y * pw..][..pw]);
                });
                levels.push(std::mem::replace(
                    &mut cur,
                    (pw.div_ceil(2), ph.div_ceil(2), next),
                ));
            }
            levels.push(cur);
        }
        let dims: Vec<[i32; 2]> = levels.iter().map(|l| [l.0 as i32, l.1 as i32]).collect();
        let sizes = (dims.len() <= 8).then(|| {
            let mut sizes = [[1; 8]; 2];
            for (k, d) in dims.iter().enumerate() {
                (sizes[0][k], sizes[1][k]) = (d[0], d[1]);
            }
            sizes
        });
        Self {
            levels,
            dims,
            sizes,
        }
    }

    /// The premultiplied colour and coverage at level `level` (>= 1) at image position `q`
    /// (pixels), filtered bilinearly between the level's texel centres, clamped to the coarsest
    /// level kept.
    #[inline(always)]
    pub fn fetch(&self, level: usize, q: Vec2) -> Rgba {
        let k = level.min(self.levels.len());
        if k == 0 {
            return [0.0; 4];
        }
        let (w, h, data) = &self.levels[k - 1];
        // 1 / 2^k is exact, so the product is the quotient bit for bit.
        let inv = 1.0 / (1u32 << k) as f32;
        let (u, v) = ((q.x * inv - 0.5).max(0.0), (q.y * inv - 0.5).max(0.0));
        let (x0, y0) = ((u as usize).min(w - 1), (v as usize).min(h - 1));
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (u - x0 as f32, v - y0 as f32);
        let (fx, fy) = (fx.clamp(0.0, 1.0), fy.clamp(0.0, 1.0));
        let mut out = [0.0f32; 4];
        for (x, y, wgt) in [
            (x0, y0, (1.0 - fx) * (1.0 - fy)),
            (x1, y0, fx * (1.0 - fy)),
            (x0, y1, (1.0 - fx) * fy),
            (x1, y1, fx * fy),
        ] {
            let c = data[y * w + x];
            for (o, v) in out.iter_mut().zip(c) {
                *o += wgt * v;
            }
        }
        out
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(|l| l.2.len() * 16).sum()
    }
}

/// The next mipmap level (`w.div_ceil(2)` x `h.div_ceil(2)`) of a `w x h` level whose row `y`
/// `load(y, row)` writes, by `filter`; indices past the level's edges are clamped to them.
fn halve(
    filter: MipFilter,
    w: usize,
    h: usize,
    mut load: impl FnMut(usize, &mut [Rgba]),
) -> Vec<Rgba> {
    let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![[0.0f32; 4]; nw * nh];
    match filter {
        MipFilter::Box => {
            let (mut r0, mut r1) = (vec![[0.0f32; 4]; w], vec![[0.0f32; 4]; w]);
            for (y, row) in out.chunks_exact_mut(nw).enumerate() {
                load(2 * y, &mut r0);
                load((2 * y + 1).min(h - 1), &mut r1);
                halve_row(&r0, &r1, row);
            }
        }
        MipFilter::Tent => {
            // The rows under output row y are 2y - 1 to 2y + 2: four in a ring, by their index
            // mod 4, each loaded once. Vertical tent into `column`, then horizontal.
            let mut ring = vec![[0.0f32; 4]; 4 * w];
            let mut held = [usize::MAX; 4];
            let mut column = vec![[0.0f32; 4]; w];
            for (y, row) in out.chunks_exact_mut(nw).enumerate() {
                let rows =
                    [2 * y, 2 * y + 1, 2 * y + 2, 2 * y + 3].map(|r| (r.max(1) - 1).min(h - 1));
                for r in rows {
                    if held[r % 4] != r {
                        load(r, &mut ring[r % 4 * w..][..w]);
                        held[r % 4] = r;
                    }
                }
                let [a, b, c, d] = rows.map(|r| ring[r % 4 * w..][..w].as_flattened());
                let taps = a.iter().zip(b).zip(c.iter().zip(d));
                for (v, ((a, b), (c, d))) in column.as_flattened_mut().iter_mut().zip(taps) {
                    *v = 0.125 * (a + d) + 0.375 * (b + c);
                }
                tent_row(&column, row);
            }
        }
    }
    out
}

/// A row of the next tent level from a row `v` of the level below: texel `x` weighs `v`'s
/// texels `2x - 1` to `2x + 2` by `[1 3 3 1] / 8`, clamped to the row.
#[inline]
fn tent_row(v: &[Rgba], out: &mut [Rgba]) {
    let last = v.len() - 1;
    for (x, o) in out.iter_mut().enumerate() {
        let (a, b) = (v[(2 * x).max(1) - 1], v[2 * x]);
        let (c, d) = (v[(2 * x + 1).min(last)], v[(2 * x + 2).min(last)]);
        *o = std::array::from_fn(|k| 0.125 * (a[k] + d[k]) + 0.375 * (b[k] + c[k]));
    }
}

/// A row of the next mipmap level from two rows `r0`, `r1` of a level: the mean of each 2x2
/// block (the last column repeated where the width is odd).
#[inline]
fn halve_row(r0: &[Rgba], r1: &[Rgba], out: &mut [Rgba]) {
    let last = r0.len() - 1;
    for (x, o) in out.iter_mut().enumerate() {
        let (x0, x1) = (2 * x, (2 * x + 1).min(last));
        let mut s = [0.0f32; 4];
        for c in [r0[x0], r0[x1], r1[x0], r1[x1]] {
            for k in 0..4 {
                s[k] += 0.25 * c[k];
            }
        }
        *o = s;
    }
}

/// What the trace reads.
pub struct TraceInput<'a> {
    /// The layers.
    pub layers: &'a DepthLayers,
    /// Per layer, the minimum CoC over each pixel's culling window ([`cull_radius`]; `None`:
    /// not culled, e.g. an empty layer has none and is skipped by `filled`).
    pub culls: Option<&'a [Option<WindowMin>]>,
    /// Per layer, whether it has any surface.
    pub filled: &'a [bool],
    /// Per layer, its mipmap for cone tracing (`None`: plain rays).
    pub mips: Option<&'a [LayerMip]>,
    /// How the mipmaps were filtered: the cones' levels are chosen for it.
    pub mip_filter: MipFilter,
    /// With cone tracing: a ray that passes a layer without hitting it still takes the
    /// coverage its cone meets there (`graze`).
    pub graze: bool,
    /// The paper's false-position refinement of a crossing (`refine_false_position`) instead
    /// of `refine`'s walk (portable code only).
    pub paper_refine: bool,
    /// The lens sample sets (unit aperture points); one, or 16 for jitter.
    pub sets: &'a [Vec<Vec2>],
    /// Per pixel of the noise tile, the index of its sample set.
    pub noise: &'a [u8],
    /// Mean distance between neighbouring lens samples (cone diameter per pixel of CoC).
    pub lambda: f32,
    /// The part of the layers traced: `(x0, y0, width, height)` in layer pixels (the frame
    /// inside the layers' guard band). The image has this size.
    pub region: (usize, usize, usize, usize),
    /// The cat's eye and the frame's lens: each pixel keeps only the rays whose lens point
    /// passes the barrel as the pixel sees it ([`LensEffects::barrel`]). `None`: every ray.
    pub clip: Option<(LensEffects, ThinLens)>,
}

/// Where a ray went.
enum Ray {
    /// Left the image: discarded.
    Discarded,
    /// Premultiplied colour gathered (alpha: coverage).
    Color(Rgba),
}

/// Traces every pixel.
pub fn trace(input: &TraceInput) -> ColorImage {
    trace_with(input, trace_row)
}

/// [`trace`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn trace_baseline(input: &TraceInput) -> ColorImage {
    trace_with(input, |input, table, rmax, y, row| {
        trace_row_inner(input, table, rmax, y, row, false)
    })
}

/// The radius of the window around a pixel, in pixels, in which its lens rays can hit layer
/// `l`, or the cones of those that pass it read it (`graze`): a layer with no surface there
/// can be skipped. A ray's position is linear in its CoC, so its samples lie within
/// `max(|C_l|, |C_l+1|) |v|` of the pixel; a grazing cone reads at the middle `C` of the layer,
/// `|C| |v|` away, between the levels `k0` and `k0 + 1` of the layer's `graze_level`, so the
/// pixels it draws on lie within [`MipFilter::texel_reach`] of level `k0 + 1` of that point.
/// (`input.culls` is not read.)
pub fn cull_radius(input: &TraceInput, l: usize) -> usize {
    let rmax = longest_ray(input);
    let (a, b) = input.layers.spacing.bounds(l);
    let hits = (a.abs().max(b.abs()) * rmax).ceil() as i64 + 1;
    let grazes = graze_level(input, l).map_or(0, |(c, level)| {
        (c.abs() * rmax + input.mip_filter.texel_reach(level.k0 + 1)).ceil() as i64 + 1
    });
    hits.max(grazes).max(0) as usize
}

/// The largest `|v|` of the lens samples: pixels of image per pixel of CoC.
fn longest_ray(input: &TraceInput) -> f32 {
    input
        .sets
        .iter()
        .flatten()
        .map(|v| v.length())
        .fold(0.0f32, f32::max)
}

fn trace_with(
    input: &TraceInput,
    row_fn: impl Fn(&TraceInput, &RayTable, f32, usize, &mut [Rgba]) + Sync,
) -> ColorImage {
    let (_, _, w, h) = input.region;
    let rmax = longest_ray(input);
    let table = RayTable::new(input);
    let mut data = vec![[0.0f32; 4]; w * h];
    data.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| row_fn(input, &table, rmax, y, row));
    ColorImage::from_vec(w, h, data).expect("sizes agree by construction")
}

/// One row of [`trace`]. Compiled for several instruction sets and chosen at run time
/// ([`multiversion`]): with SSE4.1 and later `floor` and `ceil` are one instruction instead of
/// a library call; the same arithmetic in every version, so the same bits. No AVX-512 version:
/// on an Intel Xeon with AVX-512 it traced `railing` at 1280x720 10% slower than the AVX2 one
/// (README, "Without AVX-512 where it was slower").
#[multiversion::multiversion(targets("x86_64+avx2", "aarch64+neon"))]
fn trace_row(input: &TraceInput, table: &RayTable, rmax: f32, y: usize, row: &mut [Rgba]) {
    let simd = simd_fits(input.layers.width * input.layers.height);
    trace_row_inner(input, table, rmax, y, row, simd);
}

#[inline(always)]
fn trace_row_inner(
    input: &TraceInput,
    table: &RayTable,
    rmax: f32,
    y: usize,
    row: &mut [Rgba],
    simd: bool,
) {
    let layers = input.layers;
    let m = layers.spacing.layers;
    let mut open = vec![false; m];
    let mut open_list: Vec<usize> = Vec::with_capacity(m);
    let mut kept: Vec<u32> = Vec::with_capacity(input.sets.first().map_or(0, Vec::len));
    let (x0, y0, _, _) = input.region;
    let (fy, y) = (y, y + y0);
    // A pixel at least `reach` from every side of the layers has no ray that leaves them in
    // any layer (q is linear in C between the layers' extreme CoCs), so its rays need no
    // discard test and can skip the layers that are not open. A ray enters each layer the
    // overlap margin in front of its bound, so the nearest CoC it samples is that far before
    // layer 0.
    let (c_first, _) = layers.spacing.bounds(0);
    let c_first = c_first - layers.spacing.overlap * layers.spacing.delta_px;
    let (_, c_last) = layers.spacing.bounds(m.saturating_sub(1));
    let reach = c_first.abs().max(c_last.abs()) * rmax + 1.0;
    let (lw, lh) = (layers.width as f32, layers.height as f32);
    // Per layer, the same for every pixel: its culling windows' minima, and the CoC beyond
    // which its surfaces are missed.
    let culls: Vec<Option<(&WindowMin, f32)>> = (0..m)
        .map(|l| {
            let window = input.culls.and_then(|c| c[l].as_ref())?;
            let (_, b) = layers.spacing.bounds(l);
            Some((window, b + layers.spacing.overlap * layers.spacing.delta_px))
        })
        .collect();
    for (fx, out) in row.iter_mut().enumerate() {
        let x = fx + x0;
        let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
        let safe = p.x - reach >= 0.0 && p.y - reach >= 0.0 && p.x + reach < lw && p.y + reach < lh;
        // Early layer culling for all rays of the pixel.
        for ((o, &filled), cull) in open.iter_mut().zip(input.filled).zip(&culls) {
            *o = filled;
            if let (true, Some((window, limit))) = (filled, cull) {
                *o = window.at(x, y) <= *limit;
            }
        }
        open_list.clear();
        open_list.extend((0..m).filter(|&l| open[l]));
        let set_index = input.noise[(fy % NOISE_TILE) * NOISE_TILE + fx % NOISE_TILE] as usize
            % input.sets.len();
        let set = &input.sets[set_index];
        let mut acc = [0.0f32; 4];
        let mut count = 0u32;
        // The barrel as this pixel of the frame sees it (with a cat's eye).
        let barrel = input.clip.as_ref().map(|(e, lens)| {
            (
                e,
                e.barrel(lens, Vec2::new(fx as f32 + 0.5, fy as f32 + 0.5)),
            )
        });
        if safe {
            // The pixel's rays in packets of LANES, layer by layer.
            kept.clear();
            kept.extend((0..set.len() as u32).filter(|&r| match barrel {
                Some((e, b)) => e.passes(b, set[r as usize]),
                None => true,
            }));
            for rays in kept.chunks(LANES) {
                for c in trace_packet(input, table, set_index, &open_list, p, rays, simd)
                    .iter()
                    .take(rays.len())
                {
                    for k in 0..4 {
                        acc[k] += c[k];
                    }
                }
                count += rays.len() as u32;
            }
        } else {
            for &v in set {
                if let Some((e, b)) = barrel {
                    if !e.passes(b, v) {
                        continue;
                    }
                }
                if let Ray::Color(c) = ray(input, &open, p, v) {
                    for k in 0..4 {
                        acc[k] += c[k];
                    }
                    count += 1;
                }
            }
        }
        if count > 0 {
            let inv = 1.0 / count as f32;
            *out = acc.map(|c| c * inv);
        }
    }
}

/// The steps a ray of `speed` (pixels per pixel of CoC) takes through a layer of CoCs `(ca, cb)`,
/// about one pixel of travel each, and the CoC step: the one formula of [`layer`], the
/// [`RayTable`] and the packets, which must agree bit for bit.
#[inline(always)]
fn layer_steps((ca, cb): (f32, f32), speed: f32) -> (usize, f32) {
    let n = ((cb - ca) * speed).ceil().max(1.0) as usize;
    (n, (cb - ca) / n as f32)
}

/// Traces one lens ray through `v` landing on pixel centre `p`.
#[inline(always)]
fn ray(input: &TraceInput, open: &[bool], p: Vec2, v: Vec2) -> Ray {
    let layers = input.layers;
    let (w, h) = (layers.width as f32, layers.height as f32);
    let spacing = &layers.spacing;
    let mut state = RayState::default();
    let inside = |q: Vec2| q.x >= 0.0 && q.y >= 0.0 && q.x < w && q.y < h;
    let speed = v.length();
    for (l, &is_open) in open.iter().enumerate() {
        let (ca, cb) = spacing.bounds(l);
        // A ray that leaves the image in this layer's segment is discarded (q is linear in C,
        // so the ends decide), whether or not the layer can be skipped: culling must not
        // change which rays count.
        if !inside(p - ca * v) || !inside(p - cb * v) {
            return Ray::Discarded;
        }
        if is_open && layer(input, l, p, v, speed, &mut state) {
            break;
        }
    }
    Ray::Color(state.col)
}

/// Per sample set, ray and layer, what the trace of a ray needs that does not depend on the
/// pixel: its speed `|v|` (pixels per pixel of CoC), and in each layer its number of steps and
/// its CoC step (computed as `layer` computes them, so the same bits); and per layer, where
/// the rays that pass it graze it (`graze_level`, the same for every ray: a `log2` per layer
/// instead of one per packet and layer).
pub struct RayTable {
    rays: usize,
    layers: usize,
    speed: Vec<f32>,
    steps: Vec<(u32, f32)>,
    graze: Vec<Option<(f32, ConeLevel)>>,
}

impl RayTable {
    fn new(input: &TraceInput) -> Self {
        let spacing = &input.layers.spacing;
        let rays = input.sets.iter().map(Vec::len).max().unwrap_or(0);
        let layers = spacing.layers;
        let mut speed = vec![0.0; input.sets.len() * rays];
        let mut steps = vec![(0, 0.0); input.sets.len() * layers * rays];
        for (s, set) in input.sets.iter().enumerate() {
            for (r, v) in set.iter().enumerate() {
                let sp = v.length();
                speed[s * rays + r] = sp;
                for l in 0..layers {
                    let (n, dc) = layer_steps(spacing.bounds(l), sp);
                    steps[(s * layers + l) * rays + r] = (n as u32, dc);
                }
            }
        }
        Self {
            rays,
            layers,
            speed,
            steps,
            graze: (0..layers).map(|l| graze_level(input, l)).collect(),
        }
    }

    #[inline(always)]
    fn speed(&self, set: usize, ray: u32) -> f32 {
        self.speed[set * self.rays + ray as usize]
    }

    /// Steps and CoC step of ray `ray` of set `set` in layer `l`.
    #[inline(always)]
    fn step(&self, set: usize, l: usize, ray: u32) -> (usize, f32) {
        let (n, dc) = self.steps[(set * self.layers + l) * self.rays + ray as usize];
        (n as usize, dc)
    }
}

/// Rays traced together by [`trace_packet`]: two registers of eight with AVX2, walked side by
/// side, so that one register's gathers are under way while the other's samples are tested
/// (the walk waits on its gathers). Against packets of eight, the same images bit for bit, and
/// the trace on `railing` at 1280x720 with 64 rays 1221 -> 1056 ms.
const LANES: usize = 16;

// The lanes are bits of a `u32` (`1 << n` must not overflow), and the AVX2 path reads whole
// registers of eight.
const _: () = assert!(LANES < 32 && LANES.is_multiple_of(8));

/// [`ray`] for up to [`LANES`] rays `rays` of a pixel whose rays stay inside the layers, through
/// the open layers `open` in order, with the same samples and arithmetic as [`layer`], so the
/// same colours bit for bit. The lanes step each layer side by side (independent loads, no
/// branch per sample) and refine their first crossings together; a lane whose first crossing
/// is not a hit (it passes behind a thin object) takes the layer again alone, as [`layer`]
/// does.
#[inline(always)]
fn trace_packet(
    input: &TraceInput,
    table: &RayTable,
    set: usize,
    open: &[usize],
    p: Vec2,
    rays: &[u32],
    simd: bool,
) -> [Rgba; LANES] {
    let layers = input.layers;
    let spacing = &layers.spacing;
    let n = rays.len();
    let mut vx = [0.0f32; LANES];
    let mut vy = [0.0f32; LANES];
    let mut speed = [0.0f32; LANES];
    for (j, &r) in rays.iter().enumerate() {
        let v = input.sets[set][r as usize];
        (vx[j], vy[j], speed[j]) = (v.x, v.y, table.speed(set, r));
    }
    let mut state: [RayState; LANES] = std::array::from_fn(|_| RayState::default());
    // Lanes still tracing, one bit each (the unused ones of a short packet never are). Bits
    // rather than an array of flags: testing the whole packet then reads a register, not
    // sixteen stores.
    let mut live: u32 = (1 << n) - 1;
    // The cone reads of a layer, their rows overwritten for each use rather than made anew (a
    // lane outside the mask is never read, so what it held before does not matter).
    let mut reads = ConeReads::new();
    for &l in open {
        let (ca, _) = spacing.bounds(l);
        let enter = ca - spacing.overlap * spacing.delta_px;
        let mut steps = [0usize; LANES];
        let mut stepsf = [0.0f32; LANES];
        let mut dc = [0.0f32; LANES];
        let mut most = 0;
        for (j, &r) in rays.iter().enumerate() {
            (steps[j], dc[j]) = table.step(set, l, r);
            stepsf[j] = steps[j] as f32;
            if lane(live, j) {
                most = most.max(steps[j]);
            }
        }
        let segment = Segment {
            layers,
            l,
            p,
            ca,
            enter,
            most,
            paper_refine: input.paper_refine,
        };
        let lanes = Lanes {
            vx: &vx,
            vy: &vy,
            dc: &dc,
            steps: &steps,
            stepsf: &stepsf,
            live,
        };
        let Crossings {
            found,
            hi,
            h_lo,
            h_hi,
            i_hi,
        } = if simd && !input.paper_refine {
            crossings_simd(&segment, &lanes)
        } else {
            crossings(&segment, &lanes)
        };
        if let (Some((c, level)), Some(mips)) = (table.graze[l], input.mips) {
            // `graze_at` for the lanes that passed the layer, their cones read together: where
            // they read, all lanes side by side (a lane outside the mask is not read).
            reads.mask = live & !found;
            for j in 0..LANES {
                (reads.qx[j], reads.qy[j]) = (p.x - c * vx[j], p.y - c * vy[j]);
            }
            (reads.k0, reads.t) = ([level.k0 as i32; LANES], [level.t; LANES]);
            if level.k0 == 0 {
                // Level 0 is the pixel the ray passed, which it missed.
                reads.level0 = [[0.0; 4]; LANES];
            }
            if reads.any() {
                let colors = cones(&mips[l], &reads, simd);
                for j in lanes_of(reads.mask) {
                    let c1 = &colors[j];
                    if c1[3] > 0.0 && state[j].take(c1) {
                        live &= !(1 << j);
                    }
                }
            }
        }
        if found == 0 {
            if live == 0 {
                break;
            }
            continue;
        }
        // The crossings, as `layer` and `shade` take them lane by lane: first, all lanes side by
        // side (a loop the compiler vectorises; the lanes without a crossing compute values
        // unused), whether each is a hit, whether its cone reads the mipmaps (a cone wider than
        // a pixel, `ConeLevel::with_log2`), its levels and where it reads.
        let width = input.lambda * input.mip_filter.level_scale();
        let mut hits = 0u32;
        let mut wide = 0u32;
        let (mut k0, mut t) = ([0i32; LANES], [0.0f32; LANES]);
        let (mut qx, mut qy) = ([0.0f32; LANES], [0.0f32; LANES]);
        for j in 0..LANES {
            // A ray meets the surface where it crosses it (refined to within THICKNESS_PX), or
            // where it steps onto it from a continuation of the same surface (see `layer`).
            let hit = meets(hi[j], h_hi[j], h_lo[j]);
            let d = width * hi[j].abs();
            let f = log2(d);
            // `ConeLevel::with_log2`: where `d > 1`, `f > 0`, so the floor is its whole part.
            let floor = f.floor();
            (k0[j], t[j]) = (floor as i32, f - floor);
            (qx[j], qy[j]) = (p.x - hi[j] * vx[j], p.y - hi[j] * vy[j]);
            hits |= u32::from(hit) << j;
            wide |= u32::from(d > 1.0) << j;
        }
        hits &= found;
        let cone_lanes = if input.mips.is_some() { hits & wide } else { 0 };
        for j in lanes_of(found & !hits) {
            // Behind a thin object: the rest of the layer, as `layer` walks it.
            if layer(
                input,
                l,
                p,
                Vec2::new(vx[j], vy[j]),
                speed[j],
                &mut state[j],
            ) {
                live &= !(1 << j);
            }
        }
        for j in lanes_of(hits & !cone_lanes) {
            // Level 0 alone, or no mipmaps: the hit pixel's colour.
            if state[j].take(&half4(&layers.color[i_hi[j]], simd)) {
                live &= !(1 << j);
            }
        }
        if let (true, Some(mips)) = (cone_lanes != 0, input.mips) {
            // The hits' cone reads, made together (a lane outside the mask is not read).
            (reads.mask, reads.qx, reads.qy, reads.k0, reads.t) = (cone_lanes, qx, qy, k0, t);
            for j in lanes_of(cone_lanes) {
                if k0[j] == 0 {
                    reads.level0[j] = half4(&layers.color[i_hi[j]], simd);
                }
            }
            let colors = cones(&mips[l], &reads, simd);
            for j in lanes_of(cone_lanes) {
                if state[j].take(&colors[j]) {
                    live &= !(1 << j);
                }
            }
        }
        if live == 0 {
            break;
        }
    }
    state.map(|s| s.col)
}

/// Whether lane `j` is set in the lane bits `bits`.
#[inline(always)]
fn lane(bits: u32, j: usize) -> bool {
    bits >> j & 1 != 0
}

/// The lanes set in the lane bits `bits`, in order.
#[inline(always)]
fn lanes_of(mut bits: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (bits != 0).then(|| {
            let j = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            j
        })
    })
}

/// The rays of a packet, as [`crossings`] reads them.
struct Lanes<'a> {
    vx: &'a [f32; LANES],
    vy: &'a [f32; LANES],
    /// CoC step of each lane in this layer, and its number of steps.
    dc: &'a [f32; LANES],
    steps: &'a [usize; LANES],
    stepsf: &'a [f32; LANES],
    /// Lanes still tracing, one bit each.
    live: u32,
}

/// Each lane's first crossing in a layer, refined: whether it has one, the ray's CoC there,
/// the surface's CoC just in front of it and at it, and the index of the pixel hit in the whole
/// stack of layers.
struct Crossings {
    /// One bit per lane.
    found: u32,
    hi: [f32; LANES],
    h_lo: [f32; LANES],
    h_hi: [f32; LANES],
    i_hi: [usize; LANES],
}

/// Where a packet walks one layer: layer `l` of `layers`, for the pixel centre `p`, from
/// `enter` in front of the layer's front bound `ca`, in at most `most` steps.
struct Segment<'a> {
    layers: &'a DepthLayers,
    l: usize,
    p: Vec2,
    ca: f32,
    enter: f32,
    most: usize,
    /// [`refine_false_position`] instead of [`refine`] (the portable twin only).
    paper_refine: bool,
}

/// The lanes' first crossings in the layer of `seg`, refined by [`refine`]. The portable twin
/// of [`crossings_simd`].
#[inline(always)]
fn crossings(seg: &Segment, lanes: &Lanes) -> Crossings {
    let (layers, l, p) = (seg.layers, seg.l, seg.p);
    let (vx, vy, dc, steps, live) = (lanes.vx, lanes.vy, lanes.dc, lanes.steps, lanes.live);
    let v = |j: usize| Vec2::new(vx[j], vy[j]);
    // Per lane: its first crossing from in front to behind (the samples around it).
    let mut found = [false; LANES];
    let mut lo = [0.0f32; LANES];
    let mut hi = [0.0f32; LANES];
    let mut prev = [seg.enter; LANES];
    let mut prev_front = [true; LANES];
    let mut h_prev = [f32::INFINITY; LANES];
    for k in 0..=seg.most {
        for j in 0..LANES {
            let kk = k.min(steps[j]);
            let c = seg.ca + dc[j] * kk as f32;
            let q = p - c * v(j);
            let h = layers.coc_px[layers.index(l, q.x as usize, q.y as usize)];
            let behind = h <= c;
            let cross = lane(live, j)
                && !found[j]
                && k <= steps[j]
                && prev_front[j]
                && bracketed(h, h_prev[j], c);
            if cross {
                (lo[j], hi[j]) = (prev[j], c);
            }
            found[j] |= cross;
            prev_front[j] = !behind;
            prev[j] = c;
            h_prev[j] = h;
        }
    }
    let mut out = Crossings {
        found: (0..LANES).fold(0, |m, j| m | u32::from(found[j]) << j),
        hi,
        h_lo: [0.0; LANES],
        h_hi: [0.0; LANES],
        i_hi: [0; LANES],
    };
    for j in 0..LANES {
        if found[j] {
            // The packet's pixel keeps its rays inside the layers: `refine` finds the hit.
            let (c, i, h) = refine_as(seg.paper_refine, layers, l, p, v(j), lo[j], hi[j])
                .unwrap_or((hi[j], 0, 0.0));
            (out.hi[j], out.i_hi[j], out.h_lo[j]) = (c, i, h);
            out.h_hi[j] = layers.coc_px[i];
        }
    }
    out
}

/// [`crossings`] with the lanes in AVX2 registers and the samples gathered, where the CPU has
/// AVX2 (the same arithmetic, without fused multiply-adds, so the same bits); elsewhere the
/// portable twin.
#[inline(always)]
fn crossings_simd(seg: &Segment, lanes: &Lanes) -> Crossings {
    #[cfg(target_arch = "x86_64")]
    {
        // Checked once per row by the caller; indices fit in i32 (`simd_fits`).
        // SAFETY: `simd` is only set where `is_x86_feature_detected!("avx2")` held.
        unsafe { avx2::crossings(seg, lanes) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        crossings(seg, lanes)
    }
}

/// A stored colour in f32: with F16C where `simd` says the CPU has it (the same values: the
/// conversion is exact).
#[inline(always)]
fn half4(c: &crate::raster::HalfRgba, simd: bool) -> Rgba {
    #[cfg(target_arch = "x86_64")]
    if simd {
        // SAFETY: `simd` is only set where F16C was detected (`simd_fits`).
        return unsafe { avx2::half4(c) };
    }
    let _ = simd;
    from_half(c)
}

/// Whether the AVX2 path can run on layers of `len` pixels each: the CPU has AVX2 and F16C, and
/// plane indices fit its 32-bit gathers.
fn simd_fits(len: usize) -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        len < i32::MAX as usize
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("f16c")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = len;
        false
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{ConeReads, Crossings, Lanes, LayerMip, Segment, LANES};
    use crate::image::Rgba;
    use std::arch::x86_64::*;

    /// Four halves to f32 with F16C.
    #[target_feature(enable = "f16c")]
    pub(super) unsafe fn half4(c: &crate::raster::HalfRgba) -> crate::image::Rgba {
        let bits = c.map(|h| h.to_bits() as u64);
        let packed = bits[0] | bits[1] << 16 | bits[2] << 32 | bits[3] << 48;
        let v = _mm_cvtph_ps(_mm_cvtsi64_si128(packed as i64));
        let mut out = [0.0f32; 4];
        _mm_storeu_ps(out.as_mut_ptr(), v);
        out
    }

    /// See [`super::cones`]: [`super::LayerMip::fetch`] of levels `k0` (where it is not 0)
    /// and `k0 + 1` for eight lanes at once, then [`super::cone`]'s blend per lane.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn cones(mip: &LayerMip, reads: &ConeReads) -> [Rgba; LANES] {
        let mut out = [[0.0f32; 4]; LANES];
        for at in (0..LANES).step_by(W) {
            if (reads.mask >> at) & 0xff == 0 {
                continue;
            }
            let k0 = _mm256_loadu_si256(reads.k0[at..].as_ptr().cast());
            let qx = _mm256_loadu_ps(reads.qx[at..].as_ptr());
            let qy = _mm256_loadu_ps(reads.qy[at..].as_ptr());
            let a = taps(mip, k0, qx, qy);
            let b = taps(mip, _mm256_add_epi32(k0, _mm256_set1_epi32(1)), qx, qy);
            for (jj, o) in out[at..at + W].iter_mut().enumerate() {
                let j = at + jj;
                if !super::lane(reads.mask, j) {
                    continue;
                }
                let ca = if reads.k0[j] == 0 {
                    _mm_loadu_ps(reads.level0[j].as_ptr())
                } else {
                    a.bilinear(mip, jj)
                };
                let cb = b.bilinear(mip, jj);
                let t = _mm_set1_ps(reads.t[j]);
                let c = _mm_add_ps(ca, _mm_mul_ps(t, _mm_sub_ps(cb, ca)));
                _mm_storeu_ps(o.as_mut_ptr(), c);
            }
        }
        out
    }

    /// Per lane, the level read (0-based in `LayerMip::levels`), its four texels' indices and
    /// their bilinear weights, in the order [`super::LayerMip::fetch`] sums them.
    struct Taps {
        level: [i32; W],
        index: [[i32; W]; 4],
        weight: [[f32; W]; 4],
    }

    impl Taps {
        /// Lane `j`'s bilinear read, summed as `fetch` sums it.
        #[inline(always)]
        unsafe fn bilinear(&self, mip: &LayerMip, j: usize) -> __m128 {
            let data = mip.levels[self.level[j] as usize].2.as_ptr().cast::<f32>();
            let mut c = _mm_setzero_ps();
            for k in 0..4 {
                let texel = _mm_loadu_ps(data.add(4 * self.index[k][j] as usize));
                c = _mm_add_ps(c, _mm_mul_ps(_mm_set1_ps(self.weight[k][j]), texel));
            }
            c
        }
    }

    /// [`super::LayerMip::fetch`]'s texel positions and weights at levels `k` (>= 1) for eight
    /// lanes: the same operations, so the same values.
    #[inline(always)]
    unsafe fn taps(mip: &LayerMip, k: __m256i, qx: __m256, qy: __m256) -> Taps {
        let one_i = _mm256_set1_epi32(1);
        // At least level 1: lanes that read no level (outside the mask, or `k0` 0) still
        // index the tables in bounds.
        let kk = _mm256_max_epi32(
            _mm256_min_epi32(k, _mm256_set1_epi32(mip.levels.len() as i32)),
            one_i,
        );
        let level = _mm256_sub_epi32(kk, one_i);
        // A level's size: from a register where the levels fit one (a permute, where a gather
        // waits on memory), else gathered.
        let (w, h) = match &mip.sizes {
            Some([ws, hs]) => (
                _mm256_permutevar8x32_epi32(_mm256_loadu_si256(ws.as_ptr().cast()), level),
                _mm256_permutevar8x32_epi32(_mm256_loadu_si256(hs.as_ptr().cast()), level),
            ),
            None => {
                let dims = mip.dims.as_ptr().cast::<i32>();
                (
                    _mm256_i32gather_epi32::<4>(dims, _mm256_add_epi32(level, level)),
                    _mm256_i32gather_epi32::<4>(dims.add(1), _mm256_add_epi32(level, level)),
                )
            }
        };
        // 1 / 2^k from its exponent: exact, as the scalar quotient.
        let inv = _mm256_castsi256_ps(_mm256_slli_epi32::<23>(_mm256_sub_epi32(
            _mm256_set1_epi32(127),
            kk,
        )));
        // `(q * inv - 0.5).max(0.0)`, its cell clamped into the level and the fraction into
        // [0, 1] (clamping before the conversion gives the same cell as after it). Plain
        // functions, not closures, so that they inline with AVX2.
        #[inline(always)]
        unsafe fn axis(q: __m256, n: __m256i, inv: __m256) -> (__m256i, __m256i, __m256) {
            let (zero, one, half) = (
                _mm256_setzero_ps(),
                _mm256_set1_ps(1.0),
                _mm256_set1_ps(0.5),
            );
            let one_i = _mm256_set1_epi32(1);
            let u = _mm256_max_ps(_mm256_sub_ps(_mm256_mul_ps(q, inv), half), zero);
            let last = _mm256_sub_epi32(n, one_i);
            let c0 = _mm256_cvttps_epi32(_mm256_min_ps(u, _mm256_cvtepi32_ps(last)));
            let c1 = _mm256_min_epi32(_mm256_add_epi32(c0, one_i), last);
            let f = _mm256_sub_ps(u, _mm256_cvtepi32_ps(c0));
            (c0, c1, _mm256_min_ps(_mm256_max_ps(f, zero), one))
        }
        #[inline(always)]
        unsafe fn row(y: __m256i, x: __m256i, w: __m256i) -> __m256i {
            _mm256_add_epi32(_mm256_mullo_epi32(y, w), x)
        }
        let (x0, x1, fx) = axis(qx, w, inv);
        let (y0, y1, fy) = axis(qy, h, inv);
        let one = _mm256_set1_ps(1.0);
        let (gx, gy) = (_mm256_sub_ps(one, fx), _mm256_sub_ps(one, fy));
        let mut out = Taps {
            level: [0; W],
            index: [[0; W]; 4],
            weight: [[0.0; W]; 4],
        };
        _mm256_storeu_si256(out.level.as_mut_ptr().cast(), level);
        for (k, (i, wt)) in [
            (row(y0, x0, w), _mm256_mul_ps(gx, gy)),
            (row(y0, x1, w), _mm256_mul_ps(fx, gy)),
            (row(y1, x0, w), _mm256_mul_ps(gx, fy)),
            (row(y1, x1, w), _mm256_mul_ps(fx, fy)),
        ]
        .into_iter()
        .enumerate()
        {
            _mm256_storeu_si256(out.index[k].as_mut_ptr().cast(), i);
            _mm256_storeu_ps(out.weight[k].as_mut_ptr(), wt);
        }
        out
    }

    /// Plane indices of the samples at CoCs `c`, clamped into the plane (`last` its last
    /// index), so a gather never reads outside it whatever the positions.
    #[inline(always)]
    unsafe fn index(
        c: __m256,
        px: __m256,
        py: __m256,
        vx: __m256,
        vy: __m256,
        w: __m256i,
        last: __m256i,
    ) -> __m256i {
        let qx = _mm256_sub_ps(px, _mm256_mul_ps(c, vx));
        let qy = _mm256_sub_ps(py, _mm256_mul_ps(c, vy));
        let i = _mm256_add_epi32(
            _mm256_mullo_epi32(_mm256_cvttps_epi32(qy), w),
            _mm256_cvttps_epi32(qx),
        );
        _mm256_min_epi32(_mm256_max_epi32(i, _mm256_setzero_si256()), last)
    }

    /// `new` in the lanes of `mask`, `old` elsewhere, for plane indices.
    #[inline(always)]
    unsafe fn select_index(old: __m256i, new: __m256i, mask: __m256) -> __m256i {
        _mm256_castps_si256(_mm256_blendv_ps(
            _mm256_castsi256_ps(old),
            _mm256_castsi256_ps(new),
            mask,
        ))
    }

    /// Lanes a register holds.
    const W: usize = 8;

    /// What is fixed for a walk of one layer: the layer's plane of CoCs and the pixel centre.
    struct Walk {
        base: *const f32,
        last: __m256i,
        wv: __m256i,
        px: __m256,
        py: __m256,
    }

    impl Walk {
        /// The plane index of the sample at CoCs `c` of the rays `(vx, vy)`.
        #[inline(always)]
        unsafe fn index(&self, c: __m256, vx: __m256, vy: __m256) -> __m256i {
            index(c, self.px, self.py, vx, vy, self.wv, self.last)
        }

        #[inline(always)]
        unsafe fn gather(&self, i: __m256i) -> __m256 {
            _mm256_i32gather_ps::<4>(self.base, i)
        }
    }

    /// Eight lanes of a packet walking a layer: [`super::crossings`]' state for them. A packet
    /// is walked a register of lanes after another within each step, so that one register's
    /// gathers are under way while the other's results are tested.
    struct Octet {
        vx: __m256,
        vy: __m256,
        dc: __m256,
        steps: __m256,
        seeking: __m256,
        found: __m256,
        lo: __m256,
        hi: __m256,
        prev: __m256,
        prev_front: __m256,
        // The samples at the bracket's ends, kept as they are gathered (the refinement starts
        // from them), and the lanes whose bracket opens at the entry point, which no step
        // sampled.
        h_prev: __m256,
        h_lo: __m256,
        h_hi: __m256,
        i_hi: __m256i,
        from_entry: __m256,
    }

    impl Octet {
        #[inline(always)]
        unsafe fn new(lanes: &Lanes, at: usize, enter: f32) -> Self {
            let bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
            let live = _mm256_set1_epi32((lanes.live >> at) as i32);
            Self {
                vx: _mm256_loadu_ps(lanes.vx[at..].as_ptr()),
                vy: _mm256_loadu_ps(lanes.vy[at..].as_ptr()),
                dc: _mm256_loadu_ps(lanes.dc[at..].as_ptr()),
                steps: _mm256_loadu_ps(lanes.stepsf[at..].as_ptr()),
                seeking: _mm256_castsi256_ps(_mm256_cmpeq_epi32(
                    _mm256_and_si256(live, bits),
                    bits,
                )),
                found: _mm256_setzero_ps(),
                lo: _mm256_setzero_ps(),
                hi: _mm256_setzero_ps(),
                prev: _mm256_set1_ps(enter),
                prev_front: _mm256_castsi256_ps(_mm256_set1_epi32(-1)),
                h_prev: _mm256_set1_ps(f32::INFINITY),
                h_lo: _mm256_setzero_ps(),
                h_hi: _mm256_setzero_ps(),
                i_hi: _mm256_setzero_si256(),
                from_entry: _mm256_setzero_ps(),
            }
        }

        /// Step `k` (at CoC `ca` + `k` steps): the lanes still seeking whose ray crosses from
        /// in front of the surface to behind it take the bracket.
        #[inline(always)]
        unsafe fn step(&mut self, walk: &Walk, k: usize, cav: __m256) {
            let all = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
            let kf = _mm256_set1_ps(k as f32);
            let in_layer = _mm256_cmp_ps::<_CMP_LE_OQ>(kf, self.steps);
            let c = _mm256_add_ps(cav, _mm256_mul_ps(self.dc, _mm256_min_ps(kf, self.steps)));
            let i = walk.index(c, self.vx, self.vy);
            let h = walk.gather(i);
            let behind = _mm256_cmp_ps::<_CMP_LE_OQ>(h, c);
            // `super::bracketed`: behind the surface now, or past the previous one's CoC.
            let bracket = _mm256_or_ps(behind, _mm256_cmp_ps::<_CMP_LE_OQ>(self.h_prev, c));
            let cross = _mm256_and_ps(
                _mm256_and_ps(self.seeking, in_layer),
                _mm256_and_ps(bracket, self.prev_front),
            );
            self.lo = _mm256_blendv_ps(self.lo, self.prev, cross);
            self.hi = _mm256_blendv_ps(self.hi, c, cross);
            self.h_lo = _mm256_blendv_ps(self.h_lo, self.h_prev, cross);
            self.h_hi = _mm256_blendv_ps(self.h_hi, h, cross);
            self.i_hi = select_index(self.i_hi, i, cross);
            if k == 0 {
                self.from_entry = cross;
            }
            self.found = _mm256_or_ps(self.found, cross);
            self.seeking = _mm256_andnot_ps(cross, self.seeking);
            self.prev_front = _mm256_andnot_ps(behind, all);
            self.prev = c;
            self.h_prev = h;
        }

        /// Before the refinement: the surface at the entry point of the lanes whose bracket
        /// opens there.
        #[inline(always)]
        unsafe fn entry(&mut self, walk: &Walk) {
            if _mm256_movemask_ps(self.from_entry) != 0 {
                let at_entry = walk.gather(walk.index(self.lo, self.vx, self.vy));
                self.h_lo = _mm256_blendv_ps(self.h_lo, at_entry, self.from_entry);
            }
        }

        /// The lanes' hits, as `refine` finds them: the pixels between the bracket's ends
        /// walked in order, all lanes side by side, one gather a pixel.
        #[inline(always)]
        unsafe fn refine(&mut self, walk: &Walk) {
            let zero = _mm256_setzero_ps();
            let one = _mm256_set1_epi32(1);
            let inf = _mm256_set1_ps(f32::INFINITY);
            let pixel = |c: __m256| {
                (
                    _mm256_cvttps_epi32(_mm256_sub_ps(walk.px, _mm256_mul_ps(c, self.vx))),
                    _mm256_cvttps_epi32(_mm256_sub_ps(walk.py, _mm256_mul_ps(c, self.vy))),
                )
            };
            let (mut x, mut y) = pixel(self.lo);
            let (bx, by) = pixel(self.hi);
            // Where `v > 0` the next boundary is the pixel's lower side and the walk steps
            // down (-1); elsewhere its upper side (+1), stepping up.
            let down_x = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GT_OQ>(self.vx, zero));
            let down_y = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GT_OQ>(self.vy, zero));
            let (ox, oy) = (
                _mm256_andnot_si256(down_x, one),
                _mm256_andnot_si256(down_y, one),
            );
            let (sx, sy) = (_mm256_or_si256(down_x, one), _mm256_or_si256(down_y, one));
            let ones = _mm256_set1_ps(1.0);
            let (inv_x, inv_y) = (_mm256_div_ps(ones, self.vx), _mm256_div_ps(ones, self.vy));
            let mut c_in = self.lo;
            let mut h_front = self.h_lo;
            let mut active = self.found;
            while _mm256_movemask_ps(active) != 0 {
                let i = _mm256_min_epi32(
                    _mm256_max_epi32(
                        _mm256_add_epi32(_mm256_mullo_epi32(y, walk.wv), x),
                        _mm256_setzero_si256(),
                    ),
                    walk.last,
                );
                let h_px = walk.gather(i);
                let more_x = _mm256_xor_ps(
                    _mm256_castsi256_ps(_mm256_cmpeq_epi32(x, bx)),
                    _mm256_castsi256_ps(_mm256_set1_epi32(-1)),
                );
                let more_y = _mm256_xor_ps(
                    _mm256_castsi256_ps(_mm256_cmpeq_epi32(y, by)),
                    _mm256_castsi256_ps(_mm256_set1_epi32(-1)),
                );
                let side = |p: __m256, t: __m256i, o: __m256i, inv: __m256| {
                    _mm256_mul_ps(
                        _mm256_sub_ps(p, _mm256_cvtepi32_ps(_mm256_add_epi32(t, o))),
                        inv,
                    )
                };
                let cx = _mm256_blendv_ps(inf, side(walk.px, x, ox, inv_x), more_x);
                let cy = _mm256_blendv_ps(inf, side(walk.py, y, oy, inv_y), more_y);
                let c_next = _mm256_min_ps(cx, cy);
                let last = _mm256_andnot_ps(_mm256_or_ps(more_x, more_y), active);
                let met = _mm256_cmp_ps::<_CMP_LE_OQ>(h_px, _mm256_min_ps(c_next, self.hi));
                let hit = _mm256_or_ps(_mm256_and_ps(met, active), last);
                let c_hit = _mm256_min_ps(_mm256_max_ps(c_in, h_px), self.hi);
                self.hi = _mm256_blendv_ps(self.hi, c_hit, hit);
                self.h_hi = _mm256_blendv_ps(self.h_hi, h_px, hit);
                self.i_hi = select_index(self.i_hi, i, hit);
                self.h_lo = _mm256_blendv_ps(self.h_lo, h_front, hit);
                active = _mm256_andnot_ps(hit, active);
                let step_x = _mm256_and_ps(more_x, _mm256_cmp_ps::<_CMP_LT_OQ>(cx, cy));
                let step_y = _mm256_andnot_ps(step_x, active);
                let step_x = _mm256_and_ps(step_x, active);
                x = _mm256_add_epi32(x, _mm256_and_si256(sx, _mm256_castps_si256(step_x)));
                y = _mm256_add_epi32(y, _mm256_and_si256(sy, _mm256_castps_si256(step_y)));
                h_front = h_px;
                c_in = c_next;
            }
        }
    }

    /// See [`super::crossings`]: the same samples, tests and refinement, the packet's lanes
    /// eight to a register, the registers interleaved.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn crossings(seg: &Segment, lanes: &Lanes) -> Crossings {
        let (w, h) = (seg.layers.width, seg.layers.height);
        let plane = &seg.layers.coc_px[seg.l * w * h..(seg.l + 1) * w * h];
        let walk = Walk {
            base: plane.as_ptr(),
            last: _mm256_set1_epi32(plane.len() as i32 - 1),
            wv: _mm256_set1_epi32(w as i32),
            px: _mm256_set1_ps(seg.p.x),
            py: _mm256_set1_ps(seg.p.y),
        };
        let cav = _mm256_set1_ps(seg.ca);
        let mut octets: [Octet; LANES / W] =
            std::array::from_fn(|o| Octet::new(lanes, o * W, seg.enter));
        for k in 0..=seg.most {
            let mut seeking = 0;
            for o in octets.iter_mut() {
                o.step(&walk, k, cav);
                seeking |= _mm256_movemask_ps(o.seeking);
            }
            if seeking == 0 {
                break;
            }
        }
        let mut out = Crossings {
            found: 0,
            hi: [0.0; LANES],
            h_lo: [0.0; LANES],
            h_hi: [0.0; LANES],
            i_hi: [0; LANES],
        };
        for (n, o) in octets.iter().enumerate() {
            out.found |= (_mm256_movemask_ps(o.found) as u32) << (n * W);
        }
        if out.found == 0 {
            return out;
        }
        // The hits, as `refine` finds them, from the samples at the bracket's ends.
        for o in octets.iter_mut() {
            o.entry(&walk);
            o.refine(&walk);
        }
        for (n, o) in octets.iter().enumerate() {
            let mut idx = [0i32; W];
            _mm256_storeu_si256(idx.as_mut_ptr().cast(), o.i_hi);
            _mm256_storeu_ps(out.hi[n * W..].as_mut_ptr(), o.hi);
            _mm256_storeu_ps(out.h_lo[n * W..].as_mut_ptr(), o.h_lo);
            _mm256_storeu_ps(out.h_hi[n * W..].as_mut_ptr(), o.h_hi);
            for (j, &i) in idx.iter().enumerate() {
                out.i_hi[n * W + j] = seg.l * w * h + i as usize;
            }
        }
        out
    }
}

/// What a ray has gathered: premultiplied colour, and the weight left for what lies behind.
struct RayState {
    col: Rgba,
    weight: f32,
}

impl RayState {
    /// Takes the premultiplied colour `c1` (coverage `v1` in alpha) with the weight left, and
    /// keeps `1 - v1` of it for what lies behind (`v1 c1 + (1 - v1) c2`). True when the ray is
    /// done (what remains behind weighs under 1e-3).
    #[inline(always)]
    fn take(&mut self, c1: &Rgba) -> bool {
        let v1 = c1[3].clamp(0.0, 1.0);
        // v1 c1 is the premultiplied mip colour itself.
        for (o, c) in self.col.iter_mut().zip(c1).take(3) {
            *o += self.weight * c;
        }
        self.col[3] += self.weight * v1;
        self.weight *= 1.0 - v1;
        self.weight < 1e-3
    }
}

impl Default for RayState {
    fn default() -> Self {
        Self {
            col: [0.0; 4],
            weight: 1.0,
        }
    }
}

/// Traces the ray through layer `l` and takes its colour at the hit, if any. True when the ray
/// is done (what remains behind weighs under 1e-3).
#[inline(always)]
fn layer(input: &TraceInput, l: usize, p: Vec2, v: Vec2, speed: f32, state: &mut RayState) -> bool {
    let layers = input.layers;
    let spacing = &layers.spacing;
    let (ca, cb) = spacing.bounds(l);
    let (steps, dc) = layer_steps((ca, cb), speed);
    // The ray was in front of the surface under it at the previous sample; a crossing from
    // there to behind it brackets a hit. It enters the layer in front of everything the
    // layer holds: the overlap margin before its front bound.
    let mut prev = ca - spacing.overlap * spacing.delta_px;
    let mut prev_front = true;
    // The surface under the previous sample (none at the entry point, which no step sampled).
    let mut h_prev = f32::INFINITY;
    let mut hit = None;
    for k in 0..=steps {
        let c = ca + dc * k as f32;
        let q = p - c * v;
        let i = layers.index(l, q.x as usize, q.y as usize);
        let h = layers.coc_px[i];
        let behind = h <= c;
        // A bracket: the ray is behind the surface under it now, or may have passed behind
        // the previous sample's surface before leaving its pixel ([`bracketed`]).
        if prev_front && bracketed(h, h_prev, c) {
            let (c_hit, i_hit, h_front) = refine_as(input.paper_refine, layers, l, p, v, prev, c)
                .unwrap_or((c, i, f32::INFINITY));
            // A ray meets the surface where it crosses it (refined to within
            // THICKNESS_PX), or where it steps onto it from a continuation of the same
            // surface (a slanted surface sampled pixel by pixel); one that comes in from
            // the side of a thin object, from empty space or from a surface far in
            // front, passes behind it. A ray still in front of the surface at the
            // bracket's far end crossed nothing.
            let h_hit = layers.coc_px[i_hit];
            if meets(c_hit, h_hit, h_front) {
                hit = Some((c_hit, i_hit));
                break;
            }
        }
        prev_front = !behind;
        prev = c;
        h_prev = h;
    }
    let Some((c_hit, i)) = hit else {
        return graze(input, l, p, v, state);
    };
    shade(input, p, v, Hit { l, c: c_hit, i }, state, false)
}

/// Whether the step to a sample at CoC `c` over a surface at `h`, from one over a surface at
/// `h_prev` where the ray was in front, may hold the ray's first crossing: it is behind the
/// surface under it now, or it reached the previous surface's CoC within the step, so it may
/// have met that surface before leaving its pixel (a step moves about a pixel; at a surface's
/// edge the samples either side can both lie in front, and the blur's edge came out as if the
/// surface lay at the next sample's CoC: an alpha-cut sprig 0.12 px of CoC behind a layer's
/// front bound stayed sharp). [`refine`] walks the pixels between and tells which.
#[inline(always)]
fn bracketed(h: f32, h_prev: f32, c: f32) -> bool {
    h <= c || h_prev <= c
}

/// Whether a refined crossing at ray CoC `c_hit` onto a surface at `h_hit`, from a pixel whose
/// surface lay at `h_front`, is a hit: the ray is at or behind the surface (it is not where
/// the bracket held no crossing), within [`THICKNESS_PX`] of it or stepping onto it from a
/// continuation of the same surface.
#[inline(always)]
fn meets(c_hit: f32, h_hit: f32, h_front: f32) -> bool {
    h_hit <= c_hit && (c_hit - h_hit <= THICKNESS_PX || (h_front - h_hit).abs() <= CONTINUITY_PX)
}

/// Whether rays that pass layer `l` take the coverage their cones meet there ([`graze`]): with
/// cone tracing and [`TraceInput::graze`], in the layers in front of the focal plane, where
/// thin objects occlude what lies behind them. (Behind it the window would widen a small
/// light's bokeh by the cone's diameter: a 256-ray anamorphic light came out 2.7 px wider;
/// and the built-in scenes gained nothing there.)
#[inline(always)]
fn grazes(input: &TraceInput, l: usize) -> bool {
    let (ca, cb) = input.layers.spacing.bounds(l);
    input.graze && input.mips.is_some() && ca + cb < 0.0
}

/// A ray that passed layer `l` without hitting it: where [`grazes`], its cone still meets the
/// layer's surfaces beside it. At the middle of the layer's CoC interval `C`, where
/// the cone's diameter is `lambda |C|` (above a pixel), the layer's mipmap gives the coverage
/// `v1` and colour `c1` of the cone's window, and the ray takes them as a hit would.
///
/// Why: under the paper's cone tracing only a ray whose centre hits a surface takes the
/// surface's coverage of its cone, so a thin object (narrower than the cone) is met by a share
/// `w / D` of the rays and then covers only `w / D` of each: it blocks `(w / D)^2` of the
/// light instead of `w / D`. Taken at hits and misses alike, the window's coverage averages to
/// the object's share of the rays.
#[inline(always)]
fn graze(input: &TraceInput, l: usize, p: Vec2, v: Vec2, state: &mut RayState) -> bool {
    graze_level(input, l).is_some_and(|at| graze_at(input, l, at, p, v, state))
}

/// Where the rays that pass layer `l` read its mipmap, the same for all of them: the middle
/// of its CoC interval and the cone's level there; `None` where they do not graze it, or their
/// cones are within a pixel.
#[inline(always)]
fn graze_level(input: &TraceInput, l: usize) -> Option<(f32, ConeLevel)> {
    if !grazes(input, l) {
        return None;
    }
    let (ca, cb) = input.layers.spacing.bounds(l);
    let c = 0.5 * (ca + cb);
    Some((c, ConeLevel::of(cone_width(input, c))?))
}

/// [`graze`] of the ray through `v`, with its layer's [`graze_level`].
#[inline(always)]
fn graze_at(
    input: &TraceInput,
    l: usize,
    (c, level): (f32, ConeLevel),
    p: Vec2,
    v: Vec2,
    state: &mut RayState,
) -> bool {
    let Some(mips) = input.mips else {
        return false;
    };
    // Level 0 is the pixel the ray passed, which it missed: only what its window adds.
    let c1 = cone(&mips[l], Some(level), p - c * v, || [0.0; 4]);
    c1[3] > 0.0 && state.take(&c1)
}

/// Where a ray meets a layer: the layer, the ray's CoC there, and the pixel's index in the whole
/// stack of layers.
struct Hit {
    l: usize,
    c: f32,
    i: usize,
}

/// The ray meets a layer at `hit`: it takes the colour there (cone traced with the mipmaps)
/// with the weight it has left. True when the ray is done (what remains behind weighs under
/// 1e-3).
#[inline(always)]
fn shade(input: &TraceInput, p: Vec2, v: Vec2, hit: Hit, state: &mut RayState, simd: bool) -> bool {
    let Hit { l, c: c_hit, i } = hit;
    let color = || half4(&input.layers.color[i], simd);
    let c1 = match input.mips {
        // Level 0 is the hit pixel itself.
        Some(mips) => {
            let level = ConeLevel::of(cone_width(input, c_hit));
            cone(&mips[l], level, p - c_hit * v, color)
        }
        None => color(),
    };
    state.take(&c1)
}

/// The width at which the cone of a ray at CoC `c` reads the mipmaps: its diameter
/// `lambda |c|`, scaled for their filter ([`MipFilter::level_scale`]).
#[inline(always)]
fn cone_width(input: &TraceInput, c: f32) -> f32 {
    input.lambda * input.mip_filter.level_scale() * c.abs()
}

/// Where a cone of width `d` pixels reads a layer's mipmap: the level below `log2 d` and the
/// fraction of the way to the next.
#[derive(Clone, Copy, Debug)]
struct ConeLevel {
    k0: usize,
    t: f32,
}

impl ConeLevel {
    /// `None` for a cone within a pixel (level 0 alone).
    #[inline(always)]
    fn of(d: f32) -> Option<Self> {
        Self::with_log2(d, log2(d))
    }

    /// [`ConeLevel::of`] with `f` = [`log2`]`(d)` computed beforehand.
    #[inline(always)]
    fn with_log2(d: f32, f: f32) -> Option<Self> {
        if d <= 1.0 {
            return None;
        }
        let k0 = f.floor() as usize;
        Some(Self {
            k0,
            t: f - k0 as f32,
        })
    }
}

/// `log2 x` for finite `x > 0` (not subnormal), within 3e-7 of the exact value and the sum's
/// rounding to f32: the exponent, and for the mantissa `m` (taken into `[sqrt(1/2), sqrt(2))`)
/// the series `log2 m = 2 / ln 2 (s + s^3 / 3 + s^5 / 5 + s^7 / 7)` of `s = (m - 1) / (m + 1)`,
/// `|s| < 0.172`. Plain arithmetic and selects, no call: the compiler computes a packet's eight
/// lanes together, where the library's `log2f` was a call per hit (2.3% of the trace).
#[inline(always)]
fn log2(x: f32) -> f32 {
    const C1: f32 = std::f32::consts::LOG2_E * 2.0;
    let bits = x.to_bits();
    let e = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let big = m > std::f32::consts::SQRT_2;
    let (m, e) = if big { (m * 0.5, e + 1) } else { (m, e) };
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let series = s * (C1 + s2 * (C1 / 3.0 + s2 * (C1 / 5.0 + s2 * (C1 / 7.0))));
    e as f32 + series
}

/// The premultiplied colour, coverage in alpha, of a cone at `q` in a layer's mipmap `mip`:
/// trilinear between the two mip levels of `level`, `level0()` standing for level 0 (and for
/// the whole cone where `level` is `None`).
#[inline(always)]
fn cone(mip: &LayerMip, level: Option<ConeLevel>, q: Vec2, level0: impl FnOnce() -> Rgba) -> Rgba {
    let Some(ConeLevel { k0, t }) = level else {
        return level0();
    };
    let a = if k0 == 0 { level0() } else { mip.fetch(k0, q) };
    let b = mip.fetch(k0 + 1, q);
    std::array::from_fn(|k| a[k] + t * (b[k] - a[k]))
}

/// The cone reads of a packet's lanes in one layer's mipmap, made together by [`cones`]: per
/// lane in `mask`, [`cone`] at `(qx, qy)` between levels `k0` and `k0 + 1` (`t` of the way),
/// `level0` standing for level 0 where `k0` is 0.
struct ConeReads {
    /// One bit per lane.
    mask: u32,
    qx: [f32; LANES],
    qy: [f32; LANES],
    k0: [i32; LANES],
    t: [f32; LANES],
    level0: [Rgba; LANES],
}

impl ConeReads {
    #[inline(always)]
    fn new() -> Self {
        Self {
            mask: 0,
            qx: [0.0; LANES],
            qy: [0.0; LANES],
            k0: [0; LANES],
            t: [0.0; LANES],
            level0: [[0.0; 4]; LANES],
        }
    }

    /// Lane `j` reads at `q` between the levels of `level` (the trace fills whole rows at a
    /// time; this is the tests' way in).
    #[cfg(test)]
    fn push(&mut self, j: usize, q: Vec2, level: ConeLevel, level0: Rgba) {
        self.mask |= 1 << j;
        (self.qx[j], self.qy[j]) = (q.x, q.y);
        self.k0[j] = level.k0 as i32;
        self.t[j] = level.t;
        self.level0[j] = level0;
    }

    #[inline(always)]
    fn any(&self) -> bool {
        self.mask != 0
    }
}

/// The colours of `reads` in `mip`, lane by lane as [`cone`] (zero in the lanes outside the
/// mask). With AVX2 (`simd`) the eight lanes' texel positions and weights are worked out side
/// by side, with the same arithmetic, so the same bits.
#[inline(always)]
fn cones(mip: &LayerMip, reads: &ConeReads, simd: bool) -> [Rgba; LANES] {
    #[cfg(target_arch = "x86_64")]
    if simd && !mip.levels.is_empty() {
        // SAFETY: `simd` is only set where AVX2 was detected (`simd_fits`); the mipmap has a
        // level, and its levels are no larger than the layer, whose indices fit in i32.
        return unsafe { avx2::cones(mip, reads) };
    }
    let _ = simd;
    std::array::from_fn(|j| {
        if !lane(reads.mask, j) {
            return [0.0; 4];
        }
        let level = ConeLevel {
            k0: reads.k0[j] as usize,
            t: reads.t[j],
        };
        let q = Vec2::new(reads.qx[j], reads.qy[j]);
        cone(mip, Some(level), q, || reads.level0[j])
    })
}

/// Between `lo` (in front of the surface) and `hi` (at or behind it): the ray's first point at
/// or behind the layer's surface, with the layer read as it is stored, one surface per pixel,
/// flat across it. The pixels the ray passes between the two are walked in order (at most
/// three for a step of a pixel); in each, the ray meets the surface where its CoC reaches the
/// pixel's (`h <= C` within the pixel), or at the pixel's side if it comes in already behind
/// it. Returns the hit (ray CoC and layer pixel) and the surface CoC of the pixel the ray came
/// from (the hit pixel's own where the ray meets it inside the first).
///
/// The paper refines a linear model of the surface between the bracket's ends instead (false
/// position, [`refine_false_position`]); from a surface to a slightly nearer one beside it (a
/// poster's edge on a wall) that iteration stalls at the bracket's front end and left the hit
/// on the neighbouring pixel: the in-focus edge bled a pixel outwards.
#[inline(always)]
fn refine(
    layers: &DepthLayers,
    l: usize,
    p: Vec2,
    v: Vec2,
    lo: f32,
    hi: f32,
) -> Option<(f32, usize, f32)> {
    let pixel = |c: f32| pixel_under(layers, p, v, c).map(|(x, y)| (x as i32, y as i32));
    let (mut x, mut y) = pixel(lo)?;
    let (bx, by) = pixel(hi)?;
    let at = |x: i32, y: i32| layers.index(l, x as usize, y as usize);
    // `q` falls as `C` grows where `v` is positive: the next pixel boundary is the pixel's
    // lower side, and the walk steps down; elsewhere its upper side, stepping up.
    let (ox, sx) = if v.x > 0.0 { (0, -1) } else { (1, 1) };
    let (oy, sy) = if v.y > 0.0 { (0, -1) } else { (1, 1) };
    let (inv_x, inv_y) = (1.0 / v.x, 1.0 / v.y);
    let mut c_in = lo;
    let mut h_front = layers.coc_px[at(x, y)];
    loop {
        let i = at(x, y);
        let h_px = layers.coc_px[i];
        let (more_x, more_y) = (x != bx, y != by);
        let cx = if more_x {
            (p.x - (x + ox) as f32) * inv_x
        } else {
            f32::INFINITY
        };
        let cy = if more_y {
            (p.y - (y + oy) as f32) * inv_y
        } else {
            f32::INFINITY
        };
        let c_next = cx.min(cy);
        // The last pixel is the one the bracket's far end found behind the surface (met there
        // whatever the rounding of the boundaries before it).
        if h_px <= c_next.min(hi) || !(more_x || more_y) {
            return Some((c_in.max(h_px).min(hi), i, h_front));
        }
        if more_x && cx < cy {
            x += sx;
        } else {
            y += sy;
        }
        (h_front, c_in) = (h_px, c_next);
    }
}

/// The pixel of the layers the ray through `v` landing on `p` is over at CoC `c`; `None`
/// outside them.
#[inline(always)]
fn pixel_under(layers: &DepthLayers, p: Vec2, v: Vec2, c: f32) -> Option<(usize, usize)> {
    let q = p - c * v;
    let (w, h) = (layers.width as f32, layers.height as f32);
    if q.x < 0.0 || q.y < 0.0 || q.x >= w || q.y >= h {
        return None;
    }
    Some((q.x as usize, q.y as usize))
}

/// [`refine_false_position`] where `paper`, else [`refine`].
#[inline(always)]
fn refine_as(
    paper: bool,
    layers: &DepthLayers,
    l: usize,
    p: Vec2,
    v: Vec2,
    lo: f32,
    hi: f32,
) -> Option<(f32, usize, f32)> {
    if paper {
        refine_false_position(layers, l, p, v, lo, hi)
    } else {
        refine(layers, l, p, v, lo, hi)
    }
}

/// The paper's refinement (`--paper-refine`): between `lo` (in front of the surface) and `hi`
/// (at or behind it), three false-position steps, each checked, with bisection when the linear
/// guess does not shrink the bracket. Returns the bracket's far end (ray CoC and layer pixel)
/// and the surface CoC under the ray at its near end.
#[inline(always)]
fn refine_false_position(
    layers: &DepthLayers,
    l: usize,
    p: Vec2,
    v: Vec2,
    mut lo: f32,
    mut hi: f32,
) -> Option<(f32, usize, f32)> {
    let at = |c: f32| -> Option<(f32, usize)> {
        let (x, y) = pixel_under(layers, p, v, c)?;
        let i = layers.index(l, x, y);
        Some((layers.coc_px[i], i))
    };
    let (mut h_lo, _) = at(lo)?;
    let (mut h_hi, mut i_hi) = at(hi)?;
    for _ in 0..3 {
        // f(C) = h(q(C)) - C: positive in front, <= 0 at or behind the surface.
        let (f_lo, f_hi) = (h_lo - lo, h_hi - hi);
        let mut mid = if f_lo.is_finite() && f_hi.is_finite() && f_lo != f_hi {
            lo + (hi - lo) * f_lo / (f_lo - f_hi)
        } else {
            0.5 * (lo + hi)
        };
        if !(mid > lo && mid < hi) {
            mid = 0.5 * (lo + hi);
        }
        let (h_mid, i_mid) = at(mid)?;
        if h_mid <= mid {
            hi = mid;
            h_hi = h_mid;
            i_hi = i_mid;
        } else {
            lo = mid;
            h_lo = h_mid;
        }
    }
    Some((hi, i_hi, h_lo))
}

/// Mean distance from each sample to its nearest neighbour (the paper's lambda).
pub fn mean_spacing(set: &[Vec2]) -> f32 {
    if set.len() < 2 {
        return 0.0;
    }
    let sum: f32 = set
        .iter()
        .enumerate()
        .map(|(i, a)| {
            set.iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, b)| a.distance(*b))
                .fold(f32::INFINITY, f32::min)
        })
        .sum();
    sum / set.len() as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lens::Camera;
    use crate::random::SplitMix64;
    use crate::raster::LayerSpacing;
    use glam::Vec3;

    /// The cones' `log2` against f64's, from just above 1 (the smallest cone read) to far past
    /// any cone: at powers of two, either side of the mantissa's fold at `sqrt 2`, and random
    /// values; its floor is the exponent at every power of two.
    #[test]
    fn log2_is_within_3e_7_and_a_rounding() {
        let mut rng = SplitMix64::new(11);
        let mut xs: Vec<f32> = (0..20_000)
            .map(|_| 2f32.powf(rng.range(0.0, 24.0)))
            .collect();
        for e in 0..24 {
            let p = 2f32.powi(e);
            xs.extend([
                p,
                p.next_up(),
                p.next_down().max(1.0),
                p * std::f32::consts::SQRT_2,
            ]);
            let fold = p * std::f32::consts::SQRT_2;
            xs.extend([fold.next_up(), fold.next_down()]);
            assert_eq!(log2(p).floor(), e as f32, "2^{e}");
        }
        xs.extend([1.0f32.next_up(), 1.5, 3.0, 1e6, 1.7e7]);
        for x in xs {
            let want = (x as f64).log2();
            let got = log2(x) as f64;
            // The series' error, and the rounding of the sum to f32 (half an ulp).
            let tolerance = 3e-7 + want.abs() * f64::from(f32::EPSILON) / 2.0;
            assert!(
                (got - want).abs() <= tolerance,
                "log2({x}) = {got}, want {want}"
            );
        }
    }

    /// One layer of `w x h` random colours (premultiplied, alpha in [0, 1]), a fifth of its
    /// pixels empty.
    fn random_layer(w: usize, h: usize, seed: u64) -> DepthLayers {
        let camera = Camera::look_at(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y);
        let lens = camera.thin_lens().unwrap();
        let spacing = LayerSpacing {
            lens,
            coc_near_px: -8.0,
            delta_px: 4.0,
            layers: 1,
            overlap: 0.1,
        };
        let mut layers = DepthLayers::new(spacing, w, h);
        let mut rng = SplitMix64::new(seed);
        for i in 0..w * h {
            let a = rng.next_f32();
            layers.color[i] =
                [rng.next_f32() * a, rng.next_f32() * a, 4.0 * a, a].map(half::f16::from_f32);
            layers.coc_px[i] = if rng.below(5) == 0 {
                f32::INFINITY
            } else {
                rng.range(-8.0, -4.0)
            };
        }
        layers
    }

    /// Layer 0's pixels in f64, row by row, empty pixels transparent black: level 0 of its
    /// mipmap as the tests compute it.
    fn level_zero(layers: &DepthLayers) -> Vec<[f64; 4]> {
        (0..layers.width * layers.height)
            .map(|i| {
                if layers.coc_px[i].is_finite() {
                    from_half(&layers.color[i]).map(f64::from)
                } else {
                    [0.0; 4]
                }
            })
            .collect()
    }

    /// Asserts that texel `got` of a mipmap is `want` within 1e-5 relative, naming `what`.
    fn assert_texel(got: Rgba, want: [f64; 4], what: &str) {
        for c in 0..4 {
            assert!(
                (got[c] as f64 - want[c]).abs() <= 1e-5 * (1.0 + want[c].abs()),
                "{what} channel {c}: {} vs {}",
                got[c],
                want[c]
            );
        }
    }

    #[test]
    fn mip_levels_are_the_means_of_their_blocks() {
        // Level k at texel (x, y) is the mean of the layer's 2^k x 2^k block there (empty
        // pixels counted as transparent black), computed here directly from the pixels, not
        // level by level; odd sizes check the clamped last texels' neighbours.
        let (w, h) = (37, 23);
        let layers = random_layer(w, h, 5);
        let mip = LayerMip::new(&layers, 0, 4, MipFilter::Box);
        assert_eq!(mip.levels.len(), 4);
        let pixels = level_zero(&layers);
        for (k, (lw, lh, data)) in (1..).zip(&mip.levels) {
            let s = 1usize << k;
            assert_eq!((*lw, *lh), (w.div_ceil(s), h.div_ceil(s)), "level {k}");
            for ty in 0..h / s {
                for tx in 0..w / s {
                    let mut want = [0.0f64; 4];
                    for y in ty * s..(ty + 1) * s {
                        for x in tx * s..(tx + 1) * s {
                            for (m, c) in want.iter_mut().zip(pixels[y * w + x]) {
                                *m += c / (s * s) as f64;
                            }
                        }
                    }
                    assert_texel(
                        data[ty * lw + tx],
                        want,
                        &format!("level {k} texel ({tx}, {ty})"),
                    );
                }
            }
        }
        // No levels asked for, none made.
        assert!(LayerMip::new(&layers, 0, 0, MipFilter::Box)
            .levels
            .is_empty());
    }

    #[test]
    fn tent_levels_are_the_tent_of_the_level_below() {
        // Each level computed here directly in f64 from the one below (level 0: the layer,
        // empty pixels transparent black): the 4x4 texels around it weighed by the outer
        // product of [1 3 3 1] / 8, indices clamped to the level; odd and even sizes.
        for (w, h) in [(37, 23), (16, 9), (1, 5)] {
            let layers = random_layer(w, h, 7);
            let mip = LayerMip::new(&layers, 0, 4, MipFilter::Tent);
            let mut below = level_zero(&layers);
            let (mut bw, mut bh) = (w, h);
            for (k, (lw, lh, data)) in (1..).zip(&mip.levels) {
                assert_eq!((*lw, *lh), (bw.div_ceil(2), bh.div_ceil(2)), "level {k}");
                let taps = [(-1i64, 0.125), (0, 0.375), (1, 0.375), (2, 0.125)];
                let mut level = vec![[0.0f64; 4]; lw * lh];
                for ty in 0..*lh {
                    for tx in 0..*lw {
                        for (dy, wy) in taps {
                            for (dx, wx) in taps {
                                let y = (2 * ty as i64 + dy).clamp(0, bh as i64 - 1) as usize;
                                let x = (2 * tx as i64 + dx).clamp(0, bw as i64 - 1) as usize;
                                for c in 0..4 {
                                    level[ty * lw + tx][c] += wx * wy * below[y * bw + x][c];
                                }
                            }
                        }
                        assert_texel(
                            data[ty * lw + tx],
                            level[ty * lw + tx],
                            &format!("{w}x{h} level {k} texel ({tx}, {ty})"),
                        );
                    }
                }
                (below, bw, bh) = (level, *lw, *lh);
            }
        }
    }

    /// The mipmap by `filter`, 6 levels, of a layer of 160x8 pixels empty but for a
    /// one-pixel-wide vertical line at column `x0` (coverage 1).
    fn line_mip(filter: MipFilter, x0: usize) -> LayerMip {
        let (w, h) = (160, 8);
        let mut layers = random_layer(w, h, 1);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                layers.coc_px[i] = if x == x0 { -6.0 } else { f32::INFINITY };
                layers.color[i] = [half::f16::ONE; 4];
            }
        }
        LayerMip::new(&layers, 0, 6, filter)
    }

    #[test]
    fn texel_reach_bounds_the_pixels_a_read_draws_on_tightly() {
        // Reads of level k at 1/8-pixel steps around a line at every phase of the level's
        // texels: the farthest read that sees the line has its centre within the reach less
        // half a pixel (the reach bounds the pixels' extent), and no more than a quarter of a
        // pixel nearer (the reach is tight). The culling windows rely on it.
        for filter in [MipFilter::Box, MipFilter::Tent] {
            for k in 1..=4usize {
                let reach = filter.texel_reach(k);
                let mut farthest = 0.0f32;
                for x0 in 64..64 + (1 << k) {
                    let mip = line_mip(filter, x0);
                    let centre = x0 as f32 + 0.5;
                    for i in -400..=400 {
                        let q = centre + i as f32 / 8.0;
                        if mip.fetch(k, Vec2::new(q, 4.0))[3] > 0.0 {
                            farthest = farthest.max((q - centre).abs());
                        }
                    }
                }
                assert!(
                    farthest <= reach - 0.5 && farthest >= reach - 0.75,
                    "{filter:?} level {k}: reads see the line {farthest} px away, reach {reach}"
                );
            }
        }
    }

    /// The footprint of cone reads of diameter `d` in a mipmap by `filter` of a one-pixel-wide
    /// vertical line at column `x0` (coverage 1, the rest empty): the coverage read at 1/4-pixel
    /// steps across it, and its standard deviation about the line's centre, in pixels.
    fn line_footprint(filter: MipFilter, d: f32, x0: usize) -> (Vec<f32>, f64) {
        let mip = line_mip(filter, x0);
        let level = ConeLevel::of(d * filter.level_scale());
        let centre = x0 as f64 + 0.5;
        let qs: Vec<f64> = (-256..=256).map(|i| centre + i as f64 / 4.0).collect();
        let line = |q: f64| if q.floor() as usize == x0 { 1.0 } else { 0.0 };
        let reads: Vec<f32> = qs
            .iter()
            .map(|&q| cone(&mip, level, Vec2::new(q as f32, 4.0), || [line(q); 4])[3])
            .collect();
        let (mut sum, mut second) = (0.0f64, 0.0f64);
        for (&q, &r) in qs.iter().zip(&reads) {
            sum += r as f64;
            second += r as f64 * (q - centre).powi(2);
        }
        (reads, (second / sum).sqrt())
    }

    #[test]
    fn tent_reads_are_as_wide_as_box_reads_and_do_not_follow_the_texel_phase() {
        // Cones of diameters over two octaves, 8 to an octave, each over a line at 32 phases
        // of the texels read. The footprints' standard deviations (the README's derivation):
        // - their ratio, tent to box, swings about 1 within an octave (the levels are blended
        //   linearly while their variance grows 4-fold: 0.89 to 1.10 by the derivation), and
        //   its geometric mean over an octave is 1 within 3%;
        // - the box's changes with the phase by 20-31%; the tent's by under 1%.
        let mut logs = [0.0f64; 2];
        for i in 0..16 {
            let d = 3.0 * 2f32.powf(i as f32 / 8.0);
            let mut widths = [0.0f64; 2];
            let mut spread = [0.0f64; 2];
            for (f, filter) in [MipFilter::Box, MipFilter::Tent].into_iter().enumerate() {
                let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
                for x0 in 32..64 {
                    let std = line_footprint(filter, d, x0).1;
                    widths[f] += std / 32.0;
                    (lo, hi) = (lo.min(std), hi.max(std));
                }
                spread[f] = (hi - lo) / hi;
            }
            let ratio = widths[1] / widths[0];
            assert!(
                (0.87..1.12).contains(&ratio),
                "d {d}: footprints {widths:?} (ratio {ratio})"
            );
            logs[i / 8] += ratio.ln() / 8.0;
            assert!(
                spread[1] < 0.01 && spread[0] > 0.1,
                "d {d}: footprints change with the phase by {spread:?} (box, tent)"
            );
        }
        for (octave, log) in logs.iter().enumerate() {
            assert!(
                log.abs() < 0.03f64.ln_1p(),
                "octave {octave}: geometric mean ratio {}",
                log.exp()
            );
        }
    }

    #[test]
    fn cone_reads_a_register_at_a_time_are_one_at_a_time_bit_for_bit() {
        // Positions inside, on the border of and far outside the layer, levels from 0 to past
        // the coarsest kept, lanes in and out of the mask; levels' sizes from a register (at
        // most eight levels) and gathered (ten).
        if !simd_fits(1) {
            eprintln!("skipped: this CPU has no AVX2 and F16C");
            return;
        }
        for (w, h, max_level) in [(45, 29, 5), (600, 3, 12)] {
            let layers = random_layer(w, h, 9);
            let mip = LayerMip::new(&layers, 0, max_level, MipFilter::Tent);
            assert_eq!(mip.sizes.is_some(), mip.levels.len() <= 8);
            let mut rng = SplitMix64::new(11);
            for round in 0..2000 {
                let mut reads = ConeReads::new();
                for j in 0..LANES {
                    if rng.below(4) == 0 {
                        continue;
                    }
                    let (wf, hf) = (w as f32, h as f32);
                    let q = match rng.below(4) {
                        0 => {
                            Vec2::new(rng.range(-200.0, wf + 200.0), rng.range(-200.0, hf + 200.0))
                        }
                        1 => Vec2::new(rng.below(w + 1) as f32, rng.below(h + 1) as f32),
                        _ => Vec2::new(rng.range(0.0, wf), rng.range(0.0, hf)),
                    };
                    let level = ConeLevel {
                        k0: rng.below(max_level + 3),
                        t: rng.next_f32(),
                    };
                    let level0 = [rng.next_f32(), rng.next_f32(), rng.next_f32(), 1.0];
                    reads.push(j, q, level, level0);
                }
                let fast = cones(&mip, &reads, true);
                let slow = cones(&mip, &reads, false);
                for j in 0..LANES {
                    assert_eq!(
                        fast[j].map(f32::to_bits),
                        slow[j].map(f32::to_bits),
                        "{w}x{h}, round {round}, lane {j}"
                    );
                }
            }
        }
    }

    /// A one-layer stack of `w x h` pixels whose surfaces' CoCs are `coc(x, y)`.
    fn height_field(w: usize, h: usize, mut coc: impl FnMut(usize, usize) -> f32) -> DepthLayers {
        let mut layers = random_layer(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                layers.coc_px[y * w + x] = coc(x, y);
            }
        }
        layers
    }

    #[test]
    fn a_ray_from_a_wall_onto_a_poster_a_hair_nearer_meets_the_wall() {
        // A wall at CoC 0.01 px (row 23 and above) and a poster at 0 (row 24 and below); a
        // ray over pixel row 23 whose position moves down a pixel per pixel of CoC, bracketed
        // by a sample in front of the wall at C = 0 (row 23) and one behind the poster at C = 1
        // (row 24). It passes behind the wall at C = 0.01, still over row 23: it meets the wall
        // there. (The paper's false position stays on the poster's pixel at C = 1.)
        let layers = height_field(8, 48, |_, y| if y < 24 { 0.01 } else { 0.0 });
        let (p, v) = (Vec2::new(4.5, 23.5), Vec2::new(0.0, -1.0));
        let (c, i, h_front) = refine(&layers, 0, p, v, 0.0, 1.0).unwrap();
        assert_eq!((c, i, h_front), (0.01, 23 * 8 + 4, 0.01));
        let (_, i_paper, _) = refine_false_position(&layers, 0, p, v, 0.0, 1.0).unwrap();
        assert_eq!(i_paper, 24 * 8 + 4);
    }

    #[test]
    fn refine_finds_the_first_point_behind_the_stored_surface() {
        // Random height fields (a fifth of the pixels empty, the rest in a few levels a
        // fraction of a pixel apart, so that neighbours are often a hair apart) and random
        // brackets of up to three pixels of travel: the hit is the first point of the segment
        // at or behind the surface of the pixel under it, found here by sampling the segment
        // 20000 times in f64. Points within 1e-4 of a pixel boundary are left out (either
        // side is right there).
        let (w, h) = (24, 24);
        let mut rng = SplitMix64::new(17);
        let mut checked = 0;
        for round in 0..400 {
            let levels: Vec<f32> = (0..4).map(|_| rng.range(-2.0, 2.0)).collect();
            let layers = height_field(w, h, |_, _| {
                if rng.below(5) == 0 {
                    f32::INFINITY
                } else {
                    levels[rng.below(4)] + 0.01 * rng.below(3) as f32
                }
            });
            for _ in 0..50 {
                let p = Vec2::new(8.0 + rng.below(8) as f32, 8.0 + rng.below(8) as f32) + 0.5;
                let a = rng.range(0.0, std::f32::consts::TAU);
                let v = Vec2::new(a.cos(), a.sin()) * rng.range(0.05, 1.0);
                let lo = rng.range(-3.0, 2.0);
                let hi = lo + rng.range(0.05, 3.0 / v.length()).min(4.0);
                let hf = |c: f64| {
                    let (qx, qy) = (p.x as f64 - c * v.x as f64, p.y as f64 - c * v.y as f64);
                    let i = qy.floor() as usize * w + qx.floor() as usize;
                    (layers.coc_px[i] as f64, i, qx, qy)
                };
                if hf(lo as f64).0 <= lo as f64 || hf(hi as f64).0 > hi as f64 {
                    continue;
                }
                let n = 20_000;
                let want = (0..=n)
                    .map(|k| lo as f64 + (hi - lo) as f64 * k as f64 / n as f64)
                    .find(|&c| hf(c).0 <= c)
                    .unwrap();
                let (_, i_want, qx, qy) = hf(want);
                let near_boundary = |q: f64| (q - q.round()).abs() < 1e-4;
                if near_boundary(qx) || near_boundary(qy) {
                    continue;
                }
                let (c, i, _) = refine(&layers, 0, p, v, lo, hi).unwrap();
                assert_eq!(i, i_want, "round {round}: p {p}, v {v}, [{lo}, {hi}]");
                let tolerance = (hi - lo) as f64 / n as f64 + 1e-5;
                assert!(
                    (c as f64 - want).abs() <= tolerance,
                    "round {round}: hit at {c}, want {want}"
                );
                checked += 1;
            }
        }
        assert!(checked > 5000, "only {checked} brackets checked");
    }

    /// A packet's worth of random rays for layer 0 of `layers`: each a random direction and a
    /// speed in `speed`, with its steps and CoC step there as [`RayTable`] works them out.
    struct RandomLanes {
        vx: [f32; LANES],
        vy: [f32; LANES],
        dc: [f32; LANES],
        steps: [usize; LANES],
        stepsf: [f32; LANES],
    }

    impl RandomLanes {
        fn new(rng: &mut SplitMix64, layers: &DepthLayers, speed: (f32, f32)) -> Self {
            let (ca, cb) = layers.spacing.bounds(0);
            let mut out = Self {
                vx: [0.0; LANES],
                vy: [0.0; LANES],
                dc: [0.0; LANES],
                steps: [0; LANES],
                stepsf: [0.0; LANES],
            };
            for j in 0..LANES {
                let a = rng.range(0.0, std::f32::consts::TAU);
                let v = Vec2::new(a.cos(), a.sin()) * rng.range(speed.0, speed.1);
                (out.vx[j], out.vy[j]) = (v.x, v.y);
                let (n, dc) = layer_steps((ca, cb), v.length());
                (out.steps[j], out.stepsf[j], out.dc[j]) = (n, n as f32, dc);
            }
            out
        }
    }

    #[test]
    fn a_crossing_over_a_samples_pixel_between_two_samples_is_found() {
        // Random height fields in the layer's range and random rays in front of the surface at
        // the walk's first sample. Where a ray first comes at or behind the surface under it
        // (the segment sampled 20000 times in f64) over the pixel of the sample before or after
        // that point, the walk's first bracket is that crossing, refined to it; or a bracket
        // that crossed nothing (the ray left the previous sample's pixel in front of its
        // surface), which the packet hands to `layer` to walk on. Sampled alone, a ray that
        // met a surface over one sample's pixel and was in front of the next sample's surface
        // missed it: a surface's edge was traced as if it lay a step of CoC later.
        let (w, h) = (40, 40);
        let mut rng = SplitMix64::new(29);
        let (mut checked, mut before) = (0, 0);
        for round in 0..300 {
            let levels: Vec<f32> = (0..4).map(|_| rng.range(-8.0, -4.0)).collect();
            let layers = height_field(w, h, |_, _| {
                if rng.below(5) == 0 {
                    f32::INFINITY
                } else {
                    levels[rng.below(4)]
                }
            });
            let spacing = layers.spacing;
            let (ca, _) = spacing.bounds(0);
            let p = Vec2::new(20.5, 20.5);
            let RandomLanes {
                vx,
                vy,
                dc,
                steps,
                stepsf,
            } = RandomLanes::new(&mut rng, &layers, (0.3, 1.0));
            let live = (1u32 << LANES) - 1;
            let seg = Segment {
                layers: &layers,
                l: 0,
                p,
                ca,
                enter: ca - spacing.overlap * spacing.delta_px,
                most: *steps.iter().max().unwrap(),
                paper_refine: false,
            };
            let lanes = Lanes {
                vx: &vx,
                vy: &vy,
                dc: &dc,
                steps: &steps,
                stepsf: &stepsf,
                live,
            };
            let out = crossings(&seg, &lanes);
            for j in 0..LANES {
                let v = Vec2::new(vx[j], vy[j]);
                let hf = |c: f64| {
                    let (qx, qy) = (p.x as f64 - c * v.x as f64, p.y as f64 - c * v.y as f64);
                    let i = qy.floor() as usize * w + qx.floor() as usize;
                    (layers.coc_px[i] as f64, i, qx, qy)
                };
                // The samples as the walk takes them, and the pixel under each.
                let c_at = |k: usize| ca + dc[j] * k as f32;
                let pixel_at = |k: usize| {
                    let q = p - c_at(k) * v;
                    q.y as usize * w + q.x as usize
                };
                if hf(ca as f64).0 <= ca as f64 {
                    continue;
                }
                let end = c_at(steps[j]) as f64;
                let n = 20_000;
                let Some(want) = (0..=n)
                    .map(|k| ca as f64 + (end - ca as f64) * k as f64 / n as f64)
                    .find(|&c| hf(c).0 <= c)
                else {
                    continue;
                };
                let (_, i_want, qx, qy) = hf(want);
                let near_boundary = |q: f64| (q - q.round()).abs() < 1e-4;
                let k = (0..steps[j])
                    .find(|&k| c_at(k + 1) as f64 >= want)
                    .unwrap_or(steps[j] - 1);
                if near_boundary(qx)
                    || near_boundary(qy)
                    || (i_want != pixel_at(k) && i_want != pixel_at(k + 1))
                {
                    continue;
                }
                assert!(lane(out.found, j), "round {round}, lane {j}: no bracket");
                if out.h_hi[j] > out.hi[j] {
                    // A bracket that crossed nothing, before the crossing: walked on by `layer`.
                    assert!((out.hi[j] as f64) <= want + 1e-4, "round {round}, lane {j}");
                    continue;
                }
                assert_eq!(out.i_hi[j], i_want, "round {round}, lane {j}");
                let tolerance = (end - ca as f64) / n as f64 + 1e-5;
                assert!(
                    (out.hi[j] as f64 - want).abs() <= tolerance,
                    "round {round}, lane {j}: hit at {}, want {want}",
                    out.hi[j]
                );
                checked += 1;
                before += usize::from(i_want != pixel_at(k + 1));
            }
        }
        assert!(checked > 2000, "only {checked} crossings checked");
        assert!(
            before > 100,
            "only {before} crossings over the earlier sample's pixel"
        );
    }

    #[test]
    fn crossings_a_register_at_a_time_are_one_at_a_time_bit_for_bit() {
        // Packets of random rays over random height fields as above, lanes in and out of the
        // live mask: the AVX2 walk and refinement give the portable twin's crossings.
        if !simd_fits(1) {
            eprintln!("skipped: this CPU has no AVX2 and F16C");
            return;
        }
        let (w, h) = (40, 40);
        let mut rng = SplitMix64::new(23);
        for round in 0..300 {
            let levels: Vec<f32> = (0..4).map(|_| rng.range(-7.0, -5.0)).collect();
            let layers = height_field(w, h, |_, _| {
                if rng.below(5) == 0 {
                    f32::INFINITY
                } else {
                    levels[rng.below(4)] + 0.01 * rng.below(3) as f32
                }
            });
            let (ca, _) = layers.spacing.bounds(0);
            let RandomLanes {
                vx,
                vy,
                dc,
                steps,
                stepsf,
            } = RandomLanes::new(&mut rng, &layers, (0.0, 1.0));
            let live = rng.next_u64() as u32 & ((1 << LANES) - 1);
            let most = (0..LANES)
                .filter(|&j| lane(live, j))
                .map(|j| steps[j])
                .max();
            let seg = Segment {
                layers: &layers,
                l: 0,
                p: Vec2::new(20.5, 20.5),
                ca,
                enter: ca - layers.spacing.overlap * layers.spacing.delta_px,
                most: most.unwrap_or(0),
                paper_refine: false,
            };
            let lanes = Lanes {
                vx: &vx,
                vy: &vy,
                dc: &dc,
                steps: &steps,
                stepsf: &stepsf,
                live,
            };
            let (a, b) = (crossings(&seg, &lanes), crossings_simd(&seg, &lanes));
            assert_eq!(a.found, b.found, "round {round}");
            for j in (0..LANES).filter(|&j| lane(a.found, j)) {
                let ends = |c: &Crossings| {
                    (
                        c.hi[j].to_bits(),
                        c.h_lo[j].to_bits(),
                        c.h_hi[j].to_bits(),
                        c.i_hi[j],
                    )
                };
                assert_eq!(ends(&a), ends(&b), "round {round}, lane {j}");
            }
        }
    }
}
