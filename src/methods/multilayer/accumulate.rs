//! Pass `accumulate` (Selgrad et al. section 6.1): per pixel, the fragments of every level whose
//! filter size matches their circle of confusion, blended front to back.
//!
//! The level borders of the paper's table T are where `lambda(z) = log2(sqrt(3) |C(z)|)` (the
//! width of the box with the variance of the CoC disc, against the level's box width `2^S`)
//! crosses a whole number ([`super::Borders`]). To hide the seams at the borders, as the paper
//! asks, a fragment at depth `z` is taken from the two levels around `lambda(z)`, weighted so
//! that the blend's variance is the disc's (`(1 - t) 4^S / 12 + t 4^(S+1) / 12 = C^2 / 4`),
//! clamped to the first and last level: the blur grows continuously with depth.
//! The weighted fragments of all levels at a pixel are sorted by depth; those within the depth
//! threshold of each other are one surface seen at two filter sizes: within a level they are
//! combined with the over operator (the front face of a thin double-sided object hides its back
//! face, as in a list of section 5.1), across levels their weighted contributions are summed.
//! The resulting surfaces are blended front to back with the over operator.

use rayon::prelude::*;

use super::filter::Level;
use super::Borders;
use crate::image::{ColorImage, Rgba};
use crate::raster::from_half;

/// Weight of level `s` of `levels` for a fragment at level coordinate `lambda`: with
/// `S = floor(lambda)`, level S gets `1 - t` and level S + 1 gets `t`, where
/// `t = (4^(lambda - S) - 1) / 3` blends the two box variances into the disc's.
#[inline(always)]
pub fn level_weight(lambda: f32, s: usize, levels: usize) -> f32 {
    let top = (levels - 1) as f32;
    let l = lambda.clamp(0.0, top);
    let base = l.floor();
    let t = if base >= top {
        0.0
    } else {
        ((4f32).powf(l - base) - 1.0) / 3.0
    };
    let b = base as usize;
    if s == b {
        1.0 - t
    } else if s == b + 1 {
        t
    } else {
        0.0
    }
}

/// The pixels of the levels' frame an accumulation outputs: the frame without its guard band.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Region {
    /// Column of the region's left pixel in the levels' frame.
    pub x0: usize,
    /// Row of the region's top pixel in the levels' frame.
    pub y0: usize,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
}

impl Region {
    /// The whole `width` x `height` frame.
    pub fn whole(width: usize, height: usize) -> Self {
        Self {
            x0: 0,
            y0: 0,
            width,
            height,
        }
    }
}

/// Blends the levels into the output image of `region` with the paper's box bokeh (premultiplied
/// linear RGBA): the box half of [`super::accumulate_for`], which picks it or the aperture's
/// shape.
pub fn accumulate_box(
    levels: &[Level],
    borders: &Borders,
    epsilon: f32,
    region: Region,
) -> ColorImage {
    accumulate_with(levels, borders, epsilon, region, accumulate_row)
}

/// [`accumulate_box`] built for the portable baseline only: the twin the run-time dispatched
/// build is tested against.
pub fn accumulate_box_baseline(
    levels: &[Level],
    borders: &Borders,
    epsilon: f32,
    region: Region,
) -> ColorImage {
    accumulate_with(levels, borders, epsilon, region, accumulate_row_inner)
}

/// Blends the levels into the output image with the paper's box bokeh (premultiplied linear
/// RGBA).
pub fn accumulate(
    levels: &[Level],
    borders: &Borders,
    epsilon: f32,
    width: usize,
    height: usize,
) -> ColorImage {
    accumulate_with(
        levels,
        borders,
        epsilon,
        Region::whole(width, height),
        accumulate_row,
    )
}

/// [`accumulate`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn accumulate_baseline(
    levels: &[Level],
    borders: &Borders,
    epsilon: f32,
    width: usize,
    height: usize,
) -> ColorImage {
    accumulate_with(
        levels,
        borders,
        epsilon,
        Region::whole(width, height),
        accumulate_row_inner,
    )
}

/// Per level of `n`, the depths it can serve: a weight above 0 needs `lambda` in `(s - 1, s +
/// 1)`, inside `(near(s + 1), far(s + 1))` and outside `[near(s - 1), far(s - 1)]`, widened a
/// little so that only fragments of weight 0 are skipped (the weight itself decides the rest).
/// A depth `z` is skipped where `z <= i0 || z >= i1 || (z > o0 && z < o1)`.
pub fn gates(borders: &Borders, n: usize) -> Vec<(f32, f32, f32, f32)> {
    (0..n)
        .map(|s| {
            let (i0, i1) = if s + 1 < n {
                (
                    borders.near_at(s as f32 + 1.0) * (1.0 - 1e-4),
                    borders.far_at(s as f32 + 1.0) * (1.0 + 1e-4),
                )
            } else {
                (f32::NEG_INFINITY, f32::INFINITY)
            };
            let (o0, o1) = if s > 0 {
                (
                    borders.near_at(s as f32 - 1.0) * (1.0 + 1e-4),
                    borders.far_at(s as f32 - 1.0) * (1.0 - 1e-4),
                )
            } else {
                (f32::INFINITY, f32::NEG_INFINITY)
            };
            (i0, i1, o0, o1)
        })
        .collect()
}

