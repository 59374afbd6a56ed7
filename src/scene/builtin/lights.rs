//! `lights`: bokeh shape and HDR highlights.
//!
//! Small, very bright emissive bulbs far behind the focus plane each blur into a copy of the
//! aperture (a hexagon here) whose brightness only stays right if HDR values are kept through
//! the blur; overlapping bokeh add up. Two bulbs in front of the focus plane show near-field
//! bokeh, which a real lens turns by 180 degrees (a 6-blade hexagon is symmetric under that
//! turn, so they match the far ones in shape; a 5-blade aperture shows the turn). A sharp card
//! at the focus distance makes the focus plane obvious, and partly hides the lowest string.
//!
//! Layout (view depths along -Z, metres; world Y up, floor at y = 0):
//! - camera at (0, 1.4, 0), looking horizontally down -Z;
//! - two bulbs of 4 mm at 0.72 m and 0.8 m, right of centre (near-field bokeh);
//! - a test card 0.3 x 0.2 m at 1.5 m (the focus plane), left of centre, on a thin post;
//! - three strings of bulbs sagging across the frame: 2.4 cm warm white at 10.5 m, 3 cm red,
//!   green, blue and amber at 12.5 m, and smaller (2 cm) but brighter white, warm and cold
//!   bulbs low at 13.8 m, each bulb up to 10 cm nearer or farther; about 40 in view, emission
//!   strengths 40 to 200 times a unit colour (30 for the near bulbs);
//! - a dark brick wall at 14.5 m and a dark tiled floor.
//!
//! Camera: 50 mm on a 36 mm sensor, f/1.8, 6-blade aperture (vertices up and down), focus
//! 1.5 m, 1280x720. Far bokeh are about 29 px across (CoC radius 14.1-14.7 px), the near ones
//! 29 and 36 px.

use glam::{Vec2, Vec3};

use super::random::SplitMix64;
use super::shapes::{push_box, push_card, push_disc, Face, ALL_FACES};
use super::textures::{binding, chart_texture, srgb, Chart};
use super::{mesh_for, textured};
use crate::lens::Aperture;
use crate::scene::{AlphaMode, Material, Scene, WrapMode};

/// Eye position, metres.
const EYE: Vec3 = Vec3::new(0.0, 1.4, 0.0);
/// View depth of the card (the focus distance), metres.
const CARD_DEPTH_M: f32 = 1.5;
/// Card width and height, metres.
const CARD_SIZE_M: Vec2 = Vec2::new(0.3, 0.2);
/// Centre of the card, metres.
const CARD_CENTRE: Vec2 = Vec2::new(-0.22, 1.32);
/// View depth of the back wall, metres.
const WALL_DEPTH_M: f32 = 14.5;

/// A string of bulbs hanging between two anchors.
struct LightString {
    /// View depth, metres.
    depth_m: f32,
    /// Horizontal extent, metres.
    x_range_m: (f32, f32),
    /// Height of the two anchors, metres.
    anchor_y_m: f32,
    /// How far the middle hangs below the anchors, metres.
    sag_m: f32,
    /// Distance between bulbs along x, metres.
    spacing_m: f32,
    /// Bulb radius, metres.
    radius_m: f32,
    /// Emission colours (sRGB design colours), used in turn.
    colours: &'static [u32],
    /// Emission strengths, used in turn (cycled at a different rate from the colours).
    strengths: &'static [f32],
}

const STRINGS: [LightString; 3] = [
    LightString {
        depth_m: 10.5,
        x_range_m: (-4.5, 4.5),
        anchor_y_m: 3.9,
        sag_m: 1.3,
        spacing_m: 0.7,
        radius_m: 0.012,
        colours: &[0xffd9a8],
        strengths: &[60.0, 45.0, 80.0],
    },
    LightString {
        depth_m: 12.5,
        x_range_m: (-6.0, 6.0),
        anchor_y_m: 3.3,
        sag_m: 1.25,
        spacing_m: 0.8,
        radius_m: 0.015,
        colours: &[0xff3b2a, 0x3cff5a, 0x4a78ff, 0xffaa2a],
        strengths: &[40.0, 70.0, 55.0],
    },
    LightString {
        depth_m: 13.8,
        x_range_m: (-6.5, 6.5),
        anchor_y_m: 2.3,
        sag_m: 0.8,
        spacing_m: 0.75,
        radius_m: 0.01,
        colours: &[0xfff1d6, 0xffc37a, 0x9fd0ff],
        strengths: &[200.0, 120.0, 160.0],
    },
];

