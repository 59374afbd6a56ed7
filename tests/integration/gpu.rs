//! Tests: the GPU backend. The adapter choice is tested on lists of adapter descriptions; the
//! GPU passes run on whatever adapter `--device gpu` takes (Mesa's lavapipe in CI) against
//! their CPU twins, and skip, saying so, only where there is no adapter at all.

use std::sync::OnceLock;

use defocus::gpu::{self, AdapterDescription, AdapterLimits, AdapterType, Device, GpuContext};
use defocus::image::{io, ColorImage, GrayImage};
use defocus::lens::ThinLens;
use defocus::methods::gaussian::{self, GaussianSettings};
use defocus::methods::hammon::{self, CocMode, HammonSettings, LerpDistances};
use defocus::methods::registry::{self, MethodSettings};
use defocus::metrics;
use defocus::random::SplitMix64;

use crate::cli::{defocus, s, stderr, temp_dir};

/// Least PSNR of a GPU pass against its CPU twin. The passes compute the same f32 arithmetic
/// in the same order; what differs is the GPU's division (WGSL allows 2.5 ulp) and fused
/// multiply-adds, which move a CoC across a quantisation step (1/4 px) only at its edge.
pub(crate) const MIN_PSNR_DB: f64 = 45.0;

/// The GPU context of these tests (any adapter, software included), or `None`, with the
/// printed reason, where the machine has no adapter at all.
pub(crate) fn context() -> Option<&'static GpuContext> {
    static CONTEXT: OnceLock<Option<GpuContext>> = OnceLock::new();
    let ctx = CONTEXT.get_or_init(|| {
        if gpu::adapters().is_empty() {
            return None;
        }
        Some(
            GpuContext::open(Device::Gpu)
                .expect("an adapter was found, so --device gpu opens it")
                .expect("--device gpu takes an adapter"),
        )
    });
    if ctx.is_none() {
        eprintln!("skipped: no Vulkan adapter");
    }
    ctx.as_ref()
}

/// An adapter description for the choice tests.
fn adapter(name: &str, device_type: AdapterType) -> AdapterDescription {
    AdapterDescription {
        name: name.to_string(),
        backend: "vulkan".to_string(),
        device_type,
        driver: String::new(),
        software: device_type == AdapterType::Cpu || gpu::is_software_name(name),
        timestamp_query: true,
        limits: AdapterLimits::default(),
    }
}

#[test]
fn auto_on_a_machine_with_only_software_adapters_takes_the_cpu() {
    let software = [
        adapter("llvmpipe (LLVM 19.1.7, 256 bits)", AdapterType::Cpu),
        adapter("SwiftShader Device (Subzero)", AdapterType::Other),
        adapter("Microsoft Basic Render Driver", AdapterType::Integrated),
        adapter("lavapipe", AdapterType::Virtual),
    ];
    assert!(software.iter().all(|a| a.software && !a.is_hardware()));
    assert_eq!(gpu::choose(Device::Auto, &software).unwrap(), None);
    assert_eq!(gpu::choose(Device::Cpu, &software).unwrap(), None);
    // `gpu` takes a software adapter where it is all there is.
    assert_eq!(gpu::choose(Device::Gpu, &software).unwrap(), Some(0));
}

#[test]
fn auto_takes_a_discrete_gpu_before_an_integrated_one_and_never_a_software_one() {
    let list = [
        adapter("llvmpipe (LLVM 19.1.7, 256 bits)", AdapterType::Cpu),
        adapter("Intel(R) UHD Graphics 770", AdapterType::Integrated),
        adapter("NVIDIA H100 80GB HBM3", AdapterType::Discrete),
    ];
    assert_eq!(gpu::choose(Device::Auto, &list).unwrap(), Some(2));
    assert_eq!(gpu::choose(Device::Gpu, &list).unwrap(), Some(2));
    assert_eq!(gpu::choose(Device::Auto, &list[..2]).unwrap(), Some(1));
    assert_eq!(gpu::choose(Device::Cpu, &list).unwrap(), None);
    // A virtual GPU is not taken by auto (it may be a software one behind a VM), but by gpu
    // before a software adapter.
    let vm = [
        adapter("llvmpipe", AdapterType::Cpu),
        adapter("Virtio-GPU Venus", AdapterType::Virtual),
    ];
    assert_eq!(gpu::choose(Device::Auto, &vm).unwrap(), None);
    assert_eq!(gpu::choose(Device::Gpu, &vm).unwrap(), Some(1));
}

