//! Raw command-line flags (clap). Validation and unit conversion happen in `commands`.

use std::path::PathBuf;

use clap::{Args, Parser, Subcommand};
use defocus::frames::Keyed;

use crate::common::{method_parser, parse_numbers, TimingFormat};

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
          help = format!("Worker threads, 1 to {} (default: all cores). Output is bit-identical for any count", crate::commands::MAX_THREADS))]
    pub threads: Option<usize>,
    /// No progress bar.
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Peak memory the layered methods may plan for, in GiB (default 16): a run that would need
    /// more is refused before it allocates, naming the option to lower.
    #[arg(long, global = true, value_name = "GIB", allow_negative_numbers = true)]
    pub memory_budget: Option<f64>,
}

/// Subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Render a scene (built-in or file) with a DoF method.
    Render(RenderArgs),
    /// Depth of field for a rendered colour image with a depth pass (or tilt-shift on a photo).
    Blur(Box<crate::blur::BlurArgs>),
    /// Compare two images: MSE (linear), PSNR and SSIM (sRGB, clamped to [0,1]).
    Compare(CompareArgs),
    /// Aperture kernels: singular values and low-rank approximation errors (McGraw eq. 4).
    Kernel(crate::kernel::KernelArgs),
}

/// Flags of `render`.
#[derive(Debug, Args, Clone)]
pub struct RenderArgs {
    /// Built-in scene name (railing, lights, grass, glass, traps) or a scene file (.gltf, .glb,
    /// .obj).
    #[arg(long, default_value = "railing", value_name = "NAME|PATH")]
    pub scene: String,
    /// DoF method (the library's registry).
    #[arg(long, default_value = "reference", value_parser = method_parser())]
    pub method: String,
    /// Samples: lens views for `reference` (default 256); lens rays per pixel for `multiview`
    /// (default 32); samples per pixel for `pinhole`
    /// (default 1 = pixel centres) and for the anti-aliased pinhole frame that the post-process
    /// methods blur (default 16, within 0.5 dB of a 256-sample frame on `railing` and `grass`;
    /// depth stays at pixel centres, as a renderer's Z pass).
    #[arg(long, value_name = "N")]
    pub samples: Option<usize>,
    /// Image width in pixels [default: the scene's, 1280 for built-in scenes].
    #[arg(long, value_name = "PX")]
    pub width: Option<usize>,
    /// Image height in pixels [default: the scene's, 720 for built-in scenes].
    #[arg(long, value_name = "PX")]
    pub height: Option<usize>,
    /// Focus distance in metres, along the view axis, or `auto`: the depth at the image centre
    /// (median of a small window of a pinhole render; the distance is printed)
    /// [default: the scene's]. With --frames, keyframes FRAME:M,... for a rack focus
    /// (`1:2.0,48:5.0`), interpolated linearly in 1/distance and held outside the keys.
    #[arg(long, value_name = "M|auto|F:M,...", value_parser = parse_focus, allow_negative_numbers = true)]
    pub focus: Option<Focus>,
    /// f-number N; the lens radius is focal length / (2 N) [default: the scene's]. With
    /// --frames, keyframes FRAME:N,... interpolated in stops (linearly in log N).
    #[arg(long, value_name = "N|F:N,...", value_parser = parse_fstop, allow_negative_numbers = true)]
    pub fstop: Option<Keyed>,
    /// Focal length in millimetres [default: the scene's, 50 mm for built-in scenes]. When the
    /// field of view comes from the scene file's camera or --fov, that field of view sets the
    /// projection and the focal length only sets the lens radius F / (2 N).
    #[arg(long, value_name = "MM", allow_negative_numbers = true)]
    pub focal_length: Option<f32>,
    /// Sensor width in millimetres, horizontal fit [default: the scene's, 36 mm]. No effect on
    /// the projection when the field of view comes from the scene file's camera or --fov.
    #[arg(long, value_name = "MM", allow_negative_numbers = true)]
    pub sensor_width: Option<f32>,
    /// Aperture: `disc`, `poly:B[,rot=DEG][,curve=R]` (B blades, rotation in degrees
    /// counter-clockwise, curved blades of radius R in aperture radii, R >= 1), `star[:N[,INNER]]`,
    /// `heart`, `ring[:INNER]` or `image:PATH` (a greyscale image used as density, as the
    /// far-field bokeh appears) [default: the scene's]. hammon, gaussian and multilayer (box filters) have no shape.
    #[arg(long, value_name = "SPEC")]
    pub aperture: Option<String>,
    /// Lens sampler: halton (low discrepancy), stratified, random.
    #[arg(long, default_value = "halton")]
    pub sampler: String,
    /// Seed of the lens/pixel sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Let a scene file read files outside its own folder (glTF URIs, OBJ mtllib, MTL maps
    /// that are absolute, use ../ or a link out). Off by default, so that a downloaded scene
    /// cannot read other files of yours and show them in the image or in errors.
    #[arg(long)]
    pub allow_external_files: bool,
    /// Output image: .exr (linear float RGBA), .png (8-bit sRGB) or .pfm. With --frames, a
    /// frame pattern: `shot.####.exr` (one digit per #), `shot.%04d.exr` or `shot.@.exr`.
    #[arg(long, default_value = "render.png", value_name = "FILE")]
    pub out: PathBuf,
    /// Also write the pinhole view-axis depth (metres, pixel centres, channel Z) to this EXR
    /// (a frame pattern with --frames).
    #[arg(long, value_name = "FILE.exr")]
    pub depth_out: Option<PathBuf>,
    /// Render a sequence: these frames (`1-48`, `1001-1100x2`, `1,5,10-20`) into the frame
    /// pattern of --out, with --focus and --fstop keyframed over them. Frames whose outputs
    /// exist are kept (an interrupted run resumes) unless --overwrite is given.
    #[arg(long, value_name = "FRAMES")]
    pub frames: Option<String>,
    /// With --frames: render frames whose outputs exist again, replacing them.
    #[arg(long, requires = "frames")]
    pub overwrite: bool,
    /// Set for the frames of a sequence: notes that every frame would repeat are not printed.
    #[arg(skip)]
    pub in_sequence: bool,
    /// Print per-pass timings: a table on stderr, or `--timings json` on stdout.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "table", value_name = "FORMAT")]
    pub timings: Option<TimingFormat>,
    /// Say what was run: method, paper, lens, and the peak bytes of the method's own storage
    /// where it tracks them (multilayer: fragment lists and filtered levels), on stderr.
    #[arg(long, short)]
    pub verbose: bool,
    /// EXR output options.
    #[command(flatten)]
    pub exr: crate::common::ExrArgs,
    /// Camera choice and placement (listed under their own heading).
    #[command(flatten)]
    pub view: Box<ViewArgs>,
    /// Options of the post-process methods (listed under their own heading).
    #[command(flatten)]
    pub post: Box<crate::post::PostArgs>,
}

