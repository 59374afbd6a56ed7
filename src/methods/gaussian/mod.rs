//! `gaussian`: a separable Gaussian gather whose width follows each pixel's CoC, the baseline
//! McGraw compares against ("the method of Zhou et al.", Zhou, Chen & Pullen, "Accurate depth
//! of field simulation in real time", Computer Graphics Forum 26(1), 2007; McGraw Table 1:
//! "a separable Gaussian kernel results in a much softer blur").
//!
//! # Passes, in order (each timed as `gaussian/<pass>`)
//! 1. `coc` ([`super::coc_map::coc`]): reads depth; writes the signed CoC radius in pixels,
//!    clamped to `max_coc_px`.
//! 2. `horizontal` ([`horizontal`]): reads colour and CoC; writes the row-blurred colour. Pixel
//!    `p` gathers `q = p - d`, `|d| <= ceil(truncate_sigmas * sigma_p)`, with weight
//!    `exp(-d^2 / (2 sigma_p^2))` times the depth-rejection term of
//!    [`super::poisson::rejection_weight`] (a sharper sample in front of `p` does not leak into
//!    it), divided by the sum of weights. `sigma_p = sigma_per_coc * |C_p|`.
//! 3. `vertical` ([`vertical`]): the same along columns on the row-blurred colour, with the
//!    CoC of the original pixels.
//!
//! The default `sigma_per_coc` = 1/2 gives the Gaussian the per-axis variance of a uniform disc
//! of radius `|C|` (`R^2 / 4`), so the blur has the same spread as the bokeh, only soft.
//! Radii are quantised to 1/4 px as in `lowrank`; pixels with a radius of at most 1/2 px are
//! copied unchanged. Rows (and column chunks of the vertical pass) are independent, so the
//! output does not depend on the thread count. [`naive`] is the per-pixel twin.
//!
//! [`gpu`] runs the same three passes as WGSL compute shaders, under the same names.

pub mod gpu;

use rayon::prelude::*;

use super::coc_map;
use super::coc_map::{level_count, level_of, level_radius_px};
use super::poisson::rejection_weight;
use super::MethodOutput;
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::lens::ThinLens;
use crate::timing::Timings;
use crate::{Error, Result};

/// Width in pixels of the column chunks of the vertical pass.
pub const CHUNK_PX: usize = 64;

/// Settings of the Gaussian gather.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussianSettings {
    /// Standard deviation per pixel of CoC radius (> 0, at most 4). Default 0.5: the variance of
    /// a disc of radius `|C|`.
    pub sigma_per_coc: f32,
    /// The Gaussian is cut at this many standard deviations (0.5 to 6). Default 3.
    pub truncate_sigmas: f32,
    /// Largest CoC radius in pixels; larger blurs are clamped (0 to 512). Default 64.
    pub max_coc_px: f32,
}

impl Default for GaussianSettings {
    fn default() -> Self {
        Self {
            sigma_per_coc: 0.5,
            truncate_sigmas: 3.0,
            max_coc_px: 64.0,
        }
    }
}

impl GaussianSettings {
    /// Checks every field (see their documentation).
    pub fn validate(&self) -> Result<()> {
        coc_map::check_max_coc(self.max_coc_px)?;
        if !(self.sigma_per_coc > 0.0 && self.sigma_per_coc <= 4.0) {
            return Err(Error::invalid(
                "sigma per CoC",
                format!("{}: expected a value in (0, 4]", self.sigma_per_coc),
            ));
        }
        if !(self.truncate_sigmas >= 0.5 && self.truncate_sigmas <= 6.0) {
            return Err(Error::invalid(
                "Gaussian truncation",
                format!("{} sigmas: expected 0.5 to 6", self.truncate_sigmas),
            ));
        }
        Ok(())
    }
}

/// Gaussian taps of every radius level, zero-padded to the largest.
#[derive(Clone, Debug)]
pub struct GaussTable {
    pub(crate) levels: usize,
    nmax: usize,
    pub(crate) stride: usize,
    /// Taps on each side of each level.
    pub(crate) half: Vec<usize>,
    /// `[level * stride + |d|]`.
    pub(crate) weights: Vec<f32>,
}

impl GaussTable {
    /// Tabulates the taps for radii up to `max_radius_px`.
    pub fn new(settings: &GaussianSettings, max_radius_px: f32) -> Self {
        let levels = level_count(max_radius_px);
        let half: Vec<usize> = (0..levels)
            .map(|l| half_width(settings, level_radius_px(l)))
            .collect();
        let nmax = half.iter().copied().max().unwrap_or(0);
        let stride = nmax + 1;
        let mut weights = vec![0.0f32; levels * stride];
        for (l, &n) in half.iter().enumerate() {
            let sigma = settings.sigma_per_coc * level_radius_px(l);
            for d in 0..=n {
                weights[l * stride + d] = gauss(d as f32, sigma);
            }
        }
        Self {
            levels,
            nmax,
            stride,
            half,
            weights,
        }
    }
}

