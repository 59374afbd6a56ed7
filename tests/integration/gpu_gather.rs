//! `poisson` and `lowrank` on the GPU against their CPU twins, and the analytic cases on the
//! GPU: a point light becomes the aperture, a bad depth is the CPU's error. Run on any Vulkan
//! adapter (lavapipe in CI); skipped, with the reason printed, where there is none.

use glam::Vec2;

use defocus::image::{ColorImage, GrayImage};
use defocus::lens::{Aperture, LensEffects, ThinLens};
use defocus::methods::lowrank::{self, LowRankSettings, TiltShift};
use defocus::methods::poisson::{self, PoissonSettings};
use defocus::methods::MethodOutput;

use crate::cli::{defocus, s, stderr, temp_dir};
use crate::gpu::{context, psnr_and_max_diff, random_frame, write_random_frame, MIN_PSNR_DB};
use crate::lowrank::{depth_for_coc, extents, point_light, tele_lens};

/// Every pass of `passes` is among `out`'s timings.
fn assert_passes(out: &MethodOutput, passes: &[&str]) {
    let names: Vec<&str> = out.timings.passes.iter().map(|p| p.name.as_str()).collect();
    for pass in passes {
        assert!(names.contains(pass), "{pass} missing from {names:?}");
    }
}

/// The pinhole frame of built-in scene `name` at `w`x`h`: colour, depth, lens.
fn builtin_frame(name: &str, w: usize, h: usize) -> (ColorImage, GrayImage, ThinLens) {
    let scene = defocus::scene::builtin::load(name).unwrap();
    let mut camera = scene.defaults.clone().unwrap().camera;
    (camera.width_px, camera.height_px) = (w, h);
    let pin = defocus::methods::pinhole::render(&scene, &camera, 1, 0, true).unwrap();
    (pin.image, pin.depth.unwrap(), camera.thin_lens().unwrap())
}

fn poisson_against_cpu(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &PoissonSettings,
) -> (f64, f32) {
    let ctx = context().expect("checked by the caller");
    let cpu = poisson::render(color, depth, lens, settings).unwrap();
    let gpu = poisson::gpu::render(ctx, color, depth, lens, settings).unwrap();
    assert_passes(&gpu, &poisson::gpu::PASSES);
    psnr_and_max_diff(&cpu.image, &gpu.image)
}

fn lowrank_against_cpu(
    color: &ColorImage,
    depth: &GrayImage,
    lens: &ThinLens,
    settings: &LowRankSettings,
) -> (f64, f32) {
    let ctx = context().expect("checked by the caller");
    let cpu = lowrank::render(color, depth, lens, settings).unwrap();
    let gpu = lowrank::gpu::render(ctx, color, depth, lens, settings).unwrap();
    let mut passes = vec![
        "lowrank/coc",
        "lowrank/kernel",
        "lowrank/horizontal",
        "lowrank/vertical",
    ];
    if settings.use_mask {
        passes.extend(["lowrank/edges", "lowrank/fallback"]);
    }
    assert_passes(&gpu, &passes);
    psnr_and_max_diff(&cpu.image, &gpu.image)
}

#[test]
fn gpu_poisson_and_lowrank_match_the_cpu_on_every_builtin_scene() {
    if context().is_none() {
        return;
    }
    for (w, h) in [(320, 180), (640, 360)] {
        for name in defocus::scene::builtin::NAMES {
            let (color, depth, lens) = builtin_frame(name, w, h);
            let (psnr, diff) =
                poisson_against_cpu(&color, &depth, &lens, &PoissonSettings::default());
            eprintln!(
                "poisson {name} {w}x{h}: GPU against CPU {psnr:.1} dB, largest difference {diff:e}"
            );
            assert!(psnr >= MIN_PSNR_DB, "poisson {name} {w}x{h}: {psnr} dB");
            let (psnr, diff) =
                lowrank_against_cpu(&color, &depth, &lens, &LowRankSettings::default());
            eprintln!(
                "lowrank {name} {w}x{h}: GPU against CPU {psnr:.1} dB, largest difference {diff:e}"
            );
            assert!(psnr >= MIN_PSNR_DB, "lowrank {name} {w}x{h}: {psnr} dB");
        }
    }
}

