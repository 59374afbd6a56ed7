use std::f32::consts::PI;
use std::sync::Arc;

use glam::Vec2;

use crate::image::GrayImage;
use crate::{Error, Result};

/// Every aperture spec the command line takes, for messages and help.
pub const APERTURE_SPECS: &str =
    "disc, poly:B[,rot=DEG][,curve=R], star[:N[,INNER]], heart, ring[:INNER] or image:PATH";

/// The shape of the lens opening, in the unit aperture.
///
/// A lens point `v` is given in image axes (x right, y down) inside the unit disc; the lens point
/// in camera space is `E * (v.x, -v.y, 0)`. A point at pinhole pixel `p` and depth `z` is seen
/// through `v` at `p + C(z) * v`: a far-field bokeh shows the aperture as defined here, a
/// near-field one turned 180 degrees.
#[derive(Clone, Debug, PartialEq)]
pub enum Aperture {
    /// A round opening of radius 1.
    Disc,
    /// A regular polygon with `blades` vertices on the unit circle at angles
    /// `rotation + 180/B + k*360/B` degrees, counter-clockwise from +x as the far-field bokeh
    /// appears on screen (Blender Cycles' convention).
    Polygon {
        /// Number of blades (vertices), at least 3.
        blades: u32,
        /// Rotation in radians; positive turns the bokeh counter-clockwise on screen.
        rotation_rad: f32,
        /// Curved blades: each edge is an arc of this radius (in units of the aperture radius)
        /// through its two vertices, bulging outward (McGraw fig. 7). `None` gives straight
        /// edges; 1.0 gives a circle.
        blade_radius: Option<f32>,
    },
    /// An image used as a density over the square [-1, 1]^2 (row 0 at the top, as the far-field
    /// bokeh appears on screen).
    Image(Arc<ApertureImage>),
}

/// A greyscale density image for [`Aperture::Image`], normalised to a maximum of 1.
#[derive(Clone, Debug, PartialEq)]
pub struct ApertureImage {
    density: GrayImage,
}

impl ApertureImage {
    /// Wraps a greyscale image (any non-negative values; normalised to a peak of 1).
    pub fn new(image: GrayImage) -> Result<Self> {
        let mut peak = 0.0f32;
        for &v in image.pixels() {
            if !v.is_finite() || v < 0.0 {
                return Err(Error::invalid(
                    "aperture image",
                    format!("pixel value {v}: expected finite non-negative values"),
                ));
            }
            peak = peak.max(v);
        }
        if peak <= 0.0 {
            return Err(Error::invalid(
                "aperture image",
                "the image is black everywhere: no light passes",
            ));
        }
        Ok(Self {
            density: image.map(|v| v / peak),
        })
    }

    /// Density at `v` in [-1, 1]^2 (nearest pixel), 0 outside.
    pub fn density(&self, v: Vec2) -> f32 {
        let (w, h) = (self.density.width() as f32, self.density.height() as f32);
        let x = (v.x + 1.0) * 0.5 * w;
        let y = (v.y + 1.0) * 0.5 * h;
        if !(x >= 0.0 && y >= 0.0 && x < w && y < h) {
            return 0.0;
        }
        self.density.get(x as usize, y as usize)
    }

    /// The normalised density image.
    pub fn image(&self) -> &GrayImage {
        &self.density
    }
}

impl Aperture {
    /// Parses `disc`, `poly:B[,rot=DEG][,curve=R]`. Image apertures (`image:PATH`) need a file
    /// read and are built by the caller with [`ApertureImage::new`]; this returns an error for them.
    pub fn parse(spec: &str) -> Result<Self> {
        let spec = spec.trim();
        if spec == "disc" || spec == "circle" {
            return Ok(Aperture::Disc);
        }
        if let Some(rest) = spec.strip_prefix("poly:") {
            let mut parts = rest.split(',');
            let blades_str = parts.next().unwrap_or("");
            let blades: u32 = blades_str.trim().parse().map_err(|_| {
                Error::invalid(
                    "aperture",
                    format!("'{spec}': blade count '{blades_str}' is not a whole number"),
                )
            })?;
            let mut rotation_deg = 0.0f32;
            let mut blade_radius = None;
            for part in parts {
                let (key, value) = part.split_once('=').ok_or_else(|| {
                    Error::invalid(
                        "aperture",
                        format!("'{spec}': expected key=value after the blade count, got '{part}'"),
                    )
                })?;
                let value: f32 = value.trim().parse().map_err(|_| {
                    Error::invalid(
                        "aperture",
                        format!("'{spec}': value of '{key}' is not a number"),
                    )
                })?;
                match key.trim() {
                    "rot" | "rotation" => rotation_deg = value,
                    "curve" | "blade-radius" => blade_radius = Some(value),
                    other => {
                        return Err(Error::invalid(
                            "aperture",
                            format!("'{spec}': unknown key '{other}' (expected rot or curve)"),
                        ))
                    }
                }
            }
            let aperture = Aperture::Polygon {
                blades,
                rotation_rad: rotation_deg.to_radians(),
                blade_radius,
            };
            aperture.validate()?;
            return Ok(aperture);
        }
        Err(Error::invalid(
            "aperture",
            format!("'{spec}': expected {APERTURE_SPECS}"),
        ))
    }

