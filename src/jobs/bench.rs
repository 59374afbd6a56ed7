//! `defocus bench`: the methods that run on the GPU, timed warm on the built-in scenes, per
//! pass, as one JSON value: what a graphics programmer reads a GPU cost from, and what the
//! documentation's GPU table is made of.
//!
//! For each scene and size the pinhole frame (colour and depth) is rendered once on the CPU;
//! then each method runs `warmup` untimed frames and `frames` timed ones on one GPU context
//! (`pinhole` and `reference` render the scene itself each frame, `reference` with
//! `--samples` views)
//! (pipelines compiled and per-frame constants cached by the first frames, as in a sequence),
//! and the median and least time of each pass and of the method's passes together are
//! reported. Upload and download are reported apart (`gpu/upload`, `gpu/download`): an engine
//! keeps its frame on the GPU. The built-in scenes need no file, so the release binary copied
//! alone to a machine with a GPU runs it.

use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;
use serde_json::{json, Value};

use super::flags::DeviceArg;
use crate::gpu::{Device, GpuContext};
use crate::methods::multilayer::{Bokeh, MultilayerSettings};
use crate::methods::registry::{self, Frame, InputKind, MethodSettings};
use crate::timing::{Clock, Timings};

/// `multilayer` in the paper's configuration, the one its GPU passes run: fragments at pixel
/// centres, box levels, highlights filtered as every fragment.
fn multilayer_paper(aperture: &crate::lens::Aperture) -> MultilayerSettings {
    MultilayerSettings {
        input: crate::raster::LayeredInput {
            coverage: false,
            ..Default::default()
        },
        bokeh: Bokeh::Box,
        highlights: None,
        aperture: aperture.clone(),
        ..MultilayerSettings::default()
    }
}

/// Largest number of timed or warm-up frames a run takes.
pub const MAX_FRAMES: usize = 10_000;

/// Flags of `bench`.
#[derive(Clone, Debug, Args)]
pub struct BenchArgs {
    /// Methods to time, comma-separated, among those that run on the GPU (`multilayer` in the
    /// paper's configuration, which its GPU passes run) [default: all of them]
    #[arg(long, value_delimiter = ',', value_name = "LIST")]
    pub methods: Vec<String>,
    /// Built-in scenes, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "LIST",
        default_value = "railing,grass,lights"
    )]
    pub scenes: Vec<String>,
    /// Frame sizes WIDTHxHEIGHT, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        value_name = "LIST",
        default_value = "1280x720,1920x1080"
    )]
    pub sizes: Vec<String>,
    /// Timed frames per method, scene and size (the median is reported).
    #[arg(long, value_name = "N", default_value_t = 20)]
    pub frames: usize,
    /// Untimed frames before them (pipelines compiled, tables cached, clocks up).
    #[arg(long, value_name = "N", default_value_t = 3)]
    pub warmup: usize,
    /// Where the methods run: `gpu` (any adapter, a software one included), `auto` (a
    /// hardware GPU, else the CPU) or `cpu` (the CPU twins, for comparison).
    #[arg(long, value_enum, default_value = "gpu")]
    pub device: DeviceArg,
    /// Lens views of `reference` a frame.
    #[arg(long, value_name = "N", default_value_t = 64)]
    pub samples: usize,
    /// Also write the JSON to FILE.
    #[arg(long, value_name = "FILE")]
    pub out: Option<std::path::PathBuf>,
}

/// Where a bench is: runs done, runs in all, the run going on.
pub struct BenchProgress<'a> {
    /// Runs finished.
    pub done: usize,
    /// Runs in all.
    pub total: usize,
    /// `scene WxH method` of the run going on.
    pub running: &'a str,
}

