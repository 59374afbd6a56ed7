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

#[test]
fn a_constant_frame_stays_constant_with_a_near_layer() {
    let camera = camera();
    let lens = camera.thin_lens().unwrap();
    let (w, h) = (96, 64);
    let color = ColorImage::new(w, h, [0.37, 0.2, 0.6, 1.0]);
    // Left half near (CoC about -11 px), right half in focus.
    let depth = defocus::image::GrayImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|i| if i % w < w / 2 { 1.0 } else { 2.0 })
            .collect(),
    )
    .unwrap();
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

/// Where the near bar's blur turns transparent, the board behind it shows: each method with
/// the fill is closer to `reference` over the bar's blur than without it, by at least 3 dB.
#[test]
fn a_near_bar_reveals_the_board_behind_it() {
    const MARGIN_DB: f64 = 3.0;
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
    // The bar's blur: columns 48 +- (3 + |C|), away from the top and bottom borders.
    let (x0, x1) = ((48.0 + c - 3.0) as usize, (48.0 - c + 3.0) as usize);
    let crop = |img: &ColorImage| img.crop(x0, 8, x1 - x0, 48);
    let frame = Frame {
        color: &color,
        depth: &depth,
        lens: &lens,
    };
    for id in METHODS {
        let settings = MethodSettings::default_for(id).unwrap();
        let one = registry::run_frame(&settings, &frame).unwrap().image;
        let two = fill::run_frame(&settings, &frame, &FillSettings::default())
            .unwrap()
            .image;
        let p1 = metrics::compare(&crop(&one), &crop(&truth))
            .unwrap()
            .psnr_db;
        let p2 = metrics::compare(&crop(&two), &crop(&truth))
            .unwrap()
            .psnr_db;
        eprintln!("{id}: none {p1:.2} dB, fill {p2:.2} dB");
        assert!(p2 >= p1 + MARGIN_DB, "{id}: fill {p2} against none {p1}");
    }
}
