//! Tests: scene files (glTF 2.0, GLB, OBJ + MTL): geometry lands where the camera math says,
//! materials and alpha modes behave, malformed files give errors naming the file, the shared
//! assets load and render, and the Cycles calibration scene matches Blender's renders.

use std::path::{Path, PathBuf};
use std::time::Instant;

use defocus::autofocus::{focus_at_centre, focus_at_pixel};
use defocus::image::{io, srgb_decode, ColorImage};
use defocus::lens::{Aperture, Camera};
use defocus::methods::reference::{self, ReferenceSettings};
use defocus::methods::{pinhole, MethodOutput};
use defocus::metrics;
use defocus::scene::load::{load_scene_file, read_scene_file, ViewOverride};
use defocus::scene::{AlphaMode, FilterMode, Material, Scene, WrapMode};
use glam::{Affine3A, Mat4, Quat, Vec2, Vec3};
use serde_json::{json, Value};

use crate::cli::TempFolder;
use crate::{add_screen_rect, shared_assets, test_camera};

/// A fresh, empty temporary folder for one test, removed when it passes.
fn temp_dir(name: &str) -> TempFolder {
    TempFolder::new(&format!("defocus-scenes-{}-{name}", std::process::id()))
}

/// An 8-bit RGBA PNG of `w`x`h` pixels, row 0 at the top.
fn png(w: u32, h: u32, rgba: &[[u8; 4]]) -> Vec<u8> {
    let raw: Vec<u8> = rgba.iter().flatten().copied().collect();
    let img = image::RgbaImage::from_raw(w, h, raw).unwrap();
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// Base64 (standard alphabet, padded), for data URIs.
fn base64(data: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in data.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            s.push(if k <= c.len() {
                A[(n >> (18 - 6 * k) & 63) as usize] as char
            } else {
                '='
            });
        }
    }
    s
}

/// A glTF document under construction: JSON plus one binary buffer.
pub(crate) struct Gltf {
    json: Value,
    bin: Vec<u8>,
}

impl Gltf {
    fn new() -> Self {
        Self {
            json: json!({
                "asset": {"version": "2.0"},
                "scene": 0,
                "scenes": [{"nodes": []}],
                "nodes": [], "meshes": [], "accessors": [], "bufferViews": [], "materials": [],
            }),
            bin: Vec::new(),
        }
    }

    fn push(&mut self, key: &str, v: Value) -> usize {
        if self.json.get(key).is_none() {
            self.json[key] = json!([]);
        }
        let a = self.json[key].as_array_mut().unwrap();
        a.push(v);
        a.len() - 1
    }

    fn view(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        self.push(
            "bufferViews",
            json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()}),
        )
    }

    fn positions(&mut self, p: &[Vec3]) -> usize {
        let bytes: Vec<u8> = p
            .iter()
            .flat_map(|v| v.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        let view = self.view(&bytes);
        let lo = p.iter().fold(Vec3::INFINITY, |a, &b| a.min(b));
        let hi = p.iter().fold(Vec3::NEG_INFINITY, |a, &b| a.max(b));
        self.push(
            "accessors",
            json!({"bufferView": view, "componentType": 5126, "count": p.len(), "type": "VEC3",
                   "min": lo.to_array(), "max": hi.to_array()}),
        )
    }

    fn uvs(&mut self, uv: &[Vec2]) -> usize {
        let bytes: Vec<u8> = uv
            .iter()
            .flat_map(|v| v.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        let view = self.view(&bytes);
        self.push(
            "accessors",
            json!({"bufferView": view, "componentType": 5126, "count": uv.len(), "type": "VEC2"}),
        )
    }

    fn indices(&mut self, idx: &[u32]) -> usize {
        let bytes: Vec<u8> = idx.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes);
        self.push(
            "accessors",
            json!({"bufferView": view, "componentType": 5125, "count": idx.len(), "type": "SCALAR"}),
        )
    }

    /// A quad mesh (two triangles) with corners `c` and uv (0,0), (1,0), (1,1), (0,1).
    fn quad(&mut self, c: [Vec3; 4], material: Option<usize>) -> usize {
        let pos = self.positions(&c);
        let uv = self.uvs(&[
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 1.0),
        ]);
        let idx = self.indices(&[0, 1, 2, 0, 2, 3]);
        let mut prim = json!({"attributes": {"POSITION": pos, "TEXCOORD_0": uv}, "indices": idx});
        if let Some(m) = material {
            prim["material"] = json!(m);
        }
        self.push("meshes", json!({"primitives": [prim]}))
    }

    /// Adds a node to the scene's roots.
    fn root(&mut self, node: Value) -> usize {
        let n = self.push("nodes", node);
        self.json["scenes"][0]["nodes"]
            .as_array_mut()
            .unwrap()
            .push(json!(n));
        n
    }

    /// An image stored in the buffer, with a texture using `sampler`.
    fn texture(&mut self, png_bytes: &[u8], sampler: Value) -> usize {
        let view = self.view(png_bytes);
        let image = self.push(
            "images",
            json!({"bufferView": view, "mimeType": "image/png"}),
        );
        let s = self.push("samplers", sampler);
        self.push("textures", json!({"source": image, "sampler": s}))
    }

    /// Writes `name.gltf` and `name.bin` into `dir`.
    fn write(&self, dir: &Path, name: &str) -> PathBuf {
        let mut json = self.json.clone();
        json["buffers"] = json!([{"byteLength": self.bin.len(), "uri": format!("{name}.bin")}]);
        std::fs::write(dir.join(format!("{name}.bin")), &self.bin).unwrap();
        let path = dir.join(format!("{name}.gltf"));
        std::fs::write(&path, serde_json::to_vec_pretty(&json).unwrap()).unwrap();
        path
    }

    /// Writes `name.gltf` with the buffer embedded as a base64 data URI.
    pub(crate) fn write_embedded(&self, dir: &Path, name: &str) -> PathBuf {
        let mut json = self.json.clone();
        json["buffers"] = json!([{
            "byteLength": self.bin.len(),
            "uri": format!("data:application/octet-stream;base64,{}", base64(&self.bin)),
        }]);
        let path = dir.join(format!("{name}.gltf"));
        std::fs::write(&path, serde_json::to_vec(&json).unwrap()).unwrap();
        path
    }

    /// Writes binary glTF `name.glb`.
    pub(crate) fn write_glb(&self, dir: &Path, name: &str) -> PathBuf {
        let mut json = self.json.clone();
        json["buffers"] = json!([{"byteLength": self.bin.len()}]);
        let mut j = serde_json::to_vec(&json).unwrap();
        while !j.len().is_multiple_of(4) {
            j.push(b' ');
        }
        let mut b = self.bin.clone();
        while !b.len().is_multiple_of(4) {
            b.push(0);
        }
        let total = 12 + 8 + j.len() + 8 + b.len();
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&(total as u32).to_le_bytes());
        out.extend_from_slice(&(j.len() as u32).to_le_bytes());
        out.extend_from_slice(b"JSON");
        out.extend_from_slice(&j);
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&b);
        let path = dir.join(format!("{name}.glb"));
        std::fs::write(&path, out).unwrap();
        path
    }
}

