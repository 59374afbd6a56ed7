//! Scenes: triangle meshes in world space with unlit materials, and the built-in scenes.
//!
//! Rendering is unlit: a surface's colour is its base colour (factor times texture) plus its
//! emission (factor times texture times strength), in linear light. Alpha comes from the base
//! colour; [`AlphaMode`] says how it is used.

pub mod builtin;
pub mod load;
pub(crate) mod texture;

use glam::{Vec2, Vec3};

pub use texture::{FilterMode, Texture, TextureSampler, WrapMode};

use crate::lens::{Aperture, Camera};

/// How a material's alpha is used (glTF 2.0 `alphaMode`).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha ignored; the surface is opaque.
    #[default]
    Opaque,
    /// Alpha test: fragments with alpha below `cutoff` are discarded, the rest are opaque.
    Mask {
        /// The alpha cutoff (glTF default 0.5).
        cutoff: f32,
    },
    /// Alpha blending over what is behind, composited in depth order.
    Blend,
}

/// A texture bound to a material slot: which texture, how it is sampled, and a UV transform.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureBinding {
    /// Index into [`Scene::textures`].
    pub texture: usize,
    /// Filtering and wrapping.
    pub sampler: TextureSampler,
    /// UV transform applied before sampling: `uv' = offset + R(rotation) * (scale * uv)`
    /// (KHR_texture_transform). Identity by default.
    pub uv_transform: UvTransform,
}

/// A 2D affine transform of texture coordinates (KHR_texture_transform semantics).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    /// Translation in UV units.
    pub offset: Vec2,
    /// Rotation in radians (counter-clockwise in UV space).
    pub rotation_rad: f32,
    /// Scale.
    pub scale: Vec2,
}

impl Default for UvTransform {
    fn default() -> Self {
        Self {
            offset: Vec2::ZERO,
            rotation_rad: 0.0,
            scale: Vec2::ONE,
        }
    }
}

impl UvTransform {
    /// Applies the transform to `uv`.
    #[inline]
    pub fn apply(&self, uv: Vec2) -> Vec2 {
        let s = uv * self.scale;
        let (sin, cos) = self.rotation_rad.sin_cos();
        // glTF KHR_texture_transform rotation matrix: [cos sin; -sin cos] acting on (u, v).
        Vec2::new(cos * s.x + sin * s.y, -sin * s.x + cos * s.y) + self.offset
    }

    /// True if this is the identity.
    pub fn is_identity(&self) -> bool {
        *self == Self::default()
    }
}

/// An unlit material.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name, for messages.
    pub name: String,
    /// Linear RGBA base colour factor.
    pub base_color: [f32; 4],
    /// Base colour texture (linear after sRGB decoding), multiplied with `base_color`.
    pub base_color_texture: Option<TextureBinding>,
    /// Linear RGB emissive factor.
    pub emissive: [f32; 3],
    /// Emissive strength multiplier (KHR_materials_emissive_strength), for HDR highlights.
    pub emissive_strength: f32,
    /// Emissive texture, multiplied with `emissive`.
    pub emissive_texture: Option<TextureBinding>,
    /// How alpha is used.
    pub alpha_mode: AlphaMode,
    /// When false, triangles facing away from the camera are not drawn.
    pub double_sided: bool,
}

impl Default for Material {
    fn default() -> Self {
        Self {
            name: String::new(),
            base_color: [1.0; 4],
            base_color_texture: None,
            emissive: [0.0; 3],
            emissive_strength: 1.0,
            emissive_texture: None,
            alpha_mode: AlphaMode::Opaque,
            double_sided: true,
        }
    }
}

impl Material {
    /// An opaque, double-sided material of one linear colour.
    pub fn color(name: &str, rgb: [f32; 3]) -> Self {
        Self {
            name: name.to_string(),
            base_color: [rgb[0], rgb[1], rgb[2], 1.0],
            ..Self::default()
        }
    }

