//! glTF 2.0 (`.gltf` + external or embedded files, `.glb`) to a world-space [`Scene`].
//!
//! The `gltf` crate parses and validates the JSON; the container, the buffers, the accessor
//! data and the images are read here, with every offset and count checked against the bytes
//! there are, so malformed files give errors (naming the element and what was expected) and
//! never panics.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use ::gltf as gl;
use gl::json::validation::Validate;
use glam::{Affine3A, Mat4, Quat, Vec2, Vec3};
use rayon::prelude::*;

use super::external::{self, Limit, SceneFolder, MAX_IMAGE_FILE_BYTES};
use super::image_file::{self, Encoding};
use super::{FileCamera, SceneFile};
use super::{
    DEFAULT_FAR_M, DEFAULT_FSTOP, DEFAULT_HEIGHT_PX, DEFAULT_SENSOR_WIDTH_MM, DEFAULT_WIDTH_PX,
};
use crate::error::shown;
use crate::lens::Camera;
use crate::scene::{
    AlphaMode, FilterMode, Material, Mesh, Scene, Texture, TextureBinding, TextureSampler,
    UvTransform, WrapMode,
};
use crate::{Error, Result};

/// Extensions a file may list in `extensionsRequired`. Others are refused: a required extension
/// changes what the data means. `KHR_materials_unlit` only says how to shade, and we shade unlit.
const SUPPORTED_REQUIRED_EXTENSIONS: &[&str] = &[
    "KHR_materials_emissive_strength",
    "KHR_texture_transform",
    "KHR_materials_unlit",
];

/// Most elements an accessor without a buffer view (all zeros plus sparse values) may have, so
/// a tiny file cannot ask for gigabytes.
const MAX_SPARSE_ONLY_ELEMENTS: usize = 1 << 24;

/// Bytes a JSON object of a glTF file can take once parsed, at most: the largest of the
/// `gltf` crate's structures (a node: its optional transform, children, name, weights and
/// extras, about 250 bytes) in a list that may have doubled as it grew.
const JSON_OBJECT_BYTES: usize = 512;

/// GLB chunk types (little-endian "JSON" and "BIN\0").
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// Loads a glTF or GLB file; the files it refers to are read from `folder`.
pub(super) fn load(path: &Path, folder: &SceneFolder) -> Result<SceneFile> {
    let bytes = external::read_scene(path, folder)?;
    let (json, bin) = split_container(path, &bytes)?;
    // The parsed document, counted before it is parsed: an object of a few bytes of text (a
    // node `{"mesh":0}`) becomes a structure of hundreds.
    let objects = json.iter().filter(|&&b| b == b'{').count();
    folder.ledger().reserve(
        (json.len() + objects * JSON_OBJECT_BYTES) as u64,
        || format!("{}: parsing its {objects} JSON objects", shown(&path)),
        "the scene's size",
    )?;
    let root = gl::json::Root::from_slice(json)
        .map_err(|e| Error::format(path, format!("not valid glTF JSON: {e}")))?;
    check_required_extensions(path, &root)?;
    validate(path, &root)?;
    let doc = gl::Document::from_json_without_validation(root);
    let buffers = load_buffers(path, folder, &doc, bin)?;
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    Loader {
        path,
        folder,
        doc: &doc,
        buffers,
        scene: Scene {
            name,
            ..Scene::default()
        },
        materials: HashMap::new(),
        images: HashMap::new(),
        image_order: Vec::new(),
        primitives: HashMap::new(),
    }
    .run()
}

/// Splits binary glTF into its JSON and BIN chunks; anything else is taken as JSON.
fn split_container<'a>(path: &Path, bytes: &'a [u8]) -> Result<(&'a [u8], Option<&'a [u8]>)> {
    if !bytes.starts_with(b"glTF") {
        return Ok((bytes, None));
    }
    let err = |m: String| Error::format(path, format!("binary glTF (GLB): {m}"));
    let u32_at = |o: usize| {
        bytes
            .get(o..o + 4)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(u32::from_le_bytes)
    };
    let version = u32_at(4).ok_or_else(|| err("the 12-byte header is truncated".into()))?;
    if version != 2 {
        return Err(err(format!("version {version}: expected 2")));
    }
    let length = u32_at(8).ok_or_else(|| err("the 12-byte header is truncated".into()))? as usize;
    if length > bytes.len() {
        return Err(err(format!(
            "the header gives a length of {length} bytes but the file has {} (truncated?)",
            bytes.len()
        )));
    }
    let data = &bytes[..length];
    let data_u32_at = |o: usize| {
        data.get(o..o.saturating_add(4))
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(u32::from_le_bytes)
    };
    let mut offset = 12;
    let mut json = None;
    let mut bin = None;
    while offset < data.len() {
        let (Some(len), Some(ty)) = (data_u32_at(offset), data_u32_at(offset + 4)) else {
            return Err(err(format!("chunk header at byte {offset} is truncated")));
        };
        let start = offset + 8;
        let body = start
            .checked_add(len as usize)
            .and_then(|end| data.get(start..end))
            .ok_or_else(|| {
                err(format!(
                    "chunk at byte {offset} says {len} bytes but only {} follow (truncated?)",
                    data.len().saturating_sub(start)
                ))
            })?;
        match ty {
            CHUNK_JSON if json.is_none() => json = Some(body),
            CHUNK_BIN if json.is_some() && bin.is_none() => bin = Some(body),
            _ if json.is_none() => {
                return Err(err(format!(
                    "the first chunk has type 0x{ty:08x}: expected JSON (0x{CHUNK_JSON:08x})"
                )))
            }
            _ => {} // Unknown chunks after the JSON are skipped, as the specification says.
        }
        offset = start + len as usize;
    }
    let json = json.ok_or_else(|| err("no JSON chunk".into()))?;
    Ok((json, bin))
}

