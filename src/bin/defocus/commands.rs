//! Validated jobs built from the raw flags, and their execution.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use defocus::autofocus;
use defocus::error::shown;
use defocus::image::io;
use defocus::lens::{Camera, SamplerKind};
use defocus::methods::registry::{self, MethodSettings, SceneOptions, DEFAULT_FRAME_SAMPLES};
use defocus::methods::MethodOutput;
use defocus::metrics;
use defocus::scene::{load, Scene};
use defocus::timing;
use glam::Vec3;

use crate::args::{single_value, Cli, Command, CompareArgs, Focus, RenderArgs};
use crate::common::{
    check_output, parse_aperture, progress_bar, report_timings, FrameDone, TimingFormat,
    IMAGE_EXTENSIONS,
};

/// Most worker threads `--threads` accepts (a thread per core of the largest machines, with
/// room; more only adds start-up time and memory).
pub const MAX_THREADS: usize = 512;

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    if let Some(g) = cli.memory_budget {
        if !(g.is_finite() && g > 0.0 && g <= 1e6) {
            bail!("invalid --memory-budget {g}: expected a number of GiB greater than 0");
        }
        std::env::set_var("DEFOCUS_MEMORY_BUDGET_GIB", g.to_string());
    }
    if let Some(n) = cli.threads {
        if !(1..=MAX_THREADS).contains(&n) {
            bail!("invalid --threads {n}: expected 1 to {MAX_THREADS}");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("could not start the thread pool")?;
    }
    match cli.command {
        Command::Render(args) => {
            if crate::sequence::is_render_sequence(&args)? {
                return crate::sequence::render(args, cli.quiet);
            }
            let job = RenderJob::try_from(args)?;
            job.run(cli.quiet)
        }
        Command::Blur(args) => {
            if crate::sequence::is_blur_sequence(&args)? {
                return crate::sequence::blur(&args, cli.quiet);
            }
            crate::blur::BlurJob::try_from(args.as_ref())?.run()
        }
        Command::Compare(args) => {
            if args.is_report() {
                crate::report::run(&args, cli.quiet)
            } else {
                compare(&args)
            }
        }
        Command::Kernel(args) => crate::kernel::run(&args),
    }
}

/// A validated `render` job.
pub(crate) struct RenderJob {
    scene: Scene,
    camera: Camera,
    settings: MethodSettings,
    options: SceneOptions,
    exr: io::ExrOptions,
    verbose: bool,
    out: PathBuf,
    depth_out: Option<PathBuf>,
    timings: Option<TimingFormat>,
    inputs: Vec<PathBuf>,
}

/// `compare A B` with both images given.
struct TwoImages {
    a: PathBuf,
    b: PathBuf,
    diff: Option<PathBuf>,
    json: bool,
}

fn load_scene(spec: &str, camera: Option<&str>, options: &load::LoadOptions) -> Result<Scene> {
    let file = load::scene_by_name_or_path(spec, camera, options)?;
    if !file.skipped_cameras.is_empty() {
        eprintln!(
            "note: {}: {} skipped: the thin-lens model is perspective{}",
            shown(spec),
            file.skipped_cameras.join(", "),
            if file.cameras.is_empty() && camera.is_none() {
                " (the default view frames the whole scene; --look-from and --fov place a camera)"
            } else {
                ""
            }
        );
    }
    Ok(file.scene)
}

impl TryFrom<RenderArgs> for RenderJob {
    type Error = anyhow::Error;

    fn try_from(a: RenderArgs) -> Result<Self> {
        check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
        if let Some(d) = &a.depth_out {
            check_output(d, "--depth-out", &["exr"])?;
            io::check_distinct_outputs(&[("--out", &a.out), ("--depth-out", d)])?;
        }
        let options = load::LoadOptions {
            allow_external_files: a.allow_external_files,
        };
        let scene = load_scene(&a.scene, a.view.camera.as_deref(), &options)?;
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
        for (flag, v) in [
            ("--look-from", a.view.look_from),
            ("--look-at", a.view.look_at),
        ] {
            if let Some(p) = v {
                let limit = defocus::scene::MAX_COORDINATE_M;
                if p.iter().any(|c| c.abs() > limit) {
                    bail!(
                        "invalid {flag} {},{},{}: expected coordinates in metres within +-{limit:e}",
                        p[0],
                        p[1],
                        p[2]
                    );
                }
            }
        }
        let view = load::ViewOverride {
            look_from_m: a.view.look_from.map(Vec3::from),
            look_at_m: a.view.look_at.map(Vec3::from),
            up: a.view.up.map(Vec3::from),
            yfov_rad: a.view.fov.map(f32::to_radians),
        };
        view.apply(&mut camera, &scene)
            .context("invalid camera view (check --look-from, --look-at, --up, --fov)")?;
        match &a.focus {
            Some(Focus::Metres(f)) => camera.focus_m = *f,
            Some(Focus::Keys(k)) => camera.focus_m = single_value(k, "--focus")?,
            _ => {}
        }
        if let Some(n) = &a.fstop {
            camera.fstop = single_value(n, "--fstop")?;
        }
        if let Some(f) = a.focal_length {
            camera.focal_length_mm = f;
        }
        if let Some(s) = a.sensor_width {
            camera.sensor_width_mm = s;
        }
        // Autofocus last: it renders with the final pose, size and lens.
        let focus_pixel = match (&a.focus, a.view.focus_pixel) {
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
            if !a.in_sequence || a.verbose {
                eprintln!(
                    "focus: {:.4} m (median depth of the {w}x{w} pixels around ({x}, {y}))",
                    pick.depth_m,
                    w = pick.window_px
                );
            }
        }
        // Validate the camera now, with the flag names in the message.
        camera.thin_lens().context(
            "invalid camera (check --width, --height, --focus, --fstop, --focal-length, --sensor-width)",
        )?;
        let aperture = match &a.aperture {
            Some(spec) => parse_aperture(spec)?,
            None => defaults.aperture,
        };
        let sampler = SamplerKind::parse(&a.sampler).context("invalid --sampler")?;
        let lens = camera.thin_lens()?;
        let settings = a
            .post
            .settings(&a.method, &aperture, a.seed, camera.height_px, Some(&lens))?
            .with_run(a.samples, sampler, a.seed, &aperture)?;
        let options = SceneOptions {
            frame_samples: a.samples.unwrap_or(DEFAULT_FRAME_SAMPLES),
            seed: a.seed,
            with_depth: a.depth_out.is_some(),
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
            options,
            exr: a.exr.options(),
            verbose: a.verbose,
            out: a.out,
            depth_out: a.depth_out,
            timings: a.timings,
            inputs,
        })
    }
}

