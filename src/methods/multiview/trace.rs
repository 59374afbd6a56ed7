//! Pass `trace` (Lee et al. sections 4.3-4.5): per pixel, N lens rays traced through the
//! layers front to back; the colours of their first hits are averaged.
//!
//! A lens ray through unit-aperture point `v` that lands on pixel `p` passes, at the depth
//! whose signed CoC is `C`, over the pinhole position `q(C) = p - C v` (eq. 3: a point seen at
//! pinhole position `q` appears through lens point `v` at `q + C v`). `q` is linear in `C` and
//! the layers are uniform in `C`, so each layer is a segment of at most `delta |v|` pixels,
//! tested against the layer as a height field of CoCs: the ray has hit when it is at or behind
//! the stored surface (`h(q(C)) <= C`). The segment is sampled a pixel apart from the front;
//! the first sample behind the surface brackets the hit with the one before, and three steps of
//! the paper's false-position iteration (the surface taken as linear between the bracketing
//! samples) with bisection as a guard refine it. Empty pixels hold +inf and are never hit. A
//! ray whose segment in a layer leaves the image is discarded, as in the paper. A layer the pixel's rays
//! cannot hit (the N-buffer minimum over the region they can reach lies beyond the layer) is
//! skipped.
//!
//! A hit meets the layer's premultiplied colour with its coverage in alpha (partly covered
//! pixels and see-through surfaces: [`crate::raster::DepthLayers`]); the ray takes that share
//! and goes on behind with the rest of its weight, as under cone tracing.
//!
//! Cone tracing (section 4.4): at a hit at CoC `C`, the cone around the ray has diameter
//! `lambda |C|` (lambda: the mean distance between neighbouring lens samples); the layer's
//! mipmap at that footprint gives a coverage `v1` and a colour `c1`; the ray contributes
//! `v1 c1` and continues behind with weight `1 - v1` (`v1 c1 + (1 - v1) c2`).
//!
//! Jitter (section 4.5): each pixel uses one of 16 sample sets (different seeds of the shared
//! sampler, so every set covers the aperture as `reference`'s does), picked from a 16x16 noise
//! tile, trading the aliasing of one shared pattern for noise.

use glam::Vec2;
use rayon::prelude::*;

use super::nbuffer::NBuffer;
use crate::image::{ColorImage, Rgba};
use crate::lens::{LensEffects, ThinLens};
use crate::raster::{from_half, DepthLayers};

/// How far behind the surface under it, in pixels of CoC, a ray may be at its refined hit and
/// still count as crossing it.
pub const THICKNESS_PX: f32 = 0.1;

/// Neighbouring height-field pixels whose CoCs differ by at most this many pixels are one
/// continuous surface: a ray stepping from one onto the other meets it.
pub const CONTINUITY_PX: f32 = 2.0;

/// Side of the jitter noise tile in pixels.
pub const NOISE_TILE: usize = 16;

/// Mipmaps of a layer's colour with coverage in alpha (alpha 1 where the layer has a surface,
/// 0 where it is empty), for cone tracing. Level 0 is the layer itself.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerMip {
    /// Levels 1, 2, ...: (width, height, premultiplied RGBA).
    levels: Vec<(usize, usize, Vec<Rgba>)>,
}