fn check_required_extensions(path: &Path, root: &gl::json::Root) -> Result<()> {
    for ext in &root.extensions_required {
        if !SUPPORTED_REQUIRED_EXTENSIONS.contains(&ext.as_str()) {
            return Err(Error::format(
                path,
                format!(
                    "extensionsRequired lists {ext}, which defocus does not support (supported: {})",
                    SUPPORTED_REQUIRED_EXTENSIONS.join(", ")
                ),
            ));
        }
    }
    Ok(())
}

/// Runs the `gltf` crate's validation (indices in range, required fields, enum values).
fn validate(path: &Path, root: &gl::json::Root) -> Result<()> {
    // The crate's validation looks up each POSITION accessor without a range check: check
    // attribute indices first.
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if index.value() >= root.accessors.len() {
                    return Err(Error::format(
                        path,
                        format!(
                            "invalid glTF: meshes[{mi}].primitives[{pi}].attributes.{}: accessor \
                             {} is out of range (the file has {} accessors)",
                            semantic_name(semantic),
                            index.value(),
                            root.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    let mut errors = Vec::new();
    root.validate(root, gl::json::Path::new, &mut |p, e| errors.push((p(), e)));
    // Required extensions were checked against our own list above.
    errors.retain(|(p, _)| !p.as_str().starts_with("extensionsRequired"));
    match errors.first() {
        None => Ok(()),
        Some((p, e)) => {
            let more = match errors.len() {
                1 => String::new(),
                n => format!(" (and {} more problems)", n - 1),
            };
            Err(Error::format(path, format!("invalid glTF: {p}: {e}{more}")))
        }
    }
}

fn semantic_name(s: &gl::json::validation::Checked<gl::json::mesh::Semantic>) -> String {
    use gl::json::mesh::Semantic as S;
    match s {
        gl::json::validation::Checked::Valid(s) => match s {
            S::Positions => "POSITION".into(),
            S::Normals => "NORMAL".into(),
            S::Tangents => "TANGENT".into(),
            S::Colors(n) => format!("COLOR_{n}"),
            S::TexCoords(n) => format!("TEXCOORD_{n}"),
            S::Joints(n) => format!("JOINTS_{n}"),
            S::Weights(n) => format!("WEIGHTS_{n}"),
            S::Extras(name) => name.clone(),
        },
        gl::json::validation::Checked::Invalid => "(unknown)".into(),
    }
}

/// Reads the bytes a URI points to: a `data:` URI, or a file of the scene's folder (see
/// [`SceneFolder`]) read as far as `limit` says. `field` is where the URI is (`buffers[0].uri`)
/// and `what` names the element in other errors.
fn read_uri(
    path: &Path,
    folder: &SceneFolder,
    uri: &str,
    field: &str,
    what: &str,
    limit: Limit,
) -> Result<Vec<u8>> {
    let err = |m: String| Error::format(path, format!("{what}: {m}"));
    if let Some(rest) = uri.strip_prefix("data:") {
        let (meta, payload) = rest
            .split_once(',')
            .ok_or_else(|| err("data URI without a ',' before its data".into()))?;
        // Decoded, the data takes at most as many bytes as its text.
        folder.ledger().reserve(
            payload.len() as u64,
            || format!("{}: {what} (data URI)", shown(&path)),
            "the scene's size",
        )?;
        return if meta.ends_with(";base64") {
            image_file::base64_decode(payload).map_err(err)
        } else {
            image_file::percent_decode(payload)
                .map(String::into_bytes)
                .map_err(err)
        };
    }
    if let Some((scheme, _)) = uri.split_once("://") {
        return Err(err(format!(
            "URI scheme '{}' is not supported: expected a relative file path or a data URI",
            shown(scheme)
        )));
    }
    let file = image_file::percent_decode(uri).map_err(err)?;
    folder.read(field, Path::new(&file), limit)
}

fn load_buffers<'a>(
    path: &Path,
    folder: &SceneFolder,
    doc: &gl::Document,
    bin: Option<&'a [u8]>,
) -> Result<Vec<Cow<'a, [u8]>>> {
    let mut out = Vec::new();
    for buffer in doc.buffers() {
        let i = buffer.index();
        let (data, source): (Cow<[u8]>, String) = match buffer.source() {
            gl::buffer::Source::Bin => (
                Cow::Borrowed(bin.ok_or_else(|| {
                    Error::format(
                        path,
                        format!(
                            "buffer {i} has no uri, so it is the GLB binary chunk, but the file \
                             has no binary chunk"
                        ),
                    )
                })?),
                "the GLB binary chunk".into(),
            ),
            gl::buffer::Source::Uri(uri) => (
                Cow::Owned(read_uri(
                    path,
                    folder,
                    uri,
                    &format!("buffers[{i}].uri"),
                    &format!("buffer {i}"),
                    // The declared length and no more: the rest of the file is not the buffer's.
                    Limit::Prefix(buffer.length() as u64),
                )?),
                if uri.starts_with("data:") {
                    "its data URI".into()
                } else {
                    format!("'{}'", shown(uri))
                },
            ),
        };
        if data.len() < buffer.length() {
            return Err(Error::format(
                path,
                format!(
                    "buffer {i}: {source} has {} bytes: expected byteLength {}",
                    data.len(),
                    buffer.length()
                ),
            ));
        }
        out.push(data);
    }
    Ok(out)
}

/// A primitive in its mesh's local space.
struct LocalPrimitive {
    positions: Vec<Vec3>,
    /// Local-space normals, one per position, or empty.
    normals: Vec<Vec3>,
    uvs: Vec<Vec2>,
    indices: Vec<[u32; 3]>,
    material: Option<usize>,
}

struct Loader<'a> {
    path: &'a Path,
    folder: &'a SceneFolder,
    doc: &'a gl::Document,
    buffers: Vec<Cow<'a, [u8]>>,
    scene: Scene,
    /// glTF material index (`None`: the default material) to scene material index.
    materials: HashMap<Option<usize>, usize>,
    /// glTF image index to scene texture index.
    images: HashMap<usize, usize>,
    /// glTF image index of each scene texture, in order.
    image_order: Vec<usize>,
    /// Primitives of each glTF mesh read so far (meshes used by several nodes are read once).
    primitives: HashMap<usize, Arc<Vec<LocalPrimitive>>>,
}

fn node_matrix(node: &gl::Node) -> Mat4 {
    match node.transform() {
        gl::scene::Transform::Matrix { matrix } => Mat4::from_cols_array_2d(&matrix),
        gl::scene::Transform::Decomposed {
            translation,
            rotation,
            scale,
        } => {
            let q = Quat::from_array(rotation);
            let q = if q.length_squared() > 0.0 {
                q.normalize()
            } else {
                Quat::IDENTITY
            };
            Mat4::from_scale_rotation_translation(scale.into(), q, translation.into())
        }
    }
}

fn mode_name(mode: gl::mesh::Mode) -> &'static str {
    use gl::mesh::Mode as M;
    match mode {
        M::Points => "POINTS (0)",
        M::Lines => "LINES (1)",
        M::LineLoop => "LINE_LOOP (2)",
        M::LineStrip => "LINE_STRIP (3)",
        M::Triangles => "TRIANGLES (4)",
        M::TriangleStrip => "TRIANGLE_STRIP (5)",
        M::TriangleFan => "TRIANGLE_FAN (6)",
    }
}

