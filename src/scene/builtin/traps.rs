//! `traps`: the cases that break layered depth-of-field methods, in one frame (modelled on the
//! Cycles `railing` scene of `assets/cycles-scenes/`, with the same camera and sizes).
//!
//! - A railing close to the lens crosses every border of the frame, and one bar stands just
//!   outside it: what lies beyond the frame, within the blur radius, shows in the blurred image
//!   (a method without a guard band loses it).
//! - The chart in focus is made of real geometry, not texture, so its edges are exact: a
//!   turned checkerboard of 4 px cells, a Siemens star and line gratings 1 to 4 px wide at
//!   640x360 show every aliased or softened in-focus edge.
//! - A tinted pane of 40% opacity between the railing and the chart: the chart seen through it
//!   must stay sharp while the pane's edges blur.
//! - Small HDR lights far behind focus on a dark wall make bokeh; one is hidden behind a near
//!   bar in the pinhole view, one mostly behind the rail (only the lens sees them), one is
//!   seen through the pane, and one sits just beside the chart's edge, so its bokeh is cut by
//!   the in-focus edge.
//!
//! Layout (view depths along -Z, metres; world Y up; heights relative to the eye):
//! - camera at (0, 1.2, 0), looking horizontally down -Z; no floor (nothing below is seen);
//! - railing at 0.7 m, dark steel: 12 mm round bars at x = -0.14, -0.06, 0.02 and 0.10 m
//!   (the frame's left edge is at -0.148 m there) from 0.35 m below the eye to 0.25 m above it,
//!   a fifth bar at x = 0.17 m, just outside the frame's right edge (0.148 m) but within its
//!   blur, and 12 mm rails 0.9 m long at 0.07 m below the eye (crossing the lower part of the
//!   frame), 0.3 m below and 0.2 m above it (out of view);
//! - a blue-green pane at 1.8 m, alpha 0.4 ([`AlphaMode::Blend`]), 0.288 x 0.36 m, over the
//!   upper right of the chart (its gratings, the right edge of the star, the top of the last
//!   four colour bars: each is seen both through it and directly) and past the top of the
//!   frame;
//! - chart at 2.5 m (the focus plane), 0.6 x 0.43 m, centred 4 cm right of and 5 mm below the
//!   view axis, white paper on a dark board, printed 0.5 mm in front: a 32 x 32 checkerboard
//!   of 3.3 mm cells (4 px at 1280x720) turned 5 degrees, a 24-spoke Siemens star of radius
//!   6 cm, gratings of five lines 1, 2, 3 and 4 px wide at 640x360 (1.65 mm per pixel) both
//!   vertical and horizontal, eight colour bars across the bottom and a text label at the top;
//! - nine emissive discs of 2.5 cm radius, strength 20 to 50 (white, pale blue, orange), at
//!   11.98 m on a dark checkered wall (30 cm squares) at 12 m, 9.6 x 6 m.
//!
//! Camera: 85 mm on a 36 mm sensor, f/1.4, disc aperture, focus 2.5 m, 1280x720 (the Cycles
//! scene's lens). CoC radius: railing -94 px (the bars are 52 px wide), pane -14 px, chart 0,
//! lights and wall 29 px.

use glam::{Vec2, Vec3};

use super::shapes::{
    push_box, push_card, push_convex_polygon, push_disc, push_shaded_cylinder, Face,
};
use super::textures::{binding, ramp_texture, srgb, text_width, Canvas};
use super::{mesh_for, textured};
use crate::lens::Aperture;
use crate::scene::{AlphaMode, Material, Mesh, Scene, WrapMode};

/// Eye position, metres.
const EYE: Vec3 = Vec3::new(0.0, 1.2, 0.0);
/// Focal length of the default camera, millimetres (the Cycles scene's).
const FOCAL_LENGTH_MM: f32 = 85.0;
/// Sensor width of the default camera, millimetres.
const SENSOR_WIDTH_MM: f32 = 36.0;
/// f-number of the default camera.
const FSTOP: f32 = 1.4;

