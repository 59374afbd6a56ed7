//! Pass `cull`: per layer, the minimum signed CoC over the window around each pixel that the
//! pixel's lens rays (and their cones) can reach in that layer, for early layer culling (Lee et
//! al. section 4.3): a layer whose minimum there lies beyond the rays' segment cannot be hit,
//! and empty regions (minimum +inf) are skipped.
//!
//! The paper queries an N-buffer (Décoret 2005), which answers a window of any size with four
//! lookups into one of `log2` levels. Here every pixel of a layer asks for the same window
//! radius, so the minimum over it is computed once per pixel, directly: a running minimum
//! along the rows, then along the columns (van Herk and Gil-Werman: three comparisons per
//! pixel and pass, whatever the radius). The same values as the N-buffer's query (a minimum is
//! exact in any order), one image instead of up to nine, and one lookup per pixel and layer.

use rayon::prelude::*;

/// The minimum of an image over the square window of radius `radius` around each pixel,
/// clamped to the image.
#[derive(Clone, Debug, PartialEq)]
pub struct WindowMin {
    width: usize,
    values: Vec<f32>,
}

impl WindowMin {
    /// The window minimum of `values` (`width * height`, row-major) at radius `radius`.
    pub fn new(values: &[f32], width: usize, height: usize, radius: usize) -> Self {
        assert_eq!(values.len(), width * height, "image size");
        let rows = rows_min(values, width, radius);
        Self {
            width,
            values: columns_min(&rows, width, height, radius),
        }
    }

    /// The minimum over the window around pixel `(x, y)`.
    #[inline(always)]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.values[y * self.width + x]
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.values.len() * 4
    }
}

/// Each row of `values` (rows of `width`) replaced by its running minimum of radius `radius`.
fn rows_min(values: &[f32], width: usize, radius: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; values.len()];
    if width == 0 {
        return out;
    }
    out.par_chunks_mut(width)
        .zip(values.par_chunks(width))
        .for_each_init(Scratch::default, |scratch, (dst, src)| {
            running_min(src, radius, dst, scratch)
        });
    out
}

/// Buffers of [`running_min`], kept across the rows of a thread.
#[derive(Default)]
struct Scratch {
    prefix: Vec<f32>,
    suffix: Vec<f32>,
}

/// `dst[x]` = the minimum of `src` over `[x - radius, x + radius]` clamped to `src`. Van Herk
/// and Gil-Werman: the row, padded with +inf by `radius` at both ends, is cut into blocks of
/// the window's length `k`; a window starting at `a` covers the end of `a`'s block and the
/// start of the next, so its minimum is the suffix minimum at `a` and the prefix minimum at
/// `a + k - 1`.
fn running_min(src: &[f32], radius: usize, dst: &mut [f32], scratch: &mut Scratch) {
    let n = src.len();
    // A window wider than the row sees all of it from every pixel.
    let radius = radius.min(n);
    let k = 2 * radius + 1;
    let padded = (n + 2 * radius).div_ceil(k) * k;
    let at = |i: usize| {
        if i >= radius && i - radius < n {
            src[i - radius]
        } else {
            f32::INFINITY
        }
    };
    let Scratch { prefix, suffix } = scratch;
    prefix.clear();
    prefix.resize(padded, f32::INFINITY);
    suffix.clear();
    suffix.resize(padded, f32::INFINITY);
    for ((start, pre), suf) in (0..padded)
        .step_by(k)
        .zip(prefix.chunks_exact_mut(k))
        .zip(suffix.chunks_exact_mut(k))
    {
        let mut run = f32::INFINITY;
        for (i, p) in (start..).zip(pre.iter_mut()) {
            run = run.min(at(i));
            *p = run;
        }
        let mut run = f32::INFINITY;
        for (i, s) in (start..start + k).zip(suf.iter_mut()).rev() {
            run = run.min(at(i));
            *s = run;
        }
    }
    for (a, d) in dst.iter_mut().enumerate() {
        *d = suffix[a].min(prefix[a + k - 1]);
    }
}

/// Each column of `values` (`width x height`, row-major) replaced by its running minimum of
/// radius `radius`: [`running_min`]'s blocks, a whole row at a time (the rows are contiguous,
/// so the minima run along them eight or sixteen columns to an instruction, with no
/// transpose). Block `b` of the padded column gives the output rows whose windows start in it,
/// from its suffix minima and the next block's prefix minima: a task per block.
fn columns_min(values: &[f32], width: usize, height: usize, radius: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; values.len()];
    if width == 0 || height == 0 {
        return out;
    }
    let radius = radius.min(height);
    let k = 2 * radius + 1;
    // Row `i` of the column padded with +inf by `radius` at both ends.
    let row = |i: usize| {
        (i >= radius && i - radius < height).then(|| &values[(i - radius) * width..][..width])
    };
    out.par_chunks_mut(k * width).enumerate().for_each_init(
        Vec::new,
        |scratch: &mut Vec<f32>, (b, dst)| {
            // The block's suffix minima, then the next block's prefix minima, row by row.
            scratch.clear();
            scratch.resize((2 * k + 1) * width, f32::INFINITY);
            let (suffix, rest) = scratch.split_at_mut(k * width);
            let (prefix, run) = rest.split_at_mut(k * width);
            let start = b * k;
            for (j, s) in suffix.chunks_exact_mut(width).enumerate().rev() {
                if let Some(src) = row(start + j) {
                    for (r, &v) in run.iter_mut().zip(src) {
                        *r = r.min(v);
                    }
                }
                s.copy_from_slice(run);
            }
            run.fill(f32::INFINITY);
            for (j, p) in prefix.chunks_exact_mut(width).enumerate() {
                if let Some(src) = row(start + k + j) {
                    for (r, &v) in run.iter_mut().zip(src) {
                        *r = r.min(v);
                    }
                }
                p.copy_from_slice(run);
            }
            // A window starting at padded row `a` (output row `a`) ends at `a + k - 1`.
            for (j, d) in dst.chunks_exact_mut(width).enumerate() {
                let s = &suffix[j * width..][..width];
                match j.checked_sub(1) {
                    // The window is the block itself.
                    None => d.copy_from_slice(s),
                    Some(i) => {
                        let p = &prefix[i * width..][..width];
                        for ((o, &a), &c) in d.iter_mut().zip(s).zip(p) {
                            *o = a.min(c);
                        }
                    }
                }
            }
        },
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::SplitMix64;

    #[test]
    fn window_minimum_agrees_with_a_scan() {
        // Against the minimum found by scanning each window, clamped at the borders: radii from
        // 0 to wider than the image, images with a row or a column only, +inf (empty) pixels.
        let mut rng = SplitMix64::new(3);
        for (w, h) in [(1, 1), (1, 9), (13, 1), (17, 11), (40, 23)] {
            let values: Vec<f32> = (0..w * h)
                .map(|_| {
                    if rng.below(4) == 0 {
                        f32::INFINITY
                    } else {
                        rng.range(-50.0, 50.0)
                    }
                })
                .collect();
            for radius in [0, 1, 2, 3, 7, 12, 30, 100] {
                let got = WindowMin::new(&values, w, h, radius);
                for y in 0..h {
                    for x in 0..w {
                        let mut want = f32::INFINITY;
                        for v in y.saturating_sub(radius)..=(y + radius).min(h - 1) {
                            for u in x.saturating_sub(radius)..=(x + radius).min(w - 1) {
                                want = want.min(values[v * w + u]);
                            }
                        }
                        assert_eq!(got.at(x, y), want, "{w}x{h} radius {radius} at ({x}, {y})");
                    }
                }
            }
        }
    }
}
