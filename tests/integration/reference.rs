//! Tests: the reference renderer (accumulation over the lens).

use defocus::image::ColorImage;
use defocus::lens::{Aperture, Camera, SamplerKind};
use defocus::methods::reference::{render, ReferenceSettings};
use defocus::methods::{pinhole, MethodOutput};
use defocus::scene::{Material, Scene};

use crate::{add_screen_rect, test_camera};

pub(crate) const SIZE: usize = 96;
/// Lens samples for bokeh-shape tests.
const SAMPLES: usize = 4096;

/// A long lens so that bokeh are tens of pixels wide on a small image.
pub(crate) fn tele_camera(focus_m: f32, fstop: f32) -> Camera {
    Camera {
        focal_length_mm: 150.0,
        ..test_camera(SIZE, SIZE, focus_m, fstop)
    }
}

fn settings(aperture: Aperture, samples: usize) -> ReferenceSettings {
    ReferenceSettings {
        samples,
        aperture,
        ..ReferenceSettings::default()
    }
}

fn run(scene: &Scene, camera: &Camera, s: &ReferenceSettings) -> MethodOutput {
    render(scene, camera, s, &mut |_, _| {}).unwrap()
}

/// A small very bright square at depth `z` centred on the image centre, on black. It is 2 px
/// wide: a smaller light would be hit by too few of the lens samples per bokeh pixel (with N
/// samples the lens points are ~|C| sqrt(pi/N) px apart on screen), and a larger one rounds
/// the polygon's corners. The half-maximum contour of a shape convolved with a small square
/// stays near distance |C| from the centre.
pub(crate) fn point_light_scene(camera: &Camera, z: f32) -> Scene {
    let mut scene = Scene::default();
    let m = scene.add_material(Material::emissive("light", [1.0; 3], 1000.0));
    let c = SIZE as f32 / 2.0;
    add_screen_rect(
        &mut scene,
        camera,
        (c - 1.0, c - 1.0, c + 1.0, c + 1.0),
        z,
        m,
    );
    scene
}

/// Bokeh extent in pixels from the light's centre (the pixel corner at (SIZE/2, SIZE/2)) to
/// the half-plateau crossing along +x, -x, +y, -y, interpolated linearly between pixel centres.
pub(crate) fn extents(img: &ColorImage) -> [f32; 4] {
    let lum: Vec<f32> = img.pixels().iter().map(|p| p[0]).collect();
    let w = img.width();
    let peak = {
        let mut v = lum.clone();
        v.sort_by(f32::total_cmp);
        // Plateau: the median of the brightest third of lit pixels.
        let lit: Vec<f32> = v.into_iter().filter(|&x| x > 0.0).collect();
        lit[lit.len() * 5 / 6]
    };
    let half = peak / 2.0;
    let c = SIZE / 2;
    let walk = |dx: isize, dy: isize| -> f32 {
        let mut prev = lum[c * w + c];
        for step in 1..SIZE as isize / 2 {
            let x = (c as isize + dx * step) as usize;
            let y = (c as isize + dy * step) as usize;
            let v = lum[y * w + x];
            if v < half {
                // Pixel c's centre lies 0.5 px on the + side of the light's centre.
                let t = (prev - half) / (prev - v);
                let from_centre_pixel = step as f32 - 1.0 + t;
                return if dx + dy > 0 {
                    from_centre_pixel + 0.5
                } else {
                    from_centre_pixel - 0.5
                };
            }
            prev = v;
        }
        f32::INFINITY
    };
    [walk(1, 0), walk(-1, 0), walk(0, 1), walk(0, -1)]
}

#[test]
fn point_light_far_behind_focus_becomes_a_disc_of_diameter_two_coc() {
    let camera = tele_camera(1.0, 1.4);
    let z = 50.0;
    let coc = camera.thin_lens().unwrap().coc_px(z);
    assert!(coc > 15.0 && coc < 45.0, "test setup: C = {coc}");
    let out = run(
        &point_light_scene(&camera, z),
        &camera,
        &settings(Aperture::Disc, SAMPLES),
    );
    let e = extents(&out.image);
    // The light sits at the corner between four pixels; the walk starts at pixel centre
    // (c + 0.5), so the edge at distance |C| from the light is |C| - 0.5 from there.
    for (i, d) in e.iter().enumerate() {
        let radius = *d;
        assert!(
            (radius - coc).abs() < 1.0,
            "direction {i}: radius {radius}, |C| = {coc}"
        );
    }
    // Energy: the bokeh carries the light of the pinhole square.
    let pin = pinhole::render(&point_light_scene(&camera, z), &camera, 64, 0, false).unwrap();
    let sum = |img: &ColorImage| img.pixels().iter().map(|p| p[0] as f64).sum::<f64>();
    let (a, b) = (sum(&out.image), sum(&pin.image));
    assert!((a / b - 1.0).abs() < 0.01, "bokeh energy {a}, pinhole {b}");
    // Area above half the plateau close to pi C^2.
    let plateau = out.image.get(SIZE / 2, SIZE / 2)[0];
    let lit = out
        .image
        .pixels()
        .iter()
        .filter(|p| p[0] > 0.5 * plateau)
        .count() as f32;
    let area = std::f32::consts::PI * coc * coc;
    assert!(
        (lit / area - 1.0).abs() < 0.1,
        "lit {lit} px, pi C^2 = {area}"
    );
}

