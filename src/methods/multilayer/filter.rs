//! Pass `filter` (Selgrad et al. section 5): from the base fragment lists, levels filtered by
//! box filters of width 2^S pixels, built incrementally by merging 2x2 lists of the previous
//! level: `m` mip-mapping steps (section 5.1, half resolution each) then `s` stack steps
//! (section 5.2, fig. 4: same resolution, the four lists `d = 2^k` cells apart, borders
//! clamped): the Y-map.
//!
//! Merging (section 5.1, fig. 2), merge-sort style: the nearest remaining fragment of the four
//! sources opens a merged fragment; every fragment within the depth threshold of it joins.
//! Fragments of one source list are combined with the over operator front to back (a list's
//! fragments occlude each other); the four per-list results are combined additively, divided by
//! four, with an empty list counting as transparent (lists are side by side and cannot occlude
//! each other). In premultiplied colour both rules are sums: `p' = p_a + (1 - a_a) p_b`,
//! `a' = a_a + (1 - a_a) a_b` within a list, `p = (p'_1 + ... + p'_4) / 4` across. So an opaque
//! surface stays opaque and a partly covered cell gets partial opacity.
//!
//! The depth threshold is relative (`epsilon * z` of the opening fragment): the paper gives it in
//! depth units without a value; relative to depth, one value fits scenes of any scale, as the
//! precision of a depth buffer does. The merged fragment's depth is the opacity-weighted mean of
//! the fragments merged.
//!
//! Truncation (section 6.2): a level S only serves depths whose level coordinate `lambda(z)` (see
//! [`super::Borders`]) is above `S - 1`, and every later level serves only larger ones, so
//! fragments with `lambda(z) <= S - 1` are dropped while building level S: the paper's middle
//! interval `z_N,S-1 < z < z_F,S-1`.

use rayon::prelude::*;

use crate::raster::{
    from_half, par_concat, par_copy, par_offsets, to_half, FragmentLists, HalfRgba,
};

/// Largest number of fragments kept in one list of a filtered level (the farthest are dropped
/// beyond it; merging keeps lists far shorter in practice).
pub const MAX_LEVEL_FRAGMENTS: usize = 64;

/// One level of the filtered hierarchy: per-cell fragment lists in compact arrays, and where
/// the cells sit on the image.
#[derive(Clone, Debug, PartialEq)]
pub struct Level {
    /// Cells per row.
    pub width: usize,
    /// Rows of cells.
    pub height: usize,
    /// Width in image pixels of the box filter this level applies: `2^S` for level S.
    pub footprint_px: f32,
    /// Image pixels from one cell to the next (1 for level 0 and stack levels of it).
    pub stride_px: f32,
    /// Image position, in pixels, of the centre of cell (0, 0) (0.5 for level 0).
    pub origin_px: f32,
    /// Prefix sum of per-cell counts, `width * height + 1` entries.
    pub offsets: Vec<u32>,
    /// View depth in metres of each fragment.
    pub depth: Vec<f32>,
    /// Premultiplied linear RGBA of each fragment, half precision.
    pub color: Vec<HalfRgba>,
    /// Where each fragment's light lies in its cell: the centroid of its energy (colour plus
    /// opacity, premultiplied) in pixels from the cell's centre, so that a small light keeps its
    /// place inside a box many pixels wide. Empty when not tracked (every centroid at the
    /// centre: level 0, or levels only the box accumulation reads).
    pub centroid: Vec<[f32; 2]>,
}

impl Level {
    /// Level 0: the base fragment lists themselves.
    pub fn base(lists: &FragmentLists) -> Self {
        Self {
            width: lists.width(),
            height: lists.height(),
            footprint_px: 1.0,
            stride_px: 1.0,
            origin_px: 0.5,
            offsets: par_copy(lists.offsets()),
            depth: par_copy(lists.depths()),
            color: par_copy(lists.colors()),
            centroid: Vec::new(),
        }
    }

