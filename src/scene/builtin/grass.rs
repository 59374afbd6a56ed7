//! `grass`: high depth complexity with alpha-tested cut-outs (Selgrad et al. fig. 10).
//!
//! A meadow seen from a few centimetres above the ground: thousands of crossed quads, each
//! textured with a tuft of blades (alpha 0 between the blades, [`AlphaMode::Mask`]), overlap
//! at every depth from the lens to the horizon. Almost every pixel sees several surfaces within
//! its circle of confusion, at depths on both sides of the focus plane, with thin cut-out
//! silhouettes against the sky: hard for methods that keep one or a few layers per pixel.
//!
//! Layout (view depths along -Z, metres; world Y up, ground at y = 0):
//! - camera at (0, 0.3, 0), looking horizontally down -Z (the horizon crosses the middle of
//!   the frame);
//! - about 4800 tufts 0.18-0.5 m tall from 0.35 m to 16 m, uniformly over the ground inside
//!   the view (and 0.5 m beyond its sides), each two crossed quads with one of four
//!   procedurally painted blade textures (fresh, deep and yellowish green, dry straw);
//! - 70 small white and yellow flowers on stalks among them, 0.8-12 m;
//! - a ground of soil and moss noise out to 60 m;
//! - a sky backdrop at 60 m with clouds and a blue-green tree line.
//!
//! Camera: 50 mm on a 36 mm sensor, f/2, disc aperture, focus 2 m, 1280x720. The CoC radius
//! reaches -70 px on the nearest blades (0.27 m), is 0 at 2 m, 9.7 px at 16 m and 10.7 px on
//! the backdrop.

use glam::{Vec2, Vec3};

use super::random::SplitMix64;
use super::textures::{binding, fbm, mix, scale, smoothstep, srgb, value_noise, Canvas};
use super::{mesh_for, textured};
use crate::lens::Aperture;
use crate::scene::{AlphaMode, Material, Mesh, Scene, Texture, WrapMode};

/// Eye position, metres.
const EYE: Vec3 = Vec3::new(0.0, 0.3, 0.0);
/// Focus distance, metres.
const FOCUS_M: f32 = 2.0;
/// Nearest and farthest tuft depth, metres.
const TUFT_DEPTHS_M: (f32, f32) = (0.35, 16.0);
/// Tufts per square metre of ground.
const TUFTS_PER_M2: f32 = 45.0;
/// Half the horizontal field of view as a slope (18 mm / 50 mm).
const VIEW_SLOPE: f32 = 0.36;
/// Margin beyond the sides of the view where tufts are still placed, metres.
const SIDE_MARGIN_M: f32 = 0.5;
/// View depth of the sky backdrop, metres.
const SKY_DEPTH_M: f32 = 60.0;
/// Far ends of the depth bands the tufts are grouped in (meshes near to far), metres.
const DEPTH_BANDS_M: [f32; 6] = [0.7, 1.4, 2.8, 5.6, 11.0, f32::INFINITY];
/// Alpha cutoff of the cut-out textures.
const CUTOFF: f32 = 0.5;

/// Colours of one kind of tuft (sRGB design colours).
struct TuftStyle {
    name: &'static str,
    base: u32,
    tip: u32,
    /// Relative frequency.
    weight: f32,
}

const STYLES: [TuftStyle; 4] = [
    TuftStyle {
        name: "fresh",
        base: 0x24461a,
        tip: 0x8db34a,
        weight: 0.4,
    },
    TuftStyle {
        name: "deep",
        base: 0x1c3817,
        tip: 0x5f8f33,
        weight: 0.3,
    },
    TuftStyle {
        name: "yellowish",
        base: 0x3a5420,
        tip: 0xb6c268,
        weight: 0.2,
    },
    TuftStyle {
        name: "dry",
        base: 0x5a5a2d,
        tip: 0xcdb978,
        weight: 0.1,
    },
];

/// The `grass` scene: about 4800 alpha-tested grass tufts from 0.35 m to 16 m seen from 0.3 m
/// above the ground, focus 2 m; 50 mm f/2, disc aperture.
pub fn grass() -> Scene {
    let mut scene = Scene {
        name: "grass".to_string(),
        ..Scene::default()
    };
    // Near to far, for the benefit of an early depth test.
    add_tufts(&mut scene);
    add_flowers(&mut scene);
    add_ground_and_sky(&mut scene);

    super::set_default_camera(&mut scene, EYE, FOCUS_M, 2.0, (0.05, 100.0), Aperture::Disc);
    scene
}

