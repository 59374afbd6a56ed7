//! Tests: `hammon` (GPU Gems 3 ch. 28). Behaviour on small analytic images, the fast passes
//! against their naive twins, the stated blur-level radii, and bad inputs.

use defocus::image::{ColorImage, GrayImage, Rgba};
use defocus::lens::{Camera, ThinLens};
use defocus::methods::hammon::{
    self, blur, coc, composite, downsample, near_coc, CocMode, Constants, HammonSettings,
    LerpDistances, QuarterImage, MEDIUM_BLUR_COC_PX, SMALL_BLUR_COC_PX,
};
use defocus::Error;

use crate::test_camera;

/// Agreement required between a fast pass and its naive twin (same formula, other summation
/// order), relative to 1 + |value|.
const TWIN_TOLERANCE: f32 = 2e-5;
/// Largest relative difference between the 10-90% width of a blurred step edge and the width
/// a disc of the thin-lens CoC would give: the method blends Gaussian-like levels, not discs.
const DISC_EDGE_WIDTH_TOLERANCE: f32 = 0.3;
/// Agreement required where the method should preserve a value (sums of weights that are 1 up
/// to rounding).
const PRESERVE_TOLERANCE: f32 = 1e-5;

/// A seeded generator (64-bit LCG, top 24 bits), uniform in [0, 1).
struct Lcg(u64);

impl Lcg {
    fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0x2545_F491_4F6C_DD1D)
    }

    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }
}

/// Seeded premultiplied colour: alpha in [0.2, 1), colour up to 3x alpha (HDR).
fn seeded_color(w: usize, h: usize, seed: u64) -> ColorImage {
    let mut rng = Lcg::new(seed);
    let px = (0..w * h)
        .map(|_| {
            let a = rng.range(0.2, 1.0);
            [
                rng.range(0.0, 3.0) * a,
                rng.range(0.0, 3.0) * a,
                rng.range(0.0, 3.0) * a,
                a,
            ]
        })
        .collect();
    ColorImage::from_vec(w, h, px).unwrap()
}

/// Seeded signed blur amounts in [-1, 1], a quarter of them exactly 0 (in focus).
fn seeded_amounts(w: usize, h: usize, seed: u64) -> GrayImage {
    let mut rng = Lcg::new(seed);
    let px = (0..w * h)
        .map(|_| {
            if rng.next() < 0.25 {
                0.0
            } else {
                rng.range(-1.0, 1.0)
            }
        })
        .collect();
    GrayImage::from_vec(w, h, px).unwrap()
}

/// The test camera's thin lens.
fn lens(w: usize, h: usize, focus_m: f32, fstop: f32) -> ThinLens {
    test_camera(w, h, focus_m, fstop).thin_lens().unwrap()
}

/// A 150 mm lens, so that a small image has CoCs of tens of pixels: `f_px E = 25 px m` at f/2
/// on a 160-pixel-wide image.
fn tele_lens(w: usize, h: usize, focus_m: f32, fstop: f32) -> ThinLens {
    Camera {
        focal_length_mm: 150.0,
        ..test_camera(w, h, focus_m, fstop)
    }
    .thin_lens()
    .unwrap()
}

/// Default settings with the large blur level set to an equivalent CoC radius of `coc_px`.
fn settings_with_large_blur(coc_px: f32, h: usize) -> HammonSettings {
    let mut s = HammonSettings::default();
    s.set_large_blur_coc_px(coc_px, h).unwrap();
    s
}

/// Largest difference between two RGBA images relative to 1 + |value|.
fn max_rel_diff(a: &[Rgba], b: &[Rgba]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .flat_map(|(p, q)| {
            p.iter()
                .zip(q)
                .map(|(x, y)| (x - y).abs() / (1.0 + y.abs()))
        })
        .fold(0.0, f32::max)
}

/// Largest difference between two gray images relative to 1 + |value|.
fn max_rel_diff_gray(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs() / (1.0 + y.abs()))
        .fold(0.0, f32::max)
}

/// Awkward sizes for the twin tests: single pixels, single rows and columns, odd sizes, sizes
/// that are and are not multiples of 4.
const TWIN_SIZES: [(usize, usize); 10] = [
    (1, 1),
    (1, 5),
    (6, 1),
    (3, 2),
    (5, 7),
    (8, 8),
    (17, 9),
    (37, 23),
    (64, 48),
    (129, 67),
];

#[test]
fn everything_in_focus_returns_the_input_unchanged() {
    for (w, h) in [(1, 1), (37, 23), (64, 48)] {
        let color = seeded_color(w, h, 1);
        let depth = GrayImage::new(w, h, 2.0);
        let out =
            hammon::render(&color, &depth, &lens(w, h, 2.0, 1.4), &Default::default()).unwrap();
        assert_eq!(out.image, color, "{w}x{h}");
        assert!(out.depth.is_none());
    }
}

