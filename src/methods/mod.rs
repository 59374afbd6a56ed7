//! Depth-of-field methods. Each takes the shared [`crate::lens::ThinLens`] and
//! [`crate::lens::Aperture`] and returns an image with per-pass timings.
//!
//! | id | module | input |
//! |---|---|---|
//! | `pinhole` | [`pinhole`] | scene (no blur; optional supersampling) |
//! | `reference` | [`reference`] | scene (ground truth: accumulation over the lens) |
//! | `hammon` | [`hammon`] | colour + depth (post-process blend of blur levels, GPU Gems 3 ch. 28) |
//! | `lowrank` | [`lowrank`] | colour + depth, or colour + CoC map (aperture kernel as a sum of separable filters, McGraw; depth-edge mask with 2D fallback; tilt-shift) |
//! | `gaussian` | [`gaussian`] | colour + depth (baseline: separable Gaussian gather sized by the CoC, after Zhou et al. 2007) |
//! | `poisson` | [`poisson`] | colour + depth (baseline: Poisson-disc gather with depth rejection, after Scheuermann 2004) |

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
