//! Tests: metrics. Analytic cases, a direct windowed SSIM written from Wang et al. 2004 against
//! the fast separable one, a value computed by scikit-image, and the Cycles calibration renders.

use defocus::image::io::read_color;
use defocus::image::{srgb_encode, ColorImage};
use defocus::metrics::{
    compare, error_map, error_map_top, error_map_with_top, error_ramp, mse_linear, psnr_srgb,
    srgb_abs_diff, ssim_map, ssim_srgb_luma,
};
use defocus::Error;

/// Agreement required between two implementations of the same SSIM formula.
const SSIM_SAME_FORMULA_TOLERANCE: f64 = 1e-10;
/// Agreement required with scikit-image (different code, same definition).
const SSIM_SKIMAGE_TOLERANCE: f64 = 1e-3;

/// A constant opaque image.
fn constant(w: usize, h: usize, rgb: [f32; 3]) -> ColorImage {
    ColorImage::new(w, h, [rgb[0], rgb[1], rgb[2], 1.0])
}

/// An image from a formula of (x, y, channel).
fn from_formula(w: usize, h: usize, f: impl Fn(f64, f64, f64) -> f64) -> ColorImage {
    let px = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            [
                f(x, y, 0.0) as f32,
                f(x, y, 1.0) as f32,
                f(x, y, 2.0) as f32,
                1.0,
            ]
        })
        .collect();
    ColorImage::from_vec(w, h, px).unwrap()
}

/// A seeded image of values in [-0.1, 1.2) (so clamping is exercised), from a fixed LCG.
fn seeded(w: usize, h: usize, seed: u64) -> ColorImage {
    let mut s = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
    let mut next = move || {
        s = s
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((s >> 40) as f32 / (1u64 << 24) as f32) * 1.3 - 0.1
    };
    let px = (0..w * h).map(|_| [next(), next(), next(), 1.0]).collect();
    ColorImage::from_vec(w, h, px).unwrap()
}

/// True when the first three channels of `p` are within `tol` of `q`.
fn close3(p: impl AsRef<[f32]>, q: [f32; 3], tol: f32) -> bool {
    p.as_ref().iter().zip(q).all(|(a, b)| (a - b).abs() <= tol)
}

/// Rec. 601 luma of the clamped, sRGB-encoded pixel (written out here, not taken from the crate).
fn luma(p: [f32; 4]) -> f64 {
    0.299 * srgb_encode(p[0]) as f64
        + 0.587 * srgb_encode(p[1]) as f64
        + 0.114 * srgb_encode(p[2]) as f64
}