/// View depth of the railing's axis, metres.
const RAILING_DEPTH_M: f32 = 0.7;
/// Bar and rail radius, metres (12 mm thick).
const BAR_RADIUS_M: f32 = 0.006;
/// X of the bars' axes, metres: four in the frame, the last just outside its right edge.
const BAR_XS_M: [f32; 5] = [-0.14, -0.06, 0.02, 0.10, 0.17];
/// Bottom and top of the bars relative to the eye, metres.
const BAR_SPAN_M: (f32, f32) = (-0.35, 0.25);
/// Height of the rail that crosses the frame, relative to the eye, metres.
const RAIL_Y_M: f32 = -0.07;
/// Heights of the bottom and top rails relative to the eye, metres (out of view).
const OUTER_RAILS_Y_M: [f32; 2] = [-0.3, 0.2];
/// Half the length of the rails, metres.
const RAIL_HALF_LENGTH_M: f32 = 0.45;

/// View depth of the pane, metres.
const PANE_DEPTH_M: f32 = 1.8;
/// Lower left corner of the pane relative to the eye, metres.
const PANE_MIN_M: Vec2 = Vec2::new(0.036, -0.072);
/// Pane width and height, metres.
const PANE_SIZE_M: Vec2 = Vec2::new(0.288, 0.36);
/// Pane opacity.
const PANE_ALPHA: f32 = 0.4;

/// View depth of the chart's paper (the focus distance), metres.
const CHART_DEPTH_M: f32 = 2.5;
/// How far the printed marks stand in front of the paper, metres.
const PRINT_OFFSET_M: f32 = 0.0005;
/// Chart extent relative to the eye: (left, bottom) and (right, top), metres.
const CHART_MIN_M: Vec2 = Vec2::new(-0.26, -0.22);
/// See [`CHART_MIN_M`].
const CHART_MAX_M: Vec2 = Vec2::new(0.34, 0.21);
/// Size of one pixel of a 640 px wide image on the chart, metres.
const PIXEL_640_M: f32 = CHART_DEPTH_M * SENSOR_WIDTH_MM / (FOCAL_LENGTH_MM * 640.0);
/// Checkerboard cell: 4 px of a 1280 px wide image, metres.
const CHECKER_CELL_M: f32 = 2.0 * PIXEL_640_M;
/// Checkerboard cells per side.
const CHECKER_CELLS: usize = 32;
/// Checkerboard turn, degrees counter-clockwise.
const CHECKER_TURN_DEG: f32 = 5.0;
/// Checkerboard centre relative to the eye, metres.
const CHECKER_CENTRE_M: Vec2 = Vec2::new(-0.16, 0.09);
/// Siemens star centre relative to the eye, metres.
const STAR_CENTRE_M: Vec2 = Vec2::new(0.0, 0.09);
/// Siemens star radius, metres.
const STAR_RADIUS_M: f32 = 0.06;
/// Dark spokes of the star.
const STAR_SPOKES: u32 = 24;
/// Left edge of the gratings relative to the eye, metres.
const GRATINGS_LEFT_M: f32 = 0.11;
/// Top of the vertical gratings and of the horizontal ones, relative to the eye, metres.
const GRATINGS_TOPS_M: (f32, f32) = (0.15, 0.095);
/// Height of the vertical gratings, metres.
const GRATINGS_HEIGHT_M: f32 = 0.045;
/// Colour bars: bottom and top relative to the eye, metres.
const BARS_Y_M: (f32, f32) = (-0.17, -0.03);
/// Left edge of the colour bars relative to the eye and the width of one bar, metres.
const BARS_X_M: (f32, f32) = (-0.22, 0.065);
/// The colour bars, left to right (sRGB design colours, 16-235 studio range).
const COLOUR_BARS: [(&str, u32); 8] = [
    ("white", 0xebebeb),
    ("yellow", 0xebeb10),
    ("cyan", 0x10ebeb),
    ("green", 0x10eb10),
    ("magenta", 0xeb10eb),
    ("red", 0xeb1010),
    ("blue", 0x1010eb),
    ("black", 0x101010),
];

/// View depth of the back wall, metres.
const WALL_DEPTH_M: f32 = 12.0;
/// Wall width and height, metres.
const WALL_SIZE_M: Vec2 = Vec2::new(9.6, 6.0);
/// View depth of the lights, metres (just in front of the wall).
const LIGHT_DEPTH_M: f32 = 11.98;
/// Light radius, metres.
const LIGHT_RADIUS_M: f32 = 0.025;

