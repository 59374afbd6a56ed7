//! Depth of field for a rendered frame: a colour image and its depth pass, blurred through the
//! thin lens. The job behind `defocus blur` and the Python package's `defocus.blur`: both read
//! their inputs (files, arrays), then call [`frame_lens`] for the lens and the view depth, and
//! [`crate::methods::registry::run_frame`] for the method.

use crate::autofocus::{focus_in_depth, FocusPick};
use crate::error::{Error, Result};
use crate::image::io::Placement;
use crate::image::GrayImage;
use crate::lens::{focal_length_px, Camera, ThinLens};

/// What the depth values measure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DepthKind {
    /// Distance along the view axis (Blender's and most renderers' Z pass).
    View,
    /// Distance from the eye along each pixel's ray; converted to view depth.
    Radial,
    /// 1 / view depth, 0 for infinitely far (Nuke's ScanlineRender depth); depth =
    /// --depth-scale / value.
    Inverse,
    /// The signed CoC radius in pixels (negative in front of the focus), as --coc-out writes it
    /// (EXR channel CoC, or PFM), times --depth-scale: the map gives every pixel's blur, and
    /// --focus is not used.
    Coc,
}

/// Where to focus.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FocusChoice {
    /// The depth at the frame's centre (median of a small window).
    Auto,
    /// A distance in metres along the view axis.
    Metres(f32),
    /// The depth at a pixel (column, row from the top left of the frame; for an OpenEXR image,
    /// of its display window), the median of a small window around it.
    Pixel(usize, usize),
}

/// The lens, in the units a photographer gives it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensSpec {
    /// f-number N; the lens radius is focal length / (2 N).
    pub fstop: f32,
    /// Focal length in millimetres.
    pub focal_length_mm: f32,
    /// Sensor width in millimetres (horizontal fit; full frame is 36), spanning the frame.
    pub sensor_width_mm: f32,
}

impl Default for LensSpec {
    fn default() -> Self {
        Self {
            fstop: 2.8,
            focal_length_mm: 50.0,
            sensor_width_mm: 36.0,
        }
    }
}

/// A frame's lens and view depth, ready for the methods.
#[derive(Clone, Debug)]
pub struct FrameLens {
    /// View-axis depth in metres of every pixel.
    pub depth: GrayImage,
    /// The thin lens, its focal length in pixels of the frame.
    pub lens: ThinLens,
    /// Where autofocus picked the focus (with [`FocusChoice::Auto`] or [`FocusChoice::Pixel`]).
    pub focus_pick: Option<FocusPick>,
}

