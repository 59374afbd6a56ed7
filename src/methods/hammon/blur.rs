//! Pass `blur` (section 28.5.5, after Listing 28-1): the large Gaussian blur of the shrunk
//! image, colour and near blur amount together.
//!
//! Reads the quarter-resolution "shrunk" image of pass `downsample`; writes its Gaussian blur:
//! the "large blur" colour used by the composite, and the blurred near CoC `DB` used by pass
//! `near_coc`. The kernel is a truncated Gaussian ([`gaussian_kernel`]) whose standard deviation
//! the chapter specifies at 480p and scales to the real resolution
//! ([`super::HammonSettings::large_blur_sigma_quarter_px`]); borders clamp to edge.
//!
//! One pass per pair of output rows: the vertical filter sums the kernel-weighted input rows
//! into padded scratch rows, the horizontal filter then sums shifted copies of each. Both are
//! `out[j] = sum_i w[i] in_i[j]` over contiguous `f32`s with blocks of outputs kept in
//! registers across all taps, 8 registers wide for the instruction set chosen at run time. The
//! horizontal filter is `lowrank`'s row filter, unfused ([`filter_span_unfused`]: the same bits
//! on every machine). The vertical one runs two
//! adjacent rows at once (`vertical_pair`): they share all but one of their source rows, so
//! each is loaded once for both. On the benchmark frame: 0.55 ms with one row at a time and
//! blocks of two AVX-512 registers (each tap's add waited on the previous one), 0.45 ms with
//! the shared filter's 128-float blocks, 0.37 ms in row pairs. The sums are the same in the
//! same order throughout, so the bits are too (unit test
//! `row_pairs_match_single_rows_bit_for_bit`). `lowrank`'s general
//! [`crate::methods::lowrank::filter::filter_rows`], which takes up to eight rows and skips
//! zero taps, was 10-20% slower here on two rows than this pair filter, so the blur keeps it.

use rayon::prelude::*;

use super::QuarterImage;
use crate::image::{ColorImage, GrayImage};
use crate::methods::lowrank::filter::{filter_span_unfused, filter_span_unfused_baseline};
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

/// [`blur`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn blur_baseline(shrunk: &QuarterImage, kernel: &[f32]) -> Result<QuarterImage> {
    blur_with(
        shrunk,
        kernel,
        Filters {
            span: filter_span_unfused_baseline,
            pair: vertical_pair_baseline,
        },
    )
}

/// A row filter `out[p] = sum_k w_k src[base_k + p]` over a list of `(w_k, base_k)`:
/// [`filter_span_unfused`] or its portable twin.
type Span = fn(&mut [f32], &[(f32, usize)], &[f32]);

/// The vertical filter of two adjacent rows at once ([`vertical_pair`] or its portable twin).
type Pair = fn(&mut [f32], &mut [f32], &[f32], &[usize], &[f32]);

/// The row filters a blur runs with.
#[derive(Clone, Copy)]
struct Filters {
    span: Span,
    pair: Pair,
}

/// Blurs colour and near CoC of `shrunk` with the separable kernel `kernel` (odd length,
/// offsets `-r..=r`) along both axes, clamping to the edge.
pub fn blur(shrunk: &QuarterImage, kernel: &[f32]) -> Result<QuarterImage> {
    blur_with(
        shrunk,
        kernel,
        Filters {
            span: filter_span_unfused,
            pair: vertical_pair,
        },
    )
}

/// Per-thread scratch: two padded vertical sums (colour and near CoC) and a tap list.
type Scratch = ([Vec<f32>; 2], [Vec<f32>; 2], Vec<(f32, usize)>, Vec<usize>);

