//! Tests: the input of the layered methods (`multilayer`, `splat --layers N`, `multiview`):
//! fragments and layers carry their coverage of the pixel, the frame is rasterized with a guard
//! band, and see-through surfaces stay see-through; each checked against `reference` or a
//! supersampled pinhole frame on scenes where the answer is known.

use defocus::image::ColorImage;
use defocus::lens::{Aperture, Camera};
use defocus::methods::multilayer::{self, MultilayerSettings};
use defocus::methods::multiview::{self, MultiviewSettings};
use defocus::methods::pinhole;
use defocus::methods::reference::{self, ReferenceSettings};
use defocus::methods::splat::{self, SplatSettings};
use defocus::scene::{AlphaMode, Material, Mesh, Scene};
use glam::Vec3;

use crate::{add_screen_rect, test_camera};

/// `scene`'s fragment lists through `camera`'s pinhole view, at most `cap` a pixel, sampled as
/// `input` says, without a guard band.
fn pinhole_lists(
    scene: &Scene,
    camera: &Camera,
    cap: usize,
    input: defocus::raster::LayeredInput,
) -> defocus::raster::FragmentLists {
    use defocus::raster::{render_fragment_lists, PreparedScene, View};
    let prepared = PreparedScene::new(scene, &camera.camera_from_world).unwrap();
    let view = View::pinhole(camera.thin_lens().unwrap());
    render_fragment_lists(&prepared, &view, cap, input, None).unwrap()
}

/// The three layered methods at the settings the issue measures (multiview with 64 rays).
fn layered(scene: &Scene, camera: &Camera, aperture: &Aperture) -> Vec<(&'static str, ColorImage)> {
    layered_with(
        scene,
        camera,
        aperture,
        MultilayerSettings::default().highlights,
        64,
    )
}

/// The three layered methods at their defaults but for `aperture`, the highlight threshold
/// `highlights` and `multiview`'s `rays` (`splat` with 4 layers).
fn layered_with(
    scene: &Scene,
    camera: &Camera,
    aperture: &Aperture,
    highlights: Option<f32>,
    rays: usize,
) -> Vec<(&'static str, ColorImage)> {
    let ml = multilayer::render(
        scene,
        camera,
        &MultilayerSettings {
            aperture: aperture.clone(),
            highlights,
            ..MultilayerSettings::default()
        },
    )
    .unwrap();
    let mv = multiview::render(
        scene,
        camera,
        &MultiviewSettings {
            aperture: aperture.clone(),
            samples: rays,
            highlights,
            ..MultiviewSettings::default()
        },
    )
    .unwrap();
    vec![
        ("multilayer", ml.image),
        ("splat", splat4(scene, camera, aperture, highlights)),
        ("multiview", mv.image),
    ]
}

/// `splat --layers 4` with `aperture` and the highlight threshold `highlights`.
fn splat4(
    scene: &Scene,
    camera: &Camera,
    aperture: &Aperture,
    highlights: Option<f32>,
) -> ColorImage {
    let (sp, _) = splat::render_scene(
        scene,
        camera,
        &SplatSettings {
            aperture: aperture.clone(),
            layers: 4,
            highlights,
            ..SplatSettings::default()
        },
    )
    .unwrap();
    sp.image
}

fn reference_image(
    scene: &Scene,
    camera: &Camera,
    aperture: &Aperture,
    samples: usize,
) -> ColorImage {
    reference::render(
        scene,
        camera,
        &ReferenceSettings {
            samples,
            aperture: aperture.clone(),
            ..ReferenceSettings::default()
        },
        &mut |_, _| {},
    )
    .unwrap()
    .image
}

/// Mean absolute difference of the red channel over the pixels `(x, y)` with `keep(x, y)`.
fn mean_abs_red(a: &ColorImage, b: &ColorImage, keep: impl Fn(usize, usize) -> bool) -> f32 {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for y in 0..a.height() {
        for x in 0..a.width() {
            if keep(x, y) {
                sum += (a.get(x, y)[0] - b.get(x, y)[0]).abs() as f64;
                n += 1;
            }
        }
    }
    (sum / n.max(1) as f64) as f32
}