/// World positions of the raster box `[x0, x1) x [y0, y1)` at view depth `z` of a camera at the
/// origin looking down -Z (the corners of a quad covering exactly those pixels).
fn screen_quad(camera: &Camera, (x0, y0, x1, y1): (f32, f32, f32, f32), z: f32) -> [Vec3; 4] {
    let lens = camera.thin_lens().unwrap();
    let (cx, cy) = lens.centre_px();
    let w = |x: f32, y: f32| Vec3::new((x - cx) * z / lens.f_px, -(y - cy) * z / lens.f_px, -z);
    [w(x0, y0), w(x1, y0), w(x1, y1), w(x0, y1)]
}

fn pinhole_frame(scene: &Scene, camera: &Camera, samples: usize) -> MethodOutput {
    pinhole::render(scene, camera, samples, 0, true).unwrap()
}

fn error_of<T: std::fmt::Debug>(r: defocus::Result<T>) -> String {
    r.expect_err("a malformed file must be an error")
        .to_string()
}

// ---------------------------------------------------------------------------------------------
// Geometry and cameras
// ---------------------------------------------------------------------------------------------

#[test]
fn gltf_vertex_lands_on_the_pixel_the_camera_math_predicts_with_its_view_depth() {
    // Camera: a rig node (translated, turned 20 degrees about Y) with a child camera node
    // (raised, tilted 5 degrees down). Mesh node: translated, rotated and scaled.
    let rig = Mat4::from_rotation_translation(
        Quat::from_rotation_y(20f32.to_radians()),
        Vec3::new(1.0, 0.5, 3.0),
    );
    let cam_local = Mat4::from_rotation_translation(
        Quat::from_rotation_x(-5f32.to_radians()),
        Vec3::new(0.0, 0.1, 0.0),
    );
    let world_from_camera = rig * cam_local;
    let camera_from_world = Affine3A::from_mat4(world_from_camera.inverse());
    let mesh_world = Mat4::from_scale_rotation_translation(
        Vec3::splat(2.0),
        Quat::from_rotation_z(30f32.to_radians()),
        Vec3::new(0.2, -0.1, -0.5),
    );
    // A world point 4 m in front of the camera, off-centre, and a camera-facing quad whose
    // top-left corner it is, reaching right and down on screen.
    let p = world_from_camera.transform_point3(Vec3::new(0.37, -0.21, -4.0));
    let right = world_from_camera.transform_vector3(Vec3::X);
    let up = world_from_camera.transform_vector3(Vec3::Y);
    // Counter-clockwise as seen from the camera: glTF's default material is single-sided.
    let world = [p, p - up, p + right - up, p + right];
    let local = world.map(|v| mesh_world.inverse().transform_point3(v));

    let mut g = Gltf::new();
    let mesh = g.quad(local, None);
    let (s, r, t) = mesh_world.to_scale_rotation_translation();
    g.root(json!({"mesh": mesh, "scale": s.to_array(), "rotation": r.to_array(), "translation": t.to_array()}));
    let yfov = 0.7f32;
    g.push(
        "cameras",
        json!({"type": "perspective", "name": "lens",
               "perspective": {"yfov": yfov, "aspectRatio": 1.5, "znear": 0.1, "zfar": 100.0},
               "extras": {"resolution_px": [192, 128]}}),
    );
    let child = g.push(
        "nodes",
        json!({"name": "eye", "camera": 0, "rotation": Quat::from_rotation_x(-5f32.to_radians()).to_array(),
               "translation": [0.0, 0.1, 0.0]}),
    );
    g.root(json!({"name": "rig", "children": [child],
                  "rotation": Quat::from_rotation_y(20f32.to_radians()).to_array(),
                  "translation": [1.0, 0.5, 3.0]}));
    let dir = temp_dir("vertex");
    let path = g.write(&dir, "vertex");

    let file = read_scene_file(&path).unwrap();
    assert_eq!(file.cameras.len(), 1);
    assert_eq!(file.cameras[0].name, "eye");
    let camera = file.scene.defaults.as_ref().unwrap().camera.clone();
    assert_eq!((camera.width_px, camera.height_px), (192, 128));
    assert_eq!((camera.near_m, camera.far_m), (0.1, 100.0));
    let lens = camera.thin_lens().unwrap();
    let expected_f_px = 128.0 / (2.0 * (0.5 * yfov).tan());
    assert!(
        (lens.f_px - expected_f_px).abs() < 1e-3,
        "f_px {} vs {expected_f_px}",
        lens.f_px
    );

    let (px, py, z) = lens.project(camera_from_world.transform_point3(p)).unwrap();
    let (lx, ly, lz) = lens
        .project(camera.camera_from_world.transform_point3(p))
        .unwrap();
    assert!((px - lx).abs() < 1e-3 && (py - ly).abs() < 1e-3 && (z - lz).abs() < 1e-5,
        "the loaded camera projects the vertex to ({lx}, {ly}) at {lz} m, expected ({px}, {py}) at {z} m");
    assert!((z - 4.0).abs() < 1e-4, "view depth {z}");

    // Coverage of the pixel holding the corner is the part of it right of and below the
    // corner: a sub-pixel check of where the vertex landed.
    let (ix, iy) = (px.floor() as usize, py.floor() as usize);
    let aa = pinhole_frame(&file.scene, &camera, 256);
    let coverage = aa.image.get(ix, iy)[3];
    let expected = (1.0 - px.fract()) * (1.0 - py.fract());
    assert!(
        (coverage - expected).abs() < 0.03,
        "corner pixel ({ix}, {iy}) coverage {coverage}, expected {expected} for ({px}, {py})"
    );
    assert!(aa.image.get(ix - 1, iy)[3] < 1e-6 && aa.image.get(ix, iy - 1)[3] < 1e-6);
    assert!(aa.image.get(ix + 1, iy + 1)[3] > 0.999);

    let depth = pinhole_frame(&file.scene, &camera, 1).depth.unwrap();
    let d = depth.get(ix + 1, iy + 1);
    assert!(
        (d - z).abs() < 1e-4 * z,
        "depth {d} at ({}, {}), expected the view-axis distance {z}",
        ix + 1,
        iy + 1
    );
}

#[test]
fn mirrored_nodes_keep_single_sided_front_faces_visible() {
    let camera = test_camera(32, 32, 2.0, 2.8);
    let mut g = Gltf::new();
    let m = g.push("materials", json!({"doubleSided": false}));
    // Counter-clockwise as seen from the camera, so it faces it.
    let mut c = screen_quad(&camera, (4.0, 4.0, 28.0, 28.0), 2.0);
    c.swap(1, 3);
    let mesh = g.quad(c, Some(m));
    g.root(json!({"mesh": mesh}));
    // The same quad mirrored in x (scale -1): still facing the camera after the flip.
    g.root(json!({"mesh": mesh, "scale": [-1.0, 1.0, 1.0], "translation": [0.0, 0.0, -1.0]}));
    let dir = temp_dir("mirror");
    let scene = load_scene_file(&g.write(&dir, "mirror")).unwrap();
    let out = pinhole_frame(&scene, &camera, 1);
    assert_eq!(out.depth.as_ref().unwrap().get(16, 16), 2.0);
    // Remove the front quad: the mirrored one must still be drawn.
    let mut back = scene.clone();
    back.meshes.remove(0);
    let d = pinhole_frame(&back, &camera, 1).depth.unwrap().get(16, 16);
    assert!(
        (d - 3.0).abs() < 1e-5,
        "mirrored single-sided quad culled: depth {d}"
    );
}