#[test]
fn gpu_with_no_adapter_is_a_clear_error_naming_what_was_found() {
    let e = gpu::choose(Device::Gpu, &[]).unwrap_err().to_string();
    assert!(
        e.contains("--device gpu") && e.contains("no GPU adapter") && e.contains("found no"),
        "{e}"
    );
    assert!(
        e.contains("mesa-vulkan-drivers") && e.contains("--device cpu"),
        "{e}"
    );
    assert_eq!(gpu::choose(Device::Auto, &[]).unwrap(), None);
}

#[test]
fn auto_runs_gaussian_on_the_cpu_where_there_is_no_hardware_gpu() {
    if gpu::adapters().iter().any(AdapterDescription::is_hardware) {
        eprintln!("skipped: this machine has a hardware GPU");
        return;
    }
    assert!(registry::gpu_context(Device::Auto, "gaussian")
        .unwrap()
        .is_none());
}

#[test]
fn software_adapter_names_are_recognised_in_any_case() {
    for name in [
        "llvmpipe (LLVM 15.0.6, 256 bits)",
        "LAVAPIPE",
        "SwiftShader Device (LLVM 10.0.0)",
        "Microsoft Basic Render Driver",
        "WARP",
    ] {
        assert!(gpu::is_software_name(name), "{name}");
    }
    for name in [
        "NVIDIA GeForce RTX 4090",
        "AMD Radeon RX 7900 XTX",
        "Apple M2",
    ] {
        assert!(!gpu::is_software_name(name), "{name}");
    }
}

#[test]
fn every_gpu_shader_passes_naga_validation() {
    use gpu::naga_check;
    assert!(!registry::GPU_SHADERS.is_empty());
    for (name, source) in registry::GPU_SHADERS {
        naga_check(source).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    assert!(naga_check("fn broken( {").is_err());
}

#[test]
fn gpu_opens_a_context_on_the_adapter_it_chose() {
    let Some(ctx) = context() else { return };
    let adapters = gpu::adapters();
    let chosen = gpu::choose(Device::Gpu, &adapters).unwrap().unwrap();
    assert_eq!(ctx.description().name, adapters[chosen].name);
    assert!(ctx
        .description()
        .label()
        .contains(&ctx.description().backend));
    ctx.check().unwrap();
}

#[test]
fn every_gpu_pipeline_builds_on_the_adapter() {
    let Some(ctx) = context() else { return };
    registry::prepare_gpu(ctx).unwrap();
    // Built once: a second time takes them from the context's cache.
    registry::prepare_gpu(ctx).unwrap();
    ctx.check().unwrap();
}

#[test]
fn the_registry_marks_the_gpu_methods_and_refuses_the_others_by_name() {
    assert_eq!(
        registry::gpu_ids(),
        [
            "pinhole",
            "reference",
            "hammon",
            "lowrank",
            "gaussian",
            "poisson",
            "multilayer"
        ]
    );
    registry::check_gpu("gaussian").unwrap();
    let e = registry::check_gpu("splat").unwrap_err().to_string();
    assert!(e.contains("splat") && e.contains("gaussian"), "{e}");
    // A CPU-only method on `auto` runs on the CPU without looking for an adapter.
    assert!(registry::gpu_context(Device::Auto, "splat")
        .unwrap()
        .is_none());
    assert!(registry::gpu_context(Device::Cpu, "gaussian")
        .unwrap()
        .is_none());
}

/// The GPU and the CPU gaussian on one frame: their PSNR (dB) and largest difference.
fn gpu_against_cpu(
    ctx: &GpuContext,
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &GaussianSettings,
) -> (f64, f32, ColorImage) {
    let cpu = gaussian::render(color, depth, lens, settings)
        .unwrap()
        .image;
    let out = gaussian::gpu::render(ctx, color, depth, lens, settings).unwrap();
    let names: Vec<&str> = out.timings.passes.iter().map(|p| p.name.as_str()).collect();
    for pass in gaussian::gpu::PASSES {
        assert!(names.contains(&pass), "{names:?}");
    }
    let gpu = out.image;
    let max_diff = cpu
        .pixels()
        .iter()
        .zip(gpu.pixels())
        .flat_map(|(a, b)| (0..4).map(move |k| (a[k] - b[k]).abs()))
        .fold(0.0f32, f32::max);
    let psnr = metrics::compare(&cpu, &gpu).unwrap().psnr_db;
    (psnr, max_diff, gpu)
}

#[test]
fn gpu_gaussian_matches_the_cpu_on_every_builtin_scene() {
    let Some(ctx) = context() else { return };
    for name in defocus::scene::builtin::NAMES {
        let scene = defocus::scene::builtin::load(name).unwrap();
        let mut camera = scene.defaults.clone().unwrap().camera;
        (camera.width_px, camera.height_px) = (320, 180);
        let pin = defocus::methods::pinhole::render(&scene, &camera, 1, 0, true).unwrap();
        let depth = pin.depth.unwrap();
        let lens = camera.thin_lens().unwrap();
        let (psnr, max_diff, _) =
            gpu_against_cpu(ctx, &pin.image, &depth, &lens, &GaussianSettings::default());
        eprintln!("{name}: GPU against CPU {psnr:.1} dB, largest difference {max_diff:e}");
        assert!(psnr >= MIN_PSNR_DB, "{name}: {psnr} dB");
    }
}

/// A seeded random frame: colour in [0, 4) (some HDR), depth from 0.3 to 30 m with some sky.
pub(crate) fn random_frame(w: usize, h: usize, seed: u64) -> (ColorImage, GrayImage) {
    let mut rng = SplitMix64::new(seed);
    let color = ColorImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|_| {
                let mut p = [0.0f32; 4];
                for c in &mut p[..3] {
                    *c = 4.0 * rng.next_f32() * rng.next_f32();
                }
                p[3] = 1.0;
                p
            })
            .collect(),
    )
    .unwrap();
    let depth = GrayImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|_| {
                let u = rng.next_f32();
                if u < 0.05 {
                    f32::INFINITY
                } else {
                    0.3 * 100f32.powf(u)
                }
            })
            .collect(),
    )
    .unwrap();
    (color, depth)
}