/// A white square turned 7 degrees, edges at sub-pixel places, on a black wall just behind it,
/// both in focus at f/16 (CoC under a tenth of a pixel).
fn turned_square(camera: &Camera) -> Scene {
    let lens = camera.thin_lens().unwrap();
    let mut scene = Scene::default();
    let white = scene.add_material(Material::color("white", [1.0, 1.0, 1.0]));
    let black = scene.add_material(Material::color("black", [0.0, 0.0, 0.0]));
    let z = camera.focus_m;
    let (w, h) = (camera.width_px as f32, camera.height_px as f32);
    add_screen_rect(
        &mut scene,
        camera,
        (-10.0, -10.0, w + 10.0, h + 10.0),
        z * 1.01,
        black,
    );
    let (cx, cy) = lens.centre_px();
    let to_world =
        |x: f32, y: f32| Vec3::new((x - cx) * z / lens.f_px, -(y - cy) * z / lens.f_px, -z);
    let (s, c) = 7f32.to_radians().sin_cos();
    let half = 0.3 * h;
    let corner = |u: f32, v: f32| to_world(cx + 0.37 + u * c - v * s, cy + 0.21 + u * s + v * c);
    let mut mesh = Mesh {
        material: white,
        ..Mesh::default()
    };
    let p0 = corner(-half, -half);
    mesh.push_quad(p0, corner(half, -half) - p0, corner(-half, half) - p0);
    scene.meshes.push(mesh);
    scene
}

#[test]
fn in_focus_edges_resolve_as_in_a_supersampled_frame() {
    let camera = test_camera(64, 48, 2.0, 16.0);
    let scene = turned_square(&camera);
    let aa = pinhole::render(&scene, &camera, 256, 0, false)
        .unwrap()
        .image;
    let centres = pinhole::render(&scene, &camera, 1, 0, false).unwrap().image;
    // Only pixels the edges cross (neither black nor white in the 256-sample frame) count.
    let edge = |x: usize, y: usize| {
        let v = aa.get(x, y)[0];
        v > 0.02 && v < 0.98
    };
    let aliased = mean_abs_red(&centres, &aa, edge);
    // Sampled at pixel centres an edge pixel is off by about a quarter on average.
    assert!(aliased > 0.15, "setup: centre-sampled error {aliased}");
    for (name, image) in layered(&scene, &camera, &Aperture::Disc) {
        let err = mean_abs_red(&image, &aa, edge);
        // 16 n-rooks samples put an edge within 1/16 to 3/16 of its area (see the raster
        // unit tests); on average far less.
        assert!(
            err < 0.05,
            "{name}: mean error {err} on edge pixels (centres: {aliased})"
        );
    }
}

#[test]
fn a_pane_over_a_wall_shows_the_wall_through_it_in_every_layered_method() {
    // A 40% red pane at 1.2 m over a blue wall at 2 m, focus 2 m, f/8: the pane is blurred by
    // about 2 px, so its middle is 0.4 red over 0.6 blue, as in `reference`.
    let camera = test_camera(64, 48, 2.0, 8.0);
    let mut scene = Scene::default();
    let blue = scene.add_material(Material::color("blue", [0.0, 0.0, 1.0]));
    let mut pane = Material::color("pane", [1.0, 0.0, 0.0]);
    pane.base_color[3] = 0.4;
    pane.alpha_mode = AlphaMode::Blend;
    let pane = scene.add_material(pane);
    add_screen_rect(&mut scene, &camera, (-20.0, -20.0, 84.0, 68.0), 2.0, blue);
    add_screen_rect(&mut scene, &camera, (16.0, 12.0, 48.0, 36.0), 1.2, pane);
    let truth = reference_image(&scene, &camera, &Aperture::Disc, 256);
    let middle = truth.get(32, 24);
    assert!(
        (middle[0] - 0.4).abs() < 0.02 && (middle[2] - 0.6).abs() < 0.02,
        "setup: {middle:?}"
    );
    for (name, image) in layered(&scene, &camera, &Aperture::Disc) {
        for (x, y) in [(32, 24), (24, 18), (40, 30)] {
            let (p, q) = (image.get(x, y), truth.get(x, y));
            for k in 0..3 {
                assert!(
                    (p[k] - q[k]).abs() < 0.03,
                    "{name} ({x}, {y}): {p:?} vs {q:?}"
                );
            }
        }
    }
}

