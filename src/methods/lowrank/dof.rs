//! The spatially varying low-rank filter of depth of field and tilt-shift (McGraw section 4,
//! "Tilt-shift postprocessing" and "Depth-of-field", fig. 15).
//!
//! The paper filters each pixel with the low-rank kernel scaled to the pixel's CoC diameter, as a
//! horizontal then a vertical 1D pass (accepting the artifacts of a spatially varying separable
//! filter where the CoC changes slowly), and flags pixels near depth discontinuities for a full
//! 2D solution.
//!
//! # How a kernel is scaled per pixel
//! One base kernel is decomposed ([`super::decompose`]); its scaled singular vectors are read as
//! piecewise-constant functions on the unit aperture [-1, 1] (base pixel `k` of `N` covers
//! `[-1 + 2k/N, -1 + 2(k+1)/N]`). For a CoC radius `R`, the weight of the tap at offset `d`
//! pixels is the integral of that function over the tap's footprint `[d - 1/2, d + 1/2] / R`.
//! The product of the horizontal and vertical taps is then exactly the rank-r approximation of
//! the base kernel box-filtered onto the pixels of a kernel of radius `R` (diameter `2R`, as
//! `reference`), so the bokeh edge stays anti-aliased at every size. Radii are quantised to
//! 1/[`LEVELS_PER_PX`] pixel, and the taps of every level are tabulated once per frame
//! ([`KernelBank`]). A pixel with a negative CoC (in front of the focal plane) uses the taps
//! mirrored, `w(-d)`: its bokeh is the aperture turned 180 degrees.
//!
//! The horizontal taps are divided by the sum of the rank-r kernel, `sum_i (sum u'_i)(sum
//! v'_i)`, so that every pixel's rank-r kernel sums to exactly 1 whatever its radius: a
//! constant image stays constant through a spatially varying filter.
//!
//! # Gather, per receiving pixel
//! Both passes use the kernel of the pixel being written: `U_i(x, y) = sum_d h_i(d; C(x, y))
//! img(x - d, y)`, then `out(x, y) = sum_i sum_d v_i(d; C(x, y)) U_i(x, y - d)`, with
//! clamp-to-edge borders. Where the CoC is constant this is exactly the convolution with the
//! rank-r kernel of that radius. Pixels whose kernel lies inside the pixel itself (radius at
//! most 1/2 px) are copied unchanged.
//!
//! # Depth-discontinuity mask (fig. 15)
//! [`edges`] marks the pixels whose CoC differs from a 4-neighbour's by more than a threshold
//! (finite differences of the CoC, which is an affine function of inverse depth, so one
//! threshold in pixels suits every scene). The edge image is filtered with the colour, as a
//! fifth channel of the same passes, so each pixel learns how much of its own kernel lies on
//! depth edges; thresholding that gives the mask.
//!
//! # Cache use
//! Neighbouring pixels mostly share a kernel (a surface at one depth has one CoC level), so
//! both passes split each row into runs of pixels with the same kernel and apply each tap to a
//! whole run at once, `acc[a..b] += w * src[..]` over contiguous floats, which the compiler
//! vectorises. The horizontal pass reads a clamp-padded copy of the row; the vertical pass reads,
//! for each tap, the same columns of an intermediate row, so it needs no transpose, and walks
//! blocks of rows in column strips as [`super::filter`] does, so its source rows stay in cache.
//! [`naive`] is the straightforward per-pixel twin, with its own tap integration.

use rayon::prelude::*;

use super::filter::{
    filter_rows, filter_span, filter_span_add, filter_span_ranks, filter_span_ranks_folded,
    is_opaque, pad_row, Channels, Schedule, TapPair, BAND_ROWS, MAX_RANKS, MAX_ROWS, ROW_BLOCK,
    STRIP_PX,
};
use super::svd::LowRank;
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::timing::Timings;
use crate::{Error, Result};

/// Largest tap table of a [`KernelBank`], in floats (each of the two tables: 256 MB).
pub const MAX_BANK_FLOATS: usize = 1 << 26;

pub use crate::methods::coc_map::{
    half_taps, level_count, level_of, level_radius_px, LEVELS_PER_PX,
};

/// The tap tables of every radius level for one decomposed kernel at one rank.
#[derive(Clone, Debug)]
pub struct KernelBank {
    pub(crate) rank: usize,
    pub(crate) levels: usize,
    pub(crate) nmax: usize,
    pub(crate) stride: usize,
    /// Taps on each side of the centre per table key (`sign * levels + level`): horizontal
    /// and vertical (they differ when the aperture is squeezed, [`KernelBank::with_squeeze`]).
    pub(crate) half_h: Vec<usize>,
    pub(crate) half_v: Vec<usize>,
    /// Per rank, whether its horizontal taps are even (1) or odd (-1) about the centre, exactly,
    /// or neither (0): see [`parity`].
    h_parity: Vec<i8>,
    /// `[(sign * levels + level) * rank + i] * stride + j`, the weight of offset `nmax - j`
    /// (far field, sign 0) or `j - nmax` (near field, sign 1), 0 beyond the level's taps.
    pub(crate) horizontal: Vec<f32>,
    pub(crate) vertical: Vec<f32>,
}

/// Integral of the piecewise-constant function `base` on [-1, 1] from -1 to `t`, by the
/// cumulative sums `cum` (`cum[k]` = sum of the first `k` entries).
fn integral_to(base: &[f64], cum: &[f64], t: f64) -> f64 {
    let n = base.len() as f64;
    let tau = ((t + 1.0) * 0.5 * n).clamp(0.0, n);
    let k = tau.floor() as usize;
    if k >= base.len() {
        cum[base.len()]
    } else {
        cum[k] + (tau - k as f64) * base[k]
    }
}

/// Far-field taps `w(d)`, `d = -n..=n`, of `base` scaled to radius `radius_px`.
fn far_taps(base: &[f64], radius_px: f64, n: usize) -> Vec<f64> {
    let mut cum = vec![0.0; base.len() + 1];
    for (k, &b) in base.iter().enumerate() {
        cum[k + 1] = cum[k] + b;
    }
    if radius_px <= 0.0 {
        return vec![cum[base.len()]];
    }
    (-(n as i64)..=n as i64)
        .map(|d| {
            let t0 = (d as f64 - 0.5) / radius_px;
            let t1 = (d as f64 + 0.5) / radius_px;
            integral_to(base, &cum, t1) - integral_to(base, &cum, t0)
        })
        .collect()
}

/// Largest difference between a singular vector and its mirror image (or its negated mirror
/// image), relative to its largest entry, that counts as an even (or odd) vector: a kernel
/// symmetric about an axis has singular vectors that are exactly even or odd, up to the
/// decomposition's rounding (about 1e-12) and the rasterized aperture's (its samples lie
/// symmetrically, so none); an aperture that is not symmetric differs by tenths.
const PARITY_TOLERANCE: f64 = 1e-6;