#[test]
fn the_artist_curve_leaves_its_in_focus_range_unchanged() {
    let (w, h) = (45, 31);
    let color = seeded_color(w, h, 2);
    let mut rng = Lcg::new(3);
    let depth =
        GrayImage::from_vec(w, h, (0..w * h).map(|_| rng.range(2.0, 5.0)).collect()).unwrap();
    let settings = HammonSettings {
        coc: CocMode::Artist {
            near_start_m: 1.0,
            near_end_m: 2.0,
            far_start_m: 5.0,
            far_end_m: 9.0,
        },
        ..Default::default()
    };
    // The lens is not used by the artist curve, whatever its size.
    let out = hammon::render(&color, &depth, &lens(8, 8, 1.0, 2.0), &settings).unwrap();
    assert_eq!(out.image, color);
}

#[test]
fn a_constant_image_stays_constant_for_any_depth_map() {
    let (w, h) = (61, 47);
    let c: Rgba = [0.3, 0.5, 0.7, 1.0];
    let color = ColorImage::new(w, h, c);
    let mut rng = Lcg::new(4);
    let depth = GrayImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|_| {
                if rng.next() < 0.1 {
                    f32::INFINITY
                } else {
                    rng.range(0.2, 30.0)
                }
            })
            .collect(),
    )
    .unwrap();
    let artist = CocMode::Artist {
        near_start_m: 0.5,
        near_end_m: 1.5,
        far_start_m: 3.0,
        far_end_m: 10.0,
    };
    for coc in [CocMode::Physical, artist] {
        let settings = HammonSettings {
            coc,
            far_to_near_ratio: 0.7,
            ..settings_with_large_blur(20.0, h)
        };
        let out = hammon::render(&color, &depth, &tele_lens(w, h, 1.0, 2.0), &settings).unwrap();
        for p in out.image.pixels() {
            for (v, e) in p.iter().zip(c) {
                assert!(
                    (v - e).abs() <= PRESERVE_TOLERANCE,
                    "{p:?} vs {c:?} ({coc:?})"
                );
            }
        }
    }
}

/// Width in pixels between the 10% and 90% crossings of a rising profile from 0 to 1,
/// interpolated linearly between pixel centres.
fn rise_width_10_90(profile: &[f32]) -> f32 {
    let crossing = |level: f32| -> f32 {
        let i = profile.iter().position(|&v| v >= level).unwrap();
        assert!(i > 0, "profile starts above {level}");
        let (a, b) = (profile[i - 1], profile[i]);
        (i - 1) as f32 + (level - a) / (b - a)
    };
    crossing(0.9) - crossing(0.1)
}

#[test]
fn far_field_blur_grows_with_depth() {
    let (w, h) = (160, 96);
    // Black left half, white right half, all at one depth behind the focal plane at 1 m.
    let color = ColorImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|i| {
                if i % w < w / 2 {
                    [0.0, 0.0, 0.0, 1.0]
                } else {
                    [1.0; 4]
                }
            })
            .collect(),
    )
    .unwrap();
    let lens = tele_lens(w, h, 1.0, 2.0);
    let settings = settings_with_large_blur(24.0, h);
    let mut previous = 0.0;
    // |C| = 25 (1 - 1/z) px: 0, 2.3, 5.8, 9.4, 15 and 22.5 px.
    for z in [1.0, 1.1, 1.3, 1.6, 2.5, 10.0] {
        let depth = GrayImage::new(w, h, z);
        let out = hammon::render(&color, &depth, &lens, &settings).unwrap();
        let profile: Vec<f32> = out.image.row(h / 2).iter().map(|p| p[0]).collect();
        let width = rise_width_10_90(&profile);
        assert!(
            width > previous + 0.5,
            "10-90% edge width {width} px at {z} m is not above {previous} px"
        );
        previous = width;
        // A disc of radius R blurs a step over 10-90% width 2 * 0.687 R; the blend of blur
        // levels approximates it.
        let disc_width = 2.0 * 0.687 * lens.coc_px(z).abs();
        if disc_width > 2.0 {
            assert!(
                (width - disc_width).abs() < DISC_EDGE_WIDTH_TOLERANCE * disc_width,
                "{z} m: edge width {width} px, a disc of the lens's CoC gives {disc_width} px"
            );
        }
    }
}

