//! The shared thin-lens model: camera, circle of confusion, aperture shapes and lens samplers.
//!
//! [`Camera`] holds what the user sets (photographers' units: millimetres for the focal length
//! and the sensor, metres for distances). [`Camera::thin_lens`] validates it and converts it, once,
//! into a [`ThinLens`] that every method uses: focal length in pixels, lens radius in metres, focus
//! distance in metres, and the one signed CoC function [`coc_px`].

mod aperture;
mod camera;
mod sampler;
mod shapes;
mod taps;

pub use aperture::{Aperture, ApertureImage};
pub use camera::{Camera, ThinLens};
pub(crate) use sampler::SAMPLER_SEED_SALT;
pub use sampler::{LensSample, SampleSet, SamplerKind};
pub(crate) use shapes::check_aberration;
pub use shapes::{aberration_profile, CustomShape, CUSTOM_SHAPE_PX};
pub use taps::{Taps, CANDIDATES, MAX_TAPS};

/// Signed circle-of-confusion radius in pixels of a point at view depth `z_m`:
///
/// `C(z) = f_px * E * (1/z_f - 1/z)`
///
/// with `f_px` the focal length in pixels, `E` the lens radius in metres and `z_f` the focus
/// distance in metres. Negative in front of the focal plane, positive behind it, zero on it, and
/// `f_px * E / z_f` in the limit of infinite depth. This is the only CoC formula in defocus
/// (no focus-breathing factor, as Blender Cycles).
#[inline]
pub fn coc_px(f_px: f32, lens_radius_m: f32, focus_m: f32, z_m: f32) -> f32 {
    f_px * lens_radius_m * (1.0 / focus_m - 1.0 / z_m)
}
