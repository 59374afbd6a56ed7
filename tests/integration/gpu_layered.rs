//! The layered methods on the GPU against their CPU twins: `multilayer` in the paper's
//! configuration (fragments at pixel centres, box levels, highlights filtered as every
//! fragment) on every built-in scene and on the Cycles scenes (and against Cycles' truth there);
//! the fragment lists keeping the N nearest where a pixel has more; the command line. Run on
//! any Vulkan adapter (lavapipe in CI); skipped, with the reason printed, where there is none.

use defocus::lens::Camera;
use defocus::methods::multilayer::{self, Bokeh, MultilayerSettings};
use defocus::raster::{LayeredInput, PreparedScene, View};
use defocus::scene::Scene;

use crate::cli::{defocus, s, stderr, temp_dir};
use crate::gpu::{context, psnr_and_max_diff};

/// `multilayer` GPU against CPU: the bound. The two sides run the same arithmetic on the same
/// fragments, but the GPU's lists order fragments of exactly equal depth by draw order where
/// the CPU takes them in its tiles' order (crossed quads of `grass`), its levels hold 16
/// fragments a cell (the CPU 64) and its powers and logarithms are the GPU's; 40 dB is the
/// issue's bound for the layered methods.
const MIN_PSNR_DB: f64 = 40.0;

/// The paper's configuration, which the GPU runs.
fn paper(scene: &Scene) -> MultilayerSettings {
    MultilayerSettings {
        input: LayeredInput {
            coverage: false,
            ..LayeredInput::default()
        },
        bokeh: Bokeh::Box,
        highlights: None,
        aperture: scene.defaults.as_ref().unwrap().aperture.clone(),
        ..MultilayerSettings::default()
    }
}

fn builtin(name: &str, w: usize, h: usize) -> (Scene, Camera) {
    let scene = defocus::scene::builtin::load(name).unwrap();
    let mut camera = scene.defaults.clone().unwrap().camera;
    (camera.width_px, camera.height_px) = (w, h);
    (scene, camera)
}

#[test]
fn gpu_multilayer_matches_the_cpu_on_every_builtin_scene() {
    let Some(ctx) = context() else { return };
    for name in defocus::scene::builtin::NAMES {
        let (scene, camera) = builtin(name, 640, 360);
        let settings = paper(&scene);
        let cpu = multilayer::render(&scene, &camera, &settings).unwrap();
        let gpu = multilayer::gpu::render(ctx, &scene, &camera, &settings).unwrap();
        let (psnr, diff) = psnr_and_max_diff(&cpu.image, &gpu.image);
        let (cd, gd) = (cpu.depth.unwrap(), gpu.depth.unwrap());
        let same_depth = cd
            .pixels()
            .iter()
            .zip(gd.pixels())
            .filter(|(a, b)| a == b || (**a - **b).abs() <= 1e-5 * a.abs())
            .count() as f64
            / cd.pixels().len() as f64;
        eprintln!(
            "multilayer {name} 640x360: GPU against CPU {psnr:.1} dB, largest difference \
             {diff:e}, depth equal at {:.3} % of pixels",
            100.0 * same_depth
        );
        assert!(psnr >= MIN_PSNR_DB, "{name}: {psnr} dB");
        assert!(same_depth > 0.999, "{name}: {same_depth}");
        let names: Vec<&str> = gpu.timings.passes.iter().map(|p| p.name.as_str()).collect();
        for pass in [
            "multilayer/collect",
            "multilayer/filter",
            "multilayer/accumulate",
        ] {
            assert!(names.contains(&pass), "{name}: {names:?}");
        }
    }
}

