//! Pass `blur` (section 28.5.5, after Listing 28-1): the large Gaussian blur of the shrunk
//! image, colour and near blur amount together.
//!
//! Reads the quarter-resolution "shrunk" image of pass `downsample`; writes its Gaussian blur:
//! the "large blur" colour used by the composite, and the blurred near CoC `DB` used by pass
//! `near_coc`. The kernel is a truncated Gaussian ([`gaussian_kernel`]) whose standard deviation
//! the chapter specifies at 480p and scales to the real resolution
//! ([`super::HammonSettings::large_blur_sigma_quarter_px`]); borders clamp to edge.
//!
//! One pass per output row: the vertical filter sums the kernel-weighted input rows into a
//! padded scratch row, the horizontal filter then sums shifted copies of it. Both are
//! `out[j] = sum_i w[i] in_i[j]` over contiguous `f32`s, which is `lowrank`'s row filter
//! ([`filter_span`]): blocks of outputs kept in registers across all taps, 8 registers wide
//! for the instruction set chosen at run time. With blocks of 32 floats, two AVX-512
//! registers, each tap waited on the previous add (0.55 ms on the benchmark frame; 0.45 ms
//! with the shared filter's 128-float blocks, same sums in the same order, same bits).

use rayon::prelude::*;

use super::QuarterImage;
use crate::image::{ColorImage, GrayImage};
use crate::methods::lowrank::filter::{filter_span, filter_span_baseline};
use crate::{Error, Result};

/// Weights of a Gaussian of standard deviation `sigma` (in texels) at offsets `-r..=r`,
/// `r = ceil(3 sigma)`, normalised to sum 1. `sigma <= 0` gives the identity `[1]`.
pub fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    if sigma.is_nan() || sigma <= 0.0 {
        return vec![1.0];
    }
    let sigma = sigma as f64;
    let r = (3.0 * sigma).ceil() as i64;
    let w: Vec<f64> = (-r..=r)
        .map(|i| (-((i * i) as f64) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = w.iter().sum();
    w.iter().map(|v| (v / sum) as f32).collect()
}

/// Fails unless `kernel` has an odd length (offsets `-r..=r`).
fn check_kernel(kernel: &[f32]) -> Result<()> {
    if kernel.len() % 2 == 1 {
        Ok(())
    } else {
        Err(Error::invalid(
            "blur kernel",
            format!(
                "{} weights: expected an odd number (offsets -r..=r)",
                kernel.len()
            ),
        ))
    }
}

/// Blurs colour and near CoC of `shrunk` with the separable kernel `kernel` (odd length,
/// offsets `-r..=r`) along both axes, clamping to the edge.
pub fn blur(shrunk: &QuarterImage, kernel: &[f32]) -> Result<QuarterImage> {
    blur_with(shrunk, kernel, filter_span)
}

/// [`blur`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn blur_baseline(shrunk: &QuarterImage, kernel: &[f32]) -> Result<QuarterImage> {
    blur_with(shrunk, kernel, filter_span_baseline)
}

/// The quarter-res image and kernel of a blur, shared by its rows.
struct BlurRows<'a> {
    color: &'a [f32],
    coc: &'a [f32],
    width: usize,
    height: usize,
    kernel: &'a [f32],
}

/// One output row of [`blur`] and its scratch rows.
struct BlurRow<'a> {
    y: usize,
    pad_color: &'a mut [f32],
    pad_coc: &'a mut [f32],
    taps: &'a mut Vec<(f32, usize)>,
    out_color: &'a mut [f32],
    out_coc: &'a mut [f32],
}

/// A row filter `out[p] = sum_k w_k src[base_k + p]` over a list of `(w_k, base_k)`:
/// [`filter_span`] or its portable twin.
type Span = fn(&mut [f32], &[(f32, usize)], &[f32]);

