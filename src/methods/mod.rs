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
pub mod gaussian;
pub mod hammon;
pub mod lowrank;
pub mod multilayer;
pub mod multiview;
pub mod pinhole;
pub mod poisson;
pub mod reference;
pub mod registry;
pub mod splat;

use crate::image::{ColorImage, GrayImage};
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
