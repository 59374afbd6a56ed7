//! Unlit shading of a fragment: base colour (factor x texture) plus emission
//! (factor x texture x strength), and the alpha mode.

use glam::{Vec2, Vec4};

use crate::image::Rgba;
use crate::scene::texture::{fast_log2, BoundTexture, BATCH};
use crate::scene::{AlphaMode, Material, Texture, TextureBinding, UvTransform};

/// Slack on [`BoundTexture::alpha_bound`] for rounding: a lookup's alpha is a convex blend
/// (three nested lerps) of texel alphas, which can exceed their maximum by a few units in the
/// last place, far less than this.
const ALPHA_BOUND_MARGIN: f32 = 1.0 + 1e-5;

/// A material ready to shade fragments.
pub(crate) struct Shader<'a> {
    material: &'a Material,
    /// Alpha cutoff of the early alpha test, when the material takes it (see
    /// [`Texture::wants_early_alpha_test`]).
    early_alpha_cutoff: Option<f32>,
    base: Option<Slot<'a>>,
    emissive: Option<Slot<'a>>,
    emission: [f32; 3],
    lod_bias: f32,
    /// Alpha to coverage: an alpha-mask material returns the share of the lookup's footprint
    /// it keeps as alpha instead of testing it against the cutoff (see
    /// [`Shader::with_alpha_to_coverage`]).
    alpha_to_coverage: bool,
}

impl<'a> Shader<'a> {
    pub(crate) fn new(material: &'a Material, textures: &'a [Texture], lod_bias: f32) -> Self {
        let bind = |b: &'a Option<TextureBinding>| b.as_ref().map(|b| Slot::new(b, textures));
        Self {
            material,
            early_alpha_cutoff: early_alpha_cutoff(material, textures),
            base: bind(&material.base_color_texture),
            emissive: bind(&material.emissive_texture),
            emission: material.emissive.map(|e| e * material.emissive_strength),
            lod_bias,
            alpha_to_coverage: false,
        }
    }

    /// The same shader with alpha to coverage, for an alpha-mask material whose base colour
    /// texture has two-valued alpha ([`Texture::has_two_valued_alpha`]): the filtered alpha of
    /// a lookup is then the share of its footprint that is opaque, and the shader returns it
    /// as alpha (0 where the base colour factor's alpha is below the cutoff: nothing passes)
    /// instead of one test at the lookup's centre. `None` for other materials.
    pub(crate) fn with_alpha_to_coverage(self, textures: &[Texture]) -> Option<Self> {
        let AlphaMode::Mask { .. } = self.material.alpha_mode else {
            return None;
        };
        let binding = self.material.base_color_texture.as_ref()?;
        textures
            .get(binding.texture)?
            .has_two_valued_alpha()
            .then_some(Self {
                alpha_to_coverage: true,
                ..self
            })
    }

    /// True when screen derivatives `duv_dx`, `duv_dy` (per pixel) span more than a texel of
    /// one of the shader's textures along either axis: the texture is minified there (the
    /// shader's level-of-detail bias aside).
    #[inline]
    pub(crate) fn minified(&self, duv_dx: Vec2, duv_dy: Vec2) -> bool {
        [&self.base, &self.emissive]
            .into_iter()
            .flatten()
            .any(|slot| slot.footprint(duv_dx, duv_dy) > 1.0)
    }

    /// True when shading reads texture coordinates.
    #[inline]
    pub(crate) fn needs_uv(&self) -> bool {
        self.base.is_some() || self.emissive.is_some()
    }

    /// Colour and alpha at `uv` with screen derivatives `duv_dx`, `duv_dy` (per pixel), or
    /// `None` when an alpha-mask material discards the fragment.
    #[inline]
    pub(crate) fn shade(&self, uv: Vec2, duv_dx: Vec2, duv_dy: Vec2) -> Option<Rgba> {
        let sample = |slot: &Option<Slot>| {
            slot.as_ref()
                .map(|slot| slot.sample(uv, duv_dx, duv_dy, self.lod_bias))
        };
        self.combine(sample(&self.base), sample(&self.emissive))
    }