#[test]
fn a_blurred_near_object_spreads_over_the_in_focus_background() {
    let (w, h) = (160, 120);
    let (x0, x1, y0, y1) = (64, 96, 40, 80);
    let blue: Rgba = [0.0, 0.0, 1.0, 1.0];
    let red: Rgba = [1.0, 0.0, 0.0, 1.0];
    let inside = |x: usize, y: usize| (x0..x1).contains(&x) && (y0..y1).contains(&y);
    let color = ColorImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|i| if inside(i % w, i / w) { red } else { blue })
            .collect(),
    )
    .unwrap();
    // Background in focus at 2 m; the square at 0.5 m has C = 25 (1/2 - 1/0.5) = -37.5 px.
    let depth = GrayImage::from_vec(
        w,
        h,
        (0..w * h)
            .map(|i| if inside(i % w, i / w) { 0.5 } else { 2.0 })
            .collect(),
    )
    .unwrap();
    let settings = settings_with_large_blur(24.0, h);
    let out = hammon::render(&color, &depth, &tele_lens(w, h, 2.0, 2.0), &settings).unwrap();
    let img = &out.image;
    let y = (y0 + y1) / 2;
    // The in-focus background next to the object receives its colour...
    for x in [x0 - 4, x0 - 2, x0 - 1, x1, x1 + 1, x1 + 3] {
        assert!(
            img.get(x, y)[0] > 0.2,
            "background ({x}, {y}): {:?}",
            img.get(x, y)
        );
    }
    assert!(
        img.get(x0 + 16, y0 - 2)[0] > 0.2,
        "{:?}",
        img.get(x0 + 16, y0 - 2)
    );
    // ...while far from it the background stays sharp and blue.
    assert_eq!(img.get(4, 4), blue);
    assert_eq!(img.get(w - 5, h - 5), blue);
    // The silhouette is soft: red rises gradually across the left edge, over many pixels.
    let profile: Vec<f32> = (x0 - 24..x0 + 16).map(|x| img.get(x, y)[0]).collect();
    for pair in profile.windows(2) {
        assert!(
            pair[1] >= pair[0] - 1e-4,
            "red does not rise monotonically: {profile:?}"
        );
    }
    let (lo, hi) = (profile[0], profile[profile.len() - 1]);
    let normalised: Vec<f32> = profile.iter().map(|v| (v - lo) / (hi - lo)).collect();
    let width = rise_width_10_90(&normalised);
    assert!(
        width > 8.0,
        "silhouette edge only {width} px wide: {profile:?}"
    );
    // No single step across the silhouette carries more than a fifth of the rise.
    let steepest = normalised
        .windows(2)
        .map(|p| p[1] - p[0])
        .fold(0.0, f32::max);
    assert!(steepest < 0.2, "steepest step {steepest}: {profile:?}");
}

#[test]
fn physical_blur_amount_is_the_thin_lens_coc_over_the_large_blur_radius() {
    let (w, h) = (40, 30);
    let lens = tele_lens(w, h, 1.5, 2.0);
    let settings = settings_with_large_blur(12.0, h);
    let k = Constants::new(&settings, &lens, w, h).unwrap();
    let r = k.large_blur_coc_px();
    assert!((r - 12.0).abs() < 1e-3, "{r}");
    let depths: Vec<f32> = (0..w * h).map(|i| 0.3 + 0.01 * i as f32).collect();
    let s = coc::coc(&GrayImage::from_vec(w, h, depths.clone()).unwrap(), &k).unwrap();
    for (&z, &v) in depths.iter().zip(s.pixels()) {
        let expected = (lens.coc_px(z) / r).clamp(-1.0, 1.0);
        assert!((v - expected).abs() < 1e-6, "{z} m: {v} vs {expected}");
    }
    // Sky gets no far blur, unless the sky depth is infinite.
    let sky = GrayImage::from_vec(2, 1, vec![2e6, f32::INFINITY]).unwrap();
    let k_sky = Constants::new(&settings, &tele_lens(2, 1, 1.5, 2.0), 2, 1).unwrap();
    assert_eq!(coc::coc(&sky, &k_sky).unwrap().pixels(), &[0.0, 0.0]);
    let no_sky = HammonSettings {
        sky_depth_m: f32::INFINITY,
        ..settings
    };
    let lens_sky = tele_lens(2, 1, 1.5, 2.0);
    let k_no_sky = Constants::new(&no_sky, &lens_sky, 2, 1).unwrap();
    let expected = (lens_sky.coc_at_infinity_px() / k_no_sky.large_blur_coc_px()).min(1.0);
    let s = coc::coc(&sky, &k_no_sky).unwrap();
    assert!((s.pixels()[1] - expected).abs() < 1e-6, "{:?}", s.pixels());
}

#[test]
fn artist_curve_follows_figure_28_6() {
    let settings = HammonSettings {
        coc: CocMode::Artist {
            near_start_m: 1.0,
            near_end_m: 2.0,
            far_start_m: 5.0,
            far_end_m: 9.0,
        },
        far_to_near_ratio: 0.5,
        ..Default::default()
    };
    let cases: [(f32, f32); 10] = [
        (0.5, -1.0),
        (1.0, -1.0),
        (1.5, -0.5),
        (2.0, 0.0),
        (3.0, 0.0),
        (5.0, 0.0),
        (7.0, 0.25),
        (9.0, 0.5),
        (100.0, 0.5),
        (2e6, 0.0), // sky
    ];
    let n = cases.len();
    let depth = GrayImage::from_vec(n, 1, cases.iter().map(|c| c.0).collect()).unwrap();
    let k = Constants::new(&settings, &lens(1, 1, 1.0, 2.0), n, 1).unwrap();
    let s = coc::coc(&depth, &k).unwrap();
    for (&(z, e), &v) in cases.iter().zip(s.pixels()) {
        assert!((v - e).abs() < 1e-6, "{z} m: {v}, expected {e}");
    }
    // Degenerate ranges disable a side: no near blur, and no far blur even at infinity.
    let flat = HammonSettings {
        coc: CocMode::Artist {
            near_start_m: 1.0,
            near_end_m: 1.0,
            far_start_m: 5.0,
            far_end_m: 5.0,
        },
        sky_depth_m: f32::INFINITY,
        ..Default::default()
    };
    let depth = GrayImage::from_vec(3, 1, vec![0.1, 50.0, f32::INFINITY]).unwrap();
    let k = Constants::new(&flat, &lens(1, 1, 1.0, 2.0), 3, 1).unwrap();
    assert_eq!(coc::coc(&depth, &k).unwrap().pixels(), &[0.0, 0.0, 0.0]);
}

