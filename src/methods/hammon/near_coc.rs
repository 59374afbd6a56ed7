//! Pass `near_coc` (section 28.4; Listings 28-2 `DofNearCoc` and 28-3 `SmallBlur`): the near
//! CoC that spreads an out-of-focus foreground over its surroundings, then its 3x3 blur.
//!
//! Reads the quarter-resolution "shrunk" image (colour and near blur `D0`, pass `downsample`)
//! and its Gaussian blur (blurred near blur `DB`, pass `blur`). Per texel, the near blur of the
//! larger of two neighbouring CoCs is estimated from `DB = (D0 + D1) / 2` as
//! `D = max(D0, 2 DB - D0) = 2 max(DB, D0) - D0`, clamped to [0, 1] (the chapter's render target
//! holds a blur amount, and any value >= 1 blends the same). The texels of (shrunk colour, D)
//! are then blurred with the 3x3 weights 1/16 (corners), 2/16 (edges), 4/16 (centre), which the
//! listing takes with four bilinear taps at half-texel offsets, to smooth the corners where the
//! straight-edge assumption breaks. Writes the "medium blur" image: colour and final near CoC.

use rayon::prelude::*;

use super::{saturate, QuarterImage};
use crate::image::{ColorImage, GrayImage, Rgba};
use crate::{Error, Result};

/// Fails unless both images are valid and the same size.
fn check_sizes(shrunk: &QuarterImage, blurred: &QuarterImage) -> Result<()> {
    shrunk.check()?;
    blurred.check()?;
    if shrunk.color.same_size(&blurred.color) {
        Ok(())
    } else {
        Err(Error::Mismatch(format!(
            "shrunk image is {}x{} but the blurred one is {}x{}",
            shrunk.width(),
            shrunk.height(),
            blurred.width(),
            blurred.height()
        )))
    }
}

/// Listing 28-2: the near blur of a texel from its own (`shrunk`) and blurred values.
#[inline(always)]
fn near(shrunk: f32, blurred: f32) -> f32 {
    saturate(2.0 * blurred.max(shrunk) - shrunk)
}

/// Computes the near CoC of Listing 28-2 and blurs it, with the shrunk colour, by Listing 28-3.
pub fn near_coc(shrunk: &QuarterImage, blurred: &QuarterImage) -> Result<QuarterImage> {
    near_coc_with(shrunk, blurred, near_row)
}

/// [`near_coc`] built for the portable baseline only (no run-time dispatch): the twin the
/// dispatched versions are tested against, bit for bit.
pub fn near_coc_baseline(shrunk: &QuarterImage, blurred: &QuarterImage) -> Result<QuarterImage> {
    near_coc_with(shrunk, blurred, near_row_inner)
}

/// Per-thread scratch rows of [`near_coc`]: the vertical blurs of colour and near CoC.
type RowScratch = (Vec<Rgba>, Vec<f32>);

fn near_coc_with(
    shrunk: &QuarterImage,
    blurred: &QuarterImage,
    row_fn: impl Fn(&QuarterImage, &QuarterImage, usize, &mut RowScratch, &mut [Rgba], &mut [f32])
        + Sync,
) -> Result<QuarterImage> {
    check_sizes(shrunk, blurred)?;
    let (w, h) = (shrunk.width(), shrunk.height());
    let mut out_color = vec![[0.0f32; 4]; w * h];
    let mut out_coc = vec![0.0f32; w * h];
    out_color
        .par_chunks_mut(w)
        .zip(out_coc.par_chunks_mut(w))
        .enumerate()
        .for_each_init(
            || (vec![[0.0f32; 4]; w], vec![0.0f32; w]),
            |scratch, (y, (out_c, out_k))| row_fn(shrunk, blurred, y, scratch, out_c, out_k),
        );
    Ok(QuarterImage {
        color: ColorImage::from_vec(w, h, out_color)?,
        coc: GrayImage::from_vec(w, h, out_coc)?,
    })
}

/// One output row `y` of [`near_coc`]. Compiled for several instruction sets and chosen at
/// run time ([`multiversion`]); the same arithmetic in every version, so the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512vl+avx2",
    "x86_64+avx2",
    "aarch64+neon"
))]
fn near_row(
    shrunk: &QuarterImage,
    blurred: &QuarterImage,
    y: usize,
    scratch: &mut RowScratch,
    out_c: &mut [Rgba],
    out_k: &mut [f32],
) {
    near_row_inner(shrunk, blurred, y, scratch, out_c, out_k);
}