/// Flags of `compare`: two images, or a report of every method against the reference.
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// Test image (EXR, PNG or PFM).
    pub a: Option<PathBuf>,
    /// Reference image (EXR, PNG or PFM), same size.
    pub b: Option<PathBuf>,
    /// Write a false-colour map of the absolute sRGB difference.
    #[arg(long, value_name = "FILE.png")]
    pub diff: Option<PathBuf>,
    /// Print one JSON object instead of `name: value` lines.
    #[arg(long)]
    pub json: bool,

    /// Report: render `reference` and every method on this scene (built-in name or file) and
    /// write DIR/index.html, DIR/results.json and every image.
    #[arg(long, value_name = "NAME|PATH", help_heading = "Report", conflicts_with_all = ["a", "b"])]
    pub scene: Option<String>,
    /// Report on a rendered frame: its colour image (with --depth and --truth).
    #[arg(long, value_name = "FILE", help_heading = "Report", requires_all = ["depth", "truth"], conflicts_with = "scene")]
    pub color: Option<PathBuf>,
    /// Report on a rendered frame: its depth pass (metres, view-axis; EXR, PFM or PNG).
    #[arg(long, value_name = "FILE", help_heading = "Report", requires = "color")]
    pub depth: Option<PathBuf>,
    /// Report on a rendered frame: the ground truth to compare with (e.g. from another renderer).
    #[arg(long, value_name = "FILE", help_heading = "Report", requires = "color")]
    pub truth: Option<PathBuf>,
    /// Report: the methods, `all` or a comma-separated list of ids.
    #[arg(
        long,
        default_value = "all",
        value_name = "all|ID,...",
        help_heading = "Report"
    )]
    pub methods: String,
    /// Report: lens samples of the reference.
    #[arg(long, default_value_t = 256, value_name = "N", help_heading = "Report")]
    pub reference_samples: usize,
    /// Report: run each method that has this setting once per value, e.g. `samples=8,16,32`,
    /// `merge=1,2,4`, `layers=1,4`, `fragments=4,16`, `rank=1,3,5`, `taps=16,64`,
    /// `filter-steps=1/3,2/2,4/0`, `layer-spacing=2,4,8` (repeatable).
    #[arg(long, value_name = "KEY=V1,V2,...", help_heading = "Report")]
    pub sweep: Vec<String>,
    /// Report: let a scene file read files outside its own folder (glTF URIs, OBJ mtllib, MTL maps
    /// that are absolute, use ../ or a link out). Off by default, so that a downloaded scene
    /// cannot read other files of yours and show them in the image or in errors.
    #[arg(long, help_heading = "Report")]
    pub allow_external_files: bool,
    /// Report: the output folder (created if absent).
    #[arg(long, value_name = "DIR", help_heading = "Report")]
    pub out: Option<PathBuf>,
    /// Report: image width in pixels [default: the scene's].
    #[arg(long, value_name = "PX", help_heading = "Report")]
    pub width: Option<usize>,
    /// Report: image height in pixels [default: the scene's].
    #[arg(long, value_name = "PX", help_heading = "Report")]
    pub height: Option<usize>,
    /// Report: focus distance in metres or `auto` [default: the scene's; `auto` for frames].
    #[arg(long, value_name = "M|auto", value_parser = parse_focus, allow_negative_numbers = true, help_heading = "Report")]
    pub focus: Option<Focus>,
    /// Report: f-number [default: the scene's; 2.8 for frames].
    #[arg(
        long,
        value_name = "N",
        allow_negative_numbers = true,
        help_heading = "Report"
    )]
    pub fstop: Option<f32>,
    /// Report: focal length in millimetres [default: the scene's; 50 for frames].
    #[arg(
        long,
        value_name = "MM",
        allow_negative_numbers = true,
        help_heading = "Report"
    )]
    pub focal_length: Option<f32>,
    /// Report: sensor width in millimetres [default: the scene's; 36 for frames].
    #[arg(
        long,
        value_name = "MM",
        allow_negative_numbers = true,
        help_heading = "Report"
    )]
    pub sensor_width: Option<f32>,
    /// Report: aperture (as `render --aperture`) [default: the scene's; disc for frames].
    #[arg(long, value_name = "SPEC", help_heading = "Report")]
    pub aperture: Option<String>,
    /// Report: also run `reference` at 4, 8, 16, 32, 64 and 128 lens samples (fewer than
    /// --reference-samples; another seed than the ground truth's) and mark each method as on
    /// the time-quality frontier or behind it (some `reference --samples N` is both faster and
    /// at least as good). Needs --scene.
    #[arg(long, help_heading = "Report", requires = "scene")]
    pub frontier: bool,
    /// Report: samples of the methods (as `render --samples`) [default: each method's].
    #[arg(long, value_name = "N", help_heading = "Report")]
    pub samples: Option<usize>,
    /// Report: seed of every sampler.
    #[arg(long, default_value_t = 0, help_heading = "Report")]
    pub seed: u64,
    /// Camera choice and placement (scene reports).
    #[command(flatten)]
    pub view: Box<ViewArgs>,
    /// Options of the methods.
    #[command(flatten)]
    pub post: Box<crate::post::PostArgs>,
}

