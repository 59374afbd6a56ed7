//! Spatially invariant filtering: the low-rank separable filter of fig. 2 (eq. 1) and the full 2D
//! convolution it approximates (McGraw section 3, fig. 2, fig. 4).
//!
//! Both compute the convolution `out(p) = sum_d k(c + d) img(p - d)`, `c = (width / 2,
//! height / 2)` the kernel centre (the middle pixel of an odd kernel), with clamp-to-edge
//! borders: a single bright pixel far from the borders comes out as the kernel itself, upright.
//!
//! [`filter_separable_fig2`] follows fig. 2: for each rank `i`, a horizontal pass with `v'_i`
//! writes the intermediate image `U_i`; a vertical pass with `u'_i` over every `U_i` accumulates
//! straight into the output (the `V_i` are never stored). (The paper's fig. 2 text names the
//! horizontal vector `u'`; with its eq. 1, `u` a column and `v` a row, it is the same filter with
//! the names swapped. We follow eq. 1.) [`filter_separable`], the default, computes the same sum
//! band by band ([`Schedule::Banded`]): for each band of output rows and each rank, the vertical
//! pass filters the band's source rows into a scratch band, and the horizontal pass filters that
//! into the output band, all in cache. The two passes of a rank commute, so both schedules
//! compute eq. 1 and differ by rounding only; the banded one stores no intermediate image.
//!
//! All passes and the 2D convolution work on rows of contiguous floats ([`filter_span`]): a
//! block of output floats sums all its taps in registers (each tap a shifted run of a padded
//! row for the horizontal taps, of a source row for the vertical taps), which the compiler
//! vectorises; the vertical pass needs no transpose. (A first version applied each tap to a
//! whole row, `acc[..] += w * src[..]`: three memory operations per four products made it
//! load/store bound, rank 3 at 65 px took 345 ms at 1280x720.) Vertical passes walk column
//! strips of [`STRIP_PX`] pixels, so the source rows of a strip stay in L2 from one group of
//! output rows to the next (without strips, rank 3 at 65 px streamed 195 rows of 20 KB from L3
//! for each output row and was only 2.5x faster than the 2D convolution). They take eight
//! adjacent output rows at once ([`filter_rows`]): those share all but seven of their source
//! rows, so each source row is loaded once for all eight, and prefetched two blocks ahead.
//! Bands (or blocks of [`ROW_BLOCK`] rows) run in parallel; the output does not depend on the
//! thread count.
//! [`filter_separable_naive`] and [`filter_full_2d_naive`] are the per-pixel twins, written
//! from the equations in f64.

use std::mem::MaybeUninit;

use rayon::prelude::*;

use super::svd::LowRank;
use crate::image::{ColorImage, GrayImage, Rgba};

/// Floats per register block of [`filter_span`] (8 RGBA pixels).
pub const LANES: usize = 32;

/// Floats per block where the vector registers are 8 floats wide (AVX2): 16 RGBA pixels in 8
/// of its 16 registers.
pub const WIDE_LANES: usize = 64;

/// Floats per block with AVX-512: 8 of its 32 registers of 16 floats. Each tap costs the same
/// loop overhead (its weight and offset, a range check, a broadcast) whatever the block, so
/// the wider block spends more of the loop on products (the 64-float block ran at a speed
/// that moved by a third with the loop's alignment in the binary: bound by the front end).
pub const WIDEST_LANES: usize = 128;

/// `out[p] = sum_k w_k * src[base_k + p]` for every `p` of `out`, with `taps` the list of
/// `(w_k, base_k)`. The sum for a block of [`LANES`] floats (then of 4, then single floats at
/// the end) is kept in registers over all taps and stored once, so the loop is bound by loads
/// of `src` rather than by stores. Taps whose source would run past `src` are skipped (callers
/// never produce them).
///
/// Compiled for several instruction sets and chosen at run time ([`multiversion`]): AVX-512 and
/// AVX2 on x86-64 (16 and 8 floats per register instead of SSE2's 4), NEON on aarch64, the
/// portable baseline elsewhere. Every version does the same products and sums in the same
/// order; the x86-64 versions with FMA and every aarch64 build fuse each product with its sum
/// (one rounding instead of two: [`fuses_multiply_adds`]), the others do not. So two machines
/// give the same bits where they agree on that, and otherwise differ by about a rounding per
/// tap. (Fusing took `dof_uniform/hex65` from 24.6 to 22.1 ms.)
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "aarch64+neon"
))]
pub fn filter_span(out: &mut [f32], taps: &[(f32, usize)], src: &[f32]) {
    // Evaluated at compile time for each version.
    const AVX512: bool = multiversion::target::selected_target!().supports_feature_str("avx512f");
    const AVX2: bool = multiversion::target::selected_target!().supports_feature_str("avx2");
    const FUSED: bool = fused(multiversion::target::selected_target!().supports_feature_str("fma"));
    span_for::<false, FUSED>((AVX512, AVX2), out, taps, src);
}

/// [`filter_span`] adding to `out` instead of overwriting it.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "aarch64+neon"
))]
pub fn filter_span_add(out: &mut [f32], taps: &[(f32, usize)], src: &[f32]) {
    // Evaluated at compile time for each version.
    const AVX512: bool = multiversion::target::selected_target!().supports_feature_str("avx512f");
    const AVX2: bool = multiversion::target::selected_target!().supports_feature_str("avx2");
    const FUSED: bool = fused(multiversion::target::selected_target!().supports_feature_str("fma"));
    span_for::<true, FUSED>((AVX512, AVX2), out, taps, src);
}

/// [`filter_span`] with a product then a sum per tap (never fused) in every version: the same
/// bits on every machine, for callers that promise them (`hammon`'s blur, whose vertical
/// filter does not fuse either).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
pub fn filter_span_unfused(out: &mut [f32], taps: &[(f32, usize)], src: &[f32]) {
    const AVX512: bool = multiversion::target::selected_target!().supports_feature_str("avx512f");
    const AVX2: bool = multiversion::target::selected_target!().supports_feature_str("avx2");
    span_for::<false, false>((AVX512, AVX2), out, taps, src);
}

/// [`filter_span_unfused`] as the portable baseline build only: its twin.
pub fn filter_span_unfused_baseline(out: &mut [f32], taps: &[(f32, usize)], src: &[f32]) {
    span::<false, LANES, false>(out, taps, src);
}

/// [`filter_span`] as the portable baseline build only (no run-time dispatch): the twin the
/// dispatched versions are tested against.
pub fn filter_span_baseline(out: &mut [f32], taps: &[(f32, usize)], src: &[f32]) {
    span::<false, LANES, BASELINE_FUSED>(out, taps, src);
}

/// Whether a build whose target has (`fma`) the x86 fused multiply-add sums its products with
/// it: there, and on aarch64, where every build has it.
const fn fused(fma: bool) -> bool {
    fma || cfg!(target_arch = "aarch64")
}

/// Whether the portable baseline build fuses its multiply-adds.
const BASELINE_FUSED: bool = fused(cfg!(target_feature = "fma"));

/// Whether the version of the filters this machine runs (chosen at run time, as for
/// [`filter_span`]) sums its products with fused multiply-adds. The filters give the same bits
/// on any two machines that agree on this (and differ by a rounding per tap otherwise).
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "aarch64+neon"
))]
pub fn fuses_multiply_adds() -> bool {
    fused(multiversion::target::selected_target!().supports_feature_str("fma"))
}

/// `acc + w x`: one fused multiply-add (one rounding) where `FUSED`, a product then a sum
/// otherwise.
#[inline(always)]
fn madd<const FUSED: bool>(acc: f32, w: f32, x: f32) -> f32 {
    if FUSED {
        w.mul_add(x, acc)
    } else {
        acc + w * x
    }
}

/// [`span`] in blocks as wide as the instruction set of the version calling it allows
/// (`(avx512, avx2)`, constants of that version, so only one branch is compiled into it).
#[inline(always)]
fn span_for<const ADD: bool, const FUSED: bool>(
    (avx512, avx2): (bool, bool),
    out: &mut [f32],
    taps: &[(f32, usize)],
    src: &[f32],
) {
    if avx512 {
        span::<ADD, WIDEST_LANES, FUSED>(out, taps, src);
    } else if avx2 {
        span::<ADD, WIDE_LANES, FUSED>(out, taps, src);
    } else {
        span::<ADD, LANES, FUSED>(out, taps, src);
    }
}

