//! How a real lens departs from the ideal thin lens, shared by every method: an anamorphic
//! (squeezed) aperture and the cat's eye (optical vignetting). All are off by default, and then
//! every method gives exactly the ideal lens's image.
//!
//! - **Anamorphic.** The aperture is stretched to `aspect` times as wide as it is high, its area
//!   kept: a lens point `v` of the unit aperture lies at `(v.x sqrt(aspect), v.y /
//!   sqrt(aspect))` lens radii. A far point light's bokeh is the aperture so stretched: an
//!   ellipse of axes `2|C| sqrt(aspect)` across and `2|C| / sqrt(aspect)` up for a disc. A 2x
//!   anamorphic lens's tall ovals are `aspect = 0.5`.
//! - **Chromatic aberration.** Longitudinal: the red channel is in focus `chroma_dpt` dioptres
//!   nearer than green (`1/z_r = 1/z_f + D`), the blue one as much farther (`1/z_b = 1/z_f -
//!   D`). Behind the focus red then has the largest blur and fringes the bokeh; in front of it,
//!   blue. Lateral: the red channel's aperture is `chroma_scale` times green's, blue's `1 /
//!   chroma_scale` times.
//! - **Cat's eye.** A second opening, the front of the lens barrel, lies `barrel_distance_m` in
//!   front of the aperture, of radius `barrel_radius_m` (by default the lens radius `E`). Seen
//!   from a pixel at field angle `theta` (`tan theta = r_px / f_px`, `r_px` its distance from
//!   the image centre), the opening is shifted against the aperture by `barrel_distance_m tan
//!   theta`. In aperture radii, a lens point `v` reaches that pixel when `|v + d| <= R`, with
//!   `d = barrel_distance_m (p - c) / (f_px E)` and `R = barrel_radius_m / E`. At the image
//!   centre nothing is cut; towards the corners the bokeh becomes the lemon where the two
//!   discs overlap, its long axis tangential: two unit discs `|d|` apart overlap over `2 - |d|`
//!   radii along the offset and `2 sqrt(1 - |d|^2 / 4)` across it. With a barrel radius given
//!   in millimetres, stopping down shrinks the aperture inside the opening and the cat's eye
//!   fades, as with a real lens.

use glam::Vec2;

use super::ThinLens;
use crate::error::shown;
use crate::{Error, Result};

/// Departures from the ideal thin lens (see the module doc). [`LensEffects::default`] is the
/// ideal lens.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LensEffects {
    /// Bokeh width over height (anamorphic squeeze, area kept); 1 is round.
    pub aspect: f32,
    /// Distance in metres from the aperture to the lens barrel's front opening (0: no cat's
    /// eye).
    pub barrel_distance_m: f32,
    /// Radius of the barrel's opening in metres; `None`: the lens radius (as large as the
    /// aperture at the f-number of the run).
    pub barrel_radius_m: Option<f32>,
    /// Longitudinal chromatic aberration: red in focus this many dioptres (1/m) nearer than
    /// green, blue as much farther (0: none).
    pub chroma_dpt: f32,
    /// Lateral chromatic aberration: red's aperture radius over green's, blue's being its
    /// inverse (1: none).
    pub chroma_scale: f32,
}

impl Default for LensEffects {
    fn default() -> Self {
        Self {
            aspect: 1.0,
            barrel_distance_m: 0.0,
            barrel_radius_m: None,
            chroma_dpt: 0.0,
            chroma_scale: 1.0,
        }
    }
}

/// The effects by name, as the registry and messages call them.
pub const EFFECT_NAMES: [&str; 3] = ["anamorphic", "cats-eye", "chromatic"];

/// The built-in lens presets, by name: plain JSON files in `presets/` of the repository, read
/// as [`LensEffects::preset`] reads a user's own file.
pub const PRESETS: &[(&str, &str)] = &[
    (
        "vintage-swirl",
        include_str!("../../presets/vintage-swirl.json"),
    ),
    (
        "anamorphic-2x",
        include_str!("../../presets/anamorphic-2x.json"),
    ),
    ("apochromat", include_str!("../../presets/apochromat.json")),
];

/// Most bytes of a lens preset file: far more than its few lines of JSON need.
pub const MAX_PRESET_FILE_BYTES: u64 = 1 << 20;

/// A lens preset file: a description and any of the effects, in the units of the flags.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct PresetFile {
    /// What the lens looks like.
    description: String,
    /// `--anamorphic ASPECT`.
    anamorphic: Option<f32>,
    /// `--cats-eye DIST[,RADIUS]` in millimetres.
    cats_eye_mm: Option<Vec<f32>>,
    /// `--chromatic DPT[,SCALE]`.
    chromatic: Option<Vec<f32>>,
}

