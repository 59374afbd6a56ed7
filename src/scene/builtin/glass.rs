//! `glass`: semi-transparent surfaces between near and far geometry.
//!
//! Two tinted glass panes ([`AlphaMode::Blend`]) hang between a near red post and a far chart
//! wall, overlapping each other in part; the post crosses the first pane. Each pixel behind a
//! pane sees two or three surfaces at different depths, all of which should blur by their own
//! circle of confusion.
//!
//! Focus is on the far wall, not on the panes: then the chart seen *through* the glass must
//! stay as sharp as the chart beside it, while the panes' frames, smudges and etched label
//! blur. A method that keeps one depth per pixel takes the pane's depth for the whole pixel and
//! wrongly blurs the chart behind it, which is the failure this scene is built to show.
//! (Focused on a pane, the chart behind it would be blurred anyway, hiding that error.)
//!
//! Layout (view depths along -Z, metres; world Y up, floor at y = 0, not in view):
//! - camera at (0, 1.3, 0), looking horizontally down -Z;
//! - red post, 2.5 cm square, at 0.6 m, left of centre, crossing the whole frame height and
//!   the left edge of the first pane;
//! - teal pane at 1.2 m, 0.3 x 0.26 m with a 1 cm aluminium frame, alpha 0.25-0.37 (faint
//!   smudges), over the right half of the poster;
//! - amber pane at 1.5 m, 0.3 x 0.22 m, up and to the right, overlapping the first;
//! - thin stands under both panes;
//! - wall at 4 m (the focus plane): 25 cm blue-grey checker squares, 7 x 4.5 m, with a chart
//!   poster 1.9 x 1.05 m ("THROUGH GLASS", text and a Siemens star) on it; its left half is
//!   seen directly, its right half through one or both panes.
//!
//! Camera: 50 mm on a 36 mm sensor, f/2, disc aperture, focus 4 m, 1280x720. CoC radius: post
//! -31 px, first pane -13 px, second pane -9 px, wall 0.

use glam::{Vec2, Vec3};

use super::shapes::{push_box, push_card, ALL_FACES};
use super::textures::{binding, chart_texture, fbm, smoothstep, srgb, text_width, Canvas, Chart};
use super::{mesh_for, textured};
use crate::lens::Aperture;
use crate::scene::{AlphaMode, Material, Scene, Texture, WrapMode};

/// Eye position, metres.
const EYE: Vec3 = Vec3::new(0.0, 1.3, 0.0);
/// View depth of the wall and poster (the focus distance), metres.
const WALL_DEPTH_M: f32 = 4.0;
/// View depth of the post's axis, metres.
const POST_DEPTH_M: f32 = 0.6;
/// X of the post's axis, metres: it crosses the left edge of the first pane.
const POST_X_M: f32 = -0.057;
/// Width of the square post, metres.
const POST_WIDTH_M: f32 = 0.025;
/// Width of the panes' frames, metres.
const FRAME_WIDTH_M: f32 = 0.01;
/// Texels per metre of the pane textures.
const PANE_TEXELS_PER_M: f32 = 1000.0;

/// A framed glass pane.
struct Pane {
    name: &'static str,
    /// View depth, metres.
    depth_m: f32,
    /// Centre (x, y), metres.
    centre: Vec2,
    /// Width and height, metres.
    size_m: Vec2,
    /// Glass colour (sRGB design colour).
    tint: u32,
    /// Mean opacity of the glass.
    alpha: f32,
    /// Text etched into its lower right corner.
    label: &'static str,
}

const PANES: [Pane; 2] = [
    Pane {
        name: "teal glass",
        depth_m: 1.2,
        centre: Vec2::new(0.04, 1.32),
        size_m: Vec2::new(0.3, 0.26),
        tint: 0x4f9c8f,
        alpha: 0.25,
        label: "PANE AT 1.2 M",
    },
    Pane {
        name: "amber glass",
        depth_m: 1.5,
        centre: Vec2::new(0.26, 1.41),
        size_m: Vec2::new(0.3, 0.22),
        tint: 0xb8721c,
        alpha: 0.3,
        label: "PANE AT 1.5 M",
    },
];

/// The `glass` scene: two tinted panes at 1.2 m and 1.5 m between a red post at 0.6 m and a
/// chart wall at 4 m, focus on the wall; 50 mm f/2, disc aperture.
pub fn glass() -> Scene {
    let mut scene = Scene {
        name: "glass".to_string(),
        ..Scene::default()
    };
    // Near to far, for the benefit of an early depth test.
    add_post(&mut scene);
    for pane in &PANES {
        add_pane(&mut scene, pane);
    }
    add_wall(&mut scene);

    super::set_default_camera(
        &mut scene,
        EYE,
        WALL_DEPTH_M,
        2.0,
        (0.1, 50.0),
        Aperture::Disc,
    );
    scene
}

