use glam::{Affine3A, Vec3};

use crate::{Error, Result};

/// A thin-lens camera as the user describes it.
///
/// Camera space is right-handed, looking down -Z with +Y up (as glTF). View depth `z` is the
/// distance along the view axis, `z = -Z_camera`, in metres.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Image width in pixels.
    pub width_px: usize,
    /// Image height in pixels.
    pub height_px: usize,
    /// Rigid transform from world space to camera space.
    pub camera_from_world: Affine3A,
    /// Focal length in millimetres. Sets the lens radius `E = F / (2N)`, and the field of view
    /// unless `yfov_rad` is given.
    pub focal_length_mm: f32,
    /// Sensor width in millimetres (sensor fit horizontal).
    pub sensor_width_mm: f32,
    /// f-number N (dimensionless); the lens radius is `F / (2N)`.
    pub fstop: f32,
    /// Focus distance in metres (view-axis depth of the plane in focus).
    pub focus_m: f32,
    /// Near clipping distance in metres.
    pub near_m: f32,
    /// Far clipping distance in metres.
    pub far_m: f32,
    /// Vertical field of view in radians. When set (e.g. from a glTF camera) it defines the
    /// projection and the focal length only sets the lens radius.
    pub yfov_rad: Option<f32>,
}

/// Longest focal length accepted, in millimetres (the longest photographic lenses are about
/// 5 m; beyond this a value is taken for a unit mistake).
pub const MAX_FOCAL_LENGTH_MM: f32 = 10_000.0;

/// Widest sensor accepted, in millimetres (8x10 inch large format film is 254 mm).
pub const MAX_SENSOR_WIDTH_MM: f32 = 1_000.0;

impl Camera {
    /// A camera at `from` looking at `to` with the given `up` direction, 50 mm on a 36 mm
    /// sensor at f/2.8, focused on `to`, 1280x720.
    pub fn look_at(from: Vec3, to: Vec3, up: Vec3) -> Self {
        Self {
            width_px: 1280,
            height_px: 720,
            camera_from_world: camera_from_world_look_at(from, to, up),
            focal_length_mm: 50.0,
            sensor_width_mm: 36.0,
            fstop: 2.8,
            focus_m: (to - from).length(),
            near_m: 0.05,
            far_m: 1000.0,
            yfov_rad: None,
        }
    }

    /// Validates the parameters and derives the constants every method uses.
    pub fn thin_lens(&self) -> Result<ThinLens> {
        crate::image::check_size(self.width_px, self.height_px)?;
        let finite_pos = |name: &'static str, v: f32, unit: &str| -> Result<()> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(Error::invalid(
                    name,
                    format!("{v} {unit}: expected a finite value greater than 0"),
                ))
            }
        };
        finite_pos("focal length", self.focal_length_mm, "mm")?;
        finite_pos("sensor width", self.sensor_width_mm, "mm")?;
        finite_pos("f-number", self.fstop, "")?;
        finite_pos("focus distance", self.focus_m, "m")?;
        finite_pos("near plane", self.near_m, "m")?;
        finite_pos("far plane", self.far_m, "m")?;
        if self.fstop < 0.1 {
            return Err(Error::invalid(
                "f-number",
                format!(
                    "f/{} is not a physical lens: expected at least f/0.1",
                    self.fstop
                ),
            ));
        }
        for (name, v, lo, hi) in [
            (
                "focal length",
                self.focal_length_mm,
                0.1,
                MAX_FOCAL_LENGTH_MM,
            ),
            (
                "sensor width",
                self.sensor_width_mm,
                0.1,
                MAX_SENSOR_WIDTH_MM,
            ),
        ] {
            if !(lo..=hi).contains(&v) {
                return Err(Error::invalid(
                    name,
                    format!("{v} mm is not a physical camera: expected {lo} to {hi} mm"),
                ));
            }
        }
        if self.focus_m <= self.focal_length_mm * 1e-3 {
            return Err(Error::invalid(
                "focus distance",
                format!(
                    "{} m is not beyond the focal length ({} mm): a lens cannot focus closer \
                     than its focal length",
                    self.focus_m, self.focal_length_mm
                ),
            ));
        }
        if self.far_m <= self.near_m {
            return Err(Error::invalid(
                "far plane",
                format!(
                    "{} m must be beyond the near plane at {} m",
                    self.far_m, self.near_m
                ),
            ));
        }
        if self.focus_m > self.far_m {
            return Err(Error::invalid(
                "focus distance",
                format!(
                    "{} m is behind the far plane at {} m",
                    self.focus_m, self.far_m
                ),
            ));
        }
        if self.focus_m < self.near_m {
            return Err(Error::invalid(
                "focus distance",
                format!(
                    "{} m is in front of the near plane at {} m",
                    self.focus_m, self.near_m
                ),
            ));
        }
        let f_px = match self.yfov_rad {
            Some(yfov) => {
                if !(yfov.is_finite() && yfov > 0.0 && yfov < std::f32::consts::PI) {
                    return Err(Error::invalid(
                        "vertical field of view",
                        format!("{yfov} rad: expected a value in (0, pi)"),
                    ));
                }
                super::focal_length_px_from_yfov(yfov, self.height_px)
            }
            None => {
                super::focal_length_px(self.focal_length_mm, self.sensor_width_mm, self.width_px)
            }
        };
        let lens_radius_m = super::lens_radius_m(self.focal_length_mm, self.fstop);
        Ok(ThinLens {
            width_px: self.width_px,
            height_px: self.height_px,
            f_px,
            lens_radius_m,
            focus_m: self.focus_m,
            near_m: self.near_m,
            far_m: self.far_m,
        })
    }
}

