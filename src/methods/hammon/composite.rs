//! Pass `composite` (section 28.5.2, Listing 28-4 `ApplyDepthOfField`): the variable-width blur
//! as a piecewise-linear blend of four blur levels.
//!
//! Reads the full-resolution colour and signed blur amounts `s` (computed from depth row by
//! row in the render, as the listing's `dofEqFar` does, or from an image of them), the medium image
//! (pass `near_coc`: colour and near CoC) and the large image (pass `blur`); writes the output.
//! Per pixel:
//! 1. near = the medium image's CoC, sampled bilinearly; far = `max(s, 0)` (already multiplied
//!    by `far_to_near_ratio`, and 0 for sky: pass `coc`); `t = max(near, far)`.
//! 2. Weights of unblurred, small, medium, large: `saturate(t * dofLerpScale + dofLerpBias)`,
//!    then `w_small = min(w_small, 1 - w_unblurred)`, `w_medium = min(w_medium, 1 - w_small)`
//!    (with the values before this step): they sum to 1 and rise and fall linearly in `t`, and
//!    at most two adjacent levels are non-zero: unblurred and small for `t < d0`, small and
//!    medium up to `d0 + d1`, medium and large up to 1, large alone beyond. The fast pass
//!    computes exactly that: it finds the segment of `t` and lerps its two levels; [`naive`]
//!    keeps the listing's form.
//! 3. Small blur = the mean of the 17 pixels of fig. 28-5, which the listing reads as four
//!    bilinear taps at (+0.5, -1.5), (-1.5, -0.5), (-0.5, +1.5), (+1.5, +0.5) pixels (2x2 pixels
//!    each, weight 4/17) plus the unblurred centre (1/17, through the frame-buffer blend). With
//!    y down, the pixels are, per row dy = -2..=2: dx in {0, 1}, {-2..=1}, {-2..=2}, {-1..=2},
//!    {-1, 0}. Medium and large are the quarter-res images sampled bilinearly.
//! 4. Output = `w_unblurred colour + w_small small + w_medium medium + w_large large`.
//!
//! A pixel with `t <= 0` is copied unchanged. Away from the left and right edges, pixels go in
//! groups of four (one quarter-res texel's span, so the upsampling fractions are the same in
//! every group): the small blur, medium and large levels are computed for all four as 16
//! lanes, and each lane selects its segment's two levels, with no branch per pixel. A group in
//! focus throughout is copied. The edges go pixel by pixel with the same operations in the
//! same order, so both forms give the same bits (unit test `groups_match_pixels_bit_for_bit`).
//! Branching per pixel on the segment (reading only its two levels) took 2.07 ms on the
//! benchmark frame, the groups 1.98 ms with the CoC computed from depth besides; the listing's
//! four clamped weights written out per pixel compiled to about 270 instructions per blurred
//! pixel (see `mod.rs`). Groups beyond `d0 + d1` skip the small blur, which no lane selects.

use std::mem::MaybeUninit;

use super::coc::Amounts;
use super::{quarter_size, saturate, Constants, LerpDistances, QuarterImage};
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::{Error, Result};

/// Fails unless the inputs have the sizes of the frame of `k` and of its quarter-res images.
fn check_sizes(
    color: &ColorImage,
    amounts: &Amounts,
    medium: &QuarterImage,
    large: &QuarterImage,
    k: &Constants,
) -> Result<()> {
    let (w, h) = (k.width(), k.height());
    if (color.width(), color.height()) != (w, h) {
        return Err(Error::Mismatch(format!(
            "colour image is {}x{} but the constants are for {w}x{h}",
            color.width(),
            color.height()
        )));
    }
    amounts.check_size("colour image", w, h)?;
    let (qw, qh) = quarter_size(w, h);
    for (what, q) in [("medium image", medium), ("large image", large)] {
        q.check()?;
        if (q.width(), q.height()) != (qw, qh) {
            return Err(Error::Mismatch(format!(
                "{what} is {}x{} but a {w}x{h} frame needs {qw}x{qh}",
                q.width(),
                q.height()
            )));
        }
    }
    Ok(())
}