    /// [`Shader::shade`] for the first `n` pixels of a batch, bit for bit: `out[i]` is `None`
    /// where the fragment is discarded. Texture lookups go through
    /// [`BoundTexture::sample_batch`]. False when the early alpha test discarded them all.
    pub(crate) fn shade_batch(
        &self,
        n: usize,
        uv: &UvBatch,
        out: &mut [Option<Rgba>; BATCH],
    ) -> bool {
        let base_coords = self
            .base
            .as_ref()
            .map(|b| b.coords_batch(uv, self.lod_bias));
        // Alpha-tested: fragments whose alpha is bounded below the cutoff are discarded before
        // the lookups, and the rest shaded as a smaller batch.
        let factor = self.material.base_color[3];
        if let (Some(cutoff), Some(base), Some(c)) =
            (self.early_alpha_cutoff, &self.base, &base_coords)
        {
            let mut bound = [0.0f32; BATCH];
            base.texture
                .alpha_bound_batch(&c.u, &c.v, &c.lod, &mut bound);
            let mut kept = [0usize; BATCH];
            let mut m = 0;
            for (i, &b) in bound.iter().enumerate().take(n) {
                kept[m] = i;
                // Kept unless bounded below the cutoff (a NaN bound keeps it); with alpha to
                // coverage, unless bounded at 0.
                let bound = factor * b * ALPHA_BOUND_MARGIN;
                let least = if self.alpha_to_coverage {
                    f32::MIN_POSITIVE
                } else {
                    cutoff
                };
                m += usize::from(bound >= least || bound.is_nan());
            }
            if m == 0 {
                out[..n].fill(None);
                return false;
            }
            if m < n {
                let (mut sub_uv, mut sub_c) = (UvBatch::default(), Coords::default());
                for (k, &i) in kept[..m].iter().enumerate() {
                    sub_c.u[k] = c.u[i];
                    sub_c.v[k] = c.v[i];
                    sub_c.lod[k] = c.lod[i];
                    if self.emissive.is_some() {
                        sub_uv.u[k] = uv.u[i];
                        sub_uv.v[k] = uv.v[i];
                        sub_uv.du_dx[k] = uv.du_dx[i];
                        sub_uv.dv_dx[k] = uv.dv_dx[i];
                        sub_uv.du_dy[k] = uv.du_dy[i];
                        sub_uv.dv_dy[k] = uv.dv_dy[i];
                    }
                }
                let mut shaded = [None; BATCH];
                self.shade_lanes(
                    m,
                    Some(&sub_c),
                    |e| e.coords_batch(&sub_uv, self.lod_bias),
                    &mut shaded,
                );
                out[..n].fill(None);
                for (&i, c) in kept[..m].iter().zip(shaded) {
                    out[i] = c;
                }
                return true;
            }
        }
        self.shade_lanes(
            n,
            base_coords.as_ref(),
            |e| e.coords_batch(uv, self.lod_bias),
            out,
        );
        true
    }

    /// [`Shader::shade_batch`] for lanes that share their screen derivatives `duv_dx`,
    /// `duv_dy` (one pixel's samples), bit for bit: each texture's level of detail is worked
    /// out once. `out[i]` is `None` where the fragment is discarded.
    pub(crate) fn shade_shared(
        &self,
        n: usize,
        u: &[f32; BATCH],
        v: &[f32; BATCH],
        (duv_dx, duv_dy): (Vec2, Vec2),
        out: &mut [Option<Rgba>; BATCH],
    ) {
        let coords = |slot: &Slot| slot.coords_shared(u, v, duv_dx, duv_dy, self.lod_bias);
        let base = self.base.as_ref().map(coords);
        self.shade_lanes(n, base.as_ref(), coords, out);
    }

    /// [`Shader::shade_batch`] without the early alpha test, with the base slot's coordinates
    /// worked out and the emissive slot's from `emissive_coords`.
    #[inline(always)]
    fn shade_lanes(
        &self,
        n: usize,
        base_coords: Option<&Coords>,
        emissive_coords: impl Fn(&Slot) -> Coords,
        out: &mut [Option<Rgba>; BATCH],
    ) {
        let mut base = [Vec4::ONE; BATCH];
        let mut emissive = [Vec4::ONE; BATCH];
        if let (Some(slot), Some(c)) = (&self.base, base_coords) {
            slot.texture.sample_batch(n, &c.u, &c.v, &c.lod, &mut base);
        }
        if let Some(slot) = &self.emissive {
            let c = emissive_coords(slot);
            slot.texture
                .sample_batch(n, &c.u, &c.v, &c.lod, &mut emissive);
        }
        let (has_base, has_emissive) = (self.base.is_some(), self.emissive.is_some());
        for i in 0..n {
            out[i] = self.combine(
                has_base.then(|| base[i].to_array()),
                has_emissive.then(|| emissive[i].to_array()),
            );
        }
    }