#[test]
fn a_blurred_bar_just_outside_the_frame_darkens_its_border_as_in_reference() {
    // A black bar at 0.6 m lies wholly left of the frame; focus 1.5 m on a white wall. Its blur
    // (CoC about 13 px, within the guard band's cap of 1/8 of the frame's width) reaches into
    // the frame's left columns in `reference`'s views; without a guard band the layered
    // methods would not see it at all.
    let camera = Camera {
        focal_length_mm: 100.0,
        ..test_camera(128, 48, 1.5, 1.4)
    };
    let lens = camera.thin_lens().unwrap();
    let coc = lens.coc_px(0.6).abs();
    assert!(coc > 8.0 && coc < 16.0, "setup: |C| = {coc}");
    let mut scene = Scene::default();
    let white = scene.add_material(Material::color("white", [1.0, 1.0, 1.0]));
    let black = scene.add_material(Material::color("black", [0.0, 0.0, 0.0]));
    add_screen_rect(&mut scene, &camera, (-40.0, -40.0, 168.0, 88.0), 1.5, white);
    add_screen_rect(&mut scene, &camera, (-30.0, -40.0, -2.0, 88.0), 0.6, black);
    let truth = reference_image(&scene, &camera, &Aperture::Disc, 256);
    // In `reference` the first column is visibly darkened.
    let first = truth.get(0, 24)[0];
    assert!(first < 0.8, "setup: first column {first}");
    let band = |x: usize, _y: usize| x < coc as usize;
    for (name, image) in layered(&scene, &camera, &Aperture::Disc) {
        let err = mean_abs_red(&image, &truth, band);
        assert!(err < 0.04, "{name}: border band off by {err} on average");
    }
}

/// The lit pixels of a bokeh centred in a `size`x`size` image of radius about `radius` px: after
/// a 3x3 box (which evens out the noise of `reference`'s few samples per pixel), at least half
/// the level of its middle (the pixels within half the radius of the centre).
fn lit(img: &ColorImage, size: usize, radius: f32) -> Vec<bool> {
    let v = |x: usize, y: usize| img.get(x, y)[0];
    let smooth: Vec<f32> = (0..size * size)
        .map(|i| {
            let (x, y) = (i % size, i / size);
            let mut s = 0.0;
            for dy in -1i32..=1 {
                for dx in -1i32..=1 {
                    let xx = (x as i32 + dx).clamp(0, size as i32 - 1) as usize;
                    let yy = (y as i32 + dy).clamp(0, size as i32 - 1) as usize;
                    s += v(xx, yy);
                }
            }
            s / 9.0
        })
        .collect();
    let c = size as f32 / 2.0;
    let middle: Vec<f32> = (0..size * size)
        .filter(|&i| {
            let (dx, dy) = ((i % size) as f32 + 0.5 - c, (i / size) as f32 + 0.5 - c);
            dx.hypot(dy) < 0.5 * radius
        })
        .map(|i| smooth[i])
        .collect();
    let level = middle.iter().sum::<f32>() / middle.len() as f32;
    smooth.iter().map(|&s| s > 0.5 * level).collect()
}

