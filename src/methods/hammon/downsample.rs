//! Pass `downsample` (Listing 28-1, `DofDownsample`): full resolution to 1/4 per axis.
//!
//! Reads the full-resolution colour and the signed blur amounts `s`, either from depth (the
//! render: computed row by row with [`super::coc`]'s function, as the listing does) or from an
//! image of them; writes the "shrunk" quarter-resolution image: for each 4x4 block, the mean
//! premultiplied RGBA of its pixels (the listing's four bilinear taps, each the mean of 2x2
//! pixels) and the MAX of their near blur amounts `max(-s, 0)` (the listing's 16 depth taps).
//! Where the width or height is not a multiple of 4 the last block is partial and averages the
//! pixels it has.

use rayon::prelude::*;

use super::coc::Amounts;
use super::{quarter_size, QuarterImage};
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::Result;

/// The larger of `a` and `b` (`maxss`; the blur amounts are finite).
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Downsamples `color` and the near part of the signed blur amounts to 1/4 per axis: block
/// mean of the colour, block maximum of the near blur. The amounts are an image of `s` (pass
/// [`super::coc`]) or computed here from depth ([`Amounts::Depth`]), which fails as
/// [`super::coc::coc`] does on bad depth.
pub fn downsample<'a>(color: &ColorImage, amounts: impl Into<Amounts<'a>>) -> Result<QuarterImage> {
    downsample_with(color, amounts.into(), block_row)
}

/// [`downsample`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn downsample_baseline<'a>(
    color: &ColorImage,
    amounts: impl Into<Amounts<'a>>,
) -> Result<QuarterImage> {
    downsample_with(color, amounts.into(), block_row_inner)
}

/// Scratch per worker, in rows of `w` floats: the block's amounts (4 rows), its column sums of
/// colour (4 floats a pixel), its column maxima of near blur (1) and the block sums (4).
const SCRATCH_ROWS: usize = 4 + 4 + 1 + 4;

/// One quarter-res row of the downsample: [`block_row`] or its portable twin.
type BlockRowFn = fn(&ColorImage, &Amounts, &mut [f32], usize, &mut [Rgba], &mut [f32]) -> bool;

fn downsample_with(
    color: &ColorImage,
    amounts: Amounts,
    row_fn: BlockRowFn,
) -> Result<QuarterImage> {
    let (w, h) = (color.width(), color.height());
    crate::image::check_size(w, h)?;
    amounts.check_size("colour image", w, h)?;
    let (qw, qh) = quarter_size(w, h);
    let mut out_color = vec![[0.0f32; 4]; qw * qh];
    let mut out_coc = vec![0.0f32; qw * qh];
    let bad = out_color
        .par_chunks_mut(qw)
        .zip(out_coc.par_chunks_mut(qw))
        .enumerate()
        .map_init(
            || vec![0.0f32; SCRATCH_ROWS * w],
            |scratch, (qy, (oc, ok))| row_fn(color, &amounts, scratch, qy, oc, ok),
        )
        .reduce(|| false, |a, b| a | b);
    if bad {
        return Err(amounts.error());
    }
    Ok(QuarterImage {
        color: ColorImage::from_vec(qw, qh, out_color)?,
        coc: GrayImage::from_vec(qw, qh, out_coc)?,
    })
}

/// One quarter-res row `qy` of [`downsample`]. Compiled for several instruction sets and
/// chosen at run time ([`multiversion`]); the same arithmetic in every version, so the same
/// bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn block_row(
    color: &ColorImage,
    amounts: &Amounts,
    scratch: &mut [f32],
    qy: usize,
    oc: &mut [Rgba],
    ok: &mut [f32],
) -> bool {
    block_row_inner(color, amounts, scratch, qy, oc, ok)
}

