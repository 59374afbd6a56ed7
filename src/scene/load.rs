//! Scene files: glTF 2.0 (`.gltf` with external or embedded files, `.glb`) and Wavefront OBJ
//! with its MTL materials, turned into a world-space [`Scene`] with the cameras the file has.
//!
//! Steps, for either format:
//! 1. Parse the file and check it: broken syntax, indices out of range, data past the end of a
//!    buffer, required extensions we do not support and non-triangle primitives are errors that
//!    name the file, the element and what was expected. Nothing panics on malformed input.
//! 2. Flatten the node hierarchy: every mesh instance becomes a [`Mesh`](super::Mesh) in world space.
//! 3. Decode the textures the materials use (in parallel): base colour and emissive images are
//!    sRGB-decoded to linear light, alpha stays linear and straight (not premultiplied).
//! 4. Cameras: each glTF perspective camera becomes a [`Camera`] (see [`FileCamera`]); the first
//!    one, or without any a [`frame_all`] view, goes into [`Scene::defaults`].
//!
//! Files the scene refers to are read only from its own folder, only if they are regular files,
//! and no more than the scene declares, unless [`LoadOptions`] allows external files (see
//! DESIGN.md, "Untrusted input").
//!
//! Rendering is unlit, so only base colour, emission and alpha are read; normals and PBR
//! parameters are ignored.

mod external;
mod gltf;
mod image_file;
mod obj;

pub use external::{MAX_IMAGE_FILE_BYTES, MAX_SCENE_FILE_BYTES};

use std::path::Path;

use glam::{Affine3A, Vec3};

use super::{Scene, SceneDefaults};
use crate::lens::{Aperture, Camera};
use crate::{Error, Result};

/// File extensions [`load_scene_file`] reads (lower case, without the dot).
pub const EXTENSIONS: &[&str] = &["gltf", "glb", "obj"];

/// Image width in pixels of cameras that do not state a resolution.
pub const DEFAULT_WIDTH_PX: usize = 1280;
/// Image height in pixels of cameras that state neither a resolution nor an aspect ratio.
pub const DEFAULT_HEIGHT_PX: usize = 720;
/// f-number of file cameras that do not state one (glTF has no depth-of-field parameters).
pub const DEFAULT_FSTOP: f32 = 2.8;
/// Sensor width in millimetres assumed for file cameras that do not state one (full frame).
pub const DEFAULT_SENSOR_WIDTH_MM: f32 = 36.0;
/// Far clipping distance in metres of glTF cameras without `zfar` (an infinite projection).
pub const DEFAULT_FAR_M: f32 = 1000.0;
/// How much room [`frame_all`] leaves around the scene: the bounding box fills 1 / this of the
/// narrower field of view.
pub const FRAME_MARGIN: f32 = 1.1;

/// A camera found in a scene file.
#[derive(Clone, Debug, PartialEq)]
pub struct FileCamera {
    /// Index of the camera in the file's camera list (glTF `cameras`).
    pub index: usize,
    /// Name of the node that carries the camera, else the camera's own name, else `camera N`.
    pub name: String,
    /// Name of the camera object, when it has one.
    pub camera_name: Option<String>,
    /// The camera: pose from its node, projection from `yfov` ([`Camera::yfov_rad`]), near and
    /// far planes from `znear` / `zfar`. Resolution, focal length, sensor width, f-number and
    /// focus distance come from the camera's `extras` when present (`resolution_px`,
    /// `focal_length_mm`, `sensor_width_mm`, `dof_fstop` or `dof_aperture_radius_m`,
    /// `dof_focus_distance_m`, as Blender-made calibration files write them), else: 1280 pixels
    /// wide with the height from `aspectRatio` (or 1280x720), a 36 mm sensor with the focal
    /// length that gives `yfov`, f/2.8, and focus on the view depth of the scene's bounding-box
    /// centre.
    pub camera: Camera,
    /// True when the f-number and focus distance came from the file, not from defaults.
    pub dof_from_file: bool,
}