/// Whether `v` is even (1) or odd (-1) about its middle entry within [`PARITY_TOLERANCE`], and
/// then `v` made exactly so (the mean of `v` and its mirror image, or of `v` and its negated
/// mirror image); 0 and `v` unchanged otherwise.
fn parity(v: &[f64]) -> (i8, Vec<f64>) {
    let scale = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let mirrored = |s: f64| {
        v.iter()
            .zip(v.iter().rev())
            .all(|(a, b)| (a - s * b).abs() <= PARITY_TOLERANCE * scale)
    };
    for s in [1i8, -1] {
        if scale > 0.0 && mirrored(f64::from(s)) {
            let sf = f64::from(s);
            let made = v
                .iter()
                .zip(v.iter().rev())
                .map(|(a, b)| 0.5 * (a + sf * b))
                .collect();
            return (s, made);
        }
    }
    (0, v.to_vec())
}

/// Makes `taps` (offsets `-n..=n`) exactly even (`s` = 1) or odd (`s` = -1) by copying the
/// positive offsets' weights to the negative ones, as the integrals of an even or odd vector
/// are up to rounding.
fn mirror_taps(taps: &mut [f64], s: i8) {
    let n = taps.len() / 2;
    for d in 1..=n {
        taps[n - d] = f64::from(s) * taps[n + d];
    }
    if s < 0 {
        taps[n] = 0.0;
    }
}

/// The sum of the rank-`rank` kernel, checked to be usable as a divisor.
fn rank_sum(lr: &LowRank, rank: usize) -> Result<f64> {
    let sum = lr.approximation_sum(rank);
    if sum.abs() < 1e-6 {
        return Err(Error::invalid(
            "rank",
            format!("the rank-{rank} kernel sums to {sum}: it cannot be normalised"),
        ));
    }
    Ok(sum)
}

impl KernelBank {
    /// Tabulates the taps of `lr` at rank `rank` (1 to [`LowRank::len`]) for CoC radii up to
    /// `max_radius_px` pixels.
    pub fn new(lr: &LowRank, rank: usize, max_radius_px: f32) -> Result<Self> {
        Self::with_squeeze(lr, rank, max_radius_px, 1.0, 1.0)
    }

    /// [`KernelBank::new`] for an anamorphic aperture: the horizontal taps of a CoC radius `R`
    /// are the kernel at radius `R sx`, the vertical ones at `R sy`, so the rank-r kernel is
    /// the aperture stretched by `(sx, sy)` (each pass's taps still integrate to its singular
    /// vector's sum, so the normalisation is unchanged). `(1, 1)` gives [`KernelBank::new`]'s
    /// tables bit for bit.
    pub fn with_squeeze(
        lr: &LowRank,
        rank: usize,
        max_radius_px: f32,
        sx: f32,
        sy: f32,
    ) -> Result<Self> {
        if rank == 0 || rank > lr.len() {
            return Err(Error::invalid(
                "rank",
                format!("{rank}: expected 1 to {} for this kernel", lr.len()),
            ));
        }
        if !(max_radius_px.is_finite() && max_radius_px >= 0.0) {
            return Err(Error::invalid(
                "max CoC",
                format!("{max_radius_px} px: expected a finite radius >= 0"),
            ));
        }
        let norm = rank_sum(lr, rank)?;
        let levels = level_count(max_radius_px);
        let half_h: Vec<usize> = (0..levels)
            .map(|l| half_taps(level_radius_px(l) * sx))
            .collect();
        let half_v: Vec<usize> = (0..levels)
            .map(|l| half_taps(level_radius_px(l) * sy))
            .collect();
        let nmax = half_h[levels - 1].max(half_v[levels - 1]);
        let stride = 2 * nmax + 1;
        let floats = 2 * levels * rank * stride;
        if floats > MAX_BANK_FLOATS {
            return Err(Error::invalid(
                "rank",
                format!(
                    "rank {rank} with CoC radii up to {max_radius_px} px needs {} MB of tap tables: \
                     lower the rank or the max CoC",
                    2 * floats * 4 / (1 << 20)
                ),
            ));
        }
        let mut horizontal = vec![0.0f32; floats];
        let mut vertical = vec![0.0f32; floats];
        // Tap `t` of a table of `n` taps a side is offset d = t - n; far field: j = nmax - d;
        // near field: j = nmax + d.
        let put = |table: &mut [f32], row: usize, sign: usize, n: usize, taps: &[f64], k: f64| {
            for (t, &w) in taps.iter().enumerate() {
                let d = t as i64 - n as i64;
                let j = if sign == 0 {
                    nmax as i64 - d
                } else {
                    nmax as i64 + d
                } as usize;
                table[row + j] = (w / k) as f32;
            }
        };
        // The horizontal vectors, each made exactly even or odd where it is so within rounding,
        // so that the horizontal pass can fold its taps in pairs
        // ([`super::filter::filter_span_ranks_folded`]).
        let (h_parity, h_vectors): (Vec<i8>, Vec<Vec<f64>>) = (0..rank)
            .map_while(|i| lr.horizontal(i).map(parity))
            .unzip();
        // The taps of every level and rank, levels in parallel: (level, rank, horizontal,
        // vertical).
        let taps: Vec<(usize, usize, Vec<f64>, Vec<f64>)> = (0..levels)
            .into_par_iter()
            .flat_map_iter(|level| {
                let radius = level_radius_px(level);
                let (nh, nv) = (half_h[level], half_v[level]);
                let (h_parity, h_vectors) = (&h_parity, &h_vectors);
                (0..rank).map_while(move |i| {
                    let (hv, vv) = (h_vectors.get(i)?, lr.vertical(i)?);
                    let mut h_taps = far_taps(hv, (radius * sx) as f64, nh);
                    if h_parity[i] != 0 {
                        mirror_taps(&mut h_taps, h_parity[i]);
                    }
                    let v_taps = far_taps(vv, (radius * sy) as f64, nv);
                    Some((level, i, h_taps, v_taps))
                })
            })
            .collect();
        for (level, i, h_taps, v_taps) in taps {
            let (nh, nv) = (half_h[level], half_v[level]);
            for sign in 0..2 {
                let row = ((sign * levels + level) * rank + i) * stride;
                put(&mut horizontal, row, sign, nh, &h_taps, norm);
                put(&mut vertical, row, sign, nv, &v_taps, 1.0);
            }
        }
        // Indexed by table key: the far field's levels, then the near field's.
        let (half_h, half_v) = (half_h.repeat(2), half_v.repeat(2));
        Ok(Self {
            rank,
            levels,
            nmax,
            stride,
            half_h,
            half_v,
            h_parity,
            horizontal,
            vertical,
        })
    }

    /// The rank the bank was built for.
    pub fn rank(&self) -> usize {
        self.rank
    }

    /// Number of radius levels.
    pub fn levels(&self) -> usize {
        self.levels
    }

    /// Taps on each side of the centre at the largest level.
    pub fn max_half_taps(&self) -> usize {
        self.nmax
    }

