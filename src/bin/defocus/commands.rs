//! Validated jobs built from the raw flags, and their execution.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use defocus::image::{io, GrayImage};
use defocus::lens::{Aperture, ApertureImage, Camera, SamplerKind};
use defocus::methods::lowrank::CustomShape;
use defocus::methods::reference::{self, ReferenceSettings};
use defocus::methods::MethodOutput;
use defocus::metrics;
use defocus::scene::{autofocus, builtin, load, Scene};
use defocus::timing::Timings;
use glam::Vec3;
use indicatif::{ProgressBar, ProgressStyle};

use crate::args::{Cli, Command, CompareArgs, Focus, RenderArgs, RenderMethod, TimingFormat};
use crate::post::{self, PostSettings};

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    if let Some(n) = cli.threads {
        if n == 0 {
            bail!("invalid --threads: 0 (expected at least 1)");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("could not start the thread pool")?;
    }
    match cli.command {
        Command::Render(args) => {
            let job = RenderJob::try_from(args)?;
            job.run(cli.quiet)
        }
        Command::Blur(args) => crate::blur::BlurJob::try_from(args.as_ref())?.run(),
        Command::Compare(args) => compare(&args),
        Command::Kernel(args) => crate::kernel::run(&args),
    }
}

pub(crate) const IMAGE_EXTENSIONS: &[&str] = &["exr", "png", "pfm"];

/// Checks an output path before any work is done: a supported extension and an existing folder.
pub(crate) fn check_output(path: &Path, flag: &str, extensions: &[&str]) -> Result<()> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if !extensions.contains(&ext.as_str()) {
        bail!(
            "invalid {flag} {}: expected a file ending in .{}",
            path.display(),
            extensions.join(", .")
        );
    }
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !parent.is_dir() {
            bail!(
                "invalid {flag} {}: folder {} does not exist",
                path.display(),
                parent.display()
            );
        }
    }
    Ok(())
}

/// A validated `render` job.
struct RenderJob {
    scene: Scene,
    camera: Camera,
    settings: ReferenceSettings,
    method: RenderMethod,
    /// Settings of the post-process method, for those methods.
    post: Option<PostSettings>,
    out: PathBuf,
    depth_out: Option<PathBuf>,
    timings: Option<TimingFormat>,
    inputs: Vec<PathBuf>,
}

fn load_scene(spec: &str, camera: Option<&str>) -> Result<Scene> {
    if builtin::NAMES.contains(&spec) {
        if camera.is_some() {
            bail!("invalid --camera: the built-in scene '{spec}' has one camera; --camera picks a camera of a scene file");
        }
        return Ok(builtin::load(spec)?);
    }
    let path = Path::new(spec);
    if path.exists() {
        let mut file = load::read_scene_file(path)?;
        if let Some(c) = camera {
            file.use_camera(c).context("invalid --camera")?;
        }
        return Ok(file.scene);
    }
    bail!(
        "unknown scene '{spec}': not a built-in scene ({}) and no such file",
        builtin::NAMES.join(", ")
    )
}

/// Parses `--aperture`, loading the image for `image:PATH`.
pub fn parse_aperture(spec: &str) -> Result<Aperture> {
    if let Some(path) = spec.strip_prefix("image:") {
        let img = io::read_color(Path::new(path))
            .with_context(|| format!("invalid --aperture {spec}"))?;
        let grey = img.map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]);
        let grey = GrayImage::from_vec(grey.width(), grey.height(), grey.into_vec())?;
        let density = ApertureImage::new(grey).with_context(|| format!("aperture image {path}"))?;
        return Ok(Aperture::Image(std::sync::Arc::new(density)));
    }
    let name = spec.trim().split(':').next().unwrap_or("");
    if ["star", "heart", "ring"].contains(&name) {
        let shape =
            CustomShape::parse(spec).with_context(|| format!("invalid --aperture {spec}"))?;
        return Ok(shape.aperture()?);
    }
    Aperture::parse(spec).with_context(|| format!("invalid --aperture {spec}"))
}

impl TryFrom<RenderArgs> for RenderJob {
    type Error = anyhow::Error;