/// A scene by name or path, as `--scene` takes it: a built-in scene
/// ([`crate::scene::builtin::NAMES`]) or a scene file (.gltf, .glb, .obj), with the file's camera
/// `camera` (its index or name) made the default. A built-in scene is returned with no cameras
/// in [`SceneFile::cameras`] (it has one, its default), and refuses `camera`.
pub fn scene_by_name_or_path(
    spec: &str,
    camera: Option<&str>,
    options: &LoadOptions,
) -> Result<SceneFile> {
    if crate::scene::builtin::NAMES.contains(&spec) {
        if camera.is_some() {
            return Err(Error::Option(format!(
                "invalid --camera: the built-in scene '{spec}' has one camera; --camera picks a camera of a scene file"
            )));
        }
        return Ok(SceneFile {
            scene: crate::scene::builtin::load(spec)?,
            cameras: Vec::new(),
            skipped_cameras: Vec::new(),
            files_read: Vec::new(),
        });
    }
    let path = Path::new(spec);
    if !path.exists() {
        return Err(Error::Option(format!(
            "unknown scene '{}': not a built-in scene ({}) and no such file",
            crate::error::shown(spec),
            crate::scene::builtin::NAMES.join(", ")
        )));
    }
    let mut file = read_scene_file_with(path, options)?;
    if let Some(c) = camera {
        file.use_camera(c)
            .map_err(|e| Error::Option(format!("invalid --camera: {e}")))?;
    }
    Ok(file)
}

/// A loaded scene file: the scene and every camera it has.
#[derive(Clone, Debug)]
pub struct SceneFile {
    /// The scene; its [`Scene::defaults`] hold the first camera, or a [`frame_all`] view when
    /// the file has none.
    pub scene: Scene,
    /// The file's perspective cameras, in the order of the file's camera list. Orthographic
    /// cameras are left out: the thin-lens model is perspective.
    pub cameras: Vec<FileCamera>,
    /// The cameras left out (orthographic), by index and name, so that a user can be told.
    pub skipped_cameras: Vec<String>,
    /// Every file read: the scene file as given, then the files it refers to (buffers,
    /// images, MTL libraries and maps) with links followed. Empty for a built-in scene. A
    /// command that writes files checks its outputs against these, so that no output replaces
    /// a file its scene reads.
    pub files_read: Vec<std::path::PathBuf>,
}

impl SceneFile {
    /// Finds a camera by `spec`: its index in the file's camera list (`0`, `1`, ...) or its name
    /// (node name or camera name).
    pub fn camera(&self, spec: &str) -> Result<&FileCamera> {
        let spec = spec.trim();
        let found = match spec.parse::<usize>() {
            Ok(i) => self.cameras.iter().find(|c| c.index == i),
            Err(_) => self.cameras.iter().find(|c| c.name == spec).or_else(|| {
                self.cameras
                    .iter()
                    .find(|c| c.camera_name.as_deref() == Some(spec))
            }),
        };
        found.ok_or_else(|| Error::Unknown {
            kind: "camera",
            name: spec.to_string(),
            expected: if self.cameras.is_empty() {
                format!(
                    "none: scene '{}' has no perspective camera",
                    crate::error::shown(&self.scene.name)
                )
            } else {
                self.cameras
                    .iter()
                    .map(|c| format!("{} '{}'", c.index, crate::error::shown(&c.name)))
                    .collect::<Vec<_>>()
                    .join(", ")
            },
        })
    }

    /// Makes the camera chosen by `spec` (see [`SceneFile::camera`]) the scene's default.
    pub fn use_camera(&mut self, spec: &str) -> Result<()> {
        let camera = self.camera(spec)?.camera.clone();
        self.scene.defaults = Some(SceneDefaults {
            camera,
            aperture: Aperture::Disc,
        });
        Ok(())
    }
}