impl LayerMip {
    /// The mipmap of layer `l`, down to `max_level`.
    pub fn new(layers: &DepthLayers, l: usize, max_level: usize) -> Self {
        let (w, h) = (layers.width, layers.height);
        let base: Vec<Rgba> = (0..w * h)
            .map(|i| {
                let j = l * w * h + i;
                if layers.coc_px[j].is_finite() {
                    from_half(&layers.color[j])
                } else {
                    [0.0; 4]
                }
            })
            .collect();
        let mut levels: Vec<(usize, usize, Vec<Rgba>)> = Vec::new();
        let mut prev = (w, h, base);
        for _ in 0..max_level {
            let (pw, ph, ref p) = prev;
            if pw == 1 && ph == 1 {
                break;
            }
            let (nw, nh) = (pw.div_ceil(2), ph.div_ceil(2));
            let mut next = vec![[0.0f32; 4]; nw * nh];
            for y in 0..nh {
                for x in 0..nw {
                    let mut s = [0.0f32; 4];
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (sx, sy) = ((2 * x + dx).min(pw - 1), (2 * y + dy).min(ph - 1));
                        let c = p[sy * pw + sx];
                        for k in 0..4 {
                            s[k] += 0.25 * c[k];
                        }
                    }
                    next[y * nw + x] = s;
                }
            }
            levels.push((nw, nh, next.clone()));
            prev = (nw, nh, next);
        }
        Self { levels }
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
        let s = (1u32 << k) as f32;
        let (u, v) = ((q.x / s - 0.5).max(0.0), (q.y / s - 0.5).max(0.0));
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

/// What the trace reads.
pub struct TraceInput<'a> {
    /// The layers.
    pub layers: &'a DepthLayers,
    /// Per layer, its N-buffer (`None`: not culled, e.g. an empty layer has none and is
    /// skipped by `filled`).
    pub nbuffers: Option<&'a [Option<NBuffer>]>,
    /// Per layer, whether it has any surface.
    pub filled: &'a [bool],
    /// Per layer, its mipmap for cone tracing (`None`: plain rays).
    pub mips: Option<&'a [LayerMip]>,
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
    trace_with(input, trace_row_inner)
}

fn trace_with(
    input: &TraceInput,
    row_fn: impl Fn(&TraceInput, f32, usize, &mut [Rgba]) + Sync,
) -> ColorImage {
    let (_, _, w, h) = input.region;
    let rmax = input
        .sets
        .iter()
        .flatten()
        .map(|v| v.length())
        .fold(0.0f32, f32::max);
    let mut data = vec![[0.0f32; 4]; w * h];
    data.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| row_fn(input, rmax, y, row));
    ColorImage::from_vec(w, h, data).expect("sizes agree by construction")
}

/// One row of [`trace`]. Compiled for several instruction sets and chosen at run time
/// ([`multiversion`]): with SSE4.1 and later `floor` and `ceil` are one instruction instead of
/// a library call; the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn trace_row(input: &TraceInput, rmax: f32, y: usize, row: &mut [Rgba]) {
    trace_row_inner(input, rmax, y, row);
}

#[inline(always)]
fn trace_row_inner(input: &TraceInput, rmax: f32, y: usize, row: &mut [Rgba]) {
    let layers = input.layers;
    let m = layers.spacing.layers;
    let mut open = vec![false; m];
    let (x0, y0, _, _) = input.region;
    let (fy, y) = (y, y + y0);
    for (fx, out) in row.iter_mut().enumerate() {
        let x = fx + x0;
        let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
        // Early layer culling for all rays of the pixel.
        for (l, o) in open.iter_mut().enumerate() {
            *o = input.filled[l];
            if !*o {
                continue;
            }
            if let Some(nb) = input.nbuffers.and_then(|n| n[l].as_ref()) {
                let (a, b) = layers.spacing.bounds(l);
                let r = (a.abs().max(b.abs()) * rmax).ceil() as i64 + 1;
                let (xi, yi) = (x as i64, y as i64);
                if let Some(min) = nb.min(xi - r, yi - r, xi + r, yi + r) {
                    let overlap = layers.spacing.overlap * layers.spacing.delta_px;
                    *o = min <= b + overlap;
                }
            }
        }
        let set = &input.sets[input.noise[(fy % NOISE_TILE) * NOISE_TILE + fx % NOISE_TILE]
            as usize
            % input.sets.len()];
        let mut acc = [0.0f32; 4];
        let mut count = 0u32;
        // The barrel as this pixel of the frame sees it (with a cat's eye).
        let barrel = input.clip.as_ref().map(|(e, lens)| {
            (
                e,
                e.barrel(lens, Vec2::new(fx as f32 + 0.5, fy as f32 + 0.5)),
            )
        });
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
        if count > 0 {
            let inv = 1.0 / count as f32;
            *out = acc.map(|c| c * inv);
        }
    }
}