/// What every row of [`accumulate`] reads.
struct RowInputs<'a> {
    levels: &'a [Level],
    borders: &'a Borders,
    /// Per level, the depths it can serve ([`gates`]).
    gates: &'a [(f32, f32, f32, f32)],
    epsilon: f32,
}

fn accumulate_with(
    levels: &[Level],
    borders: &Borders,
    epsilon: f32,
    region: Region,
    row_fn: impl Fn(&RowInputs, usize, usize, &mut [Rgba]) + Sync,
) -> ColorImage {
    let gates = gates(borders, levels.len());
    let Region {
        x0,
        y0,
        width,
        height,
    } = region;
    let mut data = vec![[0.0f32; 4]; width * height];
    let inputs = RowInputs {
        levels,
        borders,
        gates: &gates,
        epsilon,
    };
    data.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, row)| row_fn(&inputs, x0, y0 + y, row));
    ColorImage::from_vec(width, height, data).expect("sizes agree by construction")
}

/// One row of [`accumulate`]. Compiled for several instruction sets and chosen at run time
/// ([`multiversion`]): with SSE4.1 and later the level weight's `floor` is one instruction
/// instead of a library call; the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn accumulate_row(inputs: &RowInputs, x0: usize, y: usize, row: &mut [Rgba]) {
    accumulate_row_inner(inputs, x0, y, row);
}

#[inline(always)]
fn accumulate_row_inner(inputs: &RowInputs, x0: usize, y: usize, row: &mut [Rgba]) {
    let RowInputs {
        levels,
        borders,
        gates,
        epsilon,
    } = *inputs;
    let n = levels.len();
    let mut entries: Vec<Entry> = Vec::new();
    for (x, out) in (x0..).zip(row.iter_mut()) {
        entries.clear();
        for (s, level) in levels.iter().enumerate() {
            let (cx, cy) = level.cell_of_pixel(x, y);
            let (depths, colors) = level.cell(cx, cy);
            let (i0, i1, o0, o1) = gates[s];
            for (&z, c) in depths.iter().zip(colors) {
                if z <= i0 || z >= i1 || (z > o0 && z < o1) {
                    continue;
                }
                let weight = level_weight(borders.lambda(z), s, n);
                if weight > 0.0 {
                    entries.push(Entry {
                        depth_m: z,
                        level: s as u8,
                        weight,
                        color: from_half(c),
                    });
                }
            }
        }
        // Stable: equal depths keep level order.
        entries.sort_by(|a, b| a.depth_m.total_cmp(&b.depth_m));
        *out = composite(&entries, n, epsilon);
    }
}

/// One fragment of one level at a pixel, with its level weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Entry {
    /// View depth in metres.
    pub depth_m: f32,
    /// The level it comes from.
    pub level: u8,
    /// The level's weight at this depth (see [`level_weight`]).
    pub weight: f32,
    /// Premultiplied linear RGBA, unweighted.
    pub color: Rgba,
}

/// Front-to-back blending of depth-sorted weighted fragments: a group opens at the nearest
/// remaining fragment and takes every fragment within the depth threshold of it; within a
/// level the group's fragments are combined with the over operator, across levels their
/// weighted contributions add up; groups are blended with the over operator.
#[inline(always)]
pub fn composite(entries: &[Entry], levels: usize, epsilon: f32) -> Rgba {
    let mut out = [0.0f32; 4];
    let mut transmit = 1.0f32;
    let mut level_transmit = vec![1.0f32; levels];
    let mut i = 0;
    while i < entries.len() && transmit > 1e-5 {
        let z0 = entries[i].depth_m;
        let limit = z0 + epsilon * z0.abs();
        level_transmit.iter_mut().for_each(|t| *t = 1.0);
        let mut p = [0.0f32; 4];
        while i < entries.len() && entries[i].depth_m <= limit {
            let e = &entries[i];
            let t = &mut level_transmit[e.level as usize];
            for (pk, ck) in p.iter_mut().zip(e.color) {
                *pk += *t * e.weight * ck;
            }
            *t *= 1.0 - e.color[3];
            i += 1;
        }
        // Weights of one fragment sum to 1 over the levels, so the sum stays a coverage; a
        // group that still exceeds 1 (rounding) is scaled back to opaque.
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
