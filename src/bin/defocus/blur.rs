//! `defocus blur`: depth of field for a rendered colour image with a depth pass.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use defocus::autofocus::focus_in_depth;
use defocus::image::io::{self, DepthRead};
use defocus::image::{ColorImage, GrayImage};
use defocus::lens::{Camera, ThinLens};
use defocus::methods::lowrank::{self, tilt_shift_coc, TiltShift};
use defocus::methods::registry::{self, Frame, MethodSettings};
use defocus::methods::MethodOutput;
use defocus::timing::{self, Timings};

use crate::common::{
    check_output, method_parser, parse_aperture, report_timings, TimingFormat, IMAGE_EXTENSIONS,
};
use crate::post::PostArgs;

/// What the depth values measure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum DepthKind {
    /// Distance along the view axis (Blender's and most renderers' Z pass).
    View,
    /// Distance from the eye along each pixel's ray; converted to view depth.
    Radial,
}

/// Flags of `blur`.
#[derive(Debug, Args)]
pub struct BlurArgs {
    /// Colour image: EXR (plain R/G/B/A or a multilayer file's Combined layer), PNG (sRGB) or PFM.
    #[arg(long, value_name = "FILE")]
    pub color: PathBuf,
    /// Depth image in metres: EXR channel Z / depth / <layer>.Depth.Z (may be the colour file
    /// itself), 8/16-bit PNG or PFM (times --depth-scale). Not needed with --tilt-shift.
    #[arg(long, value_name = "FILE", required_unless_present = "tilt_shift")]
    pub depth: Option<PathBuf>,
    /// EXR depth channel (full name or unique suffix) [default: searched: Z, depth, *.Depth.Z].
    #[arg(long, value_name = "NAME")]
    pub depth_channel: Option<String>,
    /// Whether depth is view-axis distance or radial distance from the eye.
    #[arg(long, value_enum, default_value_t = DepthKind::View)]
    pub depth_kind: DepthKind,
    /// Metres per stored depth unit (a 16-bit PNG is read as value / 65535, an 8-bit one as
    /// value / 255, before this scale).
    #[arg(
        long,
        default_value_t = 1.0,
        value_name = "M",
        allow_negative_numbers = true
    )]
    pub depth_scale: f32,
    /// DoF method [default: hammon; lowrank with --tilt-shift]. Methods that need a 3D scene
    /// (reference, pinhole, and the layered ones) are refused: use `defocus render`.
    #[arg(long, value_parser = method_parser())]
    pub method: Option<String>,
    /// Focus distance in metres, or `auto` (median depth of a small window at the image centre).
    #[arg(
        long,
        default_value = "auto",
        value_name = "M|auto",
        allow_negative_numbers = true
    )]
    pub focus: String,
    /// f-number N; the lens radius is focal length / (2 N).
    #[arg(
        long,
        default_value_t = 2.8,
        value_name = "N",
        allow_negative_numbers = true
    )]
    pub fstop: f32,
    /// Focal length in millimetres.
    #[arg(
        long,
        default_value_t = 50.0,
        value_name = "MM",
        allow_negative_numbers = true
    )]
    pub focal_length: f32,
    /// Sensor width in millimetres (horizontal fit; full frame is 36).
    #[arg(
        long,
        default_value_t = 36.0,
        value_name = "MM",
        allow_negative_numbers = true
    )]
    pub sensor_width: f32,
    /// Aperture (lowrank, poisson): `disc`, `poly:B[,rot=DEG][,curve=R]`, `star[:N[,INNER]]`,
    /// `heart`, `ring[:INNER]` or `image:PATH` (greyscale density as the far-field bokeh appears).
    #[arg(long, default_value = "disc", value_name = "SPEC")]
    pub aperture: String,
    /// Seed of the methods that draw random taps (lowrank's fallback, poisson).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Tilt-shift instead of depth (lowrank): a sharp band across the image, blur growing
    /// away from it. Optional keys, comma-separated: `centre=Y` (band centre, fraction of the
    /// height from the top, 0.5), `width=W` (band width, fraction of the height, 0.15),
    /// `angle=DEG` (counter-clockwise, 0), `blur=PX` (largest CoC radius, 12), `ramp=R`
    /// (distance over which the blur grows, fraction of the height, 0.3).
    #[arg(long, value_name = "KEY=VALUE,...", num_args = 0..=1, default_missing_value = "")]
    pub tilt_shift: Option<String>,
    /// Output image: .exr (linear float RGBA), .png (8-bit sRGB) or .pfm.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Print per-pass timings: a table on stderr, or `--timings json` on stdout.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "table", value_name = "FORMAT")]
    pub timings: Option<TimingFormat>,
    /// Also write the signed CoC radius in pixels of every pixel (channel `CoC`; negative in front
    /// of the focal plane, unclamped), to check the focus set-up.
    #[arg(long, value_name = "FILE.exr")]
    pub coc_out: Option<PathBuf>,
    /// Say which channels and parameters were used (on stderr).
    #[arg(long, short)]
    pub verbose: bool,
    /// Replace NaN and infinite colour values by 0 (and say how many) instead of refusing them.
    #[arg(long)]
    pub sanitize: bool,
    /// EXR output options.
    #[command(flatten)]
    pub exr: crate::common::ExrArgs,
    /// Options of the methods.
    #[command(flatten)]
    pub post: PostArgs,
}

