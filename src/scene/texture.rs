use std::sync::OnceLock;

use glam::{Vec2, Vec4};
use rayon::prelude::*;

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
#[derive(Clone, Debug)]
pub struct Texture {
    levels: Vec<ColorImage>,
    /// Bounds on the alpha of lookups, made the first time an alpha-tested material asks.
    alpha_bounds: OnceLock<AlphaBounds>,
    /// Whether the alpha is two-valued ([`Texture::has_two_valued_alpha`]), found the first
    /// time it is asked.
    two_valued_alpha: OnceLock<bool>,
}

impl PartialEq for Texture {
    /// Textures are equal when their texels are (whether or not the bounds are made yet).
    fn eq(&self, other: &Self) -> bool {
        self.levels == other.levels
    }
}

/// Largest mean alpha of a texture for which alpha-mask materials take the early alpha test
/// (see [`Texture::wants_early_alpha_test`]).
pub(crate) const EARLY_ALPHA_TEST_MAX_MEAN: f32 = 0.5;

/// Alpha below which a texel counts as transparent, and above one minus which as opaque, in
/// [`Texture::has_two_valued_alpha`].
const TWO_VALUED_LOW: f32 = 0.02;

/// Largest share of the visible texels with alpha between transparent and opaque for
/// [`Texture::has_two_valued_alpha`]: an anti-aliased edge one or two texels wide around
/// shapes several texels across.
const TWO_VALUED_MAX_EDGE: f32 = 0.25;

/// Texels per side of the cells of [`AlphaBounds`].
const BOUND_CELL: usize = 4;

/// Upper bounds on the alpha a lookup can return, for rejecting the fragments of alpha-tested
/// materials before the full lookup (an early alpha test on a cheap coverage
/// lookup). Per mip level `L`, per cell of [`BOUND_CELL`]² texels: the largest alpha of level
/// `L` over the cell widened by [`BOUND_CELL`] texels on every side, the widening taken under
/// every wrap mode at once (clamped, repeated and mirrored indices all included).
///
/// Why that bounds a lookup at level `L` (and between `L` and `L + 1`) whose coordinate
/// `x = u w_L` lies in the cell: a bilinear footprint of level `L` reads texels
/// `floor(x - 1/2)` and the next, within 2 of `x`. One of level `L + 1` (width
/// `max(1, w_L / 2)` rounded down) reads texels `k`, `k + 1` with `k = floor(u w_(L+1) - 1/2)`,
/// and `2 u w_(L+1)` lies in `[x - 1, x]`, so `2k..=2k + 3` lies in `[x - 4, x + 3)`; each of
/// those texels is the mean of level-`L` texels `2k` and `2k + 1` (both axes), so at most their
/// largest alpha, and indices beyond the edge are wrapped at level `L + 1` onto texels whose
/// sources are again within the widened cell under one of the modes. Bilinear and trilinear
/// weights are convex, so the lookup's alpha is at most the bound (up to rounding, which the
/// test allows for).
#[derive(Clone, Debug)]
struct AlphaBounds {
    /// Per level (fixed-size tables, so lanes index them without range checks): width and
    /// height in texels (as `sample_level` scales by them), cells per row and column, and
    /// where its cells start in `max`.
    width: [f32; MAX_LEVELS],
    height: [f32; MAX_LEVELS],
    cols: [u32; MAX_LEVELS],
    rows: [u32; MAX_LEVELS],
    offset: [u32; MAX_LEVELS],
    /// Index of the last mip level.
    last: f32,
    /// The bounds of every level's cells, row-major, level after level.
    max: Vec<f32>,
}

/// More mip levels than a texture can have (sides below 2^31 texels).
const MAX_LEVELS: usize = 32;

impl AlphaBounds {
    fn new(levels: &[ColorImage]) -> Self {
        let mut b = Self {
            width: [1.0; MAX_LEVELS],
            height: [1.0; MAX_LEVELS],
            cols: [1; MAX_LEVELS],
            rows: [1; MAX_LEVELS],
            offset: [0; MAX_LEVELS],
            last: (levels.len() - 1) as f32,
            max: Vec::new(),
        };
        for (l, img) in levels.iter().enumerate().take(MAX_LEVELS) {
            let (w, h) = (img.width(), img.height());
            let (cols, rows) = (w.div_ceil(BOUND_CELL), h.div_ceil(BOUND_CELL));
            b.width[l] = w as f32;
            b.height[l] = h as f32;
            b.cols[l] = cols as u32;
            b.rows[l] = rows as u32;
            b.offset[l] = b.max.len() as u32;
            // Each cell's own largest alpha (a non-finite alpha bounds nothing), one read per
            // texel; then the largest over the cells holding the widened cell's texels, along
            // x and then along y (whole cells: a bound at least as large).
            let mut own = vec![0.0f32; rows * cols];
            let finite = own
                .par_chunks_mut(cols)
                .enumerate()
                .map(|(r, own_row)| {
                    let mut finite = true;
                    for y in r * BOUND_CELL..((r + 1) * BOUND_CELL).min(h) {
                        for (o, cell) in own_row.iter_mut().zip(img.row(y).chunks(BOUND_CELL)) {
                            // Branch-free (a NaN compares false and is caught by `finite`).
                            for p in cell {
                                let a = p[3];
                                finite &= a.is_finite();
                                *o = if a > *o { a } else { *o };
                            }
                        }
                    }
                    finite
                })
                .reduce(|| true, |a, b| a & b);
            if !finite {
                own.fill(f32::INFINITY);
            }
            let cells = |c: usize, n: usize| {
                let mut v: Vec<usize> = widened_cell(c, n)
                    .into_iter()
                    .map(|t| t / BOUND_CELL)
                    .collect();
                v.dedup();
                v
            };
            let xs: Vec<Vec<usize>> = (0..cols).map(|c| cells(c, w)).collect();
            let ys: Vec<Vec<usize>> = (0..rows).map(|c| cells(c, h)).collect();
            let mut along_x = vec![0.0f32; rows * cols];
            for r in 0..rows {
                for (c, xs) in xs.iter().enumerate() {
                    along_x[r * cols + c] =
                        xs.iter().map(|&cc| own[r * cols + cc]).fold(0.0, f32::max);
                }
            }
            for ys in &ys {
                for c in 0..cols {
                    let m = ys
                        .iter()
                        .map(|&rr| along_x[rr * cols + c])
                        .fold(0.0, f32::max);
                    b.max.push(m);
                }
            }
        }
        b
    }
}