/// Bilinear sampling of a quarter-res axis of `n` texels at full-res pixel `i`: texel j is
/// centred at full-res position 4j + 2, so the texel coordinate is `(i + 0.5) / 4 - 0.5`,
/// clamped to the edge. Returns the two texels and the weight of the second.
#[inline]
fn quarter_tap(i: usize, n: usize) -> (usize, usize, f32) {
    let u = ((i as f32 + 0.5) * 0.25 - 0.5).max(0.0);
    let i0 = (u as usize).min(n - 1);
    let i1 = (i0 + 1).min(n - 1);
    (i0, i1, u - i0 as f32)
}

/// `a + f (b - a)` per channel (exact when `a == b`).
#[inline(always)]
fn lerp4(a: Rgba, b: Rgba, f: f32) -> Rgba {
    [
        a[0] + f * (b[0] - a[0]),
        a[1] + f * (b[1] - a[1]),
        a[2] + f * (b[2] - a[2]),
        a[3] + f * (b[3] - a[3]),
    ]
}

/// The larger of `a` and `b`, without `f32::max`'s NaN handling (one `maxss`).
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// The blend segments of `t`: boundaries `d0`, `d0 + d1` (and 1) and the inverse widths.
#[derive(Clone, Copy, Debug)]
struct Segments {
    d0: f32,
    d01: f32,
    inv_d0: f32,
    inv_d1: f32,
    inv_d2: f32,
}

impl Segments {
    fn new(d: LerpDistances) -> Self {
        Self {
            d0: d.d0,
            d01: d.d0 + d.d1,
            inv_d0: 1.0 / d.d0,
            inv_d1: 1.0 / d.d1,
            inv_d2: 1.0 / d.d2,
        }
    }
}

/// `a + b` per lane.
#[inline(always)]
fn add<const N: usize>(a: [f32; N], b: [f32; N]) -> [f32; N] {
    let mut out = a;
    for (o, v) in out.iter_mut().zip(b) {
        *o += v;
    }
    out
}

/// The mean of the 17 pixels of fig. 28-5, `at(r, d)` giving the pixel(s) at row `y + r - 2`,
/// column `x + d` (one pixel for N = 4, four for N = 16). Per row `r` (y down), the columns
/// are `d` in {0, 1}, {-2..=1}, {-2..=2}, {-1..=2}, {-1, 0}. Summed as a tree (pairs within a
/// row, then rows), so no add waits on more than five before it.
#[inline(always)]
fn small_sum<const N: usize>(at: impl Fn(usize, isize) -> [f32; N]) -> [f32; N] {
    let r0 = add(at(0, 0), at(0, 1));
    let r1 = add(add(at(1, -2), at(1, -1)), add(at(1, 0), at(1, 1)));
    let r2 = add(
        add(add(at(2, -2), at(2, -1)), add(at(2, 0), at(2, 1))),
        at(2, 2),
    );
    let r3 = add(add(at(3, -1), at(3, 0)), add(at(3, 1), at(3, 2)));
    let r4 = add(at(4, -1), at(4, 0));
    add(add(add(r0, r1), add(r2, r3)), r4).map(|v| v * (1.0 / 17.0))
}

/// The 17-pixel small blur of fig. 28-5 at column `x`, from rows `y - 2..=y + 2` (clamped).
#[inline(always)]
fn small_blur(rows: &[&[Rgba]; 5], x: usize) -> Rgba {
    let last = rows[0].len() - 1;
    small_sum(|r, d| rows[r][x.saturating_add_signed(d).min(last)])
}

/// Horizontal bilinear upsampling by 4 in groups: output pixel `4q + j` lies between texels
/// `q - 1 + UPSAMPLE_LEFT[j]` and the next, at fraction `UPSAMPLE_FRACTION[j]` (texel coordinate
/// `(4q + j + 0.5) / 4 - 0.5`). Indices are into a row padded with one clamped texel at each end,
/// so group q reads padded texels `q..q + 3` and never needs a clamp.
const UPSAMPLE_LEFT: [usize; 4] = [0, 0, 1, 1];
/// See [`UPSAMPLE_LEFT`].
const UPSAMPLE_FRACTION: [f32; 4] = [0.625, 0.875, 0.125, 0.375];