#[test]
fn point_light_through_six_blades_becomes_a_hexagon() {
    let camera = tele_camera(1.0, 1.4);
    let z = 50.0;
    let coc = camera.thin_lens().unwrap().coc_px(z);
    let out = run(
        &point_light_scene(&camera, z),
        &camera,
        &settings(Aperture::parse("poly:6").unwrap(), SAMPLES),
    );
    let [right, left, down, up] = extents(&out.image);
    // Vertices up and down (extent |C|), flat sides left and right (|C| cos 30).
    let flat = coc * (30f32).to_radians().cos();
    assert!(
        (up - coc).abs() < 1.0 && (down - coc).abs() < 1.0,
        "up {up} down {down} C {coc}"
    );
    assert!(
        (left - flat).abs() < 1.0 && (right - flat).abs() < 1.0,
        "left {left} right {right} flat {flat}"
    );
}

#[test]
fn near_field_bokeh_is_the_aperture_turned_half_a_turn() {
    // Five blades: behind focus a vertex points left (extent |C| to the left, |C| cos 36 to
    // the right); in front of focus it points right.
    let camera = tele_camera(2.0, 1.0);
    let lens = camera.thin_lens().unwrap();
    let five = Aperture::parse("poly:5").unwrap();
    let far_z = 400.0;
    // In front: choose z with the same |C| as far_z.
    let c_far = lens.coc_px(far_z);
    let near_z = 1.0 / (1.0 / lens.focus_m + c_far / (lens.f_px * lens.lens_radius_m));
    assert!((lens.coc_px(near_z) + c_far).abs() < 1e-3);
    let side = c_far * (36f32).to_radians().cos();
    let far = run(
        &point_light_scene(&camera, far_z),
        &camera,
        &settings(five.clone(), SAMPLES),
    );
    let near = run(
        &point_light_scene(&camera, near_z),
        &camera,
        &settings(five, SAMPLES),
    );
    let [fr, fl, _, _] = extents(&far.image);
    let [nr, nl, _, _] = extents(&near.image);
    assert!(
        (fl - c_far).abs() < 1.0 && (fr - side).abs() < 1.0,
        "far: left {fl} right {fr}"
    );
    assert!(
        (nr - c_far).abs() < 1.0 && (nl - side).abs() < 1.0,
        "near: left {nl} right {nr}"
    );
}

fn checker_plane_scene(camera: &Camera, z: f32) -> Scene {
    let mut scene = Scene::default();
    let white = scene.add_material(Material::color("white", [0.9; 3]));
    let black = scene.add_material(Material::color("black", [0.05; 3]));
    let n = 12;
    let cell = camera.width_px as f32 / n as f32;
    for j in 0..n {
        for i in 0..n {
            let m = if (i + j) % 2 == 0 { white } else { black };
            let (x0, y0) = (i as f32 * cell, j as f32 * cell);
            add_screen_rect(&mut scene, camera, (x0, y0, x0 + cell, y0 + cell), z, m);
        }
    }
    scene
}

#[test]
fn in_focus_plane_is_as_sharp_as_the_pinhole_image() {
    let camera = test_camera(SIZE, SIZE, 2.0, 1.4);
    let scene = checker_plane_scene(&camera, 2.0);
    let s = settings(Aperture::Disc, 64);
    let dof = run(&scene, &camera, &s);
    let pin = pinhole::render(&scene, &camera, 64, s.seed, false).unwrap();
    let max_diff = dof
        .image
        .pixels()
        .iter()
        .zip(pin.image.pixels())
        .map(|(a, b)| (a[0] - b[0]).abs())
        .fold(0.0f32, f32::max);
    assert!(max_diff < 1e-3, "largest difference {max_diff}");
    // And a plane out of focus is not: it must differ clearly from its pinhole image.
    let blurred_scene = checker_plane_scene(&camera, 2.0);
    let mut off = camera.clone();
    off.focus_m = 1.0;
    let dof = run(&blurred_scene, &off, &s);
    let diff = dof
        .image
        .pixels()
        .iter()
        .zip(pin.image.pixels())
        .map(|(a, b)| (a[0] - b[0]).abs())
        .fold(0.0f32, f32::max);
    assert!(
        diff > 0.2,
        "out-of-focus plane should blur (max difference {diff})"
    );
}

#[test]
fn one_sample_is_exactly_the_pinhole_image() {
    let camera = test_camera(SIZE, SIZE, 2.0, 1.4);
    let scene = checker_plane_scene(&camera, 3.0);
    let one = run(&scene, &camera, &settings(Aperture::Disc, 1));
    let pin = pinhole::render(&scene, &camera, 1, 0, false).unwrap();
    assert_eq!(one.image, pin.image);
}

#[test]
fn output_is_bit_identical_with_one_and_two_threads() {
    let camera = test_camera(SIZE, SIZE, 1.0, 1.4);
    let mut scene = checker_plane_scene(&camera, 3.0);
    let m = scene.add_material(Material::emissive("light", [1.0, 0.5, 0.2], 50.0));
    add_screen_rect(&mut scene, &camera, (40.0, 40.0, 44.0, 44.0), 0.5, m);
    let s = ReferenceSettings {
        sampler: SamplerKind::Stratified,
        seed: 17,
        ..settings(Aperture::parse("poly:7,rot=10").unwrap(), 48)
    };
    let in_pool = |threads: usize| crate::with_threads(threads, || run(&scene, &camera, &s).image);
    let a = in_pool(1);
    let b = in_pool(2);
    let bits = |img: &ColorImage| {
        img.pixels()
            .iter()
            .flat_map(|p| p.map(f32::to_bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&a), bits(&b));
}
