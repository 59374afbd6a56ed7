//! Behaviour tests of defocus: one binary, one module per area.

mod budgets;
mod cli;
mod cli_post;
mod docs;
mod fill;
mod fuzz;
mod gpu;
mod gpu_gather;
mod gpu_layered;
mod gpu_raster;
mod hammon;
mod highlights;
mod image_io;
mod jobs;
mod layered;
mod lens;
mod lens_effects;
mod lowrank;
mod metrics;
mod multilayer;
mod multiview;
mod raster;
mod reference;
mod registry;
mod reliability;
mod report;
mod scene_files;
mod scenes;
mod sequences;
mod splat;
mod untrusted;

/// Path of the shared assets folder, or `None` (with a printed reason) when it is absent.
pub fn shared_assets() -> Option<std::path::PathBuf> {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipped: ../shared/assets is absent");
        None
    }
}

/// Runs `f` in a fresh rayon pool of `threads` threads (for tests that the output does not
/// depend on the thread count).
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("a thread pool")
        .install(f)
}

/// A camera at the origin looking down -Z: 50 mm on a 36 mm sensor, `w`x`h` pixels.
pub fn test_camera(w: usize, h: usize, focus_m: f32, fstop: f32) -> defocus::lens::Camera {
    defocus::lens::Camera {
        width_px: w,
        height_px: h,
        camera_from_world: glam::Affine3A::IDENTITY,
        focal_length_mm: 50.0,
        sensor_width_mm: 36.0,
        fstop,
        focus_m,
        near_m: 0.05,
        far_m: 1000.0,
        yfov_rad: None,
    }
}

/// Adds a camera-facing rectangle at depth `z_m` covering the raster box `[x0, x1) x [y0, y1)`
/// of `camera`'s pinhole image, with material `material`.
pub fn add_screen_rect(
    scene: &mut defocus::scene::Scene,
    camera: &defocus::lens::Camera,
    (x0, y0, x1, y1): (f32, f32, f32, f32),
    z_m: f32,
    material: usize,
) {
    let lens = camera.thin_lens().unwrap();
    let (cx, cy) = lens.centre_px();
    let to_world = |x: f32, y: f32| {
        glam::Vec3::new(
            (x - cx) * z_m / lens.f_px,
            -(y - cy) * z_m / lens.f_px,
            -z_m,
        )
    };
    let mut mesh = defocus::scene::Mesh {
        material,
        ..Default::default()
    };
    let p0 = to_world(x0, y0);
    mesh.push_quad(p0, to_world(x1, y0) - p0, to_world(x0, y1) - p0);
    scene.meshes.push(mesh);
}

/// A 96x64 frame (50 mm, f/1, focus 2 m) of a grey board in focus filling it, an opaque
/// orange square `square` (pixels) 2.8 px of CoC in front of it, and, with `wall_coc`, a dark
/// wall filling the frame behind the board at that CoC; with `reference` at 512 lens samples
/// of it.
pub fn square_before_board(
    square: (f32, f32, f32, f32),
    wall_coc: Option<f32>,
) -> (
    defocus::scene::Scene,
    defocus::lens::Camera,
    defocus::image::ColorImage,
) {
    use defocus::scene::Material;
    let camera = test_camera(96, 64, 2.0, 1.0);
    let lens = camera.thin_lens().unwrap();
    let mut scene = defocus::scene::Scene::default();
    let (w, h) = (camera.width_px as f32, camera.height_px as f32);
    let whole = (-w, -h, 2.0 * w, 2.0 * h);
    let board = scene.add_material(Material::color("board", [0.8, 0.8, 0.8]));
    if let Some(c) = wall_coc {
        let wall = scene.add_material(Material::color("wall", [0.02, 0.02, 0.05]));
        add_screen_rect(&mut scene, &camera, whole, lens.depth_for_coc_px(c), wall);
    }
    let orange = scene.add_material(Material::color("square", [0.9, 0.3, 0.1]));
    add_screen_rect(&mut scene, &camera, whole, camera.focus_m, board);
    add_screen_rect(
        &mut scene,
        &camera,
        square,
        lens.depth_for_coc_px(-2.8),
        orange,
    );
    let truth = defocus::methods::reference::render(
        &scene,
        &camera,
        &defocus::methods::reference::ReferenceSettings {
            samples: 512,
            ..Default::default()
        },
        &mut |_, _| {},
    )
    .unwrap()
    .image;
    (scene, camera, truth)
}

/// A long-lens camera (150 mm, f/1.4, focus 1 m) on a `size`x`size` image and a small very
/// bright square (2x2 px, emission 1000) at `z_m` on its centre: a point light whose bokeh is
/// tens of pixels wide. Returns the scene, the camera and the light's signed CoC in pixels.
pub fn point_light(size: usize, z_m: f32) -> (defocus::scene::Scene, defocus::lens::Camera, f32) {
    let camera = defocus::lens::Camera {
        focal_length_mm: 150.0,
        ..test_camera(size, size, 1.0, 1.4)
    };
    let coc = camera.thin_lens().unwrap().coc_px(z_m);
    let mut scene = defocus::scene::Scene::default();
    let m = scene.add_material(defocus::scene::Material::emissive(
        "light", [1.0; 3], 1000.0,
    ));
    let c = size as f32 / 2.0;
    add_screen_rect(
        &mut scene,
        &camera,
        (c - 1.0, c - 1.0, c + 1.0, c + 1.0),
        z_m,
        m,
    );
    (scene, camera, coc)
}

/// A built-in scene at 640x360 with its pinhole frame (colour, depth) and its ground truth
/// (`reference`, 256 lens samples, the scene's aperture), rendered once per test run.
pub struct GroundTruth {
    /// The scene's default aperture.
    pub aperture: defocus::lens::Aperture,
    /// The thin lens of the scene's camera at 640x360.
    pub lens: defocus::lens::ThinLens,
    /// Pinhole colour at pixel centres.
    pub pinhole: defocus::image::ColorImage,
    /// Pinhole view-axis depth in metres.
    pub depth: defocus::image::GrayImage,
    /// The reference image.
    pub truth: defocus::image::ColorImage,
}

/// The [`GroundTruth`] of built-in scene `name` ("lights" or "railing").
pub fn ground_truth(name: &str) -> &'static GroundTruth {
    use std::sync::OnceLock;
    static LIGHTS: OnceLock<GroundTruth> = OnceLock::new();
    static RAILING: OnceLock<GroundTruth> = OnceLock::new();
    let cell = match name {
        "lights" => &LIGHTS,
        "railing" => &RAILING,
        other => panic!("no ground truth for {other}"),
    };
    cell.get_or_init(|| {
        use defocus::methods::{pinhole, reference};
        let scene = defocus::scene::builtin::load(name).unwrap();
        let defaults = scene.defaults.clone().unwrap();
        let mut camera = defaults.camera.clone();
        camera.width_px = 640;
        camera.height_px = 360;
        let pin = pinhole::render(&scene, &camera, 1, 0, true).unwrap();
        let truth = reference::render(
            &scene,
            &camera,
            &reference::ReferenceSettings {
                samples: 256,
                aperture: defaults.aperture.clone(),
                ..Default::default()
            },
            &mut |_, _| {},
        )
        .unwrap();
        GroundTruth {
            aperture: defaults.aperture,
            lens: camera.thin_lens().unwrap(),
            pinhole: pin.image,
            depth: pin.depth.unwrap(),
            truth: truth.image,
        }
    })
}
