//! Tests: the thin-lens model, apertures and samplers.

use defocus::lens::{coc_px, depth_for_coc_px, Aperture, Camera, SampleSet, SamplerKind};
use glam::{Affine3A, Vec2};

fn cycles_camera() -> Camera {
    // ../shared/assets/cycles/README.md: 35 mm on a 36 mm sensor, 480x270, f/2, focus 2 m.
    Camera {
        width_px: 480,
        height_px: 270,
        camera_from_world: Affine3A::IDENTITY,
        focal_length_mm: 35.0,
        sensor_width_mm: 36.0,
        fstop: 2.0,
        focus_m: 2.0,
        near_m: 0.05,
        far_m: 100.0,
        yfov_rad: None,
    }
}

#[test]
fn coc_has_analytic_values_sign_zero_at_focus_and_limit_at_infinity() {
    // f_px = 1000, E = 1 cm, z_f = 2 m: C(z) = 10 (1/2 - 1/z).
    assert!((coc_px(1000.0, 0.01, 2.0, 4.0) - 2.5).abs() < 1e-6);
    assert!((coc_px(1000.0, 0.01, 2.0, 1.0) + 5.0).abs() < 1e-6);
    assert_eq!(coc_px(1000.0, 0.01, 2.0, 2.0), 0.0);
    assert!(
        coc_px(1000.0, 0.01, 2.0, 1.999) < 0.0,
        "in front of focus is negative"
    );
    assert!(
        coc_px(1000.0, 0.01, 2.0, 2.001) > 0.0,
        "behind focus is positive"
    );
    assert!((coc_px(1000.0, 0.01, 2.0, 1e12) - 5.0).abs() < 1e-5);
    // Infinite depth, and depths whose product with z_f overflows f32: the far limit.
    for z in [f32::INFINITY, 1e38, f32::MAX] {
        assert!((coc_px(1000.0, 0.01, 2.0, z) - 5.0).abs() < 1e-5, "z {z}");
    }
    // Within a few roundings of the formula in f64 over near, focus and far depths.
    for (focus, z) in [
        (2.0f32, 0.05f32),
        (2.0, 1.9999),
        (2.0, 2.0001),
        (0.3, 7.0),
        (40.0, 1e6),
    ] {
        let exact = 1000.0 * 0.01 * (1.0 / f64::from(focus) - 1.0 / f64::from(z));
        let got = f64::from(coc_px(1000.0, 0.01, focus, z));
        assert!(
            (got - exact).abs() <= 1e-6 * exact.abs().max(1e-3),
            "focus {focus} z {z}: {got} vs {exact}"
        );
    }
}

/// The depth of a CoC solves the CoC formula: analytic values, the round trip over near and far
/// radii, and +inf at and beyond the CoC of infinite depth.
#[test]
fn depth_for_coc_inverts_the_coc_and_is_infinite_from_the_far_limit_on() {
    // f_px = 1000, E = 1 cm, z_f = 2 m: C(z) = 10 (1/2 - 1/z), C(inf) = 5.
    assert!((depth_for_coc_px(1000.0, 0.01, 2.0, 2.5) - 4.0).abs() < 1e-5);
    assert!((depth_for_coc_px(1000.0, 0.01, 2.0, -5.0) - 1.0).abs() < 1e-6);
    assert_eq!(depth_for_coc_px(1000.0, 0.01, 2.0, 0.0), 2.0);
    for c in [-300.0f32, -20.0, -1.0, -0.01, 0.01, 1.0, 4.0, 4.99] {
        let z = depth_for_coc_px(1000.0, 0.01, 2.0, c);
        assert!(z > 0.0 && z.is_finite(), "{c} px: {z} m");
        let back = coc_px(1000.0, 0.01, 2.0, z);
        assert!(
            (back - c).abs() < 1e-4 * (1.0 + c.abs()),
            "{c} px -> {z} m -> {back} px"
        );
    }
    for c in [5.0f32, 6.0, 1e6] {
        assert_eq!(
            depth_for_coc_px(1000.0, 0.01, 2.0, c),
            f32::INFINITY,
            "{c} px"
        );
    }
}

