//! Tests: the rasterizer and the G-buffer sink.

use defocus::image::ColorImage;
use defocus::lens::{Camera, ThinLens};
use defocus::raster::{
    render_gbuffer, BinnedView, Fragment, PreparedScene, Sink, TileRect, TileSink, View,
};
use defocus::scene::{AlphaMode, Material, Mesh, Scene, Texture, TextureBinding, TextureSampler};
use glam::{Vec2, Vec3};

use crate::{add_screen_rect, test_camera};

/// Counts fragments per pixel.
struct CountSink {
    width: usize,
    counts: Vec<u32>,
}

struct CountTile {
    rect: TileRect,
    counts: Vec<u32>,
}

impl TileSink for CountTile {
    fn fragment(&mut self, f: &Fragment) {
        let i = (f.y as usize - self.rect.y0) * self.rect.width() + f.x as usize - self.rect.x0;
        self.counts[i] += 1;
    }
}

impl Sink for CountSink {
    type Tile = CountTile;
    fn begin_tile(&self, rect: TileRect) -> CountTile {
        CountTile {
            rect,
            counts: vec![0; rect.width() * rect.height()],
        }
    }
    fn end_tile(&mut self, rect: TileRect, tile: CountTile) {
        for (row, y) in (rect.y0..rect.y1).enumerate() {
            for x in rect.x0..rect.x1 {
                self.counts[y * self.width + x] += tile.counts[row * rect.width() + x - rect.x0];
            }
        }
    }
}

fn count(scene: &Scene, camera: &Camera) -> Vec<u32> {
    let lens = camera.thin_lens().unwrap();
    let prepared = PreparedScene::new(scene, &camera.camera_from_world).unwrap();
    let binned = BinnedView::new(&prepared, &View::pinhole(lens)).unwrap();
    let mut sink = CountSink {
        width: lens.width_px,
        counts: vec![0; lens.width_px * lens.height_px],
    };
    binned.rasterize(&prepared, &mut sink);
    sink.counts
}

fn one_material_scene(material: Material) -> Scene {
    let mut scene = Scene::default();
    scene.add_material(material);
    scene
}

#[test]
fn a_fan_of_triangles_covers_each_pixel_exactly_once() {
    // A fan of 7 triangles around an off-grid centre, with vertices at awkward sub-pixel
    // positions: shared edges must be watertight with no double coverage (top-left rule).
    let camera = test_camera(67, 45, 2.0, 2.8);
    let lens = camera.thin_lens().unwrap();
    let mut scene = one_material_scene(Material::color("m", [1.0; 3]));
    let z = 3.0;
    let (cx, cy) = lens.centre_px();
    let world = |x: f32, y: f32| Vec3::new((x - cx) * z / lens.f_px, -(y - cy) * z / lens.f_px, -z);
    let centre = (33.37, 21.61);
    let mut mesh = Mesh::default();
    mesh.positions.push(world(centre.0, centre.1));
    let k = 7;
    for i in 0..k {
        let a = i as f32 / k as f32 * std::f32::consts::TAU + 0.3;
        mesh.positions
            .push(world(centre.0 + 28.3 * a.cos(), centre.1 + 19.7 * a.sin()));
    }
    for i in 0..k as u32 {
        mesh.indices.push([0, 1 + i, 1 + (i + 1) % k as u32]);
    }
    scene.meshes.push(mesh);
    let counts = count(&scene, &camera);
    assert!(counts.iter().all(|&c| c <= 1), "a pixel was covered twice");
    // Pixels well inside the fan are all covered (no cracks).
    for y in 10..34 {
        for x in 22..45 {
            assert_eq!(counts[y * 67 + x], 1, "crack at ({x}, {y})");
        }
    }
}

#[test]
fn a_rectangle_covers_the_pixels_whose_centres_it_contains() {
    let camera = test_camera(40, 30, 2.0, 2.8);
    let mut scene = one_material_scene(Material::color("m", [1.0; 3]));
    // Edges at x = 5.5 (through pixel centres: the left edge includes them) and x = 20.5
    // (right edge excludes them); y from 3.2 to 17.9.
    add_screen_rect(&mut scene, &camera, (5.5, 3.2, 20.5, 17.9), 4.0, 0);
    let counts = count(&scene, &camera);
    let mut expected = 0;
    for y in 0..30 {
        for x in 0..40 {
            let inside = (5..20).contains(&x) && (3..=17).contains(&y);
            expected += inside as u32;
            assert_eq!(counts[y * 40 + x], inside as u32, "pixel ({x}, {y})");
        }
    }
    assert_eq!(expected, 15 * 15);
}