/// The texel indices along an axis of `n` texels that cell `c`, widened by [`BOUND_CELL`]
/// texels on each side, covers under any wrap mode: indices beyond the edge contribute their
/// clamped, repeated and mirrored texels.
fn widened_cell(c: usize, n: usize) -> Vec<usize> {
    let n_i = n as i64;
    let first = (c * BOUND_CELL) as i64 - BOUND_CELL as i64;
    let mut out = Vec::new();
    for t in first..first + 3 * BOUND_CELL as i64 {
        if (0..n_i).contains(&t) {
            out.push(t as usize);
        } else {
            let m = t.rem_euclid(2 * n_i);
            let mirrored = if m < n_i { m } else { 2 * n_i - 1 - m };
            out.extend([t.clamp(0, n_i - 1), t.rem_euclid(n_i), mirrored].map(|i| i as usize));
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

impl Texture {
    /// Bytes the levels of a texture of `width` x `height` texels take (RGBA floats, level 0
    /// and every mip level down to 1x1): about 4/3 of level 0.
    pub fn bytes_for(width: usize, height: usize) -> u64 {
        let (mut w, mut h) = (width.max(1) as u64, height.max(1) as u64);
        let mut total = w * h;
        while w > 1 || h > 1 {
            w = (w / 2).max(1);
            h = (h / 2).max(1);
            total += w * h;
        }
        total * std::mem::size_of::<Rgba>() as u64
    }

    /// Bytes the levels of this texture take.
    pub fn bytes(&self) -> u64 {
        self.levels
            .iter()
            .map(|l| std::mem::size_of_val(l.pixels()) as u64)
            .sum()
    }

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
        Self {
            levels,
            alpha_bounds: OnceLock::new(),
            two_valued_alpha: OnceLock::new(),
        }
    }

    /// True when the alpha of level 0 is two-valued, a cut-out: of the texels not transparent
    /// (alpha at least [`TWO_VALUED_LOW`]), at most [`TWO_VALUED_MAX_EDGE`] lie between
    /// transparent and opaque (their anti-aliased edge). Then a lookup's filtered alpha is the
    /// share of its footprint that is opaque, whatever the alpha-mask cutoff, and an alpha-mask
    /// material can take its coverage from one lookup (alpha to coverage).
    pub(crate) fn has_two_valued_alpha(&self) -> bool {
        *self.two_valued_alpha.get_or_init(|| {
            let (mut seen, mut between) = (0usize, 0usize);
            for p in self.levels[0].pixels() {
                let a = p[3];
                seen += usize::from(a >= TWO_VALUED_LOW);
                between += usize::from((TWO_VALUED_LOW..=1.0 - TWO_VALUED_LOW).contains(&a));
            }
            seen > 0 && between as f32 <= TWO_VALUED_MAX_EDGE * seen as f32
        })
    }

    /// True when the early alpha test pays for alpha-mask materials with this texture: when
    /// most of it is cut away, its mean alpha (the 1x1 mip) at most
    /// [`EARLY_ALPHA_TEST_MAX_MEAN`]. The test costs about a quarter of a lookup per fragment
    /// and saves a lookup per fragment it rejects; it rejects fragments in wholly transparent
    /// cells, which a cut-out texture has in about the proportion it is transparent, less its
    /// edges (measured: on `grass`'s blade tufts 75% of the fragments are rejected and the frame
    /// is 10% faster; on panels with 30% of their area in round holes it was 5% slower).
    pub(crate) fn wants_early_alpha_test(&self) -> bool {
        let mean = self.levels[self.levels.len() - 1].get(0, 0)[3];
        mean <= EARLY_ALPHA_TEST_MAX_MEAN
    }

    /// Makes the bounds of the early alpha test now (they are otherwise made by the first
    /// lookup that needs them).
    pub(crate) fn prepare_alpha_bounds(&self) {
        self.alpha_bounds
            .get_or_init(|| AlphaBounds::new(&self.levels));
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
        self.sample_with(sampler, uv, lod, false)
    }

    /// True when `uv` lands within `SMALL_TEXELS` texels of the origin on level 0, and so on
    /// every level (they are no larger): finite, no float wrap needed, and `floor_small` exact.
    #[inline(always)]
    fn is_small(&self, uv: Vec2) -> bool {
        let base = &self.levels[0];
        // NaN fails both comparisons.
        (uv.x * base.width() as f32).abs() < SMALL_TEXELS
            && (uv.y * base.height() as f32).abs() < SMALL_TEXELS
    }

    #[inline(always)]
    /// `small`: the caller checked [`Texture::is_small`].
    fn sample_with(&self, sampler: &TextureSampler, uv: Vec2, lod: f32, small: bool) -> Rgba {
        if lod <= 0.0 || sampler.mip_filter.is_none() {
            let filter = if lod <= 0.0 {
                sampler.mag_filter
            } else {
                sampler.min_filter
            };
            return self.sample_level(0, filter, sampler, uv, small).to_array();
        }
        let last = self.levels.len() - 1;
        let lod = lod.min(last as f32);
        match sampler.mip_filter {
            Some(FilterMode::Nearest) => self
                .sample_level((lod + 0.5) as usize, sampler.min_filter, sampler, uv, small)
                .to_array(),
            _ => {
                // `lod` is in (0, last] here, so truncation is `floor` (and needs no libm call).
                let l0 = lod as usize;
                let t = lod - l0 as f32;
                let a = self.sample_level(l0, sampler.min_filter, sampler, uv, small);
                if t <= 0.0 {
                    return a.to_array();
                }
                let b =
                    self.sample_level((l0 + 1).min(last), sampler.min_filter, sampler, uv, small);
                (a + (b - a) * t).to_array()
            }
        }
    }

    /// One mip level, filtered. Colours are `Vec4` so that the blends run on all four channels
    /// at once; the arithmetic per channel is the scalar `a + (b - a) * t`.
    #[inline(always)]
    fn sample_level(
        &self,
        level: usize,
        filter: FilterMode,
        sampler: &TextureSampler,
        uv: Vec2,
        small: bool,
    ) -> Vec4 {
        let img = &self.levels[level];
        let (w, h) = (img.width() as i32, img.height() as i32);
        let x = uv.x * w as f32;
        let y = uv.y * h as f32;
        let floor = if small { floor_small } else { fast_floor };
        let (x, y) = if small {
            (x, y)
        } else {
            if !(x.is_finite() && y.is_finite()) {
                return Vec4::from_array(img.get(0, 0));
            }
            // Far outside the texture, wrap in float first so the integer conversion cannot
            // saturate.
            (reduce(x, w, sampler.wrap_u), reduce(y, h, sampler.wrap_v))
        };
        let texels = img.pixels();
        let texel = |ix: usize, iy: usize| Vec4::from_array(texels[iy * w as usize + ix]);
        match filter {
            FilterMode::Nearest => {
                let ix = wrap(floor(x), w, sampler.wrap_u);
                let iy = wrap(floor(y), h, sampler.wrap_v);
                texel(ix, iy)
            }
            FilterMode::Linear => {
                let fx = x - 0.5;
                let fy = y - 0.5;
                let x0 = floor(fx);
                let y0 = floor(fy);
                let tx = fx - x0 as f32;
                let ty = fy - y0 as f32;
                let (xa, xb) = wrap_pair(x0, w, sampler.wrap_u);
                let (ya, yb) = wrap_pair(y0, h, sampler.wrap_v);
                let (p00, p10, p01, p11) =
                    (texel(xa, ya), texel(xb, ya), texel(xa, yb), texel(xb, yb));
                let top = p00 + (p10 - p00) * tx;
                let bottom = p01 + (p11 - p01) * tx;
                top + (bottom - top) * ty
            }
        }
    }
}

/// The glTF default sampler (trilinear) with the same wrap mode on both axes.
const fn trilinear(wrap: WrapMode) -> TextureSampler {
    TextureSampler {
        mag_filter: FilterMode::Linear,
        min_filter: FilterMode::Linear,
        mip_filter: Some(FilterMode::Linear),
        wrap_u: wrap,
        wrap_v: wrap,
    }
}

/// Samplers that get a copy of the lookup of their own, with the modes known at compile time.
#[derive(Clone, Copy, Debug)]
enum Specialised {
    TrilinearRepeat,
    TrilinearClamp,
    Other,
}

/// A texture with its sampler, for many lookups: the filter and wrap dispatch, which
/// [`Texture::sample`] does per texel, is done once here for the common samplers.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BoundTexture<'a> {
    texture: &'a Texture,
    sampler: TextureSampler,
    specialised: Specialised,
}

impl<'a> BoundTexture<'a> {
    const REPEAT: TextureSampler = trilinear(WrapMode::Repeat);
    const CLAMP: TextureSampler = trilinear(WrapMode::ClampToEdge);

    pub(crate) fn new(texture: &'a Texture, sampler: TextureSampler) -> Self {
        let specialised = if sampler == Self::REPEAT {
            Specialised::TrilinearRepeat
        } else if sampler == Self::CLAMP {
            Specialised::TrilinearClamp
        } else {
            Specialised::Other
        };
        Self {
            texture,
            sampler,
            specialised,
        }
    }

    /// Width and height of level 0.
    #[inline]
    pub(crate) fn size(&self) -> (usize, usize) {
        self.texture.size()
    }

    /// Upper bounds on the alpha of [`BoundTexture::sample`] at `(u[i], v[i])` with `lod[i]`
    /// for every lane (see [`AlphaBounds`]), +inf where there is none (coordinates outside
    /// [0, 1], NaN).
    pub(crate) fn alpha_bound_batch(
        &self,
        u: &[f32; BATCH],
        v: &[f32; BATCH],
        lod: &[f32; BATCH],
        out: &mut [f32; BATCH],
    ) {
        let levels = &self.texture.levels;
        let b = self
            .texture
            .alpha_bounds
            .get_or_init(|| AlphaBounds::new(levels));
        let mipmapped = self.sampler.mip_filter.is_some();
        let mut cell = [0u32; BATCH];
        let mut inside = [false; BATCH];
        bound_cells(b, mipmapped, u, v, lod, &mut cell, &mut inside);
        let top = b.max.len() - 1;
        for i in 0..BATCH {
            let m = b.max[(cell[i] as usize).min(top)];
            out[i] = if inside[i] { m } else { f32::INFINITY };
        }
    }

    /// Same as [`Texture::sample`] with this sampler, bit for bit.
    #[inline(always)]
    pub(crate) fn sample(&self, uv: Vec2, lod: f32) -> Rgba {
        // Each arm inlines `sample_with` with constant modes.
        match self.specialised {
            Specialised::TrilinearRepeat if self.texture.is_small(uv) => {
                self.texture.sample_with(&Self::REPEAT, uv, lod, true)
            }
            Specialised::TrilinearClamp if self.texture.is_small(uv) => {
                self.texture.sample_with(&Self::CLAMP, uv, lod, true)
            }
            _ => self.texture.sample_with(&self.sampler, uv, lod, false),
        }
    }
}

/// The cell of [`AlphaBounds`] of each lane's lookup, and whether its coordinates are in
/// [0, 1] (the lanes without a bound). (Compiled for AVX-512 with run-time dispatch, its
/// gathers made the `grass` frame 15% slower than this portable loop.)
#[inline]
fn bound_cells(
    b: &AlphaBounds,
    mipmapped: bool,
    u: &[f32; BATCH],
    v: &[f32; BATCH],
    lod: &[f32; BATCH],
    cell: &mut [u32; BATCH],
    inside: &mut [bool; BATCH],
) {
    for i in 0..BATCH {
        inside[i] = (0.0..=1.0).contains(&u[i]) && (0.0..=1.0).contains(&v[i]);
        // The level `sample_with` reads (and the next, which the bound covers); a NaN
        // level of detail reads the last level, as there.
        let level = if lod[i] <= 0.0 || !mipmapped {
            0
        } else {
            (lod[i].min(b.last) as u32 % MAX_LEVELS as u32) as usize
        };
        // The texel coordinates as `sample_level` computes them.
        let x = u[i] * b.width[level];
        let y = v[i] * b.height[level];
        let cx = (x as u32 / BOUND_CELL as u32).min(b.cols[level] - 1);
        let cy = (y as u32 / BOUND_CELL as u32).min(b.rows[level] - 1);
        cell[i] = b.offset[level] + cy * b.cols[level] + cx;
    }
}

/// Lookups per batch of [`BoundTexture::sample_batch`] (and of the rasterizer's shading).
pub(crate) const BATCH: usize = 16;

/// One bilinear footprint per lane: the four texel indices (top-left, top-right, bottom-left,
/// bottom-right) and the weights along x and y.
#[derive(Clone, Copy)]
struct Footprints {
    index: [[u32; BATCH]; 4],
    tx: [f32; BATCH],
    ty: [f32; BATCH],
}

impl Footprints {
    const EMPTY: Self = Self {
        index: [[0; BATCH]; 4],
        tx: [0.0; BATCH],
        ty: [0.0; BATCH],
    };
}

impl BoundTexture<'_> {
    /// [`BoundTexture::sample`] at `uv[i]` with `lod[i]` for the first `n` lanes, bit for bit.
    /// The common samplers (trilinear, clamped or repeating a power-of-two texture) work out
    /// levels, footprints and weights for the whole batch lane by lane with no branches, so the
    /// lookups do not wait on each other; texel fetches follow. Other samplers, and coordinates
    /// far outside the texture, take the per-lookup path.
    pub(crate) fn sample_batch(
        &self,
        n: usize,
        u: &[f32; BATCH],
        v: &[f32; BATCH],
        lod: &[f32; BATCH],
        out: &mut [Vec4; BATCH],
    ) {
        let (w, h) = self.texture.size();
        let pow2 = w.is_power_of_two() && h.is_power_of_two();
        match self.specialised {
            Specialised::TrilinearClamp => {
                trilinear_batch::<true>(self, n, u, v, lod, out);
            }
            Specialised::TrilinearRepeat if pow2 => {
                trilinear_batch::<false>(self, n, u, v, lod, out);
            }
            _ => {
                for i in 0..n {
                    out[i] = Vec4::from_array(self.sample(Vec2::new(u[i], v[i]), lod[i]));
                }
            }
        }
    }
}

