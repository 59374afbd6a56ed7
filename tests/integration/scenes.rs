//! Tests: the built-in scenes load, are valid, and put their geometry where their purpose
//! needs it (depths and circles of confusion checked numerically with the shared lens model).

use defocus::lens::{Camera, ThinLens};
use defocus::scene::builtin::{self, NAMES};
use defocus::scene::{AlphaMode, Scene};
use glam::Vec3;

/// Most triangles a built-in scene may have, so a 1280x720 frame rasterizes in milliseconds.
const MAX_TRIANGLES: usize = 50_000;

fn camera(scene: &Scene) -> Camera {
    scene
        .defaults
        .as_ref()
        .unwrap_or_else(|| panic!("scene '{}' has no default camera", scene.name))
        .camera
        .clone()
}

/// View depth of a world point: `-(camera_from_world * p).z`, in metres.
fn depth(camera: &Camera, p: Vec3) -> f32 {
    -camera.camera_from_world.transform_point3(p).z
}

/// Raster position and depth of a world point.
fn project(camera: &Camera, lens: &ThinLens, p: Vec3) -> (f32, f32, f32) {
    lens.project(camera.camera_from_world.transform_point3(p))
        .expect("point in front of the camera")
}

/// All vertices of the meshes whose material satisfies `pick`.
fn vertices_where(scene: &Scene, pick: impl Fn(&defocus::scene::Material) -> bool) -> Vec<Vec3> {
    scene
        .meshes
        .iter()
        .filter(|m| pick(&scene.materials[m.material]))
        .flat_map(|m| m.positions.iter().copied())
        .collect()
}

fn named(scene: &Scene, name: &str) -> Vec<Vec3> {
    let v = vertices_where(scene, |m| m.name == name);
    assert!(
        !v.is_empty(),
        "scene '{}' has no material '{name}'",
        scene.name
    );
    v
}

