//! Aperture kernels as images (McGraw section 3, 3.1; figs. 3, 6, 7, 10).
//!
//! A kernel is the far-field bokeh of a point as it appears on screen: [`kernel_image`] rasterizes
//! the shared [`Aperture`] into an odd-sized square, the unit aperture filling the square (radius
//! `size_px / 2` pixels), with `supersample x supersample` samples per pixel so that the edge is
//! anti-aliased (image apertures: an exact box filter of the image), an optional
//! spherical-aberration profile, and the sum normalised to 1.
//!
//! Orientation: the shared polygon convention (vertices at `rotation + 180/B + k*360/B` degrees)
//! puts every polygon with rotation 0 symmetric about the horizontal axis, which is the
//! orientation the paper advises (rows mirror about the middle row, fewer independent rows).
//! A user rotation is honoured, because the bokeh must match `reference`; it generally costs
//! low-rank accuracy (see the kernel analysis test).
//!
//! Custom shapes (star, heart, ring; fig. 10) become [`Aperture::Image`] values through
//! [`CustomShape::aperture`], so the same shape also drives `reference` and the other methods.

use glam::Vec2;

use crate::image::GrayImage;
pub(crate) use crate::lens::check_aberration;
use crate::lens::Aperture;
pub use crate::lens::{aberration_profile, CustomShape, CUSTOM_SHAPE_PX};
use crate::{Error, Result};

/// Largest kernel side in pixels accepted by [`kernel_image`] and [`super::decompose`]
/// (the SVD costs O(n^3): about 0.1 s at this size).
pub const MAX_KERNEL_PX: usize = 513;

/// Largest number of samples per pixel and axis.
pub const MAX_SUPERSAMPLE: usize = 32;

/// How to rasterize an aperture kernel.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelSpec {
    /// The aperture shape, as for every other method (far-field orientation).
    pub aperture: Aperture,
    /// Side of the square kernel in pixels; odd, 1 to [`MAX_KERNEL_PX`]. The unit aperture has
    /// radius `size_px / 2` pixels, so a disc touches the four sides. Default 65 (the paper's
    /// largest kernel).
    pub size_px: usize,
    /// Spherical aberration, -1 to 1 (figs. 6, 8): the brightness across the aperture is
    /// `max(0, 1 + aberration * (2 |v|^2 - 1))` at unit-aperture radius `|v|`, so +1 gives a
    /// bright rim and dark centre, -1 a bright centre fading to a dark rim, 0 a uniform
    /// bokeh. The mean over the unit disc is 1 whatever the value. Default 0.
    pub aberration: f32,
    /// Samples per pixel along each axis (the pixel gets `supersample^2` samples on a regular
    /// grid); 1 to [`MAX_SUPERSAMPLE`]. Image apertures do not use it: they are box-filtered
    /// exactly (each kernel pixel averages the image pixels it overlaps). Default 8.
    pub supersample: usize,
}

impl Default for KernelSpec {
    fn default() -> Self {
        Self {
            aperture: Aperture::Disc,
            size_px: 65,
            aberration: 0.0,
            supersample: 8,
        }
    }
}

impl KernelSpec {
    /// A kernel of `size_px` pixels for `aperture`, no aberration, 8x8 supersampling.
    pub fn new(aperture: Aperture, size_px: usize) -> Self {
        Self {
            aperture,
            size_px,
            ..Self::default()
        }
    }

    /// Checks every field (see their documentation).
    pub fn validate(&self) -> Result<()> {
        self.aperture.validate()?;
        if self.size_px == 0 || self.size_px.is_multiple_of(2) || self.size_px > MAX_KERNEL_PX {
            return Err(Error::invalid(
                "kernel size",
                format!(
                    "{} px: expected an odd size from 1 to {MAX_KERNEL_PX}",
                    self.size_px
                ),
            ));
        }
        check_aberration(self.aberration)?;
        if !(1..=MAX_SUPERSAMPLE).contains(&self.supersample) {
            return Err(Error::invalid(
                "kernel supersampling",
                format!(
                    "{} samples per axis: expected 1 to {MAX_SUPERSAMPLE}",
                    self.supersample
                ),
            ));
        }
        Ok(())
    }
}

/// Rasterizes the kernel of `spec`: a `size_px x size_px` image (row 0 at the top, as the
/// far-field bokeh appears on screen) summing to 1.
///
/// Fails if a field of `spec` is out of range or if no light passes (an aperture image that is
/// black where the aberration profile is not).
pub fn kernel_image(spec: &KernelSpec) -> Result<GrayImage> {
    spec.validate()?;
    let n = spec.size_px;
    let data = match &spec.aperture {
        Aperture::Image(img) => image_coverage(img.image(), n, spec.aberration),
        shape => shape_coverage(shape, n, spec.supersample, spec.aberration),
    };
    let total: f64 = data.iter().sum();
    if total.is_nan() || total <= 0.0 {
        return Err(Error::invalid(
            "aperture",
            "no light passes the aperture at this kernel size and aberration",
        ));
    }
    GrayImage::from_vec(n, n, data.iter().map(|&v| (v / total) as f32).collect())
}