#[inline(always)]
fn span<const ADD: bool, const W: usize, const FUSED: bool>(
    out: &mut [f32],
    taps: &[(f32, usize)],
    src: &[f32],
) {
    let mut p = 0;
    while p + W <= out.len() {
        block::<W, ADD, FUSED>(out, p, taps, src);
        p += W;
    }
    while p + WIDE_LANES <= out.len() && W > WIDE_LANES {
        block::<WIDE_LANES, ADD, FUSED>(out, p, taps, src);
        p += WIDE_LANES;
    }
    while p + LANES <= out.len() {
        block::<LANES, ADD, FUSED>(out, p, taps, src);
        p += LANES;
    }
    while p + 4 <= out.len() {
        block::<4, ADD, FUSED>(out, p, taps, src);
        p += 4;
    }
    while p < out.len() {
        block::<1, ADD, FUSED>(out, p, taps, src);
        p += 1;
    }
}

/// One block of `L` floats of [`filter_span`] at `out[p..p + L]`.
#[inline(always)]
fn block<const L: usize, const ADD: bool, const FUSED: bool>(
    out: &mut [f32],
    p: usize,
    taps: &[(f32, usize)],
    src: &[f32],
) {
    let Some(o) = out.get_mut(p..).and_then(|o| o.first_chunk_mut::<L>()) else {
        return;
    };
    let mut acc = if ADD { *o } else { [0.0f32; L] };
    for &(w, base) in taps {
        if let Some(s) = src.get(base + p..).and_then(|s| s.first_chunk::<L>()) {
            for t in 0..L {
                acc[t] = madd::<FUSED>(acc[t], w, s[t]);
            }
        }
    }
    *o = acc;
}

/// Most outputs [`filter_span_ranks`] computes at once.
pub const MAX_RANKS: usize = 3;

/// Several horizontal filters of one source at once, each loaded block of `src` serving all of
/// them: `out[i][p] = sum_k taps[k].1[i] src[taps[k].0 + p]` for each `i < out.len()` (at most
/// [`MAX_RANKS`]). The ranks of a separable filter's horizontal pass read the same padded row
/// with the same offsets and their own weights, so [`filter_span`] called once per rank loads
/// each block once per rank and tap, and the loop was bound by those loads (most of them
/// unaligned, a row's offsets moving by a pixel of three or four floats per tap); here each load
/// serves every rank. A weight that is 0 for one output while another's is not is multiplied
/// like the others: its product, a zero, leaves a sum of finite values unchanged (but for the
/// sign of a sum of -0). So for finite sources output `i` gets the bits of [`filter_span`] over
/// the nonzero weights of `i`, in the order of `taps`. Taps whose source would run past `src`
/// are skipped (callers never produce them). All outputs must have the same length.
///
/// Compiled for several instruction sets and chosen at run time ([`multiversion`]), as
/// [`filter_span`].
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "aarch64+neon"
))]
pub fn filter_span_ranks(out: &mut [&mut [f32]], taps: &[(usize, [f32; MAX_RANKS])], src: &[f32]) {
    const AVX512: bool = multiversion::target::selected_target!().supports_feature_str("avx512f");
    const AVX2: bool = multiversion::target::selected_target!().supports_feature_str("avx2");
    const FUSED: bool = fused(multiversion::target::selected_target!().supports_feature_str("fma"));
    // About 8 to 12 registers of sums: AVX-512 has 32, AVX2 and SSE2 16 (NEON 32, of 4 floats).
    match (out.len(), AVX512, AVX2) {
        (1, true, _) => ranks_span::<1, WIDEST_LANES, FUSED>(out, taps, src),
        (2, true, _) => ranks_span::<2, WIDE_LANES, FUSED>(out, taps, src),
        (3, true, _) => ranks_span::<3, WIDE_LANES, FUSED>(out, taps, src),
        (1, _, true) => ranks_span::<1, WIDE_LANES, FUSED>(out, taps, src),
        (2, _, true) => ranks_span::<2, LANES, FUSED>(out, taps, src),
        (3, _, true) => ranks_span::<3, LANES, FUSED>(out, taps, src),
        (1, _, _) => ranks_span::<1, LANES, FUSED>(out, taps, src),
        (2, _, _) => ranks_span::<2, 16, FUSED>(out, taps, src),
        (3, _, _) => ranks_span::<3, 12, FUSED>(out, taps, src),
        _ => {}
    }
}

/// [`filter_span_ranks`] as the portable baseline build only: its twin.
pub fn filter_span_ranks_baseline(
    out: &mut [&mut [f32]],
    taps: &[(usize, [f32; MAX_RANKS])],
    src: &[f32],
) {
    match out.len() {
        1 => ranks_span::<1, LANES, BASELINE_FUSED>(out, taps, src),
        2 => ranks_span::<2, 16, BASELINE_FUSED>(out, taps, src),
        3 => ranks_span::<3, 12, BASELINE_FUSED>(out, taps, src),
        _ => {}
    }
}

#[inline(always)]
fn ranks_span<const R: usize, const L: usize, const FUSED: bool>(
    out: &mut [&mut [f32]],
    taps: &[(usize, [f32; MAX_RANKS])],
    src: &[f32],
) {
    let len = out.first().map_or(0, |o| o.len());
    assert!(
        out.len() == R && out.iter().all(|o| o.len() == len),
        "{R} outputs of one length"
    );
    let mut p = 0;
    while p + L <= len {
        ranks_block::<R, L, FUSED>(out, p, taps, src);
        p += L;
    }
    while p + 4 <= len {
        ranks_block::<R, 4, FUSED>(out, p, taps, src);
        p += 4;
    }
    while p < len {
        ranks_block::<R, 1, FUSED>(out, p, taps, src);
        p += 1;
    }
}

/// A pair of horizontal taps at the same distance either side of the centre, `(lo, hi, w)`:
/// sources `src[lo + p]` and `src[hi + p]`, and each output's weight of the `hi` one.
pub type TapPair = (usize, usize, [f32; MAX_RANKS]);

/// [`filter_span_ranks`] for filters that are even or odd about their centre tap, each pair of
/// taps either side folded into one product: `w (x_hi + x_lo)` for the first `even` outputs
/// (even filters: both taps weigh `w`) and `w (x_hi - x_lo)` for the others (odd filters: the
/// `lo` tap weighs `-w`). Output `i` is `center.1[i] src[center.0 + p]` plus those products over
/// `pairs`, summed in the order of `pairs`. Each pair costs one sum and one difference (which
/// run beside the multiply-adds: most cores add on other ports than they multiply, or at least
/// as fast) and one multiply-add per output instead of two: the singular vectors of an aperture
/// symmetric about its axes (a disc, an upright hexagon) are all even or odd. Within a rounding
/// per tap of the unfolded sum. Chosen at run time, as [`filter_span`].
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "aarch64+neon"
))]
pub fn filter_span_ranks_folded(
    out: &mut [&mut [f32]],
    even: usize,
    center: (usize, [f32; MAX_RANKS]),
    pairs: &[TapPair],
    src: &[f32],
) {
    const AVX512: bool = multiversion::target::selected_target!().supports_feature_str("avx512f");
    const AVX2: bool = multiversion::target::selected_target!().supports_feature_str("avx2");
    const FUSED: bool = fused(multiversion::target::selected_target!().supports_feature_str("fma"));
    // Registers: `R` blocks of sums, a block of sums and one of differences of the sources.
    macro_rules! by_shape {
        ($l1:expr, $l2:expr, $l3:expr) => {
            match (out.len(), even) {
                (1, 0) => folded_span::<1, 0, { $l1 }, FUSED>(out, center, pairs, src),
                (1, 1) => folded_span::<1, 1, { $l1 }, FUSED>(out, center, pairs, src),
                (2, 0) => folded_span::<2, 0, { $l2 }, FUSED>(out, center, pairs, src),
                (2, 1) => folded_span::<2, 1, { $l2 }, FUSED>(out, center, pairs, src),
                (2, 2) => folded_span::<2, 2, { $l2 }, FUSED>(out, center, pairs, src),
                (3, 0) => folded_span::<3, 0, { $l3 }, FUSED>(out, center, pairs, src),
                (3, 1) => folded_span::<3, 1, { $l3 }, FUSED>(out, center, pairs, src),
                (3, 2) => folded_span::<3, 2, { $l3 }, FUSED>(out, center, pairs, src),
                (3, 3) => folded_span::<3, 3, { $l3 }, FUSED>(out, center, pairs, src),
                _ => {}
            }
        };
    }
    if AVX512 {
        by_shape!(WIDE_LANES, WIDE_LANES, WIDE_LANES);
    } else if AVX2 {
        by_shape!(LANES, 16, 16);
    } else {
        by_shape!(16, 8, 8);
    }
}