    /// The centroids of the fragments of cell `(x, y)` (empty when not tracked).
    #[inline]
    pub fn cell_centroids(&self, x: usize, y: usize) -> &[[f32; 2]] {
        if self.centroid.is_empty() {
            return &[];
        }
        let i = y * self.width + x;
        &self.centroid[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Image position in pixels of the centre of cell `(x, y)`.
    #[inline]
    pub fn centre_px(&self, x: usize, y: usize) -> [f32; 2] {
        [
            self.origin_px + self.stride_px * x as f32,
            self.origin_px + self.stride_px * y as f32,
        ]
    }

    /// The fragments of cell `(x, y)`.
    #[inline]
    pub fn cell(&self, x: usize, y: usize) -> (&[f32], &[HalfRgba]) {
        let i = y * self.width + x;
        let (a, b) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        (&self.depth[a..b], &self.color[a..b])
    }

    /// The cell whose centre is nearest to the centre of image pixel `(x, y)`.
    #[inline]
    pub fn cell_of_pixel(&self, x: usize, y: usize) -> (usize, usize) {
        // Truncation toward zero is the floor here once negatives are clamped to 0 (and it
        // needs no libm call).
        let c = |p: usize, n: usize| {
            let t = (p as f32 + 0.5 - self.origin_px) / self.stride_px + 0.5;
            (t.max(0.0) as usize).min(n - 1)
        };
        (c(x, self.width), c(y, self.height))
    }

    /// Among the cells (of `n` along one axis) whose index is a multiple of `step`, the two
    /// whose centres lie on either side of the centre of image pixel `p`, and the weight of the
    /// second for linear interpolation (clamped at the borders).
    #[inline]
    pub fn between(&self, p: usize, n: usize, step: usize) -> ((usize, usize), f32) {
        let t = ((p as f32 + 0.5 - self.origin_px) / (self.stride_px * step as f32)).max(0.0);
        let last = (n - 1) / step;
        // Truncation is the floor once negatives are clamped to 0.
        let k0 = (t as usize).min(last);
        let f = (t - k0 as f32).clamp(0.0, 1.0);
        ((k0 * step, (k0 + 1).min(last) * step), f)
    }

    /// Number of fragments stored.
    pub fn len(&self) -> usize {
        self.depth.len()
    }

    /// True when no cell has a fragment.
    pub fn is_empty(&self) -> bool {
        self.depth.is_empty()
    }

    /// Bytes of the compact storage.
    pub fn bytes(&self) -> usize {
        self.offsets.len() * 4
            + self.depth.len() * 4
            + self.color.len() * 8
            + self.centroid.len() * 8
    }
}

/// One filtering step (the stack steps pair cells `offset` apart, centred: see [`step`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// 2x2 cells into one, half resolution (section 5.1).
    Mip,
    /// Same resolution, the four cells `offset` cells apart (section 5.2).
    Stack {
        /// Distance in cells between the merged lists: 1, 2, 4, ... for the stack steps in
        /// turn.
        offset: usize,
    },
}

/// The steps of a Y-map with `mip` mip-mapping steps then `stack` stack steps.
pub fn y_map(mip: usize, stack: usize) -> Vec<Step> {
    let mut steps = vec![Step::Mip; mip];
    steps.extend((0..stack).map(|k| Step::Stack { offset: 1 << k }));
    steps
}

/// A fragment being accumulated from one source list (over operator, front to back).
#[derive(Clone, Copy, Default)]
struct Partial {
    p: [f32; 4],
    depth_weight: f32,
    depth_sum: f32,
    /// Energy (opacity plus colour, as composited) and its first moments in x and y.
    energy: f32,
    moment: [f32; 2],
}

/// One source list of [`merge4`]: depths, colours and centroids (empty: at the cell's centre).
pub type Source<'a> = (&'a [f32], &'a [HalfRgba], &'a [[f32; 2]]);

/// The centres of [`merge4`]'s four source cells relative to the merged cell's, in pixels.
pub type SourceCentres = [[f32; 2]; 4];

/// Where [`merge4`] writes the merged fragments.
pub struct MergeOut<'a> {
    /// Merged depths.
    pub depth: &'a mut Vec<f32>,
    /// Merged colours.
    pub color: &'a mut Vec<HalfRgba>,
    /// With the centres of the four source cells relative to the merged cell's, in pixels:
    /// each merged fragment's energy centroid goes here.
    pub centroid: Option<(&'a mut Vec<[f32; 2]>, SourceCentres)>,
}