/// Taps on each side for radius `radius_px`: 0 at most 1/2 px, else `ceil(truncate * sigma)`.
fn half_width(settings: &GaussianSettings, radius_px: f32) -> usize {
    if radius_px <= 0.5 {
        0
    } else {
        (settings.truncate_sigmas * settings.sigma_per_coc * radius_px)
            .ceil()
            .max(1.0) as usize
    }
}

#[inline]
fn gauss(d: f32, sigma: f32) -> f32 {
    (-d * d / (2.0 * sigma * sigma)).exp()
}

/// Renders depth of field from a pinhole colour image and its view-axis depth in metres.
pub fn render(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &GaussianSettings,
) -> Result<MethodOutput> {
    settings.validate()?;
    coc_map::check_frame(color, depth, lens)?;
    let mut timings = Timings::default();
    let coc_px = timings.time("gaussian/coc", || {
        coc_map::coc(depth, lens, settings.max_coc_px)
    })?;
    let max_radius = coc_px.pixels().iter().fold(0.0f32, |m, c| m.max(c.abs()));
    let table = GaussTable::new(settings, max_radius);
    let rows = timings.time("gaussian/horizontal", || horizontal(color, &coc_px, &table));
    let image = timings.time("gaussian/vertical", || {
        vertical(color, &rows, &coc_px, &table)
    });
    Ok(MethodOutput {
        image,
        depth: None,
        timings,
        memory_bytes: None,
    })
}

/// Pass `horizontal`: the row-blurred colour (see the module documentation).
pub fn horizontal(color: &ColorImage, coc_px: &GrayImage, table: &GaussTable) -> ColorImage {
    rows_with(color, color, coc_px, table, horizontal_row)
}

/// [`horizontal`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn horizontal_baseline(
    color: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
) -> ColorImage {
    rows_with(color, color, coc_px, table, horizontal_row_inner)
}

/// `color` with each row `y` written by `row_fn(y, row, source, coc_px, table)`, rows in
/// parallel: the shape of both passes (`source` is `color` for [`horizontal`], the rows it
/// wrote for [`vertical`]).
fn rows_with(
    color: &ColorImage,
    source: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
    row_fn: impl Fn(usize, &mut [Rgba], &ColorImage, &GrayImage, &GaussTable) + Sync,
) -> ColorImage {
    let w = color.width();
    let mut out = color.clone();
    if w == 0 || color.height() == 0 {
        return out;
    }
    out.pixels_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| row_fn(y, row, source, coc_px, table));
    out
}

/// One row of [`horizontal`]. Compiled for several instruction sets and chosen at run time
/// ([`multiversion`]); the same arithmetic in every version (no fused multiply-add), so the
/// same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn horizontal_row(
    y: usize,
    row: &mut [Rgba],
    color: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
) {
    horizontal_row_inner(y, row, color, coc_px, table);
}

#[inline(always)]
fn horizontal_row_inner(
    y: usize,
    row: &mut [Rgba],
    color: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
) {
    let w = color.width();
    let src = color.row(y);
    let cr = coc_px.row(y);
    for (x, o) in row.iter_mut().enumerate() {
        let c = cr[x];
        let level = level_of(c, table.levels);
        let n = table.half[level];
        if n == 0 {
            continue;
        }
        let g = &table.weights[level * table.stride..];
        let lo = x.saturating_sub(n);
        let hi = (x + n).min(w - 1);
        let mut acc = [0.0f32; 4];
        let mut total = 0.0f32;
        // Taps beyond the borders repeat the edge pixel.
        let mut add = |q: usize, d: usize, times: f32| {
            let wt = times * g[d] * rejection_weight(c, cr[q]);
            let p = src[q];
            for k in 0..4 {
                acc[k] += wt * p[k];
            }
            total += wt;
        };
        for q in lo..=hi {
            add(q, q.abs_diff(x), 1.0);
        }
        for d in x + 1..=n {
            add(0, d, 1.0);
        }
        for d in (w - 1 - x) + 1..=n {
            add(w - 1, d, 1.0);
        }
        *o = acc.map(|a| a / total);
    }
}

/// Pass `vertical`: the column blur of `rows` (the output of [`horizontal`]), copying `color`
/// where the radius is at most 1/2 px.
pub fn vertical(
    color: &ColorImage,
    rows: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
) -> ColorImage {
    rows_with(color, rows, coc_px, table, vertical_row)
}

