//! Tilt-shift postprocessing (McGraw section 4, fig. 14): a CoC map painted as a gradient band
//! instead of computed from depth, then the spatially varying low-rank filter
//! ([`super::render_coc`]).
//!
//! The band is the line through the point (`width / 2`, `centre_y * height`) at `angle_deg`
//! counter-clockwise from +x on screen. At perpendicular distance `s` pixels from that line the
//! CoC radius is
//!
//! `C = max_coc_px * clamp((s - width * height / 2) / (ramp * height), 0, 1)`
//!
//! (a step at the band edge when `ramp` is 0): sharp inside the band, growing linearly to the
//! maximum. All radii are positive (far field), so the bokeh shows the aperture as defined.

use rayon::prelude::*;

use crate::image::{check_size, GrayImage};
use crate::methods::coc_map::MAX_COC_LIMIT_PX;
use crate::{Error, Result};

/// A tilt-shift band. Lengths are fractions of the image height.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TiltShift {
    /// Height of the band's centre line where it crosses the vertical through the image centre,
    /// as a fraction of the image height from the top (0 top, 1 bottom). Default 0.5.
    pub centre_y: f32,
    /// Full width of the sharp band, as a fraction of the image height (>= 0). Default 0.15.
    pub width: f32,
    /// Angle of the band in degrees, counter-clockwise from horizontal on screen. Default 0.
    pub angle_deg: f32,
    /// CoC radius in pixels reached at `ramp` beyond the band edge and kept further out
    /// (0 to 512). Default 12.
    pub max_coc_px: f32,
    /// Distance over which the blur grows from 0 at the band edge to `max_coc_px`, as a fraction
    /// of the image height (>= 0; 0 gives a hard step). Default 0.3.
    pub ramp: f32,
}

impl Default for TiltShift {
    fn default() -> Self {
        Self {
            centre_y: 0.5,
            width: 0.15,
            angle_deg: 0.0,
            max_coc_px: 12.0,
            ramp: 0.3,
        }
    }
}

impl TiltShift {
    /// Checks every field (see their documentation).
    pub fn validate(&self) -> Result<()> {
        let finite = |name: &'static str, v: f32| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(Error::invalid(
                    name,
                    format!("{v}: expected a finite number"),
                ))
            }
        };
        finite("tilt-shift centre", self.centre_y)?;
        finite("tilt-shift angle", self.angle_deg)?;
        if !(self.width.is_finite() && self.width >= 0.0) {
            return Err(Error::invalid(
                "tilt-shift width",
                format!(
                    "{}: expected a fraction of the image height >= 0",
                    self.width
                ),
            ));
        }
        if !(self.ramp.is_finite() && self.ramp >= 0.0) {
            return Err(Error::invalid(
                "tilt-shift ramp",
                format!(
                    "{}: expected a fraction of the image height >= 0",
                    self.ramp
                ),
            ));
        }
        if !(self.max_coc_px.is_finite()
            && self.max_coc_px >= 0.0
            && self.max_coc_px <= MAX_COC_LIMIT_PX)
        {
            return Err(Error::invalid(
                "tilt-shift max CoC",
                format!(
                    "{} px: expected a radius from 0 to {MAX_COC_LIMIT_PX} pixels",
                    self.max_coc_px
                ),
            ));
        }
        Ok(())
    }
}

/// The CoC map (radius in pixels, >= 0) of a `width x height` image for the band `ts`.
pub fn tilt_shift_coc(width: usize, height: usize, ts: &TiltShift) -> Result<GrayImage> {
    tilt_shift_coc_in_frame(width, height, (0, 0), (width, height), ts)
}

/// [`tilt_shift_coc`] for an image that is part of a larger (or smaller) frame, as an OpenEXR
/// data window inside its display window: the image's pixel (0, 0) is the frame's pixel
/// `offset`, and the band is placed and sized by the `frame` (width, height), as it is on the
/// whole picture.
pub fn tilt_shift_coc_in_frame(
    width: usize,
    height: usize,
    offset: (i64, i64),
    frame: (usize, usize),
    ts: &TiltShift,
) -> Result<GrayImage> {
    check_size(width, height)?;
    // The frame is never allocated: any size will do but an empty one.
    if frame.0 == 0 || frame.1 == 0 {
        return Err(Error::invalid(
            "tilt-shift frame",
            format!("{}x{}: expected at least one pixel", frame.0, frame.1),
        ));
    }
    ts.validate()?;
    let h = frame.1 as f32;
    // The frame's centre line, in the image's pixel coordinates.
    let (cx, cy) = (
        frame.0 as f32 * 0.5 - offset.0 as f32,
        ts.centre_y * h - offset.1 as f32,
    );
    let (sin, cos) = ts.angle_deg.to_radians().sin_cos();
    let half_band = 0.5 * ts.width * h;
    let ramp_px = ts.ramp * h;
    let mut out = GrayImage::new(width, height, 0.0);
    out.pixels_mut()
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, c) in row.iter_mut().enumerate() {
                // The line's direction on screen (y down) is (cos, -sin); its normal (sin, cos).
                let s = ((x as f32 + 0.5 - cx) * sin + (y as f32 + 0.5 - cy) * cos).abs();
                let beyond = s - half_band;
                let t = if ramp_px > 0.0 {
                    (beyond / ramp_px).clamp(0.0, 1.0)
                } else {
                    f32::from(u8::from(beyond > 0.0))
                };
                *c = ts.max_coc_px * t;
            }
        });
    Ok(out)
}
