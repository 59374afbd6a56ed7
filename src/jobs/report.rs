//! `defocus compare --scene S --out DIR` (or `--color C --depth D --truth T --out DIR`): every
//! method of the library's registry against the reference, as a page a person reads in a
//! browser (`index.html`: images, error maps, a table, a time/PSNR plot), the same numbers for
//! scripts (`results.json`), and every image as PNG (preview) and EXR (linear).
//!
//! Each method runs through the same jobs as `render` and `blur`, so a report's image is the
//! image those commands write with the same flags. A method that fails is reported in the page
//! with its error; the others still run.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::error::shown;
use crate::gpu::GpuContext;
use crate::image::{io, ColorImage};
use crate::methods::registry::{self, MethodInfo, METHODS};
use crate::methods::MethodOutput;
use crate::metrics;
use crate::timing::Timings;
use anyhow::{bail, Context, Result};
use base64::Engine as _;
use serde::Serialize;

use super::blur::{BlurArgs, BlurJob, DepthKind};
use super::flags::{
    check_input, device_name, parse_focus, DeviceArg, ExrArgs, ExrCompressionArg, Focus,
};
use super::grid;
use super::render::{RenderArgs, RenderJob, ViewArgs};
use crate::options::PostArgs;
use clap::Args;

/// The report's contact sheet: the truth and every method's image side by side, with their
/// PSNR and time (see [`grid`]).
pub const GRID_PNG: &str = "grid.png";

/// Sweep keys and the methods each applies to (the flag of that name changes their settings).
const SWEEPS: &[(&str, &[&str])] = &[
    (
        "samples",
        &[
            "pinhole",
            "hammon",
            "lowrank",
            "gaussian",
            "poisson",
            "splat",
            "multiview",
        ],
    ),
    ("merge", &["splat"]),
    ("layers", &["splat", "multiview"]),
    ("fragments", &["multilayer"]),
    ("epsilon", &["multilayer"]),
    ("filter-steps", &["multilayer"]),
    ("rank", &["lowrank"]),
    ("taps", &["poisson"]),
    ("layer-spacing", &["multiview"]),
];

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
    /// Report: the ground truth to compare with (e.g. from another renderer), instead of
    /// `reference` rendered with --reference-samples. Needed with --color; with --scene it
    /// must have the scene camera's size.
    #[arg(long, value_name = "FILE", help_heading = "Report", conflicts_with_all = ["a", "b"])]
    pub truth: Option<PathBuf>,
    /// Report: the methods, `all` or a comma-separated list of ids.
    #[arg(
        long,
        default_value = "all",
        value_name = "all|ID,...",
        help_heading = "Report"
    )]
    pub methods: String,
    /// Report: where the methods run, one or a comma-separated list: `cpu`, `gpu` (any
    /// adapter, a software one included), `auto` (a hardware GPU, else the CPU). With
    /// `cpu,gpu` each method that runs on the GPU runs on both, side by side; a method without
    /// GPU passes runs on the CPU only. The reference runs on the CPU.
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "cpu",
        value_name = "cpu|gpu|auto,...",
        help_heading = "Report"
    )]
    pub device: Vec<DeviceArg>,
    /// Report: lens samples of the reference.
    #[arg(long, default_value_t = 256, value_name = "N", help_heading = "Report")]
    pub reference_samples: usize,
    /// Report: run each method that has this setting once per value, e.g. `samples=8,16,32`,
    /// `merge=1,2,4`, `layers=1,4`, `fragments=4,16`, `rank=1,3,5`, `taps=16,64`,
    /// `filter-steps=1/3,2/2,4/0`, `layer-spacing=2,4,8` (repeatable). `METHOD.KEY=...` sweeps
    /// that method alone, e.g. `splat.layers=4` runs `splat --layers 4` beside `multiview` at
    /// its own layer count.
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
    pub post: Box<PostArgs>,
}

impl CompareArgs {
    /// True for a report (a scene or a frame), false for two images.
    pub fn is_report(&self) -> bool {
        self.scene.is_some() || self.color.is_some()
    }
}

/// One method run of the report, with the sweep setting it has (if any).
struct Run {
    info: &'static MethodInfo,
    setting: Option<(String, String)>,
    /// Whether it runs on the report's GPU (else the CPU).
    on_gpu: bool,
}

impl Run {
    /// File-name-safe label: `lowrank`, `splat-merge4`, `multilayer-filter-steps1-3`, and
    /// `-gpu` after a run on the GPU: `lowrank-gpu`.
    fn label(&self) -> String {
        let base = match &self.setting {
            None => self.info.id.to_string(),
            Some((k, v)) => format!("{}-{k}{}", self.info.id, v.replace(['/', ' ', '.'], "-")),
        };
        if self.on_gpu {
            format!("{base}-gpu")
        } else {
            base
        }
    }

    fn setting_text(&self) -> String {
        self.setting
            .as_ref()
            .map(|(k, v)| format!("{k}={v}"))
            .unwrap_or_default()
    }
}

/// What one run gave.
#[derive(Serialize)]
struct RunResult {
    method: String,
    setting: String,
    label: String,
    /// `cpu`, or the adapter's label.
    device: String,
    status: String,
    error: Option<String>,
    psnr_db: Option<f64>,
    ssim: Option<f64>,
    mse: Option<f64>,
    total_ms: Option<f64>,
    passes: Vec<crate::timing::PassTiming>,
    memory_bytes: Option<usize>,
    image_png: Option<String>,
    image_exr: Option<String>,
    error_map_png: Option<String>,
    /// With `--frontier`: `on`, or `behind` with the `reference` run that beats it.
    frontier: Option<String>,
}

/// One point of the time-quality frontier: `reference` at `samples` lens samples.
#[derive(Serialize)]
struct FrontierPoint {
    samples: usize,
    seed: u64,
    psnr_db: f64,
    ssim: f64,
    total_ms: f64,
}

/// Lens samples of the frontier's `reference` runs (those below the ground truth's).
const FRONTIER_SAMPLES: [usize; 6] = [4, 8, 16, 32, 64, 128];

/// Whether a run of `total_ms` and `psnr_db` is on the frontier: `on`, or `behind` naming the
/// fastest `reference` run that is at least as fast and at least as good.
fn frontier_verdict(points: &[FrontierPoint], total_ms: f64, psnr_db: f64) -> String {
    match points
        .iter()
        .filter(|p| p.total_ms <= total_ms && p.psnr_db >= psnr_db)
        .min_by(|a, b| a.total_ms.total_cmp(&b.total_ms))
    {
        Some(p) => format!(
            "behind: reference {} samples, {:.0} ms, {:.2} dB",
            p.samples, p.total_ms, p.psnr_db
        ),
        None => "on".to_string(),
    }
}