#[inline(always)]
fn near_row_inner(
    shrunk: &QuarterImage,
    blurred: &QuarterImage,
    y: usize,
    (vert_c, vert_k): &mut RowScratch,
    out_c: &mut [Rgba],
    out_k: &mut [f32],
) {
    let (w, h) = (shrunk.width(), shrunk.height());
    // Vertical [1 2 1] / 4 of rows y - 1, y, y + 1 (clamped).
    let ys = [y.saturating_sub(1), y, (y + 1).min(h - 1)];
    let [c0, c1, c2] = ys.map(|yy| shrunk.color.row(yy));
    let columns = c0.iter().zip(c1).zip(c2);
    for (v, ((a, b), c)) in vert_c.iter_mut().zip(columns) {
        *v = std::array::from_fn(|ch| 0.25 * (a[ch] + 2.0 * b[ch] + c[ch]));
    }
    let [s0, s1, s2] = ys.map(|yy| shrunk.coc.row(yy));
    let [b0, b1, b2] = ys.map(|yy| blurred.coc.row(yy));
    let columns = (s0.iter().zip(b0))
        .zip(s1.iter().zip(b1))
        .zip(s2.iter().zip(b2));
    for (v, (((&sa, &ba), (&sb, &bb)), (&sc, &bc))) in vert_k.iter_mut().zip(columns) {
        *v = 0.25 * (near(sa, ba) + 2.0 * near(sb, bb) + near(sc, bc));
    }
    // Horizontal [1 2 1] / 4 (clamped): the ends, then the interior by windows.
    let blur3 = |a: f32, b: f32, c: f32| 0.25 * (a + 2.0 * b + c);
    let blur3c = |a: &Rgba, b: &Rgba, c: &Rgba| -> Rgba {
        std::array::from_fn(|ch| blur3(a[ch], b[ch], c[ch]))
    };
    let last = w - 1;
    out_c[0] = blur3c(&vert_c[0], &vert_c[0], &vert_c[last.min(1)]);
    out_k[0] = blur3(vert_k[0], vert_k[0], vert_k[last.min(1)]);
    if w > 1 {
        out_c[last] = blur3c(&vert_c[last - 1], &vert_c[last], &vert_c[last]);
        out_k[last] = blur3(vert_k[last - 1], vert_k[last], vert_k[last]);
    }
    for (o, v) in out_c[1..].iter_mut().zip(vert_c.windows(3)) {
        *o = blur3c(&v[0], &v[1], &v[2]);
    }
    for (o, v) in out_k[1..].iter_mut().zip(vert_k.windows(3)) {
        *o = blur3(v[0], v[1], v[2]);
    }
}

/// The straightforward twin of [`near_coc`]: Listing 28-2 on every texel into an image, then
/// Listing 28-3 as the average of four bilinear taps at (±0.5, ±0.5) texels with clamped
/// coordinates. Kept to test the fast version against.
pub fn naive(shrunk: &QuarterImage, blurred: &QuarterImage) -> Result<QuarterImage> {
    check_sizes(shrunk, blurred)?;
    let (w, h) = (shrunk.width(), shrunk.height());
    // Listing 28-2.
    let mut d = GrayImage::new(w, h, 0.0);
    for y in 0..h {
        for x in 0..w {
            let (s, b) = (shrunk.coc.get(x, y), blurred.coc.get(x, y));
            *d.get_mut(x, y) = saturate(2.0 * s.max(b) - s);
        }
    }
    // Listing 28-3: a bilinear tap half-way between texels x - 1 + i and y - 1 + j (i, j in
    // {0, 1} for the -0.5 tap, {1, 2} for the +0.5 tap) averages those four texels.
    let tap = |x: isize, y: isize, ox: isize, oy: isize| -> ([f32; 4], f32) {
        let mut c = [0.0f32; 4];
        let mut k = 0.0f32;
        for j in 0..2 {
            for i in 0..2 {
                let (sx, sy) = (x + ox + i, y + oy + j);
                for (a, v) in c.iter_mut().zip(shrunk.color.get_clamped(sx, sy)) {
                    *a += 0.25 * v;
                }
                k += 0.25 * d.get_clamped(sx, sy);
            }
        }
        (c, k)
    };
    let mut color = ColorImage::new(w, h, [0.0; 4]);
    let mut coc = GrayImage::new(w, h, 0.0);
    for y in 0..h as isize {
        for x in 0..w as isize {
            let mut c = [0.0f32; 4];
            let mut k = 0.0f32;
            for (ox, oy) in [(-1, -1), (0, -1), (-1, 0), (0, 0)] {
                let (tc, tk) = tap(x, y, ox, oy);
                for (a, v) in c.iter_mut().zip(tc) {
                    *a += 0.25 * v;
                }
                k += 0.25 * tk;
            }
            *color.get_mut(x as usize, y as usize) = c;
            *coc.get_mut(x as usize, y as usize) = k;
        }
    }
    Ok(QuarterImage { color, coc })
}