impl LensEffects {
    /// A lens preset: a built-in name ([`PRESETS`]) or a JSON file with the fields
    /// `description`, and any of `anamorphic` (aspect), `cats_eye_mm` (`[distance]` or
    /// `[distance, radius]`) and `chromatic` (`[dioptres]` or `[dioptres, scale]`). Returns the effects
    /// and the description.
    pub fn preset(spec: &str) -> Result<(LensEffects, String)> {
        let (source, text) = match PRESETS.iter().find(|(name, _)| *name == spec) {
            Some((name, json)) => (
                std::path::PathBuf::from(format!("preset {name}")),
                json.to_string(),
            ),
            None => {
                let path = std::path::Path::new(spec);
                let expected = || {
                    format!(
                        "{}, or a preset file (.json)",
                        PRESETS.iter().map(|p| p.0).collect::<Vec<_>>().join(", ")
                    )
                };
                // Nothing there: a name that is no preset. Something that is no file (a
                // folder, a FIFO, a device, a link to nothing) is named as what it is.
                let Ok(entry) = std::fs::symlink_metadata(path) else {
                    return Err(Error::Unknown {
                        kind: "lens preset",
                        name: spec.to_string(),
                        expected: expected(),
                    });
                };
                let not_a_file = |what: &str| {
                    Error::invalid(
                        "--lens",
                        format!(
                            "{}: {what}, not a preset file: expected {}",
                            shown(path),
                            expected()
                        ),
                    )
                };
                let file = match crate::input::open_regular(path) {
                    Ok(f) => f,
                    Err(crate::input::OpenError::NotRegular(kind)) => {
                        return Err(not_a_file(&format!("it is {kind}")))
                    }
                    Err(crate::input::OpenError::Io(_)) if entry.file_type().is_symlink() => {
                        return Err(not_a_file("it is a link to nothing"))
                    }
                    Err(crate::input::OpenError::Io(e)) => return Err(Error::io(path, e)),
                };
                // Refused from its size, before it is read: a preset is a few lines of JSON.
                let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
                let too_large = || {
                    Error::format(
                        path,
                        format!(
                            "larger than {} KiB: expected a lens preset, a few lines of JSON",
                            MAX_PRESET_FILE_BYTES >> 10
                        ),
                    )
                };
                if len > MAX_PRESET_FILE_BYTES {
                    return Err(too_large());
                }
                let mut text = String::with_capacity(len as usize);
                std::io::Read::read_to_string(
                    &mut std::io::Read::take(file, MAX_PRESET_FILE_BYTES + 1),
                    &mut text,
                )
                .map_err(|e| Error::io(path, e))?;
                // It grew while it was read.
                if text.len() as u64 > MAX_PRESET_FILE_BYTES {
                    return Err(too_large());
                }
                (path.to_path_buf(), text)
            }
        };
        let file: PresetFile = serde_json::from_str(&text).map_err(|e| {
            Error::format(
                &source,
                format!(
                    "not a lens preset: {e}; expected a JSON object with \"description\" and any of \"anamorphic\", \"cats_eye_mm\", \"chromatic\""
                ),
            )
        })?;
        let mut effects = LensEffects::default();
        if let Some(a) = file.anamorphic {
            effects.aspect = a;
        }
        match file.cats_eye_mm.as_deref() {
            None => {}
            Some([d]) => effects.barrel_distance_m = d / 1000.0,
            Some([d, r]) => {
                effects.barrel_distance_m = d / 1000.0;
                effects.barrel_radius_m = Some(r / 1000.0);
            }
            Some(_) => {
                return Err(Error::format(
                    &source,
                    "cats_eye_mm: expected [distance] or [distance, radius] in millimetres",
                ))
            }
        }
        match file.chromatic.as_deref() {
            None => {}
            Some([d]) => effects.chroma_dpt = *d,
            Some([d, k]) => {
                effects.chroma_dpt = *d;
                effects.chroma_scale = *k;
            }
            Some(_) => {
                return Err(Error::format(
                    &source,
                    "chromatic: expected [dioptres] or [dioptres, aperture scale]",
                ))
            }
        }
        effects
            .validate()
            .map_err(|e| Error::format(&source, e.to_string()))?;
        Ok((effects, file.description))
    }

    /// Whether this is the ideal lens (every effect off).
    pub fn is_ideal(&self) -> bool {
        *self == Self::default()
    }