/// [`filter_span_ranks_folded`] as the portable baseline build only: its twin.
pub fn filter_span_ranks_folded_baseline(
    out: &mut [&mut [f32]],
    even: usize,
    center: (usize, [f32; MAX_RANKS]),
    pairs: &[TapPair],
    src: &[f32],
) {
    match (out.len(), even) {
        (1, 0) => folded_span::<1, 0, 16, BASELINE_FUSED>(out, center, pairs, src),
        (1, 1) => folded_span::<1, 1, 16, BASELINE_FUSED>(out, center, pairs, src),
        (2, 0) => folded_span::<2, 0, 8, BASELINE_FUSED>(out, center, pairs, src),
        (2, 1) => folded_span::<2, 1, 8, BASELINE_FUSED>(out, center, pairs, src),
        (2, 2) => folded_span::<2, 2, 8, BASELINE_FUSED>(out, center, pairs, src),
        (3, 0) => folded_span::<3, 0, 8, BASELINE_FUSED>(out, center, pairs, src),
        (3, 1) => folded_span::<3, 1, 8, BASELINE_FUSED>(out, center, pairs, src),
        (3, 2) => folded_span::<3, 2, 8, BASELINE_FUSED>(out, center, pairs, src),
        (3, 3) => folded_span::<3, 3, 8, BASELINE_FUSED>(out, center, pairs, src),
        _ => {}
    }
}

#[inline(always)]
fn folded_span<const R: usize, const E: usize, const L: usize, const FUSED: bool>(
    out: &mut [&mut [f32]],
    center: (usize, [f32; MAX_RANKS]),
    pairs: &[TapPair],
    src: &[f32],
) {
    let len = out.first().map_or(0, |o| o.len());
    assert!(
        out.len() == R && out.iter().all(|o| o.len() == len),
        "{R} outputs of one length"
    );
    let mut p = 0;
    while p + L <= len {
        folded_block::<R, E, L, FUSED>(out, p, center, pairs, src);
        p += L;
    }
    while p + 4 <= len {
        folded_block::<R, E, 4, FUSED>(out, p, center, pairs, src);
        p += 4;
    }
    while p < len {
        folded_block::<R, E, 1, FUSED>(out, p, center, pairs, src);
        p += 1;
    }
}

/// One block of `L` floats at `p` of each of the `R` outputs of [`filter_span_ranks_folded`],
/// the first `E` even.
#[inline(always)]
fn folded_block<const R: usize, const E: usize, const L: usize, const FUSED: bool>(
    out: &mut [&mut [f32]],
    p: usize,
    (cb, cw): (usize, [f32; MAX_RANKS]),
    pairs: &[TapPair],
    src: &[f32],
) {
    let mut acc = [[0.0f32; L]; R];
    if let Some(x) = src.get(cb + p..).and_then(|s| s.first_chunk::<L>()) {
        for (a, &w) in acc.iter_mut().zip(&cw) {
            for t in 0..L {
                a[t] = madd::<FUSED>(a[t], w, x[t]);
            }
        }
    }
    for &(lo, hi, w) in pairs {
        let (Some(xl), Some(xh)) = (
            src.get(lo + p..).and_then(|s| s.first_chunk::<L>()),
            src.get(hi + p..).and_then(|s| s.first_chunk::<L>()),
        ) else {
            continue;
        };
        let sum: [f32; L] = std::array::from_fn(|t| xh[t] + xl[t]);
        let diff: [f32; L] = std::array::from_fn(|t| xh[t] - xl[t]);
        for (k, (a, &w)) in acc.iter_mut().zip(&w).enumerate() {
            let x = if k < E { &sum } else { &diff };
            for t in 0..L {
                a[t] = madd::<FUSED>(a[t], w, x[t]);
            }
        }
    }
    for (o, a) in out.iter_mut().zip(&acc) {
        if let Some(o) = o.get_mut(p..).and_then(|o| o.first_chunk_mut::<L>()) {
            *o = *a;
        }
    }
}

/// One block of `L` floats at `p` of each of the `R` outputs of [`filter_span_ranks`], all `R`
/// sums kept in registers over every tap.
#[inline(always)]
fn ranks_block<const R: usize, const L: usize, const FUSED: bool>(
    out: &mut [&mut [f32]],
    p: usize,
    taps: &[(usize, [f32; MAX_RANKS])],
    src: &[f32],
) {
    let mut acc = [[0.0f32; L]; R];
    for &(base, w) in taps {
        let Some(x) = src.get(base + p..).and_then(|s| s.first_chunk::<L>()) else {
            continue;
        };
        for (a, &w) in acc.iter_mut().zip(&w) {
            for t in 0..L {
                a[t] = madd::<FUSED>(a[t], w, x[t]);
            }
        }
    }
    for (o, a) in out.iter_mut().zip(&acc) {
        if let Some(o) = o.get_mut(p..).and_then(|o| o.first_chunk_mut::<L>()) {
            *o = *a;
        }
    }
}

/// Most output rows [`filter_rows`] computes at once.
pub const MAX_ROWS: usize = 8;

/// A vertical filter of up to [`MAX_ROWS`] adjacent output rows at once, each source row loaded
/// once for all of them: with `n = taps.len()`, `R = out.len()` and `base` the offsets of
/// `n + R - 1` source rows in `src`,
/// `out[r][p] (+)= sum_{i < n} taps[i] src[base[i + r] + p]`, adding to `out` when `add` is set
/// and overwriting it otherwise. Row `r`'s sum runs in the order of `i`, as [`filter_span`] and
/// [`filter_span_add`] sum their lists. Zero taps at either end of `taps` are skipped; zero taps
/// between nonzero ones are multiplied like the others, whose product, a zero, leaves a sum of
/// finite values unchanged (but for the sign of a sum of -0). So for finite sources each row gets
/// the bits of one of those functions given `taps[i]` at `base[i + r]`, the nonzero ones in
/// order. Source rows that would run past `src` are skipped (callers never produce them). All
/// rows of `out` must have the same length.
///
/// The vertical taps of a separable filter read a different source row each, so [`filter_span`]
/// loads one block per product; adjacent output rows share all but one of their source rows,
/// and here each load serves up to [`MAX_ROWS`] products. Each source row has one weight per
/// output row, zero where it is none of that row's taps, so the loop tests nothing per product
/// (a test of each weight for zero and range took a third of the vertical pass), and it asks
/// for the lines it will read two blocks on: its source rows are kilobytes apart, more streams
/// than the hardware prefetchers follow. Rank 3 at 65 px, 1280x720, RGBA, banded schedule: 29.5
/// ms with the tests and no prefetch, 27.3 ms with the prefetch, 22.9 ms without the tests too
/// (least of two interleaved runs on an AMD EPYC with AVX-512).
///
/// Compiled for several instruction sets and chosen at run time ([`multiversion`]), the same
/// arithmetic in every version.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2+fma",
    "x86_64+avx2+fma",
    "aarch64+neon"
))]
pub fn filter_rows(out: &mut [&mut [f32]], taps: &[f32], base: &[usize], src: &[f32], add: bool) {
    const AVX512: bool = multiversion::target::selected_target!().supports_feature_str("avx512f");
    const AVX2: bool = multiversion::target::selected_target!().supports_feature_str("avx2");
    // Eight rows of `L` floats in registers: 16 of AVX-512's 32, 8 of AVX2's 16.
    const L: usize = if AVX512 {
        32
    } else if AVX2 {
        8
    } else {
        4
    };
    const FUSED: bool = fused(multiversion::target::selected_target!().supports_feature_str("fma"));
    rows_dispatch::<L, FUSED>(out, taps, base, src, add);
}