    fn try_from(a: RenderArgs) -> Result<Self> {
        check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
        if let Some(d) = &a.depth_out {
            check_output(d, "--depth-out", &["exr"])?;
        }
        let scene = load_scene(&a.scene, a.view.camera.as_deref())?;
        let defaults = scene
            .defaults
            .clone()
            .with_context(|| format!("scene '{}' has no camera", a.scene))?;
        let mut camera = defaults.camera;
        if let Some(w) = a.width {
            camera.width_px = w;
        }
        if let Some(h) = a.height {
            camera.height_px = h;
        }
        let view = load::ViewOverride {
            look_from_m: a.view.look_from.map(Vec3::from),
            look_at_m: a.view.look_at.map(Vec3::from),
            up: a.view.up.map(Vec3::from),
            yfov_rad: a.view.fov.map(f32::to_radians),
        };
        view.apply(&mut camera, &scene)
            .context("invalid camera view (check --look-from, --look-at, --up, --fov)")?;
        if let Some(Focus::Metres(f)) = a.focus {
            camera.focus_m = f;
        }
        if let Some(n) = a.fstop {
            camera.fstop = n;
        }
        if let Some(f) = a.focal_length {
            camera.focal_length_mm = f;
        }
        if let Some(s) = a.sensor_width {
            camera.sensor_width_mm = s;
        }
        // Autofocus last: it renders with the final pose, size and lens.
        let focus_pixel = match (a.focus, a.view.focus_pixel) {
            (Some(Focus::Auto), _) => Some((camera.width_px / 2, camera.height_px / 2)),
            (_, pixel) => pixel,
        };
        if let Some((x, y)) = focus_pixel {
            let pick = autofocus::focus_at_pixel(&scene, &camera, x, y)
                .context("invalid --focus auto / --focus-pixel")?
                .with_context(|| {
                    format!("--focus: no surface near pixel ({x}, {y}) to focus on")
                })?;
            camera.focus_m = pick.depth_m;
            eprintln!(
                "focus: {:.4} m (median depth of the {w}x{w} pixels around ({x}, {y}))",
                pick.depth_m,
                w = pick.window_px
            );
        }
        // Validate the camera now, with the flag names in the message.
        camera.thin_lens().context(
            "invalid camera (check --width, --height, --focus, --fstop, --focal-length, --sensor-width)",
        )?;
        let aperture = match &a.aperture {
            Some(spec) => parse_aperture(spec)?,
            None => defaults.aperture,
        };
        let samples = a.samples.unwrap_or(match a.method {
            RenderMethod::Reference => 256,
            _ => 1,
        });
        if samples == 0 || samples > 1 << 20 {
            bail!("invalid --samples {samples}: expected 1 to {}", 1 << 20);
        }
        let sampler = SamplerKind::parse(&a.sampler).context("invalid --sampler")?;
        let post = match a.method.post() {
            Some(m) => Some(a.post.settings(
                m,
                &aperture,
                a.seed,
                camera.height_px,
                Some(&camera.thin_lens()?),
            )?),
            None => None,
        };
        let settings = ReferenceSettings {
            samples,
            sampler,
            seed: a.seed,
            aperture,
            use_lens: a.method == RenderMethod::Reference,
            with_depth: a.depth_out.is_some() || post.is_some(),
        };
        let mut inputs = Vec::new();
        if Path::new(&a.scene).exists() {
            inputs.push(PathBuf::from(&a.scene));
        }
        if let Some(p) = a.aperture.as_deref().and_then(|s| s.strip_prefix("image:")) {
            inputs.push(PathBuf::from(p));
        }
        Ok(Self {
            scene,
            camera,
            settings,
            method: a.method,
            post,
            out: a.out,
            depth_out: a.depth_out,
            timings: a.timings,
            inputs,
        })
    }
}

