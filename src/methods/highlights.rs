//! Bright highlights seen past nearer surfaces ray by ray, for the layered methods
//! (`multilayer`, `splat --layers N` on their fragment lists; `multiview` on its layers read as
//! lists; `--highlight-rays`).
//!
//! Those methods composite each surface's blur over what lies behind it with the blur's
//! coverage. Behind a thin near object (a railing whose blur is 48 px wide) a light far behind
//! is then dimmed evenly by the share of the lens the object covers. Through a real lens the
//! light's bokeh is the image of the aperture, each of its points seen through one lens point;
//! the bars block a band of lens points and draw a sharp shadow across the disc, as `reference`
//! and `multiview` (which trace rays) show. With a light brighter than white the even dimming
//! leaves the disc white where the shadow is dark.
//!
//! So a fragment brighter than a threshold (its colour's luminance over its coverage) is taken
//! out of the method's colour, and stays in it as an occluder: its coverage is kept and its
//! colour set to zero. It is scattered on its own: pixel `p` of its footprint (the aperture's
//! shape of radius `|C|` around its centre `x`, weighed as `splat` weighs a fragment, so it
//! keeps its energy) sees it through the one lens point `u = (p - x) / C`, and takes it with
//! that ray's visibility. The ray is over pinhole position `p - c u` at CoC `c` (eq. 3 of Lee
//! et al.), so from the light back towards the eye it passes the pixels from `x` along `u`; in
//! each it meets the fragments nearer than the light whose CoC lies within the ray's CoC over
//! that pixel, and keeps `1 - alpha` of each. The walk ends at the nearest CoC of the lists or
//! when less than 1e-3 is left.
//!
//! Only a fragment at least [`MIN_COC_PX`] out of focus is a highlight: nearer the focus no lens
//! point is cut off that the blur of its neighbours does not show as well. (`multiview` traces
//! every ray anyway; there the scatter replaces the few of a pixel's rays that meet a small
//! light, which made its bokeh noisy.)
//!
//! What keeps it affordable: a ray skips the blocks of `BLOCK` pixels and the pixels that hold
//! nothing in the 64 bins of CoC it crosses there; a highlight whose rays can pass nothing nearer
//! is drawn whole; the rest trace their visibility on a grid `stride_px` apart, pixel by pixel
//! only in the cells a shadow's edge crosses, and with four rays over the pixels at the edge.

use glam::Vec2;
use rayon::prelude::*;

use crate::image::luminance;
use crate::image::ColorImage;
use crate::lens::ThinLens;
use crate::raster::{from_half, to_half, FragmentLists};

use super::splat::blend::Shape;

/// The smallest |CoC| radius in pixels of the output at which a bright fragment is scattered
/// with its rays' visibility.
pub const MIN_COC_PX: f32 = 1.0;

/// Surfaces within this many pixels of CoC of a highlight (of the lists) are its own (the
/// light's fitting, or the light itself): they do not shade it.
const OWN_SURFACE_PX: f32 = 1.0;

/// A bright fragment taken out of the lists.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Highlight {
    /// Centre of its pixel, in the lists' pixels.
    pub centre: Vec2,
    /// Its signed CoC radius, in the lists' pixels.
    pub coc_px: f32,
    /// Linear premultiplied colour (its coverage included).
    pub color: [f32; 3],
}

/// Checks a highlight threshold (`None`: off): a luminance above zero.
pub fn check_threshold(threshold: Option<f32>) -> crate::Result<()> {
    match threshold {
        Some(t) if !(t.is_finite() && t > 0.0) => Err(crate::Error::invalid(
            "highlights",
            format!("{t}: expected a luminance above 0, or off"),
        )),
        _ => Ok(()),
    }
}

/// `--highlight-rays`: a luminance above zero, or `off` (`None`).
pub fn parse_threshold(s: &str) -> crate::Result<Option<f32>> {
    if s.trim().eq_ignore_ascii_case("off") {
        return Ok(None);
    }
    let bad = || {
        crate::Error::invalid(
            "highlight-rays",
            format!("{s:?}: expected a luminance above 0 (1 is white), or off"),
        )
    };
    let t: f32 = s.trim().parse().map_err(|_| bad())?;
    if !(t.is_finite() && t > 0.0) {
        return Err(bad());
    }
    Ok(Some(t))
}