impl RenderJob {
    /// The camera, after every override.
    pub(crate) fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Runs the method on the scene; `progress(done, total)` reports views.
    pub(crate) fn compute(&self, progress: &mut dyn FnMut(usize, usize)) -> Result<MethodOutput> {
        Ok(registry::run_scene(
            &self.settings,
            &self.scene,
            &self.camera,
            &self.options,
            progress,
        )?)
    }

    fn run(self, quiet: bool) -> Result<()> {
        let timings = self.timings;
        let done = self.execute(quiet)?;
        report_timings(
            timings,
            done.method,
            done.width,
            done.height,
            &done.timings,
            done.memory_bytes,
        )
    }

    /// Renders and writes the outputs (a progress bar of views unless `quiet`); what it took.
    pub(crate) fn execute(self, quiet: bool) -> Result<FrameDone> {
        for input in &self.inputs {
            for out in std::iter::once(&self.out).chain(self.depth_out.as_ref()) {
                io::ensure_not_same_file(input, out)?;
            }
        }
        let views = match &self.settings {
            MethodSettings::Reference(r) => r.samples,
            MethodSettings::Pinhole(p) => p.samples,
            _ => self.options.frame_samples,
        };
        let bar = progress_bar(quiet, views as u64, "views");
        let output: MethodOutput = self.compute(&mut |done, _| bar.set_position(done as u64))?;
        bar.finish_and_clear();
        let mut timings = output.timings.clone();
        let method = self.settings.id();
        timings.time(timing::WRITE, || {
            // Both outputs or neither: staged, renamed when both are written.
            let mut set = io::OutputSet::new();
            set.write_color(&self.out, &output.image, &self.exr)?;
            if let (Some(path), Some(depth)) = (&self.depth_out, &output.depth) {
                // Renderers write a large finite value where nothing was hit (Blender: 1e10).
                let depth = depth.map(|z| if z.is_finite() { z } else { 1e10 });
                set.write_depth_exr(path, &depth)?;
            }
            set.commit()?;
            anyhow::Ok(())
        })?;
        if self.verbose {
            let info = self.settings.info();
            eprintln!("method: {} ({})", info.id, info.description);
            if !info.paper.is_empty() {
                eprintln!("paper: {}", info.paper);
            }
            if let Ok(lens) = self.camera.thin_lens() {
                eprintln!(
                    "lens: f_px {:.2}, lens radius {:.5} m, focus {:.4} m, CoC at infinity {:.2} px",
                    lens.f_px,
                    lens.lens_radius_m,
                    lens.focus_m,
                    lens.coc_at_infinity_px()
                );
            }
            if let Some(bytes) = output.memory_bytes {
                eprintln!(
                    "memory: {bytes} bytes ({:.1} MiB) peak of the method's own storage",
                    bytes as f64 / (1024.0 * 1024.0)
                );
            }
        }
        Ok(FrameDone {
            method,
            width: self.camera.width_px,
            height: self.camera.height_px,
            timings,
            memory_bytes: output.memory_bytes,
        })
    }
}

fn compare(args: &CompareArgs) -> Result<()> {
    let (Some(a_path), Some(b_path)) = (&args.a, &args.b) else {
        bail!("compare needs two images A B, or a report: --scene NAME --out DIR, or --color C --depth D --truth T --out DIR");
    };
    let args = TwoImages {
        a: a_path.clone(),
        b: b_path.clone(),
        diff: args.diff.clone(),
        json: args.json,
    };
    let args = &args;
    if let Some(diff) = &args.diff {
        check_output(diff, "--diff", IMAGE_EXTENSIONS)?;
        io::ensure_not_same_file(&args.a, diff)?;
        io::ensure_not_same_file(&args.b, diff)?;
    }
    let a = io::read_color(&args.a)?;
    let b = io::read_color(&args.b)?;
    io::check_finite_color(&args.a, &a)?;
    io::check_finite_color(&args.b, &b)?;
    if !a.same_size(&b) {
        bail!(
            "size mismatch: {} is {}x{} but {} is {}x{}",
            shown(&args.a),
            a.width(),
            a.height(),
            shown(&args.b),
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
    crate::common::print_output(&text)
}