impl RenderJob {
    fn run(self, quiet: bool) -> Result<()> {
        for input in &self.inputs {
            for out in std::iter::once(&self.out).chain(self.depth_out.as_ref()) {
                io::ensure_not_same_file(input, out)?;
            }
        }
        let bar = progress_bar(quiet, self.settings.samples as u64, "views");
        let mut output: MethodOutput =
            reference::render(&self.scene, &self.camera, &self.settings, &mut |done, _| {
                bar.set_position(done as u64)
            })?;
        bar.finish_and_clear();
        let mut timings = output.timings.clone();
        if let Some(post) = &self.post {
            // The pinhole frame (colour and centre depth) is the post-process method's input.
            let depth = output
                .depth
                .take()
                .context("internal: the pinhole pass returned no depth")?;
            let lens = self.camera.thin_lens()?;
            let blurred = post::run(post, &output.image, &depth, &lens)?;
            timings.extend(&blurred.timings);
            output = MethodOutput {
                image: blurred.image,
                depth: Some(depth),
                timings: blurred.timings,
            };
        }
        let method = self.method.id();
        timings.time(&format!("{method}/write"), || {
            io::write_color(&self.out, &output.image)
        })?;
        if let (Some(path), Some(depth)) = (&self.depth_out, &output.depth) {
            // Renderers write a large finite value where nothing was hit (Blender: 1e10).
            let depth = depth.map(|z| if z.is_finite() { z } else { 1e10 });
            io::write_depth_exr(path, &depth)?;
        }
        report_timings(
            self.timings,
            method,
            self.camera.width_px,
            self.camera.height_px,
            &timings,
        );
        Ok(())
    }
}

fn progress_bar(quiet: bool, total: u64, unit: &str) -> ProgressBar {
    if quiet || total <= 1 {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    let template = format!(
        "{{spinner}} [{{elapsed_precise}}] {{wide_bar}} {{pos}}/{{len}} {unit} (eta {{eta}})"
    );
    if let Ok(style) = ProgressStyle::with_template(&template) {
        bar.set_style(style);
    }
    bar
}

pub(crate) fn report_timings(
    format: Option<TimingFormat>,
    method: &str,
    width: usize,
    height: usize,
    timings: &Timings,
) {
    match format {
        None => {}
        Some(TimingFormat::Table) => {
            let name_width = timings
                .passes
                .iter()
                .map(|p| p.name.len())
                .max()
                .unwrap_or(4)
                .max(5);
            eprintln!("{method} {width}x{height}");
            eprintln!("{:<name_width$} {:>10}", "pass", "ms");
            for p in &timings.passes {
                eprintln!("{:<name_width$} {:>10.2}", p.name, p.ms);
            }
            eprintln!("{:<name_width$} {:>10.2}", "total", timings.total_ms());
        }
        Some(TimingFormat::Json) => {
            let value = serde_json::json!({
                "method": method,
                "width": width,
                "height": height,
                "passes": timings.passes,
                "total_ms": timings.total_ms(),
            });
            #[expect(
                clippy::print_stdout,
                reason = "--timings json is the command's output"
            )]
            {
                println!("{value}");
            }
        }
    }
}

fn compare(args: &CompareArgs) -> Result<()> {
    if let Some(diff) = &args.diff {
        check_output(diff, "--diff", IMAGE_EXTENSIONS)?;
        io::ensure_not_same_file(&args.a, diff)?;
        io::ensure_not_same_file(&args.b, diff)?;
    }
    let a = io::read_color(&args.a)?;
    let b = io::read_color(&args.b)?;
    if !a.same_size(&b) {
        bail!(
            "size mismatch: {} is {}x{} but {} is {}x{}",
            args.a.display(),
            a.width(),
            a.height(),
            args.b.display(),
            b.width(),
            b.height()
        );
    }
    let m = metrics::compare(&a, &b)?;
    if let Some(diff) = &args.diff {
        io::write_color(diff, &metrics::error_map(&a, &b)?)?;
    }
    let text = if args.json {
        serde_json::json!({
            "mse": m.mse_linear,
            "psnr": if m.psnr_db.is_finite() { serde_json::json!(m.psnr_db) } else { serde_json::json!("inf") },
            "ssim": m.ssim,
        })
        .to_string()
    } else {
        format!(
            "mse: {:.6e}\npsnr: {}\nssim: {:.6}",
            m.mse_linear,
            if m.psnr_db.is_finite() {
                format!("{:.4}", m.psnr_db)
            } else {
                "inf".to_string()
            },
            m.ssim
        )
    };
    #[expect(clippy::print_stdout, reason = "the metrics are the command's output")]
    {
        println!("{text}");
    }
    Ok(())
}