/// One quarter-res row `qy`: its block rows' amounts (from `scratch` when computed from depth),
/// then the sums. Returns true if some depth was bad.
#[inline(always)]
fn block_row_inner(
    color: &ColorImage,
    amounts: &Amounts,
    scratch: &mut [f32],
    qy: usize,
    oc: &mut [Rgba],
    ok: &mut [f32],
) -> bool {
    let (w, h, qw) = (color.width(), color.height(), oc.len());
    let y0 = 4 * qy;
    let y1 = (y0 + 4).min(h);
    let (s_scratch, rest) = scratch.split_at_mut(4 * w);
    let (vsum, rest) = rest.split_at_mut(4 * w);
    let (vmax, rest) = rest.split_at_mut(w);
    let (s, bad) = amounts.rows(y0, y1, s_scratch);
    let n = y1 - y0;
    let crows: [&[f32]; 4] = std::array::from_fn(|r| color.row(y0 + r.min(n - 1)).as_flattened());
    let krows: [&[f32]; 4] = std::array::from_fn(|r| &s[w * r.min(n - 1)..w * (r.min(n - 1) + 1)]);
    // Full blocks, in two steps over contiguous floats that the compiler vectorises: the
    // block's rows summed per column (and the near maximum taken), then, for every float `i`
    // of that row of sums, the four pixels starting there, `(v[i] + v[i + 4]) + (v[i + 8] +
    // v[i + 12])`, of which block `b` reads position `16b`. Summed block by block, the
    // compiler vectorised across blocks with a gather per channel and pixel, and the blocks'
    // sums computed row by row took more loads.
    let full = w / 4;
    let (vsum, hsum) = (&mut vsum[..16 * full], &mut rest[..16 * full]);
    let vmax = &mut vmax[..4 * full];
    if n == 4 {
        for (i, v) in vsum.iter_mut().enumerate() {
            *v = ((crows[0][i] + crows[1][i]) + crows[2][i]) + crows[3][i];
        }
        for (i, m) in vmax.iter_mut().enumerate() {
            *m = max(
                max(-krows[0][i], -krows[1][i]),
                max(-krows[2][i], -krows[3][i]),
            );
        }
    } else {
        vsum.copy_from_slice(&crows[0][..16 * full]);
        for (m, &k) in vmax.iter_mut().zip(krows[0]) {
            *m = -k;
        }
        for r in 1..n {
            for (v, &c) in vsum.iter_mut().zip(crows[r]) {
                *v += c;
            }
            for (m, &k) in vmax.iter_mut().zip(krows[r]) {
                *m = max(*m, -k);
            }
        }
    }
    let last = hsum.len().saturating_sub(12);
    for (i, o) in hsum[..last].iter_mut().enumerate() {
        *o = (vsum[i] + vsum[i + 4]) + (vsum[i + 8] + vsum[i + 12]);
    }
    for (b, (o, m)) in oc.iter_mut().zip(ok.iter_mut()).take(full).enumerate() {
        *o = hsum[16 * b..16 * b + 4].try_into().expect("four channels");
        let k = &vmax[4 * b..4 * b + 4];
        *m = max(max(0.0, max(k[0], k[1])), max(k[2], k[3]));
    }
    // The partial block at the right edge, pixel by pixel.
    for (y, krow) in (y0..y1).zip(s.chunks_exact(w)) {
        let crow = color.row(y);
        if full < qw {
            for (p, &s) in crow[4 * full..].iter().zip(&krow[4 * full..]) {
                for (a, v) in oc[full].iter_mut().zip(p) {
                    *a += v;
                }
                ok[full] = max(ok[full], -s);
            }
        }
    }
    let rows = (y1 - y0) as f32;
    for (qx, acc) in oc.iter_mut().enumerate() {
        let cols = ((4 * qx + 4).min(w) - 4 * qx) as f32;
        let inv = 1.0 / (rows * cols);
        for v in acc.iter_mut() {
            *v *= inv;
        }
    }
    bad
}

/// The straightforward twin of [`downsample`], written from Listing 28-1 texel by texel: for
/// each quarter-res texel, the mean colour and the maximum near blur of the pixels of its 4x4
/// block. Kept to test the fast version against.
pub fn naive(color: &ColorImage, coc: &GrayImage) -> Result<QuarterImage> {
    let (w, h) = (color.width(), color.height());
    crate::image::check_size(w, h)?;
    Amounts::Signed(coc).check_size("colour image", w, h)?;
    let (qw, qh) = quarter_size(w, h);
    let mut out_color = ColorImage::new(qw, qh, [0.0; 4]);
    let mut out_coc = GrayImage::new(qw, qh, 0.0);
    for qy in 0..qh {
        for qx in 0..qw {
            let mut sum = [0.0f32; 4];
            let mut near_max = 0.0f32;
            let mut n = 0;
            for y in 4 * qy..(4 * qy + 4).min(h) {
                for x in 4 * qx..(4 * qx + 4).min(w) {
                    for (a, v) in sum.iter_mut().zip(color.get(x, y)) {
                        *a += v;
                    }
                    near_max = near_max.max(-coc.get(x, y));
                    n += 1;
                }
            }
            *out_color.get_mut(qx, qy) = sum.map(|v| v / n as f32);
            *out_coc.get_mut(qx, qy) = near_max;
        }
    }
    Ok(QuarterImage {
        color: out_color,
        coc: out_coc,
    })
}