#[derive(Serialize)]
struct Report {
    title: String,
    width: usize,
    height: usize,
    parameters: Vec<(String, String)>,
    reference: ReferenceInfo,
    error_map_top: f32,
    runs: Vec<RunResult>,
    /// With `--frontier`: `reference` at a few sample counts, fastest first.
    frontier: Vec<FrontierPoint>,
    /// Every image file the report wrote, with its size and hash: the record by which the next
    /// report into this folder recognises the files it may remove.
    files: Vec<RecordedFile>,
}

/// An image file a report wrote, as recorded in its `results.json` (see [`Report::files`]).
#[derive(Serialize)]
struct RecordedFile {
    name: String,
    bytes: u64,
    sha256: String,
}

#[derive(Serialize)]
struct ReferenceInfo {
    source: String,
    total_ms: Option<f64>,
    image_png: String,
    image_exr: String,
}

fn parse_methods(spec: &str) -> Result<Vec<&'static MethodInfo>> {
    if spec.trim() == "all" {
        return Ok(METHODS.iter().filter(|m| m.id != "reference").collect());
    }
    let mut out = Vec::new();
    for id in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let m = registry::find(id).with_context(|| format!("invalid --methods '{spec}'"))?;
        if !out.iter().any(|o: &&MethodInfo| o.id == m.id) {
            out.push(m);
        }
    }
    if out.is_empty() {
        bail!("invalid --methods '{spec}': expected all or a comma-separated list of method ids");
    }
    Ok(out)
}

/// One `--sweep`: its key, its values, and the one method it is limited to (`METHOD.KEY=...`).
struct Sweep {
    method: Option<&'static str>,
    key: String,
    values: Vec<String>,
}

impl Sweep {
    /// Whether the sweep changes the settings of method `id`.
    fn applies_to(&self, id: &str) -> bool {
        self.method.is_none_or(|m| m == id)
            && SWEEPS
                .iter()
                .any(|(k, ids)| *k == self.key && ids.contains(&id))
    }
}