/// A light on the wall: (x, y) relative to the eye in metres, colour (sRGB design colour),
/// emission strength.
type Light = (f32, f32, u32, f32);

const WHITE: u32 = 0xffffff;
const BLUE: u32 = 0xaadaff;
const ORANGE: u32 = 0xffcb95;

/// The lights. At 12 m the chart hides x in [-1.25, 1.63] m and y in [-1.06, 1.01] m, the bars
/// project to x = -2.4, -1.03, 0.34 and 1.71 m (0.21 m wide), the rail to y = -1.2 m, the pane
/// covers x > 0.24 m, y > -0.48 m; the frame is 5.08 x 2.86 m.
const LIGHTS: [Light; 9] = [
    (-2.0, 1.1, WHITE, 30.0),
    (-1.75, 0.3, BLUE, 25.0),
    // Behind the bar at x = -0.14 m: hidden in the pinhole view.
    (-2.4, -0.5, WHITE, 40.0),
    (-0.6, 1.25, ORANGE, 20.0),
    // Mostly behind the rail.
    (0.9, -1.3, WHITE, 50.0),
    // Seen through the pane.
    (1.9, 0.6, BLUE, 30.0),
    // 7 px (at 1280) from the chart's left edge: its bokeh is cut by the edge.
    (-1.3, -0.3, ORANGE, 40.0),
    (2.35, 1.0, WHITE, 35.0),
    (-1.45, -0.85, ORANGE, 25.0),
];

/// The `traps` scene: a railing at 0.7 m crossing the frame's borders, a 40% pane at 1.8 m, a
/// geometric test chart in focus at 2.5 m and HDR lights at 12 m; 85 mm f/1.4, disc aperture.
pub fn traps() -> Scene {
    let mut scene = Scene {
        name: "traps".to_string(),
        ..Scene::default()
    };
    // Near to far, for the benefit of an early depth test.
    add_railing(&mut scene);
    add_pane(&mut scene);
    add_chart(&mut scene);
    add_lights(&mut scene);
    add_wall(&mut scene);

    super::set_default_camera(
        &mut scene,
        EYE,
        CHART_DEPTH_M,
        FSTOP,
        (0.1, 50.0),
        Aperture::Disc,
    );
    // The shared helper sets a 50 mm lens; this scene uses the Cycles scene's 85 mm.
    if let Some(defaults) = scene.defaults.as_mut() {
        defaults.camera.focal_length_mm = FOCAL_LENGTH_MM;
        defaults.camera.sensor_width_mm = SENSOR_WIDTH_MM;
    }
    scene
}

/// A world point at height `y` relative to the eye, `x` to the right, at view depth `depth_m`.
fn at(x: f32, y: f32, depth_m: f32) -> Vec3 {
    Vec3::new(EYE.x + x, EYE.y + y, EYE.z - depth_m)
}

/// A world point printed on the chart, (x, y) relative to the eye.
fn printed(p: Vec2) -> Vec3 {
    at(p.x, p.y, CHART_DEPTH_M - PRINT_OFFSET_M)
}

/// Appends the axis-aligned rectangle from `min` to `max` (relative to the eye) printed on the
/// chart.
fn push_printed_rect(mesh: &mut Mesh, min: Vec2, max: Vec2) {
    let corners = [
        Vec2::new(min.x, max.y),
        Vec2::new(min.x, min.y),
        Vec2::new(max.x, min.y),
        max,
    ];
    push_convex_polygon(mesh, &corners.map(printed));
}