#[test]
fn gpu_poisson_matches_the_cpu_with_every_lens_effect_and_aperture() {
    if context().is_none() {
        return;
    }
    let cats_eye = LensEffects {
        barrel_distance_m: 0.03,
        ..LensEffects::default()
    };
    let all = LensEffects {
        aspect: 0.6,
        chroma_dpt: 0.4,
        ..cats_eye
    };
    for (i, &(w, h)) in [(97, 61), (1, 1), (13, 1), (200, 3)].iter().enumerate() {
        let (color, depth) = random_frame(w, h, 31 + i as u64);
        let lens = crate::test_camera(w, h, 1.5, 1.4).thin_lens().unwrap();
        if i == 0 {
            // The cat's eye clips taps on this frame: the cases below test the clipping.
            let plain = poisson::render(&color, &depth, &lens, &PoissonSettings::default());
            let clipped = PoissonSettings {
                effects: cats_eye,
                ..PoissonSettings::default()
            };
            let clipped = poisson::render(&color, &depth, &lens, &clipped);
            assert_ne!(plain.unwrap().image, clipped.unwrap().image);
        }
        for (aperture, effects) in [
            ("disc", LensEffects::default()),
            ("poly:5,rot=17", cats_eye),
            ("poly:6", all),
        ] {
            let settings = PoissonSettings {
                aperture: Aperture::parse(aperture).unwrap(),
                taps: 24,
                seed: 3,
                effects,
                ..PoissonSettings::default()
            };
            let (psnr, diff) = poisson_against_cpu(&color, &depth, &lens, &settings);
            eprintln!(
                "poisson {w}x{h} {aperture} {effects:?}: {psnr:.1} dB, largest difference {diff:e}"
            );
            assert!(psnr >= MIN_PSNR_DB, "{w}x{h} {aperture}: {psnr} dB");
        }
    }
}

#[test]
fn gpu_lowrank_matches_the_cpu_at_every_rank_aperture_and_option() {
    if context().is_none() {
        return;
    }
    let (w, h) = (97, 61);
    let (mut color, depth) = random_frame(w, h, 41);
    let lens = crate::test_camera(w, h, 1.5, 1.4).thin_lens().unwrap();
    let cases = [
        LowRankSettings::default(),
        // A turned pentagon: horizontal vectors neither even nor odd (no folding on the CPU).
        LowRankSettings {
            aperture: Aperture::parse("poly:5,rot=10").unwrap(),
            rank: 2,
            ..LowRankSettings::default()
        },
        LowRankSettings {
            aperture: Aperture::parse("poly:6").unwrap(),
            rank: 1,
            use_mask: false,
            aberration: 0.6,
            ..LowRankSettings::default()
        },
        LowRankSettings {
            rank: 4,
            max_coc_px: 6.0,
            edge_threshold_px: 0.5,
            mask_threshold: 0.2,
            fallback_taps: 16,
            effects: LensEffects {
                aspect: 0.5,
                ..LensEffects::default()
            },
            ..LowRankSettings::default()
        },
        LowRankSettings {
            effects: LensEffects {
                chroma_dpt: 0.5,
                ..LensEffects::default()
            },
            ..LowRankSettings::default()
        },
    ];
    for (i, settings) in cases.iter().enumerate() {
        let (psnr, diff) = lowrank_against_cpu(&color, &depth, &lens, settings);
        eprintln!("lowrank case {i}: {psnr:.1} dB, largest difference {diff:e}");
        assert!(psnr >= MIN_PSNR_DB, "case {i}: {psnr} dB");
    }
    // A frame with alpha below 1 filters alpha as the colour.
    for (k, p) in color.pixels_mut().iter_mut().enumerate() {
        p[3] = if k % 3 == 0 { 0.25 } else { 1.0 };
    }
    let (psnr, diff) = lowrank_against_cpu(&color, &depth, &lens, &LowRankSettings::default());
    eprintln!("lowrank with alpha: {psnr:.1} dB, largest difference {diff:e}");
    assert!(psnr >= MIN_PSNR_DB, "with alpha: {psnr} dB");
    // One-pixel rows and columns.
    for (w, h) in [(1, 1), (1, 9), (13, 1)] {
        let (color, depth) = random_frame(w, h, 5);
        let lens = crate::test_camera(w, h, 1.5, 1.4).thin_lens().unwrap();
        let (psnr, _) = lowrank_against_cpu(&color, &depth, &lens, &LowRankSettings::default());
        assert!(psnr >= MIN_PSNR_DB, "{w}x{h}: {psnr} dB");
    }
}