/// Parses `WIDTHxHEIGHT`.
fn parse_size(spec: &str) -> Result<(usize, usize)> {
    let bad = || format!("invalid --sizes entry '{spec}': expected WIDTHxHEIGHT, e.g. 1280x720");
    let (w, h) = spec.split_once(['x', 'X']).with_context(bad)?;
    let w: usize = w.trim().parse().ok().with_context(bad)?;
    let h: usize = h.trim().parse().ok().with_context(bad)?;
    if w == 0 || h == 0 || w.saturating_mul(h) > crate::image::MAX_PIXELS {
        bail!(
            "invalid --sizes entry '{spec}': expected at least 1x1 and at most {} pixels",
            crate::image::MAX_PIXELS
        );
    }
    Ok((w, h))
}

/// The median of `v` (sorted in place; the mean of the middle two for an even count).
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => 0.0,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// Whether a pass is the method's own (not the transfers of a GPU run).
fn is_method_pass(name: &str) -> bool {
    !name.starts_with("gpu/")
}

/// One method's frame, `warmup` + `frames` times by `run`: its record.
fn time_method(
    settings: &MethodSettings,
    run: &mut dyn FnMut() -> crate::Result<crate::methods::MethodOutput>,
    args: &BenchArgs,
) -> Result<Value> {
    for _ in 0..args.warmup {
        run()?;
    }
    let mut runs: Vec<Timings> = Vec::with_capacity(args.frames);
    let mut wall = Vec::with_capacity(args.frames);
    for _ in 0..args.frames {
        let start = Instant::now();
        let out = run()?;
        wall.push(start.elapsed().as_secs_f64() * 1e3);
        runs.push(out.timings);
    }
    // Passes in the order of the first run; each pass's median and least over the runs.
    let mut passes = Vec::new();
    for p in runs.first().map(|t| t.passes.clone()).unwrap_or_default() {
        let mut ms: Vec<f64> = runs
            .iter()
            .map(|t| {
                t.passes
                    .iter()
                    .find(|q| q.name == p.name)
                    .map_or(0.0, |q| q.ms)
            })
            .collect();
        let least = ms.iter().copied().fold(f64::INFINITY, f64::min);
        passes.push(json!({
            "name": p.name,
            "clock": p.clock.name(),
            "median_ms": median(&mut ms),
            "min_ms": least,
        }));
    }
    let mut method: Vec<f64> = runs
        .iter()
        .map(|t| {
            t.passes
                .iter()
                .filter(|p| is_method_pass(&p.name))
                .map(|p| p.ms)
                .sum()
        })
        .collect();
    let least = method.iter().copied().fold(f64::INFINITY, f64::min);
    let clocks: Vec<Clock> = runs
        .first()
        .map(|t| {
            t.passes
                .iter()
                .filter(|p| is_method_pass(&p.name))
                .map(|p| p.clock)
                .collect()
        })
        .unwrap_or_default();
    Ok(json!({
        "method": settings.id(),
        "median_ms": median(&mut method),
        "min_ms": least,
        "wall_median_ms": median(&mut wall),
        "gpu_timed": clocks.contains(&Clock::GpuTimestamps),
        "passes": passes,
        "settings": format!("{settings:?}"),
    }))
}