/// [`filter_rows`] as the portable baseline build only: its twin.
pub fn filter_rows_baseline(
    out: &mut [&mut [f32]],
    taps: &[f32],
    base: &[usize],
    src: &[f32],
    add: bool,
) {
    rows_dispatch::<4, BASELINE_FUSED>(out, taps, base, src, add);
}

#[inline(always)]
fn rows_dispatch<const L: usize, const FUSED: bool>(
    out: &mut [&mut [f32]],
    taps: &[f32],
    base: &[usize],
    src: &[f32],
    add: bool,
) {
    assert!(
        out.len() <= MAX_ROWS && base.len() + 1 >= taps.len() + out.len(),
        "{} rows of {} taps need {} source rows, {} given",
        out.len(),
        taps.len(),
        taps.len() + out.len().saturating_sub(1),
        base.len()
    );
    let len = out.first().map_or(0, |o| o.len());
    assert!(out.iter().all(|o| o.len() == len), "rows of one length");
    // Zero taps at either end are skipped by starting and ending the list at its nonzero ones.
    let first = taps.iter().position(|&t| t != 0.0).unwrap_or(taps.len());
    let last = taps
        .iter()
        .rposition(|&t| t != 0.0)
        .map_or(first, |i| i + 1);
    let (taps, base) = (&taps[first..last], &base[first..]);
    macro_rules! by_rows {
        ($($r:literal)*) => {
            match (out.len(), add) {
                $(
                    ($r, false) => rows_span::<$r, false, L, FUSED>(out, taps, base, src, len),
                    ($r, true) => rows_span::<$r, true, L, FUSED>(out, taps, base, src, len),
                )*
                _ => {}
            }
        };
    }
    by_rows!(1 2 3 4 5 6 7 8);
}

#[inline(always)]
fn rows_span<const R: usize, const ADD: bool, const L: usize, const FUSED: bool>(
    out: &mut [&mut [f32]],
    taps: &[f32],
    base: &[usize],
    src: &[f32],
    len: usize,
) {
    // Source row j is tap `j - r` of output row r: its weight for each row, 0 where it is none.
    let weights: Vec<[f32; R]> = (0..taps.len() + R - 1)
        .map(|j| {
            std::array::from_fn(|r| {
                j.checked_sub(r)
                    .and_then(|i| taps.get(i))
                    .copied()
                    .unwrap_or(0.0)
            })
        })
        .collect();
    let mut p = 0;
    while p + L <= len {
        rows_block::<R, ADD, L, FUSED>(out, p, &weights, base, src);
        p += L;
    }
    while p + 4 <= len {
        rows_block::<R, ADD, 4, FUSED>(out, p, &weights, base, src);
        p += 4;
    }
    while p < len {
        rows_block::<R, ADD, 1, FUSED>(out, p, &weights, base, src);
        p += 1;
    }
}

/// One block of `L` floats at `p` of each of the `R` rows of [`filter_rows`], all `R` sums kept
/// in registers over every source row.
#[inline(always)]
fn rows_block<const R: usize, const ADD: bool, const L: usize, const FUSED: bool>(
    out: &mut [&mut [f32]],
    p: usize,
    weights: &[[f32; R]],
    base: &[usize],
    src: &[f32],
) {
    let mut acc = [[0.0f32; L]; R];
    if ADD {
        for (a, o) in acc.iter_mut().zip(out.iter()) {
            if let Some(o) = o.get(p..).and_then(|o| o.first_chunk::<L>()) {
                *a = *o;
            }
        }
    }
    for (&b, wj) in base.iter().zip(weights) {
        let Some(x) = src.get(b + p..).and_then(|s| s.first_chunk::<L>()) else {
            continue;
        };
        // The lines of this source row that the block after next will read.
        prefetch(src, b + p + PREFETCH_FLOATS);
        if L > 16 {
            prefetch(src, b + p + PREFETCH_FLOATS + 16);
        }
        for (a, &w) in acc.iter_mut().zip(wj) {
            for t in 0..L {
                a[t] = madd::<FUSED>(a[t], w, x[t]);
            }
        }
    }
    for (o, a) in out.iter_mut().zip(&acc) {
        if let Some(o) = o.get_mut(p..).and_then(|o| o.first_chunk_mut::<L>()) {
            *o = *a;
        }
    }
}

/// How far ahead of its block [`filter_rows`] prefetches each source row, in floats (256 bytes):
/// its source rows are many kilobytes apart, more streams than the hardware prefetchers follow.
const PREFETCH_FLOATS: usize = 64;

/// Asks for the cache line holding `src[i]` (a hint: nothing happens where there is no such
/// instruction, and an index past the end is never read).
#[inline(always)]
fn prefetch(src: &[f32], i: usize) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch never faults and reads nothing into the program, whatever the address;
    // the pointer is formed with wrapping arithmetic and never dereferenced.
    unsafe {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        _mm_prefetch::<_MM_HINT_T0>(src.as_ptr().wrapping_add(i).cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (src, i);
}

/// Writes the first `CH` channels of `row`'s pixels into `out` (flattened: RGBA for 4, colour
/// only for 3) with `left` copies of its first pixel before it and `right` copies of its last
/// pixel after it (clamp to edge).
#[inline]
pub(crate) fn pad_row<const CH: usize>(
    row: &[Rgba],
    left: usize,
    right: usize,
    out: &mut Vec<f32>,
) {
    let (Some(first), Some(last)) = (row.first(), row.last()) else {
        out.clear();
        return;
    };
    // Sized once and filled pixel by pixel in place (a push per pixel, with its capacity
    // check, was most of a row's padding).
    out.resize((left + row.len() + right) * CH, 0.0);
    let (head, rest) = out.split_at_mut(left * CH);
    let (body, tail) = rest.split_at_mut(row.len() * CH);
    for p in head.chunks_exact_mut(CH) {
        p.copy_from_slice(&first[..CH]);
    }
    for (o, p) in body.chunks_exact_mut(CH).zip(row) {
        o.copy_from_slice(&p[..CH]);
    }
    for p in tail.chunks_exact_mut(CH) {
        p.copy_from_slice(&last[..CH]);
    }
}

/// True if every pixel's alpha is exactly 1: the image is opaque, and the filters carry only
/// its three colour channels (a quarter fewer products and bytes than RGBA).
pub fn is_opaque(img: &ColorImage) -> bool {
    img.pixels()
        .par_chunks(4096)
        .all(|c| c.iter().all(|p| p[3] == 1.0))
}

/// Which channels a filter carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channels {
    /// Colour only when the image is opaque ([`is_opaque`]), else all four. The default.
    Auto,
    /// All four channels whatever the alpha: the twin the colour-only path is tested against.
    Rgba,
}

/// Horizontal pass of one rank: `inter(x) = sum_k taps[k] img(x + c - k)` (the first `CH`
/// channels, flattened), written into `inter`, which is reused from rank to rank.
fn horizontal_pass<const CH: usize>(img: &ColorImage, taps: &[f32], c: usize, inter: &mut [f32]) {
    let w = img.width();
    let n = taps.len();
    let list = padded_row_taps::<CH>(taps);
    inter
        .par_chunks_mut(w * CH)
        .enumerate()
        .for_each_init(Vec::new, |padded, (y, row)| {
            pad_row::<CH>(img.row(y), n - 1 - c, c, padded);
            filter_span(row, &list, padded);
        });
}

/// The nonzero `taps` of a horizontal filter as [`filter_span`]'s list over a row padded with
/// `n - 1 - c` pixels on the left (`n = taps.len()`, `CH` floats per pixel):
/// `out(x) = sum_k taps[k] padded[x + n - 1 - k]`, so tap k reads from float `CH (n - 1 - k)`.
fn padded_row_taps<const CH: usize>(taps: &[f32]) -> Vec<(f32, usize)> {
    let n = taps.len();
    taps.iter()
        .enumerate()
        .filter(|(_, &wk)| wk != 0.0)
        .map(|(k, &wk)| (wk, (n - 1 - k) * CH))
        .collect()
}