#[test]
fn a_vertex_lands_on_the_pixel_the_camera_predicts_and_depth_is_view_axis() {
    // A camera away from the origin, looking at an angle; a small square around a world
    // point must appear where the thin lens projects that point, with its view depth.
    let from = Vec3::new(0.3, 0.2, 1.0);
    let target = Vec3::new(-0.5, 0.1, -3.0);
    let mut camera = Camera::look_at(from, target, Vec3::Y);
    camera.width_px = 64;
    camera.height_px = 48;
    let lens: ThinLens = camera.thin_lens().unwrap();
    let p = Vec3::new(-0.2, 0.15, -2.0);
    let pc = camera.camera_from_world.transform_point3(p);
    let (px, py, z) = lens.project(pc).unwrap();
    let mut scene = one_material_scene(Material::color("m", [1.0, 0.5, 0.25]));
    // A camera-facing square of 1.2 px around p.
    let half = 0.6 * z / lens.f_px;
    let right = camera
        .camera_from_world
        .inverse()
        .transform_vector3(Vec3::X)
        * half;
    let up = camera
        .camera_from_world
        .inverse()
        .transform_vector3(Vec3::Y)
        * half;
    let mut mesh = Mesh::default();
    mesh.push_quad(p - right + up, right * 2.0, -up * 2.0);
    scene.meshes.push(mesh);
    let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
    let g = render_gbuffer(&prepared, &View::pinhole(lens)).unwrap();
    let (ix, iy) = (px.floor() as usize, py.floor() as usize);
    // The pixel containing the projected point is covered only if its centre is within
    // 0.6 px; pick the pixel whose centre is nearest.
    let nx = (px - 0.5).round() as usize;
    let ny = (py - 0.5).round() as usize;
    assert!(ix.abs_diff(nx) <= 1 && iy.abs_diff(ny) <= 1);
    let d = g.depth.get(nx, ny);
    assert!(
        (d - z).abs() < 1e-4 * z,
        "depth {d}, expected view-axis {z}"
    );
    assert_eq!(g.color.get(nx, ny), [1.0, 0.5, 0.25, 1.0]);
    let covered = g.depth.pixels().iter().filter(|d| d.is_finite()).count();
    assert!(
        (1..=4).contains(&covered),
        "{covered} pixels covered by a 1.2 px square"
    );
}

#[test]
fn depth_on_a_tilted_plane_is_perspective_correct() {
    // Plane z = 2 + 0.5 * x (camera space X); its depth along each pixel's ray is analytic.
    let camera = test_camera(50, 40, 2.0, 2.8);
    let lens = camera.thin_lens().unwrap();
    let mut scene = one_material_scene(Material::color("m", [1.0; 3]));
    let plane_z = |x: f32| 2.0 + 0.5 * x;
    let mut mesh = Mesh::default();
    let (x0, x1, y) = (-1.0f32, 1.0f32, 1.0f32);
    mesh.positions = vec![
        Vec3::new(x0, y, -plane_z(x0)),
        Vec3::new(x1, y, -plane_z(x1)),
        Vec3::new(x1, -y, -plane_z(x1)),
        Vec3::new(x0, -y, -plane_z(x0)),
    ];
    mesh.indices = vec![[0, 1, 2], [0, 2, 3]];
    scene.meshes.push(mesh);
    let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
    let g = render_gbuffer(&prepared, &View::pinhole(lens)).unwrap();
    let (cx, _) = lens.centre_px();
    for px in [3usize, 17, 25, 40, 48] {
        // Ray through pixel centre: X = t * z, with t = (px + 0.5 - cx) / f. z = 2 + 0.5 t z.
        let t = (px as f32 + 0.5 - cx) / lens.f_px;
        let z = 2.0 / (1.0 - 0.5 * t);
        let got = g.depth.get(px, 20);
        assert!(
            (got - z).abs() < 1e-4,
            "pixel {px}: depth {got}, expected {z}"
        );
    }
}