fn add_railing(scene: &mut Scene) {
    // Dark painted steel; the ramp goes from the shadowed side to the highlight.
    let ramp = scene.add_texture(ramp_texture(&[
        srgb(0x0b0a09),
        srgb(0x201c18),
        srgb(0x45403a),
        srgb(0xb8b2aa),
    ]));
    let metal = scene.add_material(textured(
        "railing metal",
        binding(ramp, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    let mesh = mesh_for(scene, metal);
    let shading = (Vec3::new(0.5, 0.7, 0.5).normalize(), Vec3::Z);
    let (bottom, top) = BAR_SPAN_M;
    for x in BAR_XS_M {
        let ends = (at(x, bottom, RAILING_DEPTH_M), at(x, top, RAILING_DEPTH_M));
        push_shaded_cylinder(mesh, ends, BAR_RADIUS_M, 24, shading);
    }
    for y in [OUTER_RAILS_Y_M[0], RAIL_Y_M, OUTER_RAILS_Y_M[1]] {
        let ends = (
            at(-RAIL_HALF_LENGTH_M, y, RAILING_DEPTH_M),
            at(RAIL_HALF_LENGTH_M, y, RAILING_DEPTH_M),
        );
        push_shaded_cylinder(mesh, ends, BAR_RADIUS_M, 24, shading);
    }
}

fn add_pane(scene: &mut Scene) {
    let tint = srgb(0x4f9fbf);
    let glass = scene.add_material(Material {
        name: "tinted pane".to_string(),
        base_color: [tint[0], tint[1], tint[2], PANE_ALPHA],
        alpha_mode: AlphaMode::Blend,
        ..Material::default()
    });
    let top_left = at(PANE_MIN_M.x, PANE_MIN_M.y + PANE_SIZE_M.y, PANE_DEPTH_M);
    push_card(
        mesh_for(scene, glass),
        top_left,
        PANE_SIZE_M.x,
        PANE_SIZE_M.y,
    );
}

fn add_chart(scene: &mut Scene) {
    let paper = srgb(0xf2f0ea);
    let ink = srgb(0x16181d);
    let ink_material = scene.add_material(Material::color("chart ink", ink));
    let mesh = mesh_for(scene, ink_material);
    push_checkerboard(mesh);
    push_siemens_star(mesh);
    push_gratings(mesh);

    let (bottom, top) = BARS_Y_M;
    let (left, width) = BARS_X_M;
    for (i, (name, hex)) in COLOUR_BARS.iter().enumerate() {
        let material =
            scene.add_material(Material::color(&format!("colour bar {name}"), srgb(*hex)));
        let x = left + i as f32 * width;
        push_printed_rect(
            mesh_for(scene, material),
            Vec2::new(x, bottom),
            Vec2::new(x + width, top),
        );
    }

    add_label(scene, paper, ink);

    let paper_material = scene.add_material(Material::color("chart paper", paper));
    let size = CHART_MAX_M - CHART_MIN_M;
    push_card(
        mesh_for(scene, paper_material),
        at(CHART_MIN_M.x, CHART_MAX_M.y, CHART_DEPTH_M),
        size.x,
        size.y,
    );
    // Edges and back of the 2.5 cm thick board behind the paper.
    let board = scene.add_material(Material::color("chart board", srgb(0x34363b)));
    let far = at(CHART_MIN_M.x, CHART_MIN_M.y, CHART_DEPTH_M + 0.025);
    let near = at(CHART_MAX_M.x, CHART_MAX_M.y, CHART_DEPTH_M);
    push_box(
        mesh_for(scene, board),
        far,
        near,
        &[Face::PosX, Face::NegX, Face::PosY, Face::NegY, Face::NegZ],
    );
}

/// A 32 x 32 checkerboard of 4 px cells (at 1280x720) turned by a few degrees, so its edges
/// cross the pixel grid at every phase; its top-left cell is dark.
fn push_checkerboard(mesh: &mut Mesh) {
    let (s, c) = CHECKER_TURN_DEG.to_radians().sin_cos();
    let turn = |p: Vec2| CHECKER_CENTRE_M + Vec2::new(c * p.x - s * p.y, s * p.x + c * p.y);
    let half = 0.5 * CHECKER_CELLS as f32 * CHECKER_CELL_M;
    let cell = CHECKER_CELL_M;
    for row in 0..CHECKER_CELLS {
        for col in (row % 2..CHECKER_CELLS).step_by(2) {
            let x0 = -half + col as f32 * cell;
            let y0 = half - row as f32 * cell;
            let corners = [
                Vec2::new(x0, y0),
                Vec2::new(x0, y0 - cell),
                Vec2::new(x0 + cell, y0 - cell),
                Vec2::new(x0 + cell, y0),
            ];
            push_convex_polygon(mesh, &corners.map(|p| printed(turn(p))));
        }
    }
}

/// A Siemens star: `STAR_SPOKES` dark sectors, each a fan of 6 triangles.
fn push_siemens_star(mesh: &mut Mesh) {
    let sector = std::f32::consts::PI / STAR_SPOKES as f32;
    let arc_steps = 6;
    for k in 0..STAR_SPOKES {
        let start = 2.0 * k as f32 * sector;
        let mut corners = vec![printed(STAR_CENTRE_M)];
        for j in 0..=arc_steps {
            let angle = start + sector * j as f32 / arc_steps as f32;
            let (s, c) = angle.sin_cos();
            corners.push(printed(STAR_CENTRE_M + STAR_RADIUS_M * Vec2::new(c, s)));
        }
        push_convex_polygon(mesh, &corners);
    }
}

/// Line gratings 1, 2, 3 and 4 px wide at 640x360: for each width w, five vertical dark
/// lines w apart (a block 9w wide, 4.5 cm tall) and below it five horizontal ones (a 9w
/// square), blocks 2 cm apart.
fn push_gratings(mesh: &mut Mesh) {
    let (top_v, top_h) = GRATINGS_TOPS_M;
    let mut left = GRATINGS_LEFT_M;
    for w_px in 1..=4 {
        let w = w_px as f32 * PIXEL_640_M;
        for line in 0..5 {
            let offset = 2.0 * line as f32 * w;
            push_printed_rect(
                mesh,
                Vec2::new(left + offset, top_v - GRATINGS_HEIGHT_M),
                Vec2::new(left + offset + w, top_v),
            );
            push_printed_rect(
                mesh,
                Vec2::new(left, top_h - offset - w),
                Vec2::new(left + 9.0 * w, top_h - offset),
            );
        }
        left += 9.0 * w + 0.02;
    }
}

/// The chart's title, a texture of 0.5 mm texels (finer than a pixel at 1280x720).
fn add_label(scene: &mut Scene, paper: [f32; 3], ink: [f32; 3]) {
    let text = "TRAPS  85 MM  F/1.4  FOCUS 2.5 M";
    let (w, h) = (800, 40);
    let mut canvas = Canvas::new(w, h, [paper[0], paper[1], paper[2], 1.0]);
    let scale = 3.0;
    canvas.text(
        (
            0.5 * (w as f32 - text_width(text, scale)),
            0.5 * (h as f32 - 8.0 * scale),
        ),
        scale,
        text,
        ink,
    );
    let texture = scene.add_texture(canvas.into_texture());
    let label = scene.add_material(textured(
        "chart label",
        binding(texture, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    let (label_w, label_h) = (0.4, 0.02);
    let centre_x = 0.5 * (CHART_MIN_M.x + CHART_MAX_M.x);
    push_card(
        mesh_for(scene, label),
        printed(Vec2::new(centre_x - 0.5 * label_w, 0.185)),
        label_w,
        label_h,
    );
}

fn add_lights(scene: &mut Scene) {
    for (x, y, hex, strength) in LIGHTS {
        let name = format!("light {hex:06x} x{strength}");
        let material = match scene.materials.iter().position(|m| m.name == name) {
            Some(i) => i,
            None => scene.add_material(Material::emissive(&name, srgb(hex), strength)),
        };
        push_disc(
            mesh_for(scene, material),
            at(x, y, LIGHT_DEPTH_M),
            (Vec3::X, Vec3::Y),
            LIGHT_RADIUS_M,
            16,
        );
    }
}

fn add_wall(scene: &mut Scene) {
    // One texture repeat is 4 x 4 squares of 30 cm, dark blue-grey.
    let mut canvas = Canvas::new(512, 512, [0.0, 0.0, 0.0, 1.0]);
    canvas.checker((0, 0), (512, 512), 128, srgb(0x3f3f4f), srgb(0x2c2c38));
    let checker = scene.add_texture(canvas.into_texture());
    let repeat_m = 1.2;
    let wall = scene.add_material(textured(
        "dark checker wall",
        binding(checker, WrapMode::Repeat, WALL_SIZE_M / repeat_m),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    push_card(
        mesh_for(scene, wall),
        at(-0.5 * WALL_SIZE_M.x, 0.5 * WALL_SIZE_M.y, WALL_DEPTH_M),
        WALL_SIZE_M.x,
        WALL_SIZE_M.y,
    );
}