    /// An emissive, black-based material (an HDR light): `rgb * strength`.
    pub fn emissive(name: &str, rgb: [f32; 3], strength: f32) -> Self {
        Self {
            name: name.to_string(),
            base_color: [0.0, 0.0, 0.0, 1.0],
            emissive: rgb,
            emissive_strength: strength,
            ..Self::default()
        }
    }
}

/// A triangle mesh in world space.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Mesh {
    /// Vertex positions in metres, world space.
    pub positions: Vec<Vec3>,
    /// Texture coordinates (glTF convention: v = 0 at the top row of the image). Empty means
    /// all zero.
    pub uvs: Vec<Vec2>,
    /// Triangles as vertex indices, counter-clockwise front faces.
    pub indices: Vec<[u32; 3]>,
    /// Index into [`Scene::materials`].
    pub material: usize,
    /// Unit vertex normals, world space, as the file gives them (glTF `NORMAL`, OBJ `vn`).
    /// Empty when the file has none. Rendering is unlit and does not use them yet; they are
    /// kept for shading and for methods that want them.
    pub normals: Vec<Vec3>,
}

impl Mesh {
    /// Appends a parallelogram with corners `p0` (uv 0,0), `p0 + du` (uv 1,0), `p0 + du + dv`
    /// (uv 1,1) and `p0 + dv` (uv 0,1). With `du` pointing right and `dv` down on screen, the
    /// texture appears upright and the front face (counter-clockwise) faces away from the
    /// viewer, so use double-sided materials or pass `dv` up for single-sided ones.
    pub fn push_quad(&mut self, p0: Vec3, du: Vec3, dv: Vec3) {
        let base = self.positions.len() as u32;
        if self.uvs.len() < self.positions.len() {
            self.uvs.resize(self.positions.len(), Vec2::ZERO);
        }
        self.positions
            .extend_from_slice(&[p0, p0 + du, p0 + du + dv, p0 + dv]);
        self.uvs.extend_from_slice(&[
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 1.0),
        ]);
        self.indices
            .extend_from_slice(&[[base, base + 1, base + 2], [base, base + 2, base + 3]]);
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len()
    }

    /// Bytes the mesh takes: its arrays, and [`MESH_OVERHEAD_BYTES`] for itself in a scene's
    /// list and its arrays' allocations.
    pub fn bytes(&self) -> u64 {
        (self.positions.capacity() * std::mem::size_of::<Vec3>()
            + self.normals.capacity() * std::mem::size_of::<Vec3>()
            + self.uvs.capacity() * std::mem::size_of::<Vec2>()
            + self.indices.capacity() * std::mem::size_of::<[u32; 3]>()) as u64
            + MESH_OVERHEAD_BYTES
    }

    /// Bytes of a mesh of `vertices` vertices (with normals and texture coordinates as
    /// `normals` and `uvs` say) and `triangles` triangles, as [`Mesh::bytes`] counts them.
    pub fn bytes_for(vertices: usize, normals: bool, uvs: bool, triangles: usize) -> u64 {
        let per_vertex = std::mem::size_of::<Vec3>() * (1 + usize::from(normals))
            + std::mem::size_of::<Vec2>() * usize::from(uvs);
        (vertices * per_vertex + triangles * std::mem::size_of::<[u32; 3]>()) as u64
            + MESH_OVERHEAD_BYTES
    }
}

/// Bytes a mesh takes besides its arrays' contents: itself in a scene's list of meshes (which
/// may have doubled as it grew) and the allocator's share of each of its four arrays. A scene
/// of many small meshes (one triangle instanced by many nodes) is mostly this.
pub const MESH_OVERHEAD_BYTES: u64 = 2 * std::mem::size_of::<Mesh>() as u64 + 4 * 16;

/// Largest vertex coordinate in metres a scene may have (10,000 km): beyond it the depth and
/// projection arithmetic of f32 loses the precision a camera needs.
pub const MAX_COORDINATE_M: f32 = 1e7;

