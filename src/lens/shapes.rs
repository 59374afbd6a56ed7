//! Aperture shapes beyond the disc and the polygon (McGraw fig. 10: star, heart, ring), made
//! into image apertures that every method and `reference` take, and the spherical-aberration
//! brightness profile over the aperture.

use std::f32::consts::PI;
use std::sync::Arc;

use glam::Vec2;

use super::{Aperture, ApertureImage};
use crate::image::GrayImage;
use crate::{Error, Result};

/// Resolution in pixels of the images that [`CustomShape::aperture`] generates.
pub const CUSTOM_SHAPE_PX: usize = 256;

/// Checks a spherical aberration value: finite, in [-1, 1].
pub(crate) fn check_aberration(aberration: f32) -> Result<()> {
    if aberration.is_finite() && (-1.0..=1.0).contains(&aberration) {
        Ok(())
    } else {
        Err(Error::invalid(
            "aberration",
            format!("{aberration}: expected a value from -1 (bright centre) to 1 (bright rim)"),
        ))
    }
}

/// Brightness of the aperture at squared unit-aperture radius `r2` for spherical aberration
/// `aberration` (see [`crate::methods::lowrank::KernelSpec::aberration`]).
#[inline]
pub fn aberration_profile(aberration: f32, r2: f32) -> f32 {
    (1.0 + aberration * (2.0 * r2 - 1.0)).max(0.0)
}

/// Shaped bokeh for custom aperture disks (fig. 10), generated procedurally.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CustomShape {
    /// A star with `points` tips on the unit circle (one pointing up) and its inner vertices at
    /// radius `inner_radius` (0 to 1).
    Star {
        /// Number of tips, 3 to 32.
        points: u32,
        /// Radius of the inner vertices in units of the aperture radius, in (0, 1).
        inner_radius: f32,
    },
    /// The heart curve `(x^2 + y^2 - 1)^3 <= x^2 y^3`, lobes up, scaled to fit the unit square.
    Heart,
    /// An annulus between `inner_radius` and 1 (a catadioptric "donut" bokeh).
    Ring {
        /// Inner radius in units of the aperture radius, in [0, 1).
        inner_radius: f32,
    },
}

impl CustomShape {
    /// Parses `star[:POINTS[,INNER]]` (default 5 points, inner radius 0.45), `heart`, or
    /// `ring[:INNER]` (default inner radius 0.6).
    pub fn parse(spec: &str) -> Result<Self> {
        let spec = spec.trim();
        let (name, args) = spec.split_once(':').unwrap_or((spec, ""));
        let nums: Vec<&str> = if args.is_empty() {
            Vec::new()
        } else {
            args.split(',').map(str::trim).collect()
        };
        let num = |i: usize, default: f32| -> Result<f32> {
            match nums.get(i) {
                None => Ok(default),
                Some(t) => t.parse().map_err(|_| {
                    Error::invalid(
                        "custom aperture",
                        format!("'{spec}': '{t}' is not a number"),
                    )
                }),
            }
        };
        let shape = match name {
            "star" if nums.len() <= 2 => {
                let points = num(0, 5.0)?;
                if points.fract() != 0.0 || points < 0.0 {
                    return Err(Error::invalid(
                        "custom aperture",
                        format!("'{spec}': the number of points must be a whole number"),
                    ));
                }
                CustomShape::Star {
                    points: points as u32,
                    inner_radius: num(1, 0.45)?,
                }
            }
            "heart" if nums.is_empty() => CustomShape::Heart,
            "ring" if nums.len() <= 1 => CustomShape::Ring {
                inner_radius: num(0, 0.6)?,
            },
            _ => {
                return Err(Error::invalid(
                    "custom aperture",
                    format!("'{spec}': expected {}", super::aperture::APERTURE_SPECS),
                ))
            }
        };
        shape.validate()?;
        Ok(shape)
    }

    /// Checks the parameters (see the variants).
    pub fn validate(&self) -> Result<()> {
        match *self {
            CustomShape::Star {
                points,
                inner_radius,
            } => {
                if !(3..=32).contains(&points) {
                    return Err(Error::invalid(
                        "custom aperture",
                        format!("star with {points} points: expected 3 to 32"),
                    ));
                }
                if !(inner_radius > 0.0 && inner_radius < 1.0) {
                    return Err(Error::invalid(
                        "custom aperture",
                        format!("star inner radius {inner_radius}: expected a value in (0, 1)"),
                    ));
                }
            }
            CustomShape::Heart => {}
            CustomShape::Ring { inner_radius } => {
                if !(0.0..1.0).contains(&inner_radius) {
                    return Err(Error::invalid(
                        "custom aperture",
                        format!("ring inner radius {inner_radius}: expected a value in [0, 1)"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// True if the unit-aperture point `v` (image axes, x right, y down) is inside the shape.
    pub fn contains(&self, v: Vec2) -> bool {
        match *self {
            CustomShape::Star {
                points,
                inner_radius,
            } => {
                let r = v.length();
                if r > 1.0 {
                    return false;
                }
                if r <= inner_radius * (PI / points as f32).cos() {
                    return true;
                }
                // Angle from the upward tip, on screen (y down), folded into one half-sector.
                let theta = v.x.atan2(-v.y);
                let sector = 2.0 * PI / points as f32;
                let half = sector / 2.0;
                let phi = (theta.rem_euclid(sector) - half).abs();
                // Angle from the nearest tip: 0 at a tip, `half` at an inner vertex.
                let phi = half - phi;
                // The half-sector is the triangle (origin, tip, inner vertex), with the tip at
                // (1, 0) and the inner vertex at angle `half`.
                let tip = Vec2::new(1.0, 0.0);
                let inner = Vec2::new(inner_radius * half.cos(), inner_radius * half.sin());
                let p = Vec2::new(r * phi.cos(), r * phi.sin());
                let e = inner - tip;
                let d = p - tip;
                // Inside when p lies on the origin's side of the edge.
                let o = -tip;
                (e.x * d.y - e.y * d.x) * (e.x * o.y - e.y * o.x) >= 0.0
            }
            CustomShape::Heart => {
                // The curve spans x in [-1.14, 1.14], y in [-1, 1.24] (y up); centre and scale it.
                let x = v.x * 1.25;
                let y = -v.y * 1.25 + 0.12;
                let q = x * x + y * y - 1.0;
                q * q * q <= x * x * y * y * y
            }
            CustomShape::Ring { inner_radius } => {
                let r2 = v.length_squared();
                r2 <= 1.0 && r2 >= inner_radius * inner_radius
            }
        }
    }

    /// The shape as an image aperture of [`CUSTOM_SHAPE_PX`] pixels a side (4x4 samples per
    /// pixel), usable by every method and by `reference`.
    pub fn aperture(&self) -> Result<Aperture> {
        self.validate()?;
        let n = CUSTOM_SHAPE_PX;
        let s = 4;
        let mut data = vec![0.0f32; n * n];
        for j in 0..n {
            for i in 0..n {
                let mut hits = 0u32;
                for ky in 0..s {
                    for kx in 0..s {
                        let x = (i as f32 + (kx as f32 + 0.5) / s as f32) / n as f32 * 2.0 - 1.0;
                        let y = (j as f32 + (ky as f32 + 0.5) / s as f32) / n as f32 * 2.0 - 1.0;
                        hits += u32::from(self.contains(Vec2::new(x, y)));
                    }
                }
                data[j * n + i] = hits as f32 / (s * s) as f32;
            }
        }
        let image = ApertureImage::new(GrayImage::from_vec(n, n, data)?)?;
        Ok(Aperture::Image(Arc::new(image)))
    }
}