fn parse_sweeps(specs: &[String], methods: &[&'static MethodInfo]) -> Result<Vec<Sweep>> {
    let mut out = Vec::new();
    for spec in specs {
        let (k, v) = spec.split_once('=').with_context(|| {
            format!(
                "invalid --sweep '{spec}': expected KEY=V1,V2,... or METHOD.KEY=V1,V2,... \
                 (e.g. samples=8,16,32, splat.layers=4)"
            )
        })?;
        let (method, k) = match k.trim().split_once('.') {
            Some((m, k)) => (Some(m.trim()), k.trim().to_string()),
            None => (None, k.trim().to_string()),
        };
        let Some((_, ids)) = SWEEPS.iter().find(|(key, _)| *key == k) else {
            bail!(
                "invalid --sweep '{spec}': unknown key '{k}' (expected one of: {})",
                SWEEPS.iter().map(|s| s.0).collect::<Vec<_>>().join(", ")
            );
        };
        let method = match method {
            None => {
                // A key that no run takes would change nothing: refused, not ignored.
                if !methods.iter().any(|info| ids.contains(&info.id)) {
                    bail!(
                        "invalid --sweep '{spec}': no method among --methods ({}) takes '{k}' \
                         (it is a setting of: {})",
                        methods.iter().map(|i| i.id).collect::<Vec<_>>().join(","),
                        ids.join(", ")
                    );
                }
                None
            }
            Some(m) => {
                let Some(&id) = ids.iter().find(|id| **id == m) else {
                    bail!(
                        "invalid --sweep '{spec}': '{k}' is not a setting of method '{m}' \
                         (it is one of: {})",
                        ids.join(", ")
                    );
                };
                if !methods.iter().any(|info| info.id == id) {
                    bail!(
                        "invalid --sweep '{spec}': method '{id}' is not among --methods \
                         ({})",
                        methods.iter().map(|i| i.id).collect::<Vec<_>>().join(",")
                    );
                }
                Some(id)
            }
        };
        let values: Vec<String> = v
            .split(',')
            .map(|s| s.trim().to_string())
            .filter(|s| !s.is_empty())
            .collect();
        if values.is_empty() {
            bail!("invalid --sweep '{spec}': no values");
        }
        out.push(Sweep {
            method,
            key: k,
            values,
        });
    }
    Ok(out)
}

/// Every run of the report: each method (once per sweep value that applies to it) on each
/// device of `devices` (`false` the CPU, `true` the GPU) that it runs on; a method without GPU
/// passes runs on the CPU once.
fn runs(methods: &[&'static MethodInfo], sweeps: &[Sweep], devices: &[bool]) -> Vec<Run> {
    let mut out = Vec::new();
    for &info in methods {
        let mut on: Vec<bool> = devices
            .iter()
            .copied()
            .filter(|&gpu| !gpu || info.gpu)
            .collect();
        if on.is_empty() {
            on.push(false);
        }
        let settings: Vec<Option<(String, String)>> = {
            let swept: Vec<_> = sweeps
                .iter()
                .filter(|s| s.applies_to(info.id))
                .flat_map(|s| s.values.iter().map(|v| Some((s.key.clone(), v.clone()))))
                .collect();
            if swept.is_empty() {
                vec![None]
            } else {
                swept
            }
        };
        for setting in settings {
            for &on_gpu in &on {
                out.push(Run {
                    info,
                    setting: setting.clone(),
                    on_gpu,
                });
            }
        }
    }
    out
}

/// The devices of `--device` as the report runs them (`false` the CPU, `true` the GPU, each
/// once) and the GPU context they share, opened once; `auto` is the GPU where there is a
/// hardware one, else the CPU.
fn report_devices(list: &[DeviceArg]) -> Result<(Vec<bool>, Option<Arc<GpuContext>>)> {
    let mut gpu: Option<Arc<GpuContext>> = None;
    let mut devices = Vec::new();
    for &d in list {
        let on_gpu = match d {
            DeviceArg::Cpu => false,
            DeviceArg::Gpu | DeviceArg::Auto => {
                if gpu.is_none() {
                    gpu = GpuContext::open(d.into())
                        .context("--device")?
                        .map(Arc::new);
                }
                gpu.is_some()
            }
        };
        if !devices.contains(&on_gpu) {
            devices.push(on_gpu);
        }
    }
    if devices.is_empty() {
        devices.push(false);
    }
    Ok((devices, gpu))
}

/// Applies a sweep setting to the flags.
fn apply_setting(
    post: &mut PostArgs,
    samples: &mut Option<usize>,
    setting: &Option<(String, String)>,
) -> Result<()> {
    let Some((k, v)) = setting else {
        return Ok(());
    };
    let bad = || anyhow::anyhow!("invalid --sweep {k}={v}: not a valid value of --{k}");
    match k.as_str() {
        "samples" => *samples = Some(v.parse().map_err(|_| bad())?),
        "merge" => post.merge = v.parse().map_err(|_| bad())?,
        "layers" => post.layers = Some(v.parse().map_err(|_| bad())?),
        "fragments" => post.fragments = v.parse().map_err(|_| bad())?,
        "epsilon" => post.epsilon = v.parse().map_err(|_| bad())?,
        "filter-steps" => post.filter_steps = v.clone(),
        "rank" => post.rank = v.parse().map_err(|_| bad())?,
        "taps" => post.taps = v.parse().map_err(|_| bad())?,
        "layer-spacing" => post.layer_spacing = v.parse().map_err(|_| bad())?,
        _ => return Err(bad()),
    }
    Ok(())
}

/// Checks the flags of `run` (its sweep value applied) as the run itself would, without
/// reading or rendering anything: a bad sweep value fails the report before its first render.
fn check_run(a: &CompareArgs, run: &Run) -> Result<()> {
    // A method that does not render a lens effect given is marked in the report, not checked.
    if !unsupported_effects(a, run.info)?.is_empty() {
        return Ok(());
    }
    let mut post = a.post.clone();
    let mut samples = a.samples;
    apply_setting(&mut post, &mut samples, &run.setting)?;
    let what = || match &run.setting {
        Some((k, v)) => format!("invalid --sweep {k}={v}"),
        None => format!("invalid flags for {}", run.info.id),
    };
    if let Some(n) = samples {
        if !(1..=1 << 20).contains(&n) {
            bail!("{}: expected --samples 1 to {}", what(), 1 << 20);
        }
    }
    // `--large-blur-coc auto` needs the run's lens, resolved when it runs.
    if post.large_blur_coc_is_auto() {
        post.large_blur_coc = None;
    }
    let height = a.height.unwrap_or(720);
    post.settings(
        run.info.id,
        &crate::lens::Aperture::Disc,
        a.seed,
        height,
        None,
    )
    .with_context(what)?;
    Ok(())
}

/// The lens effects given (`--lens`, `--anamorphic`, ...) that `method` does not render.
fn unsupported_effects(a: &CompareArgs, method: &MethodInfo) -> Result<Vec<&'static str>> {
    Ok(a.post
        .lens_effects()?
        .active()
        .into_iter()
        .filter(|e| !method.effects.contains(e))
        .collect())
}

/// The `render` flags of a run on a scene.
fn render_args(a: &CompareArgs, scene: &str, method: &str, out: &Path) -> RenderArgs {
    RenderArgs {
        scene: scene.to_string(),
        method: method.to_string(),
        samples: a.samples,
        width: a.width,
        height: a.height,
        focus: a.focus.clone(),
        fstop: a.fstop.map(crate::frames::Keyed::constant),
        focal_length: a.focal_length,
        sensor_width: a.sensor_width,
        aperture: a.aperture.clone(),
        sampler: "halton".to_string(),
        seed: a.seed,
        allow_external_files: a.allow_external_files,
        out: out.to_path_buf(),
        depth_out: None,
        frames: None,
        overwrite: false,
        in_sequence: false,
        device: DeviceArg::Cpu,
        timings: None,
        verbose: false,
        exr: ExrArgs {
            exr_compression: ExrCompressionArg::None,
            half: false,
        },
        view: a.view.clone(),
        post: a.post.clone(),
    }
}

/// The `blur` flags of a run on a frame.
fn blur_args(a: &CompareArgs, method: &str, out: &Path) -> Result<BlurArgs> {
    Ok(BlurArgs {
        color: a.color.clone().context("--color")?,
        depth: a.depth.clone(),
        depth_channel: None,
        depth_kind: DepthKind::View,
        depth_scale: 1.0,
        zero_depth_is_far: false,
        method: Some(method.to_string()),
        focus: match a.focus {
            Some(Focus::Metres(m)) => m.to_string(),
            _ => "auto".to_string(),
        },
        focus_pixel: a.view.focus_pixel,
        fstop: crate::frames::Keyed::constant(a.fstop.unwrap_or(2.8)),
        focal_length: a.focal_length.unwrap_or(50.0),
        sensor_width: a.sensor_width.unwrap_or(36.0),
        aperture: a.aperture.clone().unwrap_or_else(|| "disc".to_string()),
        seed: a.seed,
        tilt_shift: None,
        out: out.to_path_buf(),
        frames: None,
        overwrite: false,
        in_sequence: false,
        device: DeviceArg::Cpu,
        timings: None,
        coc_out: None,
        verbose: false,
        sanitize: false,
        highlights: None,
        exr: ExrArgs {
            exr_compression: ExrCompressionArg::None,
            half: false,
        },
        post: (*a.post).clone(),
    })
}

/// How far a report has got: `done` of `total` method runs (the reference first), and what
/// runs now.
pub struct Progress<'a> {
    /// Runs finished.
    pub done: u64,
    /// Runs in all (the frontier's `reference` runs are not counted).
    pub total: u64,
    /// The run under way.
    pub running: &'a str,
}

/// A report written.
#[derive(Debug)]
pub struct Written {
    /// Its page, `DIR/index.html`.
    pub index_html: PathBuf,
    /// What `DIR/results.json` holds.
    pub results: serde_json::Value,
    /// The labels of the runs that failed (their errors are in the report).
    pub failed: Vec<String>,
    /// The runs in all.
    pub runs: usize,
}

