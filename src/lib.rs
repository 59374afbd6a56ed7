//! defocus: depth-of-field rendering on the CPU.
//!
//! One thin-lens model ([`lens::ThinLens`]) is shared by every method: the ground-truth
//! [`methods::reference`] renderer (multiview accumulation over the lens, Haeberli & Akeley)
//! and the post-process and layered methods of the papers. See `README.md` for conventions.
//!
//! The library never prints; it returns values and typed errors ([`Error`]).

pub mod autofocus;
pub mod blur;
pub mod budget;
pub mod error;
pub mod frames;
pub mod image;
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