/// How a scene file is read.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoadOptions {
    /// Let the scene read files outside its own folder: glTF buffer and image URIs, OBJ
    /// `mtllib` and MTL maps that are absolute, climb out with `../` or lead out through a link.
    /// Off by default: a scene file from elsewhere could otherwise read any file its user can
    /// (`/etc/shadow`, `~/.ssh/id_ed25519`) and show it in the image or in error messages.
    /// Either way only regular files are read (never a device or a FIFO), and no more of them
    /// than the scene declares.
    pub allow_external_files: bool,
}

/// Reads a scene file with its cameras (see [`read_scene_file_with`]), with the default
/// [`LoadOptions`]: no file outside the scene's folder is read.
pub fn read_scene_file(path: &Path) -> Result<SceneFile> {
    read_scene_file_with(path, &LoadOptions::default())
}

/// Reads a scene file with its cameras; the format follows the extension (`.gltf`, `.glb`,
/// `.obj`, any case). A `.gltf` may also hold binary glTF and the reverse. The files the scene
/// refers to are read as `options` allow.
pub fn read_scene_file_with(path: &Path, options: &LoadOptions) -> Result<SceneFile> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    match ext.as_str() {
        "gltf" | "glb" | "obj" => {}
        "" => {
            return Err(Error::format(
                path,
                format!(
                    "the file name has no extension: expected .{}",
                    EXTENSIONS.join(", .")
                ),
            ))
        }
        _ => {
            return Err(Error::format(
                path,
                format!(
                    "unknown scene file type '.{ext}': expected .{}",
                    EXTENSIONS.join(", .")
                ),
            ))
        }
    }
    let folder = external::SceneFolder::new(path, options)?;
    let mut file = if ext == "obj" {
        obj::load(path, &folder)?
    } else {
        gltf::load(path, &folder)?
    };
    file.files_read = std::iter::once(path.to_path_buf())
        .chain(folder.files_read())
        .collect();
    file.scene
        .validate()
        .map_err(|e| Error::format(path, e.to_string()))?;
    // Empty and degenerate scenes are refused alike in every format.
    if file.scene.triangle_count() == 0 {
        return Err(Error::format(
            path,
            "the scene has no triangles: expected at least one mesh face",
        ));
    }
    let has_area = file.scene.meshes.iter().any(|m| {
        m.indices.iter().any(|t| {
            let [a, b, c] = t.map(|i| m.positions[i as usize]);
            (b - a).cross(c - a).length_squared() > 0.0
        })
    });
    if !has_area {
        return Err(Error::format(
            path,
            "every triangle of the scene has zero area: nothing to render",
        ));
    }
    let camera = match file.cameras.first() {
        Some(c) => c.camera.clone(),
        None => frame_all(&file.scene, DEFAULT_WIDTH_PX, DEFAULT_HEIGHT_PX),
    };
    file.scene.defaults = Some(SceneDefaults {
        camera,
        aperture: Aperture::Disc,
    });
    Ok(file)
}

/// Loads a scene file (see [`read_scene_file`]) with its first camera, or a [`frame_all`]
/// view, in [`Scene::defaults`].
pub fn load_scene_file(path: &Path) -> Result<Scene> {
    Ok(read_scene_file(path)?.scene)
}

