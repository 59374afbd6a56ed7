//! Built-in scenes, each stressing one aspect of depth of field (see DESIGN.md).
//!
//! | scene | stresses | in focus | other depths | lens |
//! |---|---|---|---|---|
//! | [`railing`] (default) | near-field partial occlusion | chart board at 2.5 m | bars and handrail at 0.5 m, brick wall at 9 m | 50 mm f/2, disc |
//! | [`lights`] | bokeh shape, HDR highlights | card at 1.5 m | 2 lights at 0.72-0.8 m, about 40 lights at 10.4-13.9 m, wall at 14.5 m | 50 mm f/1.8, 6 blades |
//! | [`grass`] | depth complexity, alpha-tested cut-outs | grass at 2 m | about 4800 tufts from 0.35 to 16 m, sky at 60 m | 50 mm f/2, disc |
//! | [`glass`] | semi-transparent surfaces between near and far | chart wall at 4 m | post at 0.6 m, panes at 1.2 and 1.5 m | 50 mm f/2, disc |
//! | [`traps`] | what breaks layered methods: near bars crossing the frame border, a 40% pane, an aliasing-prone geometric chart, HDR bokeh | geometric chart at 2.5 m | railing at 0.7 m, pane at 1.8 m, 9 lights at 11.98 m, wall at 12 m | 85 mm f/1.4, disc |
//!
//! Every scene is a function of nothing: no file, no clock, randomness only from a seeded
//! SplitMix64, so it is identical on every run. Cameras look down -Z from near the origin (world
//! Y up), at 1280x720 on a 36 mm wide sensor; fine detail (text, grass blades) is in textures,
//! painted in linear light (`traps` draws its chart's marks as geometry, so their edges are
//! exact), and every surface extends past the frame by more than its blur.

mod glass;
mod grass;
mod lights;
mod railing;
mod random;
mod shapes;
mod textures;
mod traps;

pub use glass::glass;
pub use grass::grass;
pub use lights::lights;
pub use railing::railing;
pub use traps::traps;

use super::{AlphaMode, Material, Mesh, Scene, TextureBinding};
use crate::{Error, Result};

/// Names of the built-in scenes; the first is the default.
pub const NAMES: &[&str] = &["railing", "lights", "grass", "glass", "traps"];

/// Builds the built-in scene `name`, with its suggested camera in [`Scene::defaults`].
pub fn load(name: &str) -> Result<Scene> {
    match name {
        "railing" => Ok(railing()),
        "lights" => Ok(lights()),
        "grass" => Ok(grass()),
        "glass" => Ok(glass()),
        "traps" => Ok(traps()),
        _ => Err(Error::Unknown {
            kind: "scene",
            name: name.to_string(),
            expected: NAMES.join(", "),
        }),
    }
}

/// A double-sided material whose base colour is `texture` times `tint` (linear RGBA).
fn textured(
    name: &str,
    texture: TextureBinding,
    tint: [f32; 4],
    alpha_mode: AlphaMode,
) -> Material {
    Material {
        name: name.to_string(),
        base_color: tint,
        base_color_texture: Some(texture),
        alpha_mode,
        ..Material::default()
    }
}

/// The scene's mesh for `material`, created empty on first use, so each material gets one
/// mesh.
fn mesh_for(scene: &mut Scene, material: usize) -> &mut Mesh {
    let index = match scene.meshes.iter().position(|m| m.material == material) {
        Some(i) => i,
        None => {
            scene.meshes.push(Mesh {
                material,
                ..Mesh::default()
            });
            scene.meshes.len() - 1
        }
    };
    &mut scene.meshes[index]
}

/// The default camera of a built-in scene: at `eye_m` looking down -Z at a point `focus_m`
/// ahead, focused there, 50 mm on a 36 mm sensor at `fstop`, 1280x720, clipping `near_m` to
/// `far_m`; stored in the scene's defaults with `aperture`.
fn set_default_camera(
    scene: &mut Scene,
    eye_m: glam::Vec3,
    focus_m: f32,
    fstop: f32,
    (near_m, far_m): (f32, f32),
    aperture: crate::lens::Aperture,
) {
    let mut camera =
        crate::lens::Camera::look_at(eye_m, eye_m - glam::Vec3::Z * focus_m, glam::Vec3::Y);
    camera.focal_length_mm = 50.0;
    camera.sensor_width_mm = 36.0;
    camera.fstop = fstop;
    camera.focus_m = focus_m;
    camera.near_m = near_m;
    camera.far_m = far_m;
    camera.width_px = 1280;
    camera.height_px = 720;
    scene.defaults = Some(super::SceneDefaults { camera, aperture });
}

/// A brick wall and a tiled floor running to it: the back of `railing` and `lights`.
struct Room {
    /// Name of the wall material.
    wall_name: &'static str,
    /// Brick and mortar colours (sRGB hex) and the texture seed.
    bricks: (u32, u32, u64),
    /// Wall width and height in metres.
    wall_size_m: (f32, f32),
    /// Name of the floor material.
    floor_name: &'static str,
    /// Two tile colours, the grout colour (sRGB hex) and the texture seed.
    tiles: (u32, u32, u32, u64),
    /// Width of the floor in metres.
    floor_width_m: f32,
    /// Size in metres of one repeat of the tile texture (4 x 4 tiles).
    tile_repeat_m: f32,
    /// Distance of the wall from the origin along -Z, in metres.
    wall_depth_m: f32,
}

/// Adds `room` to `scene`. Bricks are 24 x 7.5 cm: one texture repeat is 4 bricks by 16
/// courses, 0.96 x 1.2 m. The floor's far edge comes first, so the texture's top row is away
/// from the camera.
fn add_room(scene: &mut Scene, room: &Room) {
    use textures::{binding, brick_texture, srgb, tile_texture};
    let (brick, mortar, seed) = room.bricks;
    let bricks = scene.add_texture(brick_texture(512, (4, 16), srgb(brick), srgb(mortar), seed));
    let (wall_w, wall_h) = room.wall_size_m;
    let wall = scene.add_material(textured(
        room.wall_name,
        binding(
            bricks,
            super::WrapMode::Repeat,
            glam::Vec2::new(wall_w / 0.96, wall_h / 1.2),
        ),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    shapes::push_card(
        mesh_for(scene, wall),
        glam::Vec3::new(-0.5 * wall_w, wall_h, -room.wall_depth_m),
        wall_w,
        wall_h,
    );
    let (a, b, grout, seed) = room.tiles;
    let tiles = scene.add_texture(tile_texture(512, 4, (srgb(a), srgb(b)), srgb(grout), seed));
    let (floor_w, floor_d) = (room.floor_width_m, room.wall_depth_m + 1.0);
    let floor = scene.add_material(textured(
        room.floor_name,
        binding(
            tiles,
            super::WrapMode::Repeat,
            glam::Vec2::new(floor_w / room.tile_repeat_m, floor_d / room.tile_repeat_m),
        ),
        [1.0; 4],
        AlphaMode::Opaque,
    ));
    mesh_for(scene, floor).push_quad(
        glam::Vec3::new(-0.5 * floor_w, 0.0, -room.wall_depth_m),
        glam::Vec3::X * floor_w,
        glam::Vec3::Z * floor_d,
    );
}