/// Levels, blend weights and bilinear footprints of a batch of trilinear lookups.
#[derive(Clone, Copy)]
struct TrilinearPlan {
    /// The lookup is within `SMALL_TEXELS` texels of the origin (else it takes the per-lookup
    /// path).
    small: [bool; BATCH],
    /// The two levels blended, and the weight of the second.
    level: [[u32; BATCH]; 2],
    t: [f32; BATCH],
    /// One footprint per level.
    feet: [Footprints; 2],
}

impl TrilinearPlan {
    const EMPTY: Self = Self {
        small: [false; BATCH],
        level: [[0; BATCH]; 2],
        t: [0.0; BATCH],
        feet: [Footprints::EMPTY; 2],
    };
}

/// The batch form of `sample_with` for a trilinear sampler that clamps (`CLAMP`) or repeats a
/// power-of-two texture, with the same arithmetic in each lane.
#[inline(always)]
fn trilinear_batch<const CLAMP: bool>(
    bound: &BoundTexture,
    n: usize,
    u: &[f32; BATCH],
    v: &[f32; BATCH],
    lod: &[f32; BATCH],
    out: &mut [Vec4; BATCH],
) {
    let levels = &bound.texture.levels;
    let mut plan = TrilinearPlan::EMPTY;
    if CLAMP {
        plan_clamp(levels, u, v, lod, &mut plan);
    } else {
        plan_repeat(levels, u, v, lod, &mut plan);
    }
    let sampler = if CLAMP {
        BoundTexture::CLAMP
    } else {
        BoundTexture::REPEAT
    };
    for i in 0..n {
        if !plan.small[i] {
            out[i] = Vec4::from_array(bound.texture.sample_with(
                &sampler,
                Vec2::new(u[i], v[i]),
                lod[i],
                false,
            ));
            continue;
        }
        let a = bilinear(levels, &plan, 0, i);
        out[i] = if plan.t[i] <= 0.0 {
            a
        } else {
            let b = bilinear(levels, &plan, 1, i);
            a + (b - a) * plan.t[i]
        };
    }
}