#[test]
fn downsample_agrees_with_its_naive_twin() {
    for (i, &(w, h)) in TWIN_SIZES.iter().enumerate() {
        let color = seeded_color(w, h, 10 + i as u64);
        let s = seeded_amounts(w, h, 20 + i as u64);
        let fast = downsample::downsample(&color, &s).unwrap();
        let slow = downsample::naive(&color, &s).unwrap();
        assert_eq!(
            (fast.width(), fast.height()),
            (w.div_ceil(4), h.div_ceil(4)),
            "{w}x{h}"
        );
        let d = max_rel_diff(fast.color.pixels(), slow.color.pixels());
        assert!(d <= TWIN_TOLERANCE, "{w}x{h}: colour differs by {d}");
        // The maximum is exact.
        assert_eq!(fast.coc, slow.coc, "{w}x{h}");
    }
}

/// Seeded view-axis depths in metres around a 1 m focus: near (0.2 m) to far (50 m), a tenth
/// of them sky (+inf).
fn seeded_depth(w: usize, h: usize, seed: u64) -> GrayImage {
    let mut rng = Lcg::new(seed);
    let px = (0..w * h)
        .map(|_| {
            if rng.next() < 0.1 {
                f32::INFINITY
            } else {
                0.2 * 250f32.powf(rng.next())
            }
        })
        .collect();
    GrayImage::from_vec(w, h, px).unwrap()
}

/// The render computes the blur amounts from depth inside `downsample` and `composite`
/// (`coc::Amounts::Depth`); both must give the same bits as from the image of pass `coc`,
/// for the thin-lens and the artist curves, dispatched and baseline builds.
#[test]
fn amounts_from_depth_match_the_coc_image_bit_for_bit() {
    let artist = HammonSettings {
        coc: CocMode::Artist {
            near_start_m: 0.3,
            near_end_m: 0.8,
            far_start_m: 1.5,
            far_end_m: 20.0,
        },
        ..Default::default()
    };
    for (i, &(w, h)) in TWIN_SIZES.iter().enumerate() {
        let color = seeded_color(w, h, 100 + i as u64);
        let depth = seeded_depth(w, h, 110 + i as u64);
        for settings in [HammonSettings::default(), artist] {
            let k = Constants::new(&settings, &lens(w, h, 1.0, 1.4), w, h).unwrap();
            let s = coc::coc(&depth, &k).unwrap();
            let from_depth = coc::Amounts::Depth(&depth, &k);
            let shrunk = downsample::downsample(&color, &s).unwrap();
            assert_eq!(downsample::downsample(&color, from_depth).unwrap(), shrunk);
            assert_eq!(
                downsample::downsample_baseline(&color, from_depth).unwrap(),
                shrunk
            );
            let large = blur::blur(&shrunk, k.kernel()).unwrap();
            let medium = near_coc::near_coc(&shrunk, &large).unwrap();
            let out = composite::composite(&color, &s, &medium, &large, &k).unwrap();
            assert_eq!(
                composite::composite(&color, from_depth, &medium, &large, &k).unwrap(),
                out,
                "{w}x{h}"
            );
            assert_eq!(
                composite::composite_baseline(&color, from_depth, &medium, &large, &k).unwrap(),
                out,
                "{w}x{h}"
            );
        }
    }
}

/// Each pass that computes the blur amounts from depth rejects bad depth as pass `coc` does,
/// naming the first bad pixel.
#[test]
fn passes_reading_depth_reject_bad_depth_naming_the_pixel() {
    let (w, h) = (13, 9);
    let color = seeded_color(w, h, 5);
    let k = Constants::new(&HammonSettings::default(), &lens(w, h, 1.0, 2.0), w, h).unwrap();
    let mut depth = GrayImage::new(w, h, 1.0);
    *depth.get_mut(6, 8) = f32::NAN;
    *depth.get_mut(2, 7) = -3.0;
    let quarter = seeded_quarter(w.div_ceil(4), h.div_ceil(4), 3);
    let from_depth = coc::Amounts::Depth(&depth, &k);
    for err in [
        coc::coc(&depth, &k).unwrap_err(),
        downsample::downsample(&color, from_depth).unwrap_err(),
        composite::composite(&color, from_depth, &quarter, &quarter, &k).unwrap_err(),
    ] {
        let msg = err.to_string();
        assert!(
            matches!(err, Error::Invalid { name: "depth", .. }) && msg.contains("(2, 7)"),
            "{msg}"
        );
    }
    // Depth of another size than the constants is a mismatch, not a panic.
    let small = GrayImage::new(w - 1, h, 1.0);
    let err = downsample::downsample(
        &ColorImage::new(w - 1, h, [0.5; 4]),
        coc::Amounts::Depth(&small, &k),
    )
    .unwrap_err();
    assert!(matches!(err, Error::Mismatch(_)), "{err}");
}

/// A seeded quarter-res image: colour and near blur in [0, 1].
fn seeded_quarter(w: usize, h: usize, seed: u64) -> QuarterImage {
    QuarterImage {
        color: seeded_color(w, h, seed),
        coc: seeded_amounts(w, h, seed + 1).map(f32::abs),
    }
}