/// Fills `padded` (`n + 2` texels of `CH` floats) with `a + f (b - a)` and one copy of the
/// first and last texels at the ends (clamp to edge). Over flat floats, so it vectorises.
#[inline(always)]
fn pad_lerp<const CH: usize>(padded: &mut [f32], a: &[f32], b: &[f32], f: f32) {
    let n = a.len();
    for ((p, &a), &b) in padded[CH..CH + n].iter_mut().zip(a).zip(b) {
        *p = a + f * (b - a);
    }
    padded.copy_within(CH..2 * CH, 0);
    padded.copy_within(n..n + CH, n + CH);
}

/// Blends unblurred, small, medium and large blur per pixel by the blur amount (Listing 28-4).
/// The amounts are an image of `s` (pass [`super::coc`]) or computed here from depth
/// ([`Amounts::Depth`]), which fails as [`super::coc::coc`] does on bad depth.
pub fn composite<'a>(
    color: &ColorImage,
    amounts: impl Into<Amounts<'a>>,
    medium: &QuarterImage,
    large: &QuarterImage,
    k: &Constants,
) -> Result<ColorImage> {
    composite_with(color, amounts.into(), medium, large, k, composite_row)
}

/// [`composite`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn composite_baseline<'a>(
    color: &ColorImage,
    amounts: impl Into<Amounts<'a>>,
    medium: &QuarterImage,
    large: &QuarterImage,
    k: &Constants,
) -> Result<ColorImage> {
    composite_with(
        color,
        amounts.into(),
        medium,
        large,
        k,
        composite_row_inner::<true>,
    )
}

/// The inputs every row of [`composite`] reads.
struct RowInputs<'a> {
    color: &'a ColorImage,
    amounts: Amounts<'a>,
    medium: &'a QuarterImage,
    large: &'a QuarterImage,
    seg: Segments,
}

/// Per-thread scratch rows: the quarter-res rows interpolated vertically at the output row,
/// padded (medium colour, medium near CoC, large colour), the row's amounts `s` when they are
/// computed from depth, and its blend amounts `t`.
type RowScratch = (Vec<Rgba>, Vec<f32>, Vec<Rgba>, Vec<f32>, Vec<f32>);

fn composite_with<F>(
    color: &ColorImage,
    amounts: Amounts,
    medium: &QuarterImage,
    large: &QuarterImage,
    k: &Constants,
    row_fn: F,
) -> Result<ColorImage>
where
    F: Fn(&RowInputs, &mut RowScratch, usize, &mut [MaybeUninit<Rgba>]) -> bool + Sync + Send,
{
    check_sizes(color, &amounts, medium, large, k)?;
    let (w, h) = (color.width(), color.height());
    let qw = medium.width();
    let inputs = RowInputs {
        color,
        amounts,
        medium,
        large,
        seg: Segments::new(k.lerp_distances()),
    };
    // SAFETY: `row_fn` is `composite_row` or `composite_row_inner`, which write every pixel
    // of the row they are given.
    let (out, bad) = unsafe {
        ColorImage::par_from_rows(
            w,
            h,
            || row_scratch(w, qw),
            |scratch, y, out_row| row_fn(&inputs, scratch, y, out_row),
        )
    }?;
    if bad {
        return Err(amounts.error());
    }
    Ok(out)
}

/// Scratch rows for a `w`-pixel frame with `qw`-texel quarter-res rows.
fn row_scratch(w: usize, qw: usize) -> RowScratch {
    (
        vec![[0.0f32; 4]; qw + 2],
        vec![0.0f32; qw + 2],
        vec![[0.0f32; 4]; qw + 2],
        vec![0.0f32; w],
        vec![0.0f32; w],
    )
}

/// One output row of [`composite`]. Compiled for several instruction sets and chosen at run
/// time ([`multiversion`]); the same arithmetic in every version (no fused multiply-add), so
/// the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn composite_row(
    inputs: &RowInputs,
    scratch: &mut RowScratch,
    y: usize,
    out_row: &mut [MaybeUninit<Rgba>],
) -> bool {
    composite_row_inner::<true>(inputs, scratch, y, out_row)
}