/// Writes the report `a` asks for into its `--out` folder (every file staged, then renamed
/// into it together). `progress` follows the runs; `notes` receives the lines the command line
/// shows (the focus picked, skipped cameras). A run that fails is a row of the report, not an
/// error: see [`Written::failed`].
pub fn write(
    a: &CompareArgs,
    progress: &mut dyn FnMut(Progress),
    notes: &mut dyn FnMut(String),
) -> Result<Written> {
    if !a.is_report() {
        bail!("a report needs --scene NAME|PATH, or --color, --depth and --truth (a rendered frame and its ground truth)");
    }
    if matches!(a.focus, Some(Focus::Keys(_))) {
        bail!("invalid --focus: keyframes are for sequences (render or blur with --frames); a report takes one distance or auto");
    }
    let dir = a.out.clone().context(
        "a report needs --out DIR (the folder for index.html, results.json and the images)",
    )?;
    if dir.exists() && !dir.is_dir() {
        bail!(
            "invalid --out {}: it exists and is not a folder",
            shown(&dir)
        );
    }
    if a.frontier && a.scene.is_none() {
        bail!("--frontier needs --scene: the frontier is `reference` rendered from the scene at fewer samples");
    }
    if !(1..=1 << 20).contains(&a.reference_samples) {
        bail!(
            "invalid --reference-samples {}: expected 1 to {}",
            a.reference_samples,
            1 << 20
        );
    }
    let methods = parse_methods(&a.methods)?;
    let sweeps = parse_sweeps(&a.sweep, &methods)?;
    let (devices, gpu) = report_devices(&a.device)?;
    let runs = runs(&methods, &sweeps, &devices);
    // No file the report writes may be one of its inputs: checked before anything is read.
    let names = file_names(&runs);
    let mut inputs = named_inputs(a)?;
    for (flag, input) in &inputs {
        check_not_written(&dir, &names, flag, input)?;
    }
    // Every run's flags, sweep values included, are checked before anything is rendered.
    for run in &runs {
        check_run(a, run)?;
    }
    // Made now (the runs' checks need it), and removed again if the report fails after all.
    let made = MadeFolders::create(&dir)
        .with_context(|| format!("could not create the report folder {}", shown(&dir)))?;
    let total = runs.len() as u64 + 1;
    let mut done = 0;
    progress(Progress {
        done,
        total,
        running: "reference",
    });

    // The reference: rendered, or read.
    let mut parameters: Vec<(String, String)> = Vec::new();
    let (truth, truth_ms, title, source) = if let Some(scene) = &a.scene {
        let mut args = render_args(a, scene, "reference", &dir.join("reference.exr"));
        args.samples = Some(a.reference_samples);
        let job = RenderJob::new(args, notes)?;
        // The files the scene file refers to, known once it is loaded.
        for input in job.inputs() {
            if !inputs.iter().any(|(_, p)| p == input) {
                check_not_written(&dir, &names, "--scene (a file it reads)", input)?;
                inputs.push(("--scene".to_string(), input.clone()));
            }
        }
        let cam = job.camera().clone();
        let lens = cam.thin_lens()?;
        parameters.extend([
            ("scene".to_string(), shown(scene)),
            (
                "resolution".to_string(),
                format!("{}x{}", cam.width_px, cam.height_px),
            ),
            ("focus".to_string(), format!("{:.4} m", cam.focus_m)),
            ("f-number".to_string(), format!("{}", cam.fstop)),
            (
                "focal length".to_string(),
                format!("{} mm", cam.focal_length_mm),
            ),
            (
                "CoC at infinity".to_string(),
                format!("{:.2} px", lens.coc_at_infinity_px()),
            ),
            (
                "aperture".to_string(),
                a.aperture.clone().unwrap_or_else(|| "scene default".into()),
            ),
            (
                "reference".to_string(),
                format!(
                    "{} lens samples (Halton, seed {})",
                    a.reference_samples, a.seed
                ),
            ),
        ]);
        if let Some(truth_path) = &a.truth {
            // Another renderer's truth of the same scene and camera.
            let truth = io::read_color(truth_path)?;
            if (truth.width(), truth.height()) != (cam.width_px, cam.height_px) {
                bail!(
                    "--truth {} is {}x{} but the scene's camera renders {}x{}: expected the same size (set --width and --height)",
                    shown(truth_path),
                    truth.width(),
                    truth.height(),
                    cam.width_px,
                    cam.height_px
                );
            }
            let last = parameters.len() - 1;
            parameters[last] = ("truth".to_string(), shown(truth_path));
            (
                truth,
                None,
                format!("defocus report: {}", shown(scene)),
                format!("ground truth {}", shown(truth_path)),
            )
        } else {
            let out = job.compute(&mut |_, _| {})?;
            let ms = out.timings.total_ms();
            (
                out.image,
                Some(ms),
                format!("defocus report: {}", shown(scene)),
                format!("reference, {} lens samples", a.reference_samples),
            )
        }
    } else {
        let truth_path = a.truth.clone().context("--truth")?;
        let truth = io::read_color(&truth_path)?;
        let color_path = a.color.clone().context("--color")?;
        // A truth of another size fails every run: refused before the first.
        let color = io::read_color(&color_path)?;
        if !color.same_size(&truth) {
            bail!(
                "--truth {} is {}x{} but --color {} is {}x{}: expected the same size",
                shown(&truth_path),
                truth.width(),
                truth.height(),
                shown(&color_path),
                color.width(),
                color.height()
            );
        }
        drop(color);
        parameters.extend([
            ("colour".to_string(), shown(&color_path)),
            (
                "depth".to_string(),
                a.depth.as_ref().map(|p| shown(&p)).unwrap_or_default(),
            ),
            ("truth".to_string(), shown(&truth_path)),
            (
                "resolution".to_string(),
                format!("{}x{}", truth.width(), truth.height()),
            ),
            (
                "f-number".to_string(),
                format!("{}", a.fstop.unwrap_or(2.8)),
            ),
            (
                "focal length".to_string(),
                format!("{} mm", a.focal_length.unwrap_or(50.0)),
            ),
        ]);
        (
            truth,
            None,
            format!(
                "defocus report: {}",
                color_path
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            ),
            format!("ground truth {}", shown(&truth_path)),
        )
    };
    if !a.sweep.is_empty() {
        parameters.push(("sweeps".to_string(), a.sweep.join(" ")));
    }
    let effects = a.post.lens_effects()?.active();
    if !effects.is_empty() {
        parameters.push((
            "lens effects".to_string(),
            format!(
                "{} (methods that do not render them are marked unsupported)",
                effects.join(", ")
            ),
        ));
    }
    done += 1;
    // Every file of the report is staged and renamed into the folder at the end, all together.
    let mut files = ReportFiles::new(&dir);
    files.exr("reference.exr", &truth)?;
    files.png("reference.png", &truth)?;

    // Every run.
    let mut outputs: Vec<(usize, MethodOutput)> = Vec::new();
    let mut results: Vec<RunResult> = Vec::new();
    for (i, run) in runs.iter().enumerate() {
        let label = run.label();
        progress(Progress {
            done,
            total,
            running: &label,
        });
        let out_path = dir.join(format!("{label}.exr"));
        // The images kept for the error maps (the truth's and every run's so far) are held
        // while this run runs: counted with its estimate against the budget.
        let kept = (outputs.len() as u64 + 1) * truth.pixels().len() as u64 * 16;
        // The device the run took: `--device auto` runs on the CPU what the GPU does not cover.
        let mut ran_on: Option<String> = None;
        let outcome: Result<MethodOutput> = (|| {
            crate::budget::check(
                kept + registry::peak_bytes(
                    &registry::MethodSettings::default_for(run.info.id)?,
                    truth.width(),
                    truth.height(),
                ),
                &format!(
                    "{label} beside the {} images the report keeps",
                    outputs.len() + 1
                ),
                "--methods or the resolution",
            )?;
            let missing = unsupported_effects(a, run.info)?;
            if !missing.is_empty() {
                bail!(
                    "unsupported: does not render the lens effect {}",
                    missing.join(", ")
                );
            }
            if a.scene.is_some() {
                let mut args =
                    render_args(a, a.scene.as_deref().unwrap_or(""), run.info.id, &out_path);
                apply_setting(&mut args.post, &mut args.samples, &run.setting)?;
                let on = gpu.clone().filter(|_| run.on_gpu);
                let job = RenderJob::new_on(args, on, notes)?;
                ran_on = Some(job.device());
                job.compute(&mut |_, _| {})
            } else {
                if !run.info.input.takes_frame() {
                    bail!("not applicable: needs {}", run.info.input.describe());
                }
                let mut args = blur_args(a, run.info.id, &out_path)?;
                let mut samples = None;
                apply_setting(&mut args.post, &mut samples, &run.setting)?;
                if samples.is_some() {
                    bail!("not applicable: the frame is given, so its samples cannot change");
                }
                let on = gpu.clone().filter(|_| run.on_gpu);
                BlurJob::new_on(&args, on, notes)?.compute()
            }
        })();
        let mut r = RunResult {
            method: run.info.id.to_string(),
            setting: run.setting_text(),
            label: label.clone(),
            device: ran_on.unwrap_or_else(|| device_name(gpu.as_deref().filter(|_| run.on_gpu))),
            status: "ok".to_string(),
            error: None,
            psnr_db: None,
            ssim: None,
            mse: None,
            total_ms: None,
            passes: Vec::new(),
            memory_bytes: None,
            image_png: None,
            image_exr: None,
            error_map_png: None,
            frontier: None,
        };
        match outcome.and_then(|o| {
            if !o.image.same_size(&truth) {
                bail!(
                    "the output is {}x{} but the reference is {}x{}",
                    o.image.width(),
                    o.image.height(),
                    truth.width(),
                    truth.height()
                );
            }
            Ok(o)
        }) {
            Ok(o) => {
                let m = metrics::compare(&o.image, &truth)?;
                r.psnr_db = Some(m.psnr_db);
                r.ssim = Some(m.ssim);
                r.mse = Some(m.mse_linear);
                r.total_ms = Some(without_io(&o.timings));
                r.passes = o.timings.passes.clone();
                r.memory_bytes = o.memory_bytes;
                files.exr(&format!("{label}.exr"), &o.image)?;
                files.png(&format!("{label}.png"), &o.image)?;
                r.image_exr = Some(format!("{label}.exr"));
                r.image_png = Some(format!("{label}.png"));
                outputs.push((i, o));
            }
            Err(e) => {
                let text = shown(&format!("{e:#}"));
                r.status = if text.starts_with("not applicable") {
                    "not applicable".to_string()
                } else if text.starts_with("unsupported") {
                    "unsupported".to_string()
                } else {
                    "failed".to_string()
                };
                r.error = Some(text);
            }
        }
        results.push(r);
        done += 1;
    }
    // The frontier: `reference` at a few sample counts, with another seed than the truth's.
    let mut frontier = Vec::new();
    if a.frontier {
        let scene = a.scene.as_deref().context("--frontier needs --scene")?;
        let seed = a.seed.wrapping_add(1);
        for n in FRONTIER_SAMPLES
            .into_iter()
            .filter(|&n| n < a.reference_samples)
        {
            progress(Progress {
                done,
                total,
                running: &format!("frontier: reference {n}"),
            });
            let mut args = render_args(a, scene, "reference", &dir.join("frontier.exr"));
            args.samples = Some(n);
            args.seed = seed;
            let out = RenderJob::new(args, notes)?.compute(&mut |_, _| {})?;
            let m = metrics::compare(&out.image, &truth)?;
            frontier.push(FrontierPoint {
                samples: n,
                seed,
                psnr_db: m.psnr_db,
                ssim: m.ssim,
                total_ms: without_io(&out.timings),
            });
        }
        for r in &mut results {
            if let (Some(t), Some(p)) = (r.total_ms, r.psnr_db) {
                r.frontier = Some(frontier_verdict(&frontier, t, p));
            }
        }
    }
    progress(Progress {
        done,
        total,
        running: "",
    });

    // Error maps on one scale: the largest of the methods' 99th-percentile differences.
    let mut top = metrics::ERROR_MAP_MIN_TOP;
    for (_, o) in &outputs {
        top = top.max(metrics::error_map_top(&metrics::srgb_abs_diff(
            &o.image, &truth,
        )?));
    }
    for (i, o) in &outputs {
        let map = metrics::error_map_with_top(&o.image, &truth, top)?;
        let name = format!("{}-error.png", results[*i].label);
        files.png(&name, &map)?;
        results[*i].error_map_png = Some(name);
    }
    let legend = legend_image()?;
    files.png("error-legend.png", &legend)?;
    // The contact sheet: the truth, then every run that gave an image, with its numbers.
    let truth_caption = match truth_ms {
        Some(ms) => format!("{} views {ms:.0} ms", a.reference_samples),
        None => "ground truth".to_string(),
    };
    let mut tiles = vec![grid::Tile {
        image: &truth,
        caption: vec!["truth".to_string(), truth_caption],
    }];
    for (i, o) in &outputs {
        let r = &results[*i];
        tiles.push(grid::Tile {
            image: &o.image,
            caption: vec![
                r.label.clone(),
                format!(
                    "{:.1} dB {:.0} ms",
                    r.psnr_db.unwrap_or(f64::NAN),
                    r.total_ms.unwrap_or(f64::NAN)
                ),
            ],
        });
    }
    files.png(GRID_PNG, &grid::contact_sheet(&tiles, grid::TILE_WIDTH_PX))?;

    // The record of the images, made from the staged files: what this report wrote.
    let mut recorded = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for name in image_names(&results) {
        if seen.insert(name.clone()) {
            let digest = files.set.staged_digest(&dir.join(&name))?;
            recorded.push(RecordedFile {
                name,
                bytes: digest.bytes,
                sha256: digest.sha256,
            });
        }
    }
    let report = Report {
        title,
        width: truth.width(),
        height: truth.height(),
        parameters,
        reference: ReferenceInfo {
            source,
            total_ms: truth_ms,
            image_png: "reference.png".to_string(),
            image_exr: "reference.exr".to_string(),
        },
        error_map_top: top,
        runs: results,
        frontier,
        files: recorded,
    };
    let json = serde_json::to_string_pretty(&report)?;
    files.text("results.json", &json)?;
    let html = page(&report, &files)?;
    files.text("index.html", &html)?;
    // One report at a time replaces the folder's files: the one before is read, replaced and
    // its images this one does not replace removed under the folder's lock, so that two reports
    // into one folder never leave a `results.json` naming images the other removed.
    let _lock = crate::output::FolderLock::acquire(&dir, || {
        notes(format!(
            "waiting: another report is being written into {}",
            shown(&dir)
        ))
    })
    .with_context(|| format!("could not lock the report folder {}", shown(&dir)))?;
    let before = previous_record(&dir);
    files.set.commit()?;
    let now: Vec<&str> = report.files.iter().map(|f| f.name.as_str()).collect();
    for (name, digest) in before.iter().filter(|(n, _)| !now.contains(&n.as_str())) {
        let path = dir.join(name);
        // Only a file that is still exactly what the earlier report wrote (never through a
        // link), and never an input of this one.
        let is_input = inputs.iter().any(|(_, i)| io::same_file(i, &path));
        if !is_input && digest.matches_file(&path) {
            let _ = std::fs::remove_file(&path);
        }
    }
    made.keep();
    let failed = report
        .runs
        .iter()
        .filter(|r| r.status == "failed")
        .map(|r| r.label.clone())
        .collect();
    Ok(Written {
        index_html: dir.join("index.html"),
        // Parsed back from the text written, so the values are the file's to the last digit.
        results: serde_json::from_str(&json)?,
        failed,
        runs: report.runs.len(),
    })
}