/// Runs the benchmark: one JSON value with the device, the build and a record per method,
/// scene and size. `progress` is called before each run; the library prints nothing.
pub fn run(args: &BenchArgs, progress: &mut dyn FnMut(BenchProgress)) -> Result<Value> {
    if !(1..=MAX_FRAMES).contains(&args.frames) {
        bail!(
            "invalid --frames {}: expected 1 to {MAX_FRAMES}",
            args.frames
        );
    }
    if args.warmup > MAX_FRAMES {
        bail!(
            "invalid --warmup {}: expected 0 to {MAX_FRAMES}",
            args.warmup
        );
    }
    let sizes = args
        .sizes
        .iter()
        .map(|s| parse_size(s))
        .collect::<Result<Vec<_>>>()?;
    if sizes.is_empty() || args.scenes.is_empty() {
        bail!("--sizes and --scenes need at least one entry each");
    }
    for scene in &args.scenes {
        if !crate::scene::builtin::NAMES.contains(&scene.as_str()) {
            bail!(
                "unknown scene '{scene}' in --scenes: the built-in scenes are {}",
                crate::scene::builtin::NAMES.join(", ")
            );
        }
    }
    let methods: Vec<String> = if args.methods.is_empty() {
        registry::gpu_ids()
            .into_iter()
            .map(str::to_string)
            .collect()
    } else {
        args.methods.clone()
    };
    if !(1..=registry::MAX_SAMPLES).contains(&args.samples) {
        bail!(
            "invalid --samples {}: expected 1 to {}",
            args.samples,
            registry::MAX_SAMPLES
        );
    }
    let device: Device = args.device.into();
    for id in &methods {
        let info = registry::find(id)?;
        if !matches!(info.input, InputKind::PinholeFrame | InputKind::SceneViews) && !info.gpu {
            bail!(
                "bench times the methods that run on the GPU ({}); {id} does not yet",
                registry::gpu_ids().join(", ")
            );
        }
        if device == Device::Gpu {
            registry::check_gpu(id)?;
        }
    }
    let gpu = GpuContext::open(device).context("--device")?;
    let adapter = gpu.as_ref().map(|g| g.description().clone());
    let total = args.scenes.len() * sizes.len() * methods.len();
    let mut records = Vec::with_capacity(total);
    for scene_name in &args.scenes {
        let scene = crate::scene::builtin::load(scene_name)?;
        let defaults = scene
            .defaults
            .clone()
            .with_context(|| format!("built-in scene {scene_name} has no camera"))?;
        for &(w, h) in &sizes {
            let mut camera = defaults.camera.clone();
            (camera.width_px, camera.height_px) = (w, h);
            let lens = camera.thin_lens()?;
            let pin = crate::methods::pinhole::render(&scene, &camera, 1, 0, true)?;
            let depth = pin.depth.context("the pinhole render returned no depth")?;
            let frame = Frame {
                color: &pin.image,
                depth: &depth,
                lens: &lens,
            };
            for id in &methods {
                let running = format!("{scene_name} {w}x{h} {id}");
                progress(BenchProgress {
                    done: records.len(),
                    total,
                    running: &running,
                });
                let mut settings = MethodSettings::default_for(id)?;
                match &mut settings {
                    MethodSettings::Reference(r) => r.samples = args.samples,
                    // The configuration the GPU runs (the paper's), on both devices.
                    MethodSettings::Multilayer(m) => *m = multilayer_paper(&defaults.aperture),
                    _ => {}
                }
                // `auto` runs a method without GPU passes on the CPU.
                let on = gpu
                    .as_ref()
                    .filter(|_| registry::find(id).is_ok_and(|m| m.gpu));
                let options = registry::SceneOptions::default();
                let mut run = || {
                    if settings.info().input != InputKind::PinholeFrame {
                        registry::run_scene_on(
                            &settings,
                            &scene,
                            &camera,
                            &options,
                            on,
                            &mut |_, _| {},
                        )
                    } else {
                        registry::run_frame_on(&settings, &frame, on)
                    }
                };
                let mut record = time_method(&settings, &mut run, args)
                    .with_context(|| format!("bench {running}"))?;
                record["scene"] = json!(scene_name);
                record["width"] = json!(w);
                record["height"] = json!(h);
                record["device"] = json!(super::flags::device_name(on));
                records.push(record);
            }
        }
    }
    let software = adapter.as_ref().is_some_and(|a| a.software);
    Ok(json!({
        "defocus": env!("CARGO_PKG_VERSION"),
        "device": super::flags::device_name(gpu.as_ref()),
        "adapter": adapter,
        "software": software,
        "note": if software {
            "a software adapter runs the shaders on the CPU: its times are not GPU times"
        } else {
            "median and least of each pass over the timed frames, warm; gpu/upload and \
             gpu/download are the transfers of a frame to and from the GPU"
        },
        "frames": args.frames,
        "warmup": args.warmup,
        "runs": records,
    }))
}