/// Exact box filter of an image aperture (a piecewise-constant density over [-1, 1]^2) onto
/// `n x n` kernel pixels: each kernel pixel sums the image pixels it overlaps, weighted by the
/// overlap area and the aberration profile at the overlap's centre.
fn image_coverage(density: &GrayImage, n: usize, aberration: f32) -> Vec<f64> {
    // Overlaps along one axis of `m` image pixels: for kernel pixel k, (image pixel, overlap
    // length in image pixels, centre of the overlap in unit-aperture coordinates).
    let overlaps = |m: usize| -> Vec<Vec<(usize, f64, f64)>> {
        let scale = m as f64 / n as f64;
        (0..n)
            .map(|k| {
                let (a, b) = (k as f64 * scale, (k + 1) as f64 * scale);
                let last = (b.ceil() as usize).min(m);
                (a.floor() as usize..last)
                    .filter_map(|p| {
                        let lo = a.max(p as f64);
                        let hi = b.min((p + 1) as f64);
                        (hi > lo).then(|| (p, hi - lo, (lo + hi) / m as f64 - 1.0))
                    })
                    .collect()
            })
            .collect()
    };
    let (ox, oy) = (overlaps(density.width()), overlaps(density.height()));
    let mut data = vec![0.0f64; n * n];
    for (j, rows) in oy.iter().enumerate() {
        for (i, cols) in ox.iter().enumerate() {
            let mut sum = 0.0f64;
            for &(py, ly, cy) in rows {
                for &(px, lx, cx) in cols {
                    let d = density.get(px, py) as f64;
                    if d > 0.0 {
                        let r2 = (cx * cx + cy * cy) as f32;
                        sum += d * lx * ly * aberration_profile(aberration, r2) as f64;
                    }
                }
            }
            data[j * n + i] = sum;
        }
    }
    data
}

/// Coverage of a shape (disc or polygon with straight or curved blades: convex, inside the unit
/// disc) on `n x n` kernel pixels with `s x s` samples per pixel, weighted by the aberration
/// profile `a`. Pixels beyond the unit disc are skipped, and pixels whose four corners are inside
/// are inside (convexity), so only boundary pixels evaluate the shape per sample.
fn shape_coverage(aperture: &Aperture, n: usize, s: usize, a: f32) -> Vec<f64> {
    let radius_px = n as f32 / 2.0;
    // Unit-aperture coordinate of pixel edge `i` (0..=n) and of sub-sample `k` of pixel `i`.
    let edge = |i: usize| (i as f32 - radius_px) / radius_px;
    let sub = |i: usize, k: usize| (i as f32 + (k as f32 + 0.5) / s as f32 - radius_px) / radius_px;
    let density = aperture.density_fn();
    let corner: Vec<bool> = (0..=n)
        .flat_map(|j| (0..=n).map(move |i| (i, j)))
        .map(|(i, j)| density(Vec2::new(edge(i), edge(j))) > 0.0)
        .collect();
    let mut data = vec![0.0f64; n * n];
    for j in 0..n {
        for i in 0..n {
            let nx = nearest_to_zero(edge(i), edge(i + 1));
            let ny = nearest_to_zero(edge(j), edge(j + 1));
            if nx * nx + ny * ny > 1.0 {
                continue;
            }
            let inside = corner[j * (n + 1) + i]
                && corner[j * (n + 1) + i + 1]
                && corner[(j + 1) * (n + 1) + i]
                && corner[(j + 1) * (n + 1) + i + 1];
            if inside && a == 0.0 {
                // Every sample passes at weight 1: the sum below, without its loop.
                data[j * n + i] = (s * s) as f64;
                continue;
            }
            let mut sum = 0.0f64;
            for ky in 0..s {
                let y = sub(j, ky);
                for kx in 0..s {
                    let v = Vec2::new(sub(i, kx), y);
                    let d = if inside { 1.0 } else { density(v) };
                    if d > 0.0 {
                        sum += (d * aberration_profile(a, v.length_squared())) as f64;
                    }
                }
            }
            data[j * n + i] = sum;
        }
    }
    data
}

/// The point of the interval [a, b] nearest to 0.
#[inline]
fn nearest_to_zero(a: f32, b: f32) -> f32 {
    if a > 0.0 {
        a
    } else if b < 0.0 {
        b
    } else {
        0.0
    }
}