/// The folders a report made for its `--out`: the folder and the parents it lacked, innermost
/// first. Dropped before [`MadeFolders::keep`] (the report failed), it removes those that are
/// still empty, so a refused report leaves no empty folder behind; a folder that existed before
/// is never removed.
struct MadeFolders {
    made: Vec<PathBuf>,
}

impl MadeFolders {
    /// Creates `dir` and its missing parents.
    fn create(dir: &Path) -> std::io::Result<MadeFolders> {
        let mut made = Vec::new();
        let mut next = Some(dir);
        while let Some(d) = next.filter(|d| !d.as_os_str().is_empty()) {
            if std::fs::symlink_metadata(d).is_ok() {
                break;
            }
            made.push(d.to_path_buf());
            next = d.parent();
        }
        // Built first: a creation that fails half-way removes what it made.
        let folders = MadeFolders { made };
        std::fs::create_dir_all(dir)?;
        Ok(folders)
    }

    /// Keeps the folders: the report is written.
    fn keep(mut self) {
        self.made.clear();
    }
}

impl Drop for MadeFolders {
    fn drop(&mut self) {
        for d in &self.made {
            // Only an empty folder is removed.
            if std::fs::remove_dir(d).is_err() {
                break;
            }
        }
    }
}

/// The image files a report with `results` writes, in the order written.
fn image_names(results: &[RunResult]) -> Vec<String> {
    let mut names = vec!["reference.exr".to_string(), "reference.png".to_string()];
    for r in results {
        names.extend(
            [&r.image_exr, &r.image_png, &r.error_map_png]
                .into_iter()
                .flatten()
                .cloned(),
        );
    }
    names.extend(["error-legend.png".to_string(), GRID_PNG.to_string()]);
    names
}