/// Merges four depth-sorted lists into `out` (see the module documentation). `keep(z)` says
/// whether a merged fragment at depth `z` is kept (truncation).
#[inline(always)]
pub fn merge4(
    sources: [Source; 4],
    epsilon: f32,
    keep: &dyn Fn(f32) -> bool,
    out: &mut MergeOut,
) -> usize {
    let mut idx = [0usize; 4];
    let mut emitted = 0;
    let track = out.centroid.is_some();
    loop {
        // The nearest remaining fragment opens the merged fragment.
        let mut z0 = f32::INFINITY;
        let mut any = false;
        for j in 0..4 {
            if let Some(&z) = sources[j].0.get(idx[j]) {
                if !any || z < z0 {
                    z0 = z;
                    any = true;
                }
            }
        }
        if !any {
            break;
        }
        let limit = z0 + epsilon * z0.abs();
        let mut parts = [Partial::default(); 4];
        for j in 0..4 {
            let (depths, colors, centroids) = sources[j];
            let part = &mut parts[j];
            while let Some(&z) = depths.get(idx[j]) {
                if z > limit {
                    break;
                }
                let c = from_half(&colors[idx[j]]);
                let t = 1.0 - part.p[3];
                for (pk, ck) in part.p.iter_mut().zip(c) {
                    *pk += t * ck;
                }
                let w = t * c[3];
                part.depth_weight += w;
                part.depth_sum += w * z;
                if track {
                    let e = (t * (c[0] + c[1] + c[2] + c[3])).max(0.0);
                    let at = centroids.get(idx[j]).copied().unwrap_or([0.0; 2]);
                    part.energy += e;
                    part.moment[0] += e * at[0];
                    part.moment[1] += e * at[1];
                }
                idx[j] += 1;
            }
        }
        let mut p = [0.0f32; 4];
        let (mut dw, mut ds) = (0.0f32, 0.0f32);
        for part in &parts {
            for (pk, qk) in p.iter_mut().zip(part.p) {
                *pk += 0.25 * qk;
            }
            dw += part.depth_weight;
            ds += part.depth_sum;
        }
        let z = if dw > 0.0 { ds / dw } else { z0 };
        if p[3] > 0.0 && keep(z) && emitted < MAX_LEVEL_FRAGMENTS {
            out.depth.push(z);
            out.color.push(to_half(p));
            if let Some((centroid, centres)) = out.centroid.as_mut() {
                let (mut e, mut mx, mut my) = (0.0f32, 0.0f32, 0.0f32);
                for (part, at) in parts.iter().zip(centres.iter()) {
                    e += part.energy;
                    mx += part.moment[0] + part.energy * at[0];
                    my += part.moment[1] + part.energy * at[1];
                }
                centroid.push(if e > 0.0 { [mx / e, my / e] } else { [0.0; 2] });
            }
            emitted += 1;
        }
    }
    emitted
}

/// Applies one step to `level`. `keep(z)` filters the merged fragments (truncation);
/// `centroids` tracks where each merged fragment's energy lies in its cell
/// ([`Level::centroid`]).
pub fn step(
    level: &Level,
    step: Step,
    epsilon: f32,
    keep: &(dyn Fn(f32) -> bool + Sync),
    centroids: bool,
) -> Level {
    step_with(level, step, epsilon, keep, centroids, step_row)
}

/// [`step`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn step_baseline(
    level: &Level,
    step: Step,
    epsilon: f32,
    keep: &(dyn Fn(f32) -> bool + Sync),
    centroids: bool,
) -> Level {
    step_with(level, step, epsilon, keep, centroids, step_row_inner)
}

/// One output row of a step: per cell the number of fragments, then their depths, colours and
/// centroids (empty when not tracked).
type Row = (Vec<u32>, Vec<f32>, Vec<HalfRgba>, Vec<[f32; 2]>);

/// What every row of a step reads: the level, the step, its source distance `d`, the output
/// width, `epsilon` and `keep`.
struct RowInputs<'a> {
    level: &'a Level,
    step: Step,
    d: usize,
    nw: usize,
    epsilon: f32,
    keep: &'a (dyn Fn(f32) -> bool + Sync),
    /// The output level's cell centres (`origin + stride * i` pixels), when centroids are
    /// tracked.
    centres: Option<(f32, f32)>,
}