#[test]
fn transparent_surfaces_composite_in_depth_order_whatever_the_submission_order() {
    let camera = test_camera(16, 16, 2.0, 2.8);
    let blend = |name: &str, rgb: [f32; 3], a: f32| Material {
        name: name.into(),
        base_color: [rgb[0], rgb[1], rgb[2], a],
        alpha_mode: AlphaMode::Blend,
        ..Default::default()
    };
    let build = |reverse: bool| {
        let mut scene = Scene::default();
        let red = scene.add_material(Material::color("red", [1.0, 0.0, 0.0]));
        let blue = scene.add_material(blend("blue", [0.0, 0.0, 1.0], 0.5));
        let green = scene.add_material(blend("green", [0.0, 1.0, 0.0], 0.25));
        let behind = scene.add_material(blend("behind", [1.0, 1.0, 1.0], 0.9));
        let mut layers = vec![(3.0, red), (2.0, blue), (1.0, green), (5.0, behind)];
        if reverse {
            layers.reverse();
        }
        for (z, m) in layers {
            add_screen_rect(&mut scene, &camera, (0.0, 0.0, 16.0, 16.0), z, m);
        }
        let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
        render_gbuffer(&prepared, &View::pinhole(camera.thin_lens().unwrap())).unwrap()
    };
    let a = build(false);
    let b = build(true);
    // Red, then blue at 0.5 over it, then green at 0.25; white behind red is hidden.
    let blue_over_red = [0.5, 0.0, 0.5];
    let expected = [
        0.75 * blue_over_red[0],
        0.25 + 0.75 * blue_over_red[1],
        0.75 * blue_over_red[2],
    ];
    for g in [&a, &b] {
        let p = g.color.get(8, 8);
        for k in 0..3 {
            assert!((p[k] - expected[k]).abs() < 1e-6, "{p:?} vs {expected:?}");
        }
        assert_eq!(p[3], 1.0);
        // A Z pass with alpha threshold 0.5: green (0.25) is passed through, blue (0.5) is
        // the nearest surface that opaque by itself: 2 m.
        assert_eq!(
            g.depth.get(8, 8),
            2.0,
            "depth of the nearest surface half opaque"
        );
    }
}

#[test]
fn alpha_mask_cutouts_are_holes() {
    let camera = test_camera(32, 32, 2.0, 2.8);
    let mut scene = Scene::default();
    // Texture: left half alpha 0, right half alpha 1.
    let tex = ColorImage::from_vec(
        4,
        4,
        (0..16)
            .map(|i| {
                if i % 4 < 2 {
                    [1.0, 1.0, 1.0, 0.0]
                } else {
                    [0.0, 1.0, 0.0, 1.0]
                }
            })
            .collect(),
    )
    .unwrap();
    let t = scene.add_texture(Texture::new(tex));
    let back = scene.add_material(Material::color("back", [1.0, 0.0, 0.0]));
    let cut = scene.add_material(Material {
        name: "cut".into(),
        base_color_texture: Some(TextureBinding {
            texture: t,
            sampler: TextureSampler {
                mag_filter: defocus::scene::FilterMode::Nearest,
                ..Default::default()
            },
            uv_transform: Default::default(),
        }),
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        ..Default::default()
    });
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 32.0, 32.0), 4.0, back);
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 32.0, 32.0), 1.0, cut);
    let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
    let g = render_gbuffer(&prepared, &View::pinhole(camera.thin_lens().unwrap())).unwrap();
    assert_eq!(
        g.color.get(4, 16),
        [1.0, 0.0, 0.0, 1.0],
        "hole shows the back"
    );
    assert!((g.depth.get(4, 16) - 4.0).abs() < 1e-5);
    assert_eq!(
        g.color.get(28, 16),
        [0.0, 1.0, 0.0, 1.0],
        "opaque part stays"
    );
    assert!((g.depth.get(28, 16) - 1.0).abs() < 1e-5);
}

#[test]
fn triangles_crossing_the_near_plane_are_clipped_not_dropped() {
    // A floor from behind the camera to far ahead: must cover the lower half of the image.
    let camera = test_camera(40, 30, 2.0, 2.8);
    let mut scene = one_material_scene(Material::color("m", [1.0; 3]));
    let mut mesh = Mesh::default();
    mesh.push_quad(
        Vec3::new(-50.0, -1.0, 5.0),
        Vec3::new(100.0, 0.0, 0.0),
        Vec3::new(0.0, 0.0, -100.0),
    );
    scene.meshes.push(mesh);
    let counts = count(&scene, &camera);
    for x in 0..40 {
        assert_eq!(counts[29 * 40 + x], 1, "bottom row, pixel {x}");
        assert_eq!(counts[5 * 40 + x], 0, "top rows stay empty, pixel {x}");
    }
}