/// The vertical filter of a group of adjacent output rows `strips` (top first, each the columns
/// from `x0` of rows `y..`) by [`filter_rows`]: `strips[r](x) (+)= sum_k taps[k]
/// src(x, clamp(y + r + c - k))`, `src` with rows of `w` pixels of `CH` floats and `h` rows,
/// clamped to its edge. `base` is scratch for the source rows' offsets.
#[expect(
    clippy::too_many_arguments,
    reason = "a group, its filter, its source and scratch, as both callers hold them"
)]
fn vertical_rows<const CH: usize>(
    strips: &mut [&mut [f32]],
    (y, x0): (usize, usize),
    taps: &[f32],
    c: usize,
    src: &[f32],
    (w, h): (usize, usize),
    base: &mut Vec<usize>,
    add: bool,
) {
    // With the bottom row of the group first, output row `y + m - 1 - r` reads source row
    // `y + m - 1 - r + c - k` for tap k: entry `k + r` of one list.
    let m = strips.len();
    let bottom = y + m - 1 + c;
    base.clear();
    base.extend(
        (0..taps.len() + m - 1).map(|j| (bottom.saturating_sub(j).min(h - 1) * w + x0) * CH),
    );
    strips.reverse();
    filter_rows(strips, taps, base, src, add);
}

/// Output rows per parallel task of the vertical passes.
pub const ROW_BLOCK: usize = 32;

/// Width in pixels of the column strips of the vertical passes: the source rows of one strip
/// for a block of output rows stay in the L2 cache.
pub const STRIP_PX: usize = 128;

/// Runs `f(y, x0, strip, scratch)` for every output row `y` and column strip
/// `[x0, x0 + strip.len())` of `out` (rows of `w` pixels of `P`): blocks of [`ROW_BLOCK`] rows
/// in parallel, and within a block strip by strip, so that the source rows a strip reads are
/// reused from cache by the next output row. Every output pixel is computed by the same
/// operations in the same order whatever the partition, so the result does not depend on the
/// thread count.
pub(crate) fn for_each_strip<P: Send>(
    out: &mut [P],
    w: usize,
    f: impl Fn(usize, usize, &mut [P], &mut Vec<(f32, usize)>) + Sync,
) {
    for_each_block_strip(out, w, |y0, x0, x1, rows, scratch| {
        for (dy, row) in rows.chunks_mut(w).enumerate() {
            f(y0 + dy, x0, &mut row[x0..x1], scratch);
        }
    });
}

/// [`for_each_strip`] for [`filter_rows`]: runs `f(y, x0, strips, scratch)` for every group of
/// up to [`MAX_ROWS`] output rows `y..` and column strip from `x0`, with `strips` the group's
/// rows (top first) restricted to the strip, as flat floats.
fn for_each_strip_rows<const CH: usize>(
    out: &mut [[f32; CH]],
    w: usize,
    f: impl Fn(usize, usize, &mut [&mut [f32]], &mut Vec<usize>) + Sync,
) {
    for_each_block_strip(out, w, |y0, x0, x1, rows, scratch| {
        for (g, group) in rows.chunks_mut(MAX_ROWS * w).enumerate() {
            let mut strips: [&mut [f32]; MAX_ROWS] = std::array::from_fn(|_| &mut [][..]);
            let mut m = 0;
            for (s, row) in strips.iter_mut().zip(group.chunks_mut(w)) {
                *s = row[x0..x1].as_flattened_mut();
                m += 1;
            }
            f(y0 + g * MAX_ROWS, x0, &mut strips[..m], scratch);
        }
    });
}

/// The walk of [`for_each_strip`]: `f(y0, x0, x1, rows, scratch)` for every block of
/// [`ROW_BLOCK`] rows from `y0` (in parallel) and, within it, every column strip `x0..x1`, in
/// order, with scratch made once per worker.
fn for_each_block_strip<P: Send, S: Default + Send>(
    out: &mut [P],
    w: usize,
    f: impl Fn(usize, usize, usize, &mut [P], &mut S) + Sync,
) {
    if w == 0 {
        return;
    }
    out.par_chunks_mut(ROW_BLOCK * w).enumerate().for_each_init(
        S::default,
        |scratch, (block, rows)| {
            for x0 in (0..w).step_by(STRIP_PX) {
                f(block * ROW_BLOCK, x0, (x0 + STRIP_PX).min(w), rows, scratch);
            }
        },
    );
}

/// Vertical pass of one rank: `out(y) (+)= sum_k taps[k] inter(clamp(y + c - k))`, overwriting
/// `out` for the first rank and accumulating for the others (fig. 2: the `V_i` are never
/// stored). Rows go in groups of [`MAX_ROWS`] through [`filter_rows`], which gives each the
/// bits [`filter_span`] would (unit test `filter_rows_match_the_span_filter_bit_for_bit`).
/// On the 65 px disc at rank 3 and 1280x720, one row at a time took 33.5 ms in colour only and
/// 44.7 ms in RGBA, eight rows at a time 28.4 and 31.0 ms (least of four interleaved runs on an
/// AMD EPYC with AVX-512); four at a time gained about half as much.
fn vertical_pass<const CH: usize>(
    inter: &[f32],
    out: &mut [[f32; CH]],
    (w, h): (usize, usize),
    taps: &[f32],
    c: usize,
    first: bool,
) {
    for_each_strip_rows(out, w, |y, x0, strips, base| {
        vertical_rows::<CH>(strips, (y, x0), taps, c, inter, (w, h), base, !first);
    });
}

/// Output rows per band of [`filter_separable`]'s banded schedule.
pub const BAND_ROWS: usize = 16;

/// [`Schedule::Banded`]: the separable filter of every rank, band by band of [`BAND_ROWS`]
/// output rows (bands in parallel). For each rank, the vertical taps filter the band's source
/// rows into a padded scratch band ([`filter_rows`], eight rows at once, in column strips of
/// [`STRIP_PX`]), whose rows the horizontal taps then filter into a band of sums
/// ([`filter_span`], adding from the second rank on); the sums are written into the band's
/// fresh output rows once, after the last rank, with alpha `alpha` when `CH` is 3. `src` is the
/// image's first `CH` channels, flattened. Per band, RGBA at 1280 px wide: a scratch band and a
/// band of sums of 16 rows, 350 KB each, which stay in L2 for all ranks.
fn separable_banded<const CH: usize>(
    src: &[f32],
    (w, h): (usize, usize),
    (horizontal, vertical): (&[Vec<f32>], &[Vec<f32>]),
    (cx, cy): (usize, usize),
    alpha: f32,
) -> ColorImage {
    let n = horizontal.first().map_or(0, Vec::len);
    if w == 0 || h == 0 || n == 0 || vertical.is_empty() {
        return ColorImage::new(w, h, [0.0, 0.0, 0.0, if CH == 4 { 0.0 } else { alpha }]);
    }
    let left = n - 1 - cx;
    let padded_w = (w + n - 1) * CH;
    let lists: Vec<Vec<(f32, usize)>> = horizontal
        .iter()
        .map(|t| padded_row_taps::<CH>(t))
        .collect();
    let band = |(tmp, base, sum): &mut (Vec<f32>, Vec<usize>, Vec<f32>),
                y0: usize,
                out: &mut [MaybeUninit<Rgba>]| {
        let m_rows = out.len() / w;
        tmp.resize(m_rows * padded_w, 0.0);
        sum.resize(m_rows * w * CH, 0.0);
        for (i, (list, vt)) in lists.iter().zip(vertical).enumerate() {
            for x0 in (0..w).step_by(STRIP_PX) {
                let x1 = (x0 + STRIP_PX).min(w);
                for g0 in (0..m_rows).step_by(MAX_ROWS) {
                    let m = MAX_ROWS.min(m_rows - g0);
                    let mut strips: [&mut [f32]; MAX_ROWS] = std::array::from_fn(|_| &mut [][..]);
                    for (s, row) in strips
                        .iter_mut()
                        .zip(tmp[g0 * padded_w..].chunks_mut(padded_w).take(m))
                    {
                        *s = &mut row[(left + x0) * CH..(left + x1) * CH];
                    }
                    let strips = &mut strips[..m];
                    vertical_rows::<CH>(strips, (y0 + g0, x0), vt, cy, src, (w, h), base, false);
                }
            }
            for (t, o) in tmp.chunks_mut(padded_w).zip(sum.chunks_mut(w * CH)) {
                // Clamp to edge: copies of the first and last pixels on either side.
                let (head, rest) = t.split_at_mut(left * CH);
                let (body, tail) = rest.split_at_mut(w * CH);
                for p in head.chunks_mut(CH) {
                    p.copy_from_slice(&body[..CH]);
                }
                for p in tail.chunks_mut(CH) {
                    p.copy_from_slice(&body[(w - 1) * CH..]);
                }
                if i == 0 {
                    filter_span(o, list, t);
                } else {
                    filter_span_add(o, list, t);
                }
            }
        }
        for (o, s) in out.iter_mut().zip(sum.chunks_exact(CH)) {
            o.write(if CH == 4 {
                [s[0], s[1], s[2], s[3]]
            } else {
                [s[0], s[1], s[2], alpha]
            });
        }
        false
    };
    // SAFETY: `band` writes every pixel of its rows: `sum` holds `w * CH` floats per row, one
    // pixel per `CH`, and the final loop writes each pixel from them.
    let (out, _) = unsafe {
        ColorImage::par_from_bands(
            w,
            h,
            BAND_ROWS,
            || (Vec::new(), Vec::new(), Vec::new()),
            band,
        )
    };
    out
}

