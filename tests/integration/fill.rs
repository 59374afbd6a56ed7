//! Tests: `--occlusion fill`, one image decomposed into a near and a filled back layer, so
//! that the post-process methods show what near blur uncovers.

use defocus::image::ColorImage;
use defocus::lens::Camera;
use defocus::methods::fill::{self, FillSettings};
use defocus::methods::reference::{self, ReferenceSettings};
use defocus::methods::registry::{self, Frame, MethodSettings};
use defocus::metrics;
use defocus::scene::{Material, Scene};

use crate::{add_screen_rect, test_camera};

/// The post-process methods that blur one frame.
const METHODS: [&str; 4] = ["hammon", "lowrank", "gaussian", "poisson"];

/// A 96x64 frame (150 mm f/1.4, focus 2 m): a board in focus of vertical stripes 24 px wide,
/// and with `bar`, a dark bar 6 px wide at 1 m (CoC about -11 px) down the middle of one.
fn board(camera: &Camera, bar: bool) -> Scene {
    let mut scene = Scene::default();
    let a = scene.add_material(Material::color("a", [0.8, 0.5, 0.2]));
    let b = scene.add_material(Material::color("b", [0.2, 0.4, 0.7]));
    // Stripes 24 px wide; the bar lies in the middle of one (36 to 60).
    for k in 0..5 {
        let x = -60.0 + 48.0 * k as f32;
        add_screen_rect(&mut scene, camera, (x, -64.0, x + 24.0, 128.0), 2.0, a);
        add_screen_rect(
            &mut scene,
            camera,
            (x + 24.0, -64.0, x + 48.0, 128.0),
            2.0,
            b,
        );
    }
    if bar {
        let dark = scene.add_material(Material::color("bar", [0.02, 0.02, 0.02]));
        add_screen_rect(&mut scene, camera, (45.0, -64.0, 51.0, 128.0), 1.0, dark);
    }
    scene
}

fn camera() -> Camera {
    Camera {
        focal_length_mm: 150.0,
        ..test_camera(96, 64, 2.0, 1.4)
    }
}

/// The anti-aliased pinhole frame of `scene` and its depth at pixel centres.
fn frame_of(scene: &Scene, camera: &Camera) -> (ColorImage, defocus::image::GrayImage) {
    let pin = defocus::methods::pinhole::render(scene, camera, 16, 0, true).unwrap();
    (pin.image, pin.depth.unwrap())
}

#[test]
fn without_near_blur_fill_changes_nothing() {
    let camera = camera();
    let scene = board(&camera, false);
    let (color, depth) = frame_of(&scene, &camera);
    let lens = camera.thin_lens().unwrap();
    let frame = Frame {
        color: &color,
        depth: &depth,
        lens: &lens,
    };
    for id in METHODS {
        let settings = MethodSettings::default_for(id).unwrap();
        let one = registry::run_frame(&settings, &frame).unwrap();
        let two = fill::run_frame(&settings, &frame, &FillSettings::default()).unwrap();
        assert_eq!(one.image, two.image, "{id}");
    }
}

/// Depth of a `w`x`h` frame whose left half is near (1 m, a CoC of about -11 px through
/// [`camera`]) and right half in focus (2 m).
fn half_near_depth(w: usize, h: usize) -> defocus::image::GrayImage {
    defocus::image::GrayImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|i| if i % w < w / 2 { 1.0 } else { 2.0 })
            .collect(),
    )
    .unwrap()
}

#[test]
fn a_constant_frame_stays_constant_with_a_near_layer() {
    let camera = camera();
    let lens = camera.thin_lens().unwrap();
    let (w, h) = (96, 64);
    let color = ColorImage::new(w, h, [0.37, 0.2, 0.6, 1.0]);
    // Left half near (CoC about -11 px), right half in focus.
    let depth = half_near_depth(w, h);
    assert!(lens.coc_px(1.0) < -10.0);
    let frame = Frame {
        color: &color,
        depth: &depth,
        lens: &lens,
    };
    for id in METHODS {
        let out = fill::run_frame(
            &MethodSettings::default_for(id).unwrap(),
            &frame,
            &FillSettings::default(),
        )
        .unwrap();
        for p in out.image.pixels() {
            for (a, b) in p.iter().zip([0.37, 0.2, 0.6, 1.0]) {
                assert!((a - b).abs() < 2e-3, "{id}: {p:?}");
            }
        }
    }
}

/// The board with its near bar, as the bar tests read it: the scene, its camera and lens, the
/// pinhole frame and depth, and `reference` at 256 lens samples.
struct BarScene {
    scene: Scene,
    camera: Camera,
    lens: defocus::lens::ThinLens,
    color: ColorImage,
    depth: defocus::image::GrayImage,
    truth: ColorImage,
}