/// Takes out of `lists` (made with `lens`, whose pixels are `scale` times finer than the
/// output's) every fragment brighter than `threshold` (luminance of its colour over its
/// coverage) whose CoC is at least [`MIN_COC_PX`] pixels of the output, with its CoC clamped to
/// `max_coc_px` of the output: its colour becomes zero (its coverage stays, it still hides what
/// lies behind it) and it is returned; so are the bright fragments the lists kept apart from a
/// full pixel ([`FragmentLists::overflow_highlights`]).
pub fn take(
    lists: &mut FragmentLists,
    lens: &ThinLens,
    scale: f32,
    threshold: f32,
    max_coc_px: f32,
) -> Vec<Highlight> {
    let mut found: Vec<Highlight> = take_indexed(lists, lens, scale, threshold, max_coc_px)
        .into_iter()
        .map(|(_, h)| h)
        .collect();
    // Those a full pixel kept apart (`FragmentLists::keeping_bright_overflow`): their colour
    // is in no fragment of the lists, so they are scattered whatever their CoC.
    let (width, max) = (lists.width(), max_coc_px * scale);
    let (offsets, depths, colors) = (lists.offsets(), lists.depths(), lists.colors());
    let own_alpha = lists.own_alphas();
    found.extend(
        lists
            .overflow_highlights()
            .iter()
            .map(|&(pixel, depth, c)| {
                let coc = lens.coc_px(depth);
                let range = offsets[pixel] as usize..offsets[pixel + 1] as usize;
                let seen = seen_in_pixel(lens, (depths, colors, own_alpha), &range, depth);
                Highlight {
                    centre: Vec2::new((pixel % width) as f32 + 0.5, (pixel / width) as f32 + 0.5),
                    coc_px: coc.clamp(-max, max),
                    color: [c[0], c[1], c[2]].map(|v| v * seen),
                }
            }),
    );
    found
}

/// [`take`], each highlight with the index of its fragment in the lists.
pub fn take_indexed(
    lists: &mut FragmentLists,
    lens: &ThinLens,
    scale: f32,
    threshold: f32,
    max_coc_px: f32,
) -> Vec<(usize, Highlight)> {
    let width = lists.width();
    let max = max_coc_px * scale;
    let found: Vec<(usize, Highlight)> = {
        let (offsets, depths, colors) = (lists.offsets(), lists.depths(), lists.colors());
        let own_alpha = lists.own_alphas();
        offsets
            .par_windows(2)
            .enumerate()
            .flat_map_iter(|(pixel, range)| {
                let range = range[0] as usize..range[1] as usize;
                range.clone().filter_map(move |f| {
                    let c = from_half(&colors[f]);
                    let rgb = [c[0], c[1], c[2]];
                    if c[3] <= 0.0 || luminance(rgb) <= threshold * c[3] {
                        return None;
                    }
                    let coc = lens.coc_px(depths[f]);
                    if coc.is_nan() || coc.abs() < MIN_COC_PX * scale {
                        return None;
                    }
                    let seen = seen_in_pixel(lens, (depths, colors, own_alpha), &range, depths[f]);
                    let (x, y) = (pixel % width, pixel / width);
                    let h = Highlight {
                        centre: Vec2::new(x as f32 + 0.5, y as f32 + 0.5),
                        coc_px: coc.clamp(-max, max),
                        color: rgb.map(|v| v * seen),
                    };
                    Some((f, h))
                })
            })
            .collect()
    };
    let colors = lists.colors_mut();
    for &(f, _) in &found {
        let alpha = from_half(&colors[f])[3];
        colors[f] = to_half([0.0, 0.0, 0.0, alpha]);
    }
    found
}

/// The share of a highlight at depth `depth` that its own pixel shows: the product of
/// `1 - alpha` of the pixel's fragments (`range` of the lists' `depths`, `colors` and
/// `own_alpha`) in front of it that lie within [`OWN_SURFACE_PX`] of its CoC. The method
/// composites a pixel's fragments near to far with the over operator, so that is what taking
/// the highlight out of the method removes; its rays skip those surfaces (they are the light's
/// own: the front of a small double-sided sphere before its back, whose coverage masks the
/// lists resolve only as far as the over operator goes), so without it the back of a light was
/// scattered as well as its front (up to half again a small light's energy). By depth, not by
/// place in the list: `multiview`'s layers read as lists are in the order of their layers.
fn seen_in_pixel(
    lens: &ThinLens,
    (depths, colors, own_alpha): (&[f32], &[crate::raster::HalfRgba], Option<&[half::f16]>),
    range: &std::ops::Range<usize>,
    depth: f32,
) -> f32 {
    let own = lens.coc_px(depth) - OWN_SURFACE_PX;
    range
        .clone()
        .filter(|&g| depths[g] < depth && lens.coc_px(depths[g]) > own)
        .fold(1.0, |seen, g| {
            let alpha = own_alpha.map_or(colors[g][3], |o| o[g]).to_f32();
            seen * (1.0 - alpha.clamp(0.0, 1.0))
        })
}