fn blur_with(shrunk: &QuarterImage, kernel: &[f32], filters: Filters) -> Result<QuarterImage> {
    check_kernel(kernel)?;
    shrunk.check()?;
    let (w, h) = (shrunk.width(), shrunk.height());
    let r = kernel.len() / 2;
    let (color, coc) = (shrunk.color.pixels().as_flattened(), shrunk.coc.pixels());
    let mut out_color = vec![[0.0f32; 4]; w * h];
    let mut out_coc = vec![0.0f32; w * h];
    // Rows in pairs: the vertical filter of two adjacent rows reads each source row once.
    out_color
        .as_flattened_mut()
        .par_chunks_mut(2 * 4 * w)
        .zip(out_coc.par_chunks_mut(2 * w))
        .enumerate()
        .for_each_init(
            || -> Scratch {
                (
                    [0, 1].map(|_| vec![0.0f32; 4 * (w + 2 * r)]),
                    [0, 1].map(|_| vec![0.0f32; w + 2 * r]),
                    Vec::with_capacity(kernel.len()),
                    Vec::with_capacity(kernel.len() + 1),
                )
            },
            |(pad_color, pad_coc, taps, bases), (pair, (out_c, out_k))| {
                let y = 2 * pair;
                let n = out_k.len() / w;
                // The source rows of output rows y (the first 2r + 1) and y + 1 (the last).
                let src_row = |i: usize| (y + i).saturating_sub(r).min(h - 1);
                let [pc0, pc1] = pad_color;
                let [pk0, pk1] = pad_coc;
                let (c0, c1) = (&mut pc0[4 * r..4 * (r + w)], &mut pc1[4 * r..4 * (r + w)]);
                let (k0, k1) = (&mut pk0[r..r + w], &mut pk1[r..r + w]);
                if n == 2 {
                    bases.clear();
                    bases.extend((0..=kernel.len()).map(|i| 4 * w * src_row(i)));
                    (filters.pair)(c0, c1, kernel, bases, color);
                    bases.clear();
                    bases.extend((0..=kernel.len()).map(|i| w * src_row(i)));
                    (filters.pair)(k0, k1, kernel, bases, coc);
                } else {
                    taps.clear();
                    taps.extend(
                        kernel
                            .iter()
                            .enumerate()
                            .map(|(i, &k)| (k, 4 * w * src_row(i))),
                    );
                    (filters.span)(c0, taps, color);
                    taps.clear();
                    taps.extend(kernel.iter().enumerate().map(|(i, &k)| (k, w * src_row(i))));
                    (filters.span)(k0, taps, coc);
                }
                let rows = out_c.chunks_exact_mut(4 * w).zip(out_k.chunks_exact_mut(w));
                for ((out_c, out_k), (pc, pk)) in
                    rows.zip(pad_color.iter_mut().zip(pad_coc.iter_mut()))
                {
                    horizontal(out_c, out_k, pc, pk, kernel, taps, filters.span);
                }
            },
        );
    Ok(QuarterImage {
        color: ColorImage::from_vec(w, h, out_color)?,
        coc: GrayImage::from_vec(w, h, out_coc)?,
    })
}

/// The horizontal pass of one row: pads the vertical sums `pad_color` and `pad_coc` (`r`
/// texels each side, clamp to edge), then filters them into the output row.
fn horizontal(
    out_color: &mut [f32],
    out_coc: &mut [f32],
    pad_color: &mut [f32],
    pad_coc: &mut [f32],
    kernel: &[f32],
    taps: &mut Vec<(f32, usize)>,
    span: Span,
) {
    let (r, w) = (kernel.len() / 2, out_coc.len());
    for j in 0..r {
        pad_color.copy_within(4 * r..4 * r + 4, 4 * j);
        pad_color.copy_within(4 * (r + w - 1)..4 * (r + w), 4 * (r + w + j));
        pad_coc[j] = pad_coc[r];
        pad_coc[r + w + j] = pad_coc[r + w - 1];
    }
    taps.clear();
    taps.extend(kernel.iter().enumerate().map(|(i, &k)| (k, 4 * i)));
    span(out_color, taps, pad_color);
    taps.clear();
    taps.extend(kernel.iter().enumerate().map(|(i, &k)| (k, i)));
    span(out_coc, taps, pad_coc);
}

/// The vertical filter of two adjacent output rows: with `n = kernel.len()` and `base` the
/// offsets of `n + 1` source rows, `a[p] = sum_{i < n} kernel[i] src[base[i] + p]` and
/// `b[p] = sum_{i < n} kernel[i] src[base[i + 1] + p]`, each summed in the order of `i` (as
/// [`filter_span_unfused`] does, so the same bits). Each source row is loaded once for both. Compiled
/// for several instruction sets and chosen at run time ([`multiversion`]): blocks of 8
/// registers for the two rows together.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn vertical_pair(a: &mut [f32], b: &mut [f32], kernel: &[f32], base: &[usize], src: &[f32]) {
    const AVX512: bool = multiversion::target::selected_target!().supports_feature_str("avx512f");
    const AVX2: bool = multiversion::target::selected_target!().supports_feature_str("avx2");
    if AVX512 {
        pair_span::<64>(a, b, kernel, base, src);
    } else if AVX2 {
        pair_span::<32>(a, b, kernel, base, src);
    } else {
        pair_span::<16>(a, b, kernel, base, src);
    }
}