#[test]
fn gaussian_blur_agrees_with_its_naive_twin() {
    for (i, &(w, h)) in TWIN_SIZES.iter().enumerate() {
        let shrunk = seeded_quarter(w, h, 30 + i as u64);
        for sigma in [0.0, 0.8, 2.3] {
            let kernel = blur::gaussian_kernel(sigma);
            let fast = blur::blur(&shrunk, &kernel).unwrap();
            let slow = blur::naive(&shrunk, &kernel).unwrap();
            let dc = max_rel_diff(fast.color.pixels(), slow.color.pixels());
            let dk = max_rel_diff_gray(fast.coc.pixels(), slow.coc.pixels());
            assert!(
                dc.max(dk) <= TWIN_TOLERANCE,
                "{w}x{h} sigma {sigma}: {dc} {dk}"
            );
        }
    }
    // The identity kernel returns the input exactly.
    let shrunk = seeded_quarter(13, 7, 5);
    assert_eq!(blur::blur(&shrunk, &[1.0]).unwrap(), shrunk);
}

#[test]
fn downsample_and_near_coc_are_bit_identical_to_their_baseline_builds() {
    // The run-time dispatched builds (AVX-512, AVX2 or NEON where present) do the same
    // arithmetic in the same order as the portable builds.
    for (i, &(w, h)) in TWIN_SIZES.iter().enumerate() {
        let color = seeded_color(w, h, 70 + i as u64);
        let s = seeded_amounts(w, h, 80 + i as u64);
        let dispatched = downsample::downsample(&color, &s).unwrap();
        assert_eq!(
            dispatched,
            downsample::downsample_baseline(&color, &s).unwrap(),
            "{w}x{h} downsample"
        );
        let blurred = seeded_quarter(dispatched.width(), dispatched.height(), 90 + i as u64);
        assert_eq!(
            near_coc::near_coc(&dispatched, &blurred).unwrap(),
            near_coc::near_coc_baseline(&dispatched, &blurred).unwrap(),
            "{w}x{h} near CoC"
        );
    }
}

#[test]
fn gaussian_blur_is_bit_identical_to_its_baseline_build() {
    // The run-time dispatched build (AVX-512, AVX2 or NEON where present) does the same
    // multiplies and adds in the same order as the portable build.
    for (i, &(w, h)) in TWIN_SIZES.iter().enumerate() {
        let shrunk = seeded_quarter(w, h, 60 + i as u64);
        for sigma in [0.8, 2.3, 6.0] {
            let kernel = blur::gaussian_kernel(sigma);
            let dispatched = blur::blur(&shrunk, &kernel).unwrap();
            let baseline = blur::blur_baseline(&shrunk, &kernel).unwrap();
            assert_eq!(dispatched, baseline, "{w}x{h} sigma {sigma}");
        }
    }
}

#[test]
fn gaussian_kernel_is_normalised_with_the_stated_radius_and_variance() {
    for sigma in [0.7f32, 1.0, 2.5, 3.75, 9.0] {
        let k = blur::gaussian_kernel(sigma);
        let r = (3.0 * sigma).ceil() as usize;
        assert_eq!(k.len(), 2 * r + 1, "sigma {sigma}");
        let sum: f32 = k.iter().sum();
        assert!((sum - 1.0).abs() < 1e-6, "sigma {sigma}: sum {sum}");
        let var: f32 = k
            .iter()
            .enumerate()
            .map(|(i, w)| w * (i as f32 - r as f32).powi(2))
            .sum();
        // Truncation at 3 sigma loses about 3% of the variance.
        assert!(
            var < sigma * sigma && var > 0.95 * sigma * sigma,
            "sigma {sigma}: {var}"
        );
    }
}

#[test]
fn near_coc_agrees_with_its_naive_twin() {
    for (i, &(w, h)) in TWIN_SIZES.iter().enumerate() {
        let shrunk = seeded_quarter(w, h, 40 + i as u64);
        let blurred = seeded_quarter(w, h, 50 + i as u64);
        let fast = near_coc::near_coc(&shrunk, &blurred).unwrap();
        let slow = near_coc::naive(&shrunk, &blurred).unwrap();
        let dc = max_rel_diff(fast.color.pixels(), slow.color.pixels());
        let dk = max_rel_diff_gray(fast.coc.pixels(), slow.coc.pixels());
        assert!(dc.max(dk) <= TWIN_TOLERANCE, "{w}x{h}: {dc} {dk}");
    }
}