#[test]
fn single_sided_back_faces_are_culled() {
    let camera = test_camera(16, 16, 2.0, 2.8);
    let mut scene = one_material_scene(Material {
        double_sided: false,
        ..Material::color("m", [1.0; 3])
    });
    // Wound clockwise as seen from the camera: a back face.
    let mesh = Mesh {
        positions: vec![
            Vec3::new(-1.0, -1.0, -2.0),
            Vec3::new(0.0, 1.0, -2.0),
            Vec3::new(1.0, -1.0, -2.0),
        ],
        indices: vec![[0, 1, 2]],
        ..Mesh::default()
    };
    scene.meshes.push(mesh.clone());
    assert_eq!(count(&scene, &camera).iter().sum::<u32>(), 0);
    scene.meshes[0].indices = vec![[0, 2, 1]];
    assert!(count(&scene, &camera).iter().sum::<u32>() > 0);
}

#[test]
fn mipmapped_texture_of_a_fine_checker_averages_to_grey_far_away() {
    // A 256x256 one-texel checker seen at ~16 texels per pixel must not alias: mip filtering
    // gives ~0.5 everywhere.
    let camera = test_camera(32, 32, 2.0, 2.8);
    let mut scene = Scene::default();
    let tex = ColorImage::from_vec(
        256,
        256,
        (0..256 * 256)
            .map(|i| {
                let v = ((i % 256 + i / 256) % 2) as f32;
                [v, v, v, 1.0]
            })
            .collect(),
    )
    .unwrap();
    let t = scene.add_texture(Texture::new(tex));
    let m = scene.add_material(Material {
        base_color_texture: Some(TextureBinding {
            texture: t,
            sampler: TextureSampler::default(),
            uv_transform: Default::default(),
        }),
        ..Default::default()
    });
    add_screen_rect(&mut scene, &camera, (0.0, 0.0, 16.0, 16.0), 2.0, m);
    let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
    let g = render_gbuffer(&prepared, &View::pinhole(camera.thin_lens().unwrap())).unwrap();
    for y in 1..15 {
        for x in 1..15 {
            let v = g.color.get(x, y)[0];
            assert!((v - 0.5).abs() < 0.05, "pixel ({x}, {y}) = {v}");
        }
    }
    let _ = Vec2::ZERO;
}

/// The obvious twin of the fixed-point rasterizer: is the pixel centre inside the triangle,
/// by signed distances to its edges in floating point? `None` when the centre is within
/// `eps` pixels of an edge (where rounding decides).
fn naive_inside(p: Vec2, t: [Vec2; 3], eps: f32) -> Option<bool> {
    let area = (t[1] - t[0]).perp_dot(t[2] - t[0]);
    let mut inside = true;
    for k in 0..3 {
        let (a, b) = (t[k], t[(k + 1) % 3]);
        let d = (b - a).perp_dot(p - a) * area.signum() / (b - a).length();
        if d.abs() < eps {
            return None;
        }
        inside &= d > 0.0;
    }
    Some(inside)
}

#[test]
fn coverage_agrees_with_a_naive_point_in_triangle_test_on_random_triangles() {
    // Seeded random triangles on awkward image sizes (odd, 1 pixel wide, 1x1).
    let mut state = 0x1234_5678_u64;
    let mut rnd = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    for (w, h) in [(37usize, 23usize), (1, 17), (1, 1), (64, 64)] {
        let camera = test_camera(w, h, 2.0, 2.8);
        let lens = camera.thin_lens().unwrap();
        let (cx, cy) = lens.centre_px();
        let z = 2.5;
        for _ in 0..40 {
            let t: [Vec2; 3] = std::array::from_fn(|_| {
                Vec2::new(
                    rnd() * (w as f32 + 8.0) - 4.0,
                    rnd() * (h as f32 + 8.0) - 4.0,
                )
            });
            let mut scene = one_material_scene(Material::color("m", [1.0; 3]));
            let mesh = Mesh {
                positions: t
                    .iter()
                    .map(|p| Vec3::new((p.x - cx) * z / lens.f_px, -(p.y - cy) * z / lens.f_px, -z))
                    .collect(),
                indices: vec![[0, 1, 2]],
                ..Mesh::default()
            };
            scene.meshes.push(mesh);
            let counts = count(&scene, &camera);
            for y in 0..h {
                for x in 0..w {
                    let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    if let Some(inside) = naive_inside(p, t, 0.01) {
                        assert_eq!(
                            counts[y * w + x],
                            inside as u32,
                            "{w}x{h} {t:?} pixel ({x}, {y})"
                        );
                    }
                }
            }
        }
    }
}