/// The lens and view depth of a frame whose depth pass `depth` (the image's own pixels, of the
/// kind `kind`; for [`DepthKind::Coc`], signed radii in pixels) lies at `frame` in its frame
/// (`Placement::full` for a whole frame). The sensor spans the frame, so the focal length in
/// pixels is the frame's, whatever part of it the image holds. `image` names the image in
/// errors.
pub fn frame_lens(
    depth: GrayImage,
    kind: DepthKind,
    focus: FocusChoice,
    spec: &LensSpec,
    frame: &Placement,
    image: &str,
) -> Result<FrameLens> {
    let (w, h) = (depth.width(), depth.height());
    let camera = |focus_m: f32| Camera {
        width_px: w,
        height_px: h,
        camera_from_world: glam::Affine3A::IDENTITY,
        focal_length_mm: spec.focal_length_mm,
        sensor_width_mm: spec.sensor_width_mm,
        fstop: spec.fstop,
        focus_m,
        near_m: 1e-6,
        far_m: f32::MAX,
        yfov_rad: None,
    };
    // The lens flags are checked before they are used to convert radial depth.
    camera(1.0).thin_lens().map_err(|e| {
        Error::invalid(
            "camera",
            format!("{e} (check --fstop, --focal-length, --sensor-width)"),
        )
    })?;
    let f_px = focal_length_px(
        spec.focal_length_mm,
        spec.sensor_width_mm,
        frame.display_size.0,
    );
    let mut depth = depth;
    if kind == DepthKind::Radial {
        // The principal point is the frame's centre.
        let (ox, oy) = frame.offset();
        let (fw, fh) = frame.display_size;
        let centre = (fw as f64 / 2.0 - ox as f64, fh as f64 / 2.0 - oy as f64);
        crate::image::io::radial_to_view_depth_about(&mut depth, f_px, centre);
    }
    if kind == DepthKind::Coc {
        if focus != FocusChoice::Auto {
            return Err(Error::Option(
                "--focus and --focus-pixel have no meaning with --depth-kind coc: the CoC map \
                 gives every pixel's blur"
                    .to_string(),
            ));
        }
        // A lens focused at 1 m whose CoC at infinity is twice the largest far radius, so that
        // every radius of the map is that of some depth, which the methods turn back into it.
        // Only the CoC function of this lens means anything: it is built directly, not from
        // the lens flags (it may focus closer than any real focal length).
        // The readers refuse such maps, naming their file; a map from elsewhere too, before
        // its largest radius overflows the lens below.
        if let Some(why) = crate::image::io::bad_coc_radii(depth.pixels(), w) {
            return Err(Error::invalid("CoC map", format!("of {image}: {why}")));
        }
        let max_far_px = depth.pixels().iter().fold(1.0f32, |m, &c| m.max(c));
        let lens = ThinLens {
            width_px: w,
            height_px: h,
            f_px,
            lens_radius_m: 2.0 * max_far_px / f_px,
            focus_m: 1.0,
            near_m: 1e-6,
            far_m: f32::MAX,
        };
        let depth = depth.map(|c| lens.depth_for_coc_px(c));
        return Ok(FrameLens {
            depth,
            lens,
            focus_pick: None,
        });
    }
    let (focus_m, focus_pick) = choose_focus(&depth, focus, frame, image)?;
    let lens = camera(focus_m).thin_lens().map_err(|e| {
        Error::invalid(
            "camera",
            format!("{e} (check --focus, --fstop, --focal-length, --sensor-width)"),
        )
    })?;
    Ok(FrameLens {
        depth,
        lens: ThinLens { f_px, ..lens },
        focus_pick,
    })
}

/// The focus distance in metres, and the autofocus pick it came from.
fn choose_focus(
    depth: &GrayImage,
    focus: FocusChoice,
    frame: &Placement,
    image: &str,
) -> Result<(f32, Option<FocusPick>)> {
    let (w, h) = (depth.width(), depth.height());
    match focus {
        FocusChoice::Metres(m) => Ok((m, None)),
        FocusChoice::Pixel(fx, fy) => {
            // The frame's pixel as a pixel of the image.
            let (ox, oy) = frame.offset();
            let (x, y) = (fx as i64 - ox, fy as i64 - oy);
            if !(0..w as i64).contains(&x) || !(0..h as i64).contains(&y) {
                return Err(Error::Option(format!(
                    "--focus-pixel {fx},{fy}: outside the image ({})",
                    describe_placement(image, w, h, frame)
                )));
            }
            let pick = focus_in_depth(depth, x as usize, y as usize).ok_or_else(|| {
                Error::Option(format!(
                    "--focus-pixel {fx},{fy}: no surface around it (only holes or background); give --focus M"
                ))
            })?;
            Ok((pick.depth_m, Some(pick)))
        }
        FocusChoice::Auto => {
            let (cx, cy) = frame.frame_centre_in_image(w, h);
            let pick = focus_in_depth(depth, cx, cy).ok_or_else(|| {
                Error::Option(
                    "--focus auto: the depth image has no surface (only holes or background); give --focus M"
                        .to_string(),
                )
            })?;
            Ok((pick.depth_m, Some(pick)))
        }
    }
}

/// An image's pixels as a rectangle of its file's pixel coordinates, in the frame it belongs to.
pub fn describe_placement(image: &str, w: usize, h: usize, p: &Placement) -> String {
    let (x, y) = p.data_origin;
    let (fx, fy) = p.display_origin;
    let (fw, fh) = p.display_size;
    format!(
        "{image} holds the {w}x{h} pixels from ({x}, {y}) of the {fw}x{fh} frame from ({fx}, {fy})"
    )
}

