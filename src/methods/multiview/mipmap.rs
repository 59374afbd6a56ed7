//! Pass `mipmap`: for cone tracing (Lee et al. section 4.5), each layer's colours with their
//! coverage in alpha, box-filtered level by level; a cone of diameter `d` pixels reads the
//! two levels around `log2 d`, bilinearly ([`LayerMip::fetch`]; eight lanes at a time in
//! `trace`). Built a layer to a task.

use glam::Vec2;
use half::slice::HalfFloatSliceExt;

use crate::image::Rgba;
use crate::raster::DepthLayers;

/// Mipmaps of a layer's colour with coverage in alpha (alpha 1 where the layer has a surface,
/// 0 where it is empty), for cone tracing. Level 0 is the layer itself.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerMip {
    /// Levels 1, 2, ...: (width, height, premultiplied RGBA).
    pub(super) levels: Vec<(usize, usize, Vec<Rgba>)>,
    /// Per level kept, its width and height, for the eight-lane reads ([`cones`]).
    pub(super) dims: Vec<[i32; 2]>,
}

impl LayerMip {
    /// The mipmap of layer `l`, down to `max_level`.
    pub fn new(layers: &DepthLayers, l: usize, max_level: usize) -> Self {
        let (w, h) = (layers.width, layers.height);
        let mut levels: Vec<(usize, usize, Vec<Rgba>)> = Vec::new();
        if max_level > 0 && w * h > 0 {
            // Level 0, the layer's colours (converted a slice at a time: F16C where the CPU
            // has it, the same values), empty pixels transparent black.
            let plane = l * w * h..(l + 1) * w * h;
            let mut base = vec![[0.0f32; 4]; w * h];
            layers.color[plane.clone()]
                .as_flattened()
                .convert_to_f32_slice(base.as_flattened_mut());
            for (c, coc) in base.iter_mut().zip(&layers.coc_px[plane]) {
                if !coc.is_finite() {
                    *c = [0.0; 4];
                }
            }
            // `cur` is the last level made; each level made pushes the one before it (not
            // level 0, which the hits read from the layer itself).
            let mut cur = (w, h, base);
            let mut made = false;
            for _ in 0..max_level {
                let (pw, ph, ref p) = cur;
                if pw == 1 && ph == 1 {
                    break;
                }
                let (nw, nh) = (pw.div_ceil(2), ph.div_ceil(2));
                let mut next = vec![[0.0f32; 4]; nw * nh];
                for (y, row) in next.chunks_exact_mut(nw).enumerate() {
                    let (r0, r1) = (2 * y * pw, (2 * y + 1).min(ph - 1) * pw);
                    for (x, out) in row.iter_mut().enumerate() {
                        let (x0, x1) = (2 * x, (2 * x + 1).min(pw - 1));
                        let mut s = [0.0f32; 4];
                        for c in [p[r0 + x0], p[r0 + x1], p[r1 + x0], p[r1 + x1]] {
                            for k in 0..4 {
                                s[k] += 0.25 * c[k];
                            }
                        }
                        *out = s;
                    }
                }
                let before = std::mem::replace(&mut cur, (nw, nh, next));
                if made {
                    levels.push(before);
                }
                made = true;
            }
            if made {
                levels.push(cur);
            }
        }
        let dims = levels.iter().map(|l| [l.0 as i32, l.1 as i32]).collect();
        Self { levels, dims }
    }

    /// The premultiplied colour and coverage at level `level` (>= 1) at image position `q`
    /// (pixels), filtered bilinearly between the level's texel centres, clamped to the coarsest
    /// level kept.
    #[inline(always)]
    pub fn fetch(&self, level: usize, q: Vec2) -> Rgba {
        let k = level.min(self.levels.len());
        if k == 0 {
            return [0.0; 4];
        }
        let (w, h, data) = &self.levels[k - 1];
        // 1 / 2^k is exact, so the product is the quotient bit for bit.
        let inv = 1.0 / (1u32 << k) as f32;
        let (u, v) = ((q.x * inv - 0.5).max(0.0), (q.y * inv - 0.5).max(0.0));
        let (x0, y0) = ((u as usize).min(w - 1), (v as usize).min(h - 1));
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (u - x0 as f32, v - y0 as f32);
        let (fx, fy) = (fx.clamp(0.0, 1.0), fy.clamp(0.0, 1.0));
        let mut out = [0.0f32; 4];
        for (x, y, wgt) in [
            (x0, y0, (1.0 - fx) * (1.0 - fy)),
            (x1, y0, fx * (1.0 - fy)),
            (x0, y1, (1.0 - fx) * fy),
            (x1, y1, fx * fy),
        ] {
            let c = data[y * w + x];
            for (o, v) in out.iter_mut().zip(c) {
                *o += wgt * v;
            }
        }
        out
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(|l| l.2.len() * 16).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::from_half;

    #[test]
    fn mip_levels_are_the_means_of_their_blocks() {
        // Level k at texel (x, y) is the mean of the layer's 2^k x 2^k block there (empty
        // pixels counted as transparent black), computed here directly from the pixels, not
        // level by level; odd sizes check the clamped last texels' neighbours.
        let (w, h) = (37, 23);
        let layers = super::super::trace::tests::random_layer(w, h, 5);
        let mip = LayerMip::new(&layers, 0, 4);
        assert_eq!(mip.levels.len(), 4);
        let pixel = |x: usize, y: usize| -> Rgba {
            let i = y * w + x;
            if layers.coc_px[i].is_finite() {
                from_half(&layers.color[i])
            } else {
                [0.0; 4]
            }
        };
        for (k, (lw, lh, data)) in (1..).zip(&mip.levels) {
            let s = 1usize << k;
            assert_eq!((*lw, *lh), (w.div_ceil(s), h.div_ceil(s)), "level {k}");
            for ty in 0..h / s {
                for tx in 0..w / s {
                    let mut want = [0.0f64; 4];
                    for y in ty * s..(ty + 1) * s {
                        for x in tx * s..(tx + 1) * s {
                            for (m, c) in want.iter_mut().zip(pixel(x, y)) {
                                *m += c as f64 / (s * s) as f64;
                            }
                        }
                    }
                    let got = data[ty * lw + tx];
                    for c in 0..4 {
                        assert!(
                            (got[c] as f64 - want[c]).abs() <= 1e-5 * (1.0 + want[c].abs()),
                            "level {k} texel ({tx}, {ty}) channel {c}: {} vs {}",
                            got[c],
                            want[c]
                        );
                    }
                }
            }
        }
        // No levels asked for, none made.
        assert!(LayerMip::new(&layers, 0, 0).levels.is_empty());
    }
}