/// World-to-camera transform for a camera at `from` looking at `to` (camera looks down -Z, +Y up).
pub(crate) fn camera_from_world_look_at(from: Vec3, to: Vec3, up: Vec3) -> Affine3A {
    Affine3A::look_at_rh(from, to, up)
}

/// Derived thin-lens constants, computed once from a [`Camera`] and shared by every method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThinLens {
    /// Image width in pixels.
    pub width_px: usize,
    /// Image height in pixels.
    pub height_px: usize,
    /// Focal length in pixels (square pixels: the same horizontally and vertically).
    pub f_px: f32,
    /// Lens (aperture) radius E in metres.
    pub lens_radius_m: f32,
    /// Focus distance z_f in metres.
    pub focus_m: f32,
    /// Near clipping distance in metres.
    pub near_m: f32,
    /// Far clipping distance in metres.
    pub far_m: f32,
}

impl ThinLens {
    /// Signed CoC radius in pixels at view depth `z_m` (see [`super::coc_px`]).
    #[inline]
    pub fn coc_px(&self, z_m: f32) -> f32 {
        super::coc_px(self.f_px, self.lens_radius_m, self.focus_m, z_m)
    }

    /// The view depth in metres whose signed CoC is `coc_px` (see [`super::depth_for_coc_px`]).
    #[inline]
    pub fn depth_for_coc_px(&self, coc_px: f32) -> f32 {
        super::depth_for_coc_px(self.f_px, self.lens_radius_m, self.focus_m, coc_px)
    }

    /// The CoC radius in pixels of a point at infinite depth, the largest far-field blur.
    pub fn coc_at_infinity_px(&self) -> f32 {
        self.f_px * self.lens_radius_m / self.focus_m
    }

    /// Principal point (image centre) in pixels.
    pub fn centre_px(&self) -> (f32, f32) {
        (self.width_px as f32 * 0.5, self.height_px as f32 * 0.5)
    }

    /// Pinhole projection of a camera-space point to raster coordinates (x right, y down).
    /// Returns `None` for points at or behind the lens plane.
    pub fn project(&self, p_camera: Vec3) -> Option<(f32, f32, f32)> {
        let z = -p_camera.z;
        if z <= 0.0 {
            return None;
        }
        let (cx, cy) = self.centre_px();
        Some((
            cx + self.f_px * p_camera.x / z,
            cy - self.f_px * p_camera.y / z,
            z,
        ))
    }

    /// The same lens seeing `guard_px` more pixels on every side of the frame: the frame grows
    /// by `2 guard_px` each way around the same principal point, so pixel `(x, y)` of this
    /// frame is pixel `(x - guard_px, y - guard_px)` of the original.
    pub fn with_guard_band(&self, guard_px: usize) -> Self {
        Self {
            width_px: self.width_px + 2 * guard_px,
            height_px: self.height_px + 2 * guard_px,
            ..*self
        }
    }

    /// The same lens with the aperture closed: a pinhole camera.
    pub fn pinhole(&self) -> Self {
        Self {
            lens_radius_m: 0.0,
            ..*self
        }
    }
}