#[test]
fn thin_lens_matches_the_cycles_calibration_table() {
    // Bokeh diameters 2|C| from ../shared/assets/cycles/README.md (computed there independently).
    let lens = cycles_camera().thin_lens().unwrap();
    assert!((lens.f_px - 466.6667).abs() < 1e-3);
    assert!((lens.lens_radius_m - 0.00875).abs() < 1e-7);
    for (z, d) in [
        (0.6, 9.528),
        (0.8, 6.125),
        (1.2, 2.722),
        (4.0, 2.042),
        (8.0, 3.063),
        (16.0, 3.573),
        (20.0, 3.675),
    ] {
        let got = 2.0 * lens.coc_px(z).abs();
        assert!(
            (got - d).abs() < 2e-3,
            "z = {z}: 2|C| = {got}, expected {d}"
        );
    }
    assert!((2.0 * lens.coc_at_infinity_px() - 4.083).abs() < 1e-3);
}

#[test]
fn camera_rejects_bad_lens_parameters() {
    let mut c = cycles_camera();
    c.fstop = 0.0;
    assert!(c.thin_lens().unwrap_err().to_string().contains("f-number"));
    let mut c = cycles_camera();
    c.focus_m = -1.0;
    assert!(c.thin_lens().unwrap_err().to_string().contains("focus"));
    let mut c = cycles_camera();
    c.focus_m = 200.0;
    assert!(c.thin_lens().unwrap_err().to_string().contains("far plane"));
    let mut c = cycles_camera();
    c.width_px = 0;
    assert!(c
        .thin_lens()
        .unwrap_err()
        .to_string()
        .contains("image size"));
    let mut c = cycles_camera();
    c.fstop = f32::NAN;
    assert!(c.thin_lens().is_err());
    // Absurd focal lengths and sensors (unit mistakes), and focus inside the focal length.
    for (f_mm, sensor_mm, focus_m, needle) in [
        (35_000.0, 36.0, 2.0, "focal length"),
        (0.01, 36.0, 2.0, "focal length"),
        (35.0, 36_000.0, 2.0, "sensor width"),
        (
            35.0,
            36.0,
            0.03,
            "cannot focus closer than its focal length",
        ),
    ] {
        let mut c = cycles_camera();
        c.near_m = 0.01;
        (c.focal_length_mm, c.sensor_width_mm, c.focus_m) = (f_mm, sensor_mm, focus_m);
        let e = c.thin_lens().unwrap_err().to_string();
        assert!(
            e.contains(needle),
            "{f_mm} mm, {sensor_mm} mm, {focus_m} m: {e}"
        );
    }
}

#[test]
fn polygon_vertices_follow_the_cycles_convention() {
    // 5 blades, rotation 0: a vertex at 180 degrees (pointing left), none up.
    let five = Aperture::parse("poly:5").unwrap().vertices();
    assert!(five
        .iter()
        .any(|v| (*v - Vec2::new(-1.0, 0.0)).length() < 1e-6));
    assert!(five
        .iter()
        .all(|v| (*v - Vec2::new(0.0, -1.0)).length() > 0.1));
    // 6 blades: vertices straight up and down (y down in image axes).
    let six = Aperture::parse("poly:6").unwrap().vertices();
    assert!(six
        .iter()
        .any(|v| (*v - Vec2::new(0.0, -1.0)).length() < 1e-6));
    assert!(six
        .iter()
        .any(|v| (*v - Vec2::new(0.0, 1.0)).length() < 1e-6));
    // Positive rotation turns counter-clockwise on screen: rot=18 moves the left vertex
    // (180 degrees) to 198 degrees, i.e. below the x axis on screen (y down is positive).
    let rotated = Aperture::parse("poly:5,rot=18").unwrap().vertices();
    let a = 198f32.to_radians();
    assert!(rotated
        .iter()
        .any(|v| (*v - Vec2::new(a.cos(), -a.sin())).length() < 1e-5));
}

#[test]
fn aperture_parse_errors_name_the_problem() {
    assert!(Aperture::parse("poly:2")
        .unwrap_err()
        .to_string()
        .contains("blades"));
    assert!(Aperture::parse("poly:x")
        .unwrap_err()
        .to_string()
        .contains("whole number"));
    assert!(Aperture::parse("poly:6,curve=0.5")
        .unwrap_err()
        .to_string()
        .contains("blade radius"));
    assert!(Aperture::parse("square")
        .unwrap_err()
        .to_string()
        .contains("expected disc"));
}