/// A "frame all" camera, as a model viewer's: at `width_px` x `height_px` with the default lens
/// of [`Camera::look_at`] (50 mm on a 36 mm sensor, f/2.8), on the +Z side of the scene's
/// bounding box looking down -Z at its centre, far enough that the whole box fits the view with
/// a margin ([`FRAME_MARGIN`]), focused on the box centre. An empty scene gives a camera at
/// z = 2 m looking at the origin.
pub fn frame_all(scene: &Scene, width_px: usize, height_px: usize) -> Camera {
    let (lo, hi) = scene
        .bounds()
        .filter(|(lo, hi)| lo.is_finite() && hi.is_finite())
        .unwrap_or((Vec3::splat(-0.5), Vec3::splat(0.5)));
    let centre = 0.5 * (lo + hi);
    let half = (0.5 * (hi - lo)).max(Vec3::splat(1e-3));
    let mut camera = Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y);
    camera.width_px = width_px.max(1);
    camera.height_px = height_px.max(1);
    let f_px = crate::lens::focal_length_px(
        camera.focal_length_mm,
        camera.sensor_width_mm,
        camera.width_px,
    );
    let tan_half_x = 0.5 * camera.width_px as f32 / f_px;
    let tan_half_y = 0.5 * camera.height_px as f32 / f_px;
    // The box's front face is the nearest part: if it fits, the rest (farther, smaller) does.
    let gap_m = (half.x / tan_half_x).max(half.y / tan_half_y) * FRAME_MARGIN;
    let eye = centre + Vec3::Z * (half.z + gap_m);
    camera.camera_from_world = Affine3A::look_at_rh(eye, centre, Vec3::Y);
    camera.focus_m = half.z + gap_m;
    camera.near_m = (0.1 * gap_m).min(0.05);
    camera.far_m = (4.0 * (gap_m + 2.0 * half.z)).max(DEFAULT_FAR_M);
    camera
}

/// Changes to a camera's pose and field of view (the CLI's `--look-from`, `--look-at`, `--up`
/// and `--fov`). Unset fields keep the camera's value.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ViewOverride {
    /// Eye position in metres, world space.
    pub look_from_m: Option<Vec3>,
    /// Point looked at in metres, world space. When only [`Self::look_from_m`] is given, the
    /// camera looks at the centre of the scene's bounding box.
    pub look_at_m: Option<Vec3>,
    /// World direction that appears up on screen (default +Y).
    pub up: Option<Vec3>,
    /// Vertical field of view in radians; sets [`Camera::yfov_rad`].
    pub yfov_rad: Option<f32>,
}

impl ViewOverride {
    /// True when nothing is overridden.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// Applies the override to `camera`. A new pose refocuses the camera on the point looked
    /// at (set the focus afterwards to choose another distance). `scene` gives the default
    /// point to look at.
    pub fn apply(&self, camera: &mut Camera, scene: &Scene) -> Result<()> {
        if let Some(yfov) = self.yfov_rad {
            if !(yfov.is_finite() && yfov > 0.0 && yfov < std::f32::consts::PI) {
                return Err(Error::invalid(
                    "field of view",
                    format!(
                        "{} degrees: expected more than 0 and less than 180",
                        yfov.to_degrees()
                    ),
                ));
            }
            camera.yfov_rad = Some(yfov);
        }
        if self.look_from_m.is_none() && self.look_at_m.is_none() && self.up.is_none() {
            return Ok(());
        }
        let world_from_camera = camera.camera_from_world.inverse();
        let eye = Vec3::from(world_from_camera.translation);
        let forward = world_from_camera
            .transform_vector3(-Vec3::Z)
            .normalize_or_zero();
        let from = self.look_from_m.unwrap_or(eye);
        let to = match (self.look_at_m, self.look_from_m) {
            (Some(to), _) => to,
            (None, Some(_)) => scene
                .bounds()
                .map(|(lo, hi)| 0.5 * (lo + hi))
                .unwrap_or(Vec3::ZERO),
            (None, None) => eye + forward * camera.focus_m.max(1e-3),
        };
        let up = self.up.unwrap_or(Vec3::Y);
        for (name, v) in [("look-from", from), ("look-at", to), ("up", up)] {
            if !v.is_finite() {
                return Err(Error::invalid(
                    name,
                    format!("{v}: expected finite coordinates"),
                ));
            }
        }
        let dir = to - from;
        if dir.length() < 1e-6 {
            return Err(Error::invalid(
                "look-at",
                format!("{to} is the eye position {from}: expected a point away from it"),
            ));
        }
        if up.length() < 1e-6 || dir.normalize().cross(up.normalize()).length() < 1e-4 {
            return Err(Error::invalid(
                "up",
                format!("{up} is zero or parallel to the view direction {dir}"),
            ));
        }
        camera.camera_from_world = Affine3A::look_at_rh(from, to, up);
        camera.focus_m = dir.length();
        Ok(())
    }
}