/// Lane `i`'s bilinear lookup in the `k`th level of `plan`.
#[inline(always)]
fn bilinear(levels: &[ColorImage], plan: &TrilinearPlan, k: usize, i: usize) -> Vec4 {
    let texels = levels[plan.level[k][i] as usize].pixels();
    let f = &plan.feet[k];
    let texel = |c: usize| Vec4::from_array(texels[f.index[c][i] as usize]);
    let (p00, p10, p01, p11) = (texel(0), texel(1), texel(2), texel(3));
    let top = p00 + (p10 - p00) * f.tx[i];
    let bottom = p01 + (p11 - p01) * f.tx[i];
    top + (bottom - top) * f.ty[i]
}

/// [`plan_trilinear`] for a clamping sampler. Compiled for several instruction sets and chosen
/// at run time ([`multiversion`]); every version does the same arithmetic (no fused
/// multiply-add), so the plan is identical whichever runs. No AVX-512 version: on an Intel Xeon
/// with AVX-512 the rasterizers ran 6-7% faster without it (README, "Without AVX-512 where it
/// was slower").
#[multiversion::multiversion(targets("x86_64+avx2+sse4.1", "aarch64+neon"))]
fn plan_clamp(
    levels: &[ColorImage],
    u: &[f32; BATCH],
    v: &[f32; BATCH],
    lod: &[f32; BATCH],
    plan: &mut TrilinearPlan,
) {
    plan_trilinear::<true>(levels, u, v, lod, plan);
}