    /// Table key of a pixel with signed CoC `coc_px`: `sign * levels + level`.
    #[inline]
    pub fn key(&self, coc_px: f32) -> u32 {
        let level = level_of(coc_px, self.levels);
        (usize::from(coc_px < 0.0) * self.levels + level) as u32
    }

    /// [`KernelBank::key`] of each CoC of `coc_px` into `keys`, in a loop the compiler can
    /// vectorise: the level is `4 |C|` clamped to the last level first, then rounded half up
    /// (the same level as [`level_of`] for every float, NaN included: 0).
    pub fn keys_into(&self, coc_px: &[f32], keys: &mut [u32]) {
        let top = (self.levels - 1) as f32;
        let near = self.levels as u32;
        for (k, &c) in keys.iter_mut().zip(coc_px) {
            let v = c.abs() * LEVELS_PER_PX;
            let v = if v > top { top } else { v };
            // `v` is at most `top` (or NaN, which converts to 0), so the conversion to `i32`,
            // which vectorises where `u32`'s does not, is exact.
            let t = v as i32;
            let level = (t + i32::from(v - t as f32 >= 0.5)) as u32;
            *k = level + u32::from(c < 0.0) * near;
        }
    }

    /// Horizontal half taps of the pixel with table key `key`.
    #[inline]
    fn half_h_of(&self, key: u32) -> usize {
        self.half_h[key as usize]
    }

    /// Vertical half taps of the pixel with table key `key`.
    #[inline]
    fn half_v_of(&self, key: u32) -> usize {
        self.half_v[key as usize]
    }
}

/// Pass `edges`: 1 where the CoC differs from a 4-neighbour's by more than `threshold_px`
/// pixels, else 0.
pub fn edges(coc_px: &GrayImage, threshold_px: f32) -> GrayImage {
    let (w, h) = (coc_px.width(), coc_px.height());
    let mut out = GrayImage::new(w, h, 0.0);
    if w == 0 || h == 0 {
        return out;
    }
    let c = coc_px.pixels();
    // The largest of the absolute differences, in comparisons the compiler vectorises (the CoC
    // is finite: no NaN to order).
    let biggest = |a: f32, b: f32| if a > b { a } else { b };
    out.pixels_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            let here = &c[y * w..(y + 1) * w];
            // A missing neighbour is the pixel itself: a difference of 0.
            let above = &c[y.saturating_sub(1) * w..][..w];
            let below = &c[(y + 1).min(h - 1) * w..][..w];
            let vertical =
                |x: usize| biggest((here[x] - above[x]).abs(), (here[x] - below[x]).abs());
            for (x, e) in row.iter_mut().enumerate() {
                *e = vertical(x);
            }
            // Left and right neighbours, for the pixels that have them.
            if w > 1 {
                for (e, (&v, &l)) in row[1..].iter_mut().zip(here[1..].iter().zip(here)) {
                    *e = biggest(*e, (v - l).abs());
                }
                for (e, (&v, &r)) in row.iter_mut().zip(here.iter().zip(&here[1..])) {
                    *e = biggest(*e, (v - r).abs());
                }
            }
            for e in row.iter_mut() {
                *e = f32::from(u8::from(*e > threshold_px));
            }
        });
    out
}

/// The intermediate image `U_i` of one rank (colour, and the edge channel when there is an edge
/// image), reused from rank to rank, with each pixel's table key.
#[derive(Clone, Debug)]
pub struct Intermediate {
    width: usize,
    height: usize,
    keys: Vec<u32>,
    /// Channels per pixel of `colour`: 4 (RGBA) or 3 (colour only, for an opaque image).
    channels: usize,
    /// Flattened, `channels` floats per pixel.
    colour: Vec<f32>,
    edges: Vec<f32>,
}

impl Intermediate {
    /// Buffers for `color`'s size with `channels` (3 or 4) colour channels, and the table keys
    /// of `coc_px` in `bank`.
    pub fn new(coc_px: &GrayImage, bank: &KernelBank, with_edges: bool, channels: usize) -> Self {
        let (w, h) = (coc_px.width(), coc_px.height());
        let channels = if channels == 3 { 3 } else { 4 };
        Self {
            width: w,
            height: h,
            keys: coc_px.pixels().iter().map(|&c| bank.key(c)).collect(),
            channels,
            colour: vec![0.0; w * h * channels],
            edges: vec![0.0; if with_edges { w * h } else { 0 }],
        }
    }
}

/// Passes `horizontal` and `vertical` for every rank, then the final touch: pixels with no taps
/// beyond their own get `color` back exactly, and negative results of the low-rank kernel's
/// ringing are clamped to 0. Returns the image and, with an edge image, the filtered edge
/// image. `edge_image` and `coc_px` must have the size of `color`.
///
/// The passes run band by band ([`Schedule::Banded`], timed as `lowrank/separable`): each pixel
/// gets the same products summed in the same order as in fig. 2's schedule
/// ([`filter_with_schedule`] with [`Schedule::Fig2`]), so the two give the same image (bit for
/// bit but for the sign of a zero).
///
/// An opaque image ([`super::filter::is_opaque`]) is filtered in its three colour channels
/// only, a quarter less work: its colour is bit-identical to [`Channels::Rgba`]'s, and its
/// alpha is 1, the sum of every pixel's kernel (the RGBA path gets 1 up to rounding where the
/// CoC varies).
pub fn filter(
    color: &ColorImage,
    edge_image: Option<&GrayImage>,
    coc_px: &GrayImage,
    bank: &KernelBank,
    timings: &mut Timings,
) -> (ColorImage, Option<GrayImage>) {
    filter_channels(color, edge_image, coc_px, bank, Channels::Auto, timings)
}

/// [`filter`] with the choice of channels made by the caller.
pub fn filter_channels(
    color: &ColorImage,
    edge_image: Option<&GrayImage>,
    coc_px: &GrayImage,
    bank: &KernelBank,
    channels: Channels,
    timings: &mut Timings,
) -> (ColorImage, Option<GrayImage>) {
    let schedule = Schedule::Banded;
    filter_with_schedule(color, edge_image, coc_px, bank, channels, schedule, timings)
}

/// [`filter`] with the channels and the order of the passes chosen by the caller.
/// [`Schedule::Fig2`] runs fig. 2's order, timed as `lowrank/horizontal` and `lowrank/vertical`:
/// for each rank a horizontal pass over the whole image into one intermediate image, then a
/// vertical pass from it, accumulated into the output.
pub fn filter_with_schedule(
    color: &ColorImage,
    edge_image: Option<&GrayImage>,
    coc_px: &GrayImage,
    bank: &KernelBank,
    channels: Channels,
    schedule: Schedule,
    timings: &mut Timings,
) -> (ColorImage, Option<GrayImage>) {
    let three = channels == Channels::Auto && is_opaque(color);
    match (schedule, three) {
        (Schedule::Banded, true) => timings.time("lowrank/separable", || {
            banded::<3>(color, edge_image, coc_px, bank)
        }),
        (Schedule::Banded, false) => timings.time("lowrank/separable", || {
            banded::<4>(color, edge_image, coc_px, bank)
        }),
        (Schedule::Fig2, true) => fig2::<3>(color, edge_image, coc_px, bank, timings),
        (Schedule::Fig2, false) => fig2::<4>(color, edge_image, coc_px, bank, timings),
    }
}