#[test]
fn near_coc_takes_the_larger_coc_across_an_edge_then_blurs_it_3x3() {
    // A straight edge between near blur D0 = 1 (x < 4) and 0, its Gaussian blur DB a ramp
    // 1 - x/8. Listing 28-2: D = 2 max(DB, D0) - D0 = 1 on the left, 2 DB on the right:
    // [1, 1, 1, 1, 1, 0.75, 0.5, 0.25]. Listing 28-3 then gives (D[x-1] + 2 D[x] + D[x+1]) / 4.
    let (w, h) = (8, 3);
    let d0: Vec<f32> = (0..w * h)
        .map(|i| if i % w < 4 { 1.0 } else { 0.0 })
        .collect();
    let db: Vec<f32> = (0..w * h).map(|i| 1.0 - (i % w) as f32 / 8.0).collect();
    let q = |coc: Vec<f32>| QuarterImage {
        color: ColorImage::new(w, h, [0.5; 4]),
        coc: GrayImage::from_vec(w, h, coc).unwrap(),
    };
    let expected = [1.0, 1.0, 1.0, 1.0, 0.9375, 0.75, 0.5, 0.3125];
    for out in [
        near_coc::near_coc(&q(d0.clone()), &q(db.clone())).unwrap(),
        near_coc::naive(&q(d0), &q(db)).unwrap(),
    ] {
        for y in 0..h {
            let row = out.coc.row(y);
            for (x, (v, e)) in row.iter().zip(expected).enumerate() {
                assert!((v - e).abs() < 1e-6, "({x}, {y}): {v}, expected {e}");
            }
        }
        assert!(out.color.pixels().iter().all(|p| *p == [0.5; 4]));
    }
}

#[test]
fn composite_agrees_with_its_naive_twin() {
    for (i, &(w, h)) in TWIN_SIZES.iter().enumerate() {
        let color = seeded_color(w, h, 60 + i as u64);
        let s = seeded_amounts(w, h, 70 + i as u64);
        let (qw, qh) = hammon::quarter_size(w, h);
        let medium = seeded_quarter(qw, qh, 80 + i as u64);
        let large = seeded_quarter(qw, qh, 90 + i as u64);
        for lerp in [
            None,
            Some(LerpDistances {
                d0: 0.2,
                d1: 0.3,
                d2: 0.5,
            }),
        ] {
            let settings = HammonSettings {
                lerp,
                ..Default::default()
            };
            let k = Constants::new(&settings, &lens(w, h, 2.0, 2.0), w, h).unwrap();
            let fast = composite::composite(&color, &s, &medium, &large, &k).unwrap();
            let slow = composite::naive(&color, &s, &medium, &large, &k).unwrap();
            let d = max_rel_diff(fast.pixels(), slow.pixels());
            assert!(d <= TWIN_TOLERANCE, "{w}x{h} {lerp:?}: differs by {d}");
            // The run-time dispatched build (AVX-512, AVX2 or NEON where present) does the
            // same arithmetic in the same order as the portable build.
            let baseline = composite::composite_baseline(&color, &s, &medium, &large, &k).unwrap();
            assert_eq!(
                fast, baseline,
                "{w}x{h} {lerp:?}: dispatched and baseline builds"
            );
        }
    }
}

/// Mean over the 16 positions of a 4x4 block of the per-axis second moment (x and y averaged)
/// of the response to a unit impulse, about the impulse, when every pixel has blur amount `t`.
fn impulse_second_moment(t: f32, settings: &HammonSettings) -> f32 {
    let (w, h) = (96, 96);
    let k = Constants::new(settings, &lens(w, h, 2.0, 2.0), w, h).unwrap();
    let s = GrayImage::new(w, h, t);
    let mut total = 0.0f64;
    for py in 44..48 {
        for px in 44..48 {
            let mut color = ColorImage::new(w, h, [0.0; 4]);
            *color.get_mut(px, py) = [1.0; 4];
            let shrunk = downsample::downsample(&color, &s).unwrap();
            let blurred = blur::blur(&shrunk, k.kernel()).unwrap();
            let medium = near_coc::near_coc(&shrunk, &blurred).unwrap();
            let out = composite::composite(&color, &s, &medium, &blurred, &k).unwrap();
            let (mut sum, mut m2) = (0.0f64, 0.0f64);
            for y in 0..h {
                for x in 0..w {
                    let v = out.get(x, y)[0] as f64;
                    let (dx, dy) = (x as f64 - px as f64, y as f64 - py as f64);
                    sum += v;
                    m2 += v * 0.5 * (dx * dx + dy * dy);
                }
            }
            assert!((sum - 1.0).abs() < 1e-4, "impulse energy {sum}");
            total += m2 / sum;
        }
    }
    (total / 16.0) as f32
}

#[test]
fn blur_levels_match_their_stated_coc_radii() {
    // A disc of radius R has per-axis variance R^2 / 4: each level's equivalent radius is
    // 2 sqrt(second moment).
    let settings = settings_with_large_blur(20.0, 96);
    let k = Constants::new(&settings, &lens(96, 96, 2.0, 2.0), 96, 96).unwrap();
    let d = k.lerp_distances();
    for (t, radius) in [
        (d.d0, SMALL_BLUR_COC_PX),
        (d.d0 + d.d1, MEDIUM_BLUR_COC_PX),
        (1.0, k.large_blur_coc_px()),
    ] {
        let measured = 2.0 * impulse_second_moment(t, &settings).sqrt();
        assert!(
            (measured - radius).abs() < 2e-3 * radius,
            "t = {t}: measured radius {measured} px, stated {radius} px"
        );
    }
    // With the derived blend distances, the blur amount of a level is its radius over the
    // large level's.
    assert!((d.d0 - SMALL_BLUR_COC_PX / 20.0).abs() < 1e-4, "{d:?}");
    assert!(
        (d.d0 + d.d1 - MEDIUM_BLUR_COC_PX / 20.0).abs() < 1e-4,
        "{d:?}"
    );
}

