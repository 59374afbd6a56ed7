//! `defocus kernel`: an aperture kernel, its singular values and the error of its low-rank
//! approximations (McGraw section 3, eqs. 1-4).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use defocus::image::{io, ColorImage, GrayImage};
use defocus::methods::lowrank::filter::{filter_separable_with, Channels, Schedule};
use defocus::methods::lowrank::{decompose, filter_full_2d, kernel_image, KernelSpec};
use defocus::metrics;

use crate::common::{check_input, check_output, eprint_line, parse_aperture, IMAGE_EXTENSIONS};

/// Flags of `kernel`.
#[derive(Debug, Args)]
pub struct KernelArgs {
    /// Aperture: `disc`, `poly:B[,rot=DEG][,curve=R]`, `star[:N[,INNER]]`, `heart`,
    /// `ring[:INNER]` or `image:PATH`.
    #[arg(long, default_value = "disc", value_name = "SPEC")]
    pub aperture: String,
    /// Side of the square kernel in pixels (odd; the paper's largest is 65).
    #[arg(long, default_value_t = 65, value_name = "PX")]
    pub size: usize,
    /// Ranks to report: `R` or `A..B` (inclusive) [default: 1..10, or 1..size for kernels
    /// smaller than 10 pixels].
    #[arg(long, value_name = "R|A..B")]
    pub rank: Option<String>,
    /// Spherical aberration, -1 (bright centre) to 1 (bright rim).
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "A",
        allow_negative_numbers = true
    )]
    pub aberration: f32,
    /// Samples per kernel pixel and axis when rasterizing the aperture (1 to 32).
    #[arg(long, default_value_t = 8, value_name = "N")]
    pub supersample: usize,
    /// Write the kernel as an image, scaled so its largest value is 1 (.png, .exr or .pfm).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Write the rank-r approximation of the highest rank asked for, on the kernel's scale
    /// (EXR and PFM keep its negative lobes; PNG clamps them to 0).
    #[arg(long, value_name = "FILE")]
    pub approx_out: Option<PathBuf>,
    /// Blur this image with the kernel, spatially invariant (McGraw eq. 1: per rank a
    /// horizontal and a vertical pass), at the highest rank asked for; needs --filter-out.
    #[arg(long, value_name = "IMAGE", requires = "filter_out")]
    pub filter: Option<PathBuf>,
    /// Order of the --filter passes: `banded` (band by band, no intermediate image; the
    /// fastest) or `fig2` (the paper's fig. 2: each rank's horizontal pass over the whole image,
    /// then its vertical pass). Both compute eq. 1; they differ by rounding only.
    #[arg(long, value_enum, default_value_t = ScheduleArg::Banded, requires = "filter")]
    pub schedule: ScheduleArg,
    /// Where the low-rank blur of --filter goes (.exr, .png or .pfm).
    #[arg(long, value_name = "FILE", requires = "filter")]
    pub filter_out: Option<PathBuf>,
    /// Also blur --filter with the full 2D kernel (the convolution the low-rank filter
    /// approximates) into this file, and print the difference and both times.
    #[arg(long, value_name = "FILE", requires = "filter")]
    pub full_2d_out: Option<PathBuf>,
    /// Replace NaN and infinite colour values of --filter by 0 (and say how many) instead of
    /// refusing them (a filter spreads each over its whole kernel).
    #[arg(long, requires = "filter")]
    pub sanitize: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `--schedule`: the order of the separable filter's passes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum ScheduleArg {
    /// Band by band ([`Schedule::Banded`]).
    Banded,
    /// The paper's fig. 2 ([`Schedule::Fig2`]).
    Fig2,
}

/// Parses `R` or `A..B` into an inclusive range of ranks from 1.
fn parse_ranks(spec: &str) -> Result<(usize, usize)> {
    let bad =
        || anyhow::anyhow!("invalid --rank '{spec}': expected R or A..B, whole numbers from 1");
    let (a, b) = match spec.split_once("..") {
        Some((a, b)) => (a.trim(), b.trim().trim_start_matches('=')),
        None => (spec.trim(), spec.trim()),
    };
    let a: usize = a.parse().map_err(|_| bad())?;
    let b: usize = b.parse().map_err(|_| bad())?;
    if a == 0 || b < a {
        return Err(bad());
    }
    Ok((a, b))
}

