//! Scene file benchmarks: loading a large glTF and rendering its first pinhole frame.
//!
//! The scene is generated into a temporary folder before timing: 48 displaced grid panels of
//! 80x40 quads (307,200 triangles) at depths from 2 to 12 m, in one external `.bin`, with 32
//! textures of 1024x1024 pixels (16 RGBA PNG for alpha-tested panels, 16 JPEG), and a camera.
//! Ids: `scene_load/load/<scene>`, `scene_load/pinhole/<scene>/<w>x<h>` (from a loaded scene)
//! and `scene_load/load_and_pinhole/<scene>/<w>x<h>` (what `defocus render --method pinhole`
//! does).

#![expect(
    missing_docs,
    reason = "criterion_group! generates undocumented functions"
)]

use std::io::Cursor;
use std::path::{Path, PathBuf};

use criterion::{criterion_group, criterion_main, Criterion};
use defocus::methods::pinhole;
use defocus::scene::load::load_scene_file;
use serde_json::json;

const PANELS: usize = 48;
const QUADS_X: usize = 80;
const QUADS_Y: usize = 40;
const TEXTURES: usize = 32;
const TEXTURE_PX: u32 = 1024;
const SCENE: &str = "300k_tris_32_textures";

/// A texture with structure at several scales (so it compresses like a real one): stripes,
/// a checker and a little hashed noise; alpha cut-outs (circles) for the PNG ones.
fn texture(seed: usize, with_alpha: bool) -> image::DynamicImage {
    let hash = |x: u32, y: u32| {
        let mut h = x.wrapping_mul(0x9E37_79B1) ^ y.wrapping_mul(0x85EB_CA77) ^ seed as u32;
        h ^= h >> 15;
        h = h.wrapping_mul(0x2C1B_3C6D);
        (h >> 24) as u8
    };
    let px = |x: u32, y: u32| {
        let checker = ((x / 64 + y / 64) % 2) as u8 * 90;
        let stripes = (((x + y + seed as u32 * 7) / 8) % 2) as u8 * 40;
        let noise = hash(x, y) / 16;
        let base = 60 + checker + stripes + noise;
        [base, base.wrapping_add(seed as u8 * 13), 255 - base / 2]
    };
    if with_alpha {
        image::DynamicImage::ImageRgba8(image::RgbaImage::from_fn(
            TEXTURE_PX,
            TEXTURE_PX,
            |x, y| {
                let [r, g, b] = px(x, y);
                let (cx, cy) = ((x % 128) as i32 - 64, (y % 128) as i32 - 64);
                let a = if cx * cx + cy * cy < 40 * 40 { 0 } else { 255 };
                image::Rgba([r, g, b, a])
            },
        ))
    } else {
        image::DynamicImage::ImageRgb8(image::RgbImage::from_fn(TEXTURE_PX, TEXTURE_PX, |x, y| {
            image::Rgb(px(x, y))
        }))
    }
}