/// Highlight recovery for low-dynamic-range input (`blur --highlights THRESHOLD,GAIN[,KNEE]`):
/// in an 8-bit photo a street light clips at 1.0, so its bokeh would come out a dull grey disc
/// instead of a bright one. Before the blur, in linear light, each pixel whose brightest
/// channel `m` (of the colour without its alpha) exceeds `threshold` is scaled by
/// `1 + (gain - 1) s`, where `s` rises smoothly (smoothstep) from 0 at `m = threshold` to 1 at
/// `m = threshold + knee`. A clipped pixel (`m = 1` with the default knee `1 - threshold`)
/// gets the whole gain; pixels at or below the threshold are unchanged. The gain stands for
/// the light's true brightness over the clip level, which the 8-bit file lost.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Highlights {
    /// Linear brightness (0 to 1) above which pixels are lifted.
    pub threshold: f32,
    /// Factor applied to fully clipped pixels (at least 1).
    pub gain: f32,
    /// Width of the ramp from the threshold to the full gain, in linear brightness (> 0).
    pub knee: f32,
}

impl Highlights {
    /// Parses `THRESHOLD,GAIN[,KNEE]` (the knee defaults to `1 - THRESHOLD`).
    pub fn parse(spec: &str) -> Result<Highlights> {
        let bad = |why: &str| {
            Error::Option(format!(
                "invalid --highlights '{spec}': {why}; expected THRESHOLD,GAIN[,KNEE], e.g. 0.9,20"
            ))
        };
        let v = crate::options::parse_numbers(spec).ok_or_else(|| bad("not numbers"))?;
        let (threshold, gain, knee) = match v.as_slice() {
            [t, g] => (*t, *g, 1.0 - *t),
            [t, g, k] => (*t, *g, *k),
            _ => return Err(bad("two or three numbers")),
        };
        if !(0.0..1.0).contains(&threshold) {
            return Err(bad(
                "the threshold must be at least 0 and below 1 (linear light)",
            ));
        }
        if !(1.0..=1e6).contains(&gain) {
            return Err(bad("the gain must be 1 to 1e6"));
        }
        if !(knee > 0.0 && knee <= 1.0) {
            return Err(bad("the knee must be above 0 and at most 1"));
        }
        Ok(Highlights {
            threshold,
            gain,
            knee,
        })
    }

    /// The factor applied to a pixel whose brightest channel is `m`.
    #[inline]
    pub fn factor(&self, m: f32) -> f32 {
        let t = ((m - self.threshold) / self.knee).clamp(0.0, 1.0);
        1.0 + (self.gain - 1.0) * t * t * (3.0 - 2.0 * t)
    }

    /// Lifts the highlights of `image` (linear, premultiplied alpha) in place; returns how many
    /// pixels were lifted.
    pub fn apply(&self, image: &mut crate::image::ColorImage) -> usize {
        let mut lifted = 0;
        for p in image.pixels_mut() {
            if p[3] <= 0.0 {
                continue;
            }
            let m = p[0].max(p[1]).max(p[2]) / p[3];
            if m > self.threshold {
                let f = self.factor(m);
                p[0] *= f;
                p[1] *= f;
                p[2] *= f;
                lifted += 1;
            }
        }
        lifted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn highlights_lift_clipped_pixels_by_the_gain_and_leave_the_rest() {
        let h = Highlights::parse("0.8,10").unwrap();
        assert!((h.knee - 0.2).abs() < 1e-6);
        assert_eq!(h.factor(0.5), 1.0);
        assert_eq!(h.factor(0.8), 1.0);
        assert!((h.factor(1.0) - 10.0).abs() < 1e-4);
        // Smooth and increasing between.
        let mid = h.factor(0.9);
        assert!((mid - 5.5).abs() < 1e-3, "{mid}");
        let mut img = crate::image::ColorImage::from_vec(
            3,
            1,
            vec![
                [0.2, 0.3, 0.4, 1.0],
                [1.0, 1.0, 1.0, 1.0],
                [0.5, 0.5, 0.5, 0.5],
            ],
        )
        .unwrap();
        assert_eq!(h.apply(&mut img), 2);
        assert_eq!(img.pixels()[0], [0.2, 0.3, 0.4, 1.0]);
        assert!((img.pixels()[1][0] - 10.0).abs() < 1e-4);
        // Premultiplied: a half-covered white pixel is clipped white, lifted by the gain.
        assert!((img.pixels()[2][0] - 5.0).abs() < 1e-4 && img.pixels()[2][3] == 0.5);
        for bad in [
            "",
            "1.0,10",
            "0.9,0.5",
            "0.9,10,0",
            "0.9",
            "0.9,10,1,2",
            "a,b",
        ] {
            assert!(Highlights::parse(bad).is_err(), "{bad}");
        }
    }
}