fn step_with(
    level: &Level,
    step: Step,
    epsilon: f32,
    keep: &(dyn Fn(f32) -> bool + Sync),
    centroids: bool,
    row_fn: impl Fn(&RowInputs, usize) -> Row + Sync,
) -> Level {
    let (w, h) = (level.width, level.height);
    let (nw, nh, stride, origin, d) = match step {
        Step::Mip => (
            w.div_ceil(2),
            h.div_ceil(2),
            level.stride_px * 2.0,
            level.origin_px + 0.5 * level.stride_px,
            1,
        ),
        // The first stack step pairs each cell with its right (lower) neighbour and moves the
        // centres half a cell; the later ones pair the cells d/2 on either side, so the boxes
        // stay centred on their cells and every cell centre stays inside the image.
        Step::Stack { offset } => (
            w,
            h,
            level.stride_px,
            level.origin_px
                + if offset == 1 {
                    0.5 * level.stride_px
                } else {
                    0.0
                },
            offset,
        ),
    };
    let inputs = RowInputs {
        level,
        step,
        d,
        nw,
        epsilon,
        keep,
        centres: centroids.then_some((origin, stride)),
    };
    let rows: Vec<Row> = (0..nh)
        .into_par_iter()
        .map(|y| row_fn(&inputs, y))
        .collect();
    Level {
        width: nw,
        height: nh,
        footprint_px: level.footprint_px * 2.0,
        stride_px: stride,
        origin_px: origin,
        offsets: par_offsets(&rows.iter().map(|r| &r.0[..]).collect::<Vec<_>>()),
        depth: par_concat(&rows.iter().map(|r| &r.1[..]).collect::<Vec<_>>()),
        color: par_concat(&rows.iter().map(|r| &r.2[..]).collect::<Vec<_>>()),
        centroid: par_concat(&rows.iter().map(|r| &r.3[..]).collect::<Vec<_>>()),
    }
}

/// Output row `y` of a step. Compiled for several instruction sets and chosen at run time
/// ([`multiversion`]); the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn step_row(inputs: &RowInputs, y: usize) -> Row {
    step_row_inner(inputs, y)
}

#[inline(always)]
fn step_row_inner(inputs: &RowInputs, y: usize) -> Row {
    let RowInputs {
        level,
        step,
        d,
        nw,
        epsilon,
        keep,
        centres,
    } = *inputs;
    let (w, h) = (level.width, level.height);
    let mut counts = Vec::with_capacity(nw);
    let mut depth = Vec::new();
    let mut color = Vec::new();
    let mut centroid = Vec::new();
    // Source cells of a row or column: (lo, hi), clamped to the level (border cells
    // extended, fig. 4).
    let pair = |i: usize, n: usize| -> (usize, usize) {
        match step {
            Step::Mip => ((2 * i).min(n - 1), (2 * i + 1).min(n - 1)),
            Step::Stack { .. } if d == 1 => (i, (i + 1).min(n - 1)),
            Step::Stack { .. } => (i.saturating_sub(d / 2), (i + d / 2).min(n - 1)),
        }
    };
    let (sy, y1) = pair(y, h);
    for x in 0..nw {
        let (sx, x1) = pair(x, w);
        let cells = [(sx, sy), (x1, sy), (sx, y1), (x1, y1)];
        let sources = cells.map(|(cx, cy)| {
            let (d, c) = level.cell(cx, cy);
            (d, c, level.cell_centroids(cx, cy))
        });
        let mut out = MergeOut {
            depth: &mut depth,
            color: &mut color,
            centroid: centres.map(|(origin, stride)| {
                let at = [origin + stride * x as f32, origin + stride * y as f32];
                let rel = cells.map(|(cx, cy)| {
                    let c = level.centre_px(cx, cy);
                    [c[0] - at[0], c[1] - at[1]]
                });
                (&mut centroid, rel)
            }),
        };
        let n = merge4(sources, epsilon, keep, &mut out);
        counts.push(n as u32);
    }
    (counts, depth, color, centroid)
}
