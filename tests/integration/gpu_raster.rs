//! `pinhole` and `reference` drawn by the GPU's own rasteriser against their CPU twins: every
//! built-in scene (opaque, alpha-mask and blended surfaces, textures with mip-maps), the lens
//! effects, single-sided surfaces, and a point light that becomes the aperture. Run on any
//! Vulkan adapter (lavapipe in CI); skipped, with the reason printed, where there is none.

use defocus::image::GrayImage;
use defocus::lens::{Aperture, Camera, LensEffects};
use defocus::methods::reference::{self, ReferenceSettings};
use defocus::scene::{Material, Scene};

use crate::cli::{defocus, s, stderr, temp_dir};
use crate::gpu::{context, psnr_and_max_diff, MIN_PSNR_DB};
use crate::reference::{extents, point_light_scene, tele_camera, SIZE};

/// Built-in scene `name` and its camera at `w`x`h`.
fn builtin(name: &str, w: usize, h: usize) -> (Scene, Camera) {
    let scene = defocus::scene::builtin::load(name).unwrap();
    let mut camera = scene.defaults.clone().unwrap().camera;
    (camera.width_px, camera.height_px) = (w, h);
    (scene, camera)
}

/// `settings` rendered on the CPU and on the GPU: (CPU, GPU).
fn both(
    scene: &Scene,
    camera: &Camera,
    settings: &ReferenceSettings,
) -> (
    defocus::methods::MethodOutput,
    defocus::methods::MethodOutput,
) {
    let ctx = context().expect("checked by the caller");
    let cpu = reference::render(scene, camera, settings, &mut |_, _| {}).unwrap();
    let gpu = reference::render_on(scene, camera, settings, Some(ctx), &mut |_, _| {}).unwrap();
    (cpu, gpu)
}

/// The share of pixels whose depths differ by more than 0.1 % (a different surface won).
fn depth_mismatch(a: &GrayImage, b: &GrayImage) -> f64 {
    let differ = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .filter(|(x, y)| !(x == y || ((*x - *y).abs() <= 1e-3 * x.abs().max(y.abs()))))
        .count();
    differ as f64 / a.pixels().len() as f64
}

fn pinhole(samples: usize) -> ReferenceSettings {
    ReferenceSettings {
        samples,
        use_lens: false,
        with_depth: true,
        ..ReferenceSettings::default()
    }
}

/// `grass` at one sample a pixel: the bound its cut-out blades allow. Its tufts are two quads
/// crossed along a vertical line, where both lie at the same depth, and blades whose alpha
/// passes the cutoff within a rounding error of the texture lookup; there the two rasterisers
/// (the CPU's fixed-point setup and the GPU's own) pick different surfaces, whole pixels of
/// colour apart. Measured: 40.3 dB at 320x180 and 45.6 dB at 640x360, with 0.056 % and
/// 0.024 % of the pixels on another surface; averaging views (any `--samples` above 1) brings
/// it above 45 dB.
const GRASS_ONE_SAMPLE_MIN_PSNR_DB: f64 = 38.0;

/// The share of pixels of `grass` at one sample that may show another surface (see
/// [`GRASS_ONE_SAMPLE_MIN_PSNR_DB`]); on every other scene none may.
const GRASS_ONE_SAMPLE_MAX_MISMATCH: f64 = 0.002;

#[test]
fn gpu_pinhole_matches_the_cpu_on_every_builtin_scene() {
    if context().is_none() {
        return;
    }
    for (w, h) in [(320, 180), (640, 360)] {
        for name in defocus::scene::builtin::NAMES {
            let (scene, camera) = builtin(name, w, h);
            let (cpu, gpu) = both(&scene, &camera, &pinhole(1));
            let (psnr, diff) = psnr_and_max_diff(&cpu.image, &gpu.image);
            let mismatch = depth_mismatch(cpu.depth.as_ref().unwrap(), gpu.depth.as_ref().unwrap());
            eprintln!(
                "pinhole {name} {w}x{h}: GPU against CPU {psnr:.1} dB, largest difference \
                 {diff:e}, another surface at {:.3} % of pixels",
                100.0 * mismatch
            );
            let names: Vec<&str> = gpu.timings.passes.iter().map(|p| p.name.as_str()).collect();
            assert!(names.contains(&"pinhole/raster"), "{names:?}");
            if *name == "grass" {
                assert!(
                    psnr >= GRASS_ONE_SAMPLE_MIN_PSNR_DB,
                    "grass {w}x{h}: {psnr} dB"
                );
                assert!(
                    mismatch <= GRASS_ONE_SAMPLE_MAX_MISMATCH,
                    "grass {w}x{h}: {mismatch}"
                );
            } else {
                assert!(psnr >= MIN_PSNR_DB, "pinhole {name} {w}x{h}: {psnr} dB");
                assert!(mismatch < 1e-4, "pinhole {name} {w}x{h}: depth {mismatch}");
            }
        }
    }
}