/// The lists' fragments' CoCs (in the lists' pixels), the nearest of them, and which of 64
/// bins of CoC between it and the farthest highlight's each pixel and each block of [`BLOCK`]
/// pixels holds: a ray skips the pixels and blocks that hold nothing in the bins of its CoC
/// over them.
struct Cocs {
    coc: Vec<f32>,
    nearest: f32,
    bins: Bins,
    pixel_bins: Vec<u64>,
    blocks: (i64, i64),
    block_bins: Vec<u64>,
}

/// 64 bins of CoC from `first`, `width` apart (the first and last open-ended).
#[derive(Clone, Copy)]
struct Bins {
    first: f32,
    inv_width: f32,
}

impl Bins {
    fn bin(&self, c: f32) -> u32 {
        ((c - self.first) * self.inv_width).clamp(0.0, 63.0) as u32
    }

    /// The bins CoCs from `lo` to `hi` fall in.
    fn span(&self, lo: f32, hi: f32) -> u64 {
        let (a, b) = (self.bin(lo), self.bin(hi));
        (u64::MAX >> (63 - b)) & (u64::MAX << a)
    }
}

impl Cocs {
    fn new(lists: &FragmentLists, lens: &ThinLens, farthest: f32) -> Self {
        let coc: Vec<f32> = lists.depths().par_iter().map(|&d| lens.coc_px(d)).collect();
        let nearest = coc.par_iter().copied().reduce(|| f32::INFINITY, f32::min);
        let range = (farthest - nearest).max(1e-3);
        let bins = Bins {
            first: nearest,
            inv_width: 64.0 / range,
        };
        let pixel_bins: Vec<u64> = lists
            .offsets()
            .par_windows(2)
            .map(|r| {
                coc[r[0] as usize..r[1] as usize]
                    .iter()
                    .filter(|&&c| c <= farthest)
                    .fold(0u64, |m, &c| m | 1 << bins.bin(c))
            })
            .collect();
        let (w, h) = (lists.width(), lists.height());
        let b = BLOCK as usize;
        let (bw, bh) = (w.div_ceil(b), h.div_ceil(b));
        let mut block_bins = vec![0u64; bw * bh];
        for (y, row) in pixel_bins.chunks(w.max(1)).enumerate() {
            for (x, &m) in row.iter().enumerate() {
                block_bins[(y / b) * bw + x / b] |= m;
            }
        }
        Self {
            coc,
            nearest,
            bins,
            pixel_bins,
            blocks: (bw as i64, bh as i64),
            block_bins,
        }
    }
}

impl Cocs {
    /// Whether nothing nearer than a highlight at `x0` of CoC `c0` (in the lists' pixels) lies
    /// where its rays pass, those of lens points up to `u_max` from the centre: every block
    /// within `u_max` times the rays' length of `x0` holds nothing in the bins from the nearest
    /// CoC to the highlight's own surface. Then every ray sees it whole.
    fn clear(&self, x0: Vec2, c0: f32, u_max: f32) -> bool {
        let t_end = c0 - self.nearest + 1.0;
        if t_end <= 0.0 {
            return true;
        }
        let span = self.bins.span(self.nearest, c0 - OWN_SURFACE_PX);
        let r = t_end * u_max + 1.0;
        let b = BLOCK as f32;
        let (bw, bh) = self.blocks;
        let (bx0, bx1) = (
            ((x0.x - r) / b).floor() as i64,
            ((x0.x + r) / b).floor() as i64,
        );
        let (by0, by1) = (
            ((x0.y - r) / b).floor() as i64,
            ((x0.y + r) / b).floor() as i64,
        );
        (by0.max(0)..=by1.min(bh - 1)).all(|by| {
            (bx0.max(0)..=bx1.min(bw - 1))
                .all(|bx| self.block_bins[(by * bw + bx) as usize] & span == 0)
        })
    }
}

/// Side in pixels of the blocks a ray can skip whole.
const BLOCK: i64 = 8;

/// A walk along the ray `origin + t u` (t >= 0) over square cells of side `size`: the cell it
/// is in, and the `t` at which it crosses the next cell boundary along each axis.
struct Cells {
    cell: (i64, i64),
    step: (i64, i64),
    next: (f32, f32),
    delta: (f32, f32),
}