/// One output row `y`, every pixel of `out_row` written (as [`composite_with`] relies on):
/// copied when the whole row is in focus, else group by group or pixel by pixel.
#[inline(always)]
fn composite_row_inner<const GROUPED: bool>(
    inputs: &RowInputs,
    scratch: &mut RowScratch,
    y: usize,
    out_row: &mut [MaybeUninit<Rgba>],
) -> bool {
    let RowInputs {
        color,
        ref amounts,
        medium,
        large,
        seg,
    } = *inputs;
    let (med_c, med_k, large_c, s_scratch, t) = scratch;
    let (s, bad) = amounts.rows(y, y + 1, s_scratch);
    let (h, qh) = (color.height(), medium.height());
    // The quarter-res rows interpolated vertically at this row, padded.
    let (y0, y1, fy) = quarter_tap(y, qh);
    pad_lerp::<1>(med_k, medium.coc.row(y0), medium.coc.row(y1), fy);
    blend_amounts(t, s, med_k);
    // A row in focus throughout: every pixel is copied.
    if t.iter().all(|v| v.is_nan() || *v <= 0.0) {
        for (o, &c) in out_row.iter_mut().zip(color.row(y)) {
            o.write(c);
        }
        return bad;
    }
    fn flat(img: &ColorImage, y: usize) -> &[f32] {
        img.row(y).as_flattened()
    }
    pad_lerp::<4>(
        med_c.as_flattened_mut(),
        flat(&medium.color, y0),
        flat(&medium.color, y1),
        fy,
    );
    pad_lerp::<4>(
        large_c.as_flattened_mut(),
        flat(&large.color, y0),
        flat(&large.color, y1),
        fy,
    );
    let rows = [-2isize, -1, 0, 1, 2]
        .map(|dy| color.row((y as isize + dy).clamp(0, h as isize - 1) as usize));
    let row = RowRefs {
        rows,
        t,
        med_c,
        large_c,
        seg,
    };
    let w = out_row.len();
    for (q, out4) in out_row.chunks_mut(4).enumerate() {
        // Whole groups whose small-blur footprint (columns 4q - 2 ..= 4q + 5) lies inside the
        // row take the 16-lane form; the edges and a partial last group go pixel by pixel.
        if GROUPED && q > 0 && 4 * q + 6 <= w {
            let out4: &mut [MaybeUninit<Rgba>; 4] = out4.try_into().expect("a whole group");
            row.group(q, out4);
        } else {
            for (j, o) in out4.iter_mut().enumerate() {
                o.write(row.pixel(q, j));
            }
        }
    }
    bad
}

/// The blend amounts `t = max(near, s)` of a row, with the near CoC upsampled bilinearly from
/// the padded, vertically interpolated row `med_k` (pixel `4q + j` between padded texels
/// `q + UPSAMPLE_LEFT[j]` and the next).
#[inline(always)]
fn blend_amounts(t: &mut [f32], s: &[f32], med_k: &[f32]) {
    let near = |mk: &[f32], j: usize| {
        let (l, f) = (UPSAMPLE_LEFT[j], UPSAMPLE_FRACTION[j]);
        mk[l] + f * (mk[l + 1] - mk[l])
    };
    let mut groups = t.chunks_exact_mut(4).zip(s.chunks_exact(4));
    let mut q = 0;
    for (t4, s4) in &mut groups {
        let mk: &[f32; 3] = med_k[q..q + 3].try_into().expect("three padded texels");
        for j in 0..4 {
            t4[j] = max(near(mk, j), s4[j]);
        }
        q += 1;
    }
    let rest = s.len() / 4 * 4;
    for (j, (t, &s)) in t[rest..].iter_mut().zip(&s[rest..]).enumerate() {
        *t = max(near(&med_k[q..q + 3], j), s);
    }
}

