//! Pass `nbuffer`: per layer, an N-buffer of the minimum signed CoC (Décoret 2005): level `k`
//! holds at each pixel the minimum over the `2^k x 2^k` window starting there (clamped at the
//! image border), so the minimum over any square window is four lookups into one level. Used
//! for early layer culling (Lee et al. section 4.3): a layer whose minimum over the region all
//! lens rays of a pixel can reach lies beyond the ray segment cannot be hit, and empty regions
//! (minimum +inf) are skipped.

use rayon::prelude::*;

/// Most N-buffer levels kept (windows up to 256 pixels; larger queries are not culled).
pub const MAX_LEVELS: usize = 9;

/// The N-buffer of one image.
#[derive(Clone, Debug, PartialEq)]
pub struct NBuffer {
    width: usize,
    height: usize,
    /// Level k: minimum over `[x, x + 2^k) x [y, y + 2^k)`, clamped.
    levels: Vec<Vec<f32>>,
}

impl NBuffer {
    /// Builds `levels` levels (1 to [`MAX_LEVELS`]) over `values` (`width * height`).
    pub fn new(values: &[f32], width: usize, height: usize, levels: usize) -> Self {
        let levels = levels.clamp(1, MAX_LEVELS);
        let mut out = vec![values.to_vec()];
        for k in 1..levels {
            let prev = &out[k - 1];
            let h = 1usize << (k - 1);
            let mut next = vec![0.0f32; width * height];
            next.par_chunks_mut(width.max(1))
                .enumerate()
                .for_each(|(y, row)| {
                    let y1 = (y + h).min(height - 1);
                    let (r0, r1) = (&prev[y * width..][..width], &prev[y1 * width..][..width]);
                    // Where `x + h` is inside the row, four slices side by side (vectorised);
                    // past it, the last pixel stands in for `x + h`, as the clamp says.
                    let inner = width.saturating_sub(h);
                    let (head, tail) = row.split_at_mut(inner);
                    for ((((v, a0), a1), b0), b1) in head
                        .iter_mut()
                        .zip(&r0[..inner])
                        .zip(&r0[h..])
                        .zip(&r1[..inner])
                        .zip(&r1[h..])
                    {
                        *v = a0.min(*a1).min(b0.min(*b1));
                    }
                    for (x, v) in (inner..).zip(tail) {
                        let x1 = width - 1;
                        *v = r0[x].min(r0[x1]).min(r1[x].min(r1[x1]));
                    }
                });
            out.push(next);
        }
        Self {
            width,
            height,
            levels: out,
        }
    }

    /// Minimum over the pixels `[x0, x1] x [y0, y1]` (inclusive, clamped to the image), or
    /// `None` when the window is larger than the coarsest level covers.
    #[inline]
    pub fn min(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> Option<f32> {
        let cx = |v: i64| v.clamp(0, self.width as i64 - 1) as usize;
        let cy = |v: i64| v.clamp(0, self.height as i64 - 1) as usize;
        let (x0, x1, y0, y1) = (cx(x0), cx(x1), cy(y0), cy(y1));
        let size = (x1 - x0 + 1).max(y1 - y0 + 1);
        let k = (usize::BITS - 1 - size.leading_zeros()) as usize;
        let level = self.levels.get(k)?;
        let s = 1usize << k;
        let (xa, ya) = (
            (x1 + 1).saturating_sub(s).max(x0),
            (y1 + 1).saturating_sub(s).max(y0),
        );
        let w = self.width;
        Some(
            level[y0 * w + x0]
                .min(level[y0 * w + xa])
                .min(level[ya * w + x0])
                .min(level[ya * w + xa]),
        )
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(|l| l.len() * 4).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn window_minimum_agrees_with_a_scan() {
        let (w, h) = (37, 23);
        let mut rng = crate::random::SplitMix64::new(9);
        let v: Vec<f32> = (0..w * h).map(|_| rng.range(-10.0, 10.0)).collect();
        let nb = NBuffer::new(&v, w, h, 6);
        for _ in 0..500 {
            let x0 = rng.below(w) as i64;
            let y0 = rng.below(h) as i64;
            let s = 1 + rng.below(20) as i64;
            let (x1, y1) = (x0 + s - 1, y0 + s - 1);
            let mut want = f32::INFINITY;
            for y in y0..=y1.min(h as i64 - 1) {
                for x in x0..=x1.min(w as i64 - 1) {
                    want = want.min(v[y as usize * w + x as usize]);
                }
            }
            assert_eq!(nb.min(x0, y0, x1, y1), Some(want), "{x0} {y0} {s}");
        }
    }
}
