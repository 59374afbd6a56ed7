//! Pass `downsample` (Listing 28-1, `DofDownsample`): full resolution to 1/4 per axis.
//!
//! Reads the full-resolution colour and the signed blur amounts of pass `coc`; writes the
//! "shrunk" quarter-resolution image: for each 4x4 block, the mean premultiplied RGBA of its
//! pixels (the listing's four bilinear taps, each the mean of 2x2 pixels) and the MAX of their
//! near blur amounts `max(-s, 0)` (the listing's 16 depth taps). Where the width or height is
//! not a multiple of 4 the last block is partial and averages the pixels it has.

use rayon::prelude::*;

use super::{quarter_size, QuarterImage};
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::{Error, Result};

/// Fails with [`Error::Mismatch`] unless `color` and `coc` have the same size.
fn check_sizes(color: &ColorImage, coc: &GrayImage) -> Result<()> {
    if color.same_size(coc) {
        crate::image::check_size(color.width(), color.height())
    } else {
        Err(Error::Mismatch(format!(
            "colour image is {}x{} but the CoC image is {}x{}",
            color.width(),
            color.height(),
            coc.width(),
            coc.height()
        )))
    }
}

/// The larger of `a` and `b` (`maxss`; the blur amounts are finite).
#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Downsamples `color` and the near part of the signed blur amounts `coc` to 1/4 per axis:
/// block mean of the colour, block maximum of the near blur.
pub fn downsample(color: &ColorImage, coc: &GrayImage) -> Result<QuarterImage> {
    downsample_with(color, coc, block_row)
}

/// [`downsample`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn downsample_baseline(color: &ColorImage, coc: &GrayImage) -> Result<QuarterImage> {
    downsample_with(color, coc, block_row_inner)
}

fn downsample_with(
    color: &ColorImage,
    coc: &GrayImage,
    row_fn: impl Fn(&ColorImage, &GrayImage, usize, &mut [Rgba], &mut [f32]) + Sync,
) -> Result<QuarterImage> {
    check_sizes(color, coc)?;
    let (w, h) = (color.width(), color.height());
    let (qw, qh) = quarter_size(w, h);
    let mut out_color = vec![[0.0f32; 4]; qw * qh];
    let mut out_coc = vec![0.0f32; qw * qh];
    out_color
        .par_chunks_mut(qw)
        .zip(out_coc.par_chunks_mut(qw))
        .enumerate()
        .for_each(|(qy, (oc, ok))| row_fn(color, coc, qy, oc, ok));
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
fn block_row(color: &ColorImage, coc: &GrayImage, qy: usize, oc: &mut [Rgba], ok: &mut [f32]) {
    block_row_inner(color, coc, qy, oc, ok);
}

#[inline(always)]
fn block_row_inner(
    color: &ColorImage,
    coc: &GrayImage,
    qy: usize,
    oc: &mut [Rgba],
    ok: &mut [f32],
) {
    let (w, h, qw) = (color.width(), color.height(), oc.len());
    let y0 = 4 * qy;
    let y1 = (y0 + 4).min(h);
    // Sums over the block's rows, block by block along the row: full blocks of 4 (a
    // fixed-length inner loop), then the partial block at the right edge.
    let full = w / 4;
    for y in y0..y1 {
        let (crow, krow) = (color.row(y), coc.row(y));
        let blocks = oc
            .iter_mut()
            .zip(ok.iter_mut())
            .zip(crow.chunks_exact(4).zip(krow.chunks_exact(4)));
        for ((acc, mx), (c4, k4)) in blocks {
            for (ch, a) in acc.iter_mut().enumerate() {
                *a += (c4[0][ch] + c4[1][ch]) + (c4[2][ch] + c4[3][ch]);
            }
            *mx = max(max(*mx, max(-k4[0], -k4[1])), max(-k4[2], -k4[3]));
        }
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
}

/// The straightforward twin of [`downsample`], written from Listing 28-1 texel by texel: for
/// each quarter-res texel, the mean colour and the maximum near blur of the pixels of its 4x4
/// block. Kept to test the fast version against.
pub fn naive(color: &ColorImage, coc: &GrayImage) -> Result<QuarterImage> {
    check_sizes(color, coc)?;
    let (w, h) = (color.width(), color.height());
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