/// `--ml-supersample 2` and `4` (the lists at K x K times the resolution, merged down before
/// the Y-map) on the GPU against the CPU.
#[test]
fn gpu_multilayer_supersampled_matches_the_cpu() {
    let Some(ctx) = context() else { return };
    for (name, k) in [("glass", 2), ("grass", 2), ("railing", 4)] {
        let (scene, camera) = builtin(name, 320, 180);
        let settings = MultilayerSettings {
            supersample: k,
            ..paper(&scene)
        };
        let cpu = multilayer::render(&scene, &camera, &settings).unwrap();
        let gpu = multilayer::gpu::render(ctx, &scene, &camera, &settings).unwrap();
        let (psnr, diff) = psnr_and_max_diff(&cpu.image, &gpu.image);
        eprintln!(
            "multilayer {name} 320x180, supersampled {k}x{k}: GPU against CPU {psnr:.1} dB, \
             largest difference {diff:e}"
        );
        assert!(psnr >= MIN_PSNR_DB, "{name} {k}: {psnr} dB");
    }
}

/// Pixels with more surfaces than the lists hold keep the N nearest on the GPU, as on the
/// CPU: `traps` (double-sided bars, a pane, the chart and the wall behind) with N = 2 and 4
/// against the CPU's lists of the same view, fragment for fragment.
#[test]
fn gpu_fragment_lists_keep_the_n_nearest_as_the_cpu() {
    let Some(ctx) = context() else { return };
    let (scene, camera) = builtin("traps", 320, 180);
    let lens = camera.thin_lens().unwrap();
    let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
    let input = LayeredInput {
        coverage: false,
        guard_band: false,
        ..LayeredInput::default()
    };
    let all =
        defocus::raster::render_fragment_lists(&prepared, &View::pinhole(lens), 16, input, None)
            .unwrap();
    for cap in [2, 4] {
        let deeper = (0..lens.width_px * lens.height_px)
            .filter(|&i| all.offsets()[i + 1] - all.offsets()[i] > cap as u32)
            .count();
        assert!(deeper > 100, "N = {cap}: {deeper} pixels with more");
        let cpu = defocus::raster::render_fragment_lists(
            &prepared,
            &View::pinhole(lens),
            cap,
            input,
            None,
        )
        .unwrap();
        let mut timings = defocus::timing::Timings::default();
        let lists = defocus::raster::gpu::fragment_lists(
            ctx,
            &prepared,
            lens,
            cap,
            None,
            "test/collect",
            &mut timings,
        )
        .unwrap();
        let gpu = lists.download(ctx).unwrap();
        lists.recycle(ctx);
        let mut differ = 0;
        for y in 0..lens.height_px {
            for x in 0..lens.width_px {
                let (cz, cc) = cpu.pixel(x, y);
                let (gz, gc) = gpu.pixel(x, y);
                let same = cz.len() == gz.len()
                    && cz.iter().zip(gz).all(|(a, b)| (a - b).abs() <= 1e-5 * a)
                    && cc.iter().zip(gc).all(|(a, b)| {
                        a.iter()
                            .zip(b)
                            .all(|(p, q)| (p.to_f32() - q.to_f32()).abs() <= 1e-3)
                    });
                differ += usize::from(!same);
            }
        }
        let share = differ as f64 / (lens.width_px * lens.height_px) as f64;
        eprintln!(
            "traps 320x180, N = {cap}: {deeper} pixels hold more surfaces; GPU lists differ \
             from the CPU's at {:.3} % of pixels",
            100.0 * share
        );
        assert!(share < 1e-3, "N = {cap}: {share}");
    }
}