#[test]
fn every_built_in_scene_loads_validates_and_has_a_usable_default_camera() {
    assert_eq!(NAMES, ["railing", "lights", "grass", "glass", "traps"]);
    for &name in NAMES {
        let scene = builtin::load(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(scene.name, name);
        scene.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
        let defaults = scene.defaults.as_ref().expect("defaults");
        defaults.aperture.validate().expect("aperture");
        let cam = &defaults.camera;
        let lens = cam.thin_lens().unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(
            lens.near_m < lens.focus_m && lens.focus_m < lens.far_m,
            "{name}: focus {} m outside [{}, {}] m",
            lens.focus_m,
            lens.near_m,
            lens.far_m
        );
        assert_eq!((cam.width_px, cam.height_px), (1280, 720), "{name}");
        let triangles = scene.triangle_count();
        assert!(
            (1..MAX_TRIANGLES).contains(&triangles),
            "{name}: {triangles} triangles"
        );
        // Nothing is cut by the far plane (floors may pass behind the camera: they are
        // clipped at the near plane, out of view).
        let farthest = scene
            .meshes
            .iter()
            .flat_map(|m| m.positions.iter())
            .map(|&p| depth(cam, p))
            .fold(0.0, f32::max);
        assert!(farthest < lens.far_m, "{name}: geometry at {farthest} m");
    }
}

#[test]
fn unknown_scene_is_an_error_naming_the_valid_scenes() {
    let message = builtin::load("nope").unwrap_err().to_string();
    assert!(message.contains("nope"), "{message}");
    for name in NAMES {
        assert!(message.contains(name), "{message}");
    }
}

#[test]
fn the_same_scene_is_built_identically_twice() {
    for &name in NAMES {
        assert!(
            builtin::load(name).unwrap() == builtin::load(name).unwrap(),
            "{name}"
        );
    }
}

#[test]
fn scene_textures_hold_finite_linear_colours_and_alpha_in_unit_range() {
    for &name in NAMES {
        let scene = builtin::load(name).unwrap();
        for (i, t) in scene.textures.iter().enumerate() {
            for p in t.levels()[0].pixels() {
                assert!(
                    p.iter().all(|c| c.is_finite() && (0.0..=1.0).contains(c)),
                    "{name}: texture {i} texel {p:?}"
                );
            }
        }
    }
}

#[test]
fn railing_bars_stand_in_front_of_focus_with_a_coc_over_ten_pixels() {
    let scene = builtin::railing();
    let cam = camera(&scene);
    let lens = cam.thin_lens().unwrap();
    for p in named(&scene, "railing metal") {
        let z = depth(&cam, p);
        assert!(z < lens.focus_m, "bar vertex {p} at {z} m is behind focus");
        let coc = lens.coc_px(z);
        assert!(coc < -10.0, "bar vertex {p}: CoC {coc} px");
    }
}

#[test]
fn railing_board_is_in_focus_and_bars_cross_it() {
    let scene = builtin::railing();
    let cam = camera(&scene);
    let lens = cam.thin_lens().unwrap();
    let board = named(&scene, "chart board");
    let (mut x0, mut x1, mut y0, mut y1) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
    for &p in &board {
        let (x, y, z) = project(&cam, &lens, p);
        assert!(
            lens.coc_px(z).abs() < 0.01,
            "board vertex at {z} m is out of focus"
        );
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    // The board fills most of the frame but leaves the far wall visible around it.
    let (w, h) = (lens.width_px as f32, lens.height_px as f32);
    assert!(
        x0 > 0.0 && x1 < w && y0 > 0.0 && y1 < h,
        "board {x0}..{x1} x {y0}..{y1}"
    );
    assert!(
        (x1 - x0) > 0.6 * w && (y1 - y0) > 0.6 * h,
        "board {x0}..{x1} x {y0}..{y1}"
    );

    // At least two bars run across the board, top to bottom of the frame.
    let bar_columns: Vec<f32> = named(&scene, "railing metal")
        .into_iter()
        .filter(|p| p.y < 0.5)
        .map(|p| project(&cam, &lens, p).0)
        .collect();
    let mut crossing: Vec<i32> = bar_columns
        .iter()
        .filter(|&&x| x > x0 && x < x1)
        .map(|&x| (x / 50.0) as i32)
        .collect();
    crossing.dedup();
    assert!(crossing.len() >= 2, "bars at columns {bar_columns:?}");
}

#[test]
fn lights_are_bright_emitters_far_behind_focus_and_some_in_front() {
    let scene = builtin::lights();
    let cam = camera(&scene);
    let lens = cam.thin_lens().unwrap();
    let emitters: Vec<_> = scene
        .materials
        .iter()
        .filter(|m| m.emissive.iter().any(|&c| c > 0.0))
        .collect();
    assert!(emitters.len() >= 3, "{} emissive materials", emitters.len());
    for m in &emitters {
        assert!(
            m.emissive_strength >= 10.0,
            "{}: strength {}",
            m.name,
            m.emissive_strength
        );
    }
    // Bulb triangles (12 per bulb) by their centroids.
    let (w, h) = (lens.width_px as f32, lens.height_px as f32);
    let mut far_in_frame = 0;
    let mut near_in_frame = 0;
    for mesh in &scene.meshes {
        let m = &scene.materials[mesh.material];
        if m.emissive == [0.0; 3] {
            continue;
        }
        for t in &mesh.indices {
            let c = t.iter().map(|&i| mesh.positions[i as usize]).sum::<Vec3>() / 3.0;
            let (x, y, z) = project(&cam, &lens, c);
            if !((0.0..w).contains(&x) && (0.0..h).contains(&y)) {
                continue;
            }
            if z > 5.0 * lens.focus_m {
                far_in_frame += 1;
            } else if z < lens.focus_m && lens.coc_px(z) < -10.0 {
                near_in_frame += 1;
            }
        }
    }
    assert!(
        far_in_frame >= 20 * 12,
        "{far_in_frame} far light triangles in frame"
    );
    assert!(
        near_in_frame >= 12,
        "{near_in_frame} near light triangles in frame"
    );
}

#[test]
fn grass_has_thousands_of_cut_out_tufts_from_near_the_lens_to_far_away() {
    let scene = builtin::grass();
    let cam = camera(&scene);
    let lens = cam.thin_lens().unwrap();
    let masked = |m: &defocus::scene::Material| matches!(m.alpha_mode, AlphaMode::Mask { .. });
    let triangles: usize = scene
        .meshes
        .iter()
        .filter(|m| masked(&scene.materials[m.material]))
        .map(|m| m.triangle_count())
        .sum();
    assert!(triangles >= 8000, "{triangles} cut-out triangles");
    let depths: Vec<f32> = vertices_where(&scene, masked)
        .into_iter()
        .map(|p| depth(&cam, p))
        .collect();
    let nearest = depths.iter().copied().fold(f32::MAX, f32::min);
    let farthest = depths.iter().copied().fold(0.0, f32::max);
    assert!(
        nearest < 0.5 && lens.coc_px(nearest) < -30.0,
        "nearest tuft at {nearest} m"
    );
    assert!(farthest > 10.0, "farthest tuft at {farthest} m");
}

#[test]
fn glass_panes_are_blended_between_the_near_post_and_the_wall_in_focus() {
    let scene = builtin::glass();
    let cam = camera(&scene);
    let lens = cam.thin_lens().unwrap();
    let panes = vertices_where(&scene, |m| m.alpha_mode == AlphaMode::Blend);
    assert!(!panes.is_empty());
    let post_far = named(&scene, "red post")
        .into_iter()
        .map(|p| depth(&cam, p))
        .fold(0.0, f32::max);
    for p in panes {
        let z = depth(&cam, p);
        assert!(z > post_far && z < lens.focus_m, "pane vertex at {z} m");
    }
    for p in named(&scene, "chart poster") {
        assert!(lens.coc_px(depth(&cam, p)).abs() < 0.01);
    }
}

/// The `traps` scene's pinhole frame at 160x90 (pixel centres, with depth), its thin lens at
/// that size and the thin lens of its default 1280x720 camera; rendered once per test run.
struct TrapsFrame {
    scene: Scene,
    camera: Camera,
    lens: ThinLens,
    full_lens: ThinLens,
    colour: defocus::image::ColorImage,
    depth: defocus::image::GrayImage,
}

fn traps_frame() -> &'static TrapsFrame {
    use std::sync::OnceLock;
    static FRAME: OnceLock<TrapsFrame> = OnceLock::new();
    FRAME.get_or_init(|| {
        let scene = builtin::load("traps").unwrap();
        let full = camera(&scene);
        let mut small = full.clone();
        (small.width_px, small.height_px) = (160, 90);
        let out = defocus::methods::pinhole::render(&scene, &small, 1, 0, true).unwrap();
        TrapsFrame {
            lens: small.thin_lens().unwrap(),
            full_lens: full.thin_lens().unwrap(),
            camera: small,
            colour: out.image,
            depth: out.depth.unwrap(),
            scene,
        }
    })
}

/// Raster bounding box (x0, y0, x1, y1) of a set of world points in `frame`'s pinhole view.
fn raster_box(frame: &TrapsFrame, points: &[Vec3]) -> (f32, f32, f32, f32) {
    points.iter().fold(
        (f32::MAX, f32::MAX, f32::MIN, f32::MIN),
        |(x0, y0, x1, y1), &p| {
            let (x, y, _) = project(&frame.camera, &frame.lens, p);
            (x0.min(x), y0.min(y), x1.max(x), y1.max(y))
        },
    )
}

/// Railing depth: the bars' and rails' axes are at 0.7 m (their fronts 6 mm nearer).
fn is_railing_depth(z: f32) -> bool {
    (0.68..0.71).contains(&z)
}

#[test]
fn traps_default_camera_is_the_cycles_railing_lens() {
    let cam = camera(&builtin::traps());
    assert_eq!(
        (
            cam.focal_length_mm,
            cam.sensor_width_mm,
            cam.fstop,
            cam.focus_m
        ),
        (85.0, 36.0, 1.4, 2.5)
    );
    assert_eq!((cam.width_px, cam.height_px), (1280, 720));
}

#[test]
fn traps_chart_is_at_the_focus_distance_in_the_middle_of_the_frame() {
    let f = traps_frame();
    let (w, h) = (f.depth.width(), f.depth.height());
    let z = f.depth.get(w / 2, h / 2);
    assert!((z / 2.5 - 1.0).abs() < 0.02, "depth {z} m at the centre");
    let coc = f.full_lens.coc_px(z);
    assert!(coc.abs() < 0.5, "CoC {coc} px at 1280x720 at the centre");
    // Every printed mark is in focus too.
    for p in named(&f.scene, "chart ink") {
        let coc = f.full_lens.coc_px(depth(&f.camera, p));
        assert!(coc.abs() < 0.5, "chart mark {p}: CoC {coc} px");
    }
}

#[test]
fn traps_railing_crosses_every_border_of_the_frame_by_more_than_its_blur() {
    let f = traps_frame();
    let metal = named(&f.scene, "railing metal");
    let (w, h) = (f.lens.width_px as f32, f.lens.height_px as f32);
    // The largest blur radius of the railing (its nearest point) in this frame's pixels.
    let nearest = metal
        .iter()
        .map(|&p| depth(&f.camera, p))
        .fold(f32::MAX, f32::min);
    assert!(
        (0.68..0.7).contains(&nearest),
        "railing front at {nearest} m"
    );
    let blur = f.lens.coc_px(nearest).abs();
    assert!(blur > 10.0, "railing blur {blur} px at 160x90");
    let (x0, y0, x1, y1) = raster_box(f, &metal);
    assert!(
        x0 < -blur && y0 < -blur && x1 > w + blur && y1 > h + blur,
        "railing spans {x0}..{x1} x {y0}..{y1}, blur {blur} px"
    );
    // A bar stands wholly outside the frame but within its blur of the right edge: only a
    // method that sees beyond the frame blurs it in.
    let outside: Vec<f32> = metal
        .iter()
        .map(|&p| project(&f.camera, &f.lens, p).0)
        .filter(|&x| x > w)
        .collect();
    let closest = outside.iter().copied().fold(f32::MAX, f32::min);
    assert!(
        closest < w + blur,
        "nothing outside the frame within the blur: closest at {closest}"
    );

    // In the pinhole frame the rail meets the left and right edges on the same rows...
    let rail_rows = |x: usize| -> Vec<usize> {
        (0..h as usize)
            .filter(|&y| is_railing_depth(f.depth.get(x, y)))
            .collect()
    };
    let (left, right) = (rail_rows(0), rail_rows(w as usize - 1));
    assert!(left.len() >= 3, "rail rows at the left edge: {left:?}");
    assert_eq!(left, right);
    // ...and four bars meet the top and bottom edges on the same columns.
    let bar_runs = |y: usize| -> Vec<usize> {
        (0..w as usize)
            .filter(|&x| {
                is_railing_depth(f.depth.get(x, y))
                    && (x == 0 || !is_railing_depth(f.depth.get(x - 1, y)))
            })
            .collect()
    };
    let (top, bottom) = (bar_runs(0), bar_runs(h as usize - 1));
    assert_eq!(
        top.len(),
        4,
        "bars at the top edge start at columns {top:?}"
    );
    assert_eq!(top, bottom);
}

#[test]
fn traps_pane_blends_forty_percent_of_its_tint_over_the_chart_seen_through_it() {
    let f = traps_frame();
    let pane = f
        .scene
        .materials
        .iter()
        .find(|m| m.alpha_mode == AlphaMode::Blend)
        .expect("a blended material");
    let alpha = pane.base_color[3];
    assert!((0.35..=0.45).contains(&alpha), "pane alpha {alpha}");
    // Between the railing and the chart.
    for p in vertices_where(&f.scene, |m| m.alpha_mode == AlphaMode::Blend) {
        let z = depth(&f.camera, p);
        assert!((1.5..=2.0).contains(&z), "pane vertex at {z} m");
    }

    // The pane's lower edge crosses the red colour bar: its top is seen through the pane, its
    // bottom directly.
    let (px0, py0, px1, py1) = raster_box(
        f,
        &vertices_where(&f.scene, |m| m.alpha_mode == AlphaMode::Blend),
    );
    let (bx0, by0, bx1, by1) = raster_box(f, &named(&f.scene, "colour bar red"));
    let x = (0.5 * (bx0 + bx1)) as usize;
    assert!(
        (px0..px1).contains(&(x as f32)),
        "bar column {x} not under the pane"
    );
    assert!(
        by0 < py1 && py1 < by1,
        "pane bottom {py1} outside the bar {by0}..{by1}"
    );
    let through_y = (0.5 * (by0.max(py0) + py1)) as usize;
    let direct_y = (0.5 * (py1 + by1)) as usize;
    let through = f.colour.get(x, through_y);
    let direct = f.colour.get(x, direct_y);
    for c in 0..3 {
        let expected = alpha * pane.base_color[c] + (1.0 - alpha) * direct[c];
        assert!(
            (through[c] - expected).abs() < 0.01,
            "channel {c}: {through:?} through the pane, {direct:?} directly, pane {:?}",
            pane.base_color
        );
    }
    let differs = |a: [f32; 4], b: [f32; 4]| (0..3).any(|c| (a[c] - b[c]).abs() > 0.1);
    assert!(differs(through, direct) && differs(through, pane.base_color));
}

#[test]
fn traps_lights_are_hdr_far_behind_focus_and_two_hide_behind_the_railing() {
    let f = traps_frame();
    let (w, h) = (f.depth.width(), f.depth.height());
    let mut bright_far = 0;
    for y in 0..h {
        for x in 0..w {
            let c = f.colour.get(x, y);
            let z = f.depth.get(x, y);
            if c[..3].iter().any(|&v| v > 1.0) && z > 10.0 {
                assert!(f.full_lens.coc_px(z) > 20.0, "light at {z} m");
                bright_far += 1;
            }
        }
    }
    assert!(bright_far >= 5, "{bright_far} HDR pixels");

    // Two lights' centres are covered by the railing in the pinhole view (one behind a bar, one
    // behind the rail): only rays through the lens see them.
    let mut hidden = 0;
    for mesh in &f.scene.meshes {
        let m = &f.scene.materials[mesh.material];
        assert!(
            m.emissive == [0.0; 3] || m.emissive_strength >= 20.0,
            "{}",
            m.name
        );
        if m.emissive == [0.0; 3] {
            continue;
        }
        // Each light has its own material, so a mesh's mean vertex is its light's centre.
        let centre = mesh.positions.iter().sum::<Vec3>() / mesh.positions.len() as f32;
        let (x, y, _) = project(&f.camera, &f.lens, centre);
        if (0.0..w as f32).contains(&x) && (0.0..h as f32).contains(&y) {
            hidden += usize::from(f.depth.get(x as usize, y as usize) < 1.0);
        }
    }
    assert!(hidden >= 2, "{hidden} lights hidden behind the railing");
}