/// Every file a report of `runs` may write into its folder (each run's images whether it
/// succeeds or not): known before anything runs.
fn file_names(runs: &[Run]) -> Vec<String> {
    let mut names: Vec<String> = [
        "reference.exr",
        "reference.png",
        "error-legend.png",
        GRID_PNG,
        "results.json",
        "index.html",
    ]
    .map(String::from)
    .to_vec();
    for run in runs {
        let label = run.label();
        names.extend([
            format!("{label}.exr"),
            format!("{label}.png"),
            format!("{label}-error.png"),
        ]);
    }
    names
}

/// The files a report reads that the flags name, each with its flag: the images of a frame,
/// the truth, the aperture image, the lens preset file and the scene file (the files a scene
/// refers to are known once it is loaded). Images are checked to be regular files.
fn named_inputs(a: &CompareArgs) -> Result<Vec<(String, PathBuf)>> {
    let mut inputs = Vec::new();
    for (flag, path) in [
        ("--truth", &a.truth),
        ("--color", &a.color),
        ("--depth", &a.depth),
    ] {
        if let Some(p) = path {
            check_input(p, flag)?;
            inputs.push((flag.to_string(), p.clone()));
        }
    }
    if let Some(p) = a.aperture.as_deref().and_then(|s| s.strip_prefix("image:")) {
        inputs.push(("--aperture image:".to_string(), PathBuf::from(p)));
    }
    if let Some(p) = a.post.lens_file() {
        inputs.push(("--lens".to_string(), p));
    }
    if let Some(scene) = &a.scene {
        if Path::new(scene).exists() {
            inputs.push(("--scene".to_string(), PathBuf::from(scene)));
        }
    }
    Ok(inputs)
}

/// Refuses an input (named by `flag`) that is one of the files `names` of the report folder
/// `dir`: the report would replace it. Compared as files, not as spellings (links, `./`, hard
/// links).
fn check_not_written(dir: &Path, names: &[String], flag: &str, input: &Path) -> Result<()> {
    if let Some(name) = names.iter().find(|n| io::same_file(input, &dir.join(n))) {
        bail!(
            "{flag} {} is the report's file {name} in --out {}: the report would replace it; \
             choose another --out folder, or move the input out of it",
            shown(input),
            shown(dir)
        );
    }
    Ok(())
}

/// Most bytes of a `results.json` read for its record (a report's is far smaller; a larger
/// file is not a report's, and nothing of it is removed).
const MAX_RESULTS_JSON_BYTES: u64 = 64 << 20;

/// The image files the report before this one in `dir` recorded in its `results.json`, with
/// their digests: only plain file names of PNG and EXR images in the folder (a planted
/// `results.json` cannot name files elsewhere), and only those it recorded with a digest (a
/// file is removed only if it still matches).
fn previous_record(dir: &Path) -> Vec<(String, crate::output::Digest)> {
    let Ok(file) = crate::input::open_regular(&dir.join("results.json")) else {
        return Vec::new();
    };
    // Judged by its size before it is read.
    if !file
        .metadata()
        .is_ok_and(|m| m.len() <= MAX_RESULTS_JSON_BYTES)
    {
        return Vec::new();
    }
    let mut text = String::new();
    if std::io::Read::read_to_string(
        &mut std::io::Read::take(file, MAX_RESULTS_JSON_BYTES + 1),
        &mut text,
    )
    .is_err()
        || text.len() as u64 > MAX_RESULTS_JSON_BYTES
    {
        return Vec::new();
    }
    let Ok(value) = serde_json::from_str::<serde_json::Value>(&text) else {
        return Vec::new();
    };
    let mut record = Vec::new();
    for f in value["files"].as_array().into_iter().flatten() {
        let (Some(name), Some(bytes), Some(sha256)) = (
            f["name"].as_str(),
            f["bytes"].as_u64(),
            f["sha256"].as_str(),
        ) else {
            continue;
        };
        let plain =
            Path::new(name).file_name().is_some_and(|n| n == name) && !name.starts_with('.');
        let image = name.ends_with(".png") || name.ends_with(".exr");
        if plain && image {
            record.push((
                name.to_string(),
                crate::output::Digest {
                    bytes,
                    sha256: sha256.to_string(),
                },
            ));
        }
    }
    record
}

