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

/// Appends a UV sphere of `radius_m` at `centre` (world space) to `scene` with `material`:
/// 12 rings of 24 segments.
fn add_sphere(scene: &mut Scene, centre: Vec3, radius_m: f32, material: usize) {
    add_sphere_of(scene, centre, radius_m, material, (12, 24));
}

/// [`add_sphere`] with `rings` rings of `segments` segments.
fn add_sphere_of(
    scene: &mut Scene,
    centre: Vec3,
    radius_m: f32,
    material: usize,
    (rings, segments): (u32, u32),
) {
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

/// Luminance of the light's own contribution (`with - without`) summed over the pixels
/// within `radius` of `centre`.
fn own_energy(with: &ColorImage, without: &ColorImage, centre: (f32, f32), radius: f32) -> f64 {
    let mut sum = 0.0;
    for y in 0..with.height() {
        for x in 0..with.width() {
            let (dx, dy) = (x as f32 + 0.5 - centre.0, y as f32 + 0.5 - centre.1);
            if dx * dx + dy * dy <= radius * radius {
                let (p, q) = (with.get(x, y), without.get(x, y));
                sum += f64::from(luminance([p[0] - q[0], p[1] - q[1], p[2] - q[2]]));
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

/// Small double-sided emissive spheres (a 32 x 16 UV sphere 2 px in radius: the default of
/// a modeller, whose back faces lie 0.5-1% of the depth behind its front ones) before a dim far
/// wall, 50 mm at f/0.25 focused at 4 m, CoC -23 to +10 px: each light's own contribution (the
/// image with the lights less the image without) summed over its bokeh is `reference`'s within
/// 3% in every layered method at its defaults. The back of a sphere shares the front's
/// silhouette, so it shows nowhere; where the lists or the layers held it as a second surface
/// behind a partly covered front, highlights were scattered for both (multilayer and splat
/// +32% and +46% on the lights at 1.8 and 60 m), and `multiview`'s layers, cut between the two,
/// doubled the light's rim (+10% at 19 m).
#[test]
fn small_double_sided_lights_keep_the_energy_of_reference() {
    let (w, h) = (160usize, 90usize);
    let camera = Camera {
        focal_length_mm: 100.0,
        ..test_camera(w, h, 4.0, 0.5)
    };
    let lens = camera.thin_lens().unwrap();
    let (cx, cy) = lens.centre_px();
    let world =
        |x: f32, y: f32, z: f32| Vec3::new((x - cx) * z / lens.f_px, -(y - cy) * z / lens.f_px, -z);
    // Depth, pixel, strength: in front of the focus and far behind it.
    let lights = [
        (1.8f32, (96.3f32, 36.2f32), 20.0f32),
        (19.0, (128.7, 54.6), 40.0),
        (1.3, (48.1, 63.5), 8.0),
        (60.0, (72.5, 22.6), 50.0),
    ];
    let build = |with_lights: bool| {
        let mut scene = Scene::default();
        let far = scene.add_material(Material::color("far", [0.15, 0.12, 0.1]));
        let s = w as f32;
        add_screen_rect(&mut scene, &camera, (-s, -s, 2.0 * s, 2.0 * s), 100.0, far);
        if with_lights {
            for (k, &(z, at, strength)) in lights.iter().enumerate() {
                let m = Material::emissive(&format!("light{k}"), [1.0, 0.85, 0.6], strength);
                assert!(m.double_sided);
                let m = scene.add_material(m);
                add_sphere_of(
                    &mut scene,
                    world(at.0, at.1, z),
                    2.0 * z / lens.f_px,
                    m,
                    (16, 32),
                );
            }
        }
        scene
    };
    let (with, without) = (build(true), build(false));
    let reference = |scene: &Scene| {
        let settings = ReferenceSettings {
            samples: 1024,
            ..ReferenceSettings::default()
        };
        reference::render(scene, &camera, &settings, &mut |_, _| {})
            .unwrap()
            .image
    };
    let multilayer = |scene: &Scene| {
        multilayer::render(scene, &camera, &MultilayerSettings::default())
            .unwrap()
            .image
    };
    let splat = |scene: &Scene| {
        let settings = SplatSettings {
            layers: 4,
            ..Default::default()
        };
        splat::render_scene(scene, &camera, &settings)
            .unwrap()
            .0
            .image
    };
    let multiview = |scene: &Scene| {
        multiview::render(scene, &camera, &MultiviewSettings::default())
            .unwrap()
            .image
    };
    let truth = (reference(&with), reference(&without));
    let runs = [
        ("multilayer", (multilayer(&with), multilayer(&without))),
        ("splat --layers 4", (splat(&with), splat(&without))),
        ("multiview", (multiview(&with), multiview(&without))),
    ];
    for &(z, at, _) in &lights {
        let c = lens.coc_px(z);
        let own = |(a, b): &(ColorImage, ColorImage)| own_energy(a, b, at, c.abs() + 3.0);
        let e_truth = own(&truth);
        for (name, images) in &runs {
            let e = own(images);
            eprintln!("light at {z} m, C {c:.1}: {name} {e:.2} against reference {e_truth:.2}");
            assert!(
                (e / e_truth - 1.0).abs() < ENERGY_TOLERANCE,
                "{name}, light at {z} m (C {c:.1} px): {e:.2} against reference {e_truth:.2}"
            );
        }
    }
}

/// The built-in `lights` scene at 640x360: its bulbs are found in the pinhole frame (each
/// connected patch of pixels brighter than white, at its depth pass's CoC). The luminance
/// summed over the bokeh of each whose disc meets no other's is, in every layered method at
/// its defaults (highlights scattered ray by ray), the same as with the highlights blended by
/// `multilayer --highlight-rays off` within 3%: the scatter moves light, it adds none. Summed
/// over all of those bulbs it is `reference`'s (1024 views) within 3%; bulb by bulb the bulbs,
/// 1-2 px across, are sampled by the lists' 16 coverage samples a pixel, which puts each one's
/// energy within about 10% of `reference`'s whatever the method does.
#[test]
fn each_bulb_of_lights_keeps_its_energy() {
    use defocus::methods::pinhole;
    let scene = defocus::scene::builtin::load("lights").unwrap();
    let mut camera = scene.defaults.clone().unwrap().camera;
    (camera.width_px, camera.height_px) = (640, 360);
    let lens = camera.thin_lens().unwrap();
    let frame = pinhole::render(&scene, &camera, 1, 0, true).unwrap();
    let depth = frame.depth.unwrap();
    let bulbs: Vec<((f32, f32), f32)> = bright_patches(&frame.image)
        .into_iter()
        .map(|(centre, pixel)| (centre, lens.coc_px(depth.get(pixel.0, pixel.1)).abs() + 3.0))
        .collect();
    let (w, h) = (camera.width_px as f32, camera.height_px as f32);
    let apart: Vec<((f32, f32), f32)> = bulbs
        .iter()
        .copied()
        .filter(|&((x, y), r)| {
            let inside = x >= r && y >= r && x + r <= w && y + r <= h;
            inside
                && bulbs
                    .iter()
                    .all(|&((u, v), q)| (u, v) == (x, y) || (u - x).hypot(v - y) > r + q)
        })
        .collect();
    assert!(
        apart.len() >= 20,
        "setup: {} bulbs apart of {}",
        apart.len(),
        bulbs.len()
    );
    let settings = ReferenceSettings {
        samples: 1024,
        ..ReferenceSettings::default()
    };
    let truth = reference::render(&scene, &camera, &settings, &mut |_, _| {})
        .unwrap()
        .image;
    let total = |img: &ColorImage| apart.iter().map(|&(at, r)| energy(img, at, r)).sum::<f64>();
    let e_truth = total(&truth);
    let splat_settings = SplatSettings {
        layers: 4,
        ..Default::default()
    };
    let scattered = [
        (
            "multilayer",
            multilayer::render(&scene, &camera, &MultilayerSettings::default()),
        ),
        (
            "splat --layers 4",
            splat::render_scene(&scene, &camera, &splat_settings).map(|r| r.0),
        ),
        (
            "multiview",
            multiview::render(&scene, &camera, &MultiviewSettings::default()),
        ),
    ];
    // `multiview` with its highlights blended is the paper's: its 32 rays a pixel sample a
    // light 1-2 px across too sparsely for its energy (3.4% short here); the lists' methods
    // blend it by its coverage.
    let blended_settings = MultilayerSettings {
        highlights: None,
        ..Default::default()
    };
    let blended = multilayer::render(&scene, &camera, &blended_settings)
        .unwrap()
        .image;
    for (name, run) in scattered {
        let img = run.unwrap().image;
        let e = total(&img);
        eprintln!("{name}: {e:.1} against reference {e_truth:.1}");
        assert!(
            (e / e_truth - 1.0).abs() < ENERGY_TOLERANCE,
            "{name}: {e:.1} against reference {e_truth:.1}"
        );
        for &(at, r) in &apart {
            let (e_on, e_off) = (energy(&img, at, r), energy(&blended, at, r));
            assert!(
                (e_on / e_off - 1.0).abs() < ENERGY_TOLERANCE,
                "{name}, bulb at ({:.1}, {:.1}): {e_on:.2} scattered against {e_off:.2} blended",
                at.0,
                at.1
            );
        }
    }
}

/// The connected patches (4-neighbours) of pixels brighter than white in `img`: each one's
/// luminance-weighted centre (pixel centres at +0.5) and its brightest pixel.
fn bright_patches(img: &ColorImage) -> Vec<((f32, f32), (usize, usize))> {
    let (w, h) = (img.width(), img.height());
    let lum = |x: usize, y: usize| {
        let p = img.get(x, y);
        luminance([p[0], p[1], p[2]])
    };
    let mut seen = vec![false; w * h];
    let mut patches = Vec::new();
    for start in 0..w * h {
        if seen[start] || lum(start % w, start / w) <= 1.0 {
            continue;
        }
        seen[start] = true;
        let (mut stack, mut sum, mut sx, mut sy) = (vec![start], 0.0f32, 0.0f32, 0.0f32);
        let mut brightest = (start % w, start / w);
        while let Some(i) = stack.pop() {
            let (x, y) = (i % w, i / w);
            let l = lum(x, y);
            (sum, sx, sy) = (
                sum + l,
                sx + l * (x as f32 + 0.5),
                sy + l * (y as f32 + 0.5),
            );
            if l > lum(brightest.0, brightest.1) {
                brightest = (x, y);
            }
            let neighbours = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then(|| i + w),
            ];
            for j in neighbours.into_iter().flatten() {
                if !seen[j] && lum(j % w, j / w) > 1.0 {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        patches.push(((sx / sum, sy / sum), brightest));
    }
    patches
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