/// Camera and lens settings a scene suggests (built-in scenes, glTF cameras).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneDefaults {
    /// The camera, including resolution and lens.
    pub camera: Camera,
    /// The aperture shape.
    pub aperture: Aperture,
}

/// A scene: meshes, their materials and textures, and optionally a suggested camera.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Scene {
    /// Name, for messages and reports.
    pub name: String,
    /// Triangle meshes in world space.
    pub meshes: Vec<Mesh>,
    /// Materials, indexed by [`Mesh::material`].
    pub materials: Vec<Material>,
    /// Textures, indexed by [`TextureBinding::texture`].
    pub textures: Vec<Texture>,
    /// Camera and aperture the scene suggests.
    pub defaults: Option<SceneDefaults>,
}

impl Scene {
    /// Adds a material and returns its index.
    pub fn add_material(&mut self, material: Material) -> usize {
        self.materials.push(material);
        self.materials.len() - 1
    }

    /// Adds a texture and returns its index.
    pub fn add_texture(&mut self, texture: Texture) -> usize {
        self.textures.push(texture);
        self.textures.len() - 1
    }

    /// Total number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(Mesh::triangle_count).sum()
    }

    /// Total number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.meshes.iter().map(|m| m.positions.len()).sum()
    }

    /// Bytes the scene's meshes and textures take (what a run holds for the scene itself,
    /// besides what it makes from it).
    pub fn bytes(&self) -> u64 {
        self.meshes.iter().map(Mesh::bytes).sum::<u64>()
            + self.textures.iter().map(Texture::bytes).sum::<u64>()
    }

    /// Axis-aligned bounds (min, max) of all vertices, or `None` for an empty scene.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self.meshes.iter().flat_map(|m| m.positions.iter().copied());
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }

    /// Checks indices, material and texture references, so the rasterizer can index freely.
    pub fn validate(&self) -> crate::Result<()> {
        use crate::Error;
        for (mi, mesh) in self.meshes.iter().enumerate() {
            if mesh.material >= self.materials.len() {
                return Err(Error::invalid(
                    "scene",
                    format!(
                        "mesh {mi} uses material {} but the scene has {}",
                        mesh.material,
                        self.materials.len()
                    ),
                ));
            }
            if !mesh.uvs.is_empty() && mesh.uvs.len() != mesh.positions.len() {
                return Err(Error::invalid(
                    "scene",
                    format!(
                        "mesh {mi} has {} texture coordinates for {} vertices",
                        mesh.uvs.len(),
                        mesh.positions.len()
                    ),
                ));
            }
            let n = mesh.positions.len() as u32;
            if let Some(tri) = mesh.indices.iter().find(|t| t.iter().any(|&i| i >= n)) {
                return Err(Error::invalid(
                    "scene",
                    format!("mesh {mi}: triangle {tri:?} indexes past its {n} vertices"),
                ));
            }
            if let Some(p) = mesh.positions.iter().find(|p| !p.is_finite()) {
                return Err(Error::invalid(
                    "scene",
                    format!("mesh {mi}: vertex position {p} is not finite"),
                ));
            }
            if let Some(p) = mesh
                .positions
                .iter()
                .find(|p| p.abs().max_element() > MAX_COORDINATE_M)
            {
                return Err(Error::invalid(
                    "scene",
                    format!(
                        "mesh {mi}: vertex position {p} m is beyond +-{MAX_COORDINATE_M:e} m: expected scene coordinates in metres within that range"
                    ),
                ));
            }
        }
        for m in &self.materials {
            for b in [&m.base_color_texture, &m.emissive_texture]
                .into_iter()
                .flatten()
            {
                if b.texture >= self.textures.len() {
                    return Err(Error::invalid(
                        "scene",
                        format!(
                            "material '{}' uses texture {} but the scene has {}",
                            m.name,
                            b.texture,
                            self.textures.len()
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}