impl CompareArgs {
    /// True for a report (a scene or a frame), false for two images.
    pub fn is_report(&self) -> bool {
        self.scene.is_some() || self.color.is_some()
    }
}

/// Flags of `render` that choose and place the camera (boxed in [`RenderArgs`] to keep
/// [`Command`] small).
#[derive(Debug, Args, Clone)]
#[command(next_help_heading = "Camera (scene files and views)")]
pub struct ViewArgs {
    /// Camera of the scene file: its index in the file's camera list or its name (node or
    /// camera) [default: the file's first camera, else a view of the whole scene from its +Z
    /// side].
    #[arg(long, value_name = "N|NAME")]
    pub camera: Option<String>,
    /// Camera position in metres, world space; the camera then looks at --look-at, else at the
    /// centre of the scene [default: the scene's camera].
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub look_from: Option<[f32; 3]>,
    /// Point the camera looks at, in metres, world space; also the focus distance unless
    /// --focus is given.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub look_at: Option<[f32; 3]>,
    /// World direction that is up on screen, with --look-from / --look-at [default: 0,1,0].
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3, allow_hyphen_values = true)]
    pub up: Option<[f32; 3]>,
    /// Vertical field of view in degrees; it then sets the projection and the focal length only
    /// the lens radius [default: the scene file camera's, else from --focal-length].
    #[arg(long, value_name = "DEG", allow_negative_numbers = true)]
    pub fov: Option<f32>,
    /// Focus on the surface at pixel X,Y (column, row from the top left), as --focus auto does
    /// at the centre.
    #[arg(long, value_name = "X,Y", value_parser = parse_pixel, conflicts_with = "focus")]
    pub focus_pixel: Option<(usize, usize)>,
}