fn fig2<const CH: usize>(
    color: &ColorImage,
    edge_image: Option<&GrayImage>,
    coc_px: &GrayImage,
    bank: &KernelBank,
    timings: &mut Timings,
) -> (ColorImage, Option<GrayImage>) {
    let (w, h) = (color.width(), color.height());
    let mut inter = Intermediate::new(coc_px, bank, edge_image.is_some(), CH);
    let mut out = vec![[0.0f32; CH]; w * h];
    let mut edge_out = edge_image.map(|_| GrayImage::new(w, h, 0.0));
    for i in 0..bank.rank {
        timings.time("lowrank/horizontal", || {
            horizontal(color, edge_image, bank, i, &mut inter)
        });
        timings.time("lowrank/vertical", || {
            vertical(&inter, bank, i, &mut out, edge_out.as_mut())
        });
    }
    let image = timings.time("lowrank/vertical", || finish(color, &inter, bank, &out));
    (image, edge_out)
}

/// The horizontally filtered rows of every rank for a window of source rows that slides down
/// the image with the bands of [`banded`]: source row `y` lives in slot `y % cap`, so any `cap`
/// consecutive rows have slots of their own, and a band keeps the rows it shares with the band
/// above.
struct Window {
    /// Slots: the rows one band reads, `BAND_ROWS + 2 nmax`.
    cap: usize,
    /// Rows `lo..hi` are held.
    lo: usize,
    hi: usize,
    /// Per rank, `cap` rows of `w` pixels of `CH` floats.
    colour: Vec<Vec<f32>>,
    /// Per rank, `cap` rows of `w` floats (empty without an edge image).
    edges: Vec<Vec<f32>>,
    /// Per slot: whether the source row's edge values are not all 0 (a row of zeros filters to
    /// zeros, so its taps are skipped).
    edge_rows: Vec<bool>,
    /// Per slot, each pixel's table key.
    keys: Vec<u32>,
    /// Scratch: padded colour and edge rows, a tap list, and the source rows' offsets of a
    /// group.
    padded_c: Vec<f32>,
    padded_e: Vec<f32>,
    list: Vec<(f32, usize)>,
    taps: RunTaps,
    base: Vec<usize>,
    /// The band's sums over the ranks (`BAND_ROWS` rows of `w` pixels of `CH` floats) and its
    /// column runs per group of rows: `(start, end, key)`, `u32::MAX` for columns whose rows
    /// have different keys.
    sum: Vec<f32>,
    runs: Vec<(usize, usize, u32)>,
}

/// Column runs of a group of rows mixing keys.
const MIXED: u32 = u32::MAX;

impl Window {
    fn new(bank: &KernelBank, w: usize, ch: usize, with_edges: bool) -> Self {
        let cap = BAND_ROWS + 2 * bank.nmax;
        Self {
            cap,
            lo: 0,
            hi: 0,
            colour: (0..bank.rank).map(|_| vec![0.0; cap * w * ch]).collect(),
            edges: (0..bank.rank)
                .map(|_| vec![0.0; if with_edges { cap * w } else { 0 }])
                .collect(),
            edge_rows: vec![false; cap],
            keys: vec![0; cap * w],
            padded_c: Vec::new(),
            padded_e: Vec::new(),
            list: Vec::new(),
            taps: RunTaps::default(),
            base: Vec::new(),
            sum: vec![0.0; BAND_ROWS * w * ch],
            runs: Vec::new(),
        }
    }

    /// Makes the window hold source rows `a..b` (at most `cap` of them), filtering the rows it
    /// does not hold yet.
    fn slide<const CH: usize>(
        &mut self,
        (a, b): (usize, usize),
        color: &ColorImage,
        edge_image: Option<&GrayImage>,
        coc_px: &GrayImage,
        bank: &KernelBank,
    ) {
        if !(self.lo <= a && a <= self.hi) {
            self.hi = a;
        }
        for y in self.hi.max(a)..b {
            self.filter_row::<CH>(y, color, edge_image, coc_px, bank);
        }
        (self.lo, self.hi) = (a, b);
    }

    /// The horizontal pass of source row `y` for every rank, into its slot: each run of pixels
    /// `[a, b)` sharing a kernel is one [`filter_span_ranks`] per three ranks, tap `j` reading
    /// `padded[a + j..]`, as [`horizontal_row`] does.
    fn filter_row<const CH: usize>(
        &mut self,
        y: usize,
        color: &ColorImage,
        edge_image: Option<&GrayImage>,
        coc_px: &GrayImage,
        bank: &KernelBank,
    ) {
        let w = color.width();
        let (nmax, r) = (bank.nmax, bank.rank);
        let slot = y % self.cap;
        let keys = &mut self.keys[slot * w..(slot + 1) * w];
        bank.keys_into(coc_px.row(y), keys);
        pad_row::<CH>(color.row(y), nmax, nmax, &mut self.padded_c);
        let edge_row = edge_image
            .map(|e| e.row(y))
            .filter(|e| e.iter().fold(false, |any, &v| any | (v != 0.0)));
        self.edge_rows[slot] = edge_row.is_some();
        if let Some(e) = edge_row {
            pad(e, nmax, &mut self.padded_e);
        }
        let keys = &self.keys[slot * w..(slot + 1) * w];
        for (a, b, key) in runs(keys) {
            for g in (0..r).step_by(MAX_RANKS) {
                let ranks = g..r.min(g + MAX_RANKS);
                self.taps.build(bank, key, ranks.clone(), a);
                // Every rank has an edge row, or none does.
                if self.edges.first().is_some_and(|e| !e.is_empty()) {
                    let mut outs: [&mut [f32]; MAX_RANKS] = Default::default();
                    for (o, e) in outs.iter_mut().zip(&mut self.edges[ranks.clone()]) {
                        *o = &mut e[slot * w + a..slot * w + b];
                    }
                    let outs = &mut outs[..ranks.len()];
                    if edge_row.is_some() {
                        self.taps.apply(outs, &self.padded_e);
                    } else {
                        outs.iter_mut().for_each(|o| o.fill(0.0));
                    }
                }
                self.taps.scale(CH);
                let mut outs: [&mut [f32]; MAX_RANKS] = Default::default();
                for (o, c) in outs.iter_mut().zip(&mut self.colour[ranks.clone()]) {
                    *o = &mut c[(slot * w + a) * CH..(slot * w + b) * CH];
                }
                self.taps.apply(&mut outs[..ranks.len()], &self.padded_c);
            }
        }
    }