/// One row's inputs: the five colour rows around it, its blend amounts, and the padded
/// quarter-res rows interpolated vertically at it.
struct RowRefs<'a> {
    rows: [&'a [Rgba]; 5],
    t: &'a [f32],
    med_c: &'a [Rgba],
    large_c: &'a [Rgba],
    seg: Segments,
}

impl RowRefs<'_> {
    /// Output pixel `4q + j`: the two levels of the segment of `t` blended, reading only those.
    #[inline(always)]
    fn pixel(&self, q: usize, j: usize) -> Rgba {
        let x = 4 * q + j;
        let unblurred = self.rows[2][x];
        let t = self.t[x];
        if t.is_nan() || t <= 0.0 {
            return unblurred;
        }
        let (l, f) = (UPSAMPLE_LEFT[j], UPSAMPLE_FRACTION[j]);
        let (mc, lc) = (&self.med_c[q..q + 3], &self.large_c[q..q + 3]);
        let small = || small_blur(&self.rows, x);
        let med = || lerp4(mc[l], mc[l + 1], f);
        let big = || lerp4(lc[l], lc[l + 1], f);
        let seg = self.seg;
        // The segment of t gives the two levels with non-zero weight.
        if t < seg.d0 {
            lerp4(unblurred, small(), t * seg.inv_d0)
        } else if t < seg.d01 {
            lerp4(small(), med(), (t - seg.d0) * seg.inv_d1)
        } else if t < 1.0 {
            lerp4(med(), big(), (t - seg.d01) * seg.inv_d2)
        } else {
            big()
        }
    }

    /// Output pixels `4q..4q + 4` (columns `4q - 2 ..= 4q + 5` inside the row) as 16 lanes:
    /// every level is computed for all four pixels and the segment's two are selected per lane,
    /// with the arithmetic of [`Self::pixel`] (same operations in the same order, so the same
    /// bits) but no branch per pixel. A group in focus throughout is copied.
    #[inline(always)]
    fn group(&self, q: usize, out: &mut [MaybeUninit<Rgba>; 4]) {
        let x = 4 * q;
        let unblurred: &[Rgba; 4] = self.rows[2][x..x + 4].try_into().expect("a whole group");
        let t4: &[f32; 4] = self.t[x..x + 4].try_into().expect("a whole group");
        if t4.iter().all(|t| t.is_nan() || *t <= 0.0) {
            for (o, &c) in out.iter_mut().zip(unblurred) {
                o.write(c);
            }
            return;
        }
        let u: [f32; 16] = lanes(unblurred);
        let seg = self.seg;
        // Beyond `d0 + d1` only medium and large have weight: where the whole group is there
        // (the near field, the far distance), the 17 loads of the small blur are skipped and
        // its lanes, never selected, hold the unblurred colour.
        let small = if t4.iter().any(|&t| t < seg.d01) {
            small_blur16(&self.rows, x)
        } else {
            u
        };
        let (med, big) = (upsample16(self.med_c, q), upsample16(self.large_c, q));
        let mut t = [0.0f32; 16];
        for (i, t) in t.iter_mut().enumerate() {
            *t = t4[i / 4];
        }
        let mut v = [0.0f32; 16];
        for i in 0..16 {
            let t = t[i];
            let (first, second) = (t < seg.d0, t < seg.d01);
            let lo = select(first, u[i], select(second, small[i], med[i]));
            let hi = select(first, small[i], select(second, med[i], big[i]));
            let f = select(
                first,
                t * seg.inv_d0,
                select(
                    second,
                    (t - seg.d0) * seg.inv_d1,
                    (t - seg.d01) * seg.inv_d2,
                ),
            );
            let blend = select(t < 1.0, lo + f * (hi - lo), big[i]);
            v[i] = select(t > 0.0, blend, u[i]);
        }
        for (o, c) in out.iter_mut().zip(v.chunks_exact(4)) {
            o.write(c.try_into().expect("four channels"));
        }
    }
}

/// `a` if `c`, else `b` (a select, no branch).
#[inline(always)]
fn select(c: bool, a: f32, b: f32) -> f32 {
    if c {
        a
    } else {
        b
    }
}

