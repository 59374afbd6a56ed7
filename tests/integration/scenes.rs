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
    assert_eq!(NAMES, ["railing", "lights", "grass", "glass"]);
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