/// `reference` (and supersampled `pinhole`) on the GPU against the CPU at the same samples
/// and seed, at `w`x`h`.
fn views_match_the_cpu(w: usize, h: usize, views: usize) {
    for name in defocus::scene::builtin::NAMES {
        let (scene, camera) = builtin(name, w, h);
        for settings in [
            pinhole(views / 2),
            ReferenceSettings {
                samples: views,
                seed: 3,
                with_depth: true,
                ..ReferenceSettings::default()
            },
        ] {
            let (cpu, gpu) = both(&scene, &camera, &settings);
            let (psnr, diff) = psnr_and_max_diff(&cpu.image, &gpu.image);
            let method = if settings.use_lens {
                "reference"
            } else {
                "pinhole"
            };
            eprintln!(
                "{method} {name} {w}x{h}, {} views: GPU against CPU {psnr:.1} dB, largest \
                 difference {diff:e}",
                settings.samples
            );
            assert!(psnr >= MIN_PSNR_DB, "{method} {name} {w}x{h}: {psnr} dB");
            if settings.use_lens {
                // The depth is the pinhole view's.
                let mismatch =
                    depth_mismatch(cpu.depth.as_ref().unwrap(), gpu.depth.as_ref().unwrap());
                assert!(
                    mismatch <= GRASS_ONE_SAMPLE_MAX_MISMATCH,
                    "{name}: {mismatch}"
                );
            }
        }
    }
}

#[test]
fn gpu_reference_matches_the_cpu_on_every_builtin_scene_at_320x180() {
    if context().is_none() {
        return;
    }
    views_match_the_cpu(320, 180, 16);
}

#[test]
fn gpu_reference_matches_the_cpu_on_every_builtin_scene_at_640x360() {
    if context().is_none() {
        return;
    }
    views_match_the_cpu(640, 360, 4);
}

#[test]
fn gpu_reference_matches_the_cpu_with_every_lens_effect() {
    if context().is_none() {
        return;
    }
    let (scene, camera) = builtin("lights", 160, 90);
    let cats_eye = LensEffects {
        barrel_distance_m: 0.03,
        ..LensEffects::default()
    };
    for (label, effects) in [
        ("cat's eye", cats_eye),
        (
            "anamorphic",
            LensEffects {
                aspect: 0.6,
                ..LensEffects::default()
            },
        ),
        (
            "all three",
            LensEffects {
                aspect: 0.6,
                chroma_dpt: 0.4,
                ..cats_eye
            },
        ),
    ] {
        let settings = ReferenceSettings {
            samples: 48,
            effects,
            aperture: Aperture::parse("poly:5").unwrap(),
            ..ReferenceSettings::default()
        };
        let (cpu, gpu) = both(&scene, &camera, &settings);
        let plain = reference::render(
            &scene,
            &camera,
            &ReferenceSettings {
                effects: LensEffects::default(),
                ..settings.clone()
            },
            &mut |_, _| {},
        )
        .unwrap();
        // The effect changes the image, so the agreement below tests it.
        assert_ne!(plain.image, cpu.image, "{label}");
        let (psnr, diff) = psnr_and_max_diff(&cpu.image, &gpu.image);
        eprintln!("reference, {label}: GPU against CPU {psnr:.1} dB, largest difference {diff:e}");
        assert!(psnr >= MIN_PSNR_DB, "{label}: {psnr} dB");
    }
}

