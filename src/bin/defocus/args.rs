//! Raw command-line flags (clap): the command and its subcommands. Each subcommand's flags
//! live with its job (`render`, `blur`, `report`, `kernel`); validation and unit conversion
//! happen there.

use clap::{Parser, Subcommand};

/// Depth-of-field rendering: a thin-lens ground truth and the methods of the literature.
///
/// Units: distances in metres, focal length and sensor width in millimetres (full frame is
/// 36 mm wide), image sizes and blur radii in pixels. Colour is linear light; PNG output is
/// sRGB-encoded, EXR output stays linear (HDR kept).
#[derive(Debug, Parser)]
#[command(name = "defocus", version, about, long_about)]
pub struct Cli {
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
    /// Worker threads (default: all cores). Output is bit-identical for any count.
    #[arg(long, global = true, value_name = "N",
          help = format!("Worker threads, 1 to {} (default: all cores). Output is bit-identical for any count", crate::common::MAX_THREADS))]
    pub threads: Option<usize>,
    /// No progress bar.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Peak memory a run may plan for, in GiB (default 16; also `DEFOCUS_MEMORY_BUDGET_GIB`):
    /// images read (from their headers), scene files, meshes and textures, every method's frame
    /// and scene, and the lists and layers of splat and the layered methods are counted before
    /// they are allocated, and a run that would need more is refused, naming what to lower.
    #[arg(long, global = true, value_name = "GIB", allow_negative_numbers = true)]
    pub memory_budget: Option<f64>,
    /// Do not wait for each output to reach the disk (fsync) before it replaces its target.
    /// Outputs are still written whole or not at all, but a crash or power loss soon after may
    /// lose the last ones. Saves about 10 ms a 1920x1080 EXR on a local disk.
    #[arg(long, global = true)]
    pub no_fsync: bool,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Render a scene (built-in or file) with a DoF method.
    Render(defocus::jobs::render::RenderArgs),
    /// Depth of field for a rendered colour image with a depth pass (or tilt-shift on a photo).
    Blur(Box<defocus::jobs::blur::BlurArgs>),
    /// Compare two images: MSE (linear), PSNR and SSIM (sRGB, clamped to [0,1]).
    Compare(defocus::jobs::report::CompareArgs),
    /// Aperture kernels: singular values and low-rank approximation errors (McGraw eq. 4).
    Kernel(crate::kernel::KernelArgs),
    /// The GPU adapters found (name, backend, type, software or not, limits) and the one
    /// `--device auto` takes.
    Devices(crate::devices::DevicesArgs),
    /// Time the methods that run on the GPU on the built-in scenes, warm, per pass, as JSON on
    /// standard output.
    Bench(defocus::jobs::bench::BenchArgs),
}
