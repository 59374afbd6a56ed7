//! `railing`: near-field partial occlusion (Selgrad et al. fig. 1; Lee et al. fig. 8).
//!
//! Thin dark bars stand close to the lens, far out of focus, in front of a sharp chart: a
//! correct renderer shows the chart *through* the blurred bars (each bar's blur is wider than
//! the bar, so it never fully hides what is behind), while a method that only knows the nearest
//! surface per pixel cannot reconstruct the hidden chart and leaves halos or holes.
//!
//! Layout (view depths along -Z, metres; world Y up, floor at y = 0):
//! - camera at (0, 1.2, 0), looking horizontally down -Z;
//! - railing at 0.5 m: round bars 1.5 cm thick every 10 cm (four cross the frame, two of them
//!   the board, one its left edge), a 2 cm handrail at y = 1.165 crossing the lower part of
//!   the board, and top and bottom rails outside the frame;
//! - board at 2.5 m (the focus plane), 1.25 x 0.75 m centred on the view axis (about 70% of the
//!   frame width): a focus chart with the title "DEFOCUS", a line of medium text, a
//!   checkerboard of 5 cm squares, a Siemens star and a line of small text; it stands on two
//!   legs;
//! - floor of 0.6 m stone tiles, visible below the board from about 6 m;
//! - brick wall at 9 m, 15 x 6 m.
//!
//! Camera: 50 mm on a 36 mm sensor, f/2, disc aperture, focus 2.5 m, 1280x720. Then the bars'
//! CoC radius is about 36 px (the bars are 53 px wide), the wall's 6.4 px.

use glam::{Vec2, Vec3};

use super::shapes::{push_box, push_card, push_shaded_cylinder, Face, ALL_FACES};
use super::textures::{binding, chart_texture, ramp_texture, srgb, Chart};
use super::{mesh_for, textured};
use crate::lens::Aperture;
use crate::scene::{AlphaMode, Material, Scene, WrapMode};

/// Eye position, metres.
const EYE: Vec3 = Vec3::new(0.0, 1.2, 0.0);
/// View depth of the railing's axis, metres.
const RAILING_DEPTH_M: f32 = 0.5;
/// Bar radius, metres.
const BAR_RADIUS_M: f32 = 0.0075;
/// Distance between bar axes, metres.
const BAR_SPACING_M: f32 = 0.10;
/// X of the bar nearest the view axis, metres (off-centre, so no bar hides the middle).
const BAR_OFFSET_M: f32 = -0.03;
/// Height of the handrail axis, metres: it crosses the lower rows of the board's
/// checkerboard and star.
const HANDRAIL_Y_M: f32 = 1.165;
/// Handrail radius, metres.
const HANDRAIL_RADIUS_M: f32 = 0.01;
/// View depth of the board's front face (the focus distance), metres.
const BOARD_DEPTH_M: f32 = 2.5;
/// Board width and height, metres.
const BOARD_SIZE_M: Vec2 = Vec2::new(1.25, 0.75);
/// View depth of the back wall, metres.
const WALL_DEPTH_M: f32 = 9.0;

/// The `railing` scene (the default): thin bars at 0.5 m far out of focus in front of a sharp
/// chart board at 2.5 m and a brick wall at 9 m; 50 mm f/2, disc aperture.
pub fn railing() -> Scene {
    let mut scene = Scene {
        name: "railing".to_string(),
        ..Scene::default()
    };
    // Near to far, for the benefit of an early depth test.
    add_railing(&mut scene);
    add_board(&mut scene);
    add_wall_and_floor(&mut scene);

    super::set_default_camera(
        &mut scene,
        EYE,
        BOARD_DEPTH_M,
        2.0,
        (0.1, 50.0),
        Aperture::Disc,
    );
    scene
}

fn add_wall_and_floor(scene: &mut Scene) {
    // Red bricks and stone tiles of 0.6 m.
    super::add_room(
        scene,
        &super::Room {
            wall_name: "brick wall",
            bricks: (0x8a4a36, 0xb3aa9d, 11),
            wall_size_m: (15.0, 6.0),
            floor_name: "stone floor",
            tiles: (0x8f8b84, 0x74716b, 0x45423e, 12),
            floor_width_m: 16.0,
            tile_repeat_m: 2.4,
            wall_depth_m: WALL_DEPTH_M,
        },
    );
}

fn add_board(scene: &mut Scene) {
    let paper = srgb(0xf2eee4);
    let ink = srgb(0x1c1f26);
    let chart = scene.add_texture(chart_texture(&Chart {
        width: 1000,
        height: 600,
        title: "DEFOCUS",
        subtitle: "NEAR-FIELD PARTIAL OCCLUSION",
        caption: "The quick brown fox jumps over the lazy dog. 0123456789",
        paper,
        ink,
        accent: srgb(0xc0321e),
        star: true,
    }));
    let face = scene.add_material(textured(
        "chart board",
        binding(chart, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    let (w, h) = (BOARD_SIZE_M.x, BOARD_SIZE_M.y);
    let top_left = Vec3::new(-0.5 * w, EYE.y + 0.5 * h, -BOARD_DEPTH_M);
    push_card(mesh_for(scene, face), top_left, w, h);

    // Edges and back of the 2.5 cm thick board, and its two legs, in dark painted wood.
    let frame = scene.add_material(Material::color("board frame", srgb(0x34363b)));
    let mesh = mesh_for(scene, frame);
    let bottom = EYE.y - 0.5 * h;
    push_box(
        mesh,
        Vec3::new(-0.5 * w, bottom, -BOARD_DEPTH_M - 0.025),
        Vec3::new(0.5 * w, bottom + h, -BOARD_DEPTH_M),
        &[Face::PosX, Face::NegX, Face::PosY, Face::NegY, Face::NegZ],
    );
    for x in [-0.45, 0.45] {
        push_box(
            mesh,
            Vec3::new(x - 0.02, 0.0, -BOARD_DEPTH_M - 0.065),
            Vec3::new(x + 0.02, bottom, -BOARD_DEPTH_M - 0.025),
            &ALL_FACES,
        );
    }
}

fn add_railing(scene: &mut Scene) {
    // Dark painted steel; the ramp goes from the shadowed side to the highlight.
    let ramp = scene.add_texture(ramp_texture(&[
        srgb(0x0d0f12),
        srgb(0x262a30),
        srgb(0x4c535c),
        srgb(0xc4ccd4),
    ]));
    let metal = scene.add_material(textured(
        "railing metal",
        binding(ramp, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    let mesh = mesh_for(scene, metal);
    let light = Vec3::new(-0.4, 0.8, 0.45).normalize();
    let shading = (light, Vec3::Z);
    let z = -RAILING_DEPTH_M;
    let (bottom_rail, top_rail) = (0.1, 1.45);
    for k in -4..=4 {
        let x = BAR_OFFSET_M + k as f32 * BAR_SPACING_M;
        let ends = (Vec3::new(x, 0.0, z), Vec3::new(x, 1.5, z));
        push_shaded_cylinder(mesh, ends, BAR_RADIUS_M, 24, shading);
    }
    for y in [bottom_rail, HANDRAIL_Y_M, top_rail] {
        let ends = (Vec3::new(-0.6, y, z), Vec3::new(0.6, y, z));
        push_shaded_cylinder(mesh, ends, HANDRAIL_RADIUS_M, 24, shading);
    }
}