#[test]
fn gpu_lowrank_tilt_shift_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    let (w, h) = (120, 80);
    let (color, _) = random_frame(w, h, 9);
    let ts = TiltShift {
        angle_deg: 12.0,
        ..TiltShift::default()
    };
    let coc = lowrank::tilt_shift_coc(w, h, &ts).unwrap();
    let settings = LowRankSettings::default();
    let cpu = lowrank::render_coc(&color, &coc, &settings).unwrap();
    let gpu = lowrank::gpu::render_coc(ctx, &color, &coc, &settings).unwrap();
    let (psnr, diff) = psnr_and_max_diff(&cpu.image, &gpu.image);
    eprintln!("tilt-shift: {psnr:.1} dB, largest difference {diff:e}");
    assert!(psnr >= MIN_PSNR_DB, "{psnr} dB");
    // A CoC map with NaN is refused as on the CPU.
    let mut bad = coc.clone();
    *bad.get_mut(3, 2) = f32::NAN;
    let e_cpu = lowrank::render_coc(&color, &bad, &settings)
        .unwrap_err()
        .to_string();
    let e_gpu = lowrank::gpu::render_coc(ctx, &color, &bad, &settings)
        .unwrap_err()
        .to_string();
    assert_eq!(e_cpu, e_gpu);
}

/// How far the boundary of the unit `aperture` lies from its centre along `dir`.
fn boundary_distance(aperture: &Aperture, dir: Vec2) -> f32 {
    let v = aperture.vertices();
    if v.is_empty() {
        return 1.0;
    }
    let cross = |a: Vec2, b: Vec2| a.x * b.y - a.y * b.x;
    (0..v.len())
        .filter_map(|k| {
            let (a, b) = (v[k], v[(k + 1) % v.len()]);
            let e = b - a;
            let den = cross(dir, e);
            if den.abs() < 1e-9 {
                return None;
            }
            // t dir = a + u e.
            let t = cross(a, e) / den;
            let u = cross(a, dir) / den;
            (t > 0.0 && (-1e-6..=1.0 + 1e-6).contains(&u)).then_some(t)
        })
        .fold(f32::INFINITY, f32::min)
}

#[test]
fn a_point_light_becomes_the_aperture_of_diameter_two_coc_on_the_gpu() {
    let Some(ctx) = context() else { return };
    let size = 96;
    let lens = tele_lens(size, 2.0, 1.0);
    let c = 12.0;
    for (aperture, z, sign) in [
        ("disc", depth_for_coc(&lens, c), 1.0),
        ("poly:6", depth_for_coc(&lens, c), 1.0),
        ("poly:5,rot=20", depth_for_coc(&lens, c), 1.0),
        // In front of focus the aperture is turned half a turn.
        ("poly:5,rot=20", depth_for_coc(&lens, -c), -1.0),
    ] {
        let shape = Aperture::parse(aperture).unwrap();
        let (img, depth) = point_light(size, z);
        let settings = LowRankSettings {
            aperture: shape.clone(),
            rank: 10,
            ..LowRankSettings::default()
        };
        let out = lowrank::gpu::render(ctx, &img, &depth, &lens, &settings).unwrap();
        let measured = extents(&out.image, size / 2);
        let dirs = [Vec2::X, -Vec2::X, Vec2::Y, -Vec2::Y];
        for (m, d) in measured.iter().zip(dirs) {
            // The far field's bokeh is the aperture; the near field's is turned half a turn.
            let expected = c * boundary_distance(&shape, sign * d);
            eprintln!(
                "{aperture}, C {}: along {d}: {m:.2} px, the aperture {expected:.2}",
                sign * c
            );
            assert!(
                (m - expected).abs() < 0.75,
                "{aperture}, C {}: along {d}: {m} px against {expected}",
                sign * c
            );
        }
        // Energy: the light of the square, plus what clamping the ringing adds (as on the CPU).
        let sum = |im: &ColorImage| im.pixels().iter().map(|p| p[0] as f64).sum::<f64>();
        let gain = sum(&out.image) / sum(&img) - 1.0;
        assert!(
            (-1e-4..0.03).contains(&gain),
            "{aperture}: energy gain {gain}"
        );
    }
}