    /// Colour and alpha from the texture samples of the base colour and emission slots.
    #[inline(always)]
    fn combine(&self, base: Option<Rgba>, emissive: Option<Rgba>) -> Option<Rgba> {
        let m = self.material;
        let mut c = m.base_color;
        if let Some(s) = base {
            for k in 0..4 {
                c[k] *= s[k];
            }
        }
        let mut e = self.emission;
        if let Some(s) = emissive {
            for k in 0..3 {
                e[k] *= s[k];
            }
        }
        let alpha = match m.alpha_mode {
            AlphaMode::Opaque => 1.0,
            AlphaMode::Mask { cutoff } if self.alpha_to_coverage => {
                // The texture's filtered alpha is the share kept when the factor passes.
                let share = if m.base_color[3] >= cutoff {
                    (c[3] / m.base_color[3]).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                if share.is_nan() || share <= 0.0 {
                    return None;
                }
                share
            }
            AlphaMode::Mask { cutoff } => {
                if c[3] < cutoff {
                    return None;
                }
                1.0
            }
            AlphaMode::Blend => c[3].clamp(0.0, 1.0),
        };
        Some([c[0] + e[0], c[1] + e[1], c[2] + e[2], alpha])
    }
}

/// The cutoff of `material`'s early alpha test, if it takes one: an alpha-mask material with a
/// base colour texture that is mostly cut away ([`Texture::wants_early_alpha_test`]) and a
/// base alpha factor of at least 0 (the bound is an upper bound only then).
pub(crate) fn early_alpha_cutoff(material: &Material, textures: &[Texture]) -> Option<f32> {
    let AlphaMode::Mask { cutoff } = material.alpha_mode else {
        return None;
    };
    let texture = textures.get(material.base_color_texture.as_ref()?.texture)?;
    (material.base_color[3] >= 0.0 && texture.wants_early_alpha_test()).then_some(cutoff)
}

/// Texture coordinates and their screen derivatives (per pixel, along x and y) of a batch of
/// pixels, one array per quantity.
#[derive(Clone, Copy, Debug)]
pub(crate) struct UvBatch {
    pub(crate) u: [f32; BATCH],
    pub(crate) v: [f32; BATCH],
    pub(crate) du_dx: [f32; BATCH],
    pub(crate) dv_dx: [f32; BATCH],
    pub(crate) du_dy: [f32; BATCH],
    pub(crate) dv_dy: [f32; BATCH],
}

impl Default for UvBatch {
    fn default() -> Self {
        Self {
            u: [0.0; BATCH],
            v: [0.0; BATCH],
            du_dx: [0.0; BATCH],
            dv_dx: [0.0; BATCH],
            du_dy: [0.0; BATCH],
            dv_dy: [0.0; BATCH],
        }
    }
}

/// A bound texture slot of a material, with what sampling it needs worked out once.
struct Slot<'a> {
    texture: BoundTexture<'a>,
    /// `None` for the identity.
    uv_transform: Option<UvAffine>,
    /// Level-0 size in texels.
    size: Vec2,
}

impl<'a> Slot<'a> {
    fn new(b: &TextureBinding, textures: &'a [Texture]) -> Self {
        let texture = BoundTexture::new(&textures[b.texture], b.sampler);
        let (w, h) = texture.size();
        Self {
            texture,
            uv_transform: (!b.uv_transform.is_identity()).then(|| UvAffine::new(&b.uv_transform)),
            size: Vec2::new(w as f32, h as f32),
        }
    }

    /// The squared length in texels of the longer of the footprint's axes `dx`, `dy` (texture
    /// coordinates per pixel), as [`Slot::sample`] takes it for the level of detail.
    #[inline]
    fn footprint(&self, dx: Vec2, dy: Vec2) -> f32 {
        let (dx, dy) = match &self.uv_transform {
            None => (dx, dy),
            Some(t) => (t.apply(dx) - t.origin, t.apply(dy) - t.origin),
        };
        (dx * self.size)
            .length_squared()
            .max((dy * self.size).length_squared())
    }