#[test]
fn point_light_becomes_the_aperture_shape_in_splat_and_multiview_as_in_reference() {
    let size = 96;
    let (scene, camera, coc) = crate::point_light(size, 50.0);
    assert!(coc > 15.0, "setup: C = {coc}");
    for aperture in [
        Aperture::Disc,
        Aperture::Polygon {
            blades: 6,
            rotation_rad: 0.0,
            blade_radius: None,
        },
        Aperture::Polygon {
            blades: 5,
            rotation_rad: 0.4,
            blade_radius: None,
        },
    ] {
        let truth = lit(
            &reference_image(&scene, &camera, &aperture, 2048),
            size,
            coc,
        );
        // The light is brighter than white: by default a highlight, scattered with its rays'
        // visibility; `--highlight-rays off` blends it as every fragment.
        let sp = splat4(
            &scene,
            &camera,
            &aperture,
            SplatSettings::default().highlights,
        );
        let sp_blended = splat4(&scene, &camera, &aperture, None);
        let mv = multiview::render(
            &scene,
            &camera,
            &MultiviewSettings {
                aperture: aperture.clone(),
                samples: 1024,
                cone: false,
                jitter: false,
                ..MultiviewSettings::default()
            },
        )
        .unwrap();
        for (name, image) in [
            ("splat", sp),
            ("splat --highlight-rays off", sp_blended),
            ("multiview", mv.image),
        ] {
            let ours = lit(&image, size, coc);
            let both = ours.iter().zip(&truth).filter(|(a, b)| **a && **b).count();
            let either = ours.iter().zip(&truth).filter(|(a, b)| **a || **b).count();
            let iou = both as f32 / either as f32;
            let count = |m: &[bool]| m.iter().filter(|&&b| b).count();
            let w = |m: &[bool]| (0..size).filter(|&x| m[size / 2 * size + x]).count();
            eprintln!(
                "{name} {aperture:?}: IoU {iou}, lit {} vs reference {}, width {} vs {} (|C| {coc})",
                count(&ours),
                count(&truth),
                w(&ours),
                w(&truth)
            );

            // A shape of radius |C| = 21 px: a pixel of difference all round its outline is an
            // IoU of about 0.9; a square, or a pentagon turned the wrong way (0.7), far below.
            assert!(
                iou > 0.9,
                "{name} {aperture:?}: IoU {iou} with reference's bokeh"
            );
            // The width through the centre row: the diameter 2|C| for the disc.
            if aperture == Aperture::Disc {
                let width = (0..size).filter(|&x| ours[size / 2 * size + x]).count() as f32;
                assert!(
                    (width - 2.0 * coc).abs() <= 2.0,
                    "{name}: width {width} vs 2|C| = {}",
                    2.0 * coc
                );
            }
        }
    }
}

/// The front and back of a thin closed object (two dark cards 1 cm apart, less than a pixel of
/// CoC between them, as the two sides of a double-sided bar) in front of a white board, its
/// left edge halfway across pixel 16: the lists resolve the two sides by their coverage masks.
/// The back card takes no slot where the front hides all its samples (with two slots the board
/// behind stays in the list), and at the edge the composite is the share of the pixel the
/// object leaves free, as in an anti-aliased frame, not darkened by the back side a second time.
#[test]
fn the_back_of_a_thin_object_neither_darkens_its_edge_nor_crowds_out_what_lies_behind() {
    use defocus::raster::{from_half, LayeredInput, COINCIDENT_COC_PX};
    // A long lens, so that the board lies pixels of CoC behind the object.
    let camera = Camera {
        focal_length_mm: 200.0,
        ..test_camera(64, 64, 3.0, 1.4)
    };
    let lens = camera.thin_lens().unwrap();
    assert!(
        (lens.coc_px(1.50) - lens.coc_px(1.51)).abs() < COINCIDENT_COC_PX,
        "the two sides must be closer in CoC than the threshold"
    );
    assert!((lens.coc_px(1.51) - lens.coc_px(3.0)).abs() > COINCIDENT_COC_PX);
    let mut scene = Scene::default();
    let dark = scene.add_material(Material::color("dark", [0.0; 3]));
    let white = scene.add_material(Material::color("white", [1.0; 3]));
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 64.0, 64.0), 3.0, white);
    // Back side first, as a mesh may list it.
    add_screen_rect(&mut scene, &camera, (16.5, 8.0, 48.0, 56.0), 1.51, dark);
    add_screen_rect(&mut scene, &camera, (16.5, 8.0, 48.0, 56.0), 1.50, dark);
    let lists = pinhole_lists(&scene, &camera, 2, LayeredInput::default());
    // Inside the object: its front, then the board (the back side hidden at every sample).
    let (depths, colors) = lists.pixel(32, 32);
    assert_eq!(depths.len(), 2, "{depths:?}");
    assert!(
        (depths[0] - 1.50).abs() < 1e-3 && (depths[1] - 3.0).abs() < 1e-3,
        "{depths:?}"
    );
    assert!((from_half(&colors[1])[3] - 1.0).abs() < 1e-3);
    // At the edge: over-compositing the list gives the uncovered share of white (one half,
    // to within the 16 samples' quantisation).
    let (depths, colors) = lists.pixel(16, 32);
    let (mut out, mut transmit) = (0.0f32, 1.0f32);
    for c in colors {
        let c = from_half(c);
        out += transmit * c[0];
        transmit *= 1.0 - c[3];
    }
    assert!(
        (out - 0.5).abs() <= 1.0 / 16.0 + 1e-3,
        "edge {out}, list {depths:?}"
    );
    // Without coverage masks (the papers' input) the back side is a layer of its own.
    let plain = pinhole_lists(&scene, &camera, 2, LayeredInput::PAPER);
    let (depths, _) = plain.pixel(32, 32);
    assert!((depths[1] - 1.51).abs() < 1e-3, "{depths:?}");
}

