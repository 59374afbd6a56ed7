//! The shared thin-lens model: camera, circle of confusion, aperture shapes and lens samplers.
//!
//! [`Camera`] holds what the user sets (photographers' units: millimetres for the focal length
//! and the sensor, metres for distances). [`Camera::thin_lens`] validates it and converts it, once,
//! into a [`ThinLens`] that every method uses: focal length in pixels, lens radius in metres, focus
//! distance in metres, and the one signed CoC function [`coc_px`].

mod aperture;
mod camera;
mod effects;
mod sampler;
mod shapes;
mod taps;

pub use aperture::{Aperture, ApertureImage, APERTURE_SPECS};
pub use camera::{Camera, ThinLens};
pub use effects::{LensEffects, EFFECT_NAMES, PRESETS};
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
    // `1/z_f - 1/z` as `(z - z_f) / (z_f z)`: one division, which also loses less near focus
    // than the difference of two reciprocals. Written as two reciprocals, the compiler packed
    // them into one four-lane division whose other lanes held whatever the register held, and
    // some builds ran the rasterizer's early depth test several times slower (a slow path on
    // those lanes' values; `multiview/decompose` on `grass` at 1280x720: 1.27 or 1.88 s).
    // Where `z_f z` overflows (`z` infinite or beyond about 3e38 / z_f), `1/z` is below
    // every rounding of `1/z_f`.
    let den = focus_m * z_m;
    let (num, den) = if den.is_infinite() {
        (1.0, focus_m)
    } else {
        (z_m - focus_m, den)
    };
    f_px * lens_radius_m * (num / den)
}

/// The view depth in metres whose CoC is `coc_px` ([`coc_px`] solved for `z`):
/// `z = 1 / (1/z_f - C / (f_px E))`. `+inf` where `coc_px` is at or beyond the CoC of infinite
/// depth, `f_px * E / z_f`, which no finite depth reaches.
#[inline]
pub fn depth_for_coc_px(f_px: f32, lens_radius_m: f32, focus_m: f32, coc_px: f32) -> f32 {
    let inv_z = 1.0 / focus_m - coc_px / (f_px * lens_radius_m);
    if inv_z > 0.0 {
        1.0 / inv_z
    } else {
        f32::INFINITY
    }
}

/// Focal length in pixels with the sensor fit horizontal: `F / sensor_width * width`.
#[inline]
pub fn focal_length_px(focal_length_mm: f32, sensor_width_mm: f32, width_px: usize) -> f32 {
    focal_length_mm / sensor_width_mm * width_px as f32
}

/// Focal length in pixels of a vertical field of view `yfov_rad` over `height_px` rows.
#[inline]
pub fn focal_length_px_from_yfov(yfov_rad: f32, height_px: usize) -> f32 {
    height_px as f32 / (2.0 * (0.5 * yfov_rad).tan())
}

/// Focal length in millimetres that gives `f_px` pixels on a sensor `sensor_width_mm` wide
/// imaged onto `width_px` columns (the inverse of [`focal_length_px`]).
#[inline]
pub fn focal_length_mm_from_px(f_px: f32, sensor_width_mm: f32, width_px: usize) -> f32 {
    sensor_width_mm * f_px / width_px as f32
}

/// Lens radius in metres `E = F / (2 N)` of focal length `F` in millimetres at f-number `N`.
#[inline]
pub fn lens_radius_m(focal_length_mm: f32, fstop: f32) -> f32 {
    focal_length_mm * 1e-3 / (2.0 * fstop)
}

/// The f-number `N = F / (2 E)` of a lens of focal length `F` mm and radius `E` m.
#[inline]
pub fn fstop_from_radius(focal_length_mm: f32, lens_radius_m: f32) -> f32 {
    focal_length_mm * 1e-3 / (2.0 * lens_radius_m)
}