    /// The effects that are on, by name ([`EFFECT_NAMES`]).
    pub fn active(&self) -> Vec<&'static str> {
        let mut on = Vec::new();
        if self.aspect != 1.0 {
            on.push("anamorphic");
        }
        if self.barrel_distance_m != 0.0 {
            on.push("cats-eye");
        }
        if self.is_chromatic() {
            on.push("chromatic");
        }
        on
    }

    /// Checks the ranges, and refuses the effects that are on but not among `supported` (the
    /// effects method `method_id` renders), naming them. The lens knows no method: each method
    /// passes its own list, and the registry adds which other methods render them.
    pub fn check_supported(&self, method_id: &str, supported: &[&str]) -> Result<()> {
        self.validate()?;
        let missing = self.unsupported(supported);
        if missing.is_empty() {
            return Ok(());
        }
        Err(Error::Option(format!(
            "method {method_id} does not support the lens effect {} (--{})",
            missing.join(", "),
            missing.join(", --"),
        )))
    }

    /// The effects that are on but not among `supported`, by name ([`EFFECT_NAMES`]).
    pub fn unsupported(&self, supported: &[&str]) -> Vec<&'static str> {
        self.active()
            .into_iter()
            .filter(|e| !supported.contains(e))
            .collect()
    }

    /// The same effects without chromatic aberration: what each channel's run of a method that
    /// renders colour a channel at a time sees.
    pub fn without_colour(&self) -> Self {
        Self {
            chroma_dpt: 0.0,
            chroma_scale: 1.0,
            ..*self
        }
    }

    /// Whether the channels see different lenses (chromatic aberration).
    pub fn is_chromatic(&self) -> bool {
        self.chroma_dpt != 0.0 || self.chroma_scale != 1.0
    }

    /// The focus distance in metres and the lens-radius factor of channel `c` (0 red, 1 green,
    /// 2 blue) of a lens focused at `focus_m`; an error when a channel would focus beyond
    /// infinity.
    pub fn channel_lens(&self, c: usize, focus_m: f32) -> Result<(f32, f32)> {
        let (dpt, scale) = match c {
            0 => (self.chroma_dpt, self.chroma_scale),
            2 => (-self.chroma_dpt, 1.0 / self.chroma_scale),
            _ => (0.0, 1.0),
        };
        let inverse = 1.0 / focus_m + dpt;
        if !(inverse > 0.0 && inverse.is_finite()) {
            return Err(Error::Option(format!(
                "invalid --chromatic {}: focused at {focus_m} m, the {} channel would be in focus beyond infinity; expected at most {} dioptres",
                self.chroma_dpt,
                ["red", "green", "blue"][c],
                1.0 / focus_m
            )));
        }
        Ok((1.0 / inverse, scale))
    }

    /// Checks the ranges: aspect 0.1 to 10, barrel distance 0 to 10 m, barrel radius above 0
    /// and at most 10 m.
    pub fn validate(&self) -> Result<()> {
        if !(self.aspect.is_finite() && (0.1..=10.0).contains(&self.aspect)) {
            return Err(Error::Option(format!(
                "invalid --anamorphic {}: expected the bokeh's width over height, 0.1 to 10 (0.5: a 2x anamorphic's tall ovals)",
                self.aspect
            )));
        }
        if !(self.barrel_distance_m.is_finite() && (0.0..=10.0).contains(&self.barrel_distance_m)) {
            return Err(Error::Option(format!(
                "invalid --cats-eye: barrel distance {} m: expected 0 to 10 m (in the flag, millimetres)",
                self.barrel_distance_m
            )));
        }
        if !(self.chroma_dpt.is_finite() && self.chroma_dpt.abs() <= 10.0) {
            return Err(Error::Option(format!(
                "invalid --chromatic {}: expected a focus shift of -10 to 10 dioptres",
                self.chroma_dpt
            )));
        }
        if !(self.chroma_scale.is_finite() && (0.5..=2.0).contains(&self.chroma_scale)) {
            return Err(Error::Option(format!(
                "invalid --chromatic: aperture scale {}: expected 0.5 to 2",
                self.chroma_scale
            )));
        }
        if let Some(r) = self.barrel_radius_m {
            if !(r.is_finite() && r > 0.0 && r <= 10.0) {
                return Err(Error::Option(format!(
                    "invalid --cats-eye: barrel radius {r} m: expected above 0 and at most 10 m (in the flag, millimetres)"
                )));
            }
        }
        Ok(())
    }

    /// The lens point, in lens radii, of the point `v` of the unit aperture: stretched by the
    /// anamorphic aspect.
    #[inline]
    pub fn squeeze(&self, v: Vec2) -> Vec2 {
        if self.aspect == 1.0 {
            return v;
        }
        let s = self.aspect.sqrt();
        Vec2::new(v.x * s, v.y / s)
    }

    /// Whether the cat's eye clips anything (a barrel at some distance).
    #[inline]
    pub fn has_cats_eye(&self) -> bool {
        self.barrel_distance_m != 0.0
    }

    /// The barrel seen from the pixel centre `p_px` (pixel coordinates, y down) through `lens`:
    /// its shift `d` and its radius `R`, both in aperture radii.
    #[inline]
    pub fn barrel(&self, lens: &ThinLens, p_px: Vec2) -> (Vec2, f32) {
        let c = Vec2::new(lens.width_px as f32, lens.height_px as f32) * 0.5;
        let shift = (p_px - c) * self.barrel_shift_per_px(lens);
        (shift, self.barrel_radius(lens))
    }

    /// How far the barrel [`LensEffects::barrel`] shifts per pixel from the image centre, in
    /// aperture radii.
    #[inline]
    pub fn barrel_shift_per_px(&self, lens: &ThinLens) -> f32 {
        self.barrel_distance_m / (lens.f_px * lens.lens_radius_m)
    }

    /// The radius of the barrel's opening in aperture radii ([`LensEffects::barrel`]).
    #[inline]
    pub fn barrel_radius(&self, lens: &ThinLens) -> f32 {
        self.barrel_radius_m.map_or(1.0, |r| r / lens.lens_radius_m)
    }

    /// Whether the lens point `v_lens` (in lens radii, after [`LensEffects::squeeze`]) reaches
    /// the pixel that sees the barrel `(shift, radius)` ([`LensEffects::barrel`]).
    #[inline]
    pub fn passes(&self, (shift, radius): (Vec2, f32), v_lens: Vec2) -> bool {
        (v_lens + shift).length_squared() <= radius * radius
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens() -> ThinLens {
        ThinLens {
            width_px: 200,
            height_px: 100,
            f_px: 100.0,
            lens_radius_m: 0.01,
            focus_m: 1.0,
            near_m: 0.01,
            far_m: 100.0,
        }
    }

    #[test]
    fn squeeze_keeps_the_area_and_sets_the_aspect() {
        let e = LensEffects {
            aspect: 0.5,
            ..LensEffects::default()
        };
        let x = e.squeeze(Vec2::X);
        let y = e.squeeze(Vec2::Y);
        assert!((x.x / y.y - 0.5).abs() < 1e-6);
        assert!((x.x * y.y - 1.0).abs() < 1e-6);
        assert_eq!(
            LensEffects::default().squeeze(Vec2::new(0.3, -0.7)),
            Vec2::new(0.3, -0.7)
        );
    }

    #[test]
    fn the_barrel_cuts_nothing_at_the_centre_and_a_lemon_at_the_edge() {
        let l = lens();
        let e = LensEffects {
            barrel_distance_m: 0.005,
            ..LensEffects::default()
        };
        // Centre: no shift, the whole unit disc passes.
        let b0 = e.barrel(&l, Vec2::new(100.0, 50.0));
        assert_eq!(b0, (Vec2::ZERO, 1.0));
        // 100 px right of the centre: tan theta = 1, shift 0.005 / 0.01 = 0.5 radii (pointing
        // outward); the lens points passing form the overlap of two unit discs 0.5 apart.
        let b = e.barrel(&l, Vec2::new(200.0, 50.0));
        assert!((b.0 - Vec2::new(0.5, 0.0)).length() < 1e-6);
        assert!(e.passes(b, Vec2::new(-0.7, 0.0)));
        assert!(!e.passes(b, Vec2::new(0.6, 0.0)));
        assert!(e.passes(b, Vec2::new(-0.25, 0.96)));
        assert!(!e.passes(b, Vec2::new(0.0, 0.99)));
        // A barrel of 20 mm radius around a 10 mm lens radius: no cut at this angle.
        let wide = LensEffects {
            barrel_radius_m: Some(0.02),
            ..e
        };
        let b = wide.barrel(&l, Vec2::new(200.0, 50.0));
        assert!(wide.passes(b, Vec2::new(0.99, 0.0)));
    }

    #[test]
    fn every_built_in_preset_reads_and_has_an_effect() {
        for (name, _) in PRESETS {
            let (effects, description) = LensEffects::preset(name).unwrap();
            assert!(!effects.is_ideal(), "{name}");
            assert!(!description.is_empty(), "{name}");
        }
        let (anamorphic, _) = LensEffects::preset("anamorphic-2x").unwrap();
        assert_eq!(anamorphic.aspect, 0.5);
        assert!(LensEffects::preset("no-such-lens").is_err());
    }

    #[test]
    fn ranges_are_checked() {
        for bad in [
            LensEffects {
                aspect: 0.0,
                ..LensEffects::default()
            },
            LensEffects {
                aspect: f32::NAN,
                ..LensEffects::default()
            },
            LensEffects {
                barrel_distance_m: -0.01,
                ..LensEffects::default()
            },
            LensEffects {
                barrel_radius_m: Some(0.0),
                ..LensEffects::default()
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
        assert!(LensEffects::default().validate().is_ok());
        assert!(LensEffects::default().is_ideal());
    }
}