#[test]
fn a_file_without_camera_gets_a_frame_all_view_that_shows_the_whole_box() {
    let mut g = Gltf::new();
    let mesh = g.quad(
        [
            Vec3::new(-3.0, -1.0, 0.0),
            Vec3::new(5.0, -1.0, 0.0),
            Vec3::new(5.0, 2.0, -4.0),
            Vec3::new(-3.0, 2.0, -4.0),
        ],
        None,
    );
    g.root(json!({"mesh": mesh}));
    let dir = temp_dir("frame");
    let file = read_scene_file(&g.write_glb(&dir, "frame")).unwrap();
    assert!(file.cameras.is_empty());
    let camera = file.scene.defaults.clone().unwrap().camera;
    let lens = camera.thin_lens().unwrap();
    let (lo, hi) = file.scene.bounds().unwrap();
    for i in 0..8 {
        let corner = Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let (x, y, z) = lens
            .project(camera.camera_from_world.transform_point3(corner))
            .unwrap();
        assert!(
            x > 0.0 && x < lens.width_px as f32 && y > 0.0 && y < lens.height_px as f32,
            "bounding-box corner {corner} projects to ({x}, {y}), outside the {}x{} frame",
            lens.width_px,
            lens.height_px
        );
        assert!(z > lens.near_m && z < lens.far_m);
    }
    let centre_z = -camera.camera_from_world.transform_point3(0.5 * (lo + hi)).z;
    assert!(
        (camera.focus_m - centre_z).abs() < 1e-4,
        "focus {} vs box centre at {centre_z}",
        camera.focus_m
    );
}

#[test]
fn cameras_are_chosen_by_index_or_name_and_orthographic_ones_are_skipped() {
    let mut g = Gltf::new();
    let mesh = g.quad(
        [
            Vec3::new(-1.0, -1.0, -5.0),
            Vec3::new(1.0, -1.0, -5.0),
            Vec3::new(1.0, 1.0, -5.0),
            Vec3::new(-1.0, 1.0, -5.0),
        ],
        None,
    );
    g.root(json!({"mesh": mesh}));
    g.push(
        "cameras",
        json!({"type": "perspective", "name": "wide", "perspective": {"yfov": 1.0, "znear": 0.1}}),
    );
    g.push("cameras", json!({"type": "orthographic", "orthographic": {"xmag": 1.0, "ymag": 1.0, "znear": 0.1, "zfar": 10.0}}));
    g.push("cameras", json!({"type": "perspective", "perspective": {"yfov": 0.3, "aspectRatio": 2.0, "znear": 0.2, "zfar": 50.0},
                             "extras": {"dof_fstop": 4.0, "dof_focus_distance_m": 3.0}}));
    g.root(json!({"camera": 0, "name": "overview", "translation": [0.0, 0.0, 2.0]}));
    g.root(json!({"camera": 1, "name": "plan"}));
    g.root(json!({"camera": 2, "name": "close", "translation": [0.0, 0.0, 1.0]}));
    let dir = temp_dir("cameras");
    let mut file = read_scene_file(&g.write(&dir, "cameras")).unwrap();
    let names: Vec<_> = file
        .cameras
        .iter()
        .map(|c| (c.index, c.name.as_str()))
        .collect();
    assert_eq!(names, [(0, "overview"), (2, "close")]);

    let wide = &file.camera("wide").unwrap().camera;
    assert_eq!((wide.width_px, wide.height_px), (1280, 720));
    assert_eq!(wide.far_m, 1000.0, "zfar absent: the default far plane");
    assert_eq!(wide.fstop, 2.8);
    assert!(
        (wide.focus_m - 7.0).abs() < 1e-4,
        "focus on the box centre: {}",
        wide.focus_m
    );
    // Without extras the focal length is the one that gives yfov on a 36 mm sensor.
    let f_px = 720.0 / (2.0 * 0.5f32.tan());
    assert!((wide.focal_length_mm - 36.0 * f_px / 1280.0).abs() < 1e-3);

    let close = file.camera("2").unwrap();
    assert!(close.dof_from_file);
    assert_eq!((close.camera.width_px, close.camera.height_px), (1280, 640));
    assert_eq!((close.camera.fstop, close.camera.focus_m), (4.0, 3.0));
    assert_eq!(file.camera("close").unwrap(), close);

    let err = file.camera("1").unwrap_err().to_string();
    assert!(
        err.contains("0 'overview'") && err.contains("2 'close'"),
        "{err}"
    );
    assert!(file.camera("nosuch").is_err());
    file.use_camera("close").unwrap();
    assert_eq!(file.scene.defaults.unwrap().camera.focus_m, 3.0);
}

#[test]
fn view_override_moves_the_camera_and_focuses_on_the_target() {
    let mut scene = Scene::default();
    let m = scene.add_material(Material::color("grey", [0.5; 3]));
    let mut camera = test_camera(64, 36, 2.0, 2.8);
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 64.0, 36.0), 3.0, m);
    let o = ViewOverride {
        look_from_m: Some(Vec3::new(0.0, 0.0, 5.0)),
        look_at_m: Some(Vec3::new(0.0, 0.0, -3.0)),
        up: None,
        yfov_rad: Some(30f32.to_radians()),
    };
    o.apply(&mut camera, &scene).unwrap();
    assert_eq!(camera.focus_m, 8.0);
    assert_eq!(camera.yfov_rad, Some(30f32.to_radians()));
    let p = camera
        .camera_from_world
        .transform_point3(Vec3::new(0.0, 0.0, -3.0));
    assert!(p.truncate().length() < 1e-5 && (p.z + 8.0).abs() < 1e-5);
    let bad = ViewOverride {
        look_at_m: Some(Vec3::new(0.0, 0.0, 5.0)),
        ..o
    };
    assert!(
        bad.apply(&mut camera.clone(), &scene).is_err(),
        "look-at equal to look-from"
    );
    let bad_up = ViewOverride {
        up: Some(Vec3::Z),
        ..o
    };
    assert!(
        bad_up.apply(&mut camera.clone(), &scene).is_err(),
        "up along the view direction"
    );
}

#[test]
fn autofocus_takes_the_median_depth_around_the_pixel_and_skips_holes() {
    let mut scene = Scene::default();
    let m = scene.add_material(Material::color("grey", [0.5; 3]));
    let camera = test_camera(64, 36, 2.0, 2.8);
    // A board at 3 m over the centre, a wall at 10 m on the left, nothing on the right.
    add_screen_rect(&mut scene, &camera, (20.0, 8.0, 44.0, 28.0), 3.0, m);
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 16.0, 36.0), 10.0, m);
    let pick = focus_at_centre(&scene, &camera).unwrap().unwrap();
    assert_eq!((pick.x_px, pick.y_px, pick.window_px), (32, 18, 9));
    assert!((pick.depth_m - 3.0).abs() < 1e-5, "{pick:?}");
    // On the board's left edge the window is mostly board: the median is the board.
    let edge = focus_at_pixel(&scene, &camera, 21, 18).unwrap().unwrap();
    assert!((edge.depth_m - 3.0).abs() < 1e-5, "{edge:?}");
    let wall = focus_at_pixel(&scene, &camera, 5, 5).unwrap().unwrap();
    assert!((wall.depth_m - 10.0).abs() < 1e-4, "{wall:?}");
    // Background only nearby: the window grows until it finds the board.
    let grown = focus_at_pixel(&scene, &camera, 58, 30).unwrap().unwrap();
    assert!(
        grown.window_px > 9 && (grown.depth_m - 3.0).abs() < 1e-5,
        "{grown:?}"
    );
    assert!(focus_at_pixel(&scene, &camera, 64, 0).is_err());
    assert!(focus_at_centre(&Scene::default(), &camera)
        .unwrap()
        .is_none());
}