    /// The column runs of output rows `y..y + m` (all in the window): maximal runs of columns
    /// whose `m` rows share one key, and runs of columns that mix keys ([`MIXED`]).
    fn group_runs(&mut self, y: usize, m: usize, w: usize) {
        self.runs.clear();
        let slots: Vec<usize> = (y..y + m).map(|yy| yy % self.cap * w).collect();
        let key_at = |x: usize| {
            let k = self.keys[slots[0] + x];
            if slots[1..].iter().all(|&s| self.keys[s + x] == k) {
                k
            } else {
                MIXED
            }
        };
        let mut a = 0;
        while a < w {
            let k = key_at(a);
            let mut b = a + 1;
            while b < w && key_at(b) == k {
                b += 1;
            }
            self.runs.push((a, b, k));
            a = b;
        }
    }
}

/// The banded schedule of [`filter`]: the image's rows split into one slab per worker thread,
/// each slab walked band by band of [`BAND_ROWS`] rows. For each band, the [`Window`] slides to
/// the source rows the band's vertical taps read (filtering the rows it does not hold yet, for
/// every rank), then for each rank the vertical taps sum the window into the band's sums: eight
/// rows at once ([`filter_rows`]) over the columns where they share a kernel, row by row and run
/// by run elsewhere, in column strips of [`STRIP_PX`]. The band is then finished into the
/// output. No intermediate image is stored; a slab filters `2 nmax` rows above and below it
/// twice.
fn banded<const CH: usize>(
    color: &ColorImage,
    edge_image: Option<&GrayImage>,
    coc_px: &GrayImage,
    bank: &KernelBank,
) -> (ColorImage, Option<GrayImage>) {
    let (w, h) = (color.width(), color.height());
    let mut edge_out = edge_image.map(|_| GrayImage::new(w, h, 0.0));
    if w == 0 || h == 0 || coc_px.width() != w || coc_px.height() != h {
        return (ColorImage::new(w, h, [0.0; 4]), edge_out);
    }
    let edge_image = edge_image.filter(|e| (e.width(), e.height()) == (w, h));
    let bands = h.div_ceil(BAND_ROWS);
    let slabs = rayon::current_num_threads().clamp(1, bands);
    let slab_rows = bands.div_ceil(slabs) * BAND_ROWS;
    // Each slab's rows of the filtered edge image, taken by the slab that fills them.
    let edge_parts: Vec<Option<&mut [f32]>> = match edge_out.as_mut() {
        Some(e) => e.pixels_mut().chunks_mut(slab_rows * w).map(Some).collect(),
        None => Vec::new(),
    };
    let edge_parts = std::sync::Mutex::new(edge_parts);
    let slab = |_: &mut (), y_start: usize, out: &mut [std::mem::MaybeUninit<Rgba>]| {
        let index = y_start / slab_rows;
        let mut edge_out = edge_parts
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get_mut(index)
            .and_then(Option::take);
        let mut win = Window::new(bank, w, CH, edge_image.is_some());
        let rows = out.len() / w;
        for b0 in (0..rows).step_by(BAND_ROWS) {
            let m_rows = BAND_ROWS.min(rows - b0);
            let y0 = y_start + b0;
            let reach = (
                y0.saturating_sub(bank.nmax),
                (y0 + m_rows + bank.nmax).min(h),
            );
            win.slide::<CH>(reach, color, edge_image, coc_px, bank);
            let edge_band = edge_out
                .as_deref_mut()
                .map(|e| &mut e[b0 * w..(b0 + m_rows) * w]);
            band_vertical::<CH>(&mut win, bank, (y0, m_rows), (w, h), edge_band);
            band_finish::<CH>(&win, bank, color, y0, &mut out[b0 * w..(b0 + m_rows) * w]);
        }
        false
    };
    // SAFETY: a slab's bands cover its rows, and `band_finish` writes every pixel of a band
    // (one per pixel of its rows, from the band's sums, which hold `w * CH` floats a row).
    let (out, _) = unsafe { ColorImage::par_from_bands(w, h, slab_rows, || (), slab) };
    (out, edge_out)
}

/// The vertical pass of every rank for output rows `y0..y0 + m_rows` from the window, into
/// `win.sum` (overwritten by rank 0, added to by the others) and `edge_band` (the band's rows of
/// the filtered edge image). Each pixel gets its nonzero taps in order, as in [`vertical`].
fn band_vertical<const CH: usize>(
    win: &mut Window,
    bank: &KernelBank,
    (y0, m_rows): (usize, usize),
    (w, h): (usize, usize),
    mut edge_band: Option<&mut [f32]>,
) {
    let (nmax, stride, r, cap) = (bank.nmax, bank.stride, bank.rank, win.cap);
    let slot_of = |y: isize| (y.clamp(0, h as isize - 1) as usize) % cap;
    for g0 in (0..m_rows).step_by(MAX_ROWS) {
        let m = MAX_ROWS.min(m_rows - g0);
        let yg = y0 + g0;
        win.group_runs(yg, m, w);
        for x0 in (0..w).step_by(STRIP_PX) {
            let x1 = (x0 + STRIP_PX).min(w);
            for ri in 0..win.runs.len() {
                let (a, b, key) = win.runs[ri];
                let (a, b) = (a.max(x0), b.min(x1));
                if a >= b {
                    continue;
                }
                for i in 0..r {
                    let add = i > 0;
                    if key != MIXED {
                        // The group's rows share this kernel: source row `k` of the list is
                        // row `yg + k - n`, and tap `t` of output row `g` reads entry `t + g`.
                        let n = bank.half_v_of(key);
                        let table = (key as usize * r + i) * stride;
                        let taps = &bank.vertical[table + nmax - n..=table + nmax + n];
                        let rows = (0..2 * n + m).map(|k| slot_of((yg + k) as isize - n as isize));
                        win.base.clear();
                        win.base.extend(rows.map(|s| (s * w + a) * CH));
                        let sum = &mut win.sum[g0 * w * CH..(g0 + m) * w * CH];
                        let mut outs: [&mut [f32]; MAX_ROWS] = std::array::from_fn(|_| &mut [][..]);
                        for (o, row) in outs.iter_mut().zip(sum.chunks_mut(w * CH)) {
                            *o = &mut row[a * CH..b * CH];
                        }
                        filter_rows(&mut outs[..m], taps, &win.base, &win.colour[i], add);
                        if let Some(e) = edge_band.as_deref_mut() {
                            let e = &mut e[g0 * w..(g0 + m) * w];
                            let lit = (0..2 * n + m)
                                .any(|k| win.edge_rows[slot_of((yg + k) as isize - n as isize)]);
                            if lit {
                                for v in win.base.iter_mut() {
                                    *v /= CH;
                                }
                                let mut outs: [&mut [f32]; MAX_ROWS] =
                                    std::array::from_fn(|_| &mut [][..]);
                                for (o, row) in outs.iter_mut().zip(e.chunks_mut(w)) {
                                    *o = &mut row[a..b];
                                }
                                filter_rows(&mut outs[..m], taps, &win.base, &win.edges[i], add);
                            } else if !add {
                                for row in e.chunks_mut(w) {
                                    row[a..b].fill(0.0);
                                }
                            }
                        }
                    } else {
                        for g in 0..m {
                            let y = yg + g;
                            let slot = y % cap;
                            let keys = &win.keys[slot * w + a..slot * w + b];
                            for (ra, rb, key) in runs(keys) {
                                let (ra, rb) = (a + ra, a + rb);
                                let n = bank.half_v_of(key);
                                let table = (key as usize * r + i) * stride;
                                win.list.clear();
                                let mut lit = false;
                                for j in nmax - n..=nmax + n {
                                    let wt = bank.vertical[table + j];
                                    if wt != 0.0 {
                                        let s = slot_of((y + j) as isize - nmax as isize);
                                        lit |= win.edge_rows[s];
                                        win.list.push((wt, s * w + ra));
                                    }
                                }
                                if let Some(e) = edge_band.as_deref_mut() {
                                    let e = &mut e[(g0 + g) * w + ra..(g0 + g) * w + rb];
                                    if lit {
                                        if add {
                                            filter_span_add(e, &win.list, &win.edges[i]);
                                        } else {
                                            filter_span(e, &win.list, &win.edges[i]);
                                        }
                                    } else if !add {
                                        e.fill(0.0);
                                    }
                                }
                                for t in win.list.iter_mut() {
                                    t.1 *= CH;
                                }
                                let o = &mut win.sum
                                    [((g0 + g) * w + ra) * CH..((g0 + g) * w + rb) * CH];
                                if add {
                                    filter_span_add(o, &win.list, &win.colour[i]);
                                } else {
                                    filter_span(o, &win.list, &win.colour[i]);
                                }
                            }
                        }
                    }
                }
            }
        }
    }
}

