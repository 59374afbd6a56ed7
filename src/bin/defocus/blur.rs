//! `defocus blur`: depth of field for a rendered colour image with a depth pass.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use defocus::image::io::{self, DepthRead};
use defocus::image::{ColorImage, GrayImage};
use defocus::lens::{Camera, ThinLens};
use defocus::methods::MethodOutput;

use crate::args::TimingFormat;
use crate::commands::{check_output, report_timings, IMAGE_EXTENSIONS};

/// Methods `blur` can run (single-image methods: colour + depth in, colour out).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum BlurMethod {
    /// Hammon, GPU Gems 3 ch. 28: post-process gather with a blurred near CoC.
    Hammon,
}

impl BlurMethod {
    fn id(self) -> &'static str {
        match self {
            BlurMethod::Hammon => "hammon",
        }
    }
}

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
    /// itself), 8/16-bit PNG or PFM (times --depth-scale).
    #[arg(long, value_name = "FILE")]
    pub depth: PathBuf,
    /// EXR depth channel (full name or unique suffix) [default: searched: Z, depth, *.Depth.Z].
    #[arg(long, value_name = "NAME")]
    pub depth_channel: Option<String>,
    /// Whether depth is view-axis distance or radial distance from the eye.
    #[arg(long, value_enum, default_value_t = DepthKind::View)]
    pub depth_kind: DepthKind,
    /// Metres per stored depth unit (e.g. for a 16-bit PNG read as value/65535).
    #[arg(
        long,
        default_value_t = 1.0,
        value_name = "M",
        allow_negative_numbers = true
    )]
    pub depth_scale: f32,
    /// DoF method.
    #[arg(long, value_enum, default_value_t = BlurMethod::Hammon)]
    pub method: BlurMethod,
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
    /// Output image: .exr (linear float RGBA), .png (8-bit sRGB) or .pfm.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Print per-pass timings: a table on stderr, or `--timings json` on stdout.
    #[arg(long, value_enum, num_args = 0..=1, default_missing_value = "table", value_name = "FORMAT")]
    pub timings: Option<TimingFormat>,
    /// Say which channels and parameters were used (on stderr).
    #[arg(long, short)]
    pub verbose: bool,
}

/// Half-size of the window used by `--focus auto`, as a fraction of the image width.
const AUTOFOCUS_WINDOW: f32 = 0.01;

/// Median depth of the finite depths in a window around `(x, y)` whose half-size is 1% of the
/// image width (at least 1 pixel): robust to holes and thin foreground objects.
pub fn autofocus_depth(depth: &GrayImage, x: usize, y: usize) -> Option<f32> {
    let r = ((depth.width() as f32 * AUTOFOCUS_WINDOW).round() as usize).max(1);
    let mut values: Vec<f32> = (y.saturating_sub(r)..(y + r + 1).min(depth.height()))
        .flat_map(|yy| {
            (x.saturating_sub(r)..(x + r + 1).min(depth.width())).map(move |xx| (xx, yy))
        })
        .map(|(xx, yy)| depth.get(xx, yy))
        .filter(|z| z.is_finite() && *z > 0.0 && *z < f32::MAX)
        .collect();
    if values.is_empty() {
        return None;
    }
    values.sort_by(f32::total_cmp);
    Some(values[values.len() / 2])
}

/// A validated `blur` job: images read, sizes checked, lens derived.
pub struct BlurJob {
    color: ColorImage,
    depth: GrayImage,
    lens: ThinLens,
    method: BlurMethod,
    out: PathBuf,
    timings: Option<TimingFormat>,
}

impl TryFrom<&BlurArgs> for BlurJob {
    type Error = anyhow::Error;

    fn try_from(a: &BlurArgs) -> Result<Self> {
        check_output(&a.out, "--out", IMAGE_EXTENSIONS)?;
        io::ensure_not_same_file(&a.color, &a.out)?;
        io::ensure_not_same_file(&a.depth, &a.out)?;
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
        if a.verbose
            && a.depth
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("exr"))
        {
            let (_, depth) = io::exr_channel_choice(&a.depth, a.depth_channel.as_deref())?;
            if let Ok(name) = depth {
                eprintln!("depth: {} channel {name}", a.depth.display());
            }
        }
        let color = io::read_color(&a.color)?;
        let opts = DepthRead {
            channel: a.depth_channel.clone(),
            scale: a.depth_scale,
            radial: a.depth_kind == DepthKind::Radial,
        };
        let mut depth = io::read_depth(&a.depth, &opts)?;
        if !color.same_size(&depth) {
            bail!(
                "size mismatch: colour {} is {}x{} but depth {} is {}x{}",
                a.color.display(),
                color.width(),
                color.height(),
                a.depth.display(),
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
        if a.depth_kind == DepthKind::Radial {
            let f_px = a.focal_length / a.sensor_width * color.width() as f32;
            io::radial_to_view_depth(&mut depth, f_px);
        }
        camera.focus_m = if a.focus == "auto" {
            let z = autofocus_depth(&depth, color.width() / 2, color.height() / 2)
                .context("--focus auto: no finite depth near the image centre; give --focus M")?;
            eprintln!("focus: {z:.4} m (auto, median depth at the image centre)");
            z
        } else {
            a.focus.parse::<f32>().map_err(|_| {
                anyhow::anyhow!("invalid --focus '{}': expected metres or auto", a.focus)
            })?
        };
        let lens = camera
            .thin_lens()
            .context("invalid camera (check --focus, --fstop, --focal-length, --sensor-width)")?;
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
            depth,
            lens,
            method: a.method,
            out: a.out.clone(),
            timings: a.timings,
        })
    }
}

impl BlurJob {
    /// Runs the method and writes the output.
    pub fn run(self) -> Result<()> {
        let output: MethodOutput = match self.method {
            BlurMethod::Hammon => defocus::methods::hammon::render(
                &self.color,
                &self.depth,
                &self.lens,
                &defocus::methods::hammon::HammonSettings::default(),
            )?,
        };
        let mut timings = output.timings.clone();
        let id = self.method.id();
        timings.time(&format!("{id}/write"), || {
            io::write_color(&self.out, &output.image)
        })?;
        report_timings(
            self.timings,
            id,
            self.lens.width_px,
            self.lens.height_px,
            &timings,
        );
        Ok(())
    }
}