/// Total time of the method's own passes (reading and writing files excluded).
fn without_io(t: &Timings) -> f64 {
    t.passes
        .iter()
        .filter(|p| !p.name.starts_with("io/"))
        .map(|p| p.ms)
        .sum()
}

/// The files of a report: staged in one set (see [`io::OutputSet`]), so that the folder gets
/// all of them or none; the PNGs are also kept for the page, which embeds them.
struct ReportFiles {
    dir: PathBuf,
    set: io::OutputSet,
    png: HashMap<String, Vec<u8>>,
}

impl ReportFiles {
    fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_path_buf(),
            set: io::OutputSet::new(),
            png: HashMap::new(),
        }
    }

    /// Stages `img` as the linear EXR `name`.
    fn exr(&mut self, name: &str, img: &ColorImage) -> Result<()> {
        let path = self.dir.join(name);
        self.set
            .write_color(&path, img, &io::ExrOptions::default())?;
        Ok(())
    }

    /// Stages `img` as the 8-bit sRGB PNG `name`, and keeps its bytes for [`Self::data_uri`].
    fn png(&mut self, name: &str, img: &ColorImage) -> Result<()> {
        let bytes = io::encode_png(img)?;
        self.set.write_bytes(&self.dir.join(name), &bytes)?;
        self.png.insert(name.to_string(), bytes);
        Ok(())
    }

    /// Stages `text` as the file `name`.
    fn text(&mut self, name: &str, text: &str) -> Result<()> {
        self.set
            .write_bytes(&self.dir.join(name), text.as_bytes())?;
        Ok(())
    }

    /// The PNG `name` staged by [`Self::png`], as a data URI.
    fn data_uri(&self, name: &str) -> Result<String> {
        let bytes = self
            .png
            .get(name)
            .with_context(|| format!("the report has no image {}", shown(name)))?;
        Ok(format!(
            "data:image/png;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(bytes)
        ))
    }
}

/// The error ramp from no difference (left) to the top (right), 256x16.
fn legend_image() -> Result<ColorImage> {
    let (w, h) = (256usize, 16usize);
    let mut data = Vec::with_capacity(w * h);
    for _ in 0..h {
        for x in 0..w {
            let [r, g, b] = metrics::error_ramp(x as f32 / (w - 1) as f32);
            data.push([r, g, b, 1.0]);
        }
    }
    Ok(ColorImage::from_vec(w, h, data)?)
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Time (log scale) against PSNR, one point per run, as SVG.
fn plot(report: &Report) -> Result<String> {
    use plotters::prelude::*;
    let points: Vec<(f64, f64, String)> = report
        .runs
        .iter()
        .filter_map(|r| {
            let (t, p) = (r.total_ms?, r.psnr_db?);
            (t > 0.0 && p.is_finite()).then(|| {
                let mut name = if r.setting.is_empty() {
                    r.method.clone()
                } else {
                    format!("{} {}", r.method, r.setting)
                };
                if r.device != "cpu" {
                    name.push_str(" (GPU)");
                }
                (t, p, name)
            })
        })
        .collect();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (760, 440)).into_drawing_area();
        root.fill(&WHITE)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        let curve: Vec<(f64, f64)> = report
            .frontier
            .iter()
            .filter(|p| p.total_ms > 0.0 && p.psnr_db.is_finite())
            .map(|p| (p.total_ms, p.psnr_db))
            .collect();
        let all = points
            .iter()
            .map(|p| (p.0, p.1))
            .chain(curve.iter().copied());
        let (tmin, tmax) = all.clone().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
            (a.min(p.0), b.max(p.0))
        });
        let (pmin, pmax) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
        let points_empty = points.is_empty() && curve.is_empty();
        let (tmin, tmax) = if points_empty {
            (1.0, 10.0)
        } else {
            (tmin / 1.5, tmax * 1.5)
        };
        let (pmin, pmax) = if points_empty {
            (0.0, 40.0)
        } else {
            ((pmin - 1.0).floor(), (pmax + 1.0).ceil())
        };
        let mut chart = ChartBuilder::on(&root)
            .caption("time against quality", ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d((tmin..tmax).log_scale(), pmin..pmax)
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        chart
            .configure_mesh()
            .x_desc("total time, ms (log scale)")
            .y_desc("PSNR against the reference, dB")
            .draw()
            .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        if !curve.is_empty() {
            // The frontier: `reference` at its sample counts, joined in time order.
            let grey = RGBColor(0x88, 0x88, 0x88);
            chart
                .draw_series(LineSeries::new(curve.iter().copied(), grey.stroke_width(2)))
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
            for (p, (t, q)) in report.frontier.iter().zip(&curve) {
                chart
                    .draw_series(std::iter::once(Cross::new((*t, *q), 4, grey)))
                    .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
                chart
                    .draw_series(std::iter::once(Text::new(
                        format!("ref {}", p.samples),
                        (*t, *q - 0.6),
                        ("sans-serif", 11).into_font().color(&grey),
                    )))
                    .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
            }
        }
        let palette = [
            RGBColor(0x1f, 0x77, 0xb4),
            RGBColor(0xd6, 0x27, 0x28),
            RGBColor(0x2c, 0xa0, 0x2c),
            RGBColor(0x94, 0x67, 0xbd),
            RGBColor(0xff, 0x7f, 0x0e),
            RGBColor(0x8c, 0x56, 0x4b),
            RGBColor(0xe3, 0x77, 0xc2),
            RGBColor(0x17, 0xbe, 0xcf),
        ];
        let methods: Vec<String> = {
            let mut m: Vec<String> = report.runs.iter().map(|r| r.method.clone()).collect();
            m.dedup();
            m
        };
        for (t, p, name) in &points {
            let k = methods
                .iter()
                .position(|m| name.starts_with(m.as_str()))
                .unwrap_or(0);
            let color = palette[k % palette.len()];
            chart
                .draw_series(std::iter::once(Circle::new((*t, *p), 5, color.filled())))
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
            chart
                .draw_series(std::iter::once(Text::new(
                    name.clone(),
                    (*t, *p + 0.35),
                    ("sans-serif", 12).into_font().color(&color),
                )))
                .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
        }
        root.present().map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    }
    Ok(svg)
}