impl Cells {
    /// The walk from `t`, in cells of `size` pixels, its first cell kept within `[lo, hi]` on
    /// both axes (where rounding puts a point on a boundary on the wrong side).
    fn at(origin: Vec2, u: Vec2, size: f32, t: f32, lo: (i64, i64), hi: (i64, i64)) -> Self {
        let q = origin + t * u;
        let axis = |q: f32, u: f32, lo: i64, hi: i64| {
            let cell = ((q / size).floor() as i64).clamp(lo, hi);
            let (step, delta) = if u > 0.0 {
                (1, size / u)
            } else if u < 0.0 {
                (-1, -size / u)
            } else {
                (1, f32::INFINITY)
            };
            let next = if delta.is_infinite() {
                f32::INFINITY
            } else {
                let boundary = (cell + i64::from(step > 0)) as f32 * size;
                t + (boundary - q) / u
            };
            (cell, step, next.max(t), delta)
        };
        let (cx, sx, nx, dx) = axis(q.x, u.x, lo.0, hi.0);
        let (cy, sy, ny, dy) = axis(q.y, u.y, lo.1, hi.1);
        Self {
            cell: (cx, cy),
            step: (sx, sy),
            next: (nx, ny),
            delta: (dx, dy),
        }
    }

    /// Where the ray leaves the cell.
    fn exit(&self) -> f32 {
        self.next.0.min(self.next.1)
    }

    /// On to the next cell.
    fn advance(&mut self) {
        if self.next.0 < self.next.1 {
            self.cell.0 += self.step.0;
            self.next.0 += self.delta.0;
        } else {
            self.cell.1 += self.step.1;
            self.next.1 += self.delta.1;
        }
    }
}

/// The visibility of a highlight at CoC `c0` centred at `x0` from the lens point `u` (both in
/// the lists' pixels): the product of `1 - alpha` of the fragments nearer than it that the ray
/// meets, pixel by pixel from `x0` along `u` down to CoC `nearest`, skipping the blocks of
/// [`BLOCK`] pixels that hold nothing at the ray's CoC over them.
fn visibility(lists: &FragmentLists, cocs: &Cocs, x0: Vec2, c0: f32, u: Vec2) -> f32 {
    let (w, h) = (lists.width() as i64, lists.height() as i64);
    let offsets = lists.offsets();
    let colors = lists.colors();
    // The opacity each fragment hides a light behind it with: its own surfaces' (what a full
    // pixel merged into it lay behind it), where the lists keep it.
    let own_alpha = lists.own_alphas();
    // Along t = c0 - c (0 at the light, growing towards the eye) the ray is over x0 + t u,
    // to a pixel of CoC past the nearest surface (whose CoC would otherwise end the walk's
    // last interval, which is open there).
    let t_end = c0 - cocs.nearest + 1.0;
    if t_end <= 0.0 {
        return 1.0;
    }
    // The light's own surfaces are left out.
    let own = c0 - OWN_SURFACE_PX;
    let mut v = 1.0f32;
    let anywhere = ((i64::MIN, i64::MIN), (i64::MAX, i64::MAX));
    let mut blocks = Cells::at(x0, u, BLOCK as f32, 0.0, anywhere.0, anywhere.1);
    let mut tb_in = 0.0f32;
    loop {
        let (bx, by) = blocks.cell;
        if bx < 0 || by < 0 || bx >= cocs.blocks.0 || by >= cocs.blocks.1 {
            return v;
        }
        let tb_out = blocks.exit().min(t_end);
        let span = cocs.bins.span(c0 - tb_out, (c0 - tb_in).min(own));
        if cocs.block_bins[(by * cocs.blocks.0 + bx) as usize] & span != 0 {
            // The block's pixels the ray passes (the first one kept inside the block whatever
            // the rounding).
            let first = (bx * BLOCK, by * BLOCK);
            let last = (first.0 + BLOCK - 1, first.1 + BLOCK - 1);
            let mut pixels = Cells::at(x0, u, 1.0, tb_in, first, last);
            let mut t_in = tb_in;
            while t_in < tb_out {
                let (px, py) = pixels.cell;
                if px < 0 || py < 0 || px >= w || py >= h {
                    return v;
                }
                let t_out = pixels.exit().min(tb_out);
                // The ray's CoC over this pixel: (c0 - t_out, c0 - t_in].
                let (c_lo, c_hi) = (c0 - t_out, (c0 - t_in).min(own));
                let i = (py * w + px) as usize;
                // Most pixels hold nothing at the ray's CoC over them.
                if cocs.pixel_bins[i] & cocs.bins.span(c_lo, c_hi) != 0 {
                    let range = offsets[i] as usize..offsets[i + 1] as usize;
                    for (f, &c) in range.clone().zip(&cocs.coc[range]) {
                        if c > c_lo && c <= c_hi {
                            let alpha = own_alpha.map_or(colors[f][3], |o| o[f]).to_f32();
                            v *= 1.0 - alpha.clamp(0.0, 1.0);
                        }
                    }
                    if v < 1e-3 {
                        return v;
                    }
                }
                t_in = t_out;
                pixels.advance();
            }
        }
        if tb_out >= t_end {
            return v;
        }
        tb_in = tb_out;
        blocks.advance();
    }
}

