//! Unlit shading of a fragment: base colour (factor x texture) plus emission
//! (factor x texture x strength), and the alpha mode.

use glam::Vec2;

use crate::image::Rgba;
use crate::scene::texture::fast_log2;
use crate::scene::{AlphaMode, Material, Texture, TextureBinding};

/// A material ready to shade fragments.
pub(crate) struct Shader<'a> {
    material: &'a Material,
    base: Option<(&'a TextureBinding, &'a Texture)>,
    emissive: Option<(&'a TextureBinding, &'a Texture)>,
    emission: [f32; 3],
    lod_bias: f32,
}

impl<'a> Shader<'a> {
    pub(crate) fn new(material: &'a Material, textures: &'a [Texture], lod_bias: f32) -> Self {
        let bind = |b: &'a Option<TextureBinding>| b.as_ref().map(|b| (b, &textures[b.texture]));
        Self {
            material,
            base: bind(&material.base_color_texture),
            emissive: bind(&material.emissive_texture),
            emission: material.emissive.map(|e| e * material.emissive_strength),
            lod_bias,
        }
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
        let m = self.material;
        let mut c = m.base_color;
        if let Some((b, t)) = self.base {
            let s = sample(b, t, uv, duv_dx, duv_dy, self.lod_bias);
            for k in 0..4 {
                c[k] *= s[k];
            }
        }
        let mut e = self.emission;
        if let Some((b, t)) = self.emissive {
            let s = sample(b, t, uv, duv_dx, duv_dy, self.lod_bias);
            for k in 0..3 {
                e[k] *= s[k];
            }
        }
        let alpha = match m.alpha_mode {
            AlphaMode::Opaque => 1.0,
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

#[inline]
fn sample(b: &TextureBinding, t: &Texture, uv: Vec2, dx: Vec2, dy: Vec2, lod_bias: f32) -> Rgba {
    let (w, h) = t.size();
    let size = Vec2::new(w as f32, h as f32);
    let (uv, dx, dy) = if b.uv_transform.is_identity() {
        (uv, dx, dy)
    } else {
        let o = b.uv_transform.apply(Vec2::ZERO);
        (
            b.uv_transform.apply(uv),
            b.uv_transform.apply(dx) - o,
            b.uv_transform.apply(dy) - o,
        )
    };
    let fx = (dx * size).length_squared();
    let fy = (dy * size).length_squared();
    let lod = 0.5 * fast_log2(fx.max(fy).max(1e-12)) + lod_bias;
    t.sample(&b.sampler, uv, lod)
}