/// Against Cycles' truth on the two Cycles scenes: what the CPU twin scores in the same (the
/// paper's) configuration, to 0.05 dB, and within the bound of it. That configuration scores
/// 21-22 dB on both (its single sample a pixel aliases their in-focus detail, and its box
/// levels dim the lights behind the railing evenly); the CPU's defaults, coverage masks and
/// highlights ray by ray, bring it to 38-39 dB, and are not on the GPU yet.
#[test]
fn gpu_multilayer_scores_against_cycles_as_the_cpu() {
    let Some(ctx) = context() else { return };
    let Some(assets) = crate::shared_assets() else {
        return;
    };
    for name in ["railing", "foliage"] {
        let dir = assets.join("cycles-scenes").join(name);
        let scene = defocus::scene::load::load_scene_file(&dir.join("scene.glb")).unwrap();
        let truth = defocus::image::io::read_color(&dir.join("truth.exr")).unwrap();
        let mut camera = scene.defaults.as_ref().unwrap().camera.clone();
        (camera.width_px, camera.height_px) = (truth.width(), truth.height());
        let settings = paper(&scene);
        let cpu = multilayer::render(&scene, &camera, &settings).unwrap();
        let gpu = multilayer::gpu::render(ctx, &scene, &camera, &settings).unwrap();
        let score = |img| defocus::metrics::compare(img, &truth).unwrap().psnr_db;
        let (c, g) = (score(&cpu.image), score(&gpu.image));
        let (twin, _) = psnr_and_max_diff(&cpu.image, &gpu.image);
        eprintln!(
            "Cycles {name}, multilayer (paper): CPU {c:.2} dB, GPU {g:.2} dB against Cycles; \
             GPU against CPU {twin:.1} dB"
        );
        assert!((g - c).abs() <= 0.05, "{name}: GPU {g} dB, CPU {c} dB");
        assert!(twin >= MIN_PSNR_DB, "{name}: {twin} dB");
    }
}

#[test]
fn render_multilayer_on_the_gpu_from_the_command_line() {
    if context().is_none() {
        return;
    }
    let dir = temp_dir("gpu-layered-cli");
    let out = dir.join("railing.exr");
    let paper = [
        "--no-coverage",
        "--ml-bokeh",
        "box",
        "--highlight-rays",
        "off",
    ];
    let base = [
        "render",
        "--scene",
        "railing",
        "--width",
        "160",
        "--height",
        "90",
        "--method",
        "multilayer",
        "--device",
        "gpu",
    ];
    let mut args = base.to_vec();
    args.extend_from_slice(&["--timings", "--out", s(&out)]);
    args.extend_from_slice(&paper);
    let done = defocus(&args);
    assert!(done.status.success(), "{}", stderr(&done));
    let log = stderr(&done);
    for pass in [
        "multilayer/collect",
        "multilayer/filter",
        "multilayer/accumulate",
    ] {
        assert!(log.contains(pass), "{log}");
    }
    assert!(defocus::image::io::read_color(&out).is_ok());
    // The CPU's defaults beyond the paper are refused on the GPU by name, and no file is left.
    let refused = dir.join("refused.exr");
    let mut args = base.to_vec();
    args.extend_from_slice(&["--out", s(&refused)]);
    let done = defocus(&args);
    assert!(!done.status.success());
    let err = stderr(&done);
    assert!(
        err.contains("--no-coverage") && err.contains("--device cpu"),
        "{err}"
    );
    assert!(!refused.exists());
}

/// A sequence on one context allocates on its first frames only: the pools give every buffer
/// and texture back, and the lists' and levels' sizes are remembered from the frame before, so
/// the third frame of `grass` (more fragments a pixel than the first guess) makes nothing new.
#[test]
fn gpu_multilayer_frames_after_the_first_allocate_nothing() {
    if context().is_none() {
        return;
    }
    // A context of its own: the shared one serves the tests running beside this one.
    let ctx = defocus::gpu::GpuContext::open(defocus::gpu::Device::Gpu)
        .unwrap()
        .unwrap();
    let (scene, camera) = builtin("grass", 160, 90);
    let settings = paper(&scene);
    let mut made = Vec::new();
    let mut images = Vec::new();
    for _ in 0..3 {
        let out = multilayer::gpu::render(&ctx, &scene, &camera, &settings).unwrap();
        made.push(ctx.allocations());
        images.push(out.image);
    }
    eprintln!("grass 160x90, multilayer on the GPU: allocations after each frame {made:?}");
    assert!(made[0] > 0);
    assert_eq!(made[2], made[1], "{made:?}");
    assert!(images[1] == images[0] && images[2] == images[0]);
}