impl BarScene {
    fn new() -> Self {
        let camera = camera();
        let scene = board(&camera, true);
        let (color, depth) = frame_of(&scene, &camera);
        let lens = camera.thin_lens().unwrap();
        let c = lens.coc_px(1.0);
        assert!(c < -10.0, "setup: {c}");
        let truth = reference::render(
            &scene,
            &camera,
            &ReferenceSettings {
                samples: 256,
                ..Default::default()
            },
            &mut |_, _| {},
        )
        .unwrap()
        .image;
        Self {
            scene,
            camera,
            lens,
            color,
            depth,
            truth,
        }
    }

    fn frame(&self) -> Frame<'_> {
        Frame {
            color: &self.color,
            depth: &self.depth,
            lens: &self.lens,
        }
    }

    /// PSNR of `img` against the truth over the bar's blur: columns 48 +- (3 + |C|), away from
    /// the top and bottom borders.
    fn psnr_over_blur(&self, img: &ColorImage) -> f64 {
        let c = self.lens.coc_px(1.0);
        let (x0, x1) = ((48.0 + c - 3.0) as usize, (48.0 - c + 3.0) as usize);
        let crop = |img: &ColorImage| img.crop(x0, 8, x1 - x0, 48);
        metrics::compare(&crop(img), &crop(&self.truth))
            .unwrap()
            .psnr_db
    }
}

/// Where the near bar's blur turns transparent, the board behind it shows: each method with
/// the fill is closer to `reference` over the bar's blur than without it, by at least 3 dB.
#[test]
fn a_near_bar_reveals_the_board_behind_it() {
    const MARGIN_DB: f64 = 3.0;
    let bar = BarScene::new();
    let frame = bar.frame();
    for id in METHODS {
        let settings = MethodSettings::default_for(id).unwrap();
        let one = registry::run_frame(&settings, &frame).unwrap().image;
        let two = fill::run_frame(&settings, &frame, &FillSettings::default())
            .unwrap()
            .image;
        let (p1, p2) = (bar.psnr_over_blur(&one), bar.psnr_over_blur(&two));
        eprintln!("{id}: none {p1:.2} dB, fill {p2:.2} dB");
        assert!(p2 >= p1 + MARGIN_DB, "{id}: fill {p2} against none {p1}");
    }
}

// ---------------------------------------------------------------------------------------------
// The layered methods on a frame: its fragment lists (one layer, or decomposed and filled).

/// The layered methods that blur a frame through its fragment lists.
const LAYERED: [&str; 2] = ["multilayer", "splat"];

#[test]
fn a_frames_lists_hold_the_frame_and_with_fill_the_filled_back_layer_behind_near_pixels() {
    let camera = camera();
    let scene = board(&camera, true);
    let (color, depth) = frame_of(&scene, &camera);
    let lens = camera.thin_lens().unwrap();
    let frame = Frame {
        color: &color,
        depth: &depth,
        lens: &lens,
    };
    let one = fill::fragment_lists(&frame, None).unwrap();
    assert_eq!(one.len(), 96 * 64);
    for (i, (&z, &c)) in depth.pixels().iter().zip(color.pixels()).enumerate() {
        let (zs, cs) = one.pixel(i % 96, i / 96);
        assert_eq!(zs, [z]);
        let back = defocus::raster::from_half(&cs[0]);
        for k in 0..4 {
            assert!((back[k] - c[k]).abs() <= 1e-3 * c[k].abs().max(1.0), "{i}");
        }
    }
    let two = fill::fragment_lists(&frame, Some(&FillSettings::default())).unwrap();
    // Each bar pixel (at 1 m) holds the bar, then the board (at 2 m) behind it.
    let (zs, _) = two.pixel(48, 30);
    assert_eq!(zs.len(), 2, "{zs:?}");
    assert!(
        (zs[0] - 1.0).abs() < 1e-3 && (zs[1] - 2.0).abs() < 0.05,
        "{zs:?}"
    );
    let (zs, _) = two.pixel(10, 30);
    assert_eq!(zs.len(), 1);
}

#[test]
fn the_layered_methods_on_a_frame_keep_a_constant_image_and_an_in_focus_board() {
    let camera = camera();
    let lens = camera.thin_lens().unwrap();
    let (w, h) = (96, 64);
    let color = ColorImage::new(w, h, [0.37, 0.2, 0.6, 1.0]);
    let depth = half_near_depth(w, h);
    let frame = Frame {
        color: &color,
        depth: &depth,
        lens: &lens,
    };
    for id in LAYERED {
        for occlusion in [fill::Occlusion::None, fill::Occlusion::Fill] {
            let settings = MethodSettings::default_for(id).unwrap();
            let out = fill::run_layered(&settings, &frame, occlusion).unwrap();
            // Away from the borders, which gather nothing beyond the frame. From one layer,
            // the near half's blur turns transparent within its CoC (11 px) of the in-focus
            // half, with nothing behind it: there only the filled frame stays constant.
            let columns: Vec<usize> = match occlusion {
                fill::Occlusion::Fill => (16..80).collect(),
                fill::Occlusion::None => (16..34).chain(62..80).collect(),
            };
            for y in 16..48 {
                for &x in &columns {
                    let p = out.image.get(x, y);
                    for (a, b) in p.iter().zip([0.37, 0.2, 0.6, 1.0]) {
                        assert!((a - b).abs() < 2e-2, "{id} {occlusion:?} ({x}, {y}): {p:?}");
                    }
                }
            }
        }
    }
    // A board wholly in focus comes back as it is.
    let scene = board(&camera, false);
    let (color, depth) = frame_of(&scene, &camera);
    let frame = Frame {
        color: &color,
        depth: &depth,
        lens: &lens,
    };
    for id in LAYERED {
        let settings = MethodSettings::default_for(id).unwrap();
        let out = fill::run_layered(&settings, &frame, fill::Occlusion::Fill).unwrap();
        let psnr = metrics::compare(&out.image, &color).unwrap().psnr_db;
        assert!(psnr > 40.0, "{id}: {psnr} dB");
    }
}