fn sampler_of(s: &gl::texture::Sampler) -> TextureSampler {
    use gl::texture::{MagFilter, MinFilter, WrappingMode};
    let wrap = |w: WrappingMode| match w {
        WrappingMode::ClampToEdge => WrapMode::ClampToEdge,
        WrappingMode::MirroredRepeat => WrapMode::MirroredRepeat,
        WrappingMode::Repeat => WrapMode::Repeat,
    };
    let mag_filter = match s.mag_filter() {
        Some(MagFilter::Nearest) => FilterMode::Nearest,
        Some(MagFilter::Linear) | None => FilterMode::Linear,
    };
    use FilterMode::{Linear, Nearest};
    let (min_filter, mip_filter) = match s.min_filter() {
        Some(MinFilter::Nearest) => (Nearest, None),
        Some(MinFilter::Linear) => (Linear, None),
        Some(MinFilter::NearestMipmapNearest) => (Nearest, Some(Nearest)),
        Some(MinFilter::LinearMipmapNearest) => (Linear, Some(Nearest)),
        Some(MinFilter::NearestMipmapLinear) => (Nearest, Some(Linear)),
        Some(MinFilter::LinearMipmapLinear) | None => (Linear, Some(Linear)),
    };
    TextureSampler {
        mag_filter,
        min_filter,
        mip_filter,
        wrap_u: wrap(s.wrap_s()),
        wrap_v: wrap(s.wrap_t()),
    }
}

/// The texture coordinate set a material samples: its base colour texture's, else its emissive
/// texture's.
fn uv_set(material: &gl::Material) -> Option<u32> {
    let set = |info: gl::texture::Info| {
        info.texture_transform()
            .and_then(|t| t.tex_coord())
            .unwrap_or(info.tex_coord())
    };
    material
        .pbr_metallic_roughness()
        .base_color_texture()
        .map(set)
        .or_else(|| material.emissive_texture().map(set))
}

/// Converts one component of accessor data to `T`.
type ReadFn<T> = fn(&[u8]) -> T;

fn le_u16(b: &[u8]) -> u16 {
    u16::from_le_bytes([b[0], b[1]])
}