    #[inline]
    fn sample(&self, uv: Vec2, dx: Vec2, dy: Vec2, lod_bias: f32) -> Rgba {
        let (uv, dx, dy) = match &self.uv_transform {
            None => (uv, dx, dy),
            Some(t) => (t.apply(uv), t.apply(dx) - t.origin, t.apply(dy) - t.origin),
        };
        let fx = (dx * self.size).length_squared();
        let fy = (dy * self.size).length_squared();
        let lod = 0.5 * fast_log2(fx.max(fy).max(1e-12)) + lod_bias;
        self.texture.sample(uv, lod)
    }

    /// [`Slot::coords_batch`] for lanes that share their derivatives `dx`, `dy`, bit for bit:
    /// the level of detail worked out once.
    #[inline]
    fn coords_shared(
        &self,
        u: &[f32; BATCH],
        v: &[f32; BATCH],
        dx: Vec2,
        dy: Vec2,
        lod_bias: f32,
    ) -> Coords {
        let (dx, dy) = match &self.uv_transform {
            None => (dx, dy),
            Some(t) => (t.apply(dx) - t.origin, t.apply(dy) - t.origin),
        };
        let fx = (dx * self.size).length_squared();
        let fy = (dy * self.size).length_squared();
        let mut c = Coords {
            lod: [0.5 * fast_log2(fx.max(fy).max(1e-12)) + lod_bias; BATCH],
            ..Coords::default()
        };
        match &self.uv_transform {
            None => {
                c.u = *u;
                c.v = *v;
            }
            Some(t) => {
                for i in 0..BATCH {
                    let uv = t.apply(Vec2::new(u[i], v[i]));
                    c.u[i] = uv.x;
                    c.v[i] = uv.y;
                }
            }
        }
        c
    }

    /// The texture coordinates and levels of detail that [`Slot::sample`] looks up, for every
    /// lane of a batch, bit for bit.
    #[inline]
    fn coords_batch(&self, b: &UvBatch, lod_bias: f32) -> Coords {
        let mut c = Coords::default();
        for i in 0..BATCH {
            let uv = Vec2::new(b.u[i], b.v[i]);
            let dx = Vec2::new(b.du_dx[i], b.dv_dx[i]);
            let dy = Vec2::new(b.du_dy[i], b.dv_dy[i]);
            let (uv, dx, dy) = match &self.uv_transform {
                None => (uv, dx, dy),
                Some(t) => (t.apply(uv), t.apply(dx) - t.origin, t.apply(dy) - t.origin),
            };
            c.u[i] = uv.x;
            c.v[i] = uv.y;
            let fx = (dx * self.size).length_squared();
            let fy = (dy * self.size).length_squared();
            c.lod[i] = 0.5 * fast_log2(fx.max(fy).max(1e-12)) + lod_bias;
        }
        c
    }
}

/// Texture coordinates and levels of detail of a batch of lookups.
#[derive(Clone, Copy, Debug, Default)]
struct Coords {
    u: [f32; BATCH],
    v: [f32; BATCH],
    lod: [f32; BATCH],
}

/// [`UvTransform::apply`] with the rotation's sine and cosine and the image of the origin
/// worked out once per material instead of per fragment; the same arithmetic, bit for bit.
#[derive(Clone, Copy, Debug)]
struct UvAffine {
    scale: Vec2,
    sin: f32,
    cos: f32,
    offset: Vec2,
    /// `apply(0, 0)`, subtracted to transform derivatives.
    origin: Vec2,
}

impl UvAffine {
    fn new(t: &UvTransform) -> Self {
        let (sin, cos) = t.rotation_rad.sin_cos();
        Self {
            scale: t.scale,
            sin,
            cos,
            offset: t.offset,
            origin: t.apply(Vec2::ZERO),
        }
    }