/// Writes the scene into `dir` and returns the path of its `.gltf`.
fn write_scene(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).expect("temporary folder");
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut push_view = |bin: &mut Vec<u8>, bytes: &[u8]| {
        let offset = bin.len();
        bin.extend_from_slice(bytes);
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": bytes.len()}));
        views.len() - 1
    };
    let mut images = Vec::new();
    let mut textures = Vec::new();
    let mut materials = Vec::new();
    for t in 0..TEXTURES {
        let png = t % 2 == 0;
        let name = format!("tex{t:02}.{}", if png { "png" } else { "jpg" });
        let img = texture(t, png);
        let mut bytes = Cursor::new(Vec::new());
        let format = if png {
            image::ImageFormat::Png
        } else {
            image::ImageFormat::Jpeg
        };
        img.write_to(&mut bytes, format).expect("encode texture");
        std::fs::write(dir.join(&name), bytes.into_inner()).expect("write texture");
        images.push(json!({"uri": name}));
        textures.push(json!({"source": t, "sampler": 0}));
        let mut m = json!({
            "pbrMetallicRoughness": {"baseColorTexture": {"index": t}},
            "doubleSided": true,
        });
        if png {
            m["alphaMode"] = json!("MASK");
        }
        materials.push(m);
    }
    let mut meshes = Vec::new();
    let mut nodes = Vec::new();
    let (nx, ny) = (QUADS_X + 1, QUADS_Y + 1);
    for p in 0..PANELS {
        let mut pos = Vec::with_capacity(nx * ny * 12);
        let mut uv = Vec::with_capacity(nx * ny * 8);
        for j in 0..ny {
            for i in 0..nx {
                let (u, v) = (i as f32 / QUADS_X as f32, j as f32 / QUADS_Y as f32);
                let bump = 0.05 * ((u * 17.0 + p as f32).sin() * (v * 11.0).cos());
                for c in [2.0 * u - 1.0, 0.5 - v, bump] {
                    pos.extend_from_slice(&f32::to_le_bytes(c));
                }
                uv.extend_from_slice(&f32::to_le_bytes(u * 2.0));
                uv.extend_from_slice(&f32::to_le_bytes(v));
            }
        }
        let mut idx = Vec::with_capacity(QUADS_X * QUADS_Y * 24);
        for j in 0..QUADS_Y {
            for i in 0..QUADS_X {
                let a = (j * nx + i) as u32;
                for k in [
                    a,
                    a + nx as u32,
                    a + 1,
                    a + 1,
                    a + nx as u32,
                    a + nx as u32 + 1,
                ] {
                    idx.extend_from_slice(&k.to_le_bytes());
                }
            }
        }
        let count = nx * ny;
        let vp = push_view(&mut bin, &pos);
        let vu = push_view(&mut bin, &uv);
        let vi = push_view(&mut bin, &idx);
        let a = accessors.len();
        accessors.push(
            json!({"bufferView": vp, "componentType": 5126, "count": count, "type": "VEC3",
                              "min": [-1.0, -0.5, -0.05], "max": [1.0, 0.5, 0.05]}),
        );
        accessors
            .push(json!({"bufferView": vu, "componentType": 5126, "count": count, "type": "VEC2"}));
        accessors.push(json!({"bufferView": vi, "componentType": 5125, "count": idx.len() / 4, "type": "SCALAR"}));
        meshes.push(
            json!({"primitives": [{"attributes": {"POSITION": a, "TEXCOORD_0": a + 1},
                                             "indices": a + 2, "material": p % TEXTURES}]}),
        );
        // An 8 x 6 wall of panels, farther rows deeper.
        let (col, row) = ((p % 8) as f32, (p / 8) as f32);
        let z = -2.0 - 10.0 * (p as f32 / PANELS as f32);
        let scale = 0.4 * -z;
        nodes.push(
            json!({"mesh": p, "translation": [(col - 3.5) * 0.3 * -z, (row - 2.5) * 0.2 * -z, z],
                          "scale": [scale * 0.3, scale * 0.4, 1.0]}),
        );
    }
    nodes.push(json!({"camera": 0, "translation": [0.0, 0.0, 0.5]}));
    let name = "bench";
    std::fs::write(dir.join(format!("{name}.bin")), &bin).expect("write buffer");
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": (0..=PANELS).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "textures": textures,
        "images": images,
        "samplers": [{}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 1.0, "aspectRatio": 16.0 / 9.0, "znear": 0.1}}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len(), "uri": format!("{name}.bin")}],
    });
    let path = dir.join(format!("{name}.gltf"));
    std::fs::write(&path, serde_json::to_vec(&doc).expect("json")).expect("write glTF");
    path
}

fn scene_load(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("defocus-bench-scene-{}", std::process::id()));
    let path = write_scene(&dir);
    let scene = load_scene_file(&path).expect("the generated scene loads");
    assert_eq!(scene.triangle_count(), PANELS * QUADS_X * QUADS_Y * 2);
    assert_eq!(scene.textures.len(), TEXTURES);
    let camera = scene.defaults.clone().expect("camera").camera;
    let (w, h) = (camera.width_px, camera.height_px);

    let mut group = c.benchmark_group("scene_load");
    group.sample_size(10);
    group.bench_function(format!("load/{SCENE}"), |b| {
        b.iter(|| load_scene_file(&path).expect("load"))
    });
    group.bench_function(format!("pinhole/{SCENE}/{w}x{h}"), |b| {
        b.iter(|| pinhole::render(&scene, &camera, 1, 0, false).expect("render"))
    });
    group.bench_function(format!("load_and_pinhole/{SCENE}/{w}x{h}"), |b| {
        b.iter(|| {
            let scene = load_scene_file(&path).expect("load");
            pinhole::render(&scene, &camera, 1, 0, false).expect("render")
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, scene_load);
criterion_main!(benches);
