//! Tests: highlights scattered ray by ray (`--highlight-rays`) in the layered methods: what
//! they scatter is what they take out of the blend, and a light seen through more surfaces
//! than the fragment lists hold keeps its own blur.

use defocus::image::{luminance, ColorImage};
use defocus::lens::Camera;
use defocus::methods::multilayer::{self, MultilayerSettings};
use defocus::methods::multiview::{self, MultiviewSettings};
use defocus::methods::reference::{self, ReferenceSettings};
use defocus::methods::splat::{self, SplatSettings};
use defocus::scene::{Material, Mesh, Scene};
use glam::Vec3;

use crate::{add_screen_rect, test_camera};

/// Appends a UV sphere of `radius_m` at `centre` (world space) to `scene` with `material`.
fn add_sphere(scene: &mut Scene, centre: Vec3, radius_m: f32, material: usize) {
    let (rings, segments) = (
        std::env::var("RINGS")
            .map(|v| v.parse().unwrap())
            .unwrap_or(12u32),
        std::env::var("SEGS")
            .map(|v| v.parse().unwrap())
            .unwrap_or(24u32),
    );
    let mut mesh = Mesh {
        material,
        ..Default::default()
    };
    for i in 0..=rings {
        let theta = std::f32::consts::PI * i as f32 / rings as f32;
        for j in 0..segments {
            let phi = 2.0 * std::f32::consts::PI * j as f32 / segments as f32;
            mesh.positions.push(
                centre
                    + radius_m
                        * Vec3::new(
                            theta.sin() * phi.cos(),
                            theta.cos(),
                            theta.sin() * phi.sin(),
                        ),
            );
        }
    }
    for i in 0..rings {
        for j in 0..segments {
            let a = i * segments + j;
            let b = i * segments + (j + 1) % segments;
            let (c, d) = (a + segments, b + segments);
            mesh.indices.push([a, c, b]);
            mesh.indices.push([b, c, d]);
        }
    }
    scene.meshes.push(mesh);
}

/// Luminance summed over the pixels within `radius` of `centre`.
fn energy(img: &ColorImage, centre: (f32, f32), radius: f32) -> f64 {
    let mut sum = 0.0;
    for y in 0..img.height() {
        for x in 0..img.width() {
            let (dx, dy) = (x as f32 + 0.5 - centre.0, y as f32 + 0.5 - centre.1);
            if dx * dx + dy * dy <= radius * radius {
                let p = img.get(x, y);
                sum += f64::from(luminance([p[0], p[1], p[2]]));
            }
        }
    }
    sum
}

/// The share of the light's own contribution (`with - without`) that lies farther than
/// `r` from `at`.
fn share_outside(with: &ColorImage, without: &ColorImage, at: (f32, f32), r: f32) -> f64 {
    let (mut all, mut out) = (0.0f64, 0.0f64);
    for y in 0..with.height() {
        for x in 0..with.width() {
            let (p, q) = (with.get(x, y), without.get(x, y));
            let d = f64::from(luminance([p[0] - q[0], p[1] - q[1], p[2] - q[2]]));
            all += d;
            let (dx, dy) = (x as f32 + 0.5 - at.0, y as f32 + 0.5 - at.1);
            if dx * dx + dy * dy > r * r {
                out += d;
            }
        }
    }
    out / all
}

/// Tolerance on a light's bokeh energy against `reference`: the 3%.
const ENERGY_TOLERANCE: f64 = 0.03;

/// Small emissive spheres (a UV sphere 1.2-2 px in radius, so that most of its pixels are
/// partly covered) in front of and far behind the focus, alone before a dark wall: the
/// luminance summed over each one's bokeh is `reference`'s within 3% in every layered method,
/// with highlights scattered ray by ray (the default) and blended (`--highlight-rays off`).
#[test]
fn a_small_lights_bokeh_holds_the_energy_of_reference() {
    let size = 96;
    let camera = Camera {
        focal_length_mm: 150.0,
        ..test_camera(size, size, 1.0, 1.4)
    };
    let lens = camera.thin_lens().unwrap();
    let (cx, cy) = lens.centre_px();
    for &(z, radius_px, at) in &[
        (50.0f32, 2.0f32, (48.3f32, 47.6f32)),
        (0.6, 2.0, (47.7, 48.2)),
        (50.0, 1.2, (47.8, 48.4)),
    ] {
        let mut scene = Scene::default();
        let wall = scene.add_material(Material::color("wall", [0.0; 3]));
        let s = size as f32;
        add_screen_rect(&mut scene, &camera, (-s, -s, 2.0 * s, 2.0 * s), 200.0, wall);
        let mut m = Material::emissive("light", [1.0, 0.9, 0.7], 40.0);
        m.double_sided = false;
        let light = scene.add_material(m);
        let centre = Vec3::new(
            (at.0 - cx) * z / lens.f_px,
            -(at.1 - cy) * z / lens.f_px,
            -z,
        );
        add_sphere(&mut scene, centre, radius_px * z / lens.f_px, light);
        let c = lens.coc_px(z);
        assert!(c.abs() > 10.0, "setup: C {c}");
        let disc = |img: &ColorImage| energy(img, at, c.abs() + 3.0);
        let truth = reference::render(
            &scene,
            &camera,
            &ReferenceSettings {
                samples: 1024,
                ..ReferenceSettings::default()
            },
            &mut |_, _| {},
        )
        .unwrap()
        .image;
        let e_truth = disc(&truth);
        for highlights in [Some(1.0), None] {
            let ml = multilayer::render(
                &scene,
                &camera,
                &MultilayerSettings {
                    highlights,
                    ..Default::default()
                },
            )
            .unwrap()
            .image;
            let (sp, _) = splat::render_scene(
                &scene,
                &camera,
                &SplatSettings {
                    layers: 4,
                    highlights,
                    ..Default::default()
                },
            )
            .unwrap();
            let mv = multiview::render(
                &scene,
                &camera,
                &MultiviewSettings {
                    highlights,
                    ..Default::default()
                },
            )
            .unwrap()
            .image;
            for (name, img) in [
                ("multilayer", &ml),
                ("splat", &sp.image),
                ("multiview", &mv),
            ] {
                let e = disc(img);
                eprintln!("z {z} r {radius_px} C {c:.1} {name} {highlights:?}: {e:.2} vs reference {e_truth:.2}");
                assert!(
                    (e / e_truth - 1.0).abs() < ENERGY_TOLERANCE,
                    "{name} (highlights {highlights:?}), light at {z} m: {e} vs {e_truth}"
                );
            }
        }
    }
}

