//! Built-in scenes, each stressing one aspect of depth of field (see DESIGN.md).
//!
//! | scene | stresses | in focus | other depths | lens |
//! |---|---|---|---|---|
//! | [`railing`] (default) | near-field partial occlusion | chart board at 2.5 m | bars and handrail at 0.5 m, brick wall at 9 m | 50 mm f/2, disc |
//! | [`lights`] | bokeh shape, HDR highlights | card at 1.5 m | 2 lights at 0.72-0.8 m, about 40 lights at 10.4-13.9 m, wall at 14.5 m | 50 mm f/1.8, 6 blades |
//! | [`grass`] | depth complexity, alpha-tested cut-outs | grass at 2 m | about 4800 tufts from 0.35 to 16 m, sky at 60 m | 50 mm f/2, disc |
//! | [`glass`] | semi-transparent surfaces between near and far | chart wall at 4 m | post at 0.6 m, panes at 1.2 and 1.5 m | 50 mm f/2, disc |
//!
//! Every scene is a function of nothing: no file, no clock, randomness only from a seeded
//! SplitMix64, so it is identical on every run. Cameras look down -Z from near the origin (world
//! Y up), at 1280x720 on a 36 mm wide sensor; fine detail (text, grass blades) is in textures,
//! painted in linear light, and every surface extends past the frame by more than its blur.

mod glass;
mod grass;
mod lights;
mod railing;
mod random;
mod shapes;
mod textures;

pub use glass::glass;
pub use grass::grass;
pub use lights::lights;
pub use railing::railing;

use super::{AlphaMode, Material, Mesh, Scene, TextureBinding};
use crate::{Error, Result};

/// Names of the built-in scenes; the first is the default.
pub const NAMES: &[&str] = &["railing", "lights", "grass", "glass"];

/// Builds the built-in scene `name`, with its suggested camera in [`Scene::defaults`].
pub fn load(name: &str) -> Result<Scene> {
    match name {
        "railing" => Ok(railing()),
        "lights" => Ok(lights()),
        "grass" => Ok(grass()),
        "glass" => Ok(glass()),
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