fn le_u32(b: &[u8]) -> u32 {
    u32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

/// How floats are read from each component type (glTF 2.0, section 3.11: normalised integers).
fn float_reader(ty: gl::accessor::DataType, normalized: bool) -> ReadFn<f32> {
    use gl::accessor::DataType as D;
    match (ty, normalized) {
        (D::F32, _) => |b| f32::from_bits(le_u32(b)),
        (D::U8, false) => |b| b[0] as f32,
        (D::U8, true) => |b| b[0] as f32 / 255.0,
        (D::I8, false) => |b| b[0] as i8 as f32,
        (D::I8, true) => |b| (b[0] as i8 as f32 / 127.0).max(-1.0),
        (D::U16, false) => |b| le_u16(b) as f32,
        (D::U16, true) => |b| le_u16(b) as f32 / 65535.0,
        (D::I16, false) => |b| le_u16(b) as i16 as f32,
        (D::I16, true) => |b| (le_u16(b) as i16 as f32 / 32767.0).max(-1.0),
        (D::U32, _) => |b| le_u32(b) as f32,
    }
}

impl<'a> Loader<'a> {
    fn err(&self, message: String) -> Error {
        Error::format(self.path, message)
    }

    /// Counts `bytes` that `what` is about to allocate against the memory budget (the load's
    /// ledger): refused, before allocating, when the scene would pass it.
    fn reserve(&self, bytes: usize, what: impl FnOnce() -> String) -> Result<()> {
        self.folder.ledger().reserve(
            bytes as u64,
            || format!("{}: {}", shown(&self.path), what()),
            "the scene's size",
        )
    }

    /// `make(&input)`, with its `len` elements counted against the budget before they are
    /// made and `input` released once it is dropped: one form of the data to another.
    fn convert<A, B>(
        &self,
        input: Vec<A>,
        len: usize,
        what: &str,
        make: impl FnOnce(&[A]) -> Vec<B>,
    ) -> Result<Vec<B>> {
        self.reserve(len * std::mem::size_of::<B>(), || what.to_string())?;
        let out = make(&input);
        self.folder
            .ledger()
            .release((input.len() * std::mem::size_of::<A>()) as u64);
        Ok(out)
    }

    fn run(mut self) -> Result<SceneFile> {
        let doc = self.doc;
        let roots: Vec<gl::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
            Some(s) => s.nodes().collect(),
            None => {
                let mut is_child = vec![false; doc.nodes().len()];
                for n in doc.nodes() {
                    for c in n.children() {
                        is_child[c.index()] = true;
                    }
                }
                doc.nodes().filter(|n| !is_child[n.index()]).collect()
            }
        };
        // Depth-first, in file order. A node reached twice (a cycle, or a child shared by two
        // parents, both invalid glTF) is drawn once.
        let mut visited = vec![false; doc.nodes().len()];
        let mut stack: Vec<(gl::Node, Mat4)> = roots
            .into_iter()
            .rev()
            .map(|n| (n, Mat4::IDENTITY))
            .collect();
        let mut camera_nodes = Vec::new();
        while let Some((node, parent)) = stack.pop() {
            if std::mem::replace(&mut visited[node.index()], true) {
                continue;
            }
            let world = parent * node_matrix(&node);
            if let Some(mesh) = node.mesh() {
                self.add_mesh_instance(&mesh, &world)?;
            }
            if let Some(camera) = node.camera() {
                camera_nodes.push((node.clone(), camera, world));
            }
            let children: Vec<gl::Node> = node.children().collect();
            stack.extend(children.into_iter().rev().map(|c| (c, world)));
        }
        self.decode_textures()?;
        let mut cameras = Vec::new();
        let mut skipped_cameras = Vec::new();
        for (node, camera, world) in camera_nodes {
            match self.camera(&node, &camera, &world)? {
                Some(c) => cameras.push(c),
                None => skipped_cameras.push(format!(
                    "camera {} ('{}', orthographic)",
                    camera.index(),
                    shown(node.name().or(camera.name()).unwrap_or("unnamed"))
                )),
            }
        }
        cameras.sort_by_key(|c| c.index);
        Ok(SceneFile {
            scene: self.scene,
            cameras,
            skipped_cameras,
            files_read: Vec::new(),
        })
    }

    fn add_mesh_instance(&mut self, mesh: &gl::Mesh, world: &Mat4) -> Result<()> {
        let prims = match self.primitives.get(&mesh.index()) {
            Some(p) => Arc::clone(p),
            None => {
                let p = Arc::new(self.read_mesh(mesh)?);
                self.primitives.insert(mesh.index(), Arc::clone(&p));
                p
            }
        };
        // A mirroring transform turns counter-clockwise triangles clockwise: swap two corners so
        // front faces stay counter-clockwise (glTF 2.0, section 3.7.4).
        let flip = world.determinant() < 0.0;
        let affine = Affine3A::from_mat4(*world);
        // Normals transform by the inverse transpose of the linear part.
        let normal_matrix = glam::Mat3::from_mat4(*world).inverse().transpose();
        for p in prims.iter() {
            let material = self.material(p.material)?;
            self.reserve(
                Mesh::bytes_for(
                    p.positions.len(),
                    !p.normals.is_empty(),
                    !p.uvs.is_empty(),
                    p.indices.len(),
                ) as usize,
                || {
                    format!(
                        "an instance of mesh {} ({} triangles, {} instances so far)",
                        mesh.index(),
                        p.indices.len(),
                        self.scene.meshes.len()
                    )
                },
            )?;
            self.scene.meshes.push(Mesh {
                positions: p
                    .positions
                    .iter()
                    .map(|&v| affine.transform_point3(v))
                    .collect(),
                normals: p
                    .normals
                    .iter()
                    .map(|&n| (normal_matrix * n).normalize_or_zero())
                    .collect(),
                uvs: p.uvs.clone(),
                indices: if flip {
                    p.indices.iter().map(|t| [t[0], t[2], t[1]]).collect()
                } else {
                    p.indices.clone()
                },
                material,
            });
        }
        Ok(())
    }

    fn read_mesh(&self, mesh: &gl::Mesh) -> Result<Vec<LocalPrimitive>> {
        let mut out = Vec::new();
        for prim in mesh.primitives() {
            let what = format!(
                "mesh {}{} primitive {}",
                mesh.index(),
                mesh.name()
                    .map(|n| format!(" ('{}')", shown(n)))
                    .unwrap_or_default(),
                prim.index()
            );
            let mode = prim.mode();
            if !matches!(
                mode,
                gl::mesh::Mode::Triangles
                    | gl::mesh::Mode::TriangleStrip
                    | gl::mesh::Mode::TriangleFan
            ) {
                return Err(self.err(format!(
                    "{what}: mode {} is not supported: expected TRIANGLES (4), TRIANGLE_STRIP (5) \
                     or TRIANGLE_FAN (6)",
                    mode_name(mode)
                )));
            }
            let pos = prim
                .get(&gl::Semantic::Positions)
                .ok_or_else(|| self.err(format!("{what}: no POSITION attribute")))?;
            let flat = self.read_floats(&pos, &format!("{what} POSITION"), 3)?;
            let positions: Vec<Vec3> =
                self.convert(flat, pos.count(), &format!("{what} POSITION"), |f| {
                    f.chunks_exact(3).map(Vec3::from_slice).collect()
                })?;
            let n = positions.len();
            if n > u32::MAX as usize {
                return Err(self.err(format!("{what}: {n} vertices is more than 2^32 - 1")));
            }
            let normals = match prim.get(&gl::Semantic::Normals) {
                None => Vec::new(),
                Some(acc) => {
                    let flat = self.read_floats(&acc, &format!("{what} NORMAL"), 3)?;
                    if flat.len() != 3 * n {
                        return Err(self.err(format!(
                            "{what}: NORMAL has {} elements for {n} positions",
                            flat.len() / 3
                        )));
                    }
                    self.convert(flat, n, &format!("{what} NORMAL"), |f| {
                        f.chunks_exact(3).map(Vec3::from_slice).collect()
                    })?
                }
            };
            let uvs = match uv_set(&prim.material()) {
                None => Vec::new(),
                Some(set) => {
                    let acc = prim.get(&gl::Semantic::TexCoords(set)).ok_or_else(|| {
                        self.err(format!(
                            "{what}: its material samples TEXCOORD_{set}, which the primitive \
                             does not have"
                        ))
                    })?;
                    let flat = self.read_floats(&acc, &format!("{what} TEXCOORD_{set}"), 2)?;
                    if flat.len() != 2 * n {
                        return Err(self.err(format!(
                            "{what}: TEXCOORD_{set} has {} elements for {n} positions",
                            flat.len() / 2
                        )));
                    }
                    self.convert(flat, n, &format!("{what} TEXCOORD_{set}"), |f| {
                        f.chunks_exact(2).map(Vec2::from_slice).collect()
                    })?
                }
            };
            let idx: Vec<u32> = match prim.indices() {
                Some(acc) => self.read_indices(&acc, &format!("{what} indices"))?,
                None => {
                    self.reserve(n * 4, || format!("{what} vertices as indices"))?;
                    (0..n as u32).collect()
                }
            };
            if let Some((k, &i)) = idx.iter().enumerate().find(|(_, &i)| i as usize >= n) {
                return Err(self.err(format!(
                    "{what}: index {i} (element {k} of its indices) is out of range: the \
                     primitive has {n} vertices"
                )));
            }
            if mode == gl::mesh::Mode::Triangles && !idx.len().is_multiple_of(3) {
                return Err(self.err(format!(
                    "{what}: {} indices (or vertices) for TRIANGLES: expected a multiple of 3",
                    idx.len()
                )));
            }
            let triangles = match mode {
                gl::mesh::Mode::Triangles => idx.len() / 3,
                gl::mesh::Mode::TriangleStrip => idx.len().saturating_sub(2),
                _ => idx.len().saturating_sub(2),
            };
            let indices: Vec<[u32; 3]> = self.convert(
                idx,
                triangles,
                &format!("{what} triangles"),
                |idx| match mode {
                    gl::mesh::Mode::Triangles => {
                        idx.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect()
                    }
                    gl::mesh::Mode::TriangleStrip => (0..idx.len().saturating_sub(2))
                        .map(|i| {
                            if i % 2 == 0 {
                                [idx[i], idx[i + 1], idx[i + 2]]
                            } else {
                                [idx[i + 1], idx[i], idx[i + 2]]
                            }
                        })
                        .collect(),
                    _ => (1..idx.len().saturating_sub(1))
                        .map(|i| [idx[i], idx[i + 1], idx[0]])
                        .collect(),
                },
            )?;
            out.push(LocalPrimitive {
                positions,
                normals,
                uvs,
                indices,
                material: prim.material().index(),
            });
        }
        Ok(out)
    }

    /// The bytes of a buffer view and its stride.
    fn view_bytes(
        &self,
        view: &gl::buffer::View<'a>,
        what: &str,
    ) -> Result<(&[u8], Option<usize>)> {
        let b = view.buffer().index();
        let buffer = self
            .buffers
            .get(b)
            .ok_or_else(|| self.err(format!("{what}: buffer {b} does not exist")))?;
        let start = view.offset();
        let end = start.saturating_add(view.length());
        let data = buffer.get(start..end).ok_or_else(|| {
            self.err(format!(
                "{what}: buffer view {} (bytes {start}..{end}) runs past the end of buffer {b} \
                 ({} bytes)",
                view.index(),
                buffer.len()
            ))
        })?;
        Ok((data, view.stride()))
    }

    /// The elements of an accessor, `ncomp` components each, every component read by `read`,
    /// with sparse substitution applied. Offsets, strides and counts are checked against the
    /// buffer view.
    fn read_accessor<T: Copy + Default>(
        &self,
        acc: &gl::Accessor<'a>,
        what: &str,
        ncomp: usize,
        read: ReadFn<T>,
    ) -> Result<Vec<T>> {
        let csize = acc.data_type().size();
        let elem = csize * ncomp;
        let count = acc.count();
        let ai = acc.index();
        let read_into = |out: &mut [T], data: &[u8], stride: usize| {
            for (i, dst) in out.chunks_exact_mut(ncomp).enumerate() {
                let e = &data[i * stride..];
                for (c, d) in dst.iter_mut().enumerate() {
                    *d = read(&e[c * csize..]);
                }
            }
        };
        // Byte range [start, end) of `n` elements of `size` bytes, `stride` apart, from `start`.
        let span = |start: usize, n: usize, stride: usize, size: usize| {
            if n == 0 {
                return Some(start);
            }
            (n - 1)
                .checked_mul(stride)
                .and_then(|x| x.checked_add(start))
                .and_then(|x| x.checked_add(size))
        };
        let mut out = match acc.view() {
            Some(view) => {
                let (data, stride) = self.view_bytes(&view, what)?;
                let stride = stride.unwrap_or(elem);
                if stride < elem {
                    return Err(self.err(format!(
                        "{what}: buffer view {} has byteStride {stride}, less than the \
                         {elem}-byte elements of accessor {ai}",
                        view.index()
                    )));
                }
                let start = acc.offset();
                let end = span(start, count, stride, elem).unwrap_or(usize::MAX);
                if end > data.len() {
                    return Err(self.err(format!(
                        "{what}: accessor {ai} ({count} elements) reads bytes {start}..{end} of \
                         buffer view {}, which has {} bytes",
                        view.index(),
                        data.len()
                    )));
                }
                self.reserve(count * ncomp * std::mem::size_of::<T>(), || {
                    format!("{what}: {count} elements of accessor {ai}")
                })?;
                let mut out = vec![T::default(); count * ncomp];
                read_into(&mut out, &data[start..end], stride);
                out
            }
            None => {
                if count > MAX_SPARSE_ONLY_ELEMENTS {
                    return Err(self.err(format!(
                        "{what}: accessor {ai} has {count} elements and no buffer view: expected \
                         at most {MAX_SPARSE_ONLY_ELEMENTS}"
                    )));
                }
                self.reserve(count * ncomp * std::mem::size_of::<T>(), || {
                    format!("{what}: {count} elements of accessor {ai}")
                })?;
                vec![T::default(); count * ncomp]
            }
        };
        if let Some(sparse) = acc.sparse() {
            let k = sparse.count();
            let indices = sparse.indices();
            let isize = indices.index_type().size();
            let (idata, _) = self.view_bytes(&indices.view(), what)?;
            let istart = indices.offset();
            let iend = span(istart, k, isize, isize).unwrap_or(usize::MAX);
            let values = sparse.values();
            let (vdata, _) = self.view_bytes(&values.view(), what)?;
            let vstart = values.offset();
            let vend = span(vstart, k, elem, elem).unwrap_or(usize::MAX);
            if iend > idata.len() || vend > vdata.len() {
                return Err(self.err(format!(
                    "{what}: the {k} sparse indices or values of accessor {ai} run past the end \
                     of their buffer views"
                )));
            }
            // Within the checked views: no larger than the buffers, which are counted.
            let mut vals = vec![T::default(); k * ncomp];
            read_into(&mut vals, &vdata[vstart..vend], elem);
            let ibytes = &idata[istart..iend];
            for (j, val) in vals.chunks_exact(ncomp).enumerate() {
                let b = &ibytes[j * isize..];
                let target = match isize {
                    1 => b[0] as usize,
                    2 => le_u16(b) as usize,
                    _ => le_u32(b) as usize,
                };
                let dst = out
                    .get_mut(target * ncomp..(target + 1) * ncomp)
                    .ok_or_else(|| {
                        self.err(format!(
                            "{what}: sparse index {target} of accessor {ai} is out of range (it \
                             has {count} elements)"
                        ))
                    })?;
                dst.copy_from_slice(val);
            }
        }
        Ok(out)
    }

    fn read_floats(&self, acc: &gl::Accessor<'a>, what: &str, ncomp: usize) -> Result<Vec<f32>> {
        let dims = acc.dimensions().multiplicity();
        if dims != ncomp {
            return Err(self.err(format!(
                "{what}: accessor {} has type {:?}: expected {}",
                acc.index(),
                acc.dimensions(),
                if ncomp == 1 {
                    "SCALAR".to_string()
                } else {
                    format!("VEC{ncomp}")
                }
            )));
        }
        self.read_accessor(
            acc,
            what,
            ncomp,
            float_reader(acc.data_type(), acc.normalized()),
        )
    }

    fn read_indices(&self, acc: &gl::Accessor<'a>, what: &str) -> Result<Vec<u32>> {
        use gl::accessor::DataType as D;
        if acc.dimensions() != gl::accessor::Dimensions::Scalar {
            return Err(self.err(format!(
                "{what}: accessor {} has type {:?}: expected SCALAR",
                acc.index(),
                acc.dimensions()
            )));
        }
        let read: ReadFn<u32> = match acc.data_type() {
            D::U8 => |b| b[0] as u32,
            D::U16 => |b| le_u16(b) as u32,
            D::U32 => le_u32,
            other => {
                return Err(self.err(format!(
                    "{what}: accessor {} has component type {other:?}: expected UNSIGNED_BYTE, \
                     UNSIGNED_SHORT or UNSIGNED_INT",
                    acc.index()
                )))
            }
        };
        self.read_accessor(acc, what, 1, read)
    }

    /// The scene material for a glTF material index (`None`: glTF's default material).
    fn material(&mut self, index: Option<usize>) -> Result<usize> {
        if let Some(&m) = self.materials.get(&index) {
            return Ok(m);
        }
        let material = match index {
            // glTF 2.0, section 3.9.6: white, opaque, single-sided.
            None => Material {
                name: "default".into(),
                double_sided: false,
                ..Material::default()
            },
            Some(i) => {
                let m = self
                    .doc
                    .materials()
                    .nth(i)
                    .ok_or_else(|| self.err(format!("material {i} does not exist")))?;
                self.convert_material(&m)?
            }
        };
        let m = self.scene.add_material(material);
        self.materials.insert(index, m);
        Ok(m)
    }

    fn convert_material(&mut self, m: &gl::Material) -> Result<Material> {
        let i = m.index().unwrap_or(0);
        let name = m
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("material {i}"));
        let what = format!("material {i} ('{name}')");
        let check = |field: &str, values: &[f32]| -> Result<()> {
            if values.iter().all(|v| v.is_finite() && *v >= 0.0) {
                Ok(())
            } else {
                Err(self.err(format!(
                    "{what}: {field} {values:?}: expected finite values of at least 0"
                )))
            }
        };
        let pbr = m.pbr_metallic_roughness();
        let base_color = pbr.base_color_factor();
        check("baseColorFactor", &base_color)?;
        let emissive = m.emissive_factor();
        check("emissiveFactor", &emissive)?;
        let emissive_strength = m.emissive_strength().unwrap_or(1.0);
        check(
            "KHR_materials_emissive_strength.emissiveStrength",
            &[emissive_strength],
        )?;
        let alpha_mode = match m.alpha_mode() {
            gl::material::AlphaMode::Opaque => AlphaMode::Opaque,
            gl::material::AlphaMode::Mask => AlphaMode::Mask {
                cutoff: m.alpha_cutoff().unwrap_or(0.5),
            },
            gl::material::AlphaMode::Blend => AlphaMode::Blend,
        };
        if let AlphaMode::Mask { cutoff } = alpha_mode {
            check("alphaCutoff", &[cutoff])?;
        }
        let base_color_texture = match pbr.base_color_texture() {
            Some(info) => Some(self.binding(&info, &what)?),
            None => None,
        };
        let emissive_texture = match m.emissive_texture() {
            Some(info) => Some(self.binding(&info, &what)?),
            None => None,
        };
        Ok(Material {
            name,
            base_color,
            base_color_texture,
            emissive,
            emissive_strength,
            emissive_texture,
            alpha_mode,
            double_sided: m.double_sided(),
        })
    }

    fn binding(&mut self, info: &gl::texture::Info, what: &str) -> Result<TextureBinding> {
        let texture = info.texture();
        let image = texture.source().index();
        let next = self.image_order.len();
        let slot = *self.images.entry(image).or_insert(next);
        if slot == next {
            self.image_order.push(image);
        }
        let uv_transform = match info.texture_transform() {
            None => UvTransform::default(),
            Some(t) => {
                let [ox, oy] = t.offset();
                let [sx, sy] = t.scale();
                let r = t.rotation();
                if ![ox, oy, sx, sy, r].iter().all(|v| v.is_finite()) {
                    return Err(self.err(format!(
                        "{what}: KHR_texture_transform of texture {}: expected finite offset, \
                         rotation and scale",
                        texture.index()
                    )));
                }
                UvTransform {
                    offset: Vec2::new(ox, oy),
                    rotation_rad: r,
                    scale: Vec2::new(sx, sy),
                }
            }
        };
        Ok(TextureBinding {
            texture: slot,
            sampler: sampler_of(&texture.sampler()),
            uv_transform,
        })
    }

    /// The encoded bytes of a glTF image and a label for messages.
    fn image_bytes(&self, index: usize) -> Result<(Cow<'_, [u8]>, String)> {
        let image = self
            .doc
            .images()
            .nth(index)
            .ok_or_else(|| self.err(format!("image {index} does not exist")))?;
        let named = image
            .name()
            .map(|n| format!(" ('{}')", shown(n)))
            .unwrap_or_default();
        match image.source() {
            gl::image::Source::View { view, .. } => {
                let what = format!("image {index}{named} (buffer view {})", view.index());
                let (data, _) = self.view_bytes(&view, &what)?;
                Ok((Cow::Borrowed(data), what))
            }
            gl::image::Source::Uri { uri, .. } => {
                let what = if uri.starts_with("data:") {
                    format!("image {index}{named} (data URI)")
                } else {
                    format!("image {index}{named} ('{}')", shown(uri))
                };
                let bytes = read_uri(
                    self.path,
                    self.folder,
                    uri,
                    &format!("images[{index}].uri"),
                    &what,
                    Limit::Cap(MAX_IMAGE_FILE_BYTES),
                )?;
                Ok((Cow::Owned(bytes), what))
            }
        }
    }

    /// Reads and decodes every image the materials use, in parallel. Base colour and emissive
    /// images are sRGB; both are all we read.
    fn decode_textures(&mut self) -> Result<()> {
        let this = &*self;
        let textures: Vec<Result<Texture>> = this
            .image_order
            .par_iter()
            .map(|&index| {
                let (bytes, what) = this.image_bytes(index)?;
                // Counted from the header before decoding: what the texture keeps, and what
                // its decoding holds until it is done (with the file's bytes, read for it).
                let (kept, passing, size) = image_file::decoded_bytes(&bytes)
                    .map_err(|m| this.err(format!("{what}: {m}")))?;
                this.reserve((kept + passing) as usize, || {
                    format!("{what}, decoded to {size} pixels")
                })?;
                let img = image_file::decode(&bytes, Encoding::Srgb)
                    .map_err(|m| this.err(format!("{what}: {m}")))?;
                let texture = Texture::new(img);
                let read = match bytes {
                    Cow::Owned(b) => b.len() as u64,
                    Cow::Borrowed(_) => 0,
                };
                this.folder.ledger().release(passing + read);
                Ok(texture)
            })
            .collect();
        for t in textures {
            let t = t?;
            self.scene.add_texture(t);
        }
        Ok(())
    }

    fn camera(
        &self,
        node: &gl::Node,
        camera: &gl::Camera,
        world: &Mat4,
    ) -> Result<Option<FileCamera>> {
        let gl::camera::Projection::Perspective(p) = camera.projection() else {
            return Ok(None);
        };
        let index = camera.index();
        let name = node
            .name()
            .or(camera.name())
            .map(str::to_string)
            .unwrap_or_else(|| format!("camera {index}"));
        let what = format!("camera {index} ('{name}')");
        let mut extras = self.dof_extras(node.extras(), &what)?;
        extras.merge(self.dof_extras(camera.extras(), &what)?);

        let (_, rotation, translation) = world.to_scale_rotation_translation();
        if !(rotation.is_finite() && translation.is_finite()) {
            return Err(self.err(format!("{what}: its node transform is not finite")));
        }
        let world_from_camera =
            Affine3A::from_rotation_translation(rotation.normalize(), translation);
        let camera_from_world = world_from_camera.inverse();

        let yfov = p.yfov();
        if !(yfov.is_finite() && yfov > 0.0 && yfov < std::f32::consts::PI) {
            return Err(self.err(format!(
                "{what}: yfov {yfov}: expected a value in (0, pi) radians"
            )));
        }
        let near_m = p.znear();
        let far_m = p.zfar().unwrap_or(DEFAULT_FAR_M.max(2.0 * near_m));
        if !(near_m.is_finite() && near_m > 0.0 && far_m.is_finite() && far_m > near_m) {
            return Err(self.err(format!(
                "{what}: znear {near_m}, zfar {far_m}: expected 0 < znear < zfar"
            )));
        }
        let (width_px, height_px) = match (extras.resolution_px, p.aspect_ratio()) {
            (Some(r), _) => r,
            (None, Some(a)) if a.is_finite() && a > 0.0 => (
                DEFAULT_WIDTH_PX,
                ((DEFAULT_WIDTH_PX as f32 / a).round() as usize).max(1),
            ),
            _ => (DEFAULT_WIDTH_PX, DEFAULT_HEIGHT_PX),
        };
        let f_px = crate::lens::focal_length_px_from_yfov(yfov, height_px);
        let sensor_width_mm = extras.sensor_width_mm.unwrap_or(DEFAULT_SENSOR_WIDTH_MM);
        let focal_length_mm =
            extras
                .focal_length_mm
                .unwrap_or(crate::lens::focal_length_mm_from_px(
                    f_px,
                    sensor_width_mm,
                    width_px,
                ));
        let fstop = match (extras.fstop, extras.aperture_radius_m) {
            (Some(n), _) => n,
            (None, Some(r)) => crate::lens::fstop_from_radius(focal_length_mm, r),
            (None, None) => DEFAULT_FSTOP,
        };
        let focus_m = match extras.focus_m {
            Some(f) => f,
            None => {
                let centre = self
                    .scene
                    .bounds()
                    .map(|(lo, hi)| 0.5 * (lo + hi))
                    .unwrap_or(Vec3::ZERO);
                let z = -camera_from_world.transform_point3(centre).z;
                if z.is_finite() && z > near_m {
                    z
                } else {
                    (centre - translation).length()
                }
            }
        }
        .clamp(near_m, far_m);
        Ok(Some(FileCamera {
            index,
            name,
            camera_name: camera.name().map(str::to_string),
            camera: Camera {
                width_px,
                height_px,
                camera_from_world,
                focal_length_mm,
                sensor_width_mm,
                fstop,
                focus_m,
                near_m,
                far_m,
                yfov_rad: Some(yfov),
            },
            dof_from_file: (extras.fstop.is_some() || extras.aperture_radius_m.is_some())
                && extras.focus_m.is_some(),
        }))
    }

    /// Depth-of-field parameters in a camera's (or its node's) `extras`.
    fn dof_extras(&self, extras: &gl::json::Extras, what: &str) -> Result<DofExtras> {
        let Some(raw) = extras else {
            return Ok(DofExtras::default());
        };
        let value: serde_json::Value = serde_json::from_str(raw.get())
            .map_err(|e| self.err(format!("{what}: extras: {e}")))?;
        let Some(map) = value.as_object() else {
            return Ok(DofExtras::default());
        };
        let number = |key: &str| -> Result<Option<f32>> {
            match map.get(key) {
                None | Some(serde_json::Value::Null) => Ok(None),
                Some(v) => match v.as_f64().map(|x| x as f32) {
                    Some(x) if x.is_finite() && x > 0.0 => Ok(Some(x)),
                    _ => Err(self.err(format!(
                        "{what}: extras.{key} is {v}: expected a positive number"
                    ))),
                },
            }
        };
        let resolution_px = match map.get("resolution_px") {
            None | Some(serde_json::Value::Null) => None,
            Some(v) => {
                let size = v.as_array().and_then(|a| match a.as_slice() {
                    [w, h] => Some((w.as_u64()? as usize, h.as_u64()? as usize)),
                    _ => None,
                });
                match size {
                    Some((w, h)) if crate::image::check_size(w, h).is_ok() => Some((w, h)),
                    _ => {
                        return Err(self.err(format!(
                            "{what}: extras.resolution_px is {v}: expected [width, height] in \
                             pixels, each at least 1"
                        )))
                    }
                }
            }
        };
        Ok(DofExtras {
            focus_m: number("dof_focus_distance_m")?,
            fstop: number("dof_fstop")?,
            aperture_radius_m: number("dof_aperture_radius_m")?,
            focal_length_mm: number("focal_length_mm")?,
            sensor_width_mm: number("sensor_width_mm")?,
            resolution_px,
        })
    }
}

/// Lens and image parameters that glTF cameras lack, read from `extras` when a tool wrote them.
#[derive(Clone, Copy, Debug, Default)]
struct DofExtras {
    focus_m: Option<f32>,
    fstop: Option<f32>,
    aperture_radius_m: Option<f32>,
    focal_length_mm: Option<f32>,
    sensor_width_mm: Option<f32>,
    resolution_px: Option<(usize, usize)>,
}

impl DofExtras {
    /// Takes every value `other` has.
    fn merge(&mut self, other: DofExtras) {
        self.focus_m = other.focus_m.or(self.focus_m);
        self.fstop = other.fstop.or(self.fstop);
        self.aperture_radius_m = other.aperture_radius_m.or(self.aperture_radius_m);
        self.focal_length_mm = other.focal_length_mm.or(self.focal_length_mm);
        self.sensor_width_mm = other.sensor_width_mm.or(self.sensor_width_mm);
        self.resolution_px = other.resolution_px.or(self.resolution_px);
    }
}