#[test]
fn the_large_blur_is_specified_at_480p_and_scales_with_the_height() {
    let s = HammonSettings::default();
    // At 480p: sigma 10 px = 2.5 quarter-res texels, a 17-tap kernel.
    assert_eq!(s.large_blur_sigma_quarter_px(480), 2.5);
    assert_eq!(blur::gaussian_kernel(2.5).len(), 17);
    assert_eq!(s.large_blur_sigma_quarter_px(720), 3.75);
    let (r480, r720) = (s.large_blur_coc_px(480), s.large_blur_coc_px(720));
    assert!(r720 > 1.45 * r480 && r720 < 1.55 * r480, "{r480} {r720}");
    // Small images keep a large level above the medium one.
    assert!(s.large_blur_coc_px(60) > MEDIUM_BLUR_COC_PX + 1.0);
    // set_large_blur_coc_px inverts large_blur_coc_px.
    let mut t = s;
    t.set_large_blur_coc_px(40.0, 720).unwrap();
    assert!((t.large_blur_coc_px(720) - 40.0).abs() < 1e-3);
    // Radii beyond the largest accepted blur, and non-radii, are errors.
    for bad in [1e9, f32::NAN, 0.0, -3.0] {
        assert!(t.set_large_blur_coc_px(bad, 720).is_err(), "{bad}");
    }
}

#[test]
fn passes_are_timed_under_their_pass_names() {
    let (w, h) = (20, 12);
    let out = hammon::render(
        &seeded_color(w, h, 7),
        &GrayImage::new(w, h, 5.0),
        &lens(w, h, 1.0, 1.4),
        &HammonSettings::default(),
    )
    .unwrap();
    let names: Vec<&str> = out.timings.passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "hammon/downsample",
            "hammon/blur",
            "hammon/near_coc",
            "hammon/composite"
        ]
    );
}

#[test]
fn output_is_bit_identical_with_one_thread_and_with_many() {
    let (w, h) = (83, 61);
    let color = seeded_color(w, h, 8);
    let mut rng = Lcg::new(9);
    let depth =
        GrayImage::from_vec(w, h, (0..w * h).map(|_| rng.range(0.3, 20.0)).collect()).unwrap();
    let lens = tele_lens(w, h, 1.0, 2.0);
    let settings = settings_with_large_blur(16.0, h);
    let run = |threads: usize| {
        crate::with_threads(threads, || {
            hammon::render(&color, &depth, &lens, &settings)
                .unwrap()
                .image
        })
    };
    assert_eq!(run(1), run(4));
}

#[test]
fn size_mismatch_is_an_error_naming_both_sizes() {
    let color = ColorImage::new(8, 6, [0.5; 4]);
    let depth = GrayImage::new(6, 8, 1.0);
    let err =
        hammon::render(&color, &depth, &lens(8, 6, 1.0, 2.0), &Default::default()).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(err, Error::Mismatch(_)) && msg.contains("8x6") && msg.contains("6x8"),
        "{msg}"
    );
    // In physical mode the lens must be set up for the image size.
    let depth = GrayImage::new(8, 6, 1.0);
    let err =
        hammon::render(&color, &depth, &lens(16, 12, 1.0, 2.0), &Default::default()).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(err, Error::Mismatch(_)) && msg.contains("16x12") && msg.contains("8x6"),
        "{msg}"
    );
}

#[test]
fn nan_zero_and_negative_depths_are_errors_naming_the_pixel() {
    let (w, h) = (9, 5);
    let color = ColorImage::new(w, h, [0.5; 4]);
    for bad in [f32::NAN, 0.0, -1.0, f32::NEG_INFINITY] {
        let mut depth = GrayImage::new(w, h, 1.0);
        *depth.get_mut(3, 2) = bad;
        *depth.get_mut(7, 4) = bad;
        let err =
            hammon::render(&color, &depth, &lens(w, h, 1.0, 2.0), &Default::default()).unwrap_err();
        let msg = err.to_string();
        assert!(
            matches!(err, Error::Invalid { name: "depth", .. }) && msg.contains("(3, 2)"),
            "{bad}: {msg}"
        );
    }
}

#[test]
fn infinite_depth_is_accepted_as_sky() {
    let (w, h) = (9, 5);
    let color = seeded_color(w, h, 11);
    let depth = GrayImage::new(w, h, f32::INFINITY);
    // Focus at 1 m: the sky is far behind it, but sky is not blurred.
    let out = hammon::render(&color, &depth, &lens(w, h, 1.0, 1.4), &Default::default()).unwrap();
    assert_eq!(out.image, color);
}

