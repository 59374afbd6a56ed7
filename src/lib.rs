//! defocus: depth-of-field rendering on the CPU, and on the GPU through [`gpu`] (wgpu).
//!
//! One thin-lens model ([`lens::ThinLens`]) is shared by every method: the ground-truth
//! [`methods::reference`] renderer (multiview accumulation over the lens, Haeberli & Akeley)
//! and the post-process and layered methods of the papers. See `README.md` for conventions.
//!
//! The library never prints; it returns values and typed errors ([`Error`]).
//!
//! The methods are listed in [`methods::registry::METHODS`]; [`methods::registry::run_scene`]
//! runs any of them on a scene and [`methods::registry::run_frame`] the post-process ones on a
//! colour image with its depth pass. The command line (`defocus render`, `blur`, `compare`) is
//! a thin shell over [`jobs`]. The user guide is in `docs/` (`docs/SUMMARY.md`).
//!
//! # Example
//!
//! Render the built-in `railing` scene with `multilayer`, small, then blur a colour array and
//! its depth array (a compositor's input) with `lowrank`:
//!
//! ```
//! use defocus::image::{ColorImage, GrayImage};
//! use defocus::methods::registry::{self, Frame, MethodSettings, SceneOptions};
//!
//! # fn main() -> defocus::Result<()> {
//! // A built-in scene brings its own camera and aperture.
//! let scene = defocus::scene::builtin::load("railing")?;
//! let mut camera = scene.defaults.clone().expect("built-in scenes have a camera").camera;
//! (camera.width_px, camera.height_px) = (160, 90);
//! let settings = MethodSettings::default_for("multilayer")?;
//! let out = registry::run_scene(&settings, &scene, &camera, &SceneOptions::default(), &mut |_, _| {})?;
//! assert_eq!((out.image.width(), out.image.height()), (160, 90));
//! assert!(!out.timings.passes.is_empty()); // per-pass times, named `multilayer/<pass>`
//!
//! // A frame and its depth pass: linear premultiplied RGBA, view-axis depth in metres.
//! let (w, h) = (128, 96);
//! let color = ColorImage::from_vec(w, h, (0..w * h).map(|i| {
//!     let v = if (i % w / 8 + i / w / 8) % 2 == 0 { 1.0 } else { 0.0 };
//!     [v, v, v, 1.0]
//! }).collect())?;
//! let depth = GrayImage::new(w, h, 10.0); // everything 10 m away
//! camera.width_px = w;
//! camera.height_px = h;
//! (camera.focus_m, camera.fstop) = (0.5, 1.0); // focused near, wide open: the board blurs
//! let lens = camera.thin_lens()?;
//! assert!(lens.coc_px(10.0) > 4.0); // behind the focus: a positive CoC radius, in pixels
//! let blurred = registry::run_frame(
//!     &MethodSettings::default_for("lowrank")?,
//!     &Frame { color: &color, depth: &depth, lens: &lens },
//! )?;
//! // The middle of a white square turns grey, and a normalised kernel keeps the board's mean.
//! assert!(blurred.image.get(w / 2 + 4, h / 2 + 4)[0] < 0.8);
//! let mean = |img: &ColorImage| img.pixels().iter().map(|p| p[0] as f64).sum::<f64>() / (w * h) as f64;
//! assert!((mean(&blurred.image) - mean(&color)).abs() < 0.05);
//! # Ok(())
//! # }
//! ```

pub mod autofocus;
pub mod blur;
pub mod budget;
pub mod error;
pub mod frames;
pub mod gpu;
pub mod image;
pub mod input;
pub mod jobs;
pub mod lens;
pub mod methods;
pub mod metrics;
pub mod options;
pub mod output;
pub mod random;
pub mod raster;
pub mod scene;
pub mod timing;

pub use error::{Error, Result};
