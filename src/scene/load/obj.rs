//! Wavefront OBJ + MTL (read with `tobj`) to a [`Scene`].
//!
//! Materials, as unlit glTF-style ones:
//! - `Kd` base colour (default 0.8 grey, or white under a `map_Kd`), `map_Kd` its sRGB texture;
//! - `d` opacity, or `Tr` (transparency, 1 - d) when `d` is absent; `map_d` an opacity texture
//!   (its alpha channel if it has transparency, else its grey level, linear);
//! - alpha mode: blend when the opacity factor is below 1, else alpha test at 0.5 when there is a
//!   `map_d`, else opaque;
//! - `Ke` emission, `map_Ke` its sRGB texture.
//!
//! OBJ texture coordinates have v = 0 at the bottom of the image; they are flipped to glTF's
//! top-left convention. Faces are triangulated and all materials are double-sided (OBJ says
//! nothing about culling). Texture options before a map's file name (`-s`, `-o`, `-bm`, ...) are
//! skipped.

use std::cell::RefCell;
use std::collections::HashMap;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use super::external::{self, Limit, SceneFolder, MAX_IMAGE_FILE_BYTES, MAX_SCENE_FILE_BYTES};
use super::image_file::{self, Encoding};
use super::SceneFile;
use crate::error::shown;
use crate::image::ColorImage;
use crate::scene::{
    AlphaMode, Material, Mesh, Scene, Texture, TextureBinding, TextureSampler, UvTransform,
};
use crate::{Error, Result};

/// A texture to build: colour from one image, alpha (optionally) from another, each a file of
/// the scene's folder with links followed.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
struct TextureJob {
    color: Option<PathBuf>,
    alpha: Option<PathBuf>,
}

/// Where the MTL first names each texture file, for messages: (field, file name as written).
type MapNames = HashMap<PathBuf, (String, PathBuf)>;