/// The inside of a closed double-sided mesh: behind an opaque card seen from its front, a card
/// seen from its back 4% of the depth further (2 px of CoC, more than
/// [`defocus::raster::COINCIDENT_COC_PX`]: a thicker bar, or a thin one at a higher resolution)
/// takes no slot, so with two slots the board behind stays in the list. A second card seen from
/// its front at the same distance is a surface a blur can show, and keeps its slot.
#[test]
fn the_inside_of_a_closed_mesh_takes_no_slot() {
    use defocus::raster::{LayeredInput, COINCIDENT_COC_PX};
    let camera = Camera {
        focal_length_mm: 200.0,
        ..test_camera(64, 64, 3.0, 1.4)
    };
    let lens = camera.thin_lens().unwrap();
    assert!((lens.coc_px(0.50) - lens.coc_px(0.52)).abs() > COINCIDENT_COC_PX);
    let lists_with = |back_facing: bool| {
        let mut scene = Scene::default();
        let dark = scene.add_material(Material::color("dark", [0.0; 3]));
        let white = scene.add_material(Material::color("white", [1.0; 3]));
        add_screen_rect(&mut scene, &camera, (0.0, 0.0, 64.0, 64.0), 3.0, white);
        add_screen_rect(&mut scene, &camera, (16.0, 8.0, 48.0, 56.0), 0.50, dark);
        add_screen_rect(&mut scene, &camera, (16.0, 8.0, 48.0, 56.0), 0.52, dark);
        // `add_screen_rect`'s quads face away from the view (seen from their back, as the
        // material is double-sided): turn the near card, and the far one unless it is to be
        // seen from its back.
        let turned = if back_facing { 1 } else { 2 };
        for mesh in scene.meshes.iter_mut().skip(1).take(turned) {
            for t in &mut mesh.indices {
                t.swap(1, 2);
            }
        }
        pinhole_lists(&scene, &camera, 2, LayeredInput::default())
    };
    let inside = lists_with(true);
    let (depths, _) = inside.pixel(32, 32);
    assert!(
        depths.len() == 2 && (depths[0] - 0.50).abs() < 1e-3 && (depths[1] - 3.0).abs() < 1e-3,
        "{depths:?}"
    );
    let two_cards = lists_with(false);
    let (depths, _) = two_cards.pixel(32, 32);
    assert!(
        depths.len() == 2 && (depths[1] - 0.52).abs() < 1e-3,
        "{depths:?}"
    );
}