/// SSIM straight from Wang et al. 2004, eqs. 13-16, with a 2D Gaussian window (sigma 1.5) and
/// two-pass (mean, then centred) statistics at every window that fits inside the image: the
/// obvious version the separable one is tested against. Returns the map, row-major.
fn naive_ssim_map(a: &ColorImage, b: &ColorImage) -> Vec<f64> {
    let (w, h) = (a.width(), a.height());
    let r = 5.min((w.min(h) - 1) / 2) as isize;
    let g: Vec<f64> = (-r..=r)
        .map(|i| (-((i * i) as f64) / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let total: f64 = g.iter().flat_map(|u| g.iter().map(move |v| u * v)).sum();
    let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
    let mut map = Vec::new();
    for cy in r..h as isize - r {
        for cx in r..w as isize - r {
            // (weight, x, y) over the window centred on (cx, cy).
            let mut window = Vec::new();
            for dy in -r..=r {
                for dx in -r..=r {
                    let wt = g[(dy + r) as usize] * g[(dx + r) as usize] / total;
                    let (x, y) = ((cx + dx) as usize, (cy + dy) as usize);
                    window.push((wt, luma(a.get(x, y)), luma(b.get(x, y))));
                }
            }
            let mx: f64 = window.iter().map(|(wt, x, _)| wt * x).sum();
            let my: f64 = window.iter().map(|(wt, _, y)| wt * y).sum();
            let vx: f64 = window
                .iter()
                .map(|(wt, x, _)| wt * (x - mx) * (x - mx))
                .sum();
            let vy: f64 = window
                .iter()
                .map(|(wt, _, y)| wt * (y - my) * (y - my))
                .sum();
            let vxy: f64 = window
                .iter()
                .map(|(wt, x, y)| wt * (x - mx) * (y - my))
                .sum();
            map.push(
                ((2.0 * mx * my + c1) * (2.0 * vxy + c2))
                    / ((mx * mx + my * my + c1) * (vx + vy + c2)),
            );
        }
    }
    map
}

#[test]
fn an_image_against_itself_has_zero_mse_infinite_psnr_and_ssim_exactly_one() {
    let img = seeded(41, 29, 3);
    let m = compare(&img, &img).unwrap();
    assert_eq!(m.mse_linear, 0.0);
    assert_eq!(m.psnr_db, f64::INFINITY);
    assert!((m.ssim - 1.0).abs() <= 1e-12, "{}", m.ssim);
}

#[test]
fn constant_images_differing_by_a_tenth_have_linear_mse_one_hundredth() {
    let a = constant(9, 7, [0.2, 0.5, 3.0]);
    let b = constant(9, 7, [0.3, 0.4, 3.1]);
    let mse = mse_linear(&a, &b).unwrap();
    assert!((mse - 0.01).abs() < 1e-7, "{mse}");
}

#[test]
fn psnr_is_ten_log10_of_one_over_the_srgb_mse_with_values_clamped() {
    let a = constant(5, 4, [0.2, 0.5, 2.0]);
    let b = constant(5, 4, [0.25, 0.5, 7.0]);
    let d = srgb_encode(0.2) as f64 - srgb_encode(0.25) as f64;
    let want = 10.0 * (1.0 / (d * d / 3.0)).log10();
    let got = psnr_srgb(&a, &b).unwrap();
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
}

#[test]
fn ssim_of_constant_images_is_the_luminance_term_of_their_encoded_luma() {
    for (ra, rb) in [([0.2, 0.4, 0.6], [0.3, 0.1, 0.9]), ([0.0; 3], [1.0; 3])] {
        let (a, b) = (constant(16, 12, ra), constant(16, 12, rb));
        let (la, lb) = (luma(a.get(0, 0)), luma(b.get(0, 0)));
        let c1 = 0.01f64.powi(2);
        let want = (2.0 * la * lb + c1) / (la * la + lb * lb + c1);
        let got = ssim_srgb_luma(&a, &b).unwrap();
        assert!((got - want).abs() < 1e-9, "{got} vs {want}");
    }
}

#[test]
fn fast_ssim_agrees_with_the_direct_windowed_formula_on_awkward_sizes() {
    for (i, (w, h)) in [
        (1, 1),
        (1, 9),
        (9, 1),
        (4, 3),
        (7, 12),
        (11, 11),
        (13, 19),
        (40, 23),
    ]
    .into_iter()
    .enumerate()
    {
        let a = seeded(w, h, 10 + i as u64);
        let b = seeded(w, h, 100 + i as u64);
        let naive = naive_ssim_map(&a, &b);
        let fast = ssim_map(&a, &b).unwrap();
        assert_eq!(fast.pixels().len(), naive.len(), "{w}x{h}");
        for (f, n) in fast.pixels().iter().zip(&naive) {
            assert!((*f as f64 - n).abs() < 1e-6, "{w}x{h}: {f} vs {n}");
        }
        let mean = naive.iter().sum::<f64>() / naive.len() as f64;
        let got = ssim_srgb_luma(&a, &b).unwrap();
        assert!(
            (got - mean).abs() < SSIM_SAME_FORMULA_TOLERANCE,
            "{w}x{h}: {got} vs {mean}"
        );
        // Symmetric in its arguments.
        let swapped = ssim_srgb_luma(&b, &a).unwrap();
        assert!((got - swapped).abs() < 1e-12);
    }
}

#[test]
fn ssim_map_covers_the_windows_inside_the_image() {
    let a = seeded(30, 20, 1);
    let map = ssim_map(&a, &a).unwrap();
    assert_eq!((map.width(), map.height()), (20, 10));
    let small = seeded(6, 8, 2);
    let map = ssim_map(&small, &small).unwrap();
    assert_eq!((map.width(), map.height()), (2, 4));
}

#[test]
fn ssim_matches_scikit_image_on_a_formula_defined_pair() {
    // Reference computed with scikit-image 0.26.0 (scipy 1.17.1, numpy 2.4.6) from the same
    // formulas in float64, cast to float32 as here, then clamped, sRGB-encoded and turned into
    // Rec. 601 luma in float64 (la, lb: 48x64 arrays), and
    //   skimage.metrics.structural_similarity(la, lb, gaussian_weights=True, sigma=1.5,
    //                                         use_sample_covariance=False, data_range=1.0)
    const SKIMAGE_SSIM: f64 = 0.717_947_514_593_056_2;
    let (w, h) = (64, 48);
    let base = |x: f64, y: f64, c: f64| {
        0.45 + 0.35 * (0.23 * x + 0.11 * y + 1.7 * c).sin() * (0.07 * x - 0.19 * y).cos()
    };
    let a = from_formula(w, h, base);
    let b = from_formula(w, h, |x, y, c| {
        let spot = if (x - 40.0).powi(2) + (y - 20.0).powi(2) < 16.0 {
            0.8
        } else {
            0.0
        };
        base(x, y, c) + 0.06 * (x * y / 14.0 + c).sin() + 0.03 * (1.3 * x + 2.1 * y).cos() + spot
    });
    let got = ssim_srgb_luma(&a, &b).unwrap();
    assert!(
        (got - SKIMAGE_SSIM).abs() < SSIM_SKIMAGE_TOLERANCE,
        "ours {got}, scikit-image {SKIMAGE_SSIM}"
    );
}

#[test]
fn images_of_different_sizes_are_a_mismatch_naming_both_sizes() {
    let a = constant(4, 3, [0.5; 3]);
    let b = constant(3, 4, [0.5; 3]);
    let checks: [Box<dyn Fn() -> Result<(), Error>>; 4] = [
        Box::new(|| mse_linear(&a, &b).map(drop)),
        Box::new(|| psnr_srgb(&a, &b).map(drop)),
        Box::new(|| ssim_srgb_luma(&a, &b).map(drop)),
        Box::new(|| error_map(&a, &b).map(drop)),
    ];
    for check in checks {
        let err = check().unwrap_err();
        assert!(matches!(err, Error::Mismatch(_)), "{err}");
        let msg = err.to_string();
        assert!(msg.contains("4x3") && msg.contains("3x4"), "{msg}");
    }
}

#[test]
fn error_map_is_black_where_equal_and_white_at_the_99th_percentile_difference() {
    let a = constant(20, 10, [0.1; 3]);
    assert!(error_map(&a, &a)
        .unwrap()
        .pixels()
        .iter()
        .all(|p| *p == [0.0, 0.0, 0.0, 1.0]));

    // 5 of 200 pixels (more than 1%) differ by 0.5 in sRGB: that is the 99th percentile.
    let up = |d: f32| defocus::image::srgb_decode(srgb_encode(0.1) + d);
    let mut b = a.clone();
    for x in 0..5 {
        *b.get_mut(x, 0) = [up(0.5), up(0.5), up(0.5), 1.0];
    }
    let diff = srgb_abs_diff(&a, &b).unwrap();
    assert!((diff.get(0, 0) - 0.5).abs() < 1e-5);
    assert_eq!(error_map_top(&diff), diff.get(0, 0));
    let map = error_map(&a, &b).unwrap();
    assert!(close3(map.get(0, 0), [1.0; 3], 1e-6), "{:?}", map.get(0, 0));
    assert_eq!(map.get(10, 5), [0.0, 0.0, 0.0, 1.0]);

    // Small differences use the minimum scale: 0.05 of 0.1 is half way up the ramp.
    let c = constant(20, 10, [up(0.05); 3]);
    let map = error_map(&a, &c).unwrap();
    assert!(
        close3(map.get(3, 3), error_ramp(0.5), 1e-3),
        "{:?}",
        map.get(3, 3)
    );
    // A shared scale can be imposed.
    let fixed = error_map_with_top(&a, &c, 0.05).unwrap();
    assert!(
        close3(fixed.get(3, 3), [1.0; 3], 1e-3),
        "{:?}",
        fixed.get(3, 3)
    );
    assert!(error_map_with_top(&a, &c, 0.0).is_err());
}

#[test]
fn error_ramp_runs_from_black_to_white_with_rising_luma() {
    assert_eq!(error_ramp(0.0), [0.0, 0.0, 0.0]);
    assert!(close3(error_ramp(1.0), [1.0; 3], 1e-6));
    assert!(close3(error_ramp(f32::NAN), [1.0; 3], 1e-6));
    let lum = |c: [f32; 3]| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
    let mut last = -1.0;
    for i in 0..=1000 {
        let l = lum(error_ramp(i as f32 / 1000.0));
        assert!(l > last, "luminance falls at t = {}", i as f32 / 1000.0);
        last = l;
    }
}

#[test]
fn metrics_serialise_with_their_field_names() {
    let a = constant(12, 12, [0.2; 3]);
    let b = constant(12, 12, [0.3; 3]);
    let json = serde_json::to_value(compare(&a, &b).unwrap()).unwrap();
    for key in ["mse_linear", "psnr_db", "ssim"] {
        assert!(json[key].is_number(), "{json}");
    }
}

#[test]
fn cycles_pinhole_against_round_aperture_matches_the_published_psnr_and_ssim() {
    let Some(assets) = crate::shared_assets() else {
        return;
    };
    // Published in assets/cycles/README.md ("Noise level" table).
    const PSNR_DB: f64 = 30.13;
    const SSIM: f64 = 0.98148;
    let pinhole = read_color(&assets.join("cycles/pinhole.exr")).unwrap();
    let disc = read_color(&assets.join("cycles/dof_disc.exr")).unwrap();
    let m = compare(&pinhole, &disc).unwrap();
    eprintln!("cycles pinhole vs dof_disc: {m:?}");
    assert!((m.psnr_db - PSNR_DB).abs() < 0.01, "PSNR {}", m.psnr_db);
    assert!((m.ssim - SSIM).abs() < 1e-3, "SSIM {}", m.ssim);
}

#[test]
fn empty_images_are_refused_rather_than_giving_nan() {
    let a = ColorImage::new(0, 4, [0.0; 4]);
    let err = compare(&a, &a).unwrap_err();
    assert!(matches!(err, Error::Invalid { .. }), "{err}");
    assert!(err.to_string().contains("0x4"), "{err}");
}