#[test]
fn gpu_culls_the_back_of_single_sided_surfaces_as_the_cpu_does() {
    let Some(ctx) = context() else { return };
    let camera = crate::test_camera(64, 48, 2.0, 2.8);
    let mut scene = Scene::default();
    let single = |name: &str, rgb| Material {
        double_sided: false,
        ..Material::color(name, rgb)
    };
    let red = scene.add_material(single("red", [1.0, 0.0, 0.0]));
    let green = scene.add_material(single("green", [0.0, 1.0, 0.0]));
    // Two single-sided quads side by side, one wound towards the camera, one away.
    let mut toward = defocus::scene::Mesh {
        material: red,
        ..Default::default()
    };
    let z = -2.0;
    toward.push_quad(
        glam::Vec3::new(-0.6, -0.3, z),
        glam::Vec3::new(0.5, 0.0, 0.0),
        glam::Vec3::new(0.0, 0.6, 0.0),
    );
    let mut away = defocus::scene::Mesh {
        material: green,
        ..Default::default()
    };
    away.push_quad(
        glam::Vec3::new(0.1, 0.3, z),
        glam::Vec3::new(0.5, 0.0, 0.0),
        glam::Vec3::new(0.0, -0.6, 0.0),
    );
    scene.meshes.extend([toward, away]);
    for settings in [
        pinhole(1),
        ReferenceSettings {
            samples: 16,
            ..ReferenceSettings::default()
        },
    ] {
        let cpu = reference::render(&scene, &camera, &settings, &mut |_, _| {}).unwrap();
        let gpu =
            reference::render_on(&scene, &camera, &settings, Some(ctx), &mut |_, _| {}).unwrap();
        let sum = |img: &defocus::image::ColorImage, c: usize| {
            img.pixels().iter().map(|p| p[c] as f64).sum::<f64>()
        };
        // The quad wound towards the camera is drawn, the other culled, on both.
        assert!(sum(&cpu.image, 0) > 100.0 && sum(&cpu.image, 1) == 0.0);
        let (psnr, _) = psnr_and_max_diff(&cpu.image, &gpu.image);
        assert!(psnr >= MIN_PSNR_DB, "{psnr} dB");
    }
}

/// Lens samples of the point-light tests, as the CPU's: with fewer, each pixel of the bokeh is
/// hit by too few views for its half-plateau edge (at 1024, the walk stopped at 9 px of 21).
const POINT_LIGHT_SAMPLES: usize = 4096;

fn gpu_point_light(camera: &Camera, z: f32, aperture: &str) -> [f32; 4] {
    let ctx = context().expect("checked by the caller");
    let settings = ReferenceSettings {
        samples: POINT_LIGHT_SAMPLES,
        aperture: Aperture::parse(aperture).unwrap(),
        ..ReferenceSettings::default()
    };
    let scene = point_light_scene(camera, z);
    let out = reference::render_on(&scene, camera, &settings, Some(ctx), &mut |_, _| {}).unwrap();
    assert_eq!(out.image.width(), SIZE);
    extents(&out.image)
}

#[test]
fn a_point_light_becomes_the_aperture_on_the_gpu() {
    if context().is_none() {
        return;
    }
    let camera = tele_camera(1.0, 1.4);
    let coc = camera.thin_lens().unwrap().coc_px(50.0);
    for d in gpu_point_light(&camera, 50.0, "disc") {
        assert!((d - coc).abs() < 1.0, "disc: {d}, |C| = {coc}");
    }
    // A polygon's vertex and side distances, and its turn through focus, with five blades (the
    // CPU's test also runs a hexagon; each view here is the CPU's, drawn by the GPU, and lavapipe
    // takes about 20 s a run of 4096 views).
    // Five blades: a vertex to the left behind focus, turned half a turn in front of it.
    let camera = tele_camera(2.0, 1.0);
    let lens = camera.thin_lens().unwrap();
    let c_far = lens.coc_px(400.0);
    let near_z = 1.0 / (1.0 / lens.focus_m + c_far / (lens.f_px * lens.lens_radius_m));
    let side = c_far * 36f32.to_radians().cos();
    let [fr, fl, _, _] = gpu_point_light(&camera, 400.0, "poly:5");
    assert!(
        (fl - c_far).abs() < 1.0 && (fr - side).abs() < 1.0,
        "far: {fl} {fr}"
    );
    let [nr, nl, _, _] = gpu_point_light(&camera, near_z, "poly:5");
    assert!(
        (nr - c_far).abs() < 1.0 && (nl - side).abs() < 1.0,
        "near: {nl} {nr}"
    );
}

