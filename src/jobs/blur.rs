//! `defocus blur`: depth of field for a rendered colour image with a depth pass. Its flags
//! ([`BlurArgs`]), the validated job ([`BlurJob`]: images read, sizes checked, lens derived)
//! and its run. Lines the command line shows go to a `notes` sink.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::blur::{describe_placement, frame_lens, FocusChoice, FrameLens, Highlights, LensSpec};
use crate::error::shown;
use crate::frames::Keyed;
use crate::gpu::GpuContext;
use crate::image::io::{self, DepthRead, Placement};
use crate::image::{ColorImage, GrayImage};
use crate::lens::ThinLens;
use crate::methods::fill::{self, FillSettings, Occlusion};
use crate::methods::lowrank::{self, tilt_shift_coc_in_frame, TiltShift};
use crate::methods::registry::{self, Frame, InputKind, MethodSettings};
use crate::methods::MethodOutput;
use crate::timing::{self, Timings};
use anyhow::{bail, Context, Result};
use clap::Args;

use super::flags::{
    check_input, check_output, device_name, method_parser, open_device, DeviceArg, ExrArgs,
    FrameDone, TimingFormat, IMAGE_EXTENSIONS,
};
use crate::options::{parse_aperture, PostArgs};

pub use crate::blur::DepthKind;

/// Flags of `blur`.
#[derive(Debug, Args, Clone)]
pub struct BlurArgs {
    /// Colour image: EXR (plain R/G/B/A or a multilayer file's Combined layer), PNG (sRGB) or PFM.
    /// An EXR's data window keeps its place in the display window: depth is cut to it, an EXR
    /// output keeps both windows, and autofocus and --tilt-shift measure from the display window.
    /// A frame pattern (`shot.####.exr`: one digit per # or @; or `shot.%04d.exr`) blurs a
    /// sequence: --depth, --out and --coc-out are then patterns too (a depth file without one
    /// serves every frame).
    #[arg(long, value_name = "FILE")]
    pub color: PathBuf,
    /// Depth image in metres: EXR channel Z / depth / `<layer>.Depth.Z` (may be the colour file
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
    /// A depth of exactly 0 marks "no surface" (the background of some renderers): it is taken
    /// as infinitely far instead of refused.
    #[arg(long)]
    pub zero_depth_is_far: bool,
    /// DoF method [default: hammon; lowrank with --tilt-shift]. Methods that need a 3D scene
    /// (reference, pinhole, and the layered ones) are refused: use `defocus render`.
    #[arg(long, value_parser = method_parser())]
    pub method: Option<String>,
    /// Focus distance in metres, or `auto` (median depth of a small window at the image centre,
    /// per frame). In a sequence, keyframes FRAME:M,... for a rack focus (`1001:2.0,1100:5.0`),
    /// interpolated linearly in 1/distance, the way a focus puller's ring moves the image, and
    /// held outside the keys.
    #[arg(
        long,
        default_value = "auto",
        value_name = "M|auto|F:M,...",
        allow_hyphen_values = true
    )]
    pub focus: String,
    /// Focus on the depth at pixel X,Y (column, row from the top left of the frame: for an EXR,
    /// of its display window), the median of a small window around it, as --focus auto does at
    /// the centre.
    #[arg(long, value_name = "X,Y", value_parser = super::flags::parse_pixel, conflicts_with = "focus")]
    pub focus_pixel: Option<(usize, usize)>,
    /// f-number N; the lens radius is focal length / (2 N). In a sequence, keyframes
    /// FRAME:N,... interpolated in stops (linearly in log N).
    #[arg(
        long,
        default_value = "2.8",
        value_name = "N|F:N,...",
        value_parser = super::flags::parse_fstop,
        allow_hyphen_values = true
    )]
    pub fstop: Keyed,
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
    /// Output image: .exr (linear float RGBA), .png (8-bit sRGB) or .pfm (a frame pattern for
    /// a sequence).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// The frames of a sequence (`1001-1100`, `1-100x2`, `1,5,10-20`) [default: every frame
    /// of --color's pattern found on disk]. Frames run side by side within the memory budget;
    /// a frame whose outputs exist is kept (an interrupted run resumes) unless --overwrite is
    /// given; a missing or bad frame is named and the others still finish.
    #[arg(long, value_name = "FRAMES", allow_hyphen_values = true)]
    pub frames: Option<String>,
    /// In a sequence: blur frames whose outputs exist again, replacing them.
    #[arg(long)]
    pub overwrite: bool,
    /// Set for the frames of a sequence: notes that every frame would repeat are not printed.
    #[arg(skip)]
    pub in_sequence: bool,
    /// Where the method runs: `auto` (a hardware GPU when there is one and the method runs
    /// there, else the CPU), `cpu`, or `gpu` (any GPU adapter, a software one included; an
    /// error when there is none). On the GPU so far: hammon and gaussian. `defocus devices`
    /// lists the adapters.
    #[arg(long, value_enum, default_value_t = DeviceArg::Auto, value_name = "DEVICE")]
    pub device: DeviceArg,
    /// Print per-pass timings and the device: a table on stderr, or `--timings json` on stdout.
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
    /// Lift clipped highlights of low-dynamic-range input (an 8-bit photo) back towards their
    /// true brightness before the blur, in linear light: pixels whose brightest channel is
    /// above THRESHOLD (0 to 1) are scaled by up to GAIN, reached at THRESHOLD + KNEE
    /// [default KNEE: 1 - THRESHOLD, so a clipped pixel gets the whole gain], e.g. `0.9,20`.
    /// Bokeh of street lights then comes out bright instead of grey.
    #[arg(long, value_name = "THRESHOLD,GAIN[,KNEE]")]
    pub highlights: Option<String>,
    /// EXR output options.
    #[command(flatten)]
    pub exr: ExrArgs,
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
    /// What near blur uncovers (`--occlusion`).
    occlusion: Occlusion,
    /// Time spent reading the inputs.
    read_timings: Timings,
    /// How EXR outputs are written.
    exr: io::ExrOptions,
    out: PathBuf,
    coc_out: Option<PathBuf>,
    timings: Option<TimingFormat>,
    /// The GPU the method runs on; `None` for the CPU.
    gpu: Option<Arc<GpuContext>>,
}