/// Four pixels as 16 lanes.
#[inline(always)]
fn lanes(p: &[Rgba; 4]) -> [f32; 16] {
    std::array::from_fn(|i| p[i / 4][i % 4])
}

/// The padded quarter-res row `c` upsampled to the four pixels of group `q` as 16 lanes.
#[inline(always)]
fn upsample16(c: &[Rgba], q: usize) -> [f32; 16] {
    let c: &[Rgba; 3] = c[q..q + 3].try_into().expect("a window of three texels");
    // Texels `UPSAMPLE_LEFT[j]` and the next for pixel j, written out: `array::map` here was
    // not inlined (composite 2.0 -> 3.0 ms).
    let [l0, l1, l2, l3] = UPSAMPLE_LEFT;
    let a = lanes(&[c[l0], c[l1], c[l2], c[l3]]);
    let b = lanes(&[c[l0 + 1], c[l1 + 1], c[l2 + 1], c[l3 + 1]]);
    let mut out = [0.0f32; 16];
    for (i, o) in out.iter_mut().enumerate() {
        *o = a[i] + UPSAMPLE_FRACTION[i / 4] * (b[i] - a[i]);
    }
    out
}

/// [`small_blur`] for the four pixels `x..x + 4` as 16 lanes (columns `x - 2 ..= x + 5` must
/// lie inside the rows): the same 17 pixels each, added in the same order.
#[inline(always)]
fn small_blur16(rows: &[&[Rgba]; 5], x: usize) -> [f32; 16] {
    // Columns x - 2 ..= x + 5 of each row: fixed windows, so the taps need no checks.
    let window =
        |r: usize| -> &[Rgba; 8] { rows[r][x - 2..x + 6].try_into().expect("inside the row") };
    let win = [window(0), window(1), window(2), window(3), window(4)];
    small_sum(|r, d| {
        let start = (d + 2) as usize;
        lanes(
            win[r][start..start + 4]
                .try_into()
                .expect("inside the window"),
        )
    })
}

/// Bilinear sample of `img` at (`u`, `v`) in texel units (texel i covers [i, i + 1)), clamped
/// to the edge as a GPU sampler with clamp addressing.
fn bilinear<const N: usize>(img: &crate::image::Image<[f32; N]>, u: f32, v: f32) -> [f32; N] {
    let (fu, fv) = (u - 0.5, v - 0.5);
    let (i0, j0) = (fu.floor(), fv.floor());
    let (ax, ay) = (fu - i0, fv - j0);
    let (i0, j0) = (i0 as isize, j0 as isize);
    let mut out = [0.0f32; N];
    for (dj, wy) in [(0, 1.0 - ay), (1, ay)] {
        for (di, wx) in [(0, 1.0 - ax), (1, ax)] {
            let p = img.get_clamped(i0 + di, j0 + dj);
            for (o, v) in out.iter_mut().zip(p) {
                *o += wx * wy * v;
            }
        }
    }
    out
}