#[test]
fn gpu_pinhole_of_the_cycles_calibration_scene_matches_cycles() {
    if context().is_none() {
        return;
    }
    let Some(assets) = crate::shared_assets() else {
        return;
    };
    let dir = assets.join("cycles");
    let scene = defocus::scene::load::load_scene_file(&dir.join("scene.glb")).unwrap();
    let camera = scene.defaults.as_ref().unwrap().camera.clone();
    let ctx = context().unwrap();
    // As the CPU's test: 256 samples a pixel against Cycles' 1024, at least 62 dB.
    let settings = pinhole(256);
    let ours = reference::render_on(&scene, &camera, &settings, Some(ctx), &mut |_, _| {}).unwrap();
    let truth = defocus::image::io::read_color(&dir.join("pinhole.exr")).unwrap();
    let m = defocus::metrics::compare(&ours.image, &truth).unwrap();
    eprintln!(
        "GPU pinhole of the Cycles scene: {:.2} dB against Cycles",
        m.psnr_db
    );
    assert!(m.psnr_db > 62.0, "{} dB", m.psnr_db);
}

#[test]
fn render_on_the_gpu_from_the_command_line_matches_the_cpu_on_the_cycles_scenes() {
    if context().is_none() {
        return;
    }
    let Some(assets) = crate::shared_assets() else {
        return;
    };
    let dir = temp_dir("gpu-raster-cli");
    for scene in ["railing", "foliage"] {
        let file = assets.join("cycles-scenes").join(scene).join("scene.glb");
        for (method, samples) in [("pinhole", "4"), ("reference", "16")] {
            let run = |device: &str| {
                let out = dir.join(format!("{scene}-{method}-{device}.exr"));
                let done = defocus(&[
                    "render",
                    "--scene",
                    s(&file),
                    "--width",
                    "240",
                    "--height",
                    "135",
                    "--method",
                    method,
                    "--samples",
                    samples,
                    "--device",
                    device,
                    "--timings",
                    "--out",
                    s(&out),
                ]);
                assert!(
                    done.status.success(),
                    "{scene} {method} {device}: {}",
                    stderr(&done)
                );
                (defocus::image::io::read_color(&out).unwrap(), stderr(&done))
            };
            let (cpu, _) = run("cpu");
            let (gpu, log) = run("gpu");
            let (psnr, diff) = psnr_and_max_diff(&cpu, &gpu);
            eprintln!("Cycles scene {scene}, {method}: GPU against CPU {psnr:.1} dB, largest difference {diff:e}");
            assert!(psnr >= MIN_PSNR_DB, "{scene} {method}: {psnr} dB");
            assert!(log.contains(&format!("{method}/raster")), "{log}");
        }
    }
}

#[test]
fn the_gpu_rasteriser_counts_its_targets_and_lists_against_the_budget() {
    if context().is_none() {
        return;
    }
    let dir = temp_dir("gpu-raster-budget");
    let out = dir.join("o.exr");
    // `glass` has blended panes: lists of 4 fragments a pixel (96 bytes) beside the targets,
    // sum and outputs (88 bytes), 0.18 GiB at 1024x1024, where the CPU's estimate is 0.12 GiB.
    let run = |device: &str| {
        defocus(&[
            "--memory-budget",
            "0.15",
            "render",
            "--scene",
            "glass",
            "--method",
            "pinhole",
            "--width",
            "1024",
            "--height",
            "1024",
            "--device",
            device,
            "--out",
            s(&out),
        ])
    };
    let done = run("gpu");
    let err = stderr(&done);
    assert_eq!(done.status.code(), Some(1), "{err}");
    assert!(
        err.contains("GPU rasteriser at 1024x1024") && err.contains("budget"),
        "{err}"
    );
    assert!(!out.exists());
    let done = run("cpu");
    assert!(done.status.success(), "{}", stderr(&done));
}