/// Parses a `--tilt-shift` spec (see its help).
pub fn parse_tilt_shift(spec: &str) -> Result<TiltShift> {
    let mut ts = TiltShift::default();
    for part in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (key, value) = part.split_once('=').with_context(|| {
            format!("invalid --tilt-shift '{spec}': expected KEY=VALUE, got '{part}'")
        })?;
        let v: f32 = value.trim().parse().map_err(|_| {
            anyhow::anyhow!("invalid --tilt-shift '{spec}': value of '{key}' is not a number")
        })?;
        match key.trim() {
            "centre" | "center" => ts.centre_y = v,
            "width" => ts.width = v,
            "angle" => ts.angle_deg = v,
            "blur" => ts.max_coc_px = v,
            "ramp" => ts.ramp = v,
            other => bail!(
                "invalid --tilt-shift '{spec}': unknown key '{other}' (expected centre, width, angle, blur or ramp)"
            ),
        }
    }
    ts.validate()
        .with_context(|| format!("invalid --tilt-shift '{spec}'"))?;
    Ok(ts)
}

/// What the blur is driven by.
enum Input {
    /// A depth map and the lens that turns it into a CoC.
    Depth { depth: GrayImage, lens: ThinLens },
    /// A tilt-shift CoC map (signed radius in pixels per pixel).
    TiltShift { coc_px: GrayImage },
}

/// A validated `blur` job: images read, sizes checked, lens derived, settings validated.
pub struct BlurJob {
    color: ColorImage,
    input: Input,
    settings: MethodSettings,
    /// Time spent reading the inputs.
    read_timings: Timings,
    /// How EXR outputs are written.
    exr: io::ExrOptions,
    out: PathBuf,
    coc_out: Option<PathBuf>,
    timings: Option<TimingFormat>,
}

impl TryFrom<&BlurArgs> for BlurJob {
    type Error = anyhow::Error;

