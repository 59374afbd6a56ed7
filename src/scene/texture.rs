use glam::Vec2;

use crate::image::{ColorImage, Rgba};

/// Texture filtering for magnification / minification (glTF sampler filters).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum FilterMode {
    /// Nearest texel.
    Nearest,
    /// Bilinear between the four nearest texels.
    #[default]
    Linear,
}

/// Texture coordinate wrapping (glTF sampler wrap modes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum WrapMode {
    /// Tile the texture.
    #[default]
    Repeat,
    /// Clamp to the edge texel.
    ClampToEdge,
    /// Tile with every other copy mirrored.
    MirroredRepeat,
}

/// How a texture is sampled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextureSampler {
    /// Filter when a texel covers more than a pixel.
    pub mag_filter: FilterMode,
    /// Filter within a mip level when minifying.
    pub min_filter: FilterMode,
    /// Filter between mip levels; `None` disables mipmapping (level 0 only).
    pub mip_filter: Option<FilterMode>,
    /// Wrapping along u.
    pub wrap_u: WrapMode,
    /// Wrapping along v.
    pub wrap_v: WrapMode,
}

impl Default for TextureSampler {
    /// Trilinear, repeat: glTF's recommended default.
    fn default() -> Self {
        Self {
            mag_filter: FilterMode::Linear,
            min_filter: FilterMode::Linear,
            mip_filter: Some(FilterMode::Linear),
            wrap_u: WrapMode::Repeat,
            wrap_v: WrapMode::Repeat,
        }
    }
}

/// A texture in linear light with its mip chain (level 0 first, halving to 1x1 by a box filter).
#[derive(Clone, Debug, PartialEq)]
pub struct Texture {
    levels: Vec<ColorImage>,
}

impl Texture {
    /// Builds a texture and its mip chain from a linear-light image (straight alpha). Mips are
    /// averaged with alpha-weighted colour so cut-out edges do not darken.
    pub fn new(level0: ColorImage) -> Self {
        let mut levels = vec![level0];
        loop {
            let prev = levels.last().expect("at least one level");
            let (w, h) = (prev.width(), prev.height());
            if w == 1 && h == 1 {
                break;
            }
            let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
            let mut data = Vec::with_capacity(nw * nh);
            for y in 0..nh {
                for x in 0..nw {
                    let mut acc = [0.0f32; 4];
                    let mut n = 0.0;
                    for dy in 0..2 {
                        for dx in 0..2 {
                            let sx = (2 * x + dx).min(w - 1);
                            let sy = (2 * y + dy).min(h - 1);
                            let p = prev.get(sx, sy);
                            for c in 0..3 {
                                acc[c] += p[c] * p[3];
                            }
                            acc[3] += p[3];
                            n += 1.0;
                        }
                    }
                    let a = acc[3];
                    let px = if a > 0.0 {
                        [acc[0] / a, acc[1] / a, acc[2] / a, a / n]
                    } else {
                        [0.0; 4]
                    };
                    data.push(px);
                }
            }
            levels.push(ColorImage::from_vec(nw, nh, data).expect("size matches"));
        }
        Self { levels }
    }

    /// Width and height of level 0.
    pub fn size(&self) -> (usize, usize) {
        (self.levels[0].width(), self.levels[0].height())
    }

    /// The mip levels, level 0 first.
    pub fn levels(&self) -> &[ColorImage] {
        &self.levels
    }

    /// Samples at `uv` (glTF convention: (0,0) is the top-left corner of the image) with a
    /// footprint: `lod` is log2 of the texels per pixel at level 0.
    pub fn sample(&self, sampler: &TextureSampler, uv: Vec2, lod: f32) -> Rgba {
        if lod <= 0.0 || sampler.mip_filter.is_none() {
            let filter = if lod <= 0.0 {
                sampler.mag_filter
            } else {
                sampler.min_filter
            };
            return self.sample_level(0, filter, sampler, uv);
        }
        let max_level = (self.levels.len() - 1) as f32;
        let lod = lod.min(max_level);
        match sampler.mip_filter {
            Some(FilterMode::Nearest) => {
                self.sample_level((lod + 0.5) as usize, sampler.min_filter, sampler, uv)
            }
            _ => {
                let l0 = lod.floor();
                let t = lod - l0;
                let a = self.sample_level(l0 as usize, sampler.min_filter, sampler, uv);
                if t <= 0.0 {
                    return a;
                }
                let b = self.sample_level(
                    (l0 as usize + 1).min(self.levels.len() - 1),
                    sampler.min_filter,
                    sampler,
                    uv,
                );
                std::array::from_fn(|c| a[c] + (b[c] - a[c]) * t)
            }
        }
    }