#[test]
fn curved_blades_of_radius_one_make_a_circle() {
    let curved = Aperture::parse("poly:5,curve=1").unwrap();
    let straight = Aperture::parse("poly:5").unwrap();
    assert!((curved.area() - std::f32::consts::PI).abs() < 0.02);
    // Curved blades with a large radius approach the straight polygon; radius 2 lies between.
    let mid = Aperture::parse("poly:5,curve=2").unwrap().area();
    assert!(mid > straight.area() && mid < std::f32::consts::PI, "{mid}");
}

fn check_even_cover(aperture: &Aperture, kind: SamplerKind) {
    let n = 4096;
    let set = SampleSet::generate(aperture, kind, n, 3).unwrap();
    assert_eq!(set.samples.len(), n);
    let mut mean = Vec2::ZERO;
    for s in &set.samples {
        assert!(
            aperture.density(s.lens * 0.9999) > 0.0,
            "{:?} outside {:?}",
            s.lens,
            aperture
        );
        assert!(s.pixel_offset.abs().max_element() <= 0.5);
        mean += s.lens;
    }
    mean /= n as f32;
    assert!(mean.length() < 0.02, "mean {mean} of {aperture:?}");
    // Each of 8 angular sectors gets its share of the area (the shapes tested are symmetric
    // under 90-degree turns or have many sides; 5% tolerance).
    let total = aperture.area();
    for sector in 0..8 {
        let a0 = sector as f32 * std::f32::consts::FRAC_PI_4;
        let count = set
            .samples
            .iter()
            .filter(|s| {
                let a = s.lens.y.atan2(s.lens.x).rem_euclid(std::f32::consts::TAU);
                a >= a0 && a < a0 + std::f32::consts::FRAC_PI_4
            })
            .count();
        // Area of the shape in this sector by quadrature.
        let steps = 400;
        let mut area = 0.0;
        for j in 0..steps {
            for i in 0..steps {
                let v = Vec2::new(
                    (i as f32 + 0.5) / steps as f32 * 2.0 - 1.0,
                    (j as f32 + 0.5) / steps as f32 * 2.0 - 1.0,
                );
                let a = v.y.atan2(v.x).rem_euclid(std::f32::consts::TAU);
                if a >= a0 && a < a0 + std::f32::consts::FRAC_PI_4 {
                    area += aperture.density(v) * 4.0 / (steps * steps) as f32;
                }
            }
        }
        let expected = area / total * n as f32;
        assert!(
            (count as f32 - expected).abs() < 0.05 * expected + 10.0,
            "{aperture:?} {kind:?} sector {sector}: {count} samples, expected {expected}"
        );
    }
}

#[test]
fn samplers_cover_each_aperture_evenly() {
    for kind in [
        SamplerKind::Halton,
        SamplerKind::Sobol,
        SamplerKind::Stratified,
    ] {
        check_even_cover(&Aperture::Disc, kind);
        check_even_cover(&Aperture::parse("poly:8").unwrap(), kind);
        check_even_cover(&Aperture::parse("poly:6,curve=1.5").unwrap(), kind);
    }
}

#[test]
fn one_sample_sits_at_the_lens_and_pixel_centre() {
    let set = SampleSet::generate(&Aperture::Disc, SamplerKind::Halton, 1, 99).unwrap();
    assert_eq!(set.samples.len(), 1);
    assert_eq!(set.samples[0].lens, Vec2::ZERO);
    assert_eq!(set.samples[0].pixel_offset, Vec2::ZERO);
}

#[test]
fn samples_depend_on_the_seed_only() {
    let a = SampleSet::generate(&Aperture::Disc, SamplerKind::Halton, 64, 5).unwrap();
    let b = SampleSet::generate(&Aperture::Disc, SamplerKind::Halton, 64, 5).unwrap();
    let c = SampleSet::generate(&Aperture::Disc, SamplerKind::Halton, 64, 6).unwrap();
    assert_eq!(a, b);
    assert_ne!(a, c);
    assert!(SampleSet::generate(&Aperture::Disc, SamplerKind::Halton, 0, 5).is_err());
}