/// [`plan_trilinear`] for a sampler repeating a power-of-two texture, as [`plan_clamp`].
#[multiversion::multiversion(targets("x86_64+avx2+sse4.1", "aarch64+neon"))]
fn plan_repeat(
    levels: &[ColorImage],
    u: &[f32; BATCH],
    v: &[f32; BATCH],
    lod: &[f32; BATCH],
    plan: &mut TrilinearPlan,
) {
    plan_trilinear::<false>(levels, u, v, lod, plan);
}

/// `sample_with`'s branches as selects, lane by lane, in loops the compiler vectorises: the
/// two levels and their weight, then each level's footprint.
#[inline(always)]
fn plan_trilinear<const CLAMP: bool>(
    levels: &[ColorImage],
    u: &[f32; BATCH],
    v: &[f32; BATCH],
    lod: &[f32; BATCH],
    plan: &mut TrilinearPlan,
) {
    let last = levels.len() - 1;
    let (w0_px, h0_px) = (levels[0].width() as i32, levels[0].height() as i32);
    let (w0, h0) = (w0_px as f32, h0_px as f32);
    for i in 0..BATCH {
        plan.small[i] = (u[i] * w0).abs() < SMALL_TEXELS && (v[i] * h0).abs() < SMALL_TEXELS;
        let magnify = lod[i] <= 0.0;
        let l = lod[i].min(last as f32);
        // `l` is in (0, last] (or `last` for NaN) when not magnifying: truncation is `floor`.
        let l0 = if magnify { 0 } else { l as u32 };
        plan.level[1][i] = (l0 + 1).min(last as u32);
        plan.level[0][i] = l0.min(last as u32);
        plan.t[i] = if magnify { 0.0 } else { l - l0 as f32 };
    }
    for (foot, level) in plan.feet.iter_mut().zip(&plan.level) {
        // Each lane's level size: the chain halves (rounding down, at least 1), so level `l`
        // is `max(size >> l, 1)`, a shift in every lane rather than a lookup.
        let mut w = [1i32; BATCH];
        let mut h = [1i32; BATCH];
        for i in 0..BATCH {
            let l = level[i].min(31);
            w[i] = (w0_px >> l).max(1);
            h[i] = (h0_px >> l).max(1);
        }
        for i in 0..BATCH {
            // Lanes outside the small range take the per-lookup path; zero keeps
            // `floor_small` within its domain for them.
            let x = if plan.small[i] {
                u[i] * w[i] as f32
            } else {
                0.0
            };
            let y = if plan.small[i] {
                v[i] * h[i] as f32
            } else {
                0.0
            };
            let (fx, fy) = (x - 0.5, y - 0.5);
            let (x0, y0) = (floor_small(fx), floor_small(fy));
            foot.tx[i] = fx - x0 as f32;
            foot.ty[i] = fy - y0 as f32;
            let (wm, hm) = (w[i] - 1, h[i] - 1);
            let (xa, xb, ya, yb) = if CLAMP {
                (
                    x0.max(0).min(wm),
                    (x0 + 1).max(0).min(wm),
                    y0.max(0).min(hm),
                    (y0 + 1).max(0).min(hm),
                )
            } else {
                (x0 & wm, (x0 + 1) & wm, y0 & hm, (y0 + 1) & hm)
            };
            let (ra, rb) = (ya * w[i], yb * w[i]);
            foot.index[0][i] = (ra + xa) as u32;
            foot.index[1][i] = (ra + xb) as u32;
            foot.index[2][i] = (rb + xa) as u32;
            foot.index[3][i] = (rb + xb) as u32;
        }
    }
}