/// A grey image as RGBA, scaled by `scale`.
fn to_color(g: &GrayImage, scale: f32) -> ColorImage {
    g.map(|v| {
        let v = v * scale;
        [v, v, v, 1.0]
    })
}

/// Runs `defocus kernel`.
pub fn run(a: &KernelArgs) -> Result<()> {
    let outputs = [
        (&a.out, "--out"),
        (&a.approx_out, "--approx-out"),
        (&a.filter_out, "--filter-out"),
        (&a.full_2d_out, "--full-2d-out"),
    ];
    for (path, flag) in outputs {
        if let Some(p) = path {
            check_output(p, flag, IMAGE_EXTENSIONS)?;
            if let Some(input) = &a.filter {
                io::ensure_not_same_file(input, p)?;
            }
        }
    }
    if let Some(input) = &a.filter {
        check_input(input, "--filter")?;
        check_filter_budget(input, a)?;
    }
    let named: Vec<(&str, &std::path::Path)> = outputs
        .iter()
        .filter_map(|(p, f)| p.as_deref().map(|p| (*f, p)))
        .collect();
    io::check_distinct_outputs(&named)?;
    let rank_spec = a
        .rank
        .clone()
        .unwrap_or_else(|| format!("1..{}", a.size.clamp(1, 10)));
    let (r0, r1) = parse_ranks(&rank_spec)?;
    let aperture = parse_aperture(&a.aperture)?;
    if let Some(p) = a.aperture.strip_prefix("image:") {
        for out in a.out.iter().chain(&a.approx_out) {
            io::ensure_not_same_file(std::path::Path::new(p), out)?;
        }
    }
    let spec = KernelSpec {
        aperture,
        size_px: a.size,
        aberration: a.aberration,
        supersample: a.supersample,
    };
    let kernel = kernel_image(&spec)
        .context("invalid kernel (check --size, --aberration, --supersample)")?;
    let lr = decompose(&kernel)?;
    if r1 > lr.len() {
        bail!(
            "invalid --rank '{}': a {}x{} kernel has at most rank {}",
            rank_spec,
            a.size,
            a.size,
            lr.len()
        );
    }
    let peak = kernel.pixels().iter().fold(0.0f32, |m, &v| m.max(v));
    let scale = if peak > 0.0 { 1.0 / peak } else { 1.0 };
    // Every output is staged and renamed only when all are written.
    let mut set = io::OutputSet::new();
    if let Some(p) = &a.out {
        set.write_color(p, &to_color(&kernel, scale), &Default::default())?;
    }
    if let Some(p) = &a.approx_out {
        set.write_color(
            p,
            &to_color(&lr.approximation(r1), scale),
            &Default::default(),
        )?;
    }
    let filtered = match (&a.filter, &a.filter_out) {
        (Some(input), Some(out)) => Some(filter_image(input, out, a, &kernel, &lr, r1, &mut set)?),
        _ => None,
    };
    set.commit()?;
    let ranks: Vec<(usize, f64, f64)> = (r0..=r1)
        .map(|r| (r, lr.relative_error(r), lr.approximation_sum(r)))
        .collect();
    let shown = lr.singular_values().len().min(r1.max(16));
    let text = if a.json {
        serde_json::json!({
            "aperture": a.aperture,
            "size_px": a.size,
            "aberration": a.aberration,
            "full_rank": lr.full_rank(),
            "rank_tolerance": lr.tolerance(),
            "singular_values": lr.singular_values(),
            "ranks": ranks.iter().map(|&(r, e, s)| serde_json::json!({
                "rank": r, "relative_error": e, "sum": s,
            })).collect::<Vec<_>>(),
            "filter": filtered.as_ref().map(|f| serde_json::json!({
                "rank": r1,
                "separable_ms": f.separable_ms,
                "full_2d_ms": f.full_2d_ms,
                "mse_vs_full_2d": f.against_2d.map(|m| m.mse_linear),
                "psnr_vs_full_2d": f.against_2d.map(|m| m.psnr_db),
            })),
        })
        .to_string()
    } else {
        let mut t = format!(
            "kernel: {} {}x{} px, aberration {}, {}x{} samples per pixel\n",
            a.aperture, a.size, a.size, a.aberration, a.supersample, a.supersample
        );
        t += &format!(
            "full rank: {} (singular values above {:.3e})\n",
            lr.full_rank(),
            lr.tolerance()
        );
        t += &format!("singular values (first {shown}):");
        for s in &lr.singular_values()[..shown] {
            t += &format!(" {s:.6e}");
        }
        t += "\nrank  relative_error  kernel_sum\n";
        for (r, e, s) in &ranks {
            t += &format!("{r:>4}  {e:>14.6}  {s:>10.6}\n");
        }
        if let Some(f) = &filtered {
            t += &format!("filter: rank {r1} separable {:.1} ms", f.separable_ms);
            if let (Some(ms), Some(m)) = (f.full_2d_ms, f.against_2d) {
                t += &format!(
                    ", full 2D {ms:.1} ms; rank {r1} against full 2D: MSE {:.3e}, PSNR {:.2} dB",
                    m.mse_linear, m.psnr_db
                );
            }
            t += "\n";
        }
        t.trim_end().to_string()
    };
    crate::common::print_output(&text)
}