#[test]
fn blur_runs_lowrank_and_its_tilt_shift_on_the_gpu_as_on_the_cpu() {
    if context().is_none() {
        return;
    }
    let dir = temp_dir("gpu-lowrank-blur");
    let (color, depth) = write_random_frame(&dir);
    let run = |device: &str, extra: &[&str]| {
        let out = dir.join(format!("lowrank-{device}-{}.exr", extra.len()));
        let mut args = vec!["blur", "--color", s(&color), "--method", "lowrank"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--device", device, "--timings", "json", "--out", s(&out)]);
        let done = defocus(&args);
        assert!(
            done.status.success(),
            "{device} {extra:?}: {}",
            stderr(&done)
        );
        let json: serde_json::Value = serde_json::from_slice(&done.stdout).unwrap();
        (defocus::image::io::read_color(&out).unwrap(), json)
    };
    for extra in [
        &["--depth", s(&depth), "--focus", "1.5", "--fstop", "1.4"][..],
        &["--tilt-shift", "centre=0.4,blur=6"][..],
    ] {
        let (cpu, cpu_json) = run("cpu", extra);
        let (gpu, gpu_json) = run("gpu", extra);
        assert_eq!(cpu_json["device"], "cpu");
        assert_ne!(gpu_json["device"], "cpu");
        let psnr = defocus::metrics::compare(&cpu, &gpu).unwrap().psnr_db;
        eprintln!("blur --method lowrank {extra:?} --device gpu against cpu: {psnr:.1} dB");
        assert!(psnr >= MIN_PSNR_DB, "{extra:?}: {psnr} dB");
    }
}

#[test]
fn every_gpu_method_matches_the_cpu_on_the_cycles_frames() {
    if context().is_none() {
        return;
    }
    let Some(assets) = crate::shared_assets() else {
        return;
    };
    let dir = temp_dir("gpu-cycles");
    for (scene, camera) in [
        (
            "railing",
            [
                "--focal-length",
                "85",
                "--sensor-width",
                "36",
                "--fstop",
                "1.4",
                "--focus",
                "2.5",
            ],
        ),
        (
            "foliage",
            [
                "--focal-length",
                "50",
                "--sensor-width",
                "36",
                "--fstop",
                "2",
                "--focus",
                "3",
            ],
        ),
    ] {
        let frame = assets.join("cycles-scenes").join(scene).join("pinhole.exr");
        for method in defocus::methods::registry::gpu_ids() {
            let info = defocus::methods::registry::find(method).unwrap();
            if info.input != defocus::methods::registry::InputKind::PinholeFrame {
                continue;
            }
            let run = |device: &str| {
                let out = dir.join(format!("{scene}-{method}-{device}.exr"));
                let mut args = vec!["blur", "--color", s(&frame), "--depth", s(&frame)];
                args.extend_from_slice(&camera);
                args.extend_from_slice(&["--method", method, "--device", device, "--out", s(&out)]);
                let done = defocus(&args);
                assert!(
                    done.status.success(),
                    "{scene} {method} {device}: {}",
                    stderr(&done)
                );
                defocus::image::io::read_color(&out).unwrap()
            };
            let (psnr, diff) = psnr_and_max_diff(&run("cpu"), &run("gpu"));
            eprintln!("Cycles {scene}, {method}: GPU against CPU {psnr:.1} dB, largest difference {diff:e}");
            assert!(psnr >= MIN_PSNR_DB, "{scene} {method}: {psnr} dB");
        }
    }
}

/// `defocus bench` with `args`: its JSON.
fn bench(args: &[&str]) -> serde_json::Value {
    let mut all = vec![
        "bench", "--sizes", "48x27", "--frames", "3", "--warmup", "1",
    ];
    all.extend_from_slice(args);
    let done = defocus(&all);
    assert!(done.status.success(), "{args:?}: {}", stderr(&done));
    serde_json::from_slice(&done.stdout).unwrap()
}

/// Checks a bench record: its method's passes, medians within [least, +inf), the sum.
fn check_bench_record(r: &serde_json::Value) {
    let method = r["method"].as_str().unwrap();
    let passes = r["passes"].as_array().unwrap();
    let own: Vec<&serde_json::Value> = passes
        .iter()
        .filter(|p| {
            p["name"]
                .as_str()
                .unwrap()
                .starts_with(&format!("{method}/"))
        })
        .collect();
    assert!(!own.is_empty(), "{r}");
    for p in passes {
        let (median, least) = (
            p["median_ms"].as_f64().unwrap(),
            p["min_ms"].as_f64().unwrap(),
        );
        assert!(least >= 0.0 && median >= least, "{p}");
    }
    let (median, least) = (
        r["median_ms"].as_f64().unwrap(),
        r["min_ms"].as_f64().unwrap(),
    );
    assert!(median >= least && least > 0.0, "{r}");
    assert!(r["wall_median_ms"].as_f64().unwrap() >= least, "{r}");
}

#[test]
fn bench_times_every_method_on_the_cpu_as_json() {
    let dir = temp_dir("bench-cpu");
    let out = dir.join("bench.json");
    let json = bench(&[
        "--device",
        "cpu",
        "--scenes",
        "railing,lights",
        "--out",
        s(&out),
    ]);
    assert_eq!(json["device"], "cpu");
    assert_eq!(json["frames"], 3);
    let runs = json["runs"].as_array().unwrap();
    let methods = defocus::methods::registry::gpu_ids();
    assert_eq!(runs.len(), 2 * methods.len());
    for r in runs {
        assert_eq!(r["width"], 48);
        assert_eq!(r["device"], "cpu");
        check_bench_record(r);
    }
    let written: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(written["runs"].as_array().unwrap().len(), runs.len());
    // Refusals name what was wrong, and write nothing.
    let out2 = dir.join("refused.json");
    for (args, says) in [
        (&["--methods", "multiview"][..], "multiview"),
        (&["--samples", "0"][..], "--samples"),
        (&["--sizes", "0x5"][..], "0x5"),
        (&["--scenes", "nope"][..], "nope"),
        (&["--frames", "0"][..], "--frames"),
    ] {
        let mut all = vec!["bench", "--device", "cpu", "--out", s(&out2)];
        all.extend_from_slice(args);
        let done = defocus(&all);
        assert!(!done.status.success(), "{args:?}");
        assert!(stderr(&done).contains(says), "{args:?}: {}", stderr(&done));
        assert!(!out2.exists());
    }
}

#[test]
fn bench_times_every_gpu_method_per_pass_on_the_gpu() {
    let Some(ctx) = context() else { return };
    let json = bench(&["--device", "gpu", "--scenes", "grass"]);
    assert_eq!(json["device"], ctx.description().label().as_str());
    assert_eq!(json["software"], ctx.description().software);
    let runs = json["runs"].as_array().unwrap();
    assert_eq!(runs.len(), defocus::methods::registry::gpu_ids().len());
    for r in runs {
        check_bench_record(r);
        assert_eq!(r["gpu_timed"], ctx.has_timestamps(), "{r}");
        let names: Vec<&str> = r["passes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["name"].as_str().unwrap())
            .collect();
        assert!(
            names.contains(&"gpu/upload") && names.contains(&"gpu/download"),
            "{names:?}"
        );
    }
    // A method without GPU passes is refused on the GPU.
    let done = defocus(&["bench", "--device", "gpu", "--methods", "splat"]);
    assert!(!done.status.success());
    assert!(stderr(&done).contains("splat"), "{}", stderr(&done));
}

#[test]
fn compare_runs_each_gpu_method_on_both_devices_side_by_side() {
    let Some(ctx) = context() else { return };
    let dir = temp_dir("gpu-compare");
    let out = dir.join("report");
    let done = defocus(&[
        "compare",
        "--scene",
        "railing",
        "--width",
        "96",
        "--height",
        "54",
        "--reference-samples",
        "8",
        "--methods",
        "hammon,lowrank,poisson,splat",
        "--device",
        "cpu,gpu",
        "--out",
        s(&out),
    ]);
    assert!(done.status.success(), "{}", stderr(&done));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("results.json")).unwrap()).unwrap();
    let runs = json["runs"].as_array().unwrap();
    let labels: Vec<&str> = runs.iter().map(|r| r["label"].as_str().unwrap()).collect();
    assert_eq!(
        labels,
        [
            "hammon",
            "hammon-gpu",
            "lowrank",
            "lowrank-gpu",
            "poisson",
            "poisson-gpu",
            "splat"
        ]
    );
    let label = ctx.description().label();
    for pair in runs.chunks(2).take(3) {
        assert_eq!(pair[0]["device"], "cpu");
        assert_eq!(pair[1]["device"], label.as_str());
        // The same quality against the reference on either device.
        let (a, b) = (
            pair[0]["psnr_db"].as_f64().unwrap(),
            pair[1]["psnr_db"].as_f64().unwrap(),
        );
        assert!(
            (a - b).abs() < 0.01,
            "{}: {a} against {b}",
            pair[0]["method"]
        );
        let read = |r: &serde_json::Value| {
            defocus::image::io::read_color(&out.join(r["image_exr"].as_str().unwrap())).unwrap()
        };
        let (psnr, _) = psnr_and_max_diff(&read(&pair[0]), &read(&pair[1]));
        assert!(psnr >= MIN_PSNR_DB, "{}: {psnr} dB", pair[0]["method"]);
    }
    // A method without GPU passes runs once, on the CPU.
    assert_eq!(runs[6]["device"], "cpu");
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(
        html.contains("<th class=\"l\">device</th>"),
        "no device column"
    );
}