/// Checks the statements the OBJ reader would drop or reject without a line number: vertices
/// (`v`, `vt`, `vn`) need numbers, faces (`f`) at least three vertex references.
fn check_lines(path: &Path, bytes: &[u8]) -> Result<()> {
    let text = String::from_utf8_lossy(bytes);
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let rest: Vec<&str> = words.collect();
        let at = |message: String| Error::format(path, format!("line {}: {message}", n + 1));
        let line = shown(line);
        let numbers = |ws: &[&str]| ws.iter().all(|w| w.parse::<f32>().is_ok());
        match keyword {
            "v" | "vn" if rest.len() < 3 || !numbers(&rest[..3]) => {
                return Err(at(format!("'{line}': '{keyword}' needs three numbers")));
            }
            "vt" if rest.is_empty() || !numbers(&rest) => {
                return Err(at(format!("'{line}': 'vt' needs one to three numbers")));
            }
            "f" if rest.len() < 3 => {
                return Err(at(format!(
                    "'{line}': a face needs at least 3 vertices, this one has {}",
                    rest.len()
                )));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Checks the MTL statements whose values the reader would reject without a line number:
/// colours (`Ka`, `Kd`, `Ks`, `Ke`) need three numbers, scalars (`d`, `Tr`, `Ns`, `Ni`) one.
fn check_mtl_lines(bytes: &[u8]) -> std::result::Result<(), String> {
    let text = String::from_utf8_lossy(bytes);
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let rest: Vec<&str> = words.collect();
        let numbers = |ws: &[&str]| ws.iter().all(|w| w.parse::<f32>().is_ok());
        let bad = match keyword {
            "Ka" | "Kd" | "Ks" | "Ke" => rest.len() < 3 || !numbers(&rest[..3]),
            "d" | "Tr" | "Ns" | "Ni" => rest.is_empty() || !numbers(&rest[..1]),
            _ => false,
        };
        if bad {
            let want = if keyword.starts_with('K') {
                "three numbers"
            } else {
                "a number"
            };
            return Err(format!(
                "line {}: '{}': '{keyword}' needs {want}",
                n + 1,
                shown(line)
            ));
        }
    }
    Ok(())
}

/// Bytes the OBJ reader (`tobj`, one index per vertex) makes of a byte of OBJ text while it
/// parses, at most: a face corner (`12/34 `, 6 bytes or more once a file has more than a few
/// hundred distinct corners) can make a vertex of its own (position, texture coordinates and
/// normal, 32 bytes) with its index and its entry in the reader's table of corners seen (about
/// 40). Measured: 5.5 times the text for 200,000 faces whose every corner is a new vertex.
const OBJ_PARSE_BYTES_PER_BYTE: u64 = 12;

/// Loads an OBJ file and the MTL libraries it names; those and the texture maps are read from
/// `folder`.
pub(super) fn load(path: &Path, folder: &SceneFolder) -> Result<SceneFile> {
    let bytes = external::read_scene(path, folder)?;
    check_lines(path, &bytes)?;
    // What the reader makes of the text, counted before it parses it (then what it made).
    let parsing = bytes.len() as u64 * OBJ_PARSE_BYTES_PER_BYTE;
    folder.ledger().reserve(
        parsing,
        || format!("{}: parsing its {} bytes", shown(&path), bytes.len()),
        "the scene's size",
    )?;
    let file = std::io::Cursor::new(bytes);
    let mtl_error: RefCell<Option<Error>> = RefCell::new(None);
    let options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, materials) =
        tobj::load_obj_buf(&mut BufReader::new(file), &options, |mtl: &Path| {
            let result = folder
                .read("mtllib", mtl, Limit::Cap(MAX_SCENE_FILE_BYTES))
                .and_then(|bytes| {
                    let library = |message: String| {
                        Error::format(path, format!("material library {}: {message}", shown(mtl)))
                    };
                    check_mtl_lines(&bytes).map_err(library)?;
                    tobj::load_mtl_buf(&mut BufReader::new(std::io::Cursor::new(bytes)))
                        .map_err(|e| library(e.to_string()))
                });
            result.map_err(|e| {
                mtl_error.borrow_mut().get_or_insert(e);
                tobj::LoadError::OpenFileFailed
            })
        })
        .map_err(|e| Error::format(path, format!("not a readable OBJ file: {e}")))?;
    if let Some(e) = mtl_error.into_inner() {
        return Err(e);
    }
    let materials = materials.map_err(|e| Error::format(path, format!("material library: {e}")))?;
    let parsed: usize = models
        .iter()
        .map(|m| {
            let m = &m.mesh;
            4 * (m.positions.capacity()
                + m.texcoords.capacity()
                + m.normals.capacity()
                + m.indices.capacity())
        })
        .sum();
    folder.ledger().release(parsing);
    folder.ledger().reserve(
        parsed as u64,
        || format!("{}: its parsed meshes", shown(&path)),
        "the scene's size",
    )?;

    let mut scene = Scene {
        name: path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        ..Scene::default()
    };
    let mut jobs: Vec<TextureJob> = Vec::new();
    let mut map_names = MapNames::new();
    let mut job_index: HashMap<TextureJob, usize> = HashMap::new();
    let mut bind = |job: TextureJob| {
        let next = jobs.len();
        let i = *job_index.entry(job.clone()).or_insert(next);
        if i == next {
            jobs.push(job);
        }
        TextureBinding {
            texture: i,
            sampler: TextureSampler::default(),
            uv_transform: UvTransform::default(),
        }
    };
    for m in &materials {
        let what = format!("material '{}'", shown(&m.name));
        // Each map resolved in the scene's folder now, so that a refused one fails before any
        // image is read.
        let mut map = |key: &str, spec: Option<&str>| -> Result<Option<PathBuf>> {
            let Some(spec) = spec else {
                return Ok(None);
            };
            let field = format!("{what}: {key}");
            let written = Path::new(map_file(spec));
            let file = folder.resolve_checked(&field, written)?;
            map_names
                .entry(file.clone())
                .or_insert_with(|| (field, written.to_path_buf()));
            Ok(Some(file))
        };
        let map_kd = map("map_Kd", m.diffuse_texture.as_deref())?;
        let map_d = map("map_d", m.dissolve_texture.as_deref())?;
        let map_ke = map("map_Ke", m.unknown_param.get("map_Ke").map(String::as_str))?;
        let kd = m
            .diffuse
            .unwrap_or(if map_kd.is_some() { [1.0; 3] } else { [0.8; 3] });
        let opacity = match (m.dissolve, m.unknown_param.get("Tr")) {
            (Some(d), _) => d,
            (None, Some(tr)) => {
                let tr: f32 = tr.trim().parse().map_err(|_| {
                    Error::format(
                        path,
                        format!("{what}: Tr '{}': expected a number", shown(tr)),
                    )
                })?;
                1.0 - tr
            }
            (None, None) => 1.0,
        };
        let ke = m
            .emissive
            .unwrap_or(if map_ke.is_some() { [1.0; 3] } else { [0.0; 3] });
        for (field, values) in [("Kd", &kd[..]), ("Ke", &ke[..]), ("d", &[opacity][..])] {
            if !values.iter().all(|v| v.is_finite() && *v >= 0.0) {
                return Err(Error::format(
                    path,
                    format!("{what}: {field} {values:?}: expected finite values of at least 0"),
                ));
            }
        }
        let alpha_mode = if opacity < 1.0 {
            AlphaMode::Blend
        } else if map_d.is_some() {
            AlphaMode::Mask { cutoff: 0.5 }
        } else {
            AlphaMode::Opaque
        };
        let base_color_texture = (map_kd.is_some() || map_d.is_some()).then(|| {
            bind(TextureJob {
                color: map_kd,
                alpha: map_d,
            })
        });
        let emissive_texture = map_ke.map(|p| {
            bind(TextureJob {
                color: Some(p),
                alpha: None,
            })
        });
        scene.add_material(Material {
            name: m.name.clone(),
            base_color: [kd[0], kd[1], kd[2], opacity.min(1.0)],
            base_color_texture,
            emissive: ke,
            emissive_strength: 1.0,
            emissive_texture,
            alpha_mode,
            double_sided: true,
        });
    }
    let mut default_material = None;
    for model in &models {
        let mesh = &model.mesh;
        let material = match mesh.material_id.filter(|&i| i < scene.materials.len()) {
            Some(i) => i,
            None => *default_material
                .get_or_insert_with(|| scene.add_material(Material::color("default", [0.8; 3]))),
        };
        let what = format!("object '{}'", shown(&model.name));
        let positions: Vec<Vec3> = mesh
            .positions
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect();
        let n = positions.len();
        let uvs: Vec<Vec2> = if mesh.texcoords.len() == 2 * n {
            mesh.texcoords
                .chunks_exact(2)
                .map(|t| Vec2::new(t[0], 1.0 - t[1]))
                .collect()
        } else {
            Vec::new()
        };
        let normals: Vec<Vec3> = if mesh.normals.len() == 3 * n {
            mesh.normals
                .chunks_exact(3)
                .map(|v| Vec3::from_slice(v).normalize_or_zero())
                .collect()
        } else {
            Vec::new()
        };
        if mesh.indices.len() % 3 != 0 {
            return Err(Error::format(
                path,
                format!(
                    "{what}: {} indices after triangulation: expected a multiple of 3",
                    mesh.indices.len()
                ),
            ));
        }
        if let Some(&i) = mesh.indices.iter().find(|&&i| i as usize >= n) {
            return Err(Error::format(
                path,
                format!("{what}: vertex index {i} is out of range: it has {n} vertices"),
            ));
        }
        folder.ledger().reserve(
            Mesh::bytes_for(
                n,
                !normals.is_empty(),
                !uvs.is_empty(),
                mesh.indices.len() / 3,
            ),
            || format!("{}: {what} ({n} vertices)", shown(&path)),
            "the scene's size",
        )?;
        scene.meshes.push(Mesh {
            positions,
            normals,
            uvs,
            indices: mesh
                .indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect(),
            material,
        });
    }
    let textures: Vec<Result<Texture>> = jobs
        .par_iter()
        .map(|job| build_texture(folder, &map_names, job).map(Texture::new))
        .collect();
    for t in textures {
        scene.add_texture(t?);
    }
    Ok(SceneFile {
        scene,
        cameras: Vec::new(),
        skipped_cameras: Vec::new(),
        files_read: Vec::new(),
    })
}

/// The file name of a `map_*` statement, after any options (`-s 1 1 1`, `-bm 0.5`, ...).
fn map_file(spec: &str) -> &str {
    let mut rest = spec.trim();
    while let Some(option) = rest.strip_prefix('-') {
        let (name, after) = option
            .split_once(char::is_whitespace)
            .unwrap_or((option, ""));
        // Options with up to three numbers (-o, -s, -t) take as many as follow; the others
        // take a fixed count.
        let (min_args, max_args) = match name {
            "o" | "s" | "t" => (1, 3),
            "mm" => (2, 2),
            _ => (1, 1),
        };
        rest = after.trim_start();
        for k in 0..max_args {
            let (word, after) = rest.split_once(char::is_whitespace).unwrap_or((rest, ""));
            if k >= min_args && word.parse::<f32>().is_err() {
                break;
            }
            rest = after.trim_start();
        }
    }
    rest
}

/// Reads and decodes the texture file `file` (resolved in `folder`); errors name the MTL field
/// and the file name as written.
fn read_image(
    folder: &SceneFolder,
    names: &MapNames,
    file: &Path,
    encoding: Encoding,
) -> Result<ColorImage> {
    let (field, written) = names
        .get(file)
        .map(|(f, w)| (f.as_str(), w.as_path()))
        .unwrap_or(("texture", file));
    let bytes = folder.read_resolved(field, written, file, Limit::Cap(MAX_IMAGE_FILE_BYTES))?;
    let error = |m: String| folder.error(format!("{field} '{}': {m}", shown(written)));
    // Counted from the header before decoding: what the texture keeps, and what its decoding
    // holds until it is done (with the file's bytes, read for it).
    let (kept, passing, size) = image_file::decoded_bytes(&bytes).map_err(error)?;
    folder.ledger().reserve(
        kept + passing,
        || {
            format!(
                "{}: {field} '{}', decoded to {size} pixels",
                shown(&folder.scene()),
                shown(written)
            )
        },
        "the scene's size",
    )?;
    let image = image_file::decode(&bytes, encoding).map_err(error)?;
    folder.ledger().release(passing + bytes.len() as u64);
    Ok(image)
}

/// Builds a straight-alpha linear texture image: colour from `job.color` (sRGB, white if none),
/// alpha from `job.alpha` (nearest texel when the sizes differ).
fn build_texture(folder: &SceneFolder, names: &MapNames, job: &TextureJob) -> Result<ColorImage> {
    let color = job
        .color
        .as_deref()
        .map(|p| read_image(folder, names, p, Encoding::Srgb))
        .transpose()?;
    let alpha = job
        .alpha
        .as_deref()
        .map(|p| read_image(folder, names, p, Encoding::Linear))
        .transpose()?;
    match (color, alpha) {
        (Some(c), None) => Ok(c),
        (color, Some(a)) => {
            // The alpha map is dropped once its alpha is in the colour (without a colour map,
            // a white image of its size takes its place).
            if color.is_some() {
                folder
                    .ledger()
                    .release(Texture::bytes_for(a.width(), a.height()));
            }
            let use_alpha = a.pixels().iter().any(|p| p[3] < 1.0);
            let opacity = |p: [f32; 4]| if use_alpha { p[3] } else { p[0] };
            let mut out = color.unwrap_or_else(|| ColorImage::new(a.width(), a.height(), [1.0; 4]));
            let (w, h) = (out.width(), out.height());
            for y in 0..h {
                let ay = y * a.height() / h;
                for x in 0..w {
                    let ax = x * a.width() / w;
                    out.get_mut(x, y)[3] = opacity(a.get(ax, ay));
                }
            }
            Ok(out)
        }
        (None, None) => Ok(ColorImage::new(1, 1, [1.0; 4])),
    }
}

#[cfg(test)]
mod tests {
    use super::map_file;

    #[test]
    fn map_options_are_skipped_and_names_with_spaces_kept() {
        assert_eq!(map_file("tex.png"), "tex.png");
        assert_eq!(map_file("-s 2 2 1 -o 0.5 tex.png"), "tex.png");
        assert_eq!(map_file("-s 2 tex.png"), "tex.png");
        assert_eq!(map_file("-bm 0.3 my bump.png"), "my bump.png");
        assert_eq!(map_file("-clamp on -mm 0 1 leaf.png"), "leaf.png");
    }
}
