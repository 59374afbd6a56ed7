//! Depth-of-field methods. Each takes the shared [`crate::lens::ThinLens`] and
//! [`crate::lens::Aperture`] and returns an image with per-pass timings. The list of methods,
//! their inputs and one way to run any of them is [`registry`]; shared passes are in
//! [`coc_map`] (and `lens/`, `raster/`).
//!
//! | id | module | input |
//! |---|---|---|
//! | `pinhole` | [`pinhole`] | scene (no blur; optional supersampling) |
//! | `reference` | [`reference`](mod@reference) | scene (ground truth: accumulation over the lens) |
//! | `hammon` | [`hammon`] | colour + depth (post-process blend of blur levels, GPU Gems 3 ch. 28) |
//! | `lowrank` | [`lowrank`] | colour + depth, or colour + CoC map (aperture kernel as a sum of separable filters, McGraw; depth-edge mask with 2D fallback; tilt-shift) |
//! | `gaussian` | [`gaussian`] | colour + depth (baseline: separable Gaussian gather sized by the CoC, after Zhou et al. 2007) |
//! | `poisson` | [`poisson`] | colour + depth (baseline: Poisson-disc gather with depth rejection, after Scheuermann 2004) |
//! | `splat` | [`splat`] | colour + depth, or the scene's fragment lists with `layers` > 1 (tiled DoF splatting, the poster) |
//! | `multilayer` | [`multilayer`] | the scene's per-pixel fragment lists (multi-layer filtering, Selgrad et al. 2015) |
//! | `multiview` | [`multiview`] | the scene's CoC-spaced depth layers (multiview synthesis, Lee et al. 2009) |

pub mod coc_map;
pub mod fill;
pub mod gaussian;
pub mod hammon;
pub mod highlights;
pub mod lowrank;
pub mod multilayer;
pub mod multiview;
pub mod pinhole;
pub mod poisson;
pub mod reference;
pub mod registry;
pub mod splat;

use crate::image::{ColorImage, GrayImage};
use crate::lens::LensEffects;
use crate::timing::Timings;

/// What a method returns.
#[derive(Clone, Debug)]
pub struct MethodOutput {
    /// Linear RGBA image (premultiplied alpha).
    pub image: ColorImage,
    /// View-axis depth in metres at pixel centres of the pinhole view, when the method has it.
    pub depth: Option<GrayImage>,
    /// Per-pass wall-clock timings, named `<method>/<pass>`.
    pub timings: Timings,
    /// Peak bytes of the method's own intermediate storage, where the method tracks it (the
    /// fragment lists and filtered levels of `multilayer`).
    pub memory_bytes: Option<usize>,
}

/// Chromatic aberration by one run per colour channel, as `reference` renders it:
/// `run(c, focus_m, radius_scale)` renders through channel `c`'s lens (0 red, 1 green, 2 blue:
/// its focus distance in metres, and its lens radius as a factor of the ideal lens's, from
/// [`LensEffects::channel_lens`] of a lens focused at `focus_m`). Each colour channel is taken
/// from its own run; alpha and depth are green's, the timings are summed (each pass over the
/// three runs), and the memory is the largest run's.
pub(crate) fn per_channel(
    effects: &LensEffects,
    focus_m: f32,
    mut run: impl FnMut(usize, f32, f32) -> crate::Result<MethodOutput>,
) -> crate::Result<MethodOutput> {
    let mut timings = Timings::default();
    let mut runs = Vec::with_capacity(3);
    for c in 0..3 {
        let (focus_c, scale) = effects.channel_lens(c, focus_m)?;
        let out = run(c, focus_c, scale)?;
        timings.extend(&out.timings);
        runs.push(out);
    }
    let memory_bytes = runs.iter().filter_map(|r| r.memory_bytes).max();
    let green = runs.swap_remove(1);
    let (red, blue) = (&runs[0], &runs[1]);
    let mut image = green.image;
    for ((p, r), b) in image
        .pixels_mut()
        .iter_mut()
        .zip(red.image.pixels())
        .zip(blue.image.pixels())
    {
        p[0] = r[0];
        p[2] = b[2];
    }
    Ok(MethodOutput {
        image,
        depth: green.depth,
        timings,
        memory_bytes,
    })
}

/// [`per_channel`] for a method on a frame: `run(lens)` with each channel's thin lens (its
/// focus distance, its lens radius scaled).
pub(crate) fn per_channel_lens(
    effects: &LensEffects,
    lens: &crate::lens::ThinLens,
    mut run: impl FnMut(&crate::lens::ThinLens) -> crate::Result<MethodOutput>,
) -> crate::Result<MethodOutput> {
    per_channel(effects, lens.focus_m, |_, focus_m, scale| {
        run(&crate::lens::ThinLens {
            focus_m,
            lens_radius_m: lens.lens_radius_m * scale,
            ..*lens
        })
    })
}