/// Filters `img` with the rank-`rank` approximation of the kernel decomposed in `lr` (eq. 1).
/// `rank` is capped at [`LowRank::len`]; rank 0 gives a black, transparent image.
///
/// The passes run band by band ([`Schedule::Banded`]): the same sum of separable filters as
/// fig. 2's schedule ([`filter_separable_fig2`]), with each rank's vertical pass before its
/// horizontal one, so the results differ by rounding only.
///
/// An opaque image ([`is_opaque`]) is filtered in its three colour channels only; its alpha,
/// the same at every pixel (the approximation's sum), is worked out with the same products and
/// sums, so the result is bit-identical to [`Channels::Rgba`].
pub fn filter_separable(img: &ColorImage, lr: &LowRank, rank: usize) -> ColorImage {
    filter_separable_with(img, lr, rank, Channels::Auto, Schedule::Banded)
}

/// [`filter_separable`] with the choice of channels made by the caller.
pub fn filter_separable_channels(
    img: &ColorImage,
    lr: &LowRank,
    rank: usize,
    channels: Channels,
) -> ColorImage {
    filter_separable_with(img, lr, rank, channels, Schedule::Banded)
}

/// [`filter_separable`] in the order of the paper's fig. 2 ([`Schedule::Fig2`]).
pub fn filter_separable_fig2(img: &ColorImage, lr: &LowRank, rank: usize) -> ColorImage {
    filter_separable_with(img, lr, rank, Channels::Auto, Schedule::Fig2)
}

/// The order in which [`filter_separable_with`] runs its passes. Both compute eq. 1 with the
/// same taps; they differ in rounding only.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Schedule {
    /// Fig. 2 as drawn: for each rank a horizontal pass over the whole image into an
    /// intermediate image, then a vertical pass from it, accumulated into the output.
    Fig2,
    /// Band by band of [`BAND_ROWS`] output rows, in parallel: for each rank the vertical taps
    /// filter the band's source rows into a scratch band that stays in cache, and the horizontal
    /// taps add that into a band of sums, also in cache, which is written out once. No
    /// intermediate image is stored. The default: rank 3 at 65 px, 1280x720, RGBA took
    /// 22.4-22.9 ms against fig. 2's 34.9-38.3 ms, both with the same [`filter_rows`] (AMD EPYC,
    /// AVX-512).
    Banded,
}

/// [`filter_separable`] with the channels and the schedule chosen by the caller.
pub fn filter_separable_with(
    img: &ColorImage,
    lr: &LowRank,
    rank: usize,
    channels: Channels,
    schedule: Schedule,
) -> ColorImage {
    let rank = rank.min(lr.len());
    let (w, h) = (img.width(), img.height());
    if rank == 0 || w == 0 || h == 0 {
        return ColorImage::new(w, h, [0.0; 4]);
    }
    let to_f32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let horizontal: Vec<Vec<f32>> = (0..rank)
        .filter_map(|i| lr.horizontal(i).map(to_f32))
        .collect();
    let vertical: Vec<Vec<f32>> = (0..rank)
        .filter_map(|i| lr.vertical(i).map(to_f32))
        .collect();
    let centre = (lr.width() / 2, lr.height() / 2);
    let opaque = channels == Channels::Auto && is_opaque(img);
    match (schedule, opaque) {
        (Schedule::Banded, true) => {
            let src: Vec<[f32; 3]> = img
                .pixels()
                .par_iter()
                .map(|p| [p[0], p[1], p[2]])
                .collect();
            // The RGBA filter runs the vertical taps, then the horizontal ones.
            let alpha = constant_alpha(&vertical, &horizontal);
            let taps = (&horizontal[..], &vertical[..]);
            separable_banded::<3>(src.as_flattened(), (w, h), taps, centre, alpha)
        }
        (Schedule::Banded, false) => {
            let src = img.pixels().as_flattened();
            let taps = (&horizontal[..], &vertical[..]);
            separable_banded::<4>(src, (w, h), taps, centre, 1.0)
        }
        (Schedule::Fig2, true) => {
            let (cx, cy) = centre;
            // One rank after the other: one intermediate image, reused. (Keeping all `U_i`
            // cost more in first-touch page faults than in taps: rank 3 at 17 px took 43 ms,
            // against 18 ms at rank 2.)
            let mut inter = vec![0.0f32; w * h * 3];
            let mut out = vec![[0.0f32; 3]; w * h];
            for (i, (hv, vv)) in horizontal.iter().zip(&vertical).enumerate() {
                horizontal_pass::<3>(img, hv, cx, &mut inter);
                vertical_pass::<3>(&inter, &mut out, (w, h), vv, cy, i == 0);
            }
            with_alpha(w, h, &out, constant_alpha(&horizontal, &vertical))
        }
        (Schedule::Fig2, false) => {
            let (cx, cy) = centre;
            let mut inter = vec![0.0f32; w * h * 4];
            let mut out = ColorImage::new(w, h, [0.0; 4]);
            for (i, (hv, vv)) in horizontal.iter().zip(&vertical).enumerate() {
                horizontal_pass::<4>(img, hv, cx, &mut inter);
                vertical_pass::<4>(&inter, out.pixels_mut(), (w, h), vv, cy, i == 0);
            }
            out
        }
    }
}

/// The alpha every pixel of an opaque image gets from the RGBA filter: each rank's `first` taps,
/// then its `second` taps, applied to a constant 1 with the filters' products and sums in their
/// order (nonzero taps in list order, ranks accumulated in order) and their rounding (fused
/// multiply-adds where the dispatched filters use them), so the same bits.
fn constant_alpha(first: &[Vec<f32>], second: &[Vec<f32>]) -> f32 {
    let fuse = fuses_multiply_adds();
    let mut alpha = 0.0f32;
    for (i, (a, b)) in first.iter().zip(second).enumerate() {
        let once = a.iter().filter(|&&t| t != 0.0).fold(0.0f32, |s, &t| s + t);
        let start = if i == 0 { 0.0 } else { alpha };
        alpha = b.iter().filter(|&&t| t != 0.0).fold(start, |s, &t| {
            if fuse {
                t.mul_add(once, s)
            } else {
                s + t * once
            }
        });
    }
    alpha
}

/// The RGBA image of colours `rgb` with alpha `alpha` everywhere.
pub(crate) fn with_alpha(w: usize, h: usize, rgb: &[[f32; 3]], alpha: f32) -> ColorImage {
    let pixels: Vec<Rgba> = rgb.par_iter().map(|c| [c[0], c[1], c[2], alpha]).collect();
    ColorImage::from_vec(w, h, pixels).expect("sizes agree by construction")
}