#[test]
fn gpu_gaussian_matches_the_cpu_on_random_frames_of_awkward_sizes() {
    let Some(ctx) = context() else { return };
    for (i, &(w, h)) in [(97, 61), (1, 1), (1, 9), (13, 1), (200, 3)]
        .iter()
        .enumerate()
    {
        let (color, depth) = random_frame(w, h, 7 + i as u64);
        let camera = crate::test_camera(w, h, 1.5, 1.4);
        let lens = camera.thin_lens().unwrap();
        for settings in [
            GaussianSettings::default(),
            GaussianSettings {
                sigma_per_coc: 1.0,
                truncate_sigmas: 2.0,
                max_coc_px: 9.0,
            },
        ] {
            let (psnr, max_diff, _) = gpu_against_cpu(ctx, &color, &depth, &lens, &settings);
            eprintln!("random {w}x{h}: {psnr:.1} dB, largest difference {max_diff:e}");
            assert!(psnr >= MIN_PSNR_DB, "{w}x{h}: {psnr} dB");
        }
    }
}

#[test]
fn a_constant_image_stays_constant_on_the_gpu() {
    let Some(ctx) = context() else { return };
    let (w, h) = (64, 40);
    let (_, depth) = random_frame(w, h, 3);
    let value = [0.3, 0.5, 0.7, 1.0];
    let color = ColorImage::new(w, h, value);
    let lens = crate::test_camera(w, h, 1.5, 1.4).thin_lens().unwrap();
    let out = gaussian::gpu::render(ctx, &color, &depth, &lens, &GaussianSettings::default())
        .unwrap()
        .image;
    for p in out.pixels() {
        for k in 0..4 {
            assert!((p[k] - value[k]).abs() < 1e-5, "{p:?}");
        }
    }
}