    fn try_from(a: &BlurArgs) -> Result<Self> {
        check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
        if let Some(c) = &a.coc_out {
            check_output(c, "--coc-out", &["exr"])?;
            io::check_distinct_outputs(&[("--out", &a.out), ("--coc-out", c)])?;
        }
        for out in std::iter::once(&a.out).chain(&a.coc_out) {
            io::ensure_not_same_file(&a.color, out)?;
            if let Some(d) = &a.depth {
                io::ensure_not_same_file(d, out)?;
            }
        }
        let tilt_shift = a.tilt_shift.as_deref().map(parse_tilt_shift).transpose()?;
        let method: &str = match (a.method.as_deref(), &tilt_shift) {
            (None, None) => "hammon",
            (None, Some(_)) | (Some("lowrank"), Some(_)) => "lowrank",
            (Some(m), None) => m,
            (Some(m), Some(_)) => {
                bail!("--tilt-shift works with --method lowrank (McGraw section 4), not {m}")
            }
        };
        let info = registry::find(method)?;
        if info.input.needs_scene() {
            bail!(
                "--method {method} needs {}, not a colour image with a depth pass: run `defocus render --method {method} --scene ...` instead",
                info.input.describe()
            );
        }
        let mut read_timings = Timings::default();
        if tilt_shift.is_some() && a.depth.is_some() {
            bail!("--tilt-shift paints the blur itself: give no --depth with it");
        }
        let aperture = parse_aperture(&a.aperture)?;
        if let Some(p) = a.aperture.strip_prefix("image:") {
            io::ensure_not_same_file(Path::new(p), &a.out)?;
        }
        if a.verbose
            && a.color
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
        {
            let (color, _) = io::exr_channel_choice(&a.color, None)?;
            if let Ok(names) = color {
                eprintln!(
                    "colour: {} channels {}",
                    a.color.display(),
                    names.join(", ")
                );
            }
        }
        let mut color = read_timings.time(timing::READ, || io::read_color(&a.color))?;
        if a.sanitize {
            let n = io::sanitize_color(&mut color);
            if n > 0 {
                eprintln!(
                    "--sanitize: {n} pixel(s) of {} had NaN or infinite values, set to 0",
                    a.color.display()
                );
            }
        } else {
            io::check_finite_color(&a.color, &color)?;
        }
        if let Some(ts) = tilt_shift {
            let mut post = a.post.clone();
            post.max_coc = post.max_coc.max(ts.max_coc_px);
            let settings = post.settings(method, &aperture, a.seed, color.height(), None)?;
            let coc_px = tilt_shift_coc(color.width(), color.height(), &ts)?;
            if a.verbose {
                eprintln!(
                    "tilt-shift: band centre {} of the height, width {}, angle {} deg, blur up to {} px over {} of the height",
                    ts.centre_y, ts.width, ts.angle_deg, ts.max_coc_px, ts.ramp
                );
            }
            return Ok(Self {
                color,
                input: Input::TiltShift { coc_px },
                settings,
                read_timings,
                exr: a.exr.options(),
                out: a.out.clone(),
                coc_out: a.coc_out.clone(),
                timings: a.timings,
            });
        }
        let depth_path = a
            .depth
            .as_ref()
            .context("--depth FILE is needed (or --tilt-shift)")?;
        if a.verbose
            && depth_path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
        {
            let (_, depth) = io::exr_channel_choice(depth_path, a.depth_channel.as_deref())?;
            if let Ok(name) = depth {
                eprintln!("depth: {} channel {name}", depth_path.display());
            }
        }
        let opts = DepthRead {
            channel: a.depth_channel.clone(),
            scale: a.depth_scale,
            radial: a.depth_kind == DepthKind::Radial,
        };
        let mut depth = read_timings.time(timing::READ, || io::read_depth(depth_path, &opts))?;
        if !color.same_size(&depth) {
            bail!(
                "size mismatch: colour {} is {}x{} but depth {} is {}x{}",
                a.color.display(),
                color.width(),
                color.height(),
                depth_path.display(),
                depth.width(),
                depth.height()
            );
        }
        let mut camera = Camera {
            width_px: color.width(),
            height_px: color.height(),
            camera_from_world: glam::Affine3A::IDENTITY,
            focal_length_mm: a.focal_length,
            sensor_width_mm: a.sensor_width,
            fstop: a.fstop,
            focus_m: 1.0,
            near_m: 1e-6,
            far_m: f32::MAX,
            yfov_rad: None,
        };
        // Check the lens flags before they are used to convert radial depth.
        camera
            .thin_lens()
            .context("invalid camera (check --fstop, --focal-length, --sensor-width)")?;
        if a.depth_kind == DepthKind::Radial {
            let f_px =
                defocus::lens::focal_length_px(a.focal_length, a.sensor_width, color.width());
            io::radial_to_view_depth(&mut depth, f_px);
        }
        camera.focus_m = if a.focus.trim() == "auto" {
            let pick = focus_in_depth(&depth, color.width() / 2, color.height() / 2)
                .context("--focus auto: the depth image has no surface (only holes or background); give --focus M")?;
            eprintln!(
                "focus: {:.4} m (median depth of the {w}x{w} pixels at the image centre)",
                pick.depth_m,
                w = pick.window_px
            );
            pick.depth_m
        } else {
            a.focus.trim().parse::<f32>().map_err(|_| {
                anyhow::anyhow!("invalid --focus '{}': expected metres or auto", a.focus)
            })?
        };
        let lens = camera
            .thin_lens()
            .context("invalid camera (check --focus, --fstop, --focal-length, --sensor-width)")?;
        let settings = a
            .post
            .settings(method, &aperture, a.seed, color.height(), Some(&lens))?;
        if a.verbose {
            eprintln!(
                "lens: f_px {:.2}, lens radius {:.5} m, focus {:.4} m, CoC at infinity {:.2} px",
                lens.f_px,
                lens.lens_radius_m,
                lens.focus_m,
                lens.coc_at_infinity_px()
            );
        }
        Ok(Self {
            color,
            input: Input::Depth { depth, lens },
            settings,
            read_timings,
            exr: a.exr.options(),
            out: a.out.clone(),
            coc_out: a.coc_out.clone(),
            timings: a.timings,
        })
    }
}