/// Texel coordinates below this in magnitude are exact for [`floor_small`] and need no wrap in
/// float ([`reduce`]).
const SMALL_TEXELS: f32 = 4_000_000.0;

/// `floor` of `|x| < 2^22`, exact, without the saturation checks of `as i32`: adding 1.5 * 2^23
/// leaves the nearest integer in the low mantissa bits.
#[inline(always)]
fn floor_small(x: f32) -> i32 {
    debug_assert!(x.abs() < 4_194_304.0, "{x}");
    let nearest = (x + 12_582_912.0).to_bits() as i32 - 0x4b40_0000;
    nearest - i32::from(nearest as f32 > x)
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
#[inline(always)]
fn wrap_pair(i: i32, n: i32, mode: WrapMode) -> (usize, usize) {
    match mode {
        // Power-of-two sizes (the common case) wrap with a mask, as `wrap` does.
        WrapMode::Repeat if n & (n - 1) == 0 => {
            ((i & (n - 1)) as usize, ((i + 1) & (n - 1)) as usize)
        }
        WrapMode::Repeat if (0..n - 1).contains(&i) => (i as usize, i as usize + 1),
        // `max(0).min(n - 1)` is `clamp(0, n - 1)` for n >= 1 without clamp's min <= max check.
        WrapMode::ClampToEdge => (
            i.max(0).min(n - 1) as usize,
            (i + 1).max(0).min(n - 1) as usize,
        ),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A cut-out with an anti-aliased rim is two-valued; a soft ramp of alpha is not.
    #[test]
    fn two_valued_alpha_is_told_from_a_ramp() {
        let n = 64;
        let disc = |x: usize, y: usize| {
            let d = ((x as f32 - 32.0).powi(2) + (y as f32 - 32.0).powi(2)).sqrt();
            (20.0 - d + 0.5).clamp(0.0, 1.0)
        };
        let image = |f: &dyn Fn(usize, usize) -> f32| {
            let data = (0..n * n)
                .map(|i| [0.5, 0.5, 0.5, f(i % n, i / n)])
                .collect();
            ColorImage::from_vec(n, n, data).expect("size")
        };
        assert!(Texture::new(image(&disc)).has_two_valued_alpha());
        let ramp = |x: usize, _y: usize| x as f32 / (n - 1) as f32;
        assert!(!Texture::new(image(&ramp)).has_two_valued_alpha());
        assert!(!Texture::new(image(&|_, _| 0.0)).has_two_valued_alpha());
    }

    #[test]
    fn floor_small_is_floor() {
        // A few mantissas at every scale, their neighbours, both signs.
        for m in [1.0f32, 1.25, 1.5, 1.999_999_9, 1.333_333_3] {
            for e in -30..22 {
                let x = m * 2f32.powi(e);
                for y in [x, x.next_down(), x.next_up(), x + 0.5, x - 0.5] {
                    for y in [y, -y] {
                        if y.abs() < 4_194_304.0 {
                            assert_eq!(floor_small(y), y.floor() as i32, "{y}");
                        }
                    }
                }
            }
        }
        for y in [
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.49999997,
            -0.49999997,
            4_194_303.5,
        ] {
            assert_eq!(floor_small(y), y.floor() as i32, "{y}");
        }
    }

    /// The straightforward sampler: every mode decided per texel, each channel on its own.
    fn naive_sample(t: &Texture, s: &TextureSampler, uv: Vec2, lod: f32) -> Rgba {
        let level = |level: usize, filter: FilterMode| -> Rgba {
            let img = &t.levels[level];
            let (w, h) = (img.width() as i32, img.height() as i32);
            let (x, y) = (uv.x * w as f32, uv.y * h as f32);
            if !(x.is_finite() && y.is_finite()) {
                return img.get(0, 0);
            }
            let (x, y) = (reduce(x, w, s.wrap_u), reduce(y, h, s.wrap_v));
            match filter {
                FilterMode::Nearest => img.get(
                    wrap(x.floor() as i32, w, s.wrap_u),
                    wrap(y.floor() as i32, h, s.wrap_v),
                ),
                FilterMode::Linear => {
                    let (fx, fy) = (x - 0.5, y - 0.5);
                    let (x0, y0) = (fx.floor() as i32, fy.floor() as i32);
                    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                    let (xa, xb) = (wrap(x0, w, s.wrap_u), wrap(x0 + 1, w, s.wrap_u));
                    let (ya, yb) = (wrap(y0, h, s.wrap_v), wrap(y0 + 1, h, s.wrap_v));
                    let (p00, p10) = (img.get(xa, ya), img.get(xb, ya));
                    let (p01, p11) = (img.get(xa, yb), img.get(xb, yb));
                    std::array::from_fn(|c| {
                        let top = p00[c] + (p10[c] - p00[c]) * tx;
                        let bottom = p01[c] + (p11[c] - p01[c]) * tx;
                        top + (bottom - top) * ty
                    })
                }
            }
        };
        if lod <= 0.0 || s.mip_filter.is_none() {
            let filter = if lod <= 0.0 {
                s.mag_filter
            } else {
                s.min_filter
            };
            return level(0, filter);
        }
        let last = t.levels.len() - 1;
        let lod = lod.min(last as f32);
        if s.mip_filter == Some(FilterMode::Nearest) {
            return level((lod + 0.5) as usize, s.min_filter);
        }
        let l0 = lod.floor();
        let t = lod - l0;
        let a = level(l0 as usize, s.min_filter);
        if t <= 0.0 {
            return a;
        }
        let b = level((l0 as usize + 1).min(last), s.min_filter);
        std::array::from_fn(|c| a[c] + (b[c] - a[c]) * t)
    }

    #[test]
    fn sampling_matches_the_naive_sampler_bit_for_bit() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let filters = [FilterMode::Nearest, FilterMode::Linear];
        let wraps = [
            WrapMode::Repeat,
            WrapMode::ClampToEdge,
            WrapMode::MirroredRepeat,
        ];
        for (w, h) in [(1, 1), (1, 5), (8, 8), (16, 4), (7, 3), (12, 9)] {
            let texels = (0..w * h)
                .map(|_| [next(), next(), next(), next()])
                .collect();
            let texture = Texture::new(ColorImage::from_vec(w, h, texels).expect("size"));
            for mip_filter in [None, Some(FilterMode::Nearest), Some(FilterMode::Linear)] {
                for (&mag_filter, &min_filter) in filters.iter().zip(filters.iter().rev()) {
                    for (&wrap_u, &wrap_v) in wraps.iter().zip(wraps.iter().cycle().skip(1)) {
                        for sampler in [
                            TextureSampler {
                                mag_filter,
                                min_filter,
                                mip_filter,
                                wrap_u,
                                wrap_v,
                            },
                            trilinear(wrap_u),
                        ] {
                            let bound = BoundTexture::new(&texture, sampler);
                            for i in 0..400 {
                                let scale = [1.0, 4.0, 100.0, 3.0e7, 5.0e5, 2.0e6][i % 6];
                                let uv = Vec2::new(next() - 0.5, next() - 0.5) * scale;
                                let lod = next() * 8.0 - 2.0;
                                let want = naive_sample(&texture, &sampler, uv, lod);
                                for got in
                                    [texture.sample(&sampler, uv, lod), bound.sample(uv, lod)]
                                {
                                    assert_eq!(
                                        got.map(f32::to_bits),
                                        want.map(f32::to_bits),
                                        "{w}x{h} {sampler:?} uv {uv} lod {lod}"
                                    );
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    /// The early alpha test's bounds hold: every lookup's alpha is at most the bound of its
    /// lane, over sparse cut-out alphas (mostly 0, a few texels up to 1), sizes that halve
    /// unevenly, every wrap mode, nearest and linear filters, no mipmaps, and levels of detail
    /// from magnification to past the last level.
    #[test]
    fn alpha_bounds_bound_every_lookup() {
        let mut rng = crate::random::SplitMix64::new(0x9e37_79b9);
        let mut next = move || rng.range(0.0, 1.0);
        let mut lookups = 0;
        for (w, h) in [
            (1, 1),
            (5, 1),
            (7, 3),
            (12, 9),
            (13, 31),
            (64, 32),
            (33, 17),
        ] {
            let texels = (0..w * h)
                .map(|_| {
                    let a = if next() < 0.08 { next() } else { 0.0 };
                    [next(), next(), next(), a]
                })
                .collect();
            let texture = Texture::new(ColorImage::from_vec(w, h, texels).expect("size"));
            for wrap in [
                WrapMode::Repeat,
                WrapMode::ClampToEdge,
                WrapMode::MirroredRepeat,
            ] {
                for (filter, mip_filter) in [
                    (FilterMode::Linear, Some(FilterMode::Linear)),
                    (FilterMode::Nearest, Some(FilterMode::Nearest)),
                    (FilterMode::Linear, Some(FilterMode::Nearest)),
                    (FilterMode::Linear, None),
                ] {
                    let sampler = TextureSampler {
                        mag_filter: filter,
                        min_filter: filter,
                        mip_filter,
                        wrap_u: wrap,
                        wrap_v: wrap,
                    };
                    let bound = BoundTexture::new(&texture, sampler);
                    for round in 0..300 {
                        let (mut u, mut v, mut lod) = ([0.0; BATCH], [0.0; BATCH], [0.0; BATCH]);
                        // Every other batch at one level of detail, as a triangle's mostly are.
                        let shared = next() * 9.0 - 2.0;
                        for i in 0..BATCH {
                            u[i] = next();
                            v[i] = next();
                            lod[i] = if round % 2 == 0 {
                                shared
                            } else {
                                next() * 9.0 - 2.0
                            };
                        }
                        // The edges exactly.
                        (u[0], v[0], u[1], v[1]) = (0.0, 1.0, 1.0, 0.0);
                        let mut bounds = [0.0; BATCH];
                        bound.alpha_bound_batch(&u, &v, &lod, &mut bounds);
                        for i in 0..BATCH {
                            let a = bound.sample(Vec2::new(u[i], v[i]), lod[i])[3];
                            assert!(
                                a <= bounds[i] * (1.0 + 1e-5),
                                "{w}x{h} {sampler:?} at ({}, {}) lod {}: alpha {a} above \
                                 its bound {}",
                                u[i],
                                v[i],
                                lod[i],
                                bounds[i]
                            );
                            lookups += 1;
                        }
                    }
                }
            }
        }
        assert!(lookups > 100_000);
    }

    #[test]
    fn batch_sampling_matches_single_lookups_bit_for_bit() {
        let mut rng = crate::random::SplitMix64::new(0x3c6e_f372);
        let mut next = move || rng.range(0.0, 1.0);
        let mut batches = 0;
        // Power-of-two and other sizes, so every sampler meets both the batch and the
        // per-lookup path.
        for (w, h) in [
            (1, 1),
            (8, 8),
            (16, 4),
            (7, 3),
            (12, 9),
            (64, 32),
            (5, 1),
            (3, 13),
        ] {
            let texels = (0..w * h)
                .map(|_| [next(), next(), next(), next()])
                .collect();
            let texture = Texture::new(ColorImage::from_vec(w, h, texels).expect("size"));
            for sampler in [
                trilinear(WrapMode::Repeat),
                trilinear(WrapMode::ClampToEdge),
                trilinear(WrapMode::MirroredRepeat),
                TextureSampler {
                    mip_filter: None,
                    ..trilinear(WrapMode::Repeat)
                },
            ] {
                let bound = BoundTexture::new(&texture, sampler);
                for round in 0..200 {
                    let n = 1 + round % BATCH;
                    let scale = [1.0, 4.0, 100.0, 3.0e7][round % 4];
                    let mut u = [0.0; BATCH];
                    let mut v = [0.0; BATCH];
                    let mut lod = [0.0; BATCH];
                    for i in 0..BATCH {
                        u[i] = (next() - 0.5) * scale;
                        v[i] = (next() - 0.5) * scale;
                        // Whole levels, negative ones and NaN too; every third batch all
                        // magnified (at or below level 0, as sample lookups mostly are).
                        lod[i] = match i % 5 {
                            _ if round % 3 == 1 => -(next() * 3.0).floor() * next(),
                            0 => (next() * 8.0).floor(),
                            1 if round % 7 == 0 => f32::NAN,
                            _ => next() * 10.0 - 2.0,
                        };
                    }
                    let mut out = [Vec4::ZERO; BATCH];
                    bound.sample_batch(n, &u, &v, &lod, &mut out);
                    for i in 0..n {
                        let want = bound.sample(Vec2::new(u[i], v[i]), lod[i]);
                        assert_eq!(
                            out[i].to_array().map(f32::to_bits),
                            want.map(f32::to_bits),
                            "{w}x{h} {sampler:?} uv ({}, {}) lod {}",
                            u[i],
                            v[i],
                            lod[i]
                        );
                    }
                    batches += 1;
                }
            }
        }
        assert!(batches > 1000);
    }
}