    /// Checks the parameters: at least 3 blades (at most 64), finite rotation, blade radius >= 1.
    pub fn validate(&self) -> Result<()> {
        if let Aperture::Polygon {
            blades,
            rotation_rad,
            blade_radius,
        } = self
        {
            if !(3..=64).contains(blades) {
                return Err(Error::invalid(
                    "aperture",
                    format!("{blades} blades: expected 3 to 64"),
                ));
            }
            if !rotation_rad.is_finite() {
                return Err(Error::invalid("aperture", "rotation is not finite"));
            }
            if let Some(r) = blade_radius {
                if !(r.is_finite() && *r >= 1.0) {
                    return Err(Error::invalid(
                        "aperture",
                        format!(
                            "blade radius {r}: expected at least 1 (in units of the aperture radius; 1 is a circle)"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Polygon vertices in image axes (x right, y down), counter-clockwise on screen.
    /// Empty for non-polygonal apertures.
    pub fn vertices(&self) -> Vec<Vec2> {
        match self {
            Aperture::Polygon {
                blades,
                rotation_rad,
                ..
            } => (0..*blades)
                .map(|k| {
                    let a =
                        rotation_rad + PI / *blades as f32 + k as f32 * 2.0 * PI / *blades as f32;
                    Vec2::new(a.cos(), -a.sin())
                })
                .collect(),
            _ => Vec::new(),
        }
    }

    /// Density of the aperture at `v` (image axes): 1 inside, 0 outside for shapes; the image
    /// value for [`Aperture::Image`].
    pub fn density(&self, v: Vec2) -> f32 {
        self.density_among(&self.vertices(), v)
    }

    /// [`Aperture::density`] for many points: the polygon's vertices (a sine and a cosine per
    /// blade) are worked out once, not per point. The same values bit for bit.
    pub fn density_fn(&self) -> impl Fn(Vec2) -> f32 + Send + Sync + '_ {
        let verts = self.vertices();
        move |v| self.density_among(&verts, v)
    }

    /// [`Aperture::density`] given [`Aperture::vertices`].
    fn density_among(&self, verts: &[Vec2], v: Vec2) -> f32 {
        match self {
            Aperture::Disc => f32::from(v.length_squared() <= 1.0),
            Aperture::Polygon { blade_radius, .. } => {
                let n = verts.len();
                for k in 0..n {
                    let a = verts[k];
                    let b = verts[(k + 1) % n];
                    match blade_radius {
                        None => {
                            // Inside = left of each edge in image axes for a CCW-on-screen
                            // polygon, i.e. cross(b - a, v - a) <= 0 with y down.
                            let e = b - a;
                            let d = v - a;
                            if e.x * d.y - e.y * d.x > 1e-7 {
                                return 0.0;
                            }
                        }
                        Some(r) => {
                            let mid = (a + b) * 0.5;
                            let dir = mid.normalize();
                            let half_chord = (b - a).length() * 0.5;
                            // Centre of the arc through a and b with radius r, on the inward side.
                            let dist_mid = (r * r - half_chord * half_chord).max(0.0).sqrt();
                            let centre = mid - dir * dist_mid;
                            if (v - centre).length_squared() > r * r + 1e-7 {
                                return 0.0;
                            }
                        }
                    }
                }
                1.0
            }
            Aperture::Image(img) => img.density(v),
        }
    }

    /// Maps a uniform point in [0,1)^2 onto the aperture with constant density, keeping the
    /// stratification of the input. `None` for shapes sampled by rejection (curved blades,
    /// images).
    pub fn warp(&self, u: Vec2) -> Option<Vec2> {
        match self {
            Aperture::Disc => Some(concentric_disc(u)),
            Aperture::Polygon {
                blade_radius: None, ..
            } => {
                let verts = self.vertices();
                let n = verts.len();
                let t = u.x * n as f32;
                let k = (t as usize).min(n - 1);
                let fx = t - k as f32;
                // Uniform point in the triangle (0, v_k, v_k+1).
                let s = fx.sqrt();
                Some(verts[k] * (s * (1.0 - u.y)) + verts[(k + 1) % n] * (s * u.y))
            }
            _ => None,
        }
    }

    /// True if candidates for rejection sampling should be drawn from the unit disc (the shape
    /// lies inside it); otherwise from the square [-1, 1]^2.
    pub(crate) fn inside_unit_disc(&self) -> bool {
        !matches!(self, Aperture::Image(_))
    }

    /// Area of the shape in units of the aperture radius squared (pi for the disc), estimated
    /// exactly for straight polygons and by quadrature otherwise. Weighted by density for images.
    pub fn area(&self) -> f32 {
        match self {
            Aperture::Disc => PI,
            Aperture::Polygon {
                blades,
                blade_radius: None,
                ..
            } => {
                let n = *blades as f32;
                0.5 * n * (2.0 * PI / n).sin()
            }
            _ => {
                let steps = 512;
                let mut sum = 0.0f64;
                for j in 0..steps {
                    for i in 0..steps {
                        let v = Vec2::new(
                            (i as f32 + 0.5) / steps as f32 * 2.0 - 1.0,
                            (j as f32 + 0.5) / steps as f32 * 2.0 - 1.0,
                        );
                        sum += self.density(v) as f64;
                    }
                }
                (sum * 4.0 / (steps * steps) as f64) as f32
            }
        }
    }
}

/// Shirley-Chiu concentric mapping of [0,1)^2 onto the unit disc (area-preserving, keeps strata).
pub(crate) fn concentric_disc(u: Vec2) -> Vec2 {
    let a = 2.0 * u.x - 1.0;
    let b = 2.0 * u.y - 1.0;
    if a == 0.0 && b == 0.0 {
        return Vec2::ZERO;
    }
    let (r, phi) = if a.abs() > b.abs() {
        (a, PI / 4.0 * (b / a))
    } else {
        (b, PI / 2.0 - PI / 4.0 * (a / b))
    };
    Vec2::new(r * phi.cos(), r * phi.sin())
}