// ---------------------------------------------------------------------------------------------
// Materials and alpha
// ---------------------------------------------------------------------------------------------

const NEAREST_SAMPLER: &str =
    r#"{"magFilter": 9728, "minFilter": 9728, "wrapS": 33071, "wrapT": 33071}"#;

#[test]
fn mask_cutouts_are_holes_and_blend_surfaces_blend_over_what_is_behind() {
    let camera = test_camera(64, 32, 2.0, 2.8);
    let mut g = Gltf::new();
    // 2x2 texture: top-left cut out, top-right red, bottom-left sRGB 128 green, bottom-right
    // alpha 100/255 (below the cutoff 0.5, cut out too).
    let tex = g.texture(
        &png(
            2,
            2,
            &[
                [255, 0, 0, 0],
                [255, 0, 0, 255],
                [0, 128, 0, 255],
                [255, 255, 255, 100],
            ],
        ),
        serde_json::from_str(NEAREST_SAMPLER).unwrap(),
    );
    let wall = g.push(
        "materials",
        json!({"name": "wall", "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 1.0, 1.0]}}),
    );
    let mask = g.push(
        "materials",
        json!({"name": "mask", "alphaMode": "MASK", "doubleSided": true,
        "pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}}),
    );
    let glass = g.push(
        "materials",
        json!({"name": "glass", "alphaMode": "BLEND", "doubleSided": true,
        "pbrMetallicRoughness": {"baseColorFactor": [0.0, 1.0, 0.0, 0.25]}}),
    );
    // The wall is drawn single-sided, so give it counter-clockwise corners as seen from the camera.
    let mut w = screen_quad(&camera, (-8.0, -8.0, 72.0, 40.0), 4.0);
    w.swap(1, 3);
    let m_wall = g.quad(w, Some(wall));
    let m_mask = g.quad(
        screen_quad(&camera, (0.0, 0.0, 32.0, 32.0), 2.0),
        Some(mask),
    );
    let m_glass = g.quad(
        screen_quad(&camera, (32.0, 0.0, 64.0, 32.0), 2.0),
        Some(glass),
    );
    for m in [m_wall, m_mask, m_glass] {
        g.root(json!({"mesh": m}));
    }
    let dir = temp_dir("alpha");
    let scene = load_scene_file(&g.write_embedded(&dir, "alpha")).unwrap();
    assert_eq!(scene.materials.len(), 3);
    assert_eq!(
        scene.materials[1].alpha_mode,
        AlphaMode::Mask { cutoff: 0.5 }
    );
    assert_eq!(scene.materials[2].alpha_mode, AlphaMode::Blend);
    let out = pinhole_frame(&scene, &camera, 1);
    let (img, depth) = (&out.image, out.depth.as_ref().unwrap());
    let close = |a: [f32; 4], b: [f32; 4]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-4);
    let blue = [0.0, 0.0, 1.0, 1.0];
    for (x, y, rgba, z, what) in [
        (
            8,
            8,
            blue,
            4.0,
            "top-left texel cut out: the wall shows through",
        ),
        (24, 8, [1.0, 0.0, 0.0, 1.0], 2.0, "top-right texel: red"),
        (
            8,
            24,
            [0.0, srgb_decode(128.0 / 255.0), 0.0, 1.0],
            2.0,
            "bottom-left texel: sRGB-decoded green",
        ),
        (24, 24, blue, 4.0, "bottom-right alpha 0.39 < 0.5: cut out"),
        (
            48,
            16,
            [0.0, 0.25, 0.75, 1.0],
            4.0,
            "glass: 25% green over blue; depth of the wall",
        ),
    ] {
        assert!(
            close(img.get(x, y), rgba),
            "{what}: pixel ({x}, {y}) is {:?}, expected {rgba:?}",
            img.get(x, y)
        );
        assert_eq!(depth.get(x, y), z, "{what}: depth at ({x}, {y})");
    }
}

#[test]
fn gltf_material_factors_samplers_and_texture_transforms_are_read() {
    let mut g = Gltf::new();
    let t0 = g.texture(
        &png(1, 1, &[[10, 20, 30, 255]]),
        json!({"magFilter": 9728, "minFilter": 9986, "wrapS": 33648, "wrapT": 33071}),
    );
    let t1 = g.texture(&png(1, 1, &[[200, 100, 50, 255]]), json!({}));
    let m = g.push(
        "materials",
        json!({
            "name": "lamp", "alphaMode": "MASK", "alphaCutoff": 0.3,
            "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.6, 0.7, 0.8],
                "baseColorTexture": {"index": t0, "extensions": {"KHR_texture_transform":
                    {"offset": [0.25, 0.5], "rotation": 0.1, "scale": [2.0, 3.0]}}}},
            "emissiveFactor": [1.0, 0.5, 0.25], "emissiveTexture": {"index": t1},
            "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 7.5}},
        }),
    );
    g.json["extensionsUsed"] = json!(["KHR_materials_emissive_strength", "KHR_texture_transform"]);
    g.json["extensionsRequired"] = json!(["KHR_texture_transform"]);
    let mesh = g.quad([Vec3::ZERO, Vec3::X, Vec3::ONE, Vec3::Y], Some(m));
    g.root(json!({"mesh": mesh}));
    let dir = temp_dir("material");
    let scene = load_scene_file(&g.write(&dir, "material")).unwrap();
    let mat = &scene.materials[0];
    assert_eq!(mat.name, "lamp");
    assert_eq!(mat.base_color, [0.5, 0.6, 0.7, 0.8]);
    assert_eq!(mat.emissive, [1.0, 0.5, 0.25]);
    assert_eq!(mat.emissive_strength, 7.5);
    assert_eq!(mat.alpha_mode, AlphaMode::Mask { cutoff: 0.3 });
    assert!(!mat.double_sided, "glTF's default is single-sided");
    let base = mat.base_color_texture.as_ref().unwrap();
    assert_eq!(base.sampler.mag_filter, FilterMode::Nearest);
    assert_eq!(
        (base.sampler.min_filter, base.sampler.mip_filter),
        (FilterMode::Nearest, Some(FilterMode::Linear))
    );
    assert_eq!(
        (base.sampler.wrap_u, base.sampler.wrap_v),
        (WrapMode::MirroredRepeat, WrapMode::ClampToEdge)
    );
    assert_eq!(
        (
            base.uv_transform.offset,
            base.uv_transform.rotation_rad,
            base.uv_transform.scale
        ),
        (Vec2::new(0.25, 0.5), 0.1, Vec2::new(2.0, 3.0))
    );
    let emissive = mat.emissive_texture.as_ref().unwrap();
    assert_eq!(
        emissive.sampler,
        defocus::scene::TextureSampler::default(),
        "no filters given: trilinear, repeat"
    );
    let texel =
        |b: &defocus::scene::TextureBinding| scene.textures[b.texture].levels()[0].get(0, 0);
    let expect = |v: [u8; 3]| {
        [
            srgb_decode(v[0] as f32 / 255.0),
            srgb_decode(v[1] as f32 / 255.0),
            srgb_decode(v[2] as f32 / 255.0),
            1.0,
        ]
    };
    assert_eq!(
        texel(base),
        expect([10, 20, 30]),
        "base colour texture sRGB-decoded"
    );
    assert_eq!(
        texel(emissive),
        expect([200, 100, 50]),
        "emissive texture sRGB-decoded"
    );
}

#[test]
fn triangle_strips_fans_and_non_indexed_primitives_become_triangles() {
    let mut g = Gltf::new();
    let quad = [
        Vec3::new(0.0, 0.0, -2.0),
        Vec3::new(1.0, 0.0, -2.0),
        Vec3::new(0.0, 1.0, -2.0),
        Vec3::new(1.0, 1.0, -2.0),
    ];
    let pos = g.positions(&quad);
    let strip = g.push(
        "meshes",
        json!({"primitives": [{"attributes": {"POSITION": pos}, "mode": 5}]}),
    );
    let fan_pos = g.positions(&[quad[0], quad[1], quad[3], quad[2]]);
    let fan = g.push(
        "meshes",
        json!({"primitives": [{"attributes": {"POSITION": fan_pos}, "mode": 6}]}),
    );
    let tri = g.push(
        "meshes",
        json!({"primitives": [{"attributes": {"POSITION": pos}}]}),
    );
    for m in [strip, fan] {
        g.root(json!({"mesh": m}));
    }
    let dir = temp_dir("modes");
    let scene = load_scene_file(&g.write(&dir, "modes")).unwrap();
    assert_eq!(
        scene.meshes[0].indices,
        [[0, 1, 2], [2, 1, 3]],
        "strip: odd triangles swap to keep the winding"
    );
    assert_eq!(
        scene.meshes[1].indices,
        [[1, 2, 0], [2, 3, 0]],
        "fan: around the first vertex"
    );
    // Four non-indexed vertices are not a whole number of triangles.
    g.root(json!({"mesh": tri}));
    let err = error_of(load_scene_file(&g.write(&dir, "modes-bad")));
    assert!(
        err.contains("modes-bad.gltf") && err.contains("multiple of 3"),
        "{err}"
    );
}

// ---------------------------------------------------------------------------------------------
// Malformed files
// ---------------------------------------------------------------------------------------------

/// A valid file with one textured quad, the base of the malformed variants.
pub(crate) fn valid_textured() -> Gltf {
    let mut g = Gltf::new();
    let tex = g.texture(&png(1, 1, &[[255; 4]]), json!({}));
    let m = g.push(
        "materials",
        json!({"pbrMetallicRoughness": {"baseColorTexture": {"index": tex}}}),
    );
    let mesh = g.quad([Vec3::ZERO, Vec3::X, Vec3::ONE, Vec3::Y], Some(m));
    g.root(json!({"mesh": mesh}));
    g
}

/// Loads `path` and checks the error names the file and contains every one of `needles`.
fn assert_error(path: &Path, needles: &[&str]) {
    let err = error_of(load_scene_file(path));
    let name = path.file_name().unwrap().to_str().unwrap();
    assert!(
        err.contains(name),
        "error does not name the file {name}: {err}"
    );
    for n in needles {
        assert!(err.contains(n), "error lacks '{n}': {err}");
    }
}

#[test]
fn malformed_gltf_files_are_errors_that_name_the_file_and_the_problem() {
    let dir = temp_dir("malformed");
    load_scene_file(&valid_textured().write(&dir, "valid")).expect("the base file is valid");

    let broken = dir.join("broken.gltf");
    std::fs::write(&broken, br#"{"asset": {"version": "2.0"}, "nodes": [ {"#).unwrap();
    assert_error(&broken, &["not valid glTF JSON", "line 1"]);

    let missing_bin = valid_textured().write(&dir, "nobin");
    std::fs::remove_file(dir.join("nobin.bin")).unwrap();
    assert_error(&missing_bin, &["buffers[0].uri", "nobin.bin"]);

    let mut g = valid_textured();
    g.json["images"][0] = json!({"uri": "textures/missing.png"});
    assert_error(&g.write(&dir, "notex"), &["images[0].uri", "missing.png"]);

    let mut g = valid_textured();
    g.json["images"][0] = json!({"uri": "data:image/png;base64,iVBORw0KGgoAAAANSUhE"});
    assert_error(&g.write(&dir, "badpng"), &["image 0", "PNG"]);

    let mut g = valid_textured();
    let garbage = g.view(b"this is not an image at all");
    g.json["images"][0] = json!({"bufferView": garbage, "mimeType": "image/png"});
    assert_error(&g.write(&dir, "garbage"), &["image 0", "not a PNG or JPEG"]);

    let mut g = valid_textured();
    g.json["meshes"][0]["primitives"][0]["indices"] = json!(99);
    assert_error(
        &g.write(&dir, "index"),
        &["meshes[0].primitives[0].indices", "out of bounds"],
    );

    let mut g = valid_textured();
    g.json["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(42);
    assert_error(
        &g.write(&dir, "position"),
        &["POSITION", "accessor 42 is out of range"],
    );

    let mut g = valid_textured();
    g.json["accessors"][0]["count"] = json!(400);
    assert_error(
        &g.write(&dir, "pastend"),
        &["POSITION", "accessor 0", "reads bytes"],
    );

    let mut g = valid_textured();
    g.json["bufferViews"][0]["byteLength"] = json!(1 << 20);
    assert_error(
        &g.write(&dir, "bigview"),
        &["runs past the end of buffer 0"],
    );

    let mut g = valid_textured();
    let idx = g.indices(&[0, 1, 7]);
    g.json["meshes"][0]["primitives"][0]["indices"] = json!(idx);
    assert_error(&g.write(&dir, "vertex"), &["index 7", "4 vertices"]);

    let mut g = valid_textured();
    g.json["extensionsUsed"] = json!(["KHR_draco_mesh_compression"]);
    g.json["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]);
    assert_error(
        &g.write(&dir, "draco"),
        &["KHR_draco_mesh_compression", "not support"],
    );

    for (mode, name) in [(0, "POINTS"), (1, "LINES"), (3, "LINE_STRIP")] {
        let mut g = valid_textured();
        g.json["meshes"][0]["primitives"][0]["mode"] = json!(mode);
        assert_error(&g.write(&dir, &format!("mode{mode}")), &[name, "TRIANGLES"]);
    }

    let mut g = valid_textured();
    g.json["buffers"] = json!([]);
    let mut json = g.json.clone();
    json["buffers"] =
        json!([{"byteLength": 10, "uri": "data:application/octet-stream;base64,@@@@"}]);
    let bad64 = dir.join("bad64.gltf");
    std::fs::write(&bad64, serde_json::to_vec(&json).unwrap()).unwrap();
    assert_error(&bad64, &["buffer 0", "base64"]);

    let glb = valid_textured().write_glb(&dir, "cut");
    let bytes = std::fs::read(&glb).unwrap();
    std::fs::write(&glb, &bytes[..bytes.len() - 10]).unwrap();
    assert_error(&glb, &["GLB", "truncated"]);
    std::fs::write(&glb, &bytes[..6]).unwrap();
    assert_error(&glb, &["GLB", "header"]);

    let nobin = {
        let mut g = valid_textured();
        g.bin.clear();
        g.write_glb(&dir, "nochunk")
    };
    // The BIN chunk is empty: every view runs past it.
    assert_error(&nobin, &["buffer"]);

    let fbx = dir.join("scene.fbx");
    std::fs::write(&fbx, b"").unwrap();
    assert_error(&fbx, &[".gltf, .glb, .obj"]);
    assert!(matches!(
        load_scene_file(&dir.join("absent.glb")),
        Err(defocus::Error::Io { .. })
    ));
}

// ---------------------------------------------------------------------------------------------
// OBJ + MTL
// ---------------------------------------------------------------------------------------------

#[test]
fn obj_and_mtl_materials_load_with_their_colours_opacity_emission_and_textures() {
    let dir = temp_dir("obj");
    std::fs::write(
        dir.join("wood.png"),
        png(
            2,
            2,
            &[
                [128, 0, 0, 255],
                [0, 128, 0, 255],
                [0, 0, 128, 255],
                [255, 255, 255, 255],
            ],
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("leaf mask.png"),
        png(1, 2, &[[255, 255, 255, 255], [0, 0, 0, 255]]),
    )
    .unwrap();
    std::fs::write(
        dir.join("scene.mtl"),
        "newmtl glassy\nKd 0.5 0.25 1.0\nd 0.4\nmap_Kd -s 1 1 1 wood.png\n\n\
         newmtl glow\nKd 0 0 0\nKe 2 3 4\n\n\
         newmtl leaf\nTr 0.25\nmap_d leaf mask.png\n\n\
         newmtl cutout\nmap_Kd wood.png\nmap_d leaf mask.png\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("scene.obj"),
        "mtllib scene.mtl\nv -1 -1 -2\nv 1 -1 -2\nv 1 1 -2\nv -1 1 -2\n\
         vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         o panel\nusemtl glassy\nf 1/1 2/2 3/3 4/4\n\
         o lamp\nusemtl glow\nf 1/1 2/2 3/3\n\
         o plain\nusemtl nosuch\nf 1 3 4\n",
    )
    .unwrap();
    let file = read_scene_file(&dir.join("scene.obj")).unwrap();
    let scene = &file.scene;
    let by_name = |n: &str| {
        scene
            .materials
            .iter()
            .find(|m| m.name == n)
            .unwrap_or_else(|| panic!("no material {n}"))
    };

    let glassy = by_name("glassy");
    assert_eq!(glassy.base_color, [0.5, 0.25, 1.0, 0.4]);
    assert_eq!(glassy.alpha_mode, AlphaMode::Blend);
    let tex = &scene.textures[glassy.base_color_texture.as_ref().unwrap().texture];
    assert_eq!(tex.size(), (2, 2));
    let dark_red = srgb_decode(128.0 / 255.0);
    assert_eq!(
        tex.levels()[0].get(0, 0),
        [dark_red, 0.0, 0.0, 1.0],
        "map_Kd is sRGB-decoded, row 0 on top"
    );

    let glow = by_name("glow");
    assert_eq!(glow.emissive, [2.0, 3.0, 4.0]);
    assert_eq!(glow.alpha_mode, AlphaMode::Opaque);

    let leaf = by_name("leaf");
    assert_eq!(leaf.base_color[3], 0.75, "Tr 0.25 is opacity 0.75");
    assert_eq!(leaf.alpha_mode, AlphaMode::Blend);
    let mask = &scene.textures[leaf.base_color_texture.as_ref().unwrap().texture];
    assert_eq!(
        (mask.levels()[0].get(0, 0)[3], mask.levels()[0].get(0, 1)[3]),
        (1.0, 0.0),
        "map_d grey level is opacity"
    );

    let cutout = by_name("cutout");
    assert_eq!(cutout.alpha_mode, AlphaMode::Mask { cutoff: 0.5 });
    let combined = &scene.textures[cutout.base_color_texture.as_ref().unwrap().texture].levels()[0];
    assert_eq!(combined.get(1, 0), [0.0, dark_red, 0.0, 1.0]);
    assert_eq!(
        combined.get(0, 1)[3],
        0.0,
        "alpha from map_d, resampled to map_Kd's size"
    );

    assert_eq!(scene.meshes.len(), 3);
    let panel = &scene.meshes[0];
    assert_eq!(scene.materials[panel.material].name, "glassy");
    assert_eq!(panel.indices.len(), 2, "the quad face is triangulated");
    assert_eq!(panel.positions[0], Vec3::new(-1.0, -1.0, -2.0));
    assert_eq!(
        panel.uvs[0],
        Vec2::new(0.0, 1.0),
        "OBJ v = 0 is the image bottom: flipped"
    );
    assert_eq!(scene.materials[scene.meshes[2].material].name, "default");
    assert!(file.cameras.is_empty() && scene.defaults.is_some());
}

#[test]
fn obj_with_a_missing_library_texture_or_bad_face_is_an_error_naming_it() {
    let dir = temp_dir("obj-bad");
    let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\n";
    std::fs::write(
        dir.join("nolib.obj"),
        format!("mtllib absent.mtl\n{quad}f 1 2 3\n"),
    )
    .unwrap();
    assert_error(&dir.join("nolib.obj"), &["absent.mtl"]);

    std::fs::write(dir.join("notex.mtl"), "newmtl m\nmap_Kd gone.jpg\n").unwrap();
    std::fs::write(
        dir.join("notex.obj"),
        format!("mtllib notex.mtl\n{quad}usemtl m\nf 1 2 3\n"),
    )
    .unwrap();
    assert_error(&dir.join("notex.obj"), &["gone.jpg"]);

    std::fs::write(dir.join("face.obj"), format!("{quad}f 1 2 9\n")).unwrap();
    assert_error(&dir.join("face.obj"), &["OBJ"]);
}

// ---------------------------------------------------------------------------------------------
// Shared assets
// ---------------------------------------------------------------------------------------------

/// Fraction of pixels of a small pinhole frame that must be lit for a scene to count as shown.
const MIN_LIT_FRACTION: f64 = 0.01;

#[test]
fn every_shared_scene_asset_loads_and_renders_a_lit_pinhole_frame() {
    let Some(assets) = shared_assets() else {
        return;
    };
    let mut files = vec![assets.join("cycles/scene.glb")];
    for entry in std::fs::read_dir(assets.join("scenes")).unwrap() {
        for f in std::fs::read_dir(entry.unwrap().path()).unwrap() {
            let p = f.unwrap().path();
            if matches!(p.extension().and_then(|e| e.to_str()), Some("glb" | "gltf")) {
                files.push(p);
            }
        }
    }
    files.sort();
    assert!(
        files.len() >= 6,
        "expected the five Khronos scenes and the Cycles scene: {files:?}"
    );
    for path in files {
        let t = Instant::now();
        let scene = load_scene_file(&path).unwrap_or_else(|e| panic!("{e}"));
        let load_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut camera = scene.defaults.as_ref().unwrap().camera.clone();
        camera.width_px = 256;
        camera.height_px = 144;
        let out = pinhole_frame(&scene, &camera, 1);
        let lit = out
            .image
            .pixels()
            .iter()
            .filter(|p| p[0] + p[1] + p[2] > 0.01)
            .count();
        let fraction = lit as f64 / (256.0 * 144.0);
        eprintln!(
            "{}: {} triangles, {} materials, {} textures, loaded in {load_ms:.0} ms, {:.0}% lit",
            path.file_name().unwrap().to_string_lossy(),
            scene.triangle_count(),
            scene.materials.len(),
            scene.textures.len(),
            100.0 * fraction
        );
        assert!(scene.triangle_count() > 0);
        assert!(
            fraction > MIN_LIT_FRACTION,
            "{}: only {lit} lit pixels",
            path.display()
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Cycles calibration (../shared/assets/cycles/README.md)
// ---------------------------------------------------------------------------------------------

/// Cycles' pinhole image is 1024 samples per pixel with a 1-pixel box filter, so anti-aliased
/// edges: we supersample as many times per pixel as this (the sub-pixel offsets are a low
/// discrepancy set, so edges converge fast).
const CYCLES_PINHOLE_SAMPLES: usize = 256;
/// Least PSNR of our supersampled pinhole image against `pinhole.exr`. An independent program
/// following the README's model scored 69.16 dB; Cycles' own seed pair 70.03 dB. Measured:
/// 64.5 dB at 256 samples (the sub-pixel offsets are snapped onto the rasterizer's 1/256 px grid,
/// [`defocus::raster::snap_pixel_offset`]; before that, an offset within 1/512 px of +0.5 rounded
/// onto the next pixel's edge and texel-aligned ticks picked up a neighbouring texel: 52.3 dB).
const CYCLES_PINHOLE_MIN_PSNR_DB: f64 = 62.0;
/// Lens samples of the depth-of-field renders (the README: 1024 samples should score about
/// 56-57 dB against the two-seed means; a noise-free renderer about 61 dB).
const CYCLES_DOF_SAMPLES: usize = 1024;
/// Least PSNR against `dof_disc.exr` and `dof_blades5.exr`, far above the 30.13 dB of the
/// pinhole image against `dof_disc.exr` (turning the pentagon by 18 degrees costs about 3.6 dB).
/// Measured at 1024 samples: 56.8 dB (disc) and 57.9 dB (5 blades); 59.2 and 60.4 dB at 4096
/// samples, as the Cycles README predicts for a renderer that follows Cycles' model.
const CYCLES_DOF_MIN_PSNR_DB: f64 = 55.0;
/// Least SSIM of the depth-of-field renders (Cycles' seed pair: 0.99991).
const CYCLES_DOF_MIN_SSIM: f64 = 0.9995;

fn cycles() -> Option<(PathBuf, Scene, Camera)> {
    let dir = shared_assets()?.join("cycles");
    let scene = load_scene_file(&dir.join("scene.glb")).unwrap();
    let camera = scene.defaults.as_ref().unwrap().camera.clone();
    Some((dir, scene, camera))
}

#[test]
fn cycles_scene_loads_with_the_exact_camera_of_its_readme() {
    let Some((_, scene, camera)) = cycles() else {
        return;
    };
    assert_eq!((camera.width_px, camera.height_px), (480, 270));
    assert_eq!(
        (camera.focal_length_mm, camera.sensor_width_mm),
        (35.0, 36.0)
    );
    assert_eq!((camera.fstop, camera.focus_m), (2.0, 2.0));
    assert_eq!((camera.near_m, camera.far_m), (0.05, 100.0));
    let lens = camera.thin_lens().unwrap();
    assert!((lens.f_px - 466.6667).abs() < 1e-3, "f_px {}", lens.f_px);
    assert!((lens.lens_radius_m - 0.00875).abs() < 1e-7);
    assert!(scene.triangle_count() > 0);
    // The plane's texture: NEAREST, NEAREST_MIPMAP_NEAREST, clamp; emission carries colour.
    let plane = scene
        .materials
        .iter()
        .find(|m| m.emissive_texture.is_some())
        .expect("plane material");
    let s = plane.emissive_texture.as_ref().unwrap().sampler;
    assert_eq!(
        (s.mag_filter, s.min_filter, s.mip_filter),
        (
            FilterMode::Nearest,
            FilterMode::Nearest,
            Some(FilterMode::Nearest)
        )
    );
    assert_eq!(
        (s.wrap_u, s.wrap_v),
        (WrapMode::ClampToEdge, WrapMode::ClampToEdge)
    );
    let discs: Vec<&Material> = scene
        .materials
        .iter()
        .filter(|m| m.emissive_strength == 10.0)
        .collect();
    assert!(
        !discs.is_empty(),
        "KHR_materials_emissive_strength 10 on the discs"
    );
}

#[test]
fn cycles_pinhole_colour_and_depth_match_blender() {
    let Some((dir, scene, camera)) = cycles() else {
        return;
    };
    let t = Instant::now();
    let ours = pinhole::render(&scene, &camera, CYCLES_PINHOLE_SAMPLES, 0, false).unwrap();
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let truth = io::read_color(&dir.join("pinhole.exr")).unwrap();
    let m = metrics::compare(&ours.image, &truth).unwrap();
    let centres = pinhole::render(&scene, &camera, 1, 0, true).unwrap();
    let m1 = metrics::compare(&centres.image, &truth).unwrap();
    eprintln!(
        "cycles pinhole: {CYCLES_PINHOLE_SAMPLES} spp {:.2} dB SSIM {:.5} ({ms:.0} ms); pixel centres only {:.2} dB SSIM {:.5}",
        m.psnr_db, m.ssim, m1.psnr_db, m1.ssim
    );
    assert!(
        m.psnr_db > CYCLES_PINHOLE_MIN_PSNR_DB,
        "pinhole PSNR {:.2} dB",
        m.psnr_db
    );

    // Z is from the pixel centre only, as ours.
    let z_truth = io::read_depth(&dir.join("pinhole.exr"), &io::DepthRead::default()).unwrap();
    let z = centres.depth.unwrap();
    assert!(z.same_size(&z_truth));
    let mut bad = Vec::new();
    for y in 0..z.height() {
        for x in 0..z.width() {
            let (a, b) = (z.get(x, y), z_truth.get(x, y));
            if (a - b).abs() > 1e-4 * b {
                bad.push((x, y, a, b));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "{} pixels differ in depth, first: {:?}",
        bad.len(),
        &bad[..bad.len().min(5)]
    );
}

fn cycles_dof(aperture: &str, reference_file: &str) {
    let Some((dir, scene, camera)) = cycles() else {
        return;
    };
    let settings = ReferenceSettings {
        samples: CYCLES_DOF_SAMPLES,
        aperture: Aperture::parse(aperture).unwrap(),
        ..ReferenceSettings::default()
    };
    let t = Instant::now();
    let ours = reference::render(&scene, &camera, &settings, &mut |_, _| {}).unwrap();
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let truth = io::read_color(&dir.join(reference_file)).unwrap();
    let m = metrics::compare(&ours.image, &truth).unwrap();
    let pin = io::read_color(&dir.join("pinhole.exr")).unwrap();
    let baseline = metrics::psnr_srgb(&pin, &truth).unwrap();
    eprintln!(
        "cycles {aperture} vs {reference_file}: {CYCLES_DOF_SAMPLES} lens samples {:.2} dB SSIM {:.5}, \
         MSE {:.3e} ({ms:.0} ms); pinhole.exr scores {baseline:.2} dB",
        m.psnr_db, m.ssim, m.mse_linear
    );
    assert!(
        m.psnr_db > CYCLES_DOF_MIN_PSNR_DB,
        "{aperture}: PSNR {:.2} dB against {reference_file}",
        m.psnr_db
    );
    assert!(
        m.ssim > CYCLES_DOF_MIN_SSIM,
        "{aperture}: SSIM {:.5}",
        m.ssim
    );
    assert_mean_close(&ours.image, &truth);
}

/// The total light matches (no exposure or emission-strength error): mean linear RGB within
/// 0.5%.
fn assert_mean_close(a: &ColorImage, b: &ColorImage) {
    let mean = |img: &ColorImage| {
        img.pixels()
            .iter()
            .map(|p| (p[0] + p[1] + p[2]) as f64)
            .sum::<f64>()
            / img.pixels().len() as f64
    };
    let (ma, mb) = (mean(a), mean(b));
    assert!(
        (ma - mb).abs() < 0.005 * mb,
        "mean linear RGB {ma:.5} vs Cycles {mb:.5}"
    );
}

#[test]
fn cycles_disc_aperture_depth_of_field_matches_blender() {
    cycles_dof("disc", "dof_disc.exr");
}

#[test]
fn cycles_five_blade_depth_of_field_matches_blender() {
    cycles_dof("poly:5", "dof_blades5.exr");
}

// ---------------------------------------------------------------------------------------------
// Command line
// ---------------------------------------------------------------------------------------------

fn defocus_cli(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(args)
        .arg("--quiet")
        .output()
        .expect("run defocus")
}

#[test]
fn cli_renders_a_scene_file_with_its_camera_a_chosen_view_and_autofocus() {
    let camera = test_camera(64, 36, 2.0, 2.8);
    let mut g = Gltf::new();
    let board = g.quad(screen_quad(&camera, (16.0, 9.0, 48.0, 27.0), 3.0), None);
    let wall = g.quad(
        screen_quad(&camera, (-64.0, -36.0, 128.0, 72.0), 10.0),
        None,
    );
    g.push("materials", json!({"doubleSided": true}));
    for m in [board, wall] {
        g.json["meshes"][m]["primitives"][0]["material"] = json!(0);
        g.root(json!({"mesh": m}));
    }
    g.push(
        "cameras",
        json!({"type": "perspective", "name": "main",
        "perspective": {"yfov": 0.5, "aspectRatio": 1.5, "znear": 0.1, "zfar": 50.0}}),
    );
    g.root(json!({"camera": 0, "name": "main"}));
    let dir = temp_dir("cli");
    let scene = g.write(&dir, "board");
    let (scene, out, depth) = (
        scene.to_str().unwrap(),
        dir.join("r.png"),
        dir.join("z.exr"),
    );
    let run = |extra: &[&str]| {
        let mut args = vec![
            "render",
            "--scene",
            scene,
            "--method",
            "pinhole",
            "--width",
            "48",
            "--height",
            "32",
            "--out",
            out.to_str().unwrap(),
            "--depth-out",
            depth.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        defocus_cli(&args)
    };
    let stderr = |o: &std::process::Output| String::from_utf8_lossy(&o.stderr).into_owned();

    let o = run(&["--camera", "main", "--focus", "auto"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("focus: 3.0000 m"), "{}", stderr(&o));
    let z = io::read_depth(&depth, &io::DepthRead::default()).unwrap();
    assert_eq!((z.width(), z.height()), (48, 32));
    assert!((z.get(24, 16) - 3.0).abs() < 1e-5);

    // From 5 m further back, looking at the board's centre: the board is 8 m away.
    let o = run(&[
        "--look-from",
        "0,0,5",
        "--look-at",
        "0,0,-3",
        "--fov",
        "20",
        "--focus-pixel",
        "24,16",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("focus: 8.0000 m"), "{}", stderr(&o));
    let z = io::read_depth(&depth, &io::DepthRead::default()).unwrap();
    assert!((z.get(24, 16) - 8.0).abs() < 1e-4);

    let o = run(&["--camera", "nosuch"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("unknown camera 'nosuch'") && stderr(&o).contains("0 'main'"),
        "{}",
        stderr(&o)
    );
    let o = run(&["--focus-pixel", "48,0"]);
    assert!(
        !o.status.success() && stderr(&o).contains("outside the 48x32 image"),
        "{}",
        stderr(&o)
    );
    let o = run(&["--look-from", "1,2"]);
    assert!(
        !o.status.success() && stderr(&o).contains("--look-from"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn gltf_normals_are_kept_in_world_space_with_the_inverse_transpose() {
    let dir = temp_dir("normals");
    let mut g = Gltf::new();
    // A quad in the plane x + z = 0 (local normal (1, 0, 1) / sqrt 2), under a node scaled 2x
    // along x: the world normal is diag(1/2, 1, 1) n, normalised, not diag(2, 1, 1) n.
    let c = [
        Vec3::new(-1.0, -1.0, 1.0),
        Vec3::new(1.0, -1.0, -1.0),
        Vec3::new(1.0, 1.0, -1.0),
        Vec3::new(-1.0, 1.0, 1.0),
    ];
    let mesh = g.quad(c, None);
    let n = Vec3::new(1.0, 0.0, 1.0).normalize();
    let normals = g.positions(&[n; 4]);
    g.json["meshes"][mesh]["primitives"][0]["attributes"]["NORMAL"] = json!(normals);
    g.root(json!({"mesh": mesh, "scale": [2.0, 1.0, 1.0]}));
    let path = g.write(&dir, "normals");
    let scene = load_scene_file(&path).unwrap();
    let m = &scene.meshes[0];
    assert_eq!(m.normals.len(), m.positions.len());
    let expected = Vec3::new(0.5, 0.0, 1.0).normalize();
    for got in &m.normals {
        assert!((*got - expected).length() < 1e-5, "{got} vs {expected}");
        // Perpendicular to the transformed surface.
        let e1 = m.positions[1] - m.positions[0];
        let e2 = m.positions[3] - m.positions[0];
        assert!(got.dot(e1).abs() < 1e-5 && got.dot(e2).abs() < 1e-5);
    }
    // A NORMAL accessor of the wrong length is an error naming the attribute.
    let mut bad = Gltf::new();
    let mesh = bad.quad(c, None);
    let short = bad.positions(&[n; 3]);
    bad.json["meshes"][mesh]["primitives"][0]["attributes"]["NORMAL"] = json!(short);
    bad.root(json!({"mesh": mesh}));
    let e = load_scene_file(&bad.write(&dir, "bad"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("NORMAL") && e.contains("bad.gltf"), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn obj_vertex_normals_are_kept_unit_length() {
    let dir = temp_dir("objnormals");
    std::fs::write(
        dir.join("n.obj"),
        "v -1 -1 -2\nv 1 -1 -2\nv 1 1 -2\nvn 0 0 2\nf 1//1 2//1 3//1\n",
    )
    .unwrap();
    let scene = load_scene_file(&dir.join("n.obj")).unwrap();
    let m = &scene.meshes[0];
    assert_eq!(m.normals.len(), m.positions.len());
    for n in &m.normals {
        assert!((*n - Vec3::Z).length() < 1e-6, "{n}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}