/// [`vertical_pair`] as the portable baseline build only: its twin.
fn vertical_pair_baseline(
    a: &mut [f32],
    b: &mut [f32],
    kernel: &[f32],
    base: &[usize],
    src: &[f32],
) {
    pair_span::<16>(a, b, kernel, base, src);
}

#[inline(always)]
fn pair_span<const L: usize>(
    a: &mut [f32],
    b: &mut [f32],
    kernel: &[f32],
    base: &[usize],
    src: &[f32],
) {
    let mut p = 0;
    while p + L <= a.len() {
        pair_block::<L>(a, b, p, kernel, base, src);
        p += L;
    }
    while p + 4 <= a.len() {
        pair_block::<4>(a, b, p, kernel, base, src);
        p += 4;
    }
    while p < a.len() {
        pair_block::<1>(a, b, p, kernel, base, src);
        p += 1;
    }
}

/// One block of `L` floats of [`vertical_pair`] at `p`, both rows' sums kept in registers.
#[inline(always)]
fn pair_block<const L: usize>(
    a: &mut [f32],
    b: &mut [f32],
    p: usize,
    kernel: &[f32],
    base: &[usize],
    src: &[f32],
) {
    let n = kernel.len();
    let (Some(oa), Some(ob)) = (
        a.get_mut(p..).and_then(|o| o.first_chunk_mut::<L>()),
        b.get_mut(p..).and_then(|o| o.first_chunk_mut::<L>()),
    ) else {
        return;
    };
    let row = |i: usize| src.get(base[i] + p..).and_then(|s| s.first_chunk::<L>());
    let (mut acc_a, mut acc_b) = ([0.0f32; L], [0.0f32; L]);
    if let Some(x) = row(0) {
        for t in 0..L {
            acc_a[t] += kernel[0] * x[t];
        }
    }
    for i in 1..n {
        if let Some(x) = row(i) {
            let (wa, wb) = (kernel[i], kernel[i - 1]);
            for t in 0..L {
                acc_a[t] += wa * x[t];
                acc_b[t] += wb * x[t];
            }
        }
    }
    if let Some(x) = row(n) {
        for t in 0..L {
            acc_b[t] += kernel[n - 1] * x[t];
        }
    }
    *oa = acc_a;
    *ob = acc_b;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::SplitMix64;

    /// Each row of a pair gets the bits of the single-row filter over its own source rows,
    /// for widths with whole blocks, partial blocks and single floats left over.
    #[test]
    fn row_pairs_match_single_rows_bit_for_bit() {
        let mut rng = SplitMix64::new(3);
        for (len, taps) in [(1, 1), (5, 3), (37, 7), (200, 25), (333, 13)] {
            let rows = taps + 1;
            let src: Vec<f32> = (0..len * rows).map(|_| rng.range(-2.0, 5.0)).collect();
            let kernel: Vec<f32> = (0..taps).map(|_| rng.range(0.0, 1.0)).collect();
            // Source rows in a shuffled order, as clamped rows repeat at the image's edges.
            let base: Vec<usize> = (0..rows).map(|_| len * rng.below(rows)).collect();
            for pair in [vertical_pair as Pair, vertical_pair_baseline] {
                let (mut a, mut b) = (vec![0.0f32; len], vec![0.0f32; len]);
                pair(&mut a, &mut b, &kernel, &base, &src);
                for (out, first) in [(&a, 0), (&b, 1)] {
                    let list: Vec<(f32, usize)> = kernel
                        .iter()
                        .zip(&base[first..])
                        .map(|(&k, &o)| (k, o))
                        .collect();
                    let mut single = vec![0.0f32; len];
                    filter_span_unfused_baseline(&mut single, &list, &src);
                    assert_eq!(
                        out.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        single.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        "{len} floats, {taps} taps, row {first}"
                    );
                }
            }
        }
    }
}