    #[inline]
    fn apply(&self, uv: Vec2) -> Vec2 {
        let s = uv * self.scale;
        let (sin, cos) = (self.sin, self.cos);
        Vec2::new(cos * s.x + sin * s.y, -sin * s.x + cos * s.y) + self.offset
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::ColorImage;

    /// `shade_shared` (one level of detail for lanes sharing their derivatives) gives
    /// `shade_batch`'s colours and discards bit for bit: base and emissive textures of
    /// different sizes, a turned and scaled texture transform, and an alpha-mask cut-out
    /// mostly cut away (the early alpha test's path in `shade_batch`).
    #[test]
    fn shared_derivatives_shade_as_the_batch_does() {
        let mut rng = crate::random::SplitMix64::new(0x51_7cc1);
        let mut next = move || rng.range(0.0, 1.0);
        let texture = |w: usize, h: usize, holes: bool, next: &mut dyn FnMut() -> f32| {
            let texels = (0..w * h)
                .map(|i| {
                    let alpha = if holes && i % 7 != 0 { 0.0 } else { next() };
                    [next(), next(), next(), alpha]
                })
                .collect();
            Texture::new(ColorImage::from_vec(w, h, texels).expect("size"))
        };
        let textures = vec![
            texture(64, 32, false, &mut next),
            texture(16, 16, false, &mut next),
            texture(32, 32, true, &mut next),
        ];
        let bind = |texture: usize, turned: bool| {
            Some(TextureBinding {
                texture,
                sampler: Default::default(),
                uv_transform: if turned {
                    UvTransform {
                        offset: Vec2::new(0.25, -0.5),
                        rotation_rad: 0.7,
                        scale: Vec2::new(2.0, 0.5),
                    }
                } else {
                    Default::default()
                },
            })
        };
        let materials = [
            Material {
                base_color_texture: bind(0, false),
                ..Default::default()
            },
            Material {
                base_color_texture: bind(0, true),
                emissive: [0.5, 1.0, 2.0],
                emissive_texture: bind(1, false),
                ..Default::default()
            },
            Material {
                base_color_texture: bind(2, false),
                alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
                ..Default::default()
            },
        ];
        assert!(early_alpha_cutoff(&materials[2], &textures).is_some());
        let mut compared = 0;
        for material in &materials {
            for bias in [-2.0, -1.0, 0.0] {
                let shader = Shader::new(material, &textures, bias);
                for round in 0..300 {
                    let n = 1 + round % BATCH;
                    // Footprints from a fraction of a texel to several.
                    let scale = [0.002, 0.02, 0.2][round % 3];
                    let dx = Vec2::new(next() - 0.5, next() - 0.5) * scale;
                    let dy = Vec2::new(next() - 0.5, next() - 0.5) * scale;
                    let mut uv = UvBatch::default();
                    for i in 0..BATCH {
                        uv.u[i] = next() * 3.0 - 1.0;
                        uv.v[i] = next() * 3.0 - 1.0;
                        (uv.du_dx[i], uv.dv_dx[i]) = (dx.x, dx.y);
                        (uv.du_dy[i], uv.dv_dy[i]) = (dy.x, dy.y);
                    }
                    let (mut want, mut got) = ([None; BATCH], [None; BATCH]);
                    shader.shade_batch(n, &uv, &mut want);
                    shader.shade_shared(n, &uv.u, &uv.v, (dx, dy), &mut got);
                    for i in 0..n {
                        assert_eq!(
                            got[i].map(|c| c.map(f32::to_bits)),
                            want[i].map(|c| c.map(f32::to_bits)),
                            "{} lane {i}",
                            material.name
                        );
                        compared += usize::from(want[i].is_some());
                    }
                }
            }
        }
        assert!(compared > 5000, "{compared}");
    }

    #[test]
    fn hoisted_uv_transform_matches_uv_transform_apply_bit_for_bit() {
        let mut rng = crate::random::SplitMix64::new(0x2545_f491);
        let mut next = move || rng.range(-4.0, 4.0);
        for _ in 0..1000 {
            let t = UvTransform {
                offset: Vec2::new(next(), next()),
                rotation_rad: next(),
                scale: Vec2::new(next(), next()),
            };
            let a = UvAffine::new(&t);
            assert_eq!(
                a.origin.to_array().map(f32::to_bits),
                t.apply(Vec2::ZERO).to_array().map(f32::to_bits)
            );
            for _ in 0..10 {
                let uv = Vec2::new(next(), next()) * 100.0;
                let want = t.apply(uv).to_array().map(f32::to_bits);
                assert_eq!(
                    a.apply(uv).to_array().map(f32::to_bits),
                    want,
                    "{t:?} at {uv}"
                );
            }
        }
    }
}
