//! `defocus render`: a scene (built-in or file) through the thin lens with one method. Its
//! flags ([`RenderArgs`], parsed by the command line or built by a program), the validated job
//! ([`RenderJob`]) and its run. Lines the command line shows go to a `notes` sink.

use std::path::PathBuf;
use std::sync::Arc;

use crate::autofocus;
use crate::error::shown;
use crate::frames::Keyed;
use crate::gpu::GpuContext;
use crate::image::io;
use crate::lens::{Camera, SamplerKind};
use crate::methods::registry::{self, MethodSettings, SceneOptions, DEFAULT_FRAME_SAMPLES};
use crate::methods::MethodOutput;
use crate::scene::{load, Scene};
use crate::timing;
use anyhow::{bail, Context, Result};
use clap::Args;
use glam::Vec3;

use super::flags::{
    check_output, device_name, method_parser, open_device, parse_focus, parse_fstop, parse_pixel,
    parse_vec3, single_value, DeviceArg, ExrArgs, Focus, FrameDone, TimingFormat, IMAGE_EXTENSIONS,
};
use crate::options::{parse_aperture, PostArgs};

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
    #[arg(long, value_name = "M|auto|F:M,...", value_parser = parse_focus, allow_hyphen_values = true)]
    pub focus: Option<Focus>,
    /// f-number N; the lens radius is focal length / (2 N) [default: the scene's]. With
    /// --frames, keyframes FRAME:N,... interpolated in stops (linearly in log N).
    #[arg(long, value_name = "N|F:N,...", value_parser = parse_fstop, allow_hyphen_values = true)]
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
    /// far-field bokeh appears) [default: the scene's]. hammon and gaussian have no shape; multilayer draws it for blurs of a few pixels and more (--ml-bokeh).
    #[arg(long, value_name = "SPEC")]
    pub aperture: Option<String>,
    /// Lens sampler: halton (low discrepancy, the default), sobol (Owen-scrambled), stratified, random.
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
    #[arg(long, value_name = "FRAMES", allow_hyphen_values = true)]
    pub frames: Option<String>,
    /// With --frames: render frames whose outputs exist again, replacing them.
    #[arg(long, requires = "frames")]
    pub overwrite: bool,
    /// Set for the frames of a sequence: notes that every frame would repeat are not printed.
    #[arg(skip)]
    pub in_sequence: bool,
    /// Where the method runs: `auto` (a hardware GPU when there is one and the method runs
    /// there, else the CPU), `cpu`, or `gpu` (any GPU adapter, a software one included; an
    /// error when there is none). On the GPU so far: hammon and gaussian, whose pinhole frame
    /// is rendered on the CPU. `defocus devices` lists the adapters.
    #[arg(long, value_enum, default_value_t = DeviceArg::Auto, value_name = "DEVICE")]
    pub device: DeviceArg,
    /// Print per-pass timings and the device: a table on stderr, or `--timings json` on stdout.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "table", value_name = "FORMAT")]
    pub timings: Option<TimingFormat>,
    /// Say what was run: method, paper, lens, and the peak bytes of the method's own storage
    /// where it tracks them (multilayer: fragment lists and filtered levels), on stderr.
    #[arg(long, short)]
    pub verbose: bool,
    /// EXR output options.
    #[command(flatten)]
    pub exr: ExrArgs,
    /// Camera choice and placement (listed under their own heading).
    #[command(flatten)]
    pub view: Box<ViewArgs>,
    /// Options of the post-process methods (listed under their own heading).
    #[command(flatten)]
    pub post: Box<PostArgs>,
}

/// Flags of `render` that choose and place the camera (boxed in [`RenderArgs`] to keep
/// `Command` small).
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

/// A validated `render` job.
pub struct RenderJob {
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
    /// The GPU the method runs on; `None` for the CPU.
    gpu: Option<Arc<GpuContext>>,
}

fn load_scene(
    spec: &str,
    camera: Option<&str>,
    options: &load::LoadOptions,
    notes: &mut dyn FnMut(String),
) -> Result<load::SceneFile> {
    let file = load::scene_by_name_or_path(spec, camera, options)?;
    if !file.skipped_cameras.is_empty() {
        notes(format!(
            "note: {}: {} skipped: the thin-lens model is perspective{}",
            shown(spec),
            file.skipped_cameras.join(", "),
            if file.cameras.is_empty() && camera.is_none() {
                " (the default view frames the whole scene; --look-from and --fov place a camera)"
            } else {
                ""
            }
        ));
    }
    Ok(file)
}

impl RenderJob {
    /// Checks the flags, opens the device (`--device`), loads the scene and places the camera
    /// (the autofocus renders); `notes` receives the lines the command line shows (skipped
    /// cameras, the focus picked).
    pub fn new(a: RenderArgs, notes: &mut dyn FnMut(String)) -> Result<Self> {
        let gpu = open_device(a.device, &a.method)?;
        Self::new_on(a, gpu, notes)
    }