fn add_wall(scene: &mut Scene) {
    // One texture repeat is 4 x 4 squares of 25 cm.
    let mut canvas = Canvas::new(512, 512, [0.0, 0.0, 0.0, 1.0]);
    canvas.checker((0, 0), (512, 512), 128, srgb(0xd5dae0), srgb(0x5b6e86));
    let checker = scene.add_texture(canvas.into_texture());
    let (wall_w, wall_h) = (7.0, 4.5);
    let wall = scene.add_material(textured(
        "checker wall",
        binding(checker, WrapMode::Repeat, Vec2::new(wall_w, wall_h)),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    // Behind the poster by 1 cm, so the poster's face is exactly at the focus distance.
    push_card(
        mesh_for(scene, wall),
        Vec3::new(-0.5 * wall_w, wall_h - 0.25, -WALL_DEPTH_M - 0.01),
        wall_w,
        wall_h,
    );

    let chart = scene.add_texture(chart_texture(&Chart {
        width: 1280,
        height: 704,
        title: "THROUGH GLASS",
        subtitle: "SHARP BEHIND A BLURRED PANE",
        caption: "Focus 4 m: the panes at 1.2 and 1.5 m and the post at 0.6 m blur.",
        paper: srgb(0xf4f1ea),
        ink: srgb(0x1a1d24),
        accent: srgb(0x1d6e4f),
        star: true,
    }));
    let poster = scene.add_material(textured(
        "chart poster",
        binding(chart, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    let (w, h) = (1.9, 1.05);
    push_card(
        mesh_for(scene, poster),
        Vec3::new(-0.5 * w, 1.35 + 0.5 * h, -WALL_DEPTH_M),
        w,
        h,
    );
}

fn add_post(scene: &mut Scene) {
    let red = scene.add_material(Material::color("red post", srgb(0xb8322a)));
    let (x, half) = (POST_X_M, 0.5 * POST_WIDTH_M);
    push_box(
        mesh_for(scene, red),
        Vec3::new(x - half, 0.0, -POST_DEPTH_M - half),
        Vec3::new(x + half, 3.0, -POST_DEPTH_M + half),
        &ALL_FACES,
    );
}

fn add_pane(scene: &mut Scene, pane: &Pane) {
    let texture = scene.add_texture(pane_texture(pane));
    let material = scene.add_material(textured(
        pane.name,
        binding(texture, WrapMode::ClampToEdge, Vec2::ONE),
        [1.0; 4],
        AlphaMode::Blend,
    ));
    let top_left = Vec3::new(
        pane.centre.x - 0.5 * pane.size_m.x,
        pane.centre.y + 0.5 * pane.size_m.y,
        -pane.depth_m,
    );
    push_card(
        mesh_for(scene, material),
        top_left,
        pane.size_m.x,
        pane.size_m.y,
    );

    // A 1 cm stand from the floor to the middle of the frame's bottom edge.
    let stand = match scene.materials.iter().position(|m| m.name == "pane stand") {
        Some(i) => i,
        None => scene.add_material(Material::color("pane stand", srgb(0x7d838a))),
    };
    let bottom = pane.centre.y - 0.5 * pane.size_m.y;
    push_box(
        mesh_for(scene, stand),
        Vec3::new(pane.centre.x - 0.005, 0.0, -pane.depth_m - 0.015),
        Vec3::new(pane.centre.x + 0.005, bottom + 0.01, -pane.depth_m - 0.005),
        &ALL_FACES,
    );
}

/// The pane's texture: tinted glass whose opacity varies with faint smudges, an opaque
/// aluminium frame, and a frosted label etched in the lower right corner.
fn pane_texture(pane: &Pane) -> Texture {
    let w = (pane.size_m.x * PANE_TEXELS_PER_M).round() as usize;
    let h = (pane.size_m.y * PANE_TEXELS_PER_M).round() as usize;
    let tint = srgb(pane.tint);
    let mut canvas = Canvas::new(w, h, [0.0; 4]);
    let seed = pane.tint as u64;
    for y in 0..h {
        for x in 0..w {
            let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            let smudge = smoothstep(0.55, 0.85, fbm(u, v, 4, 5, seed));
            let alpha = pane.alpha + 0.12 * smudge;
            canvas.set(x, y, [tint[0], tint[1], tint[2], alpha]);
        }
    }
    let frame = (FRAME_WIDTH_M * PANE_TEXELS_PER_M).round() as usize;
    let metal = srgb(0x8d939a);
    canvas.fill_rect(0, 0, w, frame, metal);
    canvas.fill_rect(0, h - frame, w, h, metal);
    canvas.fill_rect(0, 0, frame, h, metal);
    canvas.fill_rect(w - frame, 0, w, h, metal);
    // A 1 px darker line inside the frame reads as its edge.
    let edge = srgb(0x4c5157);
    canvas.fill_rect(frame, frame, w - frame, frame + 1, edge);
    canvas.fill_rect(frame, h - frame - 1, w - frame, h - frame, edge);
    canvas.fill_rect(frame, frame, frame + 1, h - frame, edge);
    canvas.fill_rect(w - frame - 1, frame, w - frame, h - frame, edge);

    let scale = 2.0;
    let label_x = w as f32 - frame as f32 - 10.0 - text_width(pane.label, scale);
    let label_y = h as f32 - frame as f32 - 10.0 - 8.0 * scale;
    canvas.text_rgba(
        (label_x, label_y),
        scale,
        pane.label,
        [0.95, 0.97, 0.98, 0.7],
    );
    canvas.into_texture()
}