/// [`vertical`] built for the portable baseline only: the twin the dispatched versions are
/// tested against, bit for bit.
pub fn vertical_baseline(
    color: &ColorImage,
    rows: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
) -> ColorImage {
    rows_with(color, rows, coc_px, table, vertical_row_inner)
}

/// One row of [`vertical`], multiversioned as [`horizontal_row`].
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn vertical_row(
    y: usize,
    row: &mut [Rgba],
    rows: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
) {
    vertical_row_inner(y, row, rows, coc_px, table);
}

#[inline(always)]
fn vertical_row_inner(
    y: usize,
    row: &mut [Rgba],
    rows: &ColorImage,
    coc_px: &GrayImage,
    table: &GaussTable,
) {
    let (w, h) = (rows.width(), rows.height());
    let nmax = table.nmax as isize;
    let cr = coc_px.row(y);
    let mut acc = [[0.0f32; 4]; CHUNK_PX];
    let mut total = [0.0f32; CHUNK_PX];
    let mut bases = [0usize; CHUNK_PX];
    let mut halves = [0usize; CHUNK_PX];
    for x0 in (0..w).step_by(CHUNK_PX) {
        let len = CHUNK_PX.min(w - x0);
        for t in 0..len {
            let level = level_of(cr[x0 + t], table.levels);
            bases[t] = level * table.stride;
            halves[t] = table.half[level];
        }
        let n = halves[..len].iter().copied().max().unwrap_or(0) as isize;
        if n == 0 {
            continue;
        }
        acc[..len].fill([0.0; 4]);
        total[..len].fill(0.0);
        for d in -n.min(nmax)..=n.min(nmax) {
            let yy = (y as isize - d).clamp(0, h as isize - 1) as usize;
            let src = &rows.row(yy)[x0..x0 + len];
            let cq = &coc_px.row(yy)[x0..x0 + len];
            let ad = d.unsigned_abs();
            for t in 0..len {
                if ad > halves[t] {
                    continue;
                }
                let wt = table.weights[bases[t] + ad] * rejection_weight(cr[x0 + t], cq[t]);
                for k in 0..4 {
                    acc[t][k] += wt * src[t][k];
                }
                total[t] += wt;
            }
        }
        for t in 0..len {
            if halves[t] > 0 {
                row[x0 + t] = acc[t].map(|a| a / total[t]);
            }
        }
    }
}

/// Per-pixel twin of [`horizontal`] then [`vertical`], with the Gaussian evaluated directly
/// and clamped coordinates, in f64.
pub fn naive(color: &ColorImage, coc_px: &GrayImage, settings: &GaussianSettings) -> ColorImage {
    let (w, h) = (color.width(), color.height());
    let max_radius = coc_px.pixels().iter().fold(0.0f32, |m, c| m.max(c.abs()));
    let levels = level_count(max_radius);
    let params = |c: f32| {
        let r = level_radius_px(level_of(c, levels));
        (
            half_width(settings, r) as i64,
            (settings.sigma_per_coc * r) as f64,
        )
    };
    let g = |d: i64, s: f64| (-(d * d) as f64 / (2.0 * s * s)).exp();
    let blur = |src: &dyn Fn(usize, usize) -> Rgba, horizontal: bool| -> Vec<Rgba> {
        let mut out = vec![[0.0f32; 4]; w * h];
        for y in 0..h {
            for x in 0..w {
                let c = coc_px.get(x, y);
                let (n, s) = params(c);
                if n == 0 {
                    out[y * w + x] = color.get(x, y);
                    continue;
                }
                let mut acc = [0.0f64; 4];
                let mut total = 0.0f64;
                for d in -n..=n {
                    let (qx, qy) = if horizontal {
                        ((x as i64 - d).clamp(0, w as i64 - 1) as usize, y)
                    } else {
                        (x, (y as i64 - d).clamp(0, h as i64 - 1) as usize)
                    };
                    let wt = g(d, s) * rejection_weight(c, coc_px.get(qx, qy)) as f64;
                    let p = src(qx, qy);
                    for k in 0..4 {
                        acc[k] += wt * p[k] as f64;
                    }
                    total += wt;
                }
                out[y * w + x] = acc.map(|a| (a / total) as f32);
            }
        }
        out
    };
    let rows = blur(&|x, y| color.get(x, y), true);
    let cols = blur(&|x, y| rows[y * w + x], false);
    ColorImage::from_vec(w, h, cols).unwrap_or_else(|_| color.clone())
}