fn page(report: &Report, files: &ReportFiles) -> Result<String> {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title>\n<style>\
body{{font-family:system-ui,sans-serif;margin:24px;color:#222}}table{{border-collapse:collapse;margin:8px 0}}\
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right;font-size:13px}}th{{background:#f2f2f2}}\
td.l,th.l{{text-align:left}}.grid{{display:flex;flex-wrap:wrap;gap:14px}}figure{{margin:0}}\
figure img{{display:block;max-width:480px;image-rendering:pixelated}}figcaption{{font-size:13px;margin-top:3px}}\
.err{{color:#a00}}.na{{color:#777}}</style></head><body>\n",
        esc(&report.title)
    );
    let _ = writeln!(h, "<h1>{}</h1>", esc(&report.title));
    h.push_str("<h2>Parameters</h2><table id=\"parameters\">");
    for (k, v) in &report.parameters {
        let _ = write!(
            h,
            "<tr><th class=\"l\">{}</th><td class=\"l\">{}</td></tr>",
            esc(k),
            esc(v)
        );
    }
    let _ = writeln!(
        h,
        "<tr><th class=\"l\">compared with</th><td class=\"l\">{}{}</td></tr></table>",
        esc(&report.reference.source),
        report
            .reference
            .total_ms
            .map(|t| format!(", rendered in {t:.0} ms"))
            .unwrap_or_default()
    );
    h.push_str(
        "<h2>Quality and time</h2><p>PSNR and SSIM (Wang 2004) on the sRGB image clamped to [0, 1]; MSE in linear light; time: the method's own passes (file reading and writing excluded; post-process methods on a scene include rendering their pinhole frame).</p>\n\
<table id=\"results\"><tr><th class=\"l\">method</th><th class=\"l\">setting</th><th class=\"l\">device</th><th>PSNR dB</th><th>SSIM</th><th>MSE</th><th>total ms</th><th class=\"l\">passes (ms)</th><th>peak MiB</th><th class=\"l\">frontier</th></tr>\n",
    );
    for r in &report.runs {
        let passes: Vec<String> = r
            .passes
            .iter()
            .filter(|p| !p.name.starts_with("io/"))
            .map(|p| format!("{} {:.1}", esc(&p.name), p.ms))
            .collect();
        match &r.error {
            None => {
                let _ = writeln!(
                    h,
                    "<tr class=\"run\"><td class=\"l\">{}</td><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{:.2}</td><td>{:.4}</td><td>{:.3e}</td><td>{:.1}</td><td class=\"l\">{}</td><td>{}</td><td class=\"l\">{}</td></tr>",
                    esc(&r.method),
                    esc(&r.setting),
                    esc(&r.device),
                    r.psnr_db.unwrap_or(f64::NAN),
                    r.ssim.unwrap_or(f64::NAN),
                    r.mse.unwrap_or(f64::NAN),
                    r.total_ms.unwrap_or(f64::NAN),
                    passes.join(", "),
                    r.memory_bytes
                        .map(|b| format!("{:.1}", b as f64 / 1048576.0))
                        .unwrap_or_default(),
                    esc(r.frontier.as_deref().unwrap_or_default())
                );
            }
            Some(e) => {
                let class = if r.status == "not applicable" || r.status == "unsupported" {
                    "na"
                } else {
                    "err"
                };
                let _ = writeln!(
                    h,
                    "<tr class=\"run\"><td class=\"l\">{}</td><td class=\"l\">{}</td><td class=\"l\">{}</td><td class=\"l {class}\" colspan=\"7\">{}: {}</td></tr>",
                    esc(&r.method),
                    esc(&r.setting),
                    esc(&r.device),
                    esc(&r.status),
                    esc(e)
                );
            }
        }
    }
    h.push_str("</table>\n");
    if !report.frontier.is_empty() {
        h.push_str("<h2>Frontier</h2><p><code>reference</code> at a few lens samples (another seed than the ground truth's): a method is behind the frontier when one of these is both faster and at least as good.</p>\n<table id=\"frontier\"><tr><th>samples</th><th>PSNR dB</th><th>SSIM</th><th>total ms</th></tr>\n");
        for p in &report.frontier {
            let _ = writeln!(
                h,
                "<tr><td>{}</td><td>{:.2}</td><td>{:.4}</td><td>{:.1}</td></tr>",
                p.samples, p.psnr_db, p.ssim, p.total_ms
            );
        }
        h.push_str("</table>\n");
    }
    h.push_str("<h2>Time against PSNR</h2><div id=\"plot\">\n");
    h.push_str(&plot(report)?);
    h.push_str("</div>\n<h2>Images</h2>\n<p>Each method's image and its false-colour absolute error against the reference (sRGB), all maps on one scale: ");
    let _ = writeln!(
        h,
        "<img id=\"legend\" alt=\"error scale\" src=\"{}\" style=\"vertical-align:middle;width:256px;height:16px\"> 0 to {:.3} (and more).</p>\n<div class=\"grid\">",
        files.data_uri("error-legend.png")?,
        report.error_map_top
    );
    let _ = writeln!(
        h,
        "<figure><img alt=\"reference\" src=\"{}\"><figcaption>reference ({})</figcaption></figure>",
        files.data_uri(&report.reference.image_png)?,
        esc(&report.reference.source)
    );
    h.push_str("</div>\n");
    for r in &report.runs {
        let (Some(img), Some(err)) = (&r.image_png, &r.error_map_png) else {
            continue;
        };
        let name = if r.setting.is_empty() {
            r.method.clone()
        } else {
            format!("{} ({})", r.method, r.setting)
        };
        let _ = writeln!(
            h,
            "<div class=\"grid\"><figure><img alt=\"{n}\" src=\"{}\"><figcaption>{n}: {:.2} dB, SSIM {:.3}, {:.0} ms</figcaption></figure>\
<figure><img alt=\"{n} error\" src=\"{}\"><figcaption>{n}: error</figcaption></figure></div>",
            files.data_uri(img)?,
            r.psnr_db.unwrap_or(f64::NAN),
            r.ssim.unwrap_or(f64::NAN),
            r.total_ms.unwrap_or(f64::NAN),
            files.data_uri(err)?,
            n = esc(&name)
        );
    }
    // Marks the page once every image has decoded, for automated checks.
    h.push_str(
        "<script>window.addEventListener('load',()=>{const i=[...document.images];\
document.body.dataset.imagesLoaded=i.filter(x=>x.complete&&x.naturalWidth>0).length+'/'+i.length;});</script>\n</body></html>\n",
    );
    Ok(h)
}