/// The depth pass is a renderer's Z pass with Blender Cycles' default alpha threshold (0.5):
/// the nearest surface at least half opaque by itself, through any number of fainter ones; a
/// compositor's `blur` of that renderer's frame and Z then blurs what `render` does.
#[test]
fn a_pixel_takes_the_depth_a_z_pass_with_an_alpha_threshold_gives() {
    let camera = test_camera(16, 16, 2.0, 2.8);
    let glass = |scene: &mut Scene, alpha: f32| {
        scene.add_material(Material {
            name: format!("glass {alpha}"),
            base_color: [0.2, 0.4, 0.6, alpha],
            alpha_mode: AlphaMode::Blend,
            ..Default::default()
        })
    };
    let depth_of = |scene: &Scene| {
        let prepared = PreparedScene::new(scene, &camera.camera_from_world).unwrap();
        render_gbuffer(&prepared, &View::pinhole(camera.thin_lens().unwrap()))
            .unwrap()
            .depth
    };
    for (alpha, expected_depth) in [(0.3, 4.0), (0.5, 1.5), (0.7, 1.5)] {
        let mut scene = Scene::default();
        let wall = scene.add_material(Material::color("wall", [1.0; 3]));
        let pane = glass(&mut scene, alpha);
        add_screen_rect(&mut scene, &camera, (0.0, 0.0, 16.0, 16.0), 4.0, wall);
        // The pane covers the left half only; over nothing at all on the far right.
        add_screen_rect(&mut scene, &camera, (0.0, 0.0, 8.0, 16.0), 1.5, pane);
        let depth = depth_of(&scene);
        assert_eq!(depth.get(3, 8), expected_depth, "alpha {alpha}");
        assert_eq!(depth.get(12, 8), 4.0, "beside the pane");
    }
    // Three stacked faint panes (0.30, 0.46, 0.40) before a wall: the wall shows through
    // 0.7 x 0.54 x 0.6 = 23% of the pixel, less than the middle pane's 32%, but no pane is
    // half opaque by itself: the wall's depth, as Cycles' Z pass gives. A half-opaque one
    // among them gives its own.
    for (alphas, expected_depth) in [([0.3, 0.46, 0.4], 4.0), ([0.3, 0.6, 0.4], 2.1)] {
        let mut scene = Scene::default();
        let wall = scene.add_material(Material::color("wall", [1.0; 3]));
        add_screen_rect(&mut scene, &camera, (0.0, 0.0, 16.0, 16.0), 4.0, wall);
        for (alpha, z) in alphas.into_iter().zip([1.5, 2.1, 2.8]) {
            let pane = glass(&mut scene, alpha);
            add_screen_rect(&mut scene, &camera, (0.0, 0.0, 16.0, 16.0), z, pane);
        }
        assert_eq!(
            depth_of(&scene).get(8, 8),
            expected_depth,
            "panes {alphas:?}"
        );
    }
    // A pane over empty space is all the pixel shows: it keeps its depth however faint; of
    // faint ones over nothing, the one that weighs most (0.3 x 0.8 = 0.24 against 0.2).
    for (alphas, expected_depth) in [(vec![0.1], 1.5), (vec![0.7], 1.5), (vec![0.2, 0.3], 2.5)] {
        let mut scene = Scene::default();
        for (&alpha, z) in alphas.iter().zip([1.5, 2.5]) {
            let pane = glass(&mut scene, alpha);
            add_screen_rect(&mut scene, &camera, (0.0, 0.0, 16.0, 16.0), z, pane);
        }
        assert_eq!(
            depth_of(&scene).get(8, 8),
            expected_depth,
            "alphas {alphas:?}"
        );
    }
}