/// Traces one lens ray through `v` landing on pixel centre `p`.
#[inline(always)]
fn ray(input: &TraceInput, open: &[bool], p: Vec2, v: Vec2) -> Ray {
    let layers = input.layers;
    let (w, h) = (layers.width as f32, layers.height as f32);
    let spacing = &layers.spacing;
    let mut col = [0.0f32; 4];
    let mut weight = 1.0f32;
    let inside = |q: Vec2| q.x >= 0.0 && q.y >= 0.0 && q.x < w && q.y < h;
    let speed = v.length();
    for l in 0..spacing.layers {
        let (ca, cb) = spacing.bounds(l);
        // A ray that leaves the image in this layer's segment is discarded (q is linear in C,
        // so the ends decide), whether or not the layer can be skipped: culling must not
        // change which rays count.
        if !inside(p - ca * v) || !inside(p - cb * v) {
            return Ray::Discarded;
        }
        if !open[l] {
            continue;
        }
        let steps = ((cb - ca) * speed).ceil().max(1.0) as usize;
        let dc = (cb - ca) / steps as f32;
        // The ray was in front of the surface under it at the previous sample; a crossing from
        // there to behind it brackets a hit. It enters the layer in front of everything the
        // layer holds: the overlap margin before its front bound.
        let mut prev = ca - spacing.overlap * spacing.delta_px;
        let mut prev_front = true;
        let mut hit = None;
        for k in 0..=steps {
            let c = ca + dc * k as f32;
            let q = p - c * v;
            let i = layers.index(l, q.x as usize, q.y as usize);
            let behind = layers.coc_px[i] <= c;
            if behind && prev_front {
                let (c_hit, i_hit, h_front) =
                    refine(layers, l, p, v, prev, c).unwrap_or((c, i, f32::INFINITY));
                // A ray meets the surface where it crosses it (refined to within
                // THICKNESS_PX), or where it steps onto it from a continuation of the same
                // surface (a slanted surface sampled pixel by pixel); one that comes in from
                // the side of a thin object, from empty space or from a surface far in
                // front, passes behind it.
                let h_hit = layers.coc_px[i_hit];
                if c_hit - h_hit <= THICKNESS_PX || (h_front - h_hit).abs() <= CONTINUITY_PX {
                    hit = Some((c_hit, i_hit));
                    break;
                }
            }
            prev_front = !behind;
            prev = c;
        }
        let Some((c_hit, i)) = hit else {
            continue;
        };
        let color = from_half(&layers.color[i]);
        let (v1, c1) = match input.mips {
            Some(mips) => {
                // Trilinear: the footprint's level between two mip levels (level 0 is the hit
                // pixel itself, fully covered).
                let d = input.lambda * c_hit.abs();
                if d > 1.0 {
                    let f = d.log2();
                    let k0 = f.floor() as usize;
                    let t = f - k0 as f32;
                    let q = p - c_hit * v;
                    let a = if k0 == 0 { color } else { mips[l].fetch(k0, q) };
                    let b = mips[l].fetch(k0 + 1, q);
                    let m: Rgba = std::array::from_fn(|k| a[k] + t * (b[k] - a[k]));
                    (m[3].clamp(0.0, 1.0), m)
                } else {
                    (color[3].clamp(0.0, 1.0), color)
                }
            }
            None => (color[3].clamp(0.0, 1.0), color),
        };
        // v1 c1 is the premultiplied mip colour itself.
        for k in 0..3 {
            col[k] += weight * c1[k];
        }
        col[3] += weight * v1;
        weight *= 1.0 - v1;
        if weight < 1e-3 {
            break;
        }
    }
    Ray::Color(col)
}

/// Between `lo` (in front of the surface) and `hi` (at or behind it): three false-position
/// steps, each checked, with bisection when the linear guess does not shrink the bracket.
/// Returns the refined hit (ray CoC and layer pixel) and the surface CoC under the ray just
/// in front of it.
#[inline(always)]
fn refine(
    layers: &DepthLayers,
    l: usize,
    p: Vec2,
    v: Vec2,
    mut lo: f32,
    mut hi: f32,
) -> Option<(f32, usize, f32)> {
    let (w, h) = (layers.width as f32, layers.height as f32);
    let at = |c: f32| -> Option<(f32, usize)> {
        let q = p - c * v;
        if q.x < 0.0 || q.y < 0.0 || q.x >= w || q.y >= h {
            return None;
        }
        let i = layers.index(l, q.x as usize, q.y as usize);
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