#[test]
fn an_in_focus_plane_stays_sharp_on_the_gpu() {
    let Some(ctx) = context() else { return };
    let (w, h) = (128, 48);
    let camera = crate::test_camera(w, h, 0.5, 1.0);
    let lens = camera.thin_lens().unwrap();
    // A checkerboard in focus on the left half, a far wall on the right.
    let color = ColorImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|i| {
                let v = if (i % w / 2 + i / w / 2) % 2 == 0 {
                    1.0
                } else {
                    0.0
                };
                [v, v, v, 1.0]
            })
            .collect(),
    )
    .unwrap();
    let depth = GrayImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|i| if i % w < w / 2 { 0.5 } else { 20.0 })
            .collect(),
    )
    .unwrap();
    assert!(lens.coc_px(20.0) > 4.0);
    let out = gaussian::gpu::render(ctx, &color, &depth, &lens, &GaussianSettings::default())
        .unwrap()
        .image;
    for y in 0..h {
        for x in 0..w / 2 {
            assert_eq!(out.get(x, y), color.get(x, y), "({x}, {y})");
        }
    }
    // The far half is blurred: its checkerboard turns grey.
    let p = out.get(3 * w / 4, h / 2);
    assert!(p[0] > 0.2 && p[0] < 0.8, "{p:?}");
}

/// Every GPU method refuses a depth of 0, negative (-0 included) or NaN with the CPU's error,
/// and its context still works after.
#[test]
fn a_bad_depth_gives_the_cpu_error_on_the_gpu() {
    let Some(ctx) = context() else { return };
    let (w, h) = (16, 8);
    let (color, good) = random_frame(w, h, 2);
    let lens = crate::test_camera(w, h, 2.0, 1.4).thin_lens().unwrap();
    for id in registry::gpu_ids() {
        let settings = MethodSettings::default_for(id).unwrap();
        if settings.info().input != registry::InputKind::PinholeFrame {
            continue;
        }
        for bad in [0.0, -1.0, -0.0, f32::NAN] {
            let mut depth = good.clone();
            *depth.get_mut(5, 6) = bad;
            *depth.get_mut(9, 7) = -2.0;
            let frame = registry::Frame {
                color: &color,
                depth: &depth,
                lens: &lens,
            };
            let cpu = registry::run_frame(&settings, &frame)
                .unwrap_err()
                .to_string();
            let gpu = registry::run_frame_on(&settings, &frame, Some(ctx))
                .unwrap_err()
                .to_string();
            assert_eq!(gpu, cpu, "{id}, depth {bad}");
            assert!(gpu.contains("depth"), "{id}: {gpu}");
            // The methods with a CoC pass name the first bad pixel in row order (hammon's
            // error names the depth map).
            if id != "hammon" {
                assert!(gpu.contains("(5, 6)"), "{id}: {gpu}");
            }
        }
        // The context is still usable after the error.
        let frame = registry::Frame {
            color: &color,
            depth: &good,
            lens: &lens,
        };
        registry::run_frame_on(&settings, &frame, Some(ctx)).unwrap();
    }
    ctx.check().unwrap();
}

#[test]
fn a_frame_over_the_adapters_buffer_limit_is_refused_naming_the_limit() {
    let Some(ctx) = context() else { return };
    let limit = ctx.description().limits.max_storage_buffer_binding_size;
    let e = ctx
        .check_storage("a test frame", limit + 1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("max storage buffer binding size"), "{e}");
    assert!(e.contains(&ctx.description().name), "{e}");
}

#[test]
fn the_registry_runs_gaussian_on_the_gpu_and_refuses_splat_there() {
    let Some(ctx) = context() else { return };
    let (w, h) = (40, 24);
    let (color, depth) = random_frame(w, h, 11);
    let lens = crate::test_camera(w, h, 1.5, 1.4).thin_lens().unwrap();
    let frame = registry::Frame {
        color: &color,
        depth: &depth,
        lens: &lens,
    };
    let settings = MethodSettings::default_for("gaussian").unwrap();
    let out = registry::run_frame_on(&settings, &frame, Some(ctx)).unwrap();
    let clocks: Vec<_> = out
        .timings
        .passes
        .iter()
        .filter(|p| p.name.starts_with("gaussian/"))
        .map(|p| p.clock)
        .collect();
    assert_eq!(clocks.len(), 3);
    let expected = if ctx.has_timestamps() {
        defocus::timing::Clock::GpuTimestamps
    } else {
        defocus::timing::Clock::SubmitWait
    };
    assert!(clocks.iter().all(|&c| c == expected), "{clocks:?}");
    let splat = MethodSettings::default_for("splat").unwrap();
    let e = registry::run_frame_on(&splat, &frame, Some(ctx))
        .unwrap_err()
        .to_string();
    assert!(e.contains("gaussian"), "{e}");
}