/// With the fill, the layered methods see the board behind the near bar, as they do from the
/// scene: each is at least 3 dB closer to `reference` over the bar's blur than from the frame
/// alone, and within 3 dB of its own render from the scene there.
#[test]
fn the_layered_methods_on_a_filled_frame_reveal_the_board_behind_the_bar() {
    const MARGIN_DB: f64 = 3.0;
    let bar = BarScene::new();
    let frame = bar.frame();
    let psnr = |img: &ColorImage| bar.psnr_over_blur(img);
    for id in LAYERED {
        let settings = MethodSettings::default_for(id).unwrap();
        let one = fill::run_layered(&settings, &frame, fill::Occlusion::None).unwrap();
        let two = fill::run_layered(&settings, &frame, fill::Occlusion::Fill).unwrap();
        let scene_settings = match id {
            "splat" => MethodSettings::Splat(defocus::methods::splat::SplatSettings {
                layers: 2,
                ..Default::default()
            }),
            _ => settings.clone(),
        };
        let options = registry::SceneOptions::default();
        let from_scene = registry::run_scene(
            &scene_settings,
            &bar.scene,
            &bar.camera,
            &options,
            &mut |_, _| {},
        )
        .unwrap();
        let (p1, p2, p3) = (psnr(&one.image), psnr(&two.image), psnr(&from_scene.image));
        eprintln!("{id}: frame {p1:.2} dB, filled frame {p2:.2} dB, scene {p3:.2} dB");
        assert!(p2 >= p1 + MARGIN_DB, "{id}: fill {p2} against none {p1}");
        assert!(
            p2 >= p3 - 3.0,
            "{id}: filled frame {p2} against the scene's {p3}"
        );
    }
}

#[test]
fn blur_runs_the_layered_methods_on_a_frame_and_refuses_multiview_naming_render() {
    use crate::cli::{defocus, s, stderr, temp_dir};
    let dir = temp_dir("blur-layered");
    let camera = camera();
    let scene = board(&camera, true);
    let (color, depth) = frame_of(&scene, &camera);
    let (c, d) = (dir.join("c.exr"), dir.join("d.exr"));
    defocus::image::io::write_color(&c, &color).unwrap();
    defocus::image::io::write_depth_exr(&d, &depth).unwrap();
    let lens = [
        "--focal-length",
        "150",
        "--sensor-width",
        "36",
        "--fstop",
        "1.4",
        "--focus",
        "2",
    ];
    for (method, occlusion) in [
        ("multilayer", "none"),
        ("multilayer", "fill"),
        ("splat", "fill"),
    ] {
        let out = dir.join(format!("{method}-{occlusion}.exr"));
        let mut args = vec![
            "blur",
            "--color",
            s(&c),
            "--depth",
            s(&d),
            "--method",
            method,
        ];
        args.extend_from_slice(&lens);
        args.extend_from_slice(&[
            "--occlusion",
            occlusion,
            "--timings",
            "json",
            "--out",
            s(&out),
        ]);
        let done = defocus(&args);
        assert!(
            done.status.success(),
            "{method} {occlusion}: {}",
            stderr(&done)
        );
        let json: serde_json::Value = serde_json::from_slice(&done.stdout).unwrap();
        let names: Vec<&str> = json["passes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["name"].as_str().unwrap())
            .collect();
        assert!(names.contains(&"fill/decompose"), "{names:?}");
        assert!(
            names.iter().any(|n| n.starts_with(&format!("{method}/"))),
            "{names:?}"
        );
        assert!(out.exists());
    }
    let out = dir.join("multiview.exr");
    let mut args = vec![
        "blur",
        "--color",
        s(&c),
        "--depth",
        s(&d),
        "--method",
        "multiview",
    ];
    args.extend_from_slice(&["--out", s(&out)]);
    let done = defocus(&args);
    assert!(!done.status.success());
    assert!(
        stderr(&done).contains("defocus render"),
        "{}",
        stderr(&done)
    );
    assert!(!out.exists());
}