/// The method a `blur` runs: `--method`, else `hammon`, or `lowrank` with `--tilt-shift`.
pub fn method_of(a: &BlurArgs) -> Result<&str> {
    Ok(match (a.method.as_deref(), a.tilt_shift.is_some()) {
        (None, false) => "hammon",
        (None, true) | (Some("lowrank"), true) => "lowrank",
        (Some(m), false) => m,
        (Some(m), true) => {
            bail!("--tilt-shift works with --method lowrank (McGraw section 4), not {m}")
        }
    })
}

impl BlurJob {
    /// Checks the flags, opens the device (`--device`), reads the images and derives the lens;
    /// `notes` receives the lines the command line shows (channels chosen, the focus picked,
    /// `--verbose` details).
    pub fn new(a: &BlurArgs, notes: &mut dyn FnMut(String)) -> Result<Self> {
        let gpu = open_device(a.device, method_of(a)?)?;
        Self::new_on(a, gpu, notes)
    }

    /// [`BlurJob::new`] on a GPU context the caller opened ([`open_device`]; `None` for the
    /// CPU), which a sequence shares between its frames.
    pub fn new_on(
        a: &BlurArgs,
        gpu: Option<Arc<GpuContext>>,
        notes: &mut dyn FnMut(String),
    ) -> Result<Self> {
        check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
        if let Some(c) = &a.coc_out {
            check_output(c, "--coc-out", &["exr"])?;
            io::check_distinct_outputs(&[("--out", &a.out), ("--coc-out", c)])?;
        }
        check_input(&a.color, "--color")?;
        if let Some(d) = &a.depth {
            check_input(d, "--depth")?;
        }
        for out in std::iter::once(&a.out).chain(&a.coc_out) {
            io::ensure_not_same_file(&a.color, out)?;
            if let Some(d) = &a.depth {
                io::ensure_not_same_file(d, out)?;
            }
        }
        let tilt_shift = a.tilt_shift.as_deref().map(parse_tilt_shift).transpose()?;
        let method = method_of(a)?;
        let info = registry::find(method)?;
        if !info.input.takes_frame() {
            bail!(
                "--method {method} needs {}, not a colour image with a depth pass: run `defocus render --method {method} --scene ...` instead",
                info.input.describe()
            );
        }
        let mut read_timings = Timings::default();
        if tilt_shift.is_some() && a.depth.is_some() {
            bail!("--tilt-shift paints the blur itself: give no --depth with it");
        }
        check_budget(a, method)?;
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
                notes(format!(
                    "colour: {} channels {}",
                    shown(&a.color),
                    shown(&names.join(", "))
                ));
            }
        }
        let mut color = read_timings.time(timing::READ, || io::read_color(&a.color))?;
        // Where an EXR's data window lies in its display window; `None` for other formats.
        let color_place = io::read_exr_placement(&a.color)?;
        let (w, h) = (color.width(), color.height());
        let frame = color_place.unwrap_or_else(|| Placement::full(w, h));
        if a.verbose && !frame.is_full(w, h) {
            notes(format!(
                "colour: {}",
                describe_placement(&shown(&a.color), w, h, &frame)
            ));
        }
        let mut exr = a.exr.options();
        exr.placement = color_place.filter(|p| !p.is_full(w, h));
        if exr.placement.is_some() && !has_extension(&a.out, "exr") && !a.in_sequence {
            notes(format!(
                "note: {} is not OpenEXR: it holds the colour image's {w}x{h} pixels without \
                 their place in the frame ({}); write .exr to keep it",
                shown(&a.out),
                describe_placement(&shown(&a.color), w, h, &frame)
            ));
        }
        if a.sanitize {
            let n = io::sanitize_color(&mut color);
            if n > 0 {
                notes(format!(
                    "--sanitize: {n} pixel(s) of {} had NaN or infinite values, set to 0",
                    shown(&a.color)
                ));
            }
        } else {
            io::check_finite_color(&a.color, &color)?;
        }
        if let Some(spec) = &a.highlights {
            let lifted = Highlights::parse(spec)?.apply(&mut color);
            if a.verbose {
                notes(format!("highlights: {lifted} pixel(s) lifted"));
            }
        }
        if let Some(ts) = tilt_shift {
            let mut post = a.post.clone();
            post.max_coc = Some(post.max_coc_px().max(ts.max_coc_px));
            let settings = post.settings(method, &aperture, a.seed, color.height(), None)?;
            let coc_px = tilt_shift_coc_in_frame(w, h, frame.offset(), frame.display_size, &ts)?;
            if a.verbose {
                notes(format!(
                    "tilt-shift: band centre {} of the height, width {}, angle {} deg, blur up to {} px over {} of the height",
                    ts.centre_y, ts.width, ts.angle_deg, ts.max_coc_px, ts.ramp
                ));
            }
            return Ok(Self {
                color,
                input: Input::TiltShift { coc_px },
                settings,
                occlusion: a.post.occlusion,
                read_timings,
                exr,
                out: a.out.clone(),
                coc_out: a.coc_out.clone(),
                timings: a.timings,
                gpu,
            });
        }
        let depth_path = a
            .depth
            .as_ref()
            .context("--depth FILE is needed (or --tilt-shift)")?;
        if a.verbose
            && a.depth_kind != DepthKind::Coc
            && depth_path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
        {
            let (_, depth) = io::exr_channel_choice(depth_path, a.depth_channel.as_deref())?;
            if let Ok(name) = depth {
                notes(format!(
                    "depth: {} channel {}",
                    shown(&depth_path),
                    shown(&name)
                ));
            }
        }
        let opts = DepthRead {
            channel: a.depth_channel.clone(),
            scale: a.depth_scale,
            radial: a.depth_kind == DepthKind::Radial,
            inverse: a.depth_kind == DepthKind::Inverse,
            zero_is_far: a.zero_depth_is_far,
        };
        let depth = read_timings.time(timing::READ, || -> Result<GrayImage> {
            if a.depth_kind != DepthKind::Coc {
                return Ok(io::read_depth(depth_path, &opts)?);
            }
            if !(a.depth_scale.is_finite() && a.depth_scale > 0.0) {
                bail!(
                    "--depth-scale {}: expected a finite number > 0",
                    a.depth_scale
                );
            }
            let coc = io::read_coc(depth_path, a.depth_channel.as_deref())?;
            let coc = coc.map(|c| c * a.depth_scale);
            if let Some(why) = io::bad_coc_radii(coc.pixels(), coc.width()) {
                bail!(
                    "{}: the CoC radii times --depth-scale {}: {why}",
                    shown(&depth_path),
                    a.depth_scale
                );
            }
            Ok(coc)
        })?;
        let depth_place = io::read_exr_placement(depth_path)?;
        let depth = align_depth(
            (&a.color, w, h, color_place),
            (depth_path, depth, depth_place),
        )?;
        let focus = match (a.focus_pixel, a.focus.trim()) {
            (Some((x, y)), _) => FocusChoice::Pixel(x, y),
            (None, "auto") => FocusChoice::Auto,
            (None, m) => FocusChoice::Metres(m.parse::<f32>().map_err(|_| {
                if m.contains(':') {
                    anyhow::anyhow!(
                        "--focus '{m}' has keyframes: they need a frame sequence (a frame pattern \
                         such as shot.####.exr in --color)"
                    )
                } else {
                    anyhow::anyhow!("invalid --focus '{m}': expected metres or auto")
                }
            })?),
        };
        let spec = LensSpec {
            fstop: super::flags::single_value(&a.fstop, "--fstop")?,
            focal_length_mm: a.focal_length,
            sensor_width_mm: a.sensor_width,
        };
        let kind = a.depth_kind;
        let FrameLens {
            depth,
            lens,
            focus_pick,
        } = frame_lens(depth, kind, focus, &spec, &frame, &shown(&a.color))?;
        if let Some(pick) = focus_pick.filter(|_| !a.in_sequence || a.verbose) {
            let place = match focus {
                FocusChoice::Pixel(x, y) => format!("around ({x}, {y})"),
                _ => "at the image centre".to_string(),
            };
            notes(format!(
                "focus: {:.4} m (median depth of the {w}x{w} pixels {place})",
                pick.depth_m,
                w = pick.window_px
            ));
        }
        let settings = a
            .post
            .settings(method, &aperture, a.seed, color.height(), Some(&lens))?;
        if a.verbose {
            notes(format!(
                "lens: f_px {:.2}, lens radius {:.5} m, focus {:.4} m, CoC at infinity {:.2} px",
                lens.f_px,
                lens.lens_radius_m,
                lens.focus_m,
                lens.coc_at_infinity_px()
            ));
        }
        Ok(Self {
            color,
            input: Input::Depth { depth, lens },
            settings,
            occlusion: a.post.occlusion,
            read_timings,
            exr,
            out: a.out.clone(),
            coc_out: a.coc_out.clone(),
            timings: a.timings,
            gpu,
        })
    }

    /// Runs the method: its output, with the time spent reading the inputs in its timings.
    pub fn compute(&self) -> Result<MethodOutput> {
        let mut output: MethodOutput = match (&self.input, &self.settings) {
            (Input::Depth { depth, lens }, settings) => {
                let frame = Frame {
                    color: &self.color,
                    depth,
                    lens,
                };
                let layered = registry::find(settings.id())?.input == InputKind::FragmentLists
                    || matches!(
                        (settings, self.occlusion),
                        (MethodSettings::Splat(_), Occlusion::Fill)
                    );
                match self.occlusion {
                    _ if layered => {
                        if self.gpu.is_some() {
                            registry::check_gpu(settings.id())?;
                        }
                        fill::run_layered(settings, &frame, self.occlusion)?
                    }
                    Occlusion::None => {
                        registry::run_frame_on(settings, &frame, self.gpu.as_deref())?
                    }
                    Occlusion::Fill if self.gpu.is_some() => bail!(
                        "--occlusion fill runs on the CPU only so far: use --device cpu, or --occlusion none"
                    ),
                    Occlusion::Fill => fill::run_frame(settings, &frame, &FillSettings::default())?,
                }
            }
            (Input::TiltShift { coc_px }, MethodSettings::Lowrank(s)) => {
                match self.gpu.as_deref() {
                    Some(ctx) => {
                        let out = lowrank::gpu::render_coc(ctx, &self.color, coc_px, s);
                        ctx.check()?;
                        out?
                    }
                    None => lowrank::render_coc(&self.color, coc_px, s)?,
                }
            }
            (Input::TiltShift { .. }, _) => bail!("--tilt-shift works with --method lowrank"),
        };
        let mut timings = self.read_timings.clone();
        timings.extend(&output.timings);
        output.timings = timings;
        Ok(output)
    }

    /// How `--timings` reports, if asked.
    pub fn timing_format(&self) -> Option<TimingFormat> {
        self.timings
    }

    /// Runs the method and writes the outputs; what it took.
    pub fn execute(self) -> Result<FrameDone> {
        let output = self.compute()?;
        let mut timings = output.timings.clone();
        let id = self.settings.id();
        // Both outputs or neither: staged, renamed when both are written.
        let mut set = io::OutputSet::new();
        timings.time(timing::WRITE, || {
            set.write_color(&self.out, &output.image, &self.exr)
        })?;
        if let Some(path) = &self.coc_out {
            let coc: Vec<f32> = match &self.input {
                Input::Depth { depth, lens } => {
                    depth.pixels().iter().map(|&z| lens.coc_px(z)).collect()
                }
                Input::TiltShift { coc_px } => coc_px.pixels().to_vec(),
            };
            set.write_exr_layers(
                path,
                self.color.width(),
                self.color.height(),
                &[("CoC", &coc)],
                self.exr.placement,
            )?;
        }
        set.commit()?;
        Ok(FrameDone {
            method: id,
            device: device_name(self.gpu.as_deref()),
            width: self.color.width(),
            height: self.color.height(),
            timings,
            memory_bytes: output.memory_bytes,
        })
    }
}