#[test]
fn devices_lists_the_adapters_and_what_auto_takes() {
    let out = defocus(&["devices"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("--device auto:"), "{text}");
    let adapters = gpu::adapters();
    if adapters.is_empty() {
        eprintln!("skipped: no Vulkan adapter");
        assert!(text.contains("no GPU adapter"), "{text}");
        return;
    }
    for a in &adapters {
        assert!(text.contains(&a.name), "{text}");
    }
    assert!(text.contains("max storage buffer binding size"), "{text}");
    if adapters.iter().all(|a| a.software) {
        // lavapipe here: listed as software, and auto runs on the CPU.
        assert!(text.contains("software: yes"), "{text}");
        assert!(text.contains("--device auto: cpu"), "{text}");
    }
    let json = defocus(&["devices", "--json"]);
    let value: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(value["adapters"].as_array().unwrap().len(), adapters.len());
    assert!(
        value["adapters"][0]["limits"]["max_buffer_size"]
            .as_u64()
            .unwrap()
            > 0
    );
}

/// Writes a random frame as colour and depth EXRs in `dir`.
pub(crate) fn write_random_frame(
    dir: &std::path::Path,
) -> (std::path::PathBuf, std::path::PathBuf) {
    let (color, depth) = random_frame(72, 40, 5);
    let (c, d) = (dir.join("color.exr"), dir.join("depth.exr"));
    io::write_color(&c, &color).unwrap();
    io::write_depth_exr(&d, &depth).unwrap();
    (c, d)
}

#[test]
fn blur_on_the_gpu_writes_the_images_of_the_cpu_and_names_its_device() {
    let Some(ctx) = context() else { return };
    let dir = temp_dir("gpu-blur");
    let (color, depth) = write_random_frame(&dir);
    let run = |device: &str, method: &str| {
        let out = dir.join(format!("{method}-{device}.exr"));
        let done = defocus(&[
            "blur",
            "--color",
            s(&color),
            "--depth",
            s(&depth),
            "--method",
            method,
            "--focus",
            "1.5",
            "--fstop",
            "1.4",
            "--device",
            device,
            "--timings",
            "json",
            "--out",
            s(&out),
        ]);
        assert!(done.status.success(), "{device}: {}", stderr(&done));
        let json: serde_json::Value = serde_json::from_slice(&done.stdout).unwrap();
        (io::read_color(&out).unwrap(), json)
    };
    let label = ctx.description().label();
    for (method, passes) in [("gaussian", 3), ("hammon", 4), ("poisson", 2)] {
        let (cpu, cpu_json) = run("cpu", method);
        let (gpu, gpu_json) = run("gpu", method);
        assert_eq!(cpu_json["device"], "cpu");
        assert_eq!(gpu_json["device"], label.as_str());
        let clocks: Vec<&str> = gpu_json["passes"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|p| p["name"].as_str().unwrap().starts_with(method))
            .map(|p| p["clock"].as_str().unwrap())
            .collect();
        assert_eq!(clocks.len(), passes, "{gpu_json}");
        assert!(clocks.iter().all(|c| *c != "wall"), "{gpu_json}");
        let psnr = metrics::compare(&cpu, &gpu).unwrap().psnr_db;
        eprintln!("blur --method {method} --device gpu against --device cpu: {psnr:.1} dB");
        assert!(psnr >= MIN_PSNR_DB, "{method}: {psnr} dB");
    }
    // The table names the device too.
    let table = defocus(&[
        "blur",
        "--color",
        s(&color),
        "--depth",
        s(&depth),
        "--method",
        "gaussian",
        "--device",
        "gpu",
        "--timings",
        "--out",
        s(&dir.join("table.png")),
    ]);
    assert!(table.status.success(), "{}", stderr(&table));
    let err = stderr(&table);
    assert!(err.contains(&format!("device: {label}")), "{err}");
    assert!(err.contains("gaussian/horizontal"), "{err}");
}

#[test]
fn render_on_the_gpu_blurs_the_pinhole_frame_as_the_cpu_does() {
    let Some(_) = context() else { return };
    let dir = temp_dir("gpu-render");
    let run = |device: &str| {
        let out = dir.join(format!("{device}.exr"));
        let done = defocus(&[
            "render",
            "--scene",
            "railing",
            "--method",
            "gaussian",
            "--width",
            "160",
            "--height",
            "90",
            "--samples",
            "2",
            "--device",
            device,
            "--out",
            s(&out),
        ]);
        assert!(done.status.success(), "{device}: {}", stderr(&done));
        io::read_color(&out).unwrap()
    };
    let psnr = metrics::compare(&run("cpu"), &run("gpu")).unwrap().psnr_db;
    eprintln!("render --device gpu against --device cpu: {psnr:.1} dB");
    assert!(psnr >= MIN_PSNR_DB, "{psnr} dB");
}

#[test]
fn a_method_without_gpu_passes_is_refused_on_the_gpu_naming_those_with() {
    let dir = temp_dir("gpu-refused");
    let (color, depth) = write_random_frame(&dir);
    let out = dir.join("out.png");
    let done = defocus(&[
        "blur",
        "--color",
        s(&color),
        "--depth",
        s(&depth),
        "--method",
        "splat",
        "--device",
        "gpu",
        "--out",
        s(&out),
    ]);
    assert!(!done.status.success());
    let err = stderr(&done);
    assert!(err.contains("splat") && err.contains("gaussian"), "{err}");
    assert!(!out.exists());
    let render = defocus(&[
        "render",
        "--method",
        "multiview",
        "--device",
        "gpu",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        s(&out),
    ]);
    assert!(!render.status.success());
    let err = stderr(&render);
    assert!(
        err.contains("multiview") && err.contains("gaussian"),
        "{err}"
    );
    // `auto` runs such a method on the CPU.
    let auto = defocus(&[
        "blur",
        "--color",
        s(&color),
        "--depth",
        s(&depth),
        "--method",
        "splat",
        "--timings",
        "json",
        "--out",
        s(&out),
    ]);
    assert!(auto.status.success(), "{}", stderr(&auto));
    let json: serde_json::Value = serde_json::from_slice(&auto.stdout).unwrap();
    assert_eq!(json["device"], "cpu");
}

/// PSNR (dB) of `gpu` against `cpu`, and their largest difference in any channel.
pub(crate) fn psnr_and_max_diff(cpu: &ColorImage, gpu: &ColorImage) -> (f64, f32) {
    let max_diff = cpu
        .pixels()
        .iter()
        .zip(gpu.pixels())
        .flat_map(|(a, b)| (0..4).map(move |k| (a[k] - b[k]).abs()))
        .fold(0.0f32, f32::max);
    (metrics::compare(cpu, gpu).unwrap().psnr_db, max_diff)
}

/// The GPU and the CPU hammon on one frame: PSNR (dB) and largest difference.
fn hammon_gpu_against_cpu(
    ctx: &GpuContext,
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &HammonSettings,
) -> (f64, f32) {
    let cpu = hammon::render(color, depth, lens, settings).unwrap().image;
    let out = hammon::gpu::render(ctx, color, depth, lens, settings).unwrap();
    let names: Vec<&str> = out.timings.passes.iter().map(|p| p.name.as_str()).collect();
    for pass in [
        "hammon/downsample",
        "hammon/blur",
        "hammon/near_coc",
        "hammon/composite",
    ] {
        assert!(names.contains(&pass), "{names:?}");
    }
    psnr_and_max_diff(&cpu, &out.image)
}

#[test]
fn gpu_hammon_matches_the_cpu_on_every_builtin_scene() {
    let Some(ctx) = context() else { return };
    for name in defocus::scene::builtin::NAMES {
        let scene = defocus::scene::builtin::load(name).unwrap();
        let mut camera = scene.defaults.clone().unwrap().camera;
        (camera.width_px, camera.height_px) = (320, 180);
        let pin = defocus::methods::pinhole::render(&scene, &camera, 1, 0, true).unwrap();
        let lens = camera.thin_lens().unwrap();
        let depth = pin.depth.unwrap();
        let (psnr, max_diff) =
            hammon_gpu_against_cpu(ctx, &pin.image, &depth, &lens, &HammonSettings::default());
        eprintln!("hammon {name}: GPU against CPU {psnr:.1} dB, largest difference {max_diff:e}");
        assert!(psnr >= MIN_PSNR_DB, "{name}: {psnr} dB");
    }
}

#[test]
fn gpu_hammon_matches_the_cpu_on_random_frames_with_either_curve() {
    let Some(ctx) = context() else { return };
    let artist = CocMode::Artist {
        near_start_m: 0.4,
        near_end_m: 1.2,
        far_start_m: 2.0,
        far_end_m: 9.0,
    };
    let settings = [
        HammonSettings::default(),
        HammonSettings {
            sky_depth_m: 10.0,
            far_to_near_ratio: 0.6,
            ..HammonSettings::default()
        },
        HammonSettings {
            sky_depth_m: f32::INFINITY,
            lerp: Some(LerpDistances {
                d0: 0.2,
                d1: 0.3,
                d2: 0.5,
            }),
            ..HammonSettings::default()
        },
        HammonSettings {
            coc: artist,
            ..HammonSettings::default()
        },
        HammonSettings {
            coc: CocMode::Artist {
                near_start_m: 1.0,
                near_end_m: 1.0,
                far_start_m: 2.0,
                far_end_m: 2.0,
            },
            sky_depth_m: f32::INFINITY,
            ..HammonSettings::default()
        },
    ];
    for (i, &(w, h)) in [(97, 61), (1, 1), (5, 3), (13, 1), (1, 9), (200, 7)]
        .iter()
        .enumerate()
    {
        let (color, depth) = random_frame(w, h, 21 + i as u64);
        let lens = crate::test_camera(w, h, 1.5, 1.4).thin_lens().unwrap();
        for (j, s) in settings.iter().enumerate() {
            let (psnr, max_diff) = hammon_gpu_against_cpu(ctx, &color, &depth, &lens, s);
            eprintln!("hammon random {w}x{h}, settings {j}: {psnr:.1} dB, largest difference {max_diff:e}");
            assert!(psnr >= MIN_PSNR_DB, "{w}x{h}, settings {j}: {psnr} dB");
        }
    }
}

#[test]
fn hammon_on_the_gpu_keeps_a_constant_image_and_an_in_focus_plane() {
    let Some(ctx) = context() else { return };
    let (w, h) = (66, 42);
    let (_, depth) = random_frame(w, h, 4);
    let value = [0.3, 0.5, 0.7, 1.0];
    let lens = crate::test_camera(w, h, 1.5, 1.4).thin_lens().unwrap();
    let constant = ColorImage::new(w, h, value);
    let out = hammon::gpu::render(ctx, &constant, &depth, &lens, &HammonSettings::default())
        .unwrap()
        .image;
    for p in out.pixels() {
        for k in 0..4 {
            assert!((p[k] - value[k]).abs() < 1e-5, "{p:?}");
        }
    }
    // Everything at the focus distance: no pixel is blurred, so the frame comes back as it is.
    let (color, _) = random_frame(w, h, 5);
    let focused = GrayImage::new(w, h, lens.focus_m);
    let out = hammon::gpu::render(ctx, &color, &focused, &lens, &HammonSettings::default())
        .unwrap()
        .image;
    assert_eq!(out.pixels(), color.pixels());
}

#[test]
fn render_targets_are_reused_by_size_format_and_use() {
    let Some(ctx) = context() else { return };
    let usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
    let format = wgpu::TextureFormat::R32Float;
    // A size no other test asks for, so that the shared context's pool is this test's.
    let a = ctx.texture("t", (7, 5), format, usage);
    let kept = a.clone();
    ctx.recycle_textures([a]);
    let turned = ctx.texture("t", (5, 7), format, usage);
    assert!(turned != kept);
    let other = ctx.texture("t", (7, 5), wgpu::TextureFormat::Rgba32Float, usage);
    assert!(other != kept);
    let again = ctx.texture("t", (7, 5), format, usage);
    assert!(again == kept);
}