#[test]
fn invalid_settings_are_errors_naming_the_setting() {
    let (w, h) = (4, 4);
    let color = ColorImage::new(w, h, [0.5; 4]);
    let depth = GrayImage::new(w, h, 1.0);
    let base = HammonSettings::default();
    let cases: [(HammonSettings, &str); 7] = [
        (
            HammonSettings {
                coc: CocMode::Artist {
                    near_start_m: 2.0,
                    near_end_m: 1.0,
                    far_start_m: 5.0,
                    far_end_m: 9.0,
                },
                ..base
            },
            "artist CoC distances",
        ),
        (
            HammonSettings {
                far_to_near_ratio: -1.0,
                ..base
            },
            "far-to-near blur ratio",
        ),
        (
            HammonSettings {
                sky_depth_m: f32::NAN,
                ..base
            },
            "sky depth",
        ),
        (
            HammonSettings {
                large_blur_sigma_480p_px: f32::NAN,
                ..base
            },
            "large blur sigma",
        ),
        (
            HammonSettings {
                large_blur_sigma_480p_px: f32::INFINITY,
                ..base
            },
            "large blur sigma",
        ),
        (
            HammonSettings {
                large_blur_sigma_480p_px: 1e6,
                ..base
            },
            "large blur sigma",
        ),
        (
            HammonSettings {
                lerp: Some(LerpDistances {
                    d0: 0.0,
                    d1: 0.5,
                    d2: 0.5,
                }),
                ..base
            },
            "blend distance d0",
        ),
    ];
    for (settings, expected) in cases {
        match hammon::render(&color, &depth, &lens(w, h, 1.0, 2.0), &settings) {
            Err(Error::Invalid { name, .. }) => assert_eq!(name, expected),
            other => panic!("{expected}: {other:?}"),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Against the ground truth.

#[test]
fn hammon_is_closer_to_reference_than_the_pinhole_image_on_railing_and_lights() {
    for name in ["railing", "lights"] {
        let gt = crate::ground_truth(name);
        let out =
            hammon::render(&gt.pinhole, &gt.depth, &gt.lens, &HammonSettings::default()).unwrap();
        let ham = defocus::metrics::compare(&out.image, &gt.truth).unwrap();
        let pin = defocus::metrics::compare(&gt.pinhole, &gt.truth).unwrap();
        eprintln!(
            "{name} 640x360 vs reference (256 samples): hammon PSNR {:.2} dB SSIM {:.4} MSE {:.5}; \
             pinhole PSNR {:.2} dB SSIM {:.4} MSE {:.5}",
            ham.psnr_db, ham.ssim, ham.mse_linear, pin.psnr_db, pin.ssim, pin.mse_linear
        );
        assert!(
            ham.psnr_db > pin.psnr_db + 1.0,
            "{name}: PSNR {ham:?} vs {pin:?}"
        );
        assert!(
            ham.ssim > pin.ssim + 0.02,
            "{name}: SSIM {ham:?} vs {pin:?}"
        );
    }
}

/// `render --method hammon` of an in-focus chart (stripes 2 px wide, focus on it) behind three
/// stacked faint panes (alpha 0.30, 0.46 and 0.40 at 1.5, 2.1 and 2.8 m, no one of them half
/// opaque): the depth pass the method blurs by is the chart's, as a renderer's Z pass with an
/// alpha threshold gives it and as a compositor's `blur` of that renderer's frame uses, so the
/// chart stays as sharp as the pinhole frame (every CoC is zero: the frame comes back). When
/// the depth was the pane that weighs most, the chart took that pane's blur.
#[test]
fn an_in_focus_chart_behind_faint_panes_stays_sharp() {
    use defocus::methods::registry::{self, MethodSettings, PinholeSettings, SceneOptions};
    use defocus::scene::{AlphaMode, Material, Scene};
    let camera = Camera {
        fstop: 1.0,
        ..test_camera(64, 48, 4.0, 1.0)
    };
    let mut scene = Scene::default();
    let white = scene.add_material(Material::color("white", [0.9; 3]));
    let black = scene.add_material(Material::color("black", [0.05; 3]));
    for k in 0..32 {
        let x = 2.0 * k as f32;
        let m = if k % 2 == 0 { white } else { black };
        crate::add_screen_rect(&mut scene, &camera, (x, -8.0, x + 2.0, 56.0), 4.0, m);
    }
    for (k, (alpha, z)) in [(0.3, 1.5), (0.46, 2.1), (0.4, 2.8)]
        .into_iter()
        .enumerate()
    {
        let pane = scene.add_material(Material {
            name: format!("pane{k}"),
            base_color: [0.3, 0.5, 0.4, alpha],
            alpha_mode: AlphaMode::Blend,
            ..Default::default()
        });
        crate::add_screen_rect(&mut scene, &camera, (-8.0, -8.0, 72.0, 56.0), z, pane);
    }
    let options = SceneOptions {
        with_depth: true,
        ..SceneOptions::default()
    };
    let run = |settings: &MethodSettings| {
        registry::run_scene(settings, &scene, &camera, &options, &mut |_, _| {}).unwrap()
    };
    let frame = run(&MethodSettings::Pinhole(PinholeSettings {
        samples: options.frame_samples,
        seed: options.seed,
        ..PinholeSettings::default()
    }));
    let blurred = run(&MethodSettings::Hammon(HammonSettings::default()));
    let depth = frame.depth.as_ref().expect("depth");
    assert!(
        depth.pixels().iter().all(|&z| (z - 4.0).abs() < 1e-3),
        "the depth pass is the chart's"
    );
    let diff = max_rel_diff(frame.image.pixels(), blurred.image.pixels());
    assert!(diff < PRESERVE_TOLERANCE, "the chart blurred: {diff}");
}
