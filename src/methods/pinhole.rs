//! `pinhole`: the scene through the lens centre, no blur. With one sample the pixel centres are
//! sampled (the input every post-process method starts from); with N samples each pixel is
//! supersampled with the same box filter as [`super::reference`].

use crate::lens::Camera;
use crate::scene::Scene;
use crate::Result;

use super::reference::{self, ReferenceSettings};
use super::MethodOutput;

/// Renders the pinhole image with `samples` samples per pixel (1 = pixel centres only).
pub fn render(
    scene: &Scene,
    camera: &Camera,
    samples: usize,
    seed: u64,
    with_depth: bool,
) -> Result<MethodOutput> {
    let settings = ReferenceSettings {
        samples,
        seed,
        use_lens: false,
        with_depth,
        ..ReferenceSettings::default()
    };
    reference::render(scene, camera, &settings, &mut |_, _| {})
}