/// The `lights` scene: bright emissive bulbs far behind (10.4-13.9 m) and slightly in front
/// (0.72-0.8 m) of a card in focus at 1.5 m; 50 mm f/1.8, 6-blade aperture.
pub fn lights() -> Scene {
    let mut scene = Scene {
        name: "lights".to_string(),
        ..Scene::default()
    };
    // Near to far (the far lights before the wall they hang on), for an early depth test.
    add_card(&mut scene);
    add_lights(&mut scene);
    add_room(&mut scene);

    super::set_default_camera(
        &mut scene,
        EYE,
        CARD_DEPTH_M,
        1.8,
        (0.1, 60.0),
        Aperture::Polygon {
            blades: 6,
            rotation_rad: 0.0,
            blade_radius: None,
        },
    );
    scene
}

fn add_room(scene: &mut Scene) {
    // Dark soot-stained bricks and dark tiles of 0.75 m.
    super::add_room(
        scene,
        &super::Room {
            wall_name: "dark brick wall",
            bricks: (0x3a2a24, 0x262524, 21),
            wall_size_m: (24.0, 9.0),
            floor_name: "dark floor",
            tiles: (0x2e2d2b, 0x242321, 0x121212, 22),
            floor_width_m: 24.0,
            tile_repeat_m: 3.0,
            wall_depth_m: WALL_DEPTH_M,
        },
    );
}

fn add_card(scene: &mut Scene) {
    let chart = scene.add_texture(chart_texture(&Chart {
        width: 600,
        height: 400,
        title: "BOKEH",
        subtitle: "6 blades  f/1.8",
        caption: "50 mm lens, focus 1.5 m",
        paper: srgb(0xe9e4d8),
        ink: srgb(0x17191f),
        accent: srgb(0x1f5fbf),
        star: true,
    }));
    let face = scene.add_material(textured(
        "test card",
        binding(chart, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    let (w, h) = (CARD_SIZE_M.x, CARD_SIZE_M.y);
    let top_left = Vec3::new(
        CARD_CENTRE.x - 0.5 * w,
        CARD_CENTRE.y + 0.5 * h,
        -CARD_DEPTH_M,
    );
    push_card(mesh_for(scene, face), top_left, w, h);

    let stand = scene.add_material(Material::color("card stand", srgb(0x2a2b2e)));
    let mesh = mesh_for(scene, stand);
    let bottom = CARD_CENTRE.y - 0.5 * h;
    push_box(
        mesh,
        Vec3::new(top_left.x, bottom, -CARD_DEPTH_M - 0.006),
        Vec3::new(top_left.x + w, top_left.y, -CARD_DEPTH_M),
        &[Face::PosX, Face::NegX, Face::PosY, Face::NegY, Face::NegZ],
    );
    push_box(
        mesh,
        Vec3::new(CARD_CENTRE.x - 0.006, 0.0, -CARD_DEPTH_M - 0.018),
        Vec3::new(CARD_CENTRE.x + 0.006, bottom + 0.05, -CARD_DEPTH_M - 0.006),
        &ALL_FACES,
    );
}

/// An emissive material per (colour, strength) pair, created on first use.
fn light_material(scene: &mut Scene, rgb_hex: u32, strength: f32) -> usize {
    let name = format!("light {rgb_hex:06x} x{strength}");
    match scene.materials.iter().position(|m| m.name == name) {
        Some(i) => i,
        None => scene.add_material(Material::emissive(&name, srgb(rgb_hex), strength)),
    }
}

/// A bulb facing the camera (+Z).
fn add_bulb(scene: &mut Scene, centre: Vec3, radius_m: f32, rgb_hex: u32, strength: f32) {
    let material = light_material(scene, rgb_hex, strength);
    push_disc(
        mesh_for(scene, material),
        centre,
        (Vec3::X, Vec3::Y),
        radius_m,
        12,
    );
}

fn add_lights(scene: &mut Scene) {
    let mut rng = SplitMix64::new(0x11_6475);
    for string in &STRINGS {
        let (x0, x1) = string.x_range_m;
        let mid = 0.5 * (x0 + x1);
        let half = 0.5 * (x1 - x0);
        let count = ((x1 - x0) / string.spacing_m).round() as usize;
        for i in 0..=count {
            // A parabola is close enough to the catenary of a light string.
            let x = x0 + i as f32 * string.spacing_m + rng.range(-0.06, 0.06);
            let t = (x - mid) / half;
            let y = string.anchor_y_m - string.sag_m * (1.0 - t * t) + rng.range(-0.03, 0.0);
            let colour = string.colours[i % string.colours.len()];
            let strength = string.strengths[(i / 2) % string.strengths.len()];
            let centre = Vec3::new(x, y, -string.depth_m + rng.range(-0.1, 0.1));
            add_bulb(scene, centre, string.radius_m, colour, strength);
        }
    }

    // Two bulbs in front of the focus plane, right of the card: near-field bokeh.
    add_bulb(scene, Vec3::new(0.21, 1.49, -0.72), 0.002, 0xffd9a8, 30.0);
    add_bulb(scene, Vec3::new(0.17, 1.33, -0.8), 0.002, 0x8fc0ff, 30.0);
}