/// Bytes a pixel of [`filter_separable_with`] takes besides its input image, at most: the
/// output (16) and, with the paper's schedule on an opaque image, its intermediate image and
/// sums (12 + 12; the banded schedule's colour copy is 12).
pub const SEPARABLE_BYTES_PER_PIXEL: u64 = 16 + 12 + 12;

/// Bytes [`filter_full_2d`] takes besides its input image on a `width` x `height` image with
/// a kernel `kernel_px` wide: its padded copy of the image (16 bytes a pixel of rows grown by
/// the kernel) and its output (12, then 16 with alpha).
pub fn full_2d_bytes(width: usize, height: usize, kernel_px: usize) -> u64 {
    let padded = (width + kernel_px.saturating_sub(1)) * height;
    padded as u64 * 16 + (width * height) as u64 * (12 + 16)
}

/// Convolves `img` with `kernel` (any size), the 2D filter that [`filter_separable`]
/// approximates, with the same register blocks and strips as [`filter_separable`]; zero kernel
/// entries are skipped. An opaque image is filtered in its colour channels only, with the same
/// bit-identical alpha as [`filter_separable`].
pub fn filter_full_2d(img: &ColorImage, kernel: &GrayImage) -> ColorImage {
    filter_full_2d_channels(img, kernel, Channels::Auto)
}

/// [`filter_full_2d`] with the choice of channels made by the caller.
pub fn filter_full_2d_channels(
    img: &ColorImage,
    kernel: &GrayImage,
    channels: Channels,
) -> ColorImage {
    let (w, h) = (img.width(), img.height());
    let (kw, kh) = (kernel.width(), kernel.height());
    if w == 0 || h == 0 || kw == 0 || kh == 0 {
        return ColorImage::new(w, h, [0.0; 4]);
    }
    if channels == Channels::Auto && is_opaque(img) {
        let mut out = vec![[0.0f32; 3]; w * h];
        full_2d(img, kernel, &mut out);
        // The alpha every pixel would get: the kernel applied to a constant 1 in list order.
        let alpha = (0..kh)
            .flat_map(|ky| kernel.row(ky).iter())
            .filter(|&&t| t != 0.0)
            .fold(0.0f32, |a, &t| a + t);
        return with_alpha(w, h, &out, alpha);
    }
    let mut out = ColorImage::new(w, h, [0.0; 4]);
    full_2d(img, kernel, out.pixels_mut());
    out
}

/// The 2D convolution of the first `CH` channels of `img` into `out` (`kernel` not empty).
fn full_2d<const CH: usize>(img: &ColorImage, kernel: &GrayImage, out: &mut [[f32; CH]]) {
    let (w, h) = (img.width(), img.height());
    let (kw, kh) = (kernel.width(), kernel.height());
    let (cx, cy) = (kw / 2, kh / 2);
    let padded_w = (w + kw - 1) * CH;
    let mut padded = vec![0.0f32; padded_w * h];
    padded
        .par_chunks_mut(padded_w)
        .enumerate()
        .for_each_init(Vec::new, |buf, (y, out)| {
            pad_row::<CH>(img.row(y), kw - 1 - cx, cx, buf);
            out.copy_from_slice(buf);
        });
    for_each_strip(out, w, |y, x0, strip, list| {
        list.clear();
        for ky in 0..kh {
            let yy = (y + cy).saturating_sub(ky).min(h - 1);
            for (kx, &wk) in kernel.row(ky).iter().enumerate() {
                if wk != 0.0 {
                    list.push((wk, yy * padded_w + (x0 + kw - 1 - kx) * CH));
                }
            }
        }
        filter_span(strip.as_flattened_mut(), list, &padded);
    });
}

/// Per-pixel twin of [`filter_full_2d`]: `out(x, y) = sum_{j,i} k[j][i] img(x + cx - i,
/// y + cy - j)` with clamped coordinates, accumulated in f64.
pub fn filter_full_2d_naive(img: &ColorImage, kernel: &GrayImage) -> ColorImage {
    let (w, h) = (img.width(), img.height());
    let (kw, kh) = (kernel.width(), kernel.height());
    let (cx, cy) = ((kw / 2) as isize, (kh / 2) as isize);
    let mut out = ColorImage::new(w, h, [0.0; 4]);
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f64; 4];
            for j in 0..kh {
                for i in 0..kw {
                    let k = kernel.get(i, j) as f64;
                    let p =
                        img.get_clamped(x as isize + cx - i as isize, y as isize + cy - j as isize);
                    for c in 0..4 {
                        acc[c] += k * p[c] as f64;
                    }
                }
            }
            *out.get_mut(x, y) = acc.map(|v| v as f32);
        }
    }
    out
}

/// Per-pixel twin of [`filter_separable`], eq. 1 term by term in f64: `U_i = img * v'_i`
/// (horizontal), `V_i = U_i * u'_i` (vertical), `out = sum_i V_i`.
pub fn filter_separable_naive(img: &ColorImage, lr: &LowRank, rank: usize) -> ColorImage {
    let (w, h) = (img.width(), img.height());
    let (cx, cy) = ((lr.width() / 2) as isize, (lr.height() / 2) as isize);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    let mut out = vec![[0.0f64; 4]; w * h];
    for i in 0..rank.min(lr.len()) {
        let (Some(v), Some(u)) = (lr.horizontal(i), lr.vertical(i)) else {
            break;
        };
        let mut inter = vec![[0.0f64; 4]; w * h];
        for y in 0..h {
            for x in 0..w {
                for (k, &vk) in v.iter().enumerate() {
                    let p = img.get(clamp(x as isize + cx - k as isize, w), y);
                    for c in 0..4 {
                        inter[y * w + x][c] += vk * p[c] as f64;
                    }
                }
            }
        }
        for y in 0..h {
            for x in 0..w {
                for (k, &uk) in u.iter().enumerate() {
                    let p = inter[clamp(y as isize + cy - k as isize, h) * w + x];
                    for c in 0..4 {
                        out[y * w + x][c] += uk * p[c];
                    }
                }
            }
        }
    }
    let mut image = ColorImage::new(w, h, [0.0; 4]);
    for (o, a) in image.pixels_mut().iter_mut().zip(&out) {
        *o = a.map(|v| v as f32);
    }
    image
}

#[cfg(test)]
mod dispatch_tests {
    use super::*;

    /// The portable span with products summed as the dispatched version sums them (fused or
    /// not), overwriting `out` or adding to it.
    fn span_as_dispatched(out: &mut [f32], taps: &[(f32, usize)], src: &[f32], add: bool) {
        match (fuses_multiply_adds(), add) {
            (true, false) => span::<false, LANES, true>(out, taps, src),
            (true, true) => span::<true, LANES, true>(out, taps, src),
            (false, false) => span::<false, LANES, false>(out, taps, src),
            (false, true) => span::<true, LANES, false>(out, taps, src),
        }
    }

    /// The portable span as the baseline build sums: what [`filter_span_baseline`] gives.
    fn span_as_baseline(out: &mut [f32], taps: &[(f32, usize)], src: &[f32], add: bool) {
        if add {
            span::<true, LANES, BASELINE_FUSED>(out, taps, src);
        } else {
            span::<false, LANES, BASELINE_FUSED>(out, taps, src);
        }
    }

    /// The run-time-dispatched span (AVX-512, AVX2, NEON or baseline, whichever this machine
    /// has) against the portable code with the same rounding (fused multiply-adds or not): the
    /// same products and sums in the same order, so bit-identical, over awkward lengths and tap
    /// sets; and against the baseline build, within a rounding per tap whichever each uses.
    #[test]
    fn dispatched_span_is_bit_identical_to_the_portable_code() {
        let mut rng = crate::random::SplitMix64::new(11);
        for len in [1usize, 3, 4, 5, 31, 32, 33, 63, 64, 65, 127, 200, 1283] {
            for ntaps in [1usize, 2, 7, 33] {
                let taps: Vec<(f32, usize)> = (0..ntaps)
                    .map(|_| (rng.range(-1.0, 1.0), rng.below(40)))
                    .collect();
                let src: Vec<f32> = (0..len + 48).map(|_| rng.range(-4.0, 4.0)).collect();
                let mut a = vec![0.0f32; len];
                let mut b = vec![0.0f32; len];
                filter_span(&mut a, &taps, &src);
                span_as_dispatched(&mut b, &taps, &src, false);
                assert_eq!(a, b, "len {len}, {ntaps} taps");
                let mut c = vec![0.0f32; len];
                filter_span_baseline(&mut c, &taps, &src);
                // Each of `ntaps` products of at most 4 in size, rounded once more or less.
                let bound = ntaps as f32 * 4.0 * f32::EPSILON;
                for (x, y) in a.iter().zip(&c) {
                    assert!(
                        (x - y).abs() <= bound,
                        "len {len}: {x} against baseline {y}"
                    );
                }
                let mut d = a.clone();
                filter_span_add(&mut d, &taps, &src);
                let mut e = a.clone();
                span_as_dispatched(&mut e, &taps, &src, true);
                assert_eq!(d, e, "add, len {len}");
            }
        }
    }