/// A highlight's rays' visibility at every pixel centre of the part of its footprint in the
/// output region: traced every [`stride_px`] pixels, then in each cell of that grid either
/// read bilinearly between its corners (where they agree within [`AGREE`]) or traced pixel by
/// pixel (where they differ: a shadow's edge crosses the cell).
struct Seen {
    origin: Vec2,
    cols: usize,
    rows: usize,
    v: Vec<f32>,
}

impl Seen {
    /// `visibility(p)` over the pixels within `reach` of `centre` in `region` (the footprint
    /// of radius `c`).
    fn new(
        centre: Vec2,
        c: f32,
        reach: f32,
        region: (usize, usize, usize, usize),
        visibility: impl Fn(Vec2) -> f32,
    ) -> Self {
        let stride = stride_px(c) as usize;
        let (origin, cols, rows) = window(centre, reach, region);
        let mut v = vec![0.0; cols * rows];
        // Pixels farther than a stride and a half outside the footprint's bounding circle are
        // read by no pixel of it: left at 0.
        let limit = reach + 1.5 * stride as f32;
        let trace = |i: usize, j: usize| {
            let p = origin + Vec2::new(i as f32, j as f32);
            if (p - centre).length() <= limit {
                visibility(p)
            } else {
                0.0
            }
        };
        // The grid's lines: every stride, and the last pixel.
        let lines = |n: usize| -> Vec<usize> {
            let mut l: Vec<usize> = (0..n).step_by(stride).collect();
            if n > 0 && l.last() != Some(&(n - 1)) {
                l.push(n - 1);
            }
            l
        };
        let (xs, ys) = (lines(cols), lines(rows));
        for &j in &ys {
            for &i in &xs {
                v[j * cols + i] = trace(i, j);
            }
        }
        for (ja, jb) in ys.iter().zip(ys.iter().skip(1)) {
            for (ia, ib) in xs.iter().zip(xs.iter().skip(1)) {
                let corner = |i: usize, j: usize| v[j * cols + i];
                let (a, b, d, e) = (
                    corner(*ia, *ja),
                    corner(*ib, *ja),
                    corner(*ia, *jb),
                    corner(*ib, *jb),
                );
                let (lo, hi) = (a.min(b).min(d).min(e), a.max(b).max(d).max(e));
                for j in *ja..=*jb {
                    for i in *ia..=*ib {
                        let on_line = (i == *ia || i == *ib) && (j == *ja || j == *jb);
                        if on_line {
                            continue;
                        }
                        v[j * cols + i] = if hi - lo <= AGREE {
                            let fx = (i - ia) as f32 / (ib - ia) as f32;
                            let fy = (j - ja) as f32 / (jb - ja) as f32;
                            let top = a + (b - a) * fx;
                            let bottom = d + (e - d) * fx;
                            top + (bottom - top) * fy
                        } else {
                            trace(i, j)
                        };
                    }
                }
            }
        }
        Self {
            origin,
            cols,
            rows,
            v,
        }
    }

    /// Every pixel sees the highlight whole (no samples held).
    fn clear() -> Self {
        Self {
            origin: Vec2::ZERO,
            cols: 0,
            rows: 0,
            v: Vec::new(),
        }
    }

    /// The visibility at pixel centre `p` where it agrees within [`AGREE`] with its four
    /// neighbours'; `None` where it does not (a shadow's edge passes by), for the caller to
    /// trace over the pixel's area.
    fn at(&self, p: Vec2) -> Option<f32> {
        if self.v.is_empty() {
            return Some(1.0);
        }
        let g = p - self.origin;
        let (n, m) = (self.cols as i64, self.rows as i64);
        let at = |i: i64, j: i64| self.v[(j.clamp(0, m - 1) * n + i.clamp(0, n - 1)) as usize];
        let (i, j) = (g.x.floor() as i64, g.y.floor() as i64);
        let v = at(i, j);
        let (lo, hi) = [at(i - 1, j), at(i + 1, j), at(i, j - 1), at(i, j + 1)]
            .iter()
            .fold((v, v), |(lo, hi), &a| (lo.min(a), hi.max(a)));
        (hi - lo <= AGREE).then_some(v)
    }
}