/// [`finish`] for the band from row `y0`: its sums in `win.sum` into `out`.
fn band_finish<const CH: usize>(
    win: &Window,
    bank: &KernelBank,
    color: &ColorImage,
    y0: usize,
    out: &mut [std::mem::MaybeUninit<Rgba>],
) {
    let w = color.width();
    for (g, (row, sums)) in out.chunks_mut(w).zip(win.sum.chunks(w * CH)).enumerate() {
        let slot = (y0 + g) % win.cap;
        let keys = &win.keys[slot * w..(slot + 1) * w];
        let c_row = color.row(y0 + g);
        for (((o, s), &key), &c) in row
            .iter_mut()
            .zip(sums.chunks_exact(CH))
            .zip(keys)
            .zip(c_row)
        {
            o.write(if bank.half_h_of(key) == 0 && bank.half_v_of(key) == 0 {
                c
            } else {
                let v = |k: usize| if k < CH { s[k].max(0.0) } else { 1.0 };
                [v(0), v(1), v(2), v(3)]
            });
        }
    }
}

/// Pass `horizontal` for rank `i`: `U_i(x, y) = sum_d h_i(d; C(x, y)) img(x - d, y)`, and the
/// same for the edge image when given, into `inter`.
pub fn horizontal(
    color: &ColorImage,
    edge_image: Option<&GrayImage>,
    bank: &KernelBank,
    i: usize,
    inter: &mut Intermediate,
) {
    let w = inter.width;
    if w == 0 || inter.height == 0 || i >= bank.rank {
        return;
    }
    let (keys, ch) = (&inter.keys, inter.channels);
    let row =
        |y: usize, out_c: &mut [f32], out_e: Option<&mut [f32]>, bufs: &mut HorizontalScratch| {
            let keys = &keys[y * w..(y + 1) * w];
            let edge_row = edge_image.map(|e| e.row(y));
            horizontal_row(bank, i, keys, color.row(y), edge_row, out_c, out_e, bufs);
        };
    if edge_image.is_some() && !inter.edges.is_empty() {
        inter
            .colour
            .par_chunks_mut(w * ch)
            .zip(inter.edges.par_chunks_mut(w))
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new(), RunTaps::default()),
                |bufs, (y, (c, e))| row(y, c, Some(e), bufs),
            );
    } else {
        inter
            .colour
            .par_chunks_mut(w * ch)
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new(), RunTaps::default()),
                |bufs, (y, c)| row(y, c, None, bufs),
            );
    }
}

/// Copies `row` into `buf` with `n` clamped copies of its ends on each side.
fn pad<T: Copy>(row: &[T], n: usize, buf: &mut Vec<T>) {
    buf.clear();
    buf.extend(std::iter::repeat_n(row[0], n));
    buf.extend_from_slice(row);
    buf.extend(std::iter::repeat_n(row[row.len() - 1], n));
}

/// Splits `keys` into maximal runs of equal keys: `(start, end, key)`.
fn runs(keys: &[u32]) -> impl Iterator<Item = (usize, usize, u32)> + '_ {
    let mut start = 0;
    std::iter::from_fn(move || {
        let &key = keys.get(start)?;
        let len = keys[start..].iter().take_while(|&&k| k == key).count();
        let run = (start, start + len, key);
        start += len;
        Some(run)
    })
}

/// The horizontal taps of up to [`MAX_RANKS`] ranks of one kernel over a run of pixels, as
/// [`filter_span_ranks_folded`] takes them where every rank's taps are even or odd
/// ([`KernelBank`]'s parity), as [`filter_span_ranks`] takes them otherwise.
#[derive(Default)]
struct RunTaps {
    /// Whether the taps are folded into `center` and `pairs`, or listed in `plain`.
    folded: bool,
    /// The ranks in the order their weights are stored: the even ones first when folded.
    ranks: Vec<usize>,
    /// Folded: how many of `ranks` are even.
    even: usize,
    center: (usize, [f32; MAX_RANKS]),
    pairs: Vec<TapPair>,
    plain: Vec<(usize, [f32; MAX_RANKS])>,
}

impl RunTaps {
    /// The taps of `ranks` for table key `key` on the run starting at pixel `a` of a row padded
    /// with `nmax` pixels each side: tap `j` reads pixel `a + j` of the padded row.
    fn build(&mut self, bank: &KernelBank, key: u32, ranks: std::ops::Range<usize>, a: usize) {
        let (nmax, stride, r) = (bank.nmax, bank.stride, bank.rank);
        let n = bank.half_h_of(key);
        let weight = |i: usize, j: usize| bank.horizontal[(key as usize * r + i) * stride + j];
        self.folded = ranks.clone().all(|i| bank.h_parity[i] != 0);
        self.ranks.clear();
        if self.folded {
            self.ranks
                .extend(ranks.clone().filter(|&i| bank.h_parity[i] > 0));
            self.even = self.ranks.len();
            self.ranks.extend(ranks.filter(|&i| bank.h_parity[i] < 0));
            let mut cw = [0.0; MAX_RANKS];
            for (k, &i) in self.ranks.iter().enumerate() {
                cw[k] = weight(i, nmax);
            }
            self.center = (a + nmax, cw);
            self.pairs.clear();
            for d in 1..=n {
                let mut wt = [0.0; MAX_RANKS];
                for (k, &i) in self.ranks.iter().enumerate() {
                    wt[k] = weight(i, nmax + d);
                }
                if wt.iter().any(|&v| v != 0.0) {
                    self.pairs.push((a + nmax - d, a + nmax + d, wt));
                }
            }
        } else {
            self.ranks.extend(ranks);
            self.plain.clear();
            for j in nmax - n..=nmax + n {
                let mut wt = [0.0; MAX_RANKS];
                for (k, &i) in self.ranks.iter().enumerate() {
                    wt[k] = weight(i, j);
                }
                if wt.iter().any(|&v| v != 0.0) {
                    self.plain.push((a + j, wt));
                }
            }
        }
    }