/// A light far behind focus (CoC +21 px) hidden in the pinhole view behind a near opaque bar
/// (CoC -14 px) that covers part of the lens from every pixel of the light's bokeh: through the
/// lens the bar's shadow crosses the disc as a dark stripe (`reference`). `multilayer`, `splat
/// --layers 4` and `multiview` scatter the light as a highlight, each pixel of its bokeh with
/// the visibility of its one lens ray past the bar, and draw the stripe; blended as every
/// fragment (`--highlight-rays off`) the first two only dim the whole disc.
#[test]
fn a_near_bar_draws_its_shadow_across_the_bokeh_of_a_light_behind_it() {
    let size = 96;
    let (mut scene, camera, coc) = crate::point_light(size, 50.0);
    let lens = camera.thin_lens().unwrap();
    let z_bar = 0.6;
    let c_bar = lens.coc_px(z_bar);
    assert!(coc > 20.0 && c_bar < -13.0, "setup: C {coc}, bar {c_bar}");
    let bar = scene.add_material(Material::color("bar", [0.02, 0.02, 0.02]));
    let c = size as f32 / 2.0;
    // The bar covers pinhole columns c - 2 to c + 12, the light (at c) among them.
    let (x0, x1) = (c - 2.0, c + 12.0);
    add_screen_rect(
        &mut scene,
        &camera,
        (x0, -(size as f32), x1, 2.0 * size as f32),
        z_bar,
        bar,
    );
    let truth = reference_image(&scene, &camera, &Aperture::Disc, 2048);
    // The ray of disc pixel p sees the light through lens point u = (p - c) / C and passes the
    // bar's depth over c + (C - C_bar) u: the shadow is the disc's pixels whose ray falls on the
    // bar, columns c + C (x0 - c) / (C - C_bar) to c + C (x1 - c) / (C - C_bar).
    let t = coc - c_bar;
    let (s0, s1) = (c + coc * (x0 - c) / t, c + coc * (x1 - c) / t);
    let in_disc = |x: usize, y: usize| {
        let d = glam::Vec2::new(x as f32 + 0.5 - c, y as f32 + 0.5 - c);
        d.length() < coc - 2.0
    };
    let px = |x: usize| x as f32 + 0.5;
    let shadow = |x: usize, y: usize| in_disc(x, y) && px(x) > s0 + 1.0 && px(x) < s1 - 1.0;
    let lit = |x: usize, y: usize| in_disc(x, y) && (px(x) < s0 - 1.0 || px(x) > s1 + 1.0);
    let mean = |img: &ColorImage, keep: &dyn Fn(usize, usize) -> bool| {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for y in 0..size {
            for x in 0..size {
                if keep(x, y) {
                    sum += img.get(x, y)[0] as f64;
                    n += 1;
                }
            }
        }
        assert!(n > 10, "setup: {n} pixels");
        sum / n as f64
    };
    let (lit_truth, dark_truth) = (mean(&truth, &lit), mean(&truth, &shadow));
    assert!(
        dark_truth < 0.05 * lit_truth,
        "reference: {dark_truth} vs {lit_truth}"
    );
    for highlights in [Some(1.0), None] {
        let mut images = layered_with(&scene, &camera, &Aperture::Disc, highlights, 32);
        if highlights.is_none() {
            // Traced, its 32 rays meet the small light too seldom for the columns to compare.
            images.retain(|(name, _)| *name != "multiview");
        }
        for (name, img) in images {
            let (l, d) = (mean(&img, &lit), mean(&img, &shadow));
            // Column by column over the disc (`reference`'s pixels are noisy: a few of its
            // 2048 views light each one), the largest difference of the column means.
            let error = (0..size)
                .filter(|&x| (px(x) - c).abs() < coc - 6.0)
                .map(|x0| {
                    let column = |x: usize, y: usize| x == x0 && in_disc(x, y);
                    (mean(&img, &column) - mean(&truth, &column)).abs()
                })
                .fold(0.0f64, f64::max);
            eprintln!(
                "{name} highlights {highlights:?}: lit {l:.3} shadow {d:.3} (reference {lit_truth:.3} {dark_truth:.3}), columns within {error:.3}"
            );
            if highlights.is_some() {
                // The stripe as dark as in `reference`, the rest of the disc as bright, and
                // every column of the disc within 15% of the disc's brightness of
                // `reference`'s (where the stripe's edges fall).
                assert!(d < 0.05 * l, "{name}: shadow {d} vs lit {l}");
                assert!(
                    (l / lit_truth - 1.0).abs() < 0.1,
                    "{name}: lit {l} vs {lit_truth}"
                );
                assert!(error < 0.15 * lit_truth, "{name}: columns within {error}");
            } else {
                // Blended, the bar dims the whole disc evenly: no stripe.
                assert!(
                    d > 0.5 * l,
                    "{name}: shadow {d} vs lit {l} without highlights"
                );
            }
        }
    }
}