    /// [`filter_span_ranks`] (dispatched and baseline, 1 to 3 outputs) gives each output the
    /// bits of the one-output span over that output's nonzero weights, with weights that are 0
    /// for some outputs and not others, over awkward lengths.
    #[test]
    fn ranks_span_matches_one_span_per_rank_bit_for_bit() {
        let mut rng = crate::random::SplitMix64::new(23);
        for len in [1usize, 3, 4, 11, 12, 13, 31, 64, 65, 200, 1283] {
            for ntaps in [1usize, 5, 33, 65] {
                let taps: Vec<(usize, [f32; MAX_RANKS])> = (0..ntaps)
                    .map(|k| {
                        let w = std::array::from_fn(|i| {
                            if (k + i) % 4 == 1 {
                                0.0
                            } else {
                                rng.range(-1.0, 1.0)
                            }
                        });
                        (k * 3, w)
                    })
                    .collect();
                let src: Vec<f32> = (0..len + 3 * ntaps).map(|_| rng.range(-4.0, 4.0)).collect();
                for r in 1..=MAX_RANKS {
                    for (name, f, span_as) in [
                        (
                            "dispatched",
                            filter_span_ranks
                                as fn(&mut [&mut [f32]], &[(usize, [f32; MAX_RANKS])], &[f32]),
                            span_as_dispatched as fn(&mut [f32], &[(f32, usize)], &[f32], bool),
                        ),
                        ("baseline", filter_span_ranks_baseline, span_as_baseline),
                    ] {
                        let mut out = vec![vec![f32::NAN; len]; r];
                        let mut refs: Vec<&mut [f32]> =
                            out.iter_mut().map(|o| o.as_mut_slice()).collect();
                        f(&mut refs, &taps, &src);
                        for (i, got) in out.iter().enumerate() {
                            let list: Vec<(f32, usize)> = taps
                                .iter()
                                .filter(|t| t.1[i] != 0.0)
                                .map(|t| (t.1[i], t.0))
                                .collect();
                            let mut want = vec![0.0f32; len];
                            span_as(&mut want, &list, &src, false);
                            assert_eq!(
                                got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                                "{name}: {len} floats, {ntaps} taps, output {i} of {r}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// [`filter_span_ranks_folded`] (dispatched and baseline, 1 to 3 outputs, any number of
    /// them even) against the unfolded taps it stands for, summed in f64: within a rounding per
    /// tap; and the dispatched version against the baseline within the same bound.
    #[test]
    fn folded_ranks_span_is_the_unfolded_filter() {
        let mut rng = crate::random::SplitMix64::new(31);
        for len in [1usize, 3, 4, 9, 16, 17, 63, 64, 65, 200, 1283] {
            for n in [0usize, 1, 5, 32] {
                let src: Vec<f32> = (0..len + 2 * n + 1).map(|_| rng.range(-4.0, 4.0)).collect();
                let cw: [f32; MAX_RANKS] = std::array::from_fn(|_| rng.range(-1.0, 1.0));
                let pairs: Vec<TapPair> = (1..=n)
                    .map(|d| (n - d, n + d, std::array::from_fn(|_| rng.range(-1.0, 1.0))))
                    .collect();
                for r in 1..=MAX_RANKS {
                    for even in 0..=r {
                        // Odd filters have no centre tap.
                        let mut cw = cw;
                        cw[even..].iter_mut().for_each(|w| *w = 0.0);
                        let mut got = vec![vec![vec![f32::NAN; len]; r]; 2];
                        for (g, f) in got.iter_mut().zip([
                            filter_span_ranks_folded
                                as fn(&mut [&mut [f32]], usize, _, &[TapPair], &[f32]),
                            filter_span_ranks_folded_baseline,
                        ]) {
                            let mut refs: Vec<&mut [f32]> =
                                g.iter_mut().map(|o| o.as_mut_slice()).collect();
                            f(&mut refs, even, (n, cw), &pairs, &src);
                        }
                        for k in 0..r {
                            let sign = if k < even { 1.0 } else { -1.0 };
                            for p in 0..len {
                                let mut want = f64::from(cw[k]) * f64::from(src[n + p]);
                                let mut size = want.abs();
                                for &(lo, hi, w) in &pairs {
                                    let term = f64::from(w[k])
                                        * (f64::from(src[hi + p]) + sign * f64::from(src[lo + p]));
                                    want += term;
                                    size += term.abs();
                                }
                                let bound = 4.0 * (n + 1) as f64 * f64::from(f32::EPSILON) * size;
                                for (name, g) in ["dispatched", "baseline"].iter().zip(&got) {
                                    let v = f64::from(g[k][p]);
                                    assert!(
                                        (v - want).abs() <= bound + 1e-30,
                                        "{name}: {len} floats, {n} pairs, output {k} of {r} \
                                         ({even} even), float {p}: {v} against {want}"
                                    );
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// Each row of [`filter_rows`] (dispatched and baseline, 1 to 8 rows, overwriting and
    /// adding) gets the bits of the one-row filter (summing as it does, fused or not) over its
    /// own list of nonzero taps, for
    /// lengths with whole blocks, partial blocks and single floats left over, with zero taps
    /// among the others and source rows repeated in any order, as clamped rows are.
    #[test]
    fn filter_rows_match_the_span_filter_bit_for_bit() {
        let mut rng = crate::random::SplitMix64::new(5);
        for (len, ntaps) in [(1, 1), (5, 3), (37, 7), (200, 25), (333, 13), (1100, 65)] {
            for m in 1..=MAX_ROWS {
                let rows = ntaps + m - 1;
                let src: Vec<f32> = (0..len * rows).map(|_| rng.range(-2.0, 5.0)).collect();
                let taps: Vec<f32> = (0..ntaps)
                    .map(|i| {
                        if i % 5 == 2 {
                            0.0
                        } else {
                            rng.range(-0.5, 1.0)
                        }
                    })
                    .collect();
                let base: Vec<usize> = (0..rows).map(|_| len * rng.below(rows)).collect();
                let start: Vec<Vec<f32>> = (0..m)
                    .map(|_| (0..len).map(|_| rng.range(-1.0, 1.0)).collect())
                    .collect();
                for add in [false, true] {
                    for (name, f, span_as) in [
                        (
                            "dispatched",
                            filter_rows as fn(&mut [&mut [f32]], _, _, _, _),
                            span_as_dispatched as fn(&mut [f32], &[(f32, usize)], &[f32], bool),
                        ),
                        ("baseline", filter_rows_baseline, span_as_baseline),
                    ] {
                        let mut out = start.clone();
                        let mut refs: Vec<&mut [f32]> =
                            out.iter_mut().map(|o| o.as_mut_slice()).collect();
                        f(&mut refs, &taps, &base, &src, add);
                        for (r, got) in out.iter().enumerate() {
                            let list: Vec<(f32, usize)> = taps
                                .iter()
                                .zip(&base[r..])
                                .filter(|(&w, _)| w != 0.0)
                                .map(|(&w, &b)| (w, b))
                                .collect();
                            let mut want = start[r].clone();
                            span_as(&mut want, &list, &src, add);
                            assert_eq!(
                                got.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                                want.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                                "{name}: {len} floats, {ntaps} taps, row {r} of {m}, add {add}"
                            );
                        }
                    }
                }
            }
        }
    }
}