/// The pixels within `reach` of `centre` in the output region `(x0, y0, width, height)`: the
/// first one's centre, and how many columns and rows.
fn window(
    centre: Vec2,
    reach: f32,
    (x0, y0, width, height): (usize, usize, usize, usize),
) -> (Vec2, usize, usize) {
    let span = |centre: f32, lo: usize, n: usize| {
        let first = (centre - reach).floor().max(lo as f32);
        let last = (centre + reach).ceil().min((lo + n) as f32);
        (first + 0.5, (last - first).max(0.0) as usize)
    };
    let ((ox, cols), (oy, rows)) = (span(centre.x, x0, width), span(centre.y, y0, height));
    (Vec2::new(ox, oy), cols, rows)
}

/// How many visibility samples the grids of the highlights scattered together hold at most
/// (one highlight may hold more alone).
const GRID_SAMPLES: f32 = 8.0e6;

/// How far apart the visibility samples around a pixel may be for it to take them rather than
/// trace its own rays.
const AGREE: f32 = 1.0 / 64.0;

/// Offsets within a pixel of the four rays a pixel at a shadow's edge traces, and, paired with
/// them in turn, of the points of the highlight's own pixel they leave from: the ray
/// visibility averaged over both pixels, as `reference`'s views average it.
const EDGE_RAYS: [(Vec2, Vec2); 4] = [
    (Vec2::new(-0.25, -0.25), Vec2::new(0.25, -0.25)),
    (Vec2::new(0.25, -0.25), Vec2::new(0.25, 0.25)),
    (Vec2::new(0.25, 0.25), Vec2::new(-0.25, 0.25)),
    (Vec2::new(-0.25, 0.25), Vec2::new(-0.25, -0.25)),
];

/// How far apart, in output pixels, a highlight of CoC radius `c` samples its rays'
/// visibility before tracing the pixels between samples that differ: every pixel up to a
/// radius of 16, then at least 16 samples across the footprint. (A shadow narrower than the
/// stride can fall between samples that agree and be missed: a near object's shadow is its
/// width scaled by `C / (C - C_near)`, so such an object is thinner than a few pixels.)
fn stride_px(c: f32) -> f32 {
    (c.abs() / 8.0).floor().max(1.0)
}

/// The highlights scattered with their rays' visibility through `lists` (made with `lens`,
/// `scale` list pixels to an output pixel), over the output region `(x0, y0, width, height)`
/// (in output pixels of the lists' grid): their footprints in `shape`, each weighed to sum to
/// its list pixel's share of an output pixel.
pub fn scatter(
    highlights: &[Highlight],
    lists: &FragmentLists,
    lens: &ThinLens,
    shape: &Shape,
    scale: f32,
    region: (usize, usize, usize, usize),
) -> ColorImage {
    let (x0, y0, width, height) = region;
    let mut data = vec![[0.0f32; 4]; width * height];
    if highlights.is_empty() || width == 0 {
        return ColorImage::from_vec(width, height, data).expect("sizes agree by construction");
    }
    let farthest = highlights
        .iter()
        .map(|h| h.coc_px)
        .fold(f32::NEG_INFINITY, f32::max);
    let cocs = Cocs::new(lists, lens, farthest);
    // In output pixels: each highlight's centre, signed radius, reach and weight, and its
    // rays' visibility over the part of its footprint in the region.
    let soft = 1.0;
    // A few at a time, so that their visibility grids stay within some tens of megabytes
    // however wide the blur.
    let mut rest = highlights;
    while !rest.is_empty() {
        let mut area = 0.0f32;
        let n = rest
            .iter()
            .take_while(|h| {
                let side = 2.0 * (h.coc_px / scale).abs() * shape.stretch() + 4.0;
                area += side * side;
                area <= GRID_SAMPLES
            })
            .count()
            .max(1);
        let (chunk, tail) = rest.split_at(n);
        rest = tail;
        let drawn: Vec<(Vec2, f32, f32, f32, Seen)> = chunk
            .par_iter()
            .map(|h| {
                let (centre, c) = (h.centre / scale, h.coc_px / scale);
                let reach = c.abs() * shape.stretch() + soft;
                let seen = if cocs.clear(h.centre, h.coc_px, reach / c.abs()) {
                    Seen::clear()
                } else {
                    Seen::new(centre, c, reach, region, |p| {
                        // The lens point (in the unit aperture, as the footprint maps it) and
                        // the ray's visibility, in the lists' pixels.
                        visibility(lists, &cocs, h.centre, h.coc_px, (p - centre) / c)
                    })
                };
                (centre, c, reach, shape.norm(centre, c, soft), seen)
            })
            .collect();
        data.par_chunks_mut(width)
            .enumerate()
            .for_each(|(row, out)| {
                let y = (row + y0) as f32 + 0.5;
                for (h, (centre, c, reach, norm, seen)) in chunk.iter().zip(&drawn) {
                    if (y - centre.y).abs() > *reach {
                        continue;
                    }
                    let first = (centre.x - reach).floor().max(x0 as f32) as usize;
                    let last = ((centre.x + reach).ceil().max(0.0) as usize).min(x0 + width);
                    for x in first..last {
                        let p = Vec2::new(x as f32 + 0.5, y);
                        let cover = shape.coverage(p - *centre, *c, soft);
                        if cover <= 0.0 {
                            continue;
                        }
                        let seen = seen.at(p).unwrap_or_else(|| {
                            EDGE_RAYS
                                .iter()
                                .map(|&(dp, dl)| {
                                    let from = *centre + dl / scale;
                                    visibility(
                                        lists,
                                        &cocs,
                                        from * scale,
                                        h.coc_px,
                                        (p + dp - from) / *c,
                                    )
                                })
                                .sum::<f32>()
                                / EDGE_RAYS.len() as f32
                        });
                        // A list pixel is `1 / scale^2` of an output pixel.
                        let wt = cover * norm * seen / (scale * scale);
                        for (o, k) in out[x - x0].iter_mut().zip(h.color) {
                            *o += wt * k;
                        }
                    }
                }
            });
    }
    ColorImage::from_vec(width, height, data).expect("sizes agree by construction")
}