/// A screen-filling texture minified four times along one screen axis and magnified twice
/// along the other (stripes across the magnified axis, half a texel a pixel there, four texel
/// rows a pixel down), at `z_m` metres with the focus at `focus_m` (f/1, 64x64): the worst
/// error of the layered input's colours against the texture's bilinear reconstruction averaged
/// over each pixel, with per-sample lookups (`LayeredInput::SAMPLE_SHADED`) and with one lookup
/// a quadrant (the default), and whether the two inputs are the same bit for bit.
fn minified_stripes(focus_m: f32, z_m: f32) -> (f32, f32, bool) {
    use defocus::raster::{from_half, LayeredInput};
    use defocus::scene::{Texture, TextureBinding};
    let (columns, rows) = (32usize, 256usize);
    let stripe = |c: usize| ((c / 5) % 2) as f32;
    let texels = (0..columns * rows)
        .map(|i| {
            let v = stripe(i % columns);
            [v, v, v, 1.0]
        })
        .collect();
    let camera = test_camera(64, 64, focus_m, 1.0);
    let mut scene = Scene::default();
    let t = scene.add_texture(Texture::new(
        ColorImage::from_vec(columns, rows, texels).unwrap(),
    ));
    let striped = scene.add_material(Material {
        name: "stripes".into(),
        base_color_texture: Some(TextureBinding {
            texture: t,
            sampler: Default::default(),
            uv_transform: Default::default(),
        }),
        ..Default::default()
    });
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 64.0, 64.0), z_m, striped);
    // The bilinear reconstruction across the stripes at `u` texels (texel centres at c + 0.5),
    // and its mean over pixel x (half a texel), from 64 points.
    let bilinear = |u: f32| {
        let f = u - 0.5;
        let c = f.floor();
        let t = f - c;
        let at = |c: f32| stripe(c.clamp(0.0, columns as f32 - 1.0) as usize);
        at(c) * (1.0 - t) + at(c + 1.0) * t
    };
    let truth = |x: usize| {
        (0..64)
            .map(|k| bilinear((x as f32 + (k as f32 + 0.5) / 64.0) / 2.0))
            .sum::<f32>()
            / 64.0
    };
    let lists = |input: LayeredInput| {
        let lists = pinhole_lists(&scene, &camera, 2, input);
        let colors: Vec<f32> = (0..64 * 64)
            .map(|i| from_half(&lists.pixel(i % 64, i / 64).1[0])[0])
            .collect();
        colors
    };
    let worst = |colors: &[f32]| {
        let mut worst = 0.0f32;
        for y in 2..62 {
            for x in 8..56 {
                worst = worst.max((colors[y * 64 + x] - truth(x)).abs());
            }
        }
        worst
    };
    let (sampled, quadrants) = (
        lists(LayeredInput::SAMPLE_SHADED),
        lists(LayeredInput::default()),
    );
    let same = sampled
        .iter()
        .zip(&quadrants)
        .all(|(a, b)| a.to_bits() == b.to_bits());
    (worst(&sampled), worst(&quadrants), same)
}

/// In focus, each pixel of the layered input is the mean of the texture over the pixel, as
/// `reference`'s many views average it (`multiview`'s input, [`minified_stripes`]). One lookup
/// a quadrant (`--texture-lookups quadrant`, `multilayer`'s and `splat`'s) takes its level from
/// the pixel's longer axis, whose texels are two of the stripes' texels wide across, and
/// smears the stripes' edges over the pixels beside them.
#[test]
fn a_minified_texture_keeps_its_edges_in_the_layered_input() {
    let (sampled, quadrants, _) = minified_stripes(2.0, 2.0);
    assert!(sampled < 0.05, "per-sample lookups: worst {sampled}");
    assert!(
        quadrants > 0.1,
        "one lookup a quadrant blurs the edges (the case the default is for): {quadrants}"
    );
}