    /// [`RenderJob::new`] on a GPU context the caller opened ([`open_device`]; `None` for the
    /// CPU), which a sequence shares between its frames.
    pub fn new_on(
        a: RenderArgs,
        gpu: Option<Arc<GpuContext>>,
        notes: &mut dyn FnMut(String),
    ) -> Result<Self> {
        check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
        if let Some(d) = &a.depth_out {
            check_output(d, "--depth-out", &["exr"])?;
            io::check_distinct_outputs(&[("--out", &a.out), ("--depth-out", d)])?;
        }
        let options = load::LoadOptions {
            allow_external_files: a.allow_external_files,
        };
        let file = load_scene(&a.scene, a.view.camera.as_deref(), &options, notes)?;
        // Every file the job reads: the scene's, the aperture image, the lens preset file.
        let mut inputs = file.files_read;
        let scene = file.scene;
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
                let limit = crate::scene::MAX_COORDINATE_M;
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
            // The run would be refused at this size: refuse it before the autofocus renders.
            let settings = MethodSettings::default_for(&a.method)?;
            registry::check_scene_budget(&settings, &scene, &camera)?;
            let pick = autofocus::focus_at_pixel(&scene, &camera, x, y)
                .context("invalid --focus auto / --focus-pixel")?
                .with_context(|| {
                    format!("--focus: no surface near pixel ({x}, {y}) to focus on")
                })?;
            camera.focus_m = pick.depth_m;
            if !a.in_sequence || a.verbose {
                notes(format!(
                    "focus: {:.4} m (median depth of the {w}x{w} pixels around ({x}, {y}))",
                    pick.depth_m,
                    w = pick.window_px
                ));
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
            occlusion: a.post.occlusion,
        };
        if let Some(p) = a.aperture.as_deref().and_then(|s| s.strip_prefix("image:")) {
            inputs.push(PathBuf::from(p));
        }
        inputs.extend(a.post.lens_file());
        // `auto` runs on the CPU what the GPU passes do not cover (and `--timings` says so).
        let gpu = gpu.filter(|g| !g.chosen_by_auto() || registry::runs_on_gpu(&settings));
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
            gpu,
        })
    }

    /// Every file the job reads: the scene file and the files it refers to, the aperture
    /// image, the lens preset file. No output may be one of them.
    pub fn inputs(&self) -> &[PathBuf] {
        &self.inputs
    }

    /// The device the job runs on, as `--timings` names it: `cpu`, or the GPU adapter's label.
    pub fn device(&self) -> String {
        device_name(self.gpu.as_deref())
    }

    /// The camera, after every override.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Runs the method on the scene; `progress(done, total)` reports views.
    pub fn compute(&self, progress: &mut dyn FnMut(usize, usize)) -> Result<MethodOutput> {
        Ok(registry::run_scene_on(
            &self.settings,
            &self.scene,
            &self.camera,
            &self.options,
            self.gpu.as_deref(),
            progress,
        )?)
    }

    /// The views the method renders (the size of its progress).
    pub fn views(&self) -> usize {
        match &self.settings {
            MethodSettings::Reference(r) => r.samples,
            MethodSettings::Pinhole(p) => p.samples,
            _ => self.options.frame_samples,
        }
    }

    /// How `--timings` reports, if asked.
    pub fn timing_format(&self) -> Option<TimingFormat> {
        self.timings
    }

    /// Renders and writes the outputs (both or neither); what it took. `progress(done,
    /// total)` reports views; `notes` receives the `--verbose` lines.
    pub fn execute(
        self,
        progress: &mut dyn FnMut(usize, usize),
        notes: &mut dyn FnMut(String),
    ) -> Result<FrameDone> {
        for input in &self.inputs {
            for out in std::iter::once(&self.out).chain(self.depth_out.as_ref()) {
                io::ensure_not_same_file(input, out)?;
            }
        }
        let output: MethodOutput = self.compute(progress)?;
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
            notes(format!("method: {} ({})", info.id, info.description));
            if !info.paper.is_empty() {
                notes(format!("paper: {}", info.paper));
            }
            if let Ok(lens) = self.camera.thin_lens() {
                notes(format!(
                    "lens: f_px {:.2}, lens radius {:.5} m, focus {:.4} m, CoC at infinity {:.2} px",
                    lens.f_px,
                    lens.lens_radius_m,
                    lens.focus_m,
                    lens.coc_at_infinity_px()
                ));
            }
            if let Some(bytes) = output.memory_bytes {
                notes(format!(
                    "memory: {bytes} bytes ({:.1} MiB) peak of the method's own storage",
                    bytes as f64 / (1024.0 * 1024.0)
                ));
            }
        }
        Ok(FrameDone {
            method,
            device: device_name(self.gpu.as_deref()),
            width: self.camera.width_px,
            height: self.camera.height_px,
            timings,
            memory_bytes: output.memory_bytes,
        })
    }
}