#[test]
fn a_gpu_run_is_planned_against_the_budget_and_the_adapters_limits() {
    let Some(ctx) = context() else { return };
    // Within both.
    ctx.plan("a small frame", 1 << 20, 8 << 20).unwrap();
    // More than the memory budget (16 GiB unless set) in all: refused before any allocation,
    // naming the budget and the flag to raise.
    let e = ctx
        .plan("a frame", 1 << 20, 1 << 40)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a frame") && e.contains("budget") && e.contains("--memory-budget"),
        "{e}"
    );
    // One buffer over the adapter's limit: refused naming the limit.
    let limit = ctx.description().limits.max_storage_buffer_binding_size;
    let e = ctx
        .plan("a huge frame", limit + 4, limit + 4)
        .unwrap_err()
        .to_string();
    assert!(e.contains("max storage buffer binding size"), "{e}");
    ctx.check().unwrap();
}

#[test]
fn a_lost_device_is_an_error_naming_it_not_a_crash() {
    if context().is_none() {
        return;
    }
    // A context of its own, whose device is then destroyed: what a driver reset does.
    let ctx = defocus::gpu::GpuContext::open(defocus::gpu::Device::Gpu)
        .unwrap()
        .unwrap();
    let (color, depth) = random_frame(40, 24, 1);
    let lens = crate::test_camera(40, 24, 1.5, 1.4).thin_lens().unwrap();
    poisson::gpu::render(&ctx, &color, &depth, &lens, &PoissonSettings::default()).unwrap();
    ctx.device().destroy();
    for run in 0..2 {
        let e = lowrank::gpu::render(&ctx, &color, &depth, &lens, &LowRankSettings::default())
            .map(|_| ())
            .and_then(|()| ctx.check())
            .unwrap_err()
            .to_string();
        eprintln!("after the device was destroyed, run {run}: {e}");
        assert!(
            e.contains(&ctx.description().label()) && e.contains("the device was lost"),
            "{e}"
        );
    }
}