/// The straightforward twin of [`composite`], written from Listing 28-4: four bilinear taps
/// for the small blur, bilinear medium and large samples, `dofLerpScale/Bias` rebuilt from d0,
/// d1, d2, and the frame-buffer blend `out = colour + (1 - alpha) unblurred` with
/// `alpha = 16/17 w_small + w_medium + w_large`. Kept to test the fast version against.
pub fn naive(
    color: &ColorImage,
    coc: &GrayImage,
    medium: &QuarterImage,
    large: &QuarterImage,
    k: &Constants,
) -> Result<ColorImage> {
    check_sizes(color, &Amounts::Signed(coc), medium, large, k)?;
    let (w, h) = (color.width(), color.height());
    let (scale, bias) = k.lerp_distances().scale_bias();
    let near_image = medium.coc.map(|v| [v]);
    let mut out = ColorImage::new(w, h, [0.0; 4]);
    for y in 0..h {
        for x in 0..w {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let mut small = [0.0f32; 4];
            for (ox, oy) in [(0.5, -1.5), (-1.5, -0.5), (-0.5, 1.5), (1.5, 0.5)] {
                let tap = bilinear(color, px + ox, py + oy);
                for (s, v) in small.iter_mut().zip(tap) {
                    *s += 4.0 / 17.0 * v;
                }
            }
            let (qu, qv) = (px / 4.0, py / 4.0);
            let med = bilinear(&medium.color, qu, qv);
            let big = bilinear(&large.color, qu, qv);
            let near = bilinear(&near_image, qu, qv)[0];
            let t = near.max(coc.get(x, y).max(0.0));
            let mut wt = [0.0f32; 4];
            for i in 0..4 {
                wt[i] = saturate(t * scale[i] + bias[i]);
            }
            let (wy, wz) = (wt[1].min(1.0 - wt[0]), wt[2].min(1.0 - wt[1]));
            let alpha = wy * 16.0 / 17.0 + wz + wt[3];
            let unblurred = color.get(x, y);
            let mut o = [0.0f32; 4];
            for c in 0..4 {
                o[c] = wy * small[c] + wz * med[c] + wt[3] * big[c] + (1.0 - alpha) * unblurred[c];
            }
            *out.get_mut(x, y) = o;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::SplitMix64;

    /// The 16-lane groups give the same bits as the pixel-by-pixel segment form, over blur
    /// amounts in every segment, at its boundaries, negative and NaN, and widths that leave
    /// partial and edge groups.
    #[test]
    fn groups_match_pixels_bit_for_bit() {
        let mut rng = SplitMix64::new(7);
        let seg = Segments::new(LerpDistances {
            d0: 0.1,
            d1: 0.25,
            d2: 0.65,
        });
        let special = [0.0, -0.0, 0.1, 0.35, 1.0, f32::NAN, -1.0, 2.0];
        for (w, h) in [(6, 5), (9, 7), (37, 11), (64, 9)] {
            let amount = |rng: &mut SplitMix64| {
                if rng.below(4) == 0 {
                    special[rng.below(special.len())]
                } else {
                    rng.range(-0.3, 1.2)
                }
            };
            let color: Vec<Rgba> = (0..w * h)
                .map(|_| std::array::from_fn(|_| rng.range(0.0, 4.0)))
                .collect();
            let s: Vec<f32> = (0..w * h).map(|_| amount(&mut rng)).collect();
            let (qw, qh) = quarter_size(w, h);
            let quarter = |rng: &mut SplitMix64| QuarterImage {
                color: ColorImage::from_vec(
                    qw,
                    qh,
                    (0..qw * qh)
                        .map(|_| std::array::from_fn(|_| rng.range(0.0, 4.0)))
                        .collect(),
                )
                .unwrap(),
                coc: GrayImage::from_vec(qw, qh, (0..qw * qh).map(|_| amount(rng)).collect())
                    .unwrap(),
            };
            let (medium, large) = (quarter(&mut rng), quarter(&mut rng));
            let color = ColorImage::from_vec(w, h, color).unwrap();
            let coc = GrayImage::from_vec(w, h, s).unwrap();
            let inputs = RowInputs {
                color: &color,
                amounts: Amounts::Signed(&coc),
                medium: &medium,
                large: &large,
                seg,
            };
            // SAFETY: `composite_row_inner` writes every pixel of its row.
            let (grouped, pixels) = unsafe {
                (
                    ColorImage::par_from_rows(
                        w,
                        h,
                        || row_scratch(w, qw),
                        |scratch, y, out| composite_row_inner::<true>(&inputs, scratch, y, out),
                    ),
                    ColorImage::par_from_rows(
                        w,
                        h,
                        || row_scratch(w, qw),
                        |scratch, y, out| composite_row_inner::<false>(&inputs, scratch, y, out),
                    ),
                )
            };
            let (grouped, pixels) = (grouped.unwrap().0, pixels.unwrap().0);
            for (i, (a, b)) in grouped.pixels().iter().zip(pixels.pixels()).enumerate() {
                let (x, y) = (i % w, i / w);
                assert_eq!(
                    a.map(f32::to_bits),
                    b.map(f32::to_bits),
                    "{w}x{h} at ({x}, {y})"
                );
            }
        }
    }
}