    /// Multiplies every source offset by `ch` (pixels of `ch` floats).
    fn scale(&mut self, ch: usize) {
        self.center.0 *= ch;
        for t in self.pairs.iter_mut() {
            (t.0, t.1) = (t.0 * ch, t.1 * ch);
        }
        for t in self.plain.iter_mut() {
            t.0 *= ch;
        }
    }

    /// Filters `src` into `outs`, one output per rank of `build`'s range, in its order.
    fn apply(&self, outs: &mut [&mut [f32]], src: &[f32]) {
        let first = self.ranks.iter().copied().min().unwrap_or(0);
        let mut ordered: [&mut [f32]; MAX_RANKS] = Default::default();
        for (k, &i) in self.ranks.iter().enumerate() {
            ordered[k] = std::mem::take(&mut outs[i - first]);
        }
        let ordered = &mut ordered[..self.ranks.len()];
        if self.folded {
            filter_span_ranks_folded(ordered, self.even, self.center, &self.pairs, src);
        } else {
            filter_span_ranks(ordered, &self.plain, src);
        }
    }
}

/// Scratch buffers of one thread of the horizontal pass: padded colour (flattened) and edge
/// rows, and a tap list.
type HorizontalScratch = (Vec<f32>, Vec<f32>, RunTaps);

/// One row of the horizontal pass for rank `i`, with the edge row when there is an edge
/// image; `out_c` holds `out_c.len() / keys.len()` channels per pixel (3 or 4). Each run of
/// pixels `[a, b)` sharing a kernel is one [`filter_span`]: tap `j` reads `padded[a + j..]`.
#[expect(
    clippy::too_many_arguments,
    reason = "one row of one rank: inputs, outputs and scratch, all used once"
)]
fn horizontal_row(
    bank: &KernelBank,
    i: usize,
    keys: &[u32],
    colour_row: &[Rgba],
    edge_row: Option<&[f32]>,
    out_c: &mut [f32],
    out_e: Option<&mut [f32]>,
    (padded_c, padded_e, taps): &mut HorizontalScratch,
) {
    let nmax = bank.nmax;
    let ch = out_c.len() / keys.len().max(1);
    if ch == 3 {
        pad_row::<3>(colour_row, nmax, nmax, padded_c);
    } else {
        pad_row::<4>(colour_row, nmax, nmax, padded_c);
    }
    if let Some(e) = edge_row {
        pad(e, nmax, padded_e);
    }
    let mut out_e = out_e;
    for (a, b, key) in runs(keys) {
        taps.build(bank, key, i..i + 1, a);
        if let Some(e) = out_e.as_deref_mut() {
            taps.apply(&mut [&mut e[a..b]], padded_e);
        }
        taps.scale(ch);
        taps.apply(&mut [&mut out_c[a * ch..b * ch]], padded_c);
    }
}

/// Pass `vertical` for rank `i`: `out(x, y) (+)= sum_d v_i(d; C(x, y)) U_i(x, y - d)`,
/// overwriting `out` for rank 0 and accumulating for the others, and the same for the edge
/// channel into `edge_out`. Rows are walked in blocks and column strips as in the separable
/// filter, and each run of pixels sharing a kernel within a strip is one [`filter_span`].
pub fn vertical<const CH: usize>(
    inter: &Intermediate,
    bank: &KernelBank,
    i: usize,
    out: &mut [[f32; CH]],
    edge_out: Option<&mut GrayImage>,
) {
    let (w, h, r) = (inter.width, inter.height, bank.rank);
    if w == 0 || h == 0 || i >= r || out.len() != w * h || inter.channels != CH {
        return;
    }
    let edge_out =
        edge_out.filter(|e| (e.width(), e.height()) == (w, h) && !inter.edges.is_empty());
    let first = i == 0;
    let row = |y: usize,
               x0: usize,
               out_c: &mut [[f32; CH]],
               mut out_e: Option<&mut [f32]>,
               list: &mut Vec<(f32, usize)>| {
        let x1 = x0 + out_c.len();
        let keys = &inter.keys[y * w + x0..y * w + x1];
        let (nmax, stride) = (bank.nmax, bank.stride);
        for (a, b, key) in runs(keys) {
            let n = bank.half_v_of(key);
            list.clear();
            for j in nmax - n..=nmax + n {
                let yy = (y + j).saturating_sub(nmax).min(h - 1);
                let wt = bank.vertical[(key as usize * r + i) * stride + j];
                if wt != 0.0 {
                    list.push((wt, yy * w + x0 + a));
                }
            }
            if let Some(e) = out_e.as_deref_mut() {
                if first {
                    filter_span(&mut e[a..b], list, &inter.edges);
                } else {
                    filter_span_add(&mut e[a..b], list, &inter.edges);
                }
            }
            for t in list.iter_mut() {
                t.1 *= CH;
            }
            let acc = out_c[a..b].as_flattened_mut();
            if first {
                filter_span(acc, list, &inter.colour);
            } else {
                filter_span_add(acc, list, &inter.colour);
            }
        }
    };
    let block = |list: &mut Vec<(f32, usize)>,
                 index: usize,
                 colour_rows: &mut [[f32; CH]],
                 mut edge_rows: Option<&mut [f32]>| {
        let y0 = index * ROW_BLOCK;
        for x0 in (0..w).step_by(STRIP_PX) {
            let x1 = (x0 + STRIP_PX).min(w);
            for (dy, c) in colour_rows.chunks_mut(w).enumerate() {
                let e = edge_rows
                    .as_deref_mut()
                    .map(|e| &mut e[dy * w + x0..dy * w + x1]);
                row(y0 + dy, x0, &mut c[x0..x1], e, list);
            }
        }
    };
    match edge_out {
        Some(e) => out
            .par_chunks_mut(ROW_BLOCK * w)
            .zip(e.pixels_mut().par_chunks_mut(ROW_BLOCK * w))
            .enumerate()
            .for_each_init(Vec::new, |list, (i, (c, e))| block(list, i, c, Some(e))),
        None => out
            .par_chunks_mut(ROW_BLOCK * w)
            .enumerate()
            .for_each_init(Vec::new, |list, (i, c)| block(list, i, c, None)),
    }
}