/// Refuses a blur beyond the memory budget ([`crate::budget`]) from its images' headers,
/// before any pixel is decoded: the peak of reading the colour (all its channels with
/// `--verbose`, which lists them), of reading the depth while the colour is held, and the
/// method's own estimate at the colour's size ([`registry::peak_bytes`]), whichever is the
/// largest. Errors name the file or the method, and the budget. A header that does not read is
/// left to the read itself, whose error says what is wrong with the file.
fn check_budget(a: &BlurArgs, method: &str) -> Result<()> {
    use io::ReadAs;
    let Ok((mut color, (w, h))) = io::read_peak_bytes(&a.color, ReadAs::Color) else {
        return Ok(());
    };
    if a.verbose && has_extension(&a.color, "exr") {
        if let Ok((all, _)) = io::read_peak_bytes(&a.color, ReadAs::Channel) {
            color = color.max(all);
        }
    }
    crate::budget::check(
        color,
        &format!("decoding {} ({w}x{h})", shown(&a.color)),
        "the image's size",
    )?;
    let image_bytes = (w * h) as u64 * std::mem::size_of::<crate::image::Rgba>() as u64;
    if let Some(d) = &a.depth {
        if let Ok((depth, (dw, dh))) = io::read_peak_bytes(d, ReadAs::Channel) {
            crate::budget::check(
                image_bytes + depth,
                &format!("decoding {} ({dw}x{dh}) beside the colour image", shown(d)),
                "the images' size",
            )?;
        }
    }
    let settings = MethodSettings::default_for(method)?;
    crate::budget::check(
        registry::peak_bytes(&settings, w, h),
        &format!("blur --method {method} of {} ({w}x{h})", shown(&a.color)),
        "the resolution",
    )?;
    Ok(())
}

