//! Focus helpers: the focus distance that puts a pixel's surface in focus.
//!
//! The scene is rasterized once through the lens centre (a pinhole view at pixel centres) and
//! the view-axis depth is read in a small window around the pixel. The median of the window's
//! finite depths is robust to holes (alpha cut-outs, the background) and to the edge of an
//! object falling on the pixel. When the window sees only background it doubles until it finds
//! a surface or covers the whole image. A blended surface counts as a renderer's Z pass takes it (see
//! [`crate::raster::GBuffer::depth`]).

use crate::image::GrayImage;
use crate::lens::Camera;
use crate::methods::registry::{MethodSettings, PinholeSettings};
use crate::raster::{render_gbuffer, PreparedScene, View};
use crate::scene::Scene;
use crate::{Error, Result};

/// Side in pixels of the window whose median depth is taken.
pub const WINDOW_PX: usize = 9;

/// The depth picked for focusing, and where it came from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FocusPick {
    /// Median view-axis depth in metres of the surfaces seen in the window.
    pub depth_m: f32,
    /// Pixel column of the window centre.
    pub x_px: usize,
    /// Pixel row of the window centre.
    pub y_px: usize,
    /// Side of the window used, in pixels.
    pub window_px: usize,
}

/// The focus distance for pixel (`x_px`, `y_px`) of `camera`'s image: the median view-axis depth
/// in metres of the window around it in a pinhole render. `None` when no opaque or alpha-tested
/// surface is in view at all. The camera's own focus distance is not used. The render is held to
/// the memory budget as a one-sample `pinhole` run is
/// ([`check_scene_budget`](crate::methods::registry::check_scene_budget)), before anything is
/// allocated for it.
pub fn focus_at_pixel(
    scene: &Scene,
    camera: &Camera,
    x_px: usize,
    y_px: usize,
) -> Result<Option<FocusPick>> {
    if x_px >= camera.width_px || y_px >= camera.height_px {
        return Err(Error::invalid(
            "focus pixel",
            format!(
                "({x_px}, {y_px}) is outside the {}x{} image: expected a column below {} and a \
                 row below {}",
                camera.width_px, camera.height_px, camera.width_px, camera.height_px
            ),
        ));
    }
    // Any valid focus distance will do for a pinhole view.
    let mut pinhole = camera.clone();
    pinhole.focus_m = if pinhole.focus_m.is_finite() {
        pinhole.focus_m.clamp(pinhole.near_m, pinhole.far_m)
    } else {
        pinhole.near_m
    };
    // Beyond the focal length too (a lens cannot focus closer), when the planes allow it.
    pinhole.focus_m = pinhole
        .focus_m
        .max(2e-3 * pinhole.focal_length_mm)
        .min(pinhole.far_m);
    let lens = pinhole.thin_lens()?.pinhole();
    let settings = MethodSettings::Pinhole(PinholeSettings::default());
    crate::methods::registry::check_scene_budget(&settings, scene, camera)?;
    let prepared = PreparedScene::new(scene, &camera.camera_from_world)?;
    let depth = render_gbuffer(&prepared, &View::pinhole(lens))?.depth;
    Ok(focus_in_depth(&depth, x_px, y_px))
}

/// Depths at and beyond this many metres are background ("no hit"): renderers write a large
/// finite value there (Blender 1e10), and our own depth passes write +inf.
pub const BACKGROUND_DEPTH_M: f32 = 1e9;

/// The median view-axis depth of the window around (`x_px`, `y_px`) of a depth image in
/// metres, skipping holes (NaN, infinite, background and non-positive values); the window
/// starts at [`WINDOW_PX`] and doubles until it finds a surface. `None` when the image has
/// none, or the pixel is outside it.
pub fn focus_in_depth(depth: &GrayImage, x_px: usize, y_px: usize) -> Option<FocusPick> {
    if x_px >= depth.width() || y_px >= depth.height() {
        return None;
    }
    let mut window_px = WINDOW_PX;
    let whole_image = 2 * depth.width().max(depth.height()) + 1;
    loop {
        let r = window_px / 2;
        let mut values: Vec<f32> = (y_px.saturating_sub(r)..(y_px + r + 1).min(depth.height()))
            .flat_map(|y| {
                let row = depth.row(y);
                let x0 = x_px.saturating_sub(r);
                let x1 = (x_px + r + 1).min(depth.width());
                row[x0..x1].iter().copied()
            })
            .filter(|z| z.is_finite() && *z > 0.0 && *z < BACKGROUND_DEPTH_M)
            .collect();
        if !values.is_empty() {
            values.sort_by(f32::total_cmp);
            let n = values.len();
            let depth_m = if n % 2 == 1 {
                values[n / 2]
            } else {
                0.5 * (values[n / 2 - 1] + values[n / 2])
            };
            return Some(FocusPick {
                depth_m,
                x_px,
                y_px,
                window_px,
            });
        }
        if window_px >= whole_image {
            return None;
        }
        window_px = 2 * window_px - 1;
    }
}

/// [`focus_at_pixel`] at the image centre (pixel (width / 2, height / 2)).
pub fn focus_at_centre(scene: &Scene, camera: &Camera) -> Result<Option<FocusPick>> {
    focus_at_pixel(scene, camera, camera.width_px / 2, camera.height_px / 2)
}