/// After the last rank: pixels whose kernel lies inside the pixel (no taps beyond their own)
/// get `color` back exactly; the others are clamped to 0 from below, with alpha 1 when only
/// the colour was filtered (`CH` = 3).
fn finish<const CH: usize>(
    color: &ColorImage,
    inter: &Intermediate,
    bank: &KernelBank,
    out: &[[f32; CH]],
) -> ColorImage {
    let (w, h) = (color.width(), color.height());
    if out.len() != w * h || inter.keys.len() != w * h {
        return ColorImage::new(w, h, [0.0; 4]);
    }
    let pixels: Vec<Rgba> = out
        .par_iter()
        .zip(&inter.keys)
        .zip(color.pixels())
        .map(|((f, &key), &c)| {
            if bank.half_h_of(key) == 0 && bank.half_v_of(key) == 0 {
                c
            } else {
                let v = |k: usize| if k < CH { f[k].max(0.0) } else { 1.0 };
                [v(0), v(1), v(2), v(3)]
            }
        })
        .collect();
    ColorImage::from_vec(w, h, pixels).expect("sizes agree by construction")
}

/// Taps of `base` scaled to `radius_px`, by summing the overlap of each base cell with each
/// tap's footprint (the naive twin of the cumulative-sum integration of [`KernelBank`]).
fn naive_taps(base: &[f64], radius_px: f64, n: usize) -> Vec<f64> {
    let nb = base.len() as f64;
    if radius_px <= 0.0 {
        return vec![base.iter().sum()];
    }
    (-(n as i64)..=n as i64)
        .map(|d| {
            let a = ((d as f64 - 0.5) / radius_px).max(-1.0);
            let b = ((d as f64 + 0.5) / radius_px).min(1.0);
            base.iter()
                .enumerate()
                .map(|(k, &v)| {
                    let c0 = -1.0 + 2.0 * k as f64 / nb;
                    let c1 = -1.0 + 2.0 * (k + 1) as f64 / nb;
                    let overlap = (b.min(c1) - a.max(c0)).max(0.0);
                    v * overlap / (2.0 / nb)
                })
                .sum()
        })
        .collect()
}

/// Per-pixel twin of [`horizontal`] followed by [`vertical`], written from the equations in
/// f64 with the same quantisation of radii: returns the image and the filtered edge image.
pub fn naive(
    color: &ColorImage,
    edge_image: Option<&GrayImage>,
    coc_px: &GrayImage,
    lr: &LowRank,
    rank: usize,
    max_radius_px: f32,
) -> Result<(ColorImage, Option<GrayImage>)> {
    let (w, h) = (color.width(), color.height());
    let norm = rank_sum(lr, rank)?;
    let levels = level_count(max_radius_px);
    // Taps of pixel (x, y) for rank i: (horizontal, vertical), index d + n.
    let taps = |x: usize, y: usize, i: usize| -> (Vec<f64>, Vec<f64>, usize) {
        let c = coc_px.get(x, y);
        let level = level_of(c, levels);
        let radius = level_radius_px(level) as f64;
        let n = half_taps(level_radius_px(level));
        let mut ht = naive_taps(lr.horizontal(i).unwrap_or(&[]), radius, n);
        let mut vt = naive_taps(lr.vertical(i).unwrap_or(&[]), radius, n);
        if c < 0.0 {
            ht.reverse();
            vt.reverse();
        }
        (ht, vt, n)
    };
    let clamp = |v: i64, n: usize| v.clamp(0, n as i64 - 1) as usize;
    let mut u = vec![vec![[0.0f64; 5]; w * h]; rank];
    for y in 0..h {
        for x in 0..w {
            for (i, ui) in u.iter_mut().enumerate() {
                let (ht, _, n) = taps(x, y, i);
                for (t, &wt) in ht.iter().enumerate() {
                    let d = t as i64 - n as i64;
                    let sx = clamp(x as i64 - d, w);
                    let p = color.get(sx, y);
                    let e = edge_image.map_or(0.0, |e| e.get(sx, y));
                    let acc = &mut ui[y * w + x];
                    for k in 0..4 {
                        acc[k] += wt / norm * p[k] as f64;
                    }
                    acc[4] += wt / norm * e as f64;
                }
            }
        }
    }
    let mut out = ColorImage::new(w, h, [0.0; 4]);
    let mut edge_out = GrayImage::new(w, h, 0.0);
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f64; 5];
            let mut n_here = 0;
            for (i, ui) in u.iter().enumerate() {
                let (_, vt, n) = taps(x, y, i);
                n_here = n;
                for (t, &wt) in vt.iter().enumerate() {
                    let d = t as i64 - n as i64;
                    let p = ui[clamp(y as i64 - d, h) * w + x];
                    for k in 0..5 {
                        acc[k] += wt * p[k];
                    }
                }
            }
            *out.get_mut(x, y) = if n_here == 0 {
                color.get(x, y)
            } else {
                [acc[0], acc[1], acc[2], acc[3]].map(|v| v.max(0.0) as f32)
            };
            *edge_out.get_mut(x, y) = acc[4] as f32;
        }
    }
    Ok((out, edge_image.map(|_| edge_out)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lens::Aperture;
    use crate::methods::lowrank::decompose;
    use crate::methods::lowrank::kernel::{kernel_image, KernelSpec};

    fn bank(aperture: &str, rank: usize) -> KernelBank {
        let spec = KernelSpec::new(Aperture::parse(aperture).expect("aperture"), 67);
        let lr = decompose(&kernel_image(&spec).expect("kernel")).expect("svd");
        KernelBank::new(&lr, rank, 20.0).expect("bank")
    }

    /// An aperture symmetric about the vertical axis (a disc, an upright hexagon) has even or
    /// odd horizontal singular vectors, and its taps are then exactly so at every level, near
    /// field and far; a rotated pentagon's are not all even or odd, and its taps are left as
    /// they are.
    #[test]
    fn a_symmetric_aperture_gets_even_or_odd_horizontal_taps() {
        for aperture in ["disc", "poly:6", "poly:8"] {
            let b = bank(aperture, 3);
            assert!(
                b.h_parity.iter().all(|&p| p != 0),
                "{aperture}: parities {:?}",
                b.h_parity
            );
            for key in 0..2 * b.levels as u32 {
                let n = b.half_h_of(key);
                for (i, &p) in b.h_parity.iter().enumerate() {
                    let t = &b.horizontal[(key as usize * b.rank + i) * b.stride..][..b.stride];
                    for d in 1..=n {
                        assert_eq!(
                            t[b.nmax - d],
                            f32::from(p) * t[b.nmax + d],
                            "{aperture}, key {key}, rank {i}, offset {d}"
                        );
                    }
                }
            }
        }
        let b = bank("poly:5,rot=10", 3);
        assert!(b.h_parity.contains(&0), "pentagon: {:?}", b.h_parity);
    }
}