impl BlurJob {
    /// Runs the method: its output, with the time spent reading the inputs in its timings.
    pub fn compute(&self) -> Result<MethodOutput> {
        let mut output: MethodOutput = match (&self.input, &self.settings) {
            (Input::Depth { depth, lens }, settings) => registry::run_frame(
                settings,
                &Frame {
                    color: &self.color,
                    depth,
                    lens,
                },
            )?,
            (Input::TiltShift { coc_px }, MethodSettings::Lowrank(s)) => {
                lowrank::render_coc(&self.color, coc_px, s)?
            }
            (Input::TiltShift { .. }, _) => bail!("--tilt-shift works with --method lowrank"),
        };
        let mut timings = self.read_timings.clone();
        timings.extend(&output.timings);
        output.timings = timings;
        Ok(output)
    }

    /// Runs the method and writes the output.
    pub fn run(self) -> Result<()> {
        let output = self.compute()?;
        let mut timings = output.timings.clone();
        let id = self.settings.id();
        // Both outputs or neither: staged, renamed when both are written.
        let mut set = io::OutputSet::new();
        timings.time(timing::WRITE, || {
            io::write_color_with(&set.stage(&self.out)?, &output.image, &self.exr)
        })?;
        if let Some(path) = &self.coc_out {
            let path = &set.stage(path)?;
            let coc: Vec<f32> = match &self.input {
                Input::Depth { depth, lens } => {
                    depth.pixels().iter().map(|&z| lens.coc_px(z)).collect()
                }
                Input::TiltShift { coc_px } => coc_px.pixels().to_vec(),
            };
            io::write_exr_layers(
                path,
                self.color.width(),
                self.color.height(),
                &[("CoC", &coc)],
            )?;
        }
        set.commit()?;
        report_timings(
            self.timings,
            id,
            self.color.width(),
            self.color.height(),
            &timings,
            output.memory_bytes,
        );
        Ok(())
    }
}