/// Refuses a `--filter` beyond the memory budget from the image's header, before any pixel
/// is decoded: reading it, then the low-rank filter and, with `--full-2d-out`, the full 2D
/// filter beside the low-rank result and the metrics of the two ([`metrics::compare`]), while
/// the image is held. A header that does not read is left to the read, whose error says why.
fn check_filter_budget(input: &std::path::Path, a: &KernelArgs) -> Result<()> {
    use defocus::budget::check;
    use defocus::methods::lowrank::filter::{full_2d_bytes, SEPARABLE_BYTES_PER_PIXEL};
    let Ok((read, (w, h))) = io::read_peak_bytes(input, io::ReadAs::Color) else {
        return Ok(());
    };
    let name = defocus::error::shown(input);
    check(
        read,
        &format!("decoding {name} ({w}x{h})"),
        "the image's size",
    )?;
    let image = (w * h) as u64 * std::mem::size_of::<defocus::image::Rgba>() as u64;
    let mut peak = image + (w * h) as u64 * SEPARABLE_BYTES_PER_PIXEL;
    if a.full_2d_out.is_some() {
        // The full filter beside the image and the low-rank result, then the metrics of the
        // two results beside the image.
        peak = peak
            .max(2 * image + full_2d_bytes(w, h, a.size))
            .max(image + metrics::compare_peak_bytes(w, h));
    }
    check(
        peak,
        &format!("kernel --filter {name} ({w}x{h})"),
        "the image's size or --size",
    )?;
    Ok(())
}

/// What `--filter` measured.
struct Filtered {
    separable_ms: f64,
    full_2d_ms: Option<f64>,
    against_2d: Option<metrics::Metrics>,
}

/// Blurs the `--filter` image with the rank-`rank` filter (and the full 2D kernel when asked),
/// writes the results and times both.
fn filter_image(
    input: &std::path::Path,
    out: &std::path::Path,
    a: &KernelArgs,
    kernel: &GrayImage,
    lr: &defocus::methods::lowrank::LowRank,
    rank: usize,
    set: &mut io::OutputSet,
) -> Result<Filtered> {
    let mut img = io::read_color(input)?;
    if a.sanitize {
        let n = io::sanitize_color(&mut img);
        if n > 0 {
            eprint_line(&format!(
                "--sanitize: {n} pixel(s) of {} had NaN or infinite values, set to 0",
                defocus::error::shown(input)
            ));
        }
    } else {
        io::check_finite_color(input, &img)?;
    }
    let start = std::time::Instant::now();
    let schedule = match a.schedule {
        ScheduleArg::Banded => Schedule::Banded,
        ScheduleArg::Fig2 => Schedule::Fig2,
    };
    let low = filter_separable_with(&img, lr, rank, Channels::Auto, schedule);
    let separable_ms = start.elapsed().as_secs_f64() * 1e3;
    set.write_color(out, &low, &Default::default())?;
    let (full_2d_ms, against_2d) = match &a.full_2d_out {
        Some(p) => {
            let start = std::time::Instant::now();
            let full = filter_full_2d(&img, kernel);
            let ms = start.elapsed().as_secs_f64() * 1e3;
            set.write_color(p, &full, &Default::default())?;
            (Some(ms), Some(metrics::compare(&low, &full)?))
        }
        None => (None, None),
    };
    Ok(Filtered {
        separable_ms,
        full_2d_ms,
        against_2d,
    })
}