/// A light far behind the focus (CoC +21 px) seen through four semi-transparent panes (three
/// panes and a leaf-like one nearer, CoC -2.4 to -14 px) before a wall: six surfaces on the
/// ray, two more than the lists hold at `multilayer`'s and `splat --layers 4`'s defaults. The
/// light's own contribution (the image with it less the image without it) spreads as its own
/// disc: the share beyond 0.6 of its CoC radius is `reference`'s (0.64 for a uniform disc)
/// within 0.05, not the nearly nothing of a dot the size of the last pane's blur, and it
/// carries `reference`'s energy within 5% (the panes' tint over the lens is `reference`'s
/// noise).
#[test]
fn a_light_behind_more_surfaces_than_the_lists_hold_keeps_its_own_blur() {
    use defocus::scene::AlphaMode;
    let size = 96;
    let camera = Camera {
        focal_length_mm: 150.0,
        ..test_camera(size, size, 1.0, 1.4)
    };
    let lens = camera.thin_lens().unwrap();
    let c = size as f32 / 2.0;
    let panes = [0.9f32, 0.8, 0.7, 0.6];
    let build = |with_light: bool| {
        let mut scene = Scene::default();
        let wall = scene.add_material(Material::color("wall", [0.02; 3]));
        let s = size as f32;
        add_screen_rect(&mut scene, &camera, (-s, -s, 2.0 * s, 2.0 * s), 100.0, wall);
        if with_light {
            let light = scene.add_material(Material::emissive("light", [1.0; 3], 400.0));
            add_screen_rect(
                &mut scene,
                &camera,
                (c - 1.0, c - 1.0, c + 1.0, c + 1.0),
                50.0,
                light,
            );
        }
        for (k, z) in panes.into_iter().enumerate() {
            let mut m = Material::color(&format!("pane{k}"), [0.3, 0.5, 0.4]);
            m.base_color[3] = 0.4;
            m.alpha_mode = AlphaMode::Blend;
            let pane = scene.add_material(m);
            add_screen_rect(&mut scene, &camera, (-s, -s, 2.0 * s, 2.0 * s), z, pane);
        }
        scene
    };
    let (with, without) = (build(true), build(false));
    let cl = lens.coc_px(50.0);
    assert!(
        cl > 20.0 && panes.iter().all(|&z| lens.coc_px(z) < -2.0),
        "setup"
    );
    let r = 0.6 * cl;
    let reference_of = |s: &Scene| {
        reference::render(
            s,
            &camera,
            &ReferenceSettings {
                samples: 512,
                ..Default::default()
            },
            &mut |_, _| {},
        )
        .unwrap()
        .image
    };
    let (t_with, t_without) = (reference_of(&with), reference_of(&without));
    let truth_share = share_outside(&t_with, &t_without, (c, c), r);
    let truth_energy = energy(&t_with, (c, c), 40.0) - energy(&t_without, (c, c), 40.0);
    let ml = |s: &Scene| {
        multilayer::render(s, &camera, &MultilayerSettings::default())
            .unwrap()
            .image
    };
    let sp = |s: &Scene| {
        splat::render_scene(
            s,
            &camera,
            &SplatSettings {
                layers: 4,
                ..Default::default()
            },
        )
        .unwrap()
        .0
        .image
    };
    assert!(MultilayerSettings::default().fragments < panes.len() + 2);
    for (name, a, b) in [
        ("multilayer", ml(&with), ml(&without)),
        ("splat", sp(&with), sp(&without)),
    ] {
        let share = share_outside(&a, &b, (c, c), r);
        let e = energy(&a, (c, c), 40.0) - energy(&b, (c, c), 40.0);
        eprintln!("{name}: share outside {share:.3} (reference {truth_share:.3}), energy {e:.1} ({truth_energy:.1})");
        assert!(
            (share - truth_share).abs() < 0.05,
            "{name}: {share} vs {truth_share}"
        );
        assert!(
            (e / truth_energy - 1.0).abs() < 0.05,
            "{name}: {e} vs {truth_energy}"
        );
    }
}