/// Adds `b` into `a` (the same size), colour only.
pub fn add_into(a: &mut ColorImage, b: &ColorImage) {
    for (p, q) in a.pixels_mut().iter_mut().zip(b.pixels()) {
        for k in 0..3 {
            p[k] += q[k];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lens::Camera;
    use glam::Vec3;

    #[test]
    fn thresholds_parse_and_are_checked() {
        assert_eq!(parse_threshold("off").unwrap(), None);
        assert_eq!(parse_threshold(" OFF ").unwrap(), None);
        assert_eq!(parse_threshold("2.5").unwrap(), Some(2.5));
        for bad in ["0", "-1", "inf", "NaN", "bright", ""] {
            let e = parse_threshold(bad).unwrap_err().to_string();
            assert!(
                e.contains("highlight-rays") && e.contains("off"),
                "{bad}: {e}"
            );
        }
    }

    /// Lists of 64x64 pixels, each holding a wall at CoC +12 px (behind every highlight here),
    /// with an opaque vertical strip at CoC -20 over columns 40-43, a half-covering one at
    /// CoC -5 over columns 20-21, and an opaque one at CoC +9.5 over column 32.
    fn strips() -> (FragmentLists, ThinLens) {
        let lens = Camera::look_at(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y)
            .thin_lens()
            .unwrap();
        let z = |c: f32| lens.depth_for_coc_px(c);
        let (w, h) = (64, 64);
        let pixels: Vec<Vec<(f32, crate::image::Rgba)>> = (0..w * h)
            .map(|i| {
                let x = i % w;
                let mut f = vec![(z(12.0), [0.1, 0.1, 0.1, 1.0])];
                if (40..44).contains(&x) {
                    f.push((z(-20.0), [0.0, 0.0, 0.0, 1.0]));
                }
                if (20..22).contains(&x) {
                    f.push((z(-5.0), [0.0, 0.0, 0.0, 0.5]));
                }
                if x == 32 {
                    // The highlight's own fitting, half a pixel of CoC in front of it.
                    f.push((z(9.5), [0.0, 0.0, 0.0, 1.0]));
                }
                f
            })
            .collect();
        (FragmentLists::from_pixels(w, h, 4, &pixels), lens)
    }

    #[test]
    fn a_ray_keeps_what_the_strips_it_passes_leave() {
        // A highlight at CoC +10 at (32.5, 32.5): its ray through lens point u is over
        // 32.5 + (10 - c) u at CoC c, so it passes the opaque strip (c = -20, t = 30) where
        // u.x is in [0.25, 0.383) and the half one (c = -5, t = 15) where u.x is in
        // [-0.833, -0.7). The wall, behind the highlight, never counts, nor the strip half a
        // pixel of CoC in front of it over its own column (its own surface).
        let (lists, lens) = strips();
        let cocs = Cocs::new(&lists, &lens, 10.0);
        let x0 = Vec2::new(32.5, 32.5);
        let mut checked = [0; 3];
        for k in 0..=400 {
            let ux = -1.0 + k as f32 / 200.0;
            for uy in [-0.3f32, 0.0, 0.2] {
                let u = Vec2::new(ux, uy);
                let v = visibility(&lists, &cocs, x0, 10.0, u);
                let near = |a: f32, b: f32| (ux - a).abs() < 0.01 || (ux - b).abs() < 0.01;
                let want = if near(0.25, 0.3833) || near(-0.8333, -0.7) {
                    continue;
                } else if (0.25..0.3833).contains(&ux) {
                    checked[0] += 1;
                    0.0
                } else if (-0.8333..-0.7).contains(&ux) {
                    checked[1] += 1;
                    0.5
                } else {
                    checked[2] += 1;
                    1.0
                };
                assert!((v - want).abs() < 1e-3, "u {u}: {v}, want {want}");
            }
        }
        assert!(checked.iter().all(|&n| n > 20), "{checked:?}");
    }

    #[test]
    fn a_highlight_with_nothing_nearer_in_reach_is_seen_whole() {
        // In the strips' lists a highlight at CoC +10 at (32.5, 32.5) has the opaque strip at
        // CoC -20 within reach of its rays (30 px of CoC away, 7.5 px to the side).
        let (lists, lens) = strips();
        let cocs = Cocs::new(&lists, &lens, 10.0);
        assert!(!cocs.clear(Vec2::new(32.5, 32.5), 10.0, 1.0));
        // Rays of lens points within 0.1 of the centre stay within 3 px of the highlight: no
        // strip there but its own fitting (not counted) and the wall behind it.
        assert!(cocs.clear(Vec2::new(32.5, 32.5), 10.0, 0.1));
        for k in 0..50 {
            let u = Vec2::new((k as f32 * 0.37).cos(), (k as f32 * 0.37).sin()) * 0.09;
            let v = visibility(&lists, &cocs, Vec2::new(32.5, 32.5), 10.0, u);
            assert_eq!(v, 1.0, "u {u}");
        }
        // A strip within reach of some of them: not clear.
        assert!(!cocs.clear(Vec2::new(16.5, 32.5), 10.0, 0.2));
    }

    #[test]
    fn taking_highlights_keeps_their_coverage_and_order() {
        // Only fragments brighter than the threshold (over their coverage) and at least a
        // pixel out of focus are taken; they stay in the lists, black, with their coverage.
        let lens = Camera::look_at(Vec3::ZERO, Vec3::NEG_Z, Vec3::Y)
            .thin_lens()
            .unwrap();
        let z = |c: f32| lens.depth_for_coc_px(c);
        let pixels = vec![
            vec![(z(8.0), [3.0, 3.0, 3.0, 0.5])],
            vec![(z(8.0), [0.375, 0.375, 0.375, 0.5])],
            vec![(z(0.2), [9.0, 9.0, 9.0, 1.0])],
            vec![
                (z(-3.0), [0.2, 0.2, 0.2, 1.0]),
                (z(6.0), [5.0, 1.0, 1.0, 1.0]),
            ],
        ];
        let mut lists = FragmentLists::from_pixels(2, 2, 4, &pixels);
        let before = lists.depths().to_vec();
        let taken = take(&mut lists, &lens, 1.0, 1.0, f32::INFINITY);
        assert_eq!(taken.len(), 2, "{taken:?}");
        assert_eq!(taken[0].centre, Vec2::new(0.5, 0.5));
        assert_eq!(taken[1].centre, Vec2::new(1.5, 1.5));
        assert!((taken[1].coc_px - 6.0).abs() < 1e-3, "{}", taken[1].coc_px);
        assert_eq!(lists.depths(), &before[..]);
        let colors: Vec<_> = lists.colors().iter().map(from_half).collect();
        assert_eq!(colors[0], [0.0, 0.0, 0.0, 0.5]);
        assert_eq!(colors[1], [0.375, 0.375, 0.375, 0.5]);
        assert_eq!(colors[2], [9.0, 9.0, 9.0, 1.0]);
        assert_eq!(colors[4], [0.0, 0.0, 0.0, 1.0]);
        // Clamped to the largest CoC asked for.
        let mut lists = FragmentLists::from_pixels(2, 2, 4, &pixels);
        let taken = take(&mut lists, &lens, 1.0, 1.0, 4.0);
        assert!(taken.iter().all(|h| h.coc_px.abs() <= 4.0), "{taken:?}");
    }
}