/// Whether `path` ends in `.ext` (any case).
fn has_extension(path: &Path, ext: &str) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case(ext))
}

/// The depth of the colour image's pixels. Same size as the colour image: taken as it is.
/// Otherwise the two are placed in one frame by their OpenEXR windows (data window inside
/// display window), an image of another format covering its partner's whole frame, and the
/// depth is cropped to the colour's pixels, which it must cover.
fn align_depth(
    (color_path, w, h, color_place): (&Path, usize, usize, Option<Placement>),
    (depth_path, depth, depth_place): (&Path, GrayImage, Option<Placement>),
) -> Result<GrayImage> {
    let (dw, dh) = (depth.width(), depth.height());
    // Rectangles (x, y, width, height) in the file's pixel coordinates.
    let rect = |p: &Placement, w: usize, h: usize| {
        (i64::from(p.data_origin.0), i64::from(p.data_origin.1), w, h)
    };
    let frame_rect = |p: &Placement| {
        let (x, y) = p.display_origin;
        (
            i64::from(x),
            i64::from(y),
            p.display_size.0,
            p.display_size.1,
        )
    };
    let placed = match (color_place, depth_place) {
        (Some(c), Some(d)) => Some((rect(&c, w, h), rect(&d, dw, dh))),
        // A depth image without a window the size of the colour's frame is that frame.
        (Some(c), None) if (dw, dh) != (w, h) && c.display_size == (dw, dh) => {
            Some((rect(&c, w, h), frame_rect(&c)))
        }
        // A colour image without a window the size of the depth's frame is that frame.
        (None, Some(d)) if (dw, dh) != (w, h) && d.display_size == (w, h) => {
            Some((frame_rect(&d), rect(&d, dw, dh)))
        }
        _ => None,
    };
    let Some((c, d)) = placed else {
        if (dw, dh) != (w, h) {
            bail!(
                "size mismatch: colour {} is {w}x{h} but depth {} is {dw}x{dh}",
                shown(&color_path),
                shown(&depth_path),
            );
        }
        return Ok(depth);
    };
    if c == d {
        return Ok(depth);
    }
    let (x0, y0) = (c.0 - d.0, c.1 - d.1);
    let inside = x0 >= 0 && y0 >= 0 && x0 + c.2 as i64 <= dw as i64 && y0 + c.3 as i64 <= dh as i64;
    if !inside {
        let describe =
            |r: (i64, i64, usize, usize)| format!("{}x{} pixels from ({}, {})", r.2, r.3, r.0, r.1);
        bail!(
            "depth {} covers {} of the frame but colour {} covers {}: expected depth for every \
             colour pixel (OpenEXR data windows, or a PNG/PFM the size of the frame)",
            shown(&depth_path),
            describe(d),
            shown(&color_path),
            describe(c),
        );
    }
    let (x0, y0) = (x0 as usize, y0 as usize);
    let mut cropped = Vec::with_capacity(w * h);
    for row in depth.pixels().chunks_exact(dw).skip(y0).take(h) {
        cropped.extend_from_slice(&row[x0..x0 + w]);
    }
    Ok(GrayImage::from_vec(w, h, cropped)?)
}