fn add_ground_and_sky(scene: &mut Scene) {
    // Ground: one texture repeat is 2.5 m of soil, moss and clover.
    let ground = scene.add_texture(ground_texture(31));
    let (ground_w, ground_d) = (90.0, SKY_DEPTH_M + 2.0);
    let material = scene.add_material(textured(
        "meadow ground",
        binding(
            ground,
            WrapMode::Repeat,
            Vec2::new(ground_w / 2.5, ground_d / 2.5),
        ),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    mesh_for(scene, material).push_quad(
        Vec3::new(-0.5 * ground_w, 0.0, -SKY_DEPTH_M),
        Vec3::X * ground_w,
        Vec3::Z * ground_d,
    );

    // Sky and tree line, 90 x 18 m, standing on the ground at the end of the field.
    let (sky_w, sky_h) = (90.0, 18.0);
    let sky = scene.add_texture(sky_texture(sky_w, sky_h, 32));
    let material = scene.add_material(textured(
        "sky and trees",
        binding(sky, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    super::shapes::push_card(
        mesh_for(scene, material),
        Vec3::new(-0.5 * sky_w, sky_h, -SKY_DEPTH_M),
        sky_w,
        sky_h,
    );
}

fn add_tufts(scene: &mut Scene) {
    // One material per style and tint: the tint varies the brightness between tufts.
    let tints = [[1.0, 1.0, 1.0, 1.0], [0.82, 0.9, 0.78, 1.0]];
    let mut materials = Vec::new();
    for (i, style) in STYLES.iter().enumerate() {
        let texture = scene.add_texture(tuft_texture(style, 40 + i as u64));
        for (j, tint) in tints.iter().enumerate() {
            let m = scene.add_material(textured(
                &format!("grass tuft {} {j}", style.name),
                binding(texture, WrapMode::ClampToEdge, Vec2::ONE),
                *tint,
                AlphaMode::Mask { cutoff: CUTOFF },
            ));
            materials.push((m, style.weight / tints.len() as f32));
        }
    }

    let (z0, z1) = TUFT_DEPTHS_M;
    let half_width = |z: f32| VIEW_SLOPE * z + SIDE_MARGIN_M;
    // Area of the trapezoid of ground the tufts cover.
    let area = (z1 - z0) * (half_width(z0) + half_width(z1));
    let count = (area * TUFTS_PER_M2).round() as usize;
    let mut rng = SplitMix64::new(0x6752_6173);
    let mut tufts = Vec::with_capacity(count);
    while tufts.len() < count {
        // Uniform over the trapezoid by rejection from its bounding box.
        let z = rng.range(z0, z1);
        let x = rng.range(-half_width(z1), half_width(z1));
        if x.abs() > half_width(z) {
            continue;
        }
        let pick = rng.next_f32();
        let mut acc = 0.0;
        let slot = materials
            .iter()
            .position(|&(_, w)| {
                acc += w;
                pick < acc
            })
            .unwrap_or(materials.len() - 1);
        let height = rng.range(0.18, 0.5);
        let width = height * rng.range(0.6, 0.9);
        let yaw = rng.range(0.0, std::f32::consts::PI);
        tufts.push((z, x, slot, width, height, yaw));
    }

    // Near to far, in depth bands of one mesh per material, so that the rasterizer's early
    // depth test rejects most of the hidden far grass before shading it.
    tufts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut band_start = 0;
    for band_end_m in DEPTH_BANDS_M {
        let band_len = tufts[band_start..].partition_point(|t| t.0 < band_end_m);
        let band = &tufts[band_start..band_start + band_len];
        band_start += band_len;
        for (slot, &(material, _)) in materials.iter().enumerate() {
            let mut mesh = Mesh {
                material,
                ..Mesh::default()
            };
            for &(z, x, _, width, height, yaw) in band.iter().filter(|t| t.2 == slot) {
                push_crossed_quads(&mut mesh, Vec3::new(x, 0.0, -z), width, height, yaw);
            }
            if !mesh.indices.is_empty() {
                scene.meshes.push(mesh);
            }
        }
    }
}

/// Two upright quads crossing at `base` (on the ground), the first turned by `yaw_rad` about
/// Y, the second at right angles to it; the texture's bottom row is at the ground, sunk 1 cm so
/// no gap shows.
fn push_crossed_quads(mesh: &mut Mesh, base: Vec3, width_m: f32, height_m: f32, yaw_rad: f32) {
    for turn in [0.0, std::f32::consts::FRAC_PI_2] {
        let (s, c) = (yaw_rad + turn).sin_cos();
        let across = Vec3::new(c, 0.0, s) * width_m;
        let top_left = base - 0.5 * across + Vec3::Y * (height_m - 0.01);
        mesh.push_quad(top_left, across, Vec3::NEG_Y * height_m);
    }
}

fn add_flowers(scene: &mut Scene) {
    let heads = [
        ("white flower", srgb(0xf3f0e4), 41),
        ("yellow flower", srgb(0xf1c232), 42),
    ];
    let stalk = scene.add_material(Material::color("flower stalk", srgb(0x4d7a2a)));
    let mut head_materials = Vec::new();
    for (name, petal, seed) in heads {
        let texture = scene.add_texture(flower_texture(petal, seed));
        head_materials.push(scene.add_material(textured(
            name,
            binding(texture, WrapMode::ClampToEdge, Vec2::ONE),
            [1.0; 4],
            AlphaMode::Mask { cutoff: CUTOFF },
        )));
    }
    let mut rng = SplitMix64::new(0x466c_6f77);
    for i in 0..70 {
        let z = rng.range(0.8, 12.0);
        let x = rng.range(-1.0, 1.0) * (VIEW_SLOPE * z);
        let height = rng.range(0.2, 0.42);
        let size = rng.range(0.03, 0.05);
        // Face the camera, give or take 30 degrees.
        let yaw = rng.range(-0.5, 0.5);
        let across = Vec3::new(yaw.cos(), 0.0, yaw.sin());
        let centre = Vec3::new(x, height, -z);
        let head = head_materials[i % head_materials.len()];
        mesh_for(scene, head).push_quad(
            centre - 0.5 * size * across + Vec3::Y * 0.5 * size,
            across * size,
            Vec3::NEG_Y * size,
        );
        mesh_for(scene, stalk).push_quad(
            Vec3::new(x, 0.0, -z) - 0.002 * across,
            across * 0.004,
            Vec3::Y * (height - 0.2 * size),
        );
    }
}

/// A tuft of 9 to 13 grass blades on a transparent 256x256 texture: curved, tapering blades
/// rising from the bottom edge, darker at the base, lighter at the tip, one side of each blade
/// lit.
fn tuft_texture(style: &TuftStyle, seed: u64) -> Texture {
    const SIZE: f32 = 256.0;
    let mut canvas = Canvas::new(SIZE as usize, SIZE as usize, [0.0; 4]);
    let mut rng = SplitMix64::new(seed);
    let (base_rgb, tip_rgb) = (srgb(style.base), srgb(style.tip));
    let blades = 9 + rng.below(5);
    for _ in 0..blades {
        let root_x = rng.range(0.3, 0.7) * SIZE;
        let height = rng.range(0.45, 0.98) * SIZE;
        // Horizontal offset of the tip: blades lean outward from the middle of the tuft.
        let lean =
            (root_x / SIZE - 0.5) * rng.range(0.4, 1.0) * SIZE + rng.range(-0.12, 0.12) * SIZE;
        let half_width = rng.range(0.016, 0.03) * SIZE;
        let brightness = rng.range(0.75, 1.15);
        let lit_side = if rng.next_f32() < 0.5 { -1.0 } else { 1.0 };
        let bottom = SIZE;
        let top = bottom - height;
        let (left, right) = (
            root_x.min(root_x + lean) - half_width - 1.0,
            root_x.max(root_x + lean) + half_width + 1.0,
        );
        canvas.paint((left, top), (right, bottom), |px, py| {
            let s = (bottom - py) / height;
            if !(0.0..=1.0).contains(&s) {
                return None;
            }
            // The blade bends more towards its tip.
            let centre = root_x + lean * s * s;
            let w = half_width * (1.0 - s).powf(0.7);
            let d = (px - centre) / w.max(1e-6);
            if d.abs() > 1.0 {
                return None;
            }
            let along = mix(base_rgb, tip_rgb, s.powf(0.8));
            let across = 0.78 + 0.22 * (0.5 + 0.5 * d * lit_side);
            Some(scale(along, brightness * across))
        });
    }
    canvas.bleed_into_transparent();
    canvas.into_texture()
}

/// A flower head on a transparent 64x64 texture: six petals of colour `petal` around an
/// orange centre.
fn flower_texture(petal: [f32; 3], seed: u64) -> Texture {
    const SIZE: f32 = 64.0;
    let mut canvas = Canvas::new(SIZE as usize, SIZE as usize, [0.0; 4]);
    let mut rng = SplitMix64::new(seed);
    let c = 0.5 * SIZE;
    let twist = rng.range(0.0, 1.0);
    for k in 0..6 {
        let angle = (k as f32 + twist) * std::f32::consts::TAU / 6.0;
        let dir = Vec2::new(angle.cos(), angle.sin());
        let shade = rng.range(0.85, 1.0);
        canvas.paint((0.0, 0.0), (SIZE, SIZE), |px, py| {
            let p = Vec2::new(px - c, py - c);
            let along = p.dot(dir) - 0.26 * SIZE;
            let across = p.perp_dot(dir);
            let e = (along / (0.23 * SIZE)).powi(2) + (across / (0.11 * SIZE)).powi(2);
            (e <= 1.0).then_some(scale(petal, shade * (0.85 + 0.15 * (1.0 - e))))
        });
    }
    canvas.disc((c, c), 0.12 * SIZE, srgb(0xd9891c));
    canvas.bleed_into_transparent();
    canvas.into_texture()
}

/// Ground of soil, moss and clover as tileable noise, 256x256.
fn ground_texture(seed: u64) -> Texture {
    const SIZE: usize = 256;
    let (soil, moss, clover) = (srgb(0x4a3b29), srgb(0x3b5723), srgb(0x557a2e));
    let mut canvas = Canvas::new(SIZE, SIZE, [0.0, 0.0, 0.0, 1.0]);
    for y in 0..SIZE {
        for x in 0..SIZE {
            let (u, v) = (
                (x as f32 + 0.5) / SIZE as f32,
                (y as f32 + 0.5) / SIZE as f32,
            );
            let cover = smoothstep(0.35, 0.65, fbm(u, v, 4, 4, seed));
            let patch = smoothstep(0.55, 0.75, fbm(u, v, 8, 3, seed + 10));
            let grain = value_noise(u, v, 128, seed + 20);
            let green = mix(moss, clover, patch);
            let c = scale(mix(soil, green, cover), 0.8 + 0.4 * grain);
            canvas.set(x, y, [c[0], c[1], c[2], 1.0]);
        }
    }
    canvas.into_texture()
}

/// Sky with clouds over a tree line, for a backdrop `width_m` x `height_m` standing on the
/// ground: pale at the horizon, deeper blue above; trees 3-9 m tall, hazy blue-green.
fn sky_texture(width_m: f32, height_m: f32, seed: u64) -> Texture {
    let (w, h) = (1024usize, 256usize);
    let (horizon, zenith) = (srgb(0xdce8f0), srgb(0x6b9bd0));
    let (cloud, trees_near, trees_far) = (srgb(0xf7f8fa), srgb(0x2c4636), srgb(0x5d7a78));
    let mut canvas = Canvas::new(w, h, [0.0, 0.0, 0.0, 1.0]);
    let texel_m = height_m / h as f32;
    for y in 0..h {
        for x in 0..w {
            let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            let height = (1.0 - v) * height_m;
            // Back row of trees, lighter with haze, then the front row; their outlines are
            // anti-aliased by the distance to them in texels.
            let far_line = 4.0 + 4.0 * fbm(u * 0.5, 0.3, 24, 4, seed);
            let near_line = 2.5 + 6.5 * smoothstep(0.3, 0.8, fbm(u * 0.5, 0.7, 16, 5, seed + 1));
            let leaves = fbm(u * width_m / 16.0, v * height_m / 16.0, 16, 3, seed + 2);
            let t = smoothstep(0.0, height_m, height).sqrt();
            let density = fbm(u * 2.0, v * 0.5, 4, 5, seed + 3);
            let clouds = smoothstep(0.5, 0.75, density) * smoothstep(6.0, 10.0, height);
            let sky = mix(mix(horizon, zenith, t), cloud, clouds);
            let cover = |line: f32| ((line - height) / texel_m + 0.5).clamp(0.0, 1.0);
            let far = mix(sky, scale(trees_far, 0.85 + 0.3 * leaves), cover(far_line));
            let c = mix(
                far,
                scale(trees_near, 0.75 + 0.5 * leaves),
                cover(near_line),
            );
            canvas.set(x, y, [c[0], c[1], c[2], 1.0]);
        }
    }
    canvas.into_texture()
}
