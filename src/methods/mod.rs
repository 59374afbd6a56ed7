//! Depth-of-field methods. Each takes the shared [`crate::lens::ThinLens`] and
//! [`crate::lens::Aperture`] and returns an image with per-pass timings.
//!
//! | id | module | input |
//! |---|---|---|
//! | `pinhole` | [`pinhole`] | scene (no blur; optional supersampling) |
//! | `reference` | [`reference`] | scene (ground truth: accumulation over the lens) |

pub mod pinhole;
pub mod reference;

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
}