    #[inline]
    fn sample_level(
        &self,
        level: usize,
        filter: FilterMode,
        sampler: &TextureSampler,
        uv: Vec2,
    ) -> Rgba {
        let img = &self.levels[level];
        let (w, h) = (img.width() as i32, img.height() as i32);
        let x = uv.x * w as f32;
        let y = uv.y * h as f32;
        if !(x.is_finite() && y.is_finite()) {
            return img.get(0, 0);
        }
        // Far outside the texture, wrap in float first so the integer conversion cannot saturate.
        let (x, y) = (reduce(x, w, sampler.wrap_u), reduce(y, h, sampler.wrap_v));
        match filter {
            FilterMode::Nearest => {
                let ix = wrap(fast_floor(x), w, sampler.wrap_u);
                let iy = wrap(fast_floor(y), h, sampler.wrap_v);
                img.get(ix, iy)
            }
            FilterMode::Linear => {
                let fx = x - 0.5;
                let fy = y - 0.5;
                let x0 = fast_floor(fx);
                let y0 = fast_floor(fy);
                let tx = fx - x0 as f32;
                let ty = fy - y0 as f32;
                let (xa, xb) = wrap_pair(x0, w, sampler.wrap_u);
                let (ya, yb) = wrap_pair(y0, h, sampler.wrap_v);
                let row_a = img.row(ya);
                let row_b = img.row(yb);
                let (p00, p10, p01, p11) = (row_a[xa], row_a[xb], row_b[xa], row_b[xb]);
                std::array::from_fn(|c| {
                    let top = p00[c] + (p10[c] - p00[c]) * tx;
                    let bottom = p01[c] + (p11[c] - p01[c]) * tx;
                    top + (bottom - top) * ty
                })
            }
        }
    }
}

/// `floor` without a libm call (x86-64 without SSE4.1 has no rounding instruction).
#[inline]
fn fast_floor(x: f32) -> i32 {
    let i = x as i32;
    i - i32::from((i as f32) > x)
}

/// Brings a texel coordinate into a small range around the texture without changing the
/// texel it wraps to.
#[inline]
fn reduce(x: f32, n: i32, mode: WrapMode) -> f32 {
    // Integer texel indices are exact up to 2^24; only beyond that is a float reduction needed.
    if x.abs() < 16_777_216.0 {
        return x;
    }
    let n = n as f32;
    match mode {
        WrapMode::Repeat => x.rem_euclid(n),
        WrapMode::MirroredRepeat => x.rem_euclid(2.0 * n),
        WrapMode::ClampToEdge => x.clamp(-1.0, n + 1.0),
    }
}

/// Wrapped indices of texels `i` and `i + 1`.
#[inline]
fn wrap_pair(i: i32, n: i32, mode: WrapMode) -> (usize, usize) {
    match mode {
        WrapMode::Repeat if (0..n - 1).contains(&i) => (i as usize, i as usize + 1),
        WrapMode::ClampToEdge => (i.clamp(0, n - 1) as usize, (i + 1).clamp(0, n - 1) as usize),
        _ => (wrap(i, n, mode), wrap(i + 1, n, mode)),
    }
}

/// log2 accurate to about 0.01, for mip level selection (no libm call).
#[inline]
pub(crate) fn fast_log2(x: f32) -> f32 {
    let bits = x.to_bits();
    let exponent = ((bits >> 23) & 0xff) as i32 - 127;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000); // mantissa in [1, 2)
                                                                // Quadratic fit of log2 on [1, 2]; error below 0.005.
    let t = m - 1.0;
    exponent as f32 + t * (1.346_555_7 - 0.346_555_7 * t)
}

#[inline]
fn wrap(i: i32, n: i32, mode: WrapMode) -> usize {
    let r = match mode {
        // Power-of-two sizes (the common case) wrap with a mask instead of a division.
        WrapMode::Repeat if n & (n - 1) == 0 => i & (n - 1),
        WrapMode::Repeat => i.rem_euclid(n),
        WrapMode::ClampToEdge => i.clamp(0, n - 1),
        WrapMode::MirroredRepeat => {
            let period = 2 * n;
            let m = i.rem_euclid(period);
            if m < n {
                m
            } else {
                period - 1 - m
            }
        }
    };
    r.clamp(0, n - 1) as usize
}