fn blur_with(shrunk: &QuarterImage, kernel: &[f32], span: Span) -> Result<QuarterImage> {
    check_kernel(kernel)?;
    shrunk.check()?;
    let (w, h) = (shrunk.width(), shrunk.height());
    let r = kernel.len() / 2;
    let rows = BlurRows {
        color: shrunk.color.pixels().as_flattened(),
        coc: shrunk.coc.pixels(),
        width: w,
        height: h,
        kernel,
    };
    let mut out_color = vec![[0.0f32; 4]; w * h];
    let mut out_coc = vec![0.0f32; w * h];
    out_color
        .par_chunks_mut(w)
        .zip(out_coc.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || {
                (
                    vec![0.0f32; 4 * (w + 2 * r)],
                    vec![0.0f32; w + 2 * r],
                    Vec::with_capacity(kernel.len()),
                )
            },
            |(pad_color, pad_coc, taps), (y, (out_c, out_k))| {
                blur_row(
                    &rows,
                    BlurRow {
                        y,
                        pad_color,
                        pad_coc,
                        taps,
                        out_color: out_c.as_flattened_mut(),
                        out_coc: out_k,
                    },
                    span,
                );
            },
        );
    Ok(QuarterImage {
        color: ColorImage::from_vec(w, h, out_color)?,
        coc: GrayImage::from_vec(w, h, out_coc)?,
    })
}

/// One row of [`blur`]: the vertical pass into the padded scratch rows, then the horizontal
/// pass into the output, each a row filter `span` over the kernel's taps.
fn blur_row(rows: &BlurRows, row: BlurRow, span: Span) {
    let BlurRows {
        color,
        coc,
        width: w,
        height: h,
        kernel,
    } = *rows;
    let BlurRow {
        y,
        pad_color,
        pad_coc,
        taps,
        out_color,
        out_coc,
    } = row;
    let r = kernel.len() / 2;
    let src_row = |i: usize| (y + i).saturating_sub(r).min(h - 1);
    let mut filter = |out: &mut [f32], src: &[f32], base: &dyn Fn(usize) -> usize| {
        taps.clear();
        taps.extend(kernel.iter().enumerate().map(|(i, &k)| (k, base(i))));
        span(out, taps, src);
    };
    filter(&mut pad_color[4 * r..4 * (r + w)], color, &|i| {
        4 * w * src_row(i)
    });
    filter(&mut pad_coc[r..r + w], coc, &|i| w * src_row(i));
    for j in 0..r {
        pad_color.copy_within(4 * r..4 * r + 4, 4 * j);
        pad_color.copy_within(4 * (r + w - 1)..4 * (r + w), 4 * (r + w + j));
        pad_coc[j] = pad_coc[r];
        pad_coc[r + w + j] = pad_coc[r + w - 1];
    }
    filter(out_color, pad_color, &|i| 4 * i);
    filter(out_coc, pad_coc, &|i| i);
}

/// The straightforward twin of [`blur`]: the 2D sum `sum_i sum_j k[i] k[j] in(x + j - r,
/// y + i - r)` with clamped coordinates, texel by texel. Kept to test the fast version against.
pub fn naive(shrunk: &QuarterImage, kernel: &[f32]) -> Result<QuarterImage> {
    check_kernel(kernel)?;
    shrunk.check()?;
    let (w, h) = (shrunk.width(), shrunk.height());
    let r = (kernel.len() / 2) as isize;
    let mut color = ColorImage::new(w, h, [0.0; 4]);
    let mut coc = GrayImage::new(w, h, 0.0);
    for y in 0..h as isize {
        for x in 0..w as isize {
            let mut sum_c = [0.0f32; 4];
            let mut sum_k = 0.0f32;
            for (i, &wy) in kernel.iter().enumerate() {
                for (j, &wx) in kernel.iter().enumerate() {
                    let (sx, sy) = (x + j as isize - r, y + i as isize - r);
                    let wt = wy * wx;
                    for (a, v) in sum_c.iter_mut().zip(shrunk.color.get_clamped(sx, sy)) {
                        *a += wt * v;
                    }
                    sum_k += wt * shrunk.coc.get_clamped(sx, sy);
                }
            }
            *color.get_mut(x as usize, y as usize) = sum_c;
            *coc.get_mut(x as usize, y as usize) = sum_k;
        }
    }
    Ok(QuarterImage { color, coc })
}