/// `--focus`: a distance, `auto`, or keyframed distances (for a sequence).
#[derive(Clone, Debug, PartialEq)]
pub enum Focus {
    /// Focus distance in metres.
    Metres(f32),
    /// The depth at the image centre.
    Auto,
    /// Distances in metres keyed to frames (a rack focus over a sequence).
    Keys(Keyed),
}

pub fn parse_focus(s: &str) -> Result<Focus, String> {
    if s.trim() == "auto" {
        return Ok(Focus::Auto);
    }
    if s.contains(':') {
        return Keyed::parse(s, "--focus")
            .map(Focus::Keys)
            .map_err(|e| e.to_string());
    }
    s.trim()
        .parse()
        .map(Focus::Metres)
        .map_err(|_| format!("'{s}': expected a distance in metres or 'auto'"))
}

/// `--fstop`: an f-number, or keyframes `FRAME:N,...` (for a sequence).
pub fn parse_fstop(s: &str) -> Result<Keyed, String> {
    Keyed::parse(s, "--fstop").map_err(|e| e.to_string())
}

/// The one value of a flag that may hold keyframes; keyframes outside a sequence are refused.
pub fn single_value(k: &Keyed, flag: &str) -> anyhow::Result<f32> {
    match k.constant_value() {
        Some(v) => Ok(v),
        None => anyhow::bail!(
            "{flag} has keyframes: they need a frame sequence (a frame pattern such as \
             shot.####.exr and --frames)"
        ),
    }
}

/// Parses `X,Y,Z` (three finite numbers).
fn parse_vec3(s: &str) -> Result<[f32; 3], String> {
    parse_numbers(s)
        .and_then(|v| <[f32; 3]>::try_from(v).ok())
        .ok_or_else(|| format!("'{s}': expected three numbers X,Y,Z"))
}

/// Parses `X,Y` (two pixel indices).
pub(crate) fn parse_pixel(s: &str) -> Result<(usize, usize), String> {
    let (x, y) = s
        .split_once(',')
        .ok_or_else(|| format!("'{s}': expected a pixel column and row X,Y"))?;
    match (x.trim().parse(), y.trim().parse()) {
        (Ok(x), Ok(y)) => Ok((x, y)),
        _ => Err(format!(
            "'{s}': expected a pixel column and row X,Y (whole numbers from 0)"
        )),
    }
}