/// Per-sample lookups stop where the defocus blur hides what they add: on a surface whose CoC
/// radius is beyond `SAMPLE_SHADING_MAX_COC_PX` (2 px), in front of the focus or behind it,
/// the input is the quadrant lookups' bit for bit; within it, it is the per-sample one.
#[test]
fn per_sample_lookups_stop_where_the_blur_hides_them() {
    use defocus::raster::SAMPLE_SHADING_MAX_COC_PX;
    let z_m = 0.5;
    // The focus that puts the surface at `z_m` at a signed CoC radius of `coc_px`.
    let lens = test_camera(64, 64, 1.0, 1.0).thin_lens().unwrap();
    let focus_for = |coc_px: f32| 1.0 / (1.0 / z_m + coc_px / (lens.f_px * lens.lens_radius_m));
    for coc_px in [-1.5f32, 1.5] {
        assert!(coc_px.abs() < SAMPLE_SHADING_MAX_COC_PX);
        let (sampled, quadrants, same) = minified_stripes(focus_for(coc_px), z_m);
        assert!(
            sampled < 0.05 && quadrants > 0.1 && !same,
            "CoC {coc_px} px: per-sample {sampled}, quadrants {quadrants}"
        );
    }
    for coc_px in [-2.5, 2.5] {
        let (_, quadrants, same) = minified_stripes(focus_for(coc_px), z_m);
        assert!(
            same && quadrants > 0.1,
            "CoC {coc_px} px: the input should be the quadrants' ({quadrants})"
        );
    }
}

/// Alpha to coverage: an alpha-mask card whose texture's alpha is two-valued (transparent left
/// half, opaque right half, green throughout), magnified so that its filtered edge spans a few
/// pixels, in front of a white board. Across the edge each pixel's card fragment is the card's
/// colour, opaque over the samples it keeps: its alpha is a whole number of the 16 samples
/// (the kept share of the filtered alpha), it climbs from the hole to the solid part, and the
/// board stays in the list behind it where the card leaves samples free.
#[test]
fn alpha_to_coverage_keeps_whole_opaque_samples_across_a_cut_outs_edge() {
    use defocus::raster::{from_half, LayeredInput};
    use defocus::scene::{FilterMode, Texture, TextureBinding, TextureSampler, WrapMode};
    let camera = test_camera(64, 64, 3.0, 2.8);
    let mut scene = Scene::default();
    let texels = (0..16 * 16)
        .map(|i| [0.0, 1.0, 0.0, if i % 16 < 8 { 0.0 } else { 1.0 }])
        .collect();
    let t = scene.add_texture(Texture::new(ColorImage::from_vec(16, 16, texels).unwrap()));
    let card = scene.add_material(Material {
        name: "cut-out".into(),
        base_color_texture: Some(TextureBinding {
            texture: t,
            sampler: TextureSampler {
                mag_filter: FilterMode::Linear,
                wrap_u: WrapMode::ClampToEdge,
                wrap_v: WrapMode::ClampToEdge,
                ..Default::default()
            },
            uv_transform: Default::default(),
        }),
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        ..Default::default()
    });
    let white = scene.add_material(Material::color("board", [1.0; 3]));
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 64.0, 64.0), 3.0, white);
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 64.0, 64.0), 1.5, card);
    let lists = pinhole_lists(&scene, &camera, 4, LayeredInput::default());
    let mut alphas = Vec::new();
    for x in 20..44 {
        let (depths, colors) = lists.pixel(x, 32);
        let card_alpha = match depths.first() {
            Some(&z) if (z - 1.5).abs() < 1e-3 => {
                let c = from_half(&colors[0]);
                let a = c[3];
                assert!(
                    (a * 16.0 - (a * 16.0).round()).abs() < 1e-3,
                    "pixel {x}: alpha {a} is not a whole number of samples"
                );
                assert!(
                    c[0].abs() < 1e-3 && (c[1] - a).abs() < 2e-3 && c[2].abs() < 1e-3,
                    "pixel {x}: {c:?} is not the card's green, premultiplied"
                );
                a
            }
            _ => 0.0,
        };
        if card_alpha < 1.0 {
            let board = depths.iter().position(|&z| (z - 3.0).abs() < 1e-3);
            assert!(board.is_some(), "pixel {x}: no board behind, {depths:?}");
        }
        alphas.push(card_alpha);
    }
    assert!(alphas.windows(2).all(|w| w[0] <= w[1]), "{alphas:?}");
    assert_eq!(
        (alphas[0], alphas[alphas.len() - 1]),
        (0.0, 1.0),
        "{alphas:?}"
    );
    let partial = alphas.iter().filter(|&&a| a > 0.0 && a < 1.0).count();
    assert!(partial >= 2, "the edge spans pixels: {alphas:?}");
}
