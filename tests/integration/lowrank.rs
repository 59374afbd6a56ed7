//! Tests: low-rank bokeh filters (McGraw), tilt-shift, kernel analysis, and the `gaussian` and
//! `poisson` baselines.

use defocus::image::{ColorImage, GrayImage};
use defocus::lens::{Aperture, ThinLens};
use defocus::methods::lowrank::{
    self, decompose, dof, filter, filter_full_2d, filter_separable, kernel_image, tilt_shift_coc,
    tilt_shift_coc_in_frame, CustomShape, KernelSpec, LowRankSettings, TiltShift,
};
use defocus::methods::{gaussian, poisson};
use defocus::Error;

use crate::test_camera;

/// Tolerance for float32 filters against their f64 twins, relative to the signal's scale.
const F32_TOLERANCE: f32 = 2e-5;

/// SplitMix64 for seeded test inputs.
struct Rng(u64);

impl Rng {
    fn next_f32(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn random_image(w: usize, h: usize, seed: u64) -> ColorImage {
    let mut rng = Rng(seed);
    let data = (0..w * h)
        .map(|_| {
            let a = rng.next_f32();
            [
                rng.next_f32() * a * 4.0,
                rng.next_f32() * a,
                rng.next_f32() * a,
                a,
            ]
        })
        .collect();
    ColorImage::from_vec(w, h, data).unwrap()
}

fn max_abs_diff(a: &ColorImage, b: &ColorImage) -> f32 {
    assert!(a.same_size(b));
    a.pixels()
        .iter()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..4).map(move |k| (p[k] - q[k]).abs()))
        .fold(0.0, f32::max)
}

fn kernel(aperture: &str, size: usize) -> GrayImage {
    kernel_image(&KernelSpec::new(Aperture::parse(aperture).unwrap(), size)).unwrap()
}

/// A lens with a long focal length so that bokeh are tens of pixels wide on a small image.
pub(crate) fn tele_lens(size: usize, focus_m: f32, fstop: f32) -> ThinLens {
    defocus::lens::Camera {
        focal_length_mm: 150.0,
        ..test_camera(size, size, focus_m, fstop)
    }
    .thin_lens()
    .unwrap()
}

/// Depth at which the lens has CoC `coc_px` (either sign).
pub(crate) fn depth_for_coc(lens: &ThinLens, coc_px: f32) -> f32 {
    1.0 / (1.0 / lens.focus_m - coc_px / (lens.f_px * lens.lens_radius_m))
}

// ---------------------------------------------------------------------------------------------
// Section 3: decomposition and spatially invariant filtering.

#[test]
fn rank_r_error_equals_the_tail_of_the_singular_values_and_falls_as_r_grows() {
    let k = kernel("poly:6", 33);
    let lr = decompose(&k).unwrap();
    let norm: f64 = k
        .pixels()
        .iter()
        .map(|&v| (v as f64) * (v as f64))
        .sum::<f64>()
        .sqrt();
    let mut previous = f64::INFINITY;
    for r in 0..=lr.len() {
        let approx = lr.approximation(r);
        let direct: f64 = k
            .pixels()
            .iter()
            .zip(approx.pixels())
            .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
            .sum::<f64>()
            .sqrt()
            / norm;
        let e = lr.relative_error(r);
        assert!(
            (e - direct).abs() < 1e-6,
            "rank {r}: eq. 4 gives {e}, ||k - k_r|| / ||k|| = {direct}"
        );
        assert!(
            e <= previous + 1e-12,
            "rank {r}: error {e} rose from {previous}"
        );
        previous = e;
    }
    assert!(lr.relative_error(1) > 0.05, "a hexagon is not separable");
    assert!(lr.relative_error(lr.full_rank()) < 1e-6);
    assert_eq!(lr.relative_error(0), 1.0);
}

#[test]
fn full_rank_separable_filter_reproduces_the_2d_convolution() {
    let img = random_image(37, 23, 1);
    for aperture in ["poly:5", "disc", "poly:7,rot=10"] {
        let k = kernel(aperture, 15);
        let lr = decompose(&k).unwrap();
        let separable = filter_separable(&img, &lr, lr.len());
        let full = filter_full_2d(&img, &k);
        let d = max_abs_diff(&separable, &full);
        assert!(d < F32_TOLERANCE * 4.0, "{aperture}: max difference {d}");
    }
}

#[test]
fn single_bright_pixel_filtered_by_rank_r_reproduces_the_rank_r_kernel() {
    let n = 17;
    let (w, h) = (41, 39);
    let mut img = ColorImage::new(w, h, [0.0; 4]);
    *img.get_mut(20, 19) = [1.0; 4];
    let k = kernel("poly:5", n);
    let lr = decompose(&k).unwrap();
    for rank in 1..=4 {
        let out = filter_separable(&img, &lr, rank);
        let approx = lr.approximation(rank);
        for j in 0..n {
            for i in 0..n {
                let got = out.get(20 + i - n / 2, 19 + j - n / 2)[0];
                let want = approx.get(i, j);
                assert!(
                    (got - want).abs() < 1e-7,
                    "rank {rank}, kernel pixel ({i}, {j}): {got} vs {want}"
                );
            }
        }
        // Nothing outside the kernel's square.
        let outside: f32 = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .filter(|&(x, y)| x.abs_diff(20) > n / 2 || y.abs_diff(19) > n / 2)
            .map(|(x, y)| out.get(x, y)[0].abs())
            .sum();
        assert!(outside < 1e-9, "rank {rank}: {outside} outside the kernel");
    }
}

#[test]
fn kernels_sum_to_one_so_filtering_conserves_energy() {
    let star = CustomShape::parse("star:6").unwrap().aperture().unwrap();
    let heart = CustomShape::parse("heart").unwrap().aperture().unwrap();
    let ring = CustomShape::parse("ring:0.5").unwrap().aperture().unwrap();
    let specs = [
        KernelSpec::new(Aperture::Disc, 65),
        KernelSpec::new(Aperture::parse("poly:8").unwrap(), 33),
        KernelSpec {
            aberration: 1.0,
            ..KernelSpec::new(Aperture::parse("poly:5,curve=1.5").unwrap(), 31)
        },
        KernelSpec {
            aberration: -1.0,
            ..KernelSpec::new(Aperture::parse("poly:6,rot=15").unwrap(), 21)
        },
        KernelSpec::new(star, 41),
        KernelSpec::new(heart, 41),
        KernelSpec::new(ring, 41),
        KernelSpec::new(Aperture::Disc, 1),
    ];
    let mut img = ColorImage::new(71, 71, [0.0; 4]);
    *img.get_mut(35, 35) = [5.0, 1.0, 0.5, 1.0];
    for spec in &specs {
        let k = kernel_image(spec).unwrap();
        let sum: f64 = k.pixels().iter().map(|&v| v as f64).sum();
        assert!((sum - 1.0).abs() < 1e-5, "{spec:?}: sum {sum}");
        assert!(k.pixels().iter().all(|&v| v >= 0.0));
        let out = filter_full_2d(&img, &k);
        let energy: f64 = out.pixels().iter().map(|p| p[0] as f64).sum();
        assert!((energy - 5.0).abs() < 1e-4, "{spec:?}: energy {energy}");
    }
}

#[test]
fn kernel_edges_are_anti_aliased_and_the_shape_is_symmetric() {
    let k = kernel("poly:6", 33);
    let partial = k
        .pixels()
        .iter()
        .filter(|&&v| v > 0.0 && v < 0.99 * k.get(16, 16))
        .count();
    assert!(partial > 40, "only {partial} partially covered pixels");
    // Rotation 0: symmetric about the horizontal axis (rows mirror), as the paper advises.
    for j in 0..33 {
        for i in 0..33 {
            assert!((k.get(i, j) - k.get(i, 32 - j)).abs() < 1e-6);
        }
    }
    // Six blades: vertices up and down, flat sides left and right.
    assert!(k.get(16, 0) > 0.0 && k.get(0, 16) == 0.0);
}

#[test]
fn aberration_brightens_the_rim_when_positive_and_the_centre_when_negative() {
    let spec = |a: f32| KernelSpec {
        aberration: a,
        ..KernelSpec::new(Aperture::parse("poly:8").unwrap(), 33)
    };
    // Pixel (16, 2) lies at |v| = 0.85 (brightness 1.44 for +1, 0.56 for -1), the centre at 0
    // (brightness 0 for +1, 2 for -1).
    let rim = kernel_image(&spec(1.0)).unwrap();
    let centre = kernel_image(&spec(-1.0)).unwrap();
    assert!(rim.get(16, 2) > 100.0 * rim.get(16, 16));
    assert!(centre.get(16, 16) > 3.0 * centre.get(16, 2));
    let flat = kernel_image(&spec(0.0)).unwrap();
    assert_eq!(flat.get(16, 2), flat.get(16, 16));
}

#[test]
fn separable_filter_matches_its_naive_twin_on_odd_and_one_pixel_images() {
    let mut rng = Rng(7);
    let odd_kernel = GrayImage::from_vec(7, 5, (0..35).map(|_| rng.next_f32()).collect()).unwrap();
    let kernels = [kernel("poly:5", 9), odd_kernel, kernel("disc", 1)];
    for (w, h) in [
        (1, 1),
        (1, 7),
        (13, 1),
        (31, 17),
        (4, 9),
        (133, 37),
        (300, 41),
    ] {
        let img = random_image(w, h, (w * 100 + h) as u64);
        for k in &kernels {
            let lr = decompose(k).unwrap();
            for rank in [1, 2, lr.len()] {
                let naive = filter::filter_separable_naive(&img, &lr, rank);
                for schedule in [filter::Schedule::Banded, filter::Schedule::Fig2] {
                    let fast = filter::filter_separable_with(
                        &img,
                        &lr,
                        rank,
                        filter::Channels::Auto,
                        schedule,
                    );
                    let d = max_abs_diff(&fast, &naive);
                    assert!(
                        d < F32_TOLERANCE * 4.0,
                        "{w}x{h}, kernel {}x{}, rank {rank}, {schedule:?}: {d}",
                        k.width(),
                        k.height()
                    );
                }
            }
            let fast = filter_full_2d(&img, k);
            let naive = filter::filter_full_2d_naive(&img, k);
            let d = max_abs_diff(&fast, &naive);
            assert!(d < F32_TOLERANCE * 4.0, "{w}x{h} full 2D: {d}");
        }
    }
}

/// Both schedules give the same bits on one thread as on several: bands and blocks are fixed
/// by the image, not by the thread count, and each output float is one sum in a fixed order.
#[test]
fn separable_filter_bits_do_not_depend_on_the_thread_count() {
    let img = random_image(150, 70, 9);
    let lr = decompose(&kernel("poly:6", 21)).unwrap();
    for schedule in [filter::Schedule::Banded, filter::Schedule::Fig2] {
        let run = |threads: usize| {
            crate::with_threads(threads, || {
                filter::filter_separable_with(&img, &lr, 3, filter::Channels::Auto, schedule)
            })
        };
        assert_eq!(run(1).pixels(), run(3).pixels(), "{schedule:?}");
    }
}

/// An opaque image is filtered in its colour channels only (issue #15's RGB path): the result,
/// alpha included, is bit-identical to filtering all four channels, since every colour float
/// goes through the same products and sums and the alpha is the taps' sum in the same order.
#[test]
fn opaque_images_take_the_colour_only_path_bit_for_bit() {
    let mut rng = Rng(21);
    let odd_kernel = GrayImage::from_vec(7, 5, (0..35).map(|_| rng.next_f32()).collect()).unwrap();
    let kernels = [kernel("poly:6", 17), odd_kernel, kernel("disc", 1)];
    for (w, h) in [(1, 1), (13, 1), (31, 17), (133, 37)] {
        let mut img = random_image(w, h, (w * 31 + h) as u64);
        for p in img.pixels_mut() {
            p[3] = 1.0;
        }
        assert!(filter::is_opaque(&img));
        for k in &kernels {
            let lr = decompose(k).unwrap();
            for rank in [1, 2, lr.len()] {
                for schedule in [filter::Schedule::Banded, filter::Schedule::Fig2] {
                    let with = |channels| {
                        filter::filter_separable_with(&img, &lr, rank, channels, schedule)
                    };
                    let (rgb, rgba) = (with(filter::Channels::Auto), with(filter::Channels::Rgba));
                    assert_eq!(
                        rgb.pixels(),
                        rgba.pixels(),
                        "{w}x{h}, rank {rank}, {schedule:?}"
                    );
                }
            }
            let rgb = filter_full_2d(&img, k);
            let rgba = filter::filter_full_2d_channels(&img, k, filter::Channels::Rgba);
            assert_eq!(rgb.pixels(), rgba.pixels(), "{w}x{h} full 2D");
        }
        // One pixel not quite opaque sends the whole image down the RGBA path.
        img.pixels_mut()[w * h / 2][3] = 0.5;
        assert!(!filter::is_opaque(&img));
    }
}

#[test]
fn bad_kernel_specs_and_kernels_are_errors_not_panics() {
    let bad = [
        KernelSpec::new(Aperture::Disc, 64),
        KernelSpec::new(Aperture::Disc, 0),
        KernelSpec::new(Aperture::Disc, 1025),
        KernelSpec {
            aberration: 1.5,
            ..KernelSpec::default()
        },
        KernelSpec {
            aberration: f32::NAN,
            ..KernelSpec::default()
        },
        KernelSpec {
            supersample: 0,
            ..KernelSpec::default()
        },
    ];
    for spec in &bad {
        assert!(
            matches!(kernel_image(spec), Err(Error::Invalid { .. })),
            "{spec:?}"
        );
    }
    assert!(decompose(&GrayImage::new(5, 5, 0.0)).is_err());
    assert!(decompose(&GrayImage::new(3, 3, f32::NAN)).is_err());
    assert!(CustomShape::parse("star:2").is_err());
    assert!(CustomShape::parse("ring:1.5").is_err());
    assert!(CustomShape::parse("blob").is_err());
    // Rank beyond the decomposition is capped, rank 0 gives black.
    let lr = decompose(&kernel("disc", 5)).unwrap();
    let img = random_image(6, 4, 3);
    let capped = filter_separable(&img, &lr, 99);
    assert!(max_abs_diff(&capped, &filter_separable(&img, &lr, 5)) == 0.0);
    assert!(filter_separable(&img, &lr, 0)
        .pixels()
        .iter()
        .all(|p| *p == [0.0; 4]));
}

// ---------------------------------------------------------------------------------------------
// Section 3.1: the kernel analysis of fig. 3 and fig. 9.

#[test]
fn kernel_analysis_full_ranks_and_low_rank_errors() {
    let size = 65;
    eprintln!("kernel analysis, {size}x{size} kernels, 8x8 samples per pixel, rotation 0");
    eprintln!("full ranks (paper: 5-sided 55, 6-sided 36, 8-sided 38, circular 39):");
    for name in ["poly:5", "poly:6", "poly:8", "disc"] {
        let lr = decompose(&kernel(name, size)).unwrap();
        let loose = lr.rank_above(lr.singular_values()[0] * 1e-6);
        eprintln!(
            "  {name:7} full rank {:2} (above 1e-6 s_1: {loose:2})",
            lr.full_rank()
        );
    }
    let blades = [5u32, 6, 7, 8, 9];
    let errors: Vec<Vec<f64>> = blades
        .iter()
        .map(|b| {
            let lr = decompose(&kernel(&format!("poly:{b}"), size)).unwrap();
            (0..=10).map(|r| lr.relative_error(r)).collect()
        })
        .collect();
    let disc = decompose(&kernel("disc", size)).unwrap();
    eprintln!("relative error (eq. 4) by rank:");
    eprintln!(
        "  rank {}   disc",
        blades.map(|b| format!("  {b} blades")).join("")
    );
    for r in 1..=10 {
        let row: String = errors.iter().map(|e| format!("  {:8.5}", e[r])).collect();
        eprintln!("  {r:4} {row}  {:8.5}", disc.relative_error(r));
    }
    // The paper's observations (section 3.1): even blade counts have lower error than odd ones,
    // and 8 blades the lowest of 5..9, for 2 <= r <= 10.
    /// The ranks the paper discusses, 2 to 10.
    const RANKS: [usize; 9] = [2, 3, 4, 5, 6, 7, 8, 9, 10];
    let mut lowest = Vec::new();
    for r in RANKS {
        let best = (0..blades.len())
            .min_by(|&a, &b| errors[a][r].total_cmp(&errors[b][r]))
            .unwrap();
        lowest.push((r, blades[best]));
    }
    eprintln!("lowest error by rank (rank, blades): {lowest:?}");
    assert!(
        lowest.iter().all(|&(_, b)| b == 8),
        "the paper: 8 blades lowest for 2 <= r <= 10; ours: {lowest:?}"
    );
    for r in RANKS {
        // Even blade counts below their odd neighbours (fig. 3, fig. 9).
        assert!(errors[1][r] < errors[0][r].min(errors[2][r]), "rank {r}");
        assert!(errors[3][r] < errors[2][r].min(errors[4][r]), "rank {r}");
    }
    // Orientation (section 3.1): turning a shape off its axis of symmetry raises the error.
    for name in ["poly:5", "poly:6", "poly:8"] {
        let upright = decompose(&kernel(name, size)).unwrap();
        let turned = decompose(&kernel(&format!("{name},rot=7"), size)).unwrap();
        eprintln!(
            "  {name}: rank-3 error {:.5} upright, {:.5} turned 7 degrees; full rank {} vs {}",
            upright.relative_error(3),
            turned.relative_error(3),
            upright.full_rank(),
            turned.full_rank()
        );
        assert!(turned.relative_error(3) > upright.relative_error(3));
    }
}

#[test]
fn rank_3_error_against_aberration_and_blade_radius_as_fig_9() {
    let size = 65;
    let blades = [5u32, 6, 7, 8, 9, 60];
    let error = |spec: KernelSpec| {
        decompose(&kernel_image(&spec).unwrap())
            .unwrap()
            .relative_error(3)
    };
    eprintln!("rank-3 relative error vs spherical aberration (fig. 9 left), {size} px:");
    eprintln!(
        "  aberration {}",
        blades.map(|b| format!("{b:>8}")).join("")
    );
    let mut by_aberration = Vec::new();
    for a in [-1.0f32, -0.5, 0.0, 0.5, 1.0] {
        let row: Vec<f64> = blades
            .iter()
            .map(|b| {
                error(KernelSpec {
                    aberration: a,
                    ..KernelSpec::new(Aperture::parse(&format!("poly:{b}")).unwrap(), size)
                })
            })
            .collect();
        eprintln!(
            "  {a:10.1} {}",
            row.iter().map(|e| format!("{e:8.4}")).collect::<String>()
        );
        by_aberration.push(row);
    }
    eprintln!("rank-3 relative error vs blade radius (fig. 9 right):");
    eprintln!(
        "  radius     {}",
        blades.map(|b| format!("{b:>8}")).join("")
    );
    let mut by_radius = Vec::new();
    for radius in [1.0f32, 1.25, 1.5, 2.0, 4.0] {
        let row: Vec<f64> = blades
            .iter()
            .map(|b| {
                error(KernelSpec::new(
                    Aperture::parse(&format!("poly:{b},curve={radius}")).unwrap(),
                    size,
                ))
            })
            .collect();
        eprintln!(
            "  {radius:10.2} {}",
            row.iter().map(|e| format!("{e:8.4}")).collect::<String>()
        );
        by_radius.push(row);
    }
    // The paper: straighter blades (larger radius) raise the error of odd blade counts and lower
    // that of even ones; the circle does not depend on it; radius 1 is the circle for all.
    for (k, b) in blades.iter().enumerate() {
        let (from, to) = (by_radius[2][k], by_radius[4][k]);
        match b {
            60 => assert!((from - to).abs() < 1e-3, "circle: {from} {to}"),
            b if b % 2 == 1 => assert!(to > from, "{b} blades: {from} -> {to}"),
            _ => assert!(to < from, "{b} blades: {from} -> {to}"),
        }
        assert!((by_radius[0][k] - by_radius[0][5]).abs() < 1e-3);
    }
    // The paper: a brighter centre (our negative aberration) lowers the error, for every shape.
    for (k, b) in blades.iter().enumerate() {
        assert!(
            by_aberration[0][k] < by_aberration[2][k] && by_aberration[2][k] < by_aberration[4][k],
            "{b} blades: {:?}",
            by_aberration.iter().map(|r| r[k]).collect::<Vec<_>>()
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Section 4: depth of field.

/// Bokeh extents from the light's centre (the corner at (c, c)) to the half-plateau crossing
/// along +x, -x, +y, -y.
pub(crate) fn extents(img: &ColorImage, c: usize) -> [f32; 4] {
    let w = img.width();
    let lum: Vec<f32> = img.pixels().iter().map(|p| p[0]).collect();
    let mut lit: Vec<f32> = lum.iter().copied().filter(|&x| x > 1e-3).collect();
    lit.sort_by(f32::total_cmp);
    let half = lit[lit.len() * 5 / 6] / 2.0;
    let walk = |dx: isize, dy: isize| -> f32 {
        let mut prev = lum[c * w + c];
        for step in 1..(w / 2) as isize {
            let x = (c as isize + dx * step) as usize;
            let y = (c as isize + dy * step) as usize;
            let v = lum[y * w + x];
            if v < half {
                let t = (prev - half) / (prev - v);
                let from_pixel = step as f32 - 1.0 + t;
                return if dx + dy > 0 {
                    from_pixel + 0.5
                } else {
                    from_pixel - 0.5
                };
            }
            prev = v;
        }
        f32::INFINITY
    };
    [walk(1, 0), walk(-1, 0), walk(0, 1), walk(0, -1)]
}

/// A 2x2 bright square centred on the corner (c, c) of a black image, all at depth `z`.
pub(crate) fn point_light(size: usize, z: f32) -> (ColorImage, GrayImage) {
    let mut img = ColorImage::new(size, size, [0.0, 0.0, 0.0, 1.0]);
    let c = size / 2;
    for (x, y) in [(c - 1, c - 1), (c, c - 1), (c - 1, c), (c, c)] {
        *img.get_mut(x, y) = [100.0, 100.0, 100.0, 1.0];
    }
    (img, GrayImage::new(size, size, z))
}

fn settings(aperture: &str) -> LowRankSettings {
    LowRankSettings {
        aperture: Aperture::parse(aperture).unwrap(),
        ..LowRankSettings::default()
    }
}

#[test]
fn point_light_far_behind_focus_becomes_the_aperture_with_diameter_two_coc() {
    let size = 96;
    let lens = tele_lens(size, 1.0, 1.4);
    let z = 50.0;
    let coc = lens.coc_px(z);
    assert!(coc > 15.0 && coc < 40.0, "test setup: C = {coc}");
    let (img, depth) = point_light(size, z);
    // Disc: radius |C| in all four directions.
    let out = lowrank::render(&img, &depth, &lens, &settings("disc")).unwrap();
    let e = extents(&out.image, size / 2);
    for (i, r) in e.iter().enumerate() {
        assert!(
            (r - coc).abs() < 1.0,
            "disc, direction {i}: {r} vs |C| {coc}"
        );
    }
    // Energy: the bokeh carries the light of the square, plus what clamping the rank-3
    // kernel's negative lobes to 0 adds.
    let sum = |im: &ColorImage| im.pixels().iter().map(|p| p[0] as f64).sum::<f64>();
    let gain = sum(&out.image) / sum(&img) - 1.0;
    eprintln!("disc, rank 3, |C| = {coc}: energy gain from clamping the ringing {gain:.4}");
    assert!((0.0..0.02).contains(&gain), "energy gain {gain}");
    // Six blades: vertices up and down (extent |C|), flat sides left and right (|C| cos 30).
    // A low rank blunts the vertices: at |C| = 21 the half-maximum at a vertex is 1.15 px short
    // at rank 3 and 0.34 px short at rank 10 (0.34 is the blunting by the 2x2 light itself).
    let flat = coc * 30f32.to_radians().cos();
    for (rank, vertex_tolerance) in [(3, 1.5), (10, 0.5)] {
        let s = LowRankSettings {
            rank,
            ..settings("poly:6")
        };
        let out = lowrank::render(&img, &depth, &lens, &s).unwrap();
        let [right, left, down, up] = extents(&out.image, size / 2);
        assert!(
            (up - coc).abs() < vertex_tolerance && (down - coc).abs() < vertex_tolerance,
            "rank {rank}: {up} {down} vs {coc}"
        );
        assert!(
            (left - flat).abs() < 0.5 && (right - flat).abs() < 0.5,
            "rank {rank}: {left} {right} vs {flat}"
        );
    }
}

#[test]
fn near_field_bokeh_is_the_aperture_turned_half_a_turn() {
    let size = 96;
    let lens = tele_lens(size, 2.0, 1.0);
    // At most f_px E / z_f = 15 px behind focus.
    let c_far = 12.0;
    let far_z = depth_for_coc(&lens, c_far);
    let near_z = depth_for_coc(&lens, -c_far);
    assert!((lens.coc_px(near_z) + c_far).abs() < 1e-3 && near_z < lens.focus_m);
    let side = c_far * 36f32.to_radians().cos();
    let s = settings("poly:5");
    let (img, depth) = point_light(size, far_z);
    let far = lowrank::render(&img, &depth, &lens, &s).unwrap();
    let (img, depth) = point_light(size, near_z);
    let near = lowrank::render(&img, &depth, &lens, &s).unwrap();
    let [fr, fl, _, _] = extents(&far.image, size / 2);
    let [nr, nl, _, _] = extents(&near.image, size / 2);
    // Behind focus a vertex points left; in front of focus it points right. Rank 3 blunts the
    // vertex (measured: 1.06 px short at |C| = 12), not the flat side.
    assert!(
        (fl - c_far).abs() < 1.5 && (fr - side).abs() < 0.5,
        "far: left {fl} right {fr}"
    );
    assert!(
        (nr - c_far).abs() < 1.5 && (nl - side).abs() < 0.5,
        "near: left {nl} right {nr}"
    );
    assert!((fl - nr).abs() < 1e-3 && (fr - nl).abs() < 1e-3);
}

#[test]
fn in_focus_input_returns_unchanged() {
    let (w, h) = (45, 31);
    let lens = test_camera(w, h, 3.0, 2.0).thin_lens().unwrap();
    let img = random_image(w, h, 11);
    let depth = GrayImage::new(w, h, 3.0);
    let out = lowrank::render(&img, &depth, &lens, &LowRankSettings::default()).unwrap();
    assert_eq!(out.image, img);
    let out = gaussian::render(&img, &depth, &lens, &Default::default()).unwrap();
    assert_eq!(out.image, img);
    let out = poisson::render(&img, &depth, &lens, &Default::default()).unwrap();
    assert_eq!(out.image, img);
}

/// A depth map with a smooth ramp and a step, far and near of focus.
fn ramp_and_step_depth(w: usize, h: usize) -> GrayImage {
    let mut d = GrayImage::new(w, h, 1.0);
    for y in 0..h {
        for x in 0..w {
            *d.get_mut(x, y) = if x < w / 3 {
                0.6 + 0.02 * y as f32
            } else if x < 2 * w / 3 {
                2.0 + 0.2 * x as f32
            } else {
                f32::INFINITY
            };
        }
    }
    d
}

#[test]
fn constant_image_stays_constant_whatever_the_depth() {
    let (w, h) = (60, 40);
    let lens = test_camera(w, h, 1.0, 1.4).thin_lens().unwrap();
    let value = [0.3, 0.5, 0.7, 1.0];
    let img = ColorImage::new(w, h, value);
    let depth = ramp_and_step_depth(w, h);
    let check = |name: &str, out: &ColorImage| {
        for p in out.pixels() {
            for k in 0..4 {
                assert!((p[k] - value[k]).abs() < 1e-5, "{name}: {p:?}");
            }
        }
    };
    for use_mask in [false, true] {
        let s = LowRankSettings {
            use_mask,
            aperture: Aperture::parse("poly:7").unwrap(),
            ..LowRankSettings::default()
        };
        check(
            "lowrank",
            &lowrank::render(&img, &depth, &lens, &s).unwrap().image,
        );
    }
    check(
        "gaussian",
        &gaussian::render(&img, &depth, &lens, &Default::default())
            .unwrap()
            .image,
    );
    check(
        "poisson",
        &poisson::render(&img, &depth, &lens, &Default::default())
            .unwrap()
            .image,
    );
}

/// A CoC map with smooth regions, jumps and both signs, for twin tests.
fn test_coc(w: usize, h: usize, seed: u64) -> GrayImage {
    let mut rng = Rng(seed);
    let mut c = GrayImage::new(w, h, 0.0);
    for y in 0..h {
        for x in 0..w {
            let base = if (x / 7 + y / 5) % 3 == 0 {
                -6.0
            } else {
                4.0 + 0.3 * x as f32
            };
            *c.get_mut(x, y) = base + rng.next_f32() * 2.0 - 1.0;
        }
    }
    c
}

#[test]
fn dof_passes_match_their_naive_twin_on_odd_and_one_pixel_images() {
    for (w, h) in [(1, 1), (1, 9), (9, 1), (37, 21), (70, 5), (150, 40)] {
        let img = random_image(w, h, (w * 31 + h) as u64);
        let coc = test_coc(w, h, 5);
        let max_r = coc.pixels().iter().fold(0.0f32, |m, c| m.max(c.abs()));
        let edges = dof::edges(&coc, 1.0);
        for (aperture, rank) in [("poly:5", 3), ("disc", 1), ("poly:6,rot=20", 4)] {
            let spec = KernelSpec::new(Aperture::parse(aperture).unwrap(), 25);
            let lr = decompose(&kernel_image(&spec).unwrap()).unwrap();
            let bank = dof::KernelBank::new(&lr, rank, max_r).unwrap();
            let mut timings = defocus::timing::Timings::default();
            let (fast, fast_edges) = dof::filter(&img, Some(&edges), &coc, &bank, &mut timings);
            let (naive, naive_edges) =
                dof::naive(&img, Some(&edges), &coc, &lr, rank, max_r).unwrap();
            let d = max_abs_diff(&fast, &naive);
            assert!(d < F32_TOLERANCE * 4.0, "{w}x{h} {aperture} r{rank}: {d}");
            let (fe, ne) = (fast_edges.unwrap(), naive_edges.unwrap());
            let de = fe
                .pixels()
                .iter()
                .zip(ne.pixels())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(de < F32_TOLERANCE, "{w}x{h} edges: {de}");
            // Without edges.
            let (plain, none) = dof::filter(&img, None, &coc, &bank, &mut timings);
            assert!(none.is_none());
            assert_eq!(plain, fast);
        }
    }
}

/// A CoC map with blocks of one CoC (both signs) beside the varying map of [`test_coc`], so
/// that groups of rows share a kernel over long runs of columns and others mix kernels.
fn blocky_coc(w: usize, h: usize, seed: u64) -> GrayImage {
    let mut c = test_coc(w, h, seed);
    for y in 0..h {
        for x in 0..w {
            if x < w / 3 {
                *c.get_mut(x, y) = 5.0;
            } else if y < h / 2 && x < 2 * w / 3 {
                *c.get_mut(x, y) = -7.25;
            }
        }
    }
    c
}

/// The banded schedule of the spatially varying filter (the default) sums each pixel's
/// products in fig. 2's order, so both give the same image bit for bit (a zero's sign aside),
/// whatever the thread count (the slabs, and where each starts its window, follow it), in
/// colour only and RGBA, with and without the edge channel.
#[test]
fn dof_banded_schedule_is_fig2_bit_for_bit() {
    let bits = |img: &ColorImage| -> Vec<u32> {
        img.pixels()
            .iter()
            .flat_map(|p| p.map(|v| if v == 0.0 { 0 } else { v.to_bits() }))
            .collect()
    };
    let gray_bits = |img: &GrayImage| -> Vec<u32> {
        let zero = |v: &f32| if *v == 0.0 { 0 } else { v.to_bits() };
        img.pixels().iter().map(zero).collect()
    };
    for (w, h) in [(1, 1), (9, 1), (1, 9), (150, 40), (97, 70), (64, 130)] {
        let mut img = random_image(w, h, (w * 13 + h) as u64);
        let coc = blocky_coc(w, h, 11);
        let max_r = coc.pixels().iter().fold(0.0f32, |m, c| m.max(c.abs()));
        let edges = dof::edges(&coc, 1.0);
        for (aperture, rank) in [("poly:6", 3), ("disc", 2)] {
            let spec = KernelSpec::new(Aperture::parse(aperture).unwrap(), 25);
            let lr = decompose(&kernel_image(&spec).unwrap()).unwrap();
            let bank = dof::KernelBank::new(&lr, rank, max_r).unwrap();
            for opaque in [false, true] {
                if opaque {
                    for p in img.pixels_mut() {
                        p[3] = 1.0;
                    }
                }
                let mut timings = defocus::timing::Timings::default();
                for edge_image in [Some(&edges), None] {
                    let run = |schedule| {
                        dof::filter_with_schedule(
                            &img,
                            edge_image,
                            &coc,
                            &bank,
                            filter::Channels::Auto,
                            schedule,
                            &mut defocus::timing::Timings::default(),
                        )
                    };
                    let (fig2, fig2_edges) = run(filter::Schedule::Fig2);
                    for threads in [1, 2, 3] {
                        let pool = rayon::ThreadPoolBuilder::new()
                            .num_threads(threads)
                            .build()
                            .unwrap();
                        let (banded, banded_edges) = pool.install(|| run(filter::Schedule::Banded));
                        let at =
                            format!("{w}x{h} {aperture} r{rank} opaque {opaque} {threads} threads");
                        let first_diff =
                            |a: Vec<u32>, b: Vec<u32>| a.iter().zip(&b).position(|(p, q)| p != q);
                        assert_eq!(first_diff(bits(&banded), bits(&fig2)), None, "{at}");
                        assert_eq!(banded_edges.is_some(), fig2_edges.is_some());
                        if let (Some(b), Some(f)) = (&banded_edges, &fig2_edges) {
                            assert_eq!(first_diff(gray_bits(b), gray_bits(f)), None, "{at} edges");
                        }
                    }
                }
                let (_, _) = dof::filter(&img, Some(&edges), &coc, &bank, &mut timings);
                assert!(timings.passes.iter().any(|p| p.name == "lowrank/separable"));
            }
        }
    }
}

/// The spatially varying filter on an opaque image carries only the colour channels: their
/// values are bit-identical to the RGBA path's, and alpha is 1 (every pixel's kernel sums to
/// 1; the RGBA path gets 1 up to rounding). The edge channel is unchanged.
#[test]
fn dof_filter_on_an_opaque_image_is_the_rgba_filter_with_alpha_one() {
    for (w, h) in [(1, 1), (9, 1), (37, 21), (150, 40)] {
        let mut img = random_image(w, h, (w * 7 + h) as u64);
        for p in img.pixels_mut() {
            p[3] = 1.0;
        }
        let coc = test_coc(w, h, 3);
        let max_r = coc.pixels().iter().fold(0.0f32, |m, c| m.max(c.abs()));
        let edges = dof::edges(&coc, 1.0);
        for (aperture, rank) in [("poly:5", 3), ("disc", 1)] {
            let spec = KernelSpec::new(Aperture::parse(aperture).unwrap(), 25);
            let lr = decompose(&kernel_image(&spec).unwrap()).unwrap();
            let bank = dof::KernelBank::new(&lr, rank, max_r).unwrap();
            let mut timings = defocus::timing::Timings::default();
            let (rgb, rgb_edges) = dof::filter(&img, Some(&edges), &coc, &bank, &mut timings);
            let (rgba, rgba_edges) = dof::filter_channels(
                &img,
                Some(&edges),
                &coc,
                &bank,
                filter::Channels::Rgba,
                &mut timings,
            );
            assert_eq!(rgb_edges, rgba_edges);
            for (p, q) in rgb.pixels().iter().zip(rgba.pixels()) {
                assert_eq!(p[..3], q[..3], "{w}x{h} {aperture} r{rank}");
                assert_eq!(p[3], 1.0);
                assert!((q[3] - 1.0).abs() < 1e-5, "RGBA alpha {}", q[3]);
            }
        }
    }
}

#[test]
fn poisson_gather_is_bit_identical_to_its_baseline_build() {
    // The run-time dispatched build (AVX-512, AVX2 or NEON where present; `floor` in one
    // instruction) does the same arithmetic in the same order as the portable build.
    let taps =
        defocus::lens::Taps::poisson_disc(&Aperture::parse("poly:6").unwrap(), 32, 7, 0.0).unwrap();
    for (w, h) in [(1, 1), (9, 1), (37, 21), (150, 40)] {
        let img = random_image(w, h, (w * 13 + h) as u64);
        let coc = test_coc(w, h, 11);
        let mask: Vec<bool> = (0..w * h).map(|i| i % 3 != 0).collect();
        for m in [None, Some(mask.as_slice())] {
            let mut fast = img.clone();
            poisson::gather_into(&mut fast, &img, &coc, &taps, m);
            let mut base = img.clone();
            poisson::gather_into_baseline(&mut base, &img, &coc, &taps, m);
            assert_eq!(fast, base, "{w}x{h}, mask {}", m.is_some());
        }
    }
}

#[test]
fn gaussian_passes_match_their_naive_twin() {
    let s = gaussian::GaussianSettings::default();
    for (w, h) in [(1, 1), (1, 9), (9, 1), (37, 21), (70, 5), (150, 40)] {
        let img = random_image(w, h, (w * 17 + h) as u64);
        let coc = test_coc(w, h, 9);
        let max_r = coc.pixels().iter().fold(0.0f32, |m, c| m.max(c.abs()));
        let table = gaussian::GaussTable::new(&s, max_r);
        let rows = gaussian::horizontal(&img, &coc, &table);
        let fast = gaussian::vertical(&img, &rows, &coc, &table);
        let naive = gaussian::naive(&img, &coc, &s);
        let d = max_abs_diff(&fast, &naive);
        assert!(d < F32_TOLERANCE * 4.0, "{w}x{h}: {d}");
        // The run-time dispatched build (AVX-512, AVX2 or NEON where present) does the same
        // arithmetic in the same order as the portable build.
        let base_rows = gaussian::horizontal_baseline(&img, &coc, &table);
        assert_eq!(base_rows, rows, "{w}x{h} horizontal");
        let base = gaussian::vertical_baseline(&img, &base_rows, &coc, &table);
        assert_eq!(base, fast, "{w}x{h} vertical");
    }
}

#[test]
fn spatially_varying_filter_with_constant_coc_is_the_rank_r_convolution() {
    let (w, h) = (50, 44);
    let img = random_image(w, h, 21);
    let coc = GrayImage::new(w, h, 8.5);
    let spec = KernelSpec::new(Aperture::parse("poly:6").unwrap(), 17);
    let lr = decompose(&kernel_image(&spec).unwrap()).unwrap();
    let s = LowRankSettings {
        aperture: spec.aperture.clone(),
        kernel_size_px: Some(17),
        rank: 17,
        use_mask: false,
        ..LowRankSettings::default()
    };
    // Radius 8.5 with a 17 px base kernel: the taps are the base kernel's pixels exactly.
    let out = lowrank::render_coc(&img, &coc, &s).unwrap();
    let want = filter_full_2d(&img, &lr.approximation(17));
    let d = max_abs_diff(&out.image, &want);
    assert!(d < F32_TOLERANCE * 4.0, "{d}");
}

#[test]
fn depth_edge_mask_covers_the_pixels_whose_kernel_crosses_a_depth_jump() {
    let (w, h) = (80, 30);
    let lens = defocus::lens::Camera {
        focal_length_mm: 150.0,
        ..test_camera(w, h, 1.0, 1.4)
    }
    .thin_lens()
    .unwrap();
    // Left half at 4 m (blurred), right half at 0.5 m (blurred the other way).
    let mut depth = GrayImage::new(w, h, 4.0);
    for y in 0..h {
        for x in w / 2..w {
            *depth.get_mut(x, y) = 0.5;
        }
    }
    let c_left = lens.coc_px(4.0);
    assert!(c_left > 5.0, "test setup: {c_left}");
    let img = random_image(w, h, 4);
    let d = lowrank::render_detailed(&img, &depth, &lens, &LowRankSettings::default()).unwrap();
    let mask = d.mask.unwrap();
    let edges = d.edges.unwrap();
    let y = h / 2;
    assert_eq!(edges.get(w / 2 - 1, y), 1.0);
    assert_eq!(edges.get(w / 2, y), 1.0);
    assert_eq!(edges.get(w / 2 - 2, y), 0.0);
    // Left pixels within their radius of the jump are masked, those well beyond it are not.
    let reach = c_left.floor() as usize;
    assert_eq!(mask.get(w / 2 - reach + 1, y), 1.0);
    assert_eq!(mask.get(w / 2 - reach - 3, y), 0.0);
    let names: Vec<&str> = d
        .output
        .timings
        .passes
        .iter()
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(
        names,
        [
            "lowrank/coc",
            "lowrank/kernel",
            "lowrank/edges",
            "lowrank/separable",
            "lowrank/fallback"
        ]
    );
}

#[test]
fn bad_inputs_are_errors_naming_what_was_expected() {
    let lens = test_camera(8, 6, 2.0, 2.0).thin_lens().unwrap();
    let img = random_image(8, 6, 1);
    let s = LowRankSettings::default();
    let err = lowrank::render(&img, &GrayImage::new(8, 5, 1.0), &lens, &s).unwrap_err();
    assert!(
        matches!(&err, Error::Mismatch(m) if m.contains("8x6") && m.contains("8x5")),
        "{err}"
    );
    let other_lens = test_camera(9, 6, 2.0, 2.0).thin_lens().unwrap();
    assert!(matches!(
        lowrank::render(&img, &GrayImage::new(8, 6, 1.0), &other_lens, &s),
        Err(Error::Mismatch(_))
    ));
    for bad in [f32::NAN, -1.0, 0.0] {
        let mut depth = GrayImage::new(8, 6, 1.0);
        *depth.get_mut(3, 2) = bad;
        let err = lowrank::render(&img, &depth, &lens, &s).unwrap_err();
        assert!(err.to_string().contains("(3, 2)"), "{err}");
        assert!(gaussian::render(&img, &depth, &lens, &Default::default()).is_err());
        assert!(poisson::render(&img, &depth, &lens, &Default::default()).is_err());
    }
    // +inf is the far limit.
    let depth = GrayImage::new(8, 6, f32::INFINITY);
    assert!(lowrank::render(&img, &depth, &lens, &s).is_ok());
    let bad_settings = [
        LowRankSettings {
            rank: 0,
            ..LowRankSettings::default()
        },
        LowRankSettings {
            rank: 40,
            kernel_size_px: Some(17),
            ..LowRankSettings::default()
        },
        LowRankSettings {
            max_coc_px: f32::NAN,
            ..LowRankSettings::default()
        },
        LowRankSettings {
            mask_threshold: 2.0,
            ..LowRankSettings::default()
        },
        LowRankSettings {
            kernel_size_px: Some(16),
            ..LowRankSettings::default()
        },
        LowRankSettings {
            fallback_taps: 0,
            ..LowRankSettings::default()
        },
    ];
    for bad in &bad_settings {
        assert!(
            matches!(
                lowrank::render(&img, &depth, &lens, bad),
                Err(Error::Invalid { .. })
            ),
            "{bad:?}"
        );
    }
    let coc = GrayImage::new(8, 6, f32::NAN);
    assert!(lowrank::render_coc(&img, &coc, &s).is_err());
}

// ---------------------------------------------------------------------------------------------
// Section 4: tilt-shift.

#[test]
fn tilt_shift_band_is_sharp_inside_and_reaches_the_maximum_blur_outside() {
    let (w, h) = (120, 100);
    let ts = TiltShift {
        centre_y: 0.4,
        width: 0.2,
        angle_deg: 0.0,
        max_coc_px: 6.0,
        ramp: 0.2,
    };
    let coc = tilt_shift_coc(w, h, &ts).unwrap();
    // Band from y = 30 to 50 (centre 40, half width 10), full blur 20 px beyond it.
    assert_eq!(coc.get(60, 40), 0.0);
    assert_eq!(coc.get(5, 31), 0.0);
    assert_eq!(coc.get(60, 0), 6.0);
    assert_eq!(coc.get(60, 99), 6.0);
    assert!((coc.get(60, 60) - 6.0 * (60.5 - 50.0) / 20.0).abs() < 1e-4);
    // Turned 90 degrees: a vertical band through the image centre.
    let vertical = tilt_shift_coc(
        w,
        h,
        &TiltShift {
            angle_deg: 90.0,
            ..ts
        },
    )
    .unwrap();
    assert_eq!(vertical.get(60, 0), 0.0);
    assert_eq!(vertical.get(0, 50), 6.0);
    // Filtering: the band stays sharp, the rest is blurred.
    let img = random_image(w, h, 8);
    let out = lowrank::render_coc(&img, &coc, &LowRankSettings::default()).unwrap();
    assert_eq!(out.image.row(40), img.row(40));
    assert_ne!(out.image.row(5), img.row(5));
    assert!(tilt_shift_coc(w, h, &TiltShift { width: -1.0, ..ts }).is_err());
    assert!(tilt_shift_coc(0, h, &ts).is_err());
}

/// A part of a frame (an OpenEXR data window) gets the band of the whole frame: its CoC map is
/// the whole frame's map cut at its place, including a part that reaches past the frame's edge.
#[test]
fn tilt_shift_of_a_part_of_the_frame_is_the_frame_band_cut_out() {
    let (fw, fh) = (120, 100);
    let ts = TiltShift {
        centre_y: 0.3,
        width: 0.2,
        angle_deg: 12.0,
        max_coc_px: 6.0,
        ramp: 0.2,
    };
    let whole = tilt_shift_coc(fw, fh, &ts).unwrap();
    for (x0, y0, w, h) in [(10, 20, 50, 40), (0, 0, fw, fh), (70, 55, 50, 45)] {
        let part = tilt_shift_coc_in_frame(w, h, (x0, y0), (fw, fh), &ts).unwrap();
        for y in 0..h {
            for x in 0..w {
                let (a, b) = (part.get(x, y), whole.get(x + x0 as usize, y + y0 as usize));
                assert!(
                    (a - b).abs() < 1e-3,
                    "({x}, {y}) of the part at ({x0}, {y0}): {a} vs {b}"
                );
            }
        }
    }
    // The frame is not allocated: a huge one is fine, an empty one is refused.
    assert!(tilt_shift_coc_in_frame(8, 8, (0, 0), (200_000, 200_000), &ts).is_ok());
    assert!(tilt_shift_coc_in_frame(8, 8, (0, 0), (0, 10), &ts).is_err());
    // Reaching 10 px past the frame's top-left: the band continues there.
    let over = tilt_shift_coc_in_frame(fw + 20, fh + 20, (-10, -10), (fw, fh), &ts).unwrap();
    for (x, y) in [(0usize, 0usize), (60, 40), (119, 99)] {
        assert!((over.get(x + 10, y + 10) - whole.get(x, y)).abs() < 1e-3);
    }
}

#[test]
fn custom_shapes_are_symmetric_apertures() {
    for (spec, mirror_x) in [("star:5", true), ("heart", true), ("ring", true)] {
        let aperture = CustomShape::parse(spec).unwrap().aperture().unwrap();
        let k = kernel_image(&KernelSpec::new(aperture, 33)).unwrap();
        if mirror_x {
            for j in 0..33 {
                for i in 0..33 {
                    assert!(
                        (k.get(i, j) - k.get(32 - i, j)).abs() < 1e-6,
                        "{spec} ({i}, {j})"
                    );
                }
            }
        }
    }
    // The ring lets no light through its centre.
    let ring = CustomShape::parse("ring:0.5").unwrap().aperture().unwrap();
    let k = kernel_image(&KernelSpec::new(ring, 33)).unwrap();
    assert_eq!(k.get(16, 16), 0.0);
}

// ---------------------------------------------------------------------------------------------
// Against the ground truth (McGraw Table 1: MSE 31% lower than Zhou's Gaussian on average).

#[test]
fn lowrank_is_closer_to_reference_than_the_gaussian_on_lights_and_railing() {
    for name in ["lights", "railing"] {
        let start = std::time::Instant::now();
        let gt = crate::ground_truth(name);
        let reference_ms = start.elapsed().as_millis();
        let (lens, depth) = (&gt.lens, &gt.depth);
        let lr = lowrank::render(
            &gt.pinhole,
            depth,
            lens,
            &LowRankSettings {
                aperture: gt.aperture.clone(),
                ..LowRankSettings::default()
            },
        )
        .unwrap();
        let ga = gaussian::render(&gt.pinhole, depth, lens, &Default::default()).unwrap();
        let po = poisson::render(
            &gt.pinhole,
            depth,
            lens,
            &poisson::PoissonSettings {
                aperture: gt.aperture.clone(),
                ..Default::default()
            },
        )
        .unwrap();
        let mse = |img: &ColorImage| defocus::metrics::mse_linear(img, &gt.truth).unwrap();
        let (m_lr, m_ga, m_po, m_pin) = (
            mse(&lr.image),
            mse(&ga.image),
            mse(&po.image),
            mse(&gt.pinhole),
        );
        eprintln!(
            "{name} 640x360 ({:?}): MSE vs reference (256 samples, {reference_ms} ms if not shared): lowrank {m_lr:.5} \
             gaussian {m_ga:.5} poisson {m_po:.5} pinhole {m_pin:.5}; lowrank {:+.0}% vs gaussian",
            gt.aperture,
            100.0 * (m_lr / m_ga - 1.0)
        );
        assert!(m_lr < m_ga, "{name}: lowrank {m_lr} vs gaussian {m_ga}");
    }
}

/// `level_of` rounds `4 |C|` half away from zero without `f32::round`: the same level as
/// `round` for halves, the floats either side of them, zeros, NaN, infinities and huge values.
#[test]
fn level_of_rounds_as_f32_round() {
    let by_round = |c: f32, levels: usize| ((c.abs() * 4.0).round() as usize).min(levels - 1);
    let mut values = vec![
        0.0f32,
        -0.0,
        f32::NAN,
        f32::INFINITY,
        -f32::INFINITY,
        1e30,
        3e9,
    ];
    for k in 0..2000 {
        let half = (k as f32 + 0.5) / 4.0;
        values.extend([
            half,
            -half,
            half.next_up(),
            half.next_down(),
            k as f32 / 4.0,
        ]);
    }
    let mut rng = Rng(9);
    values.extend((0..10_000).map(|_| (rng.next_f32() - 0.5) * 300.0));
    for levels in [1, 7, 1000, usize::MAX] {
        for &c in &values {
            assert_eq!(
                dof::level_of(c, levels),
                by_round(c, levels),
                "{c} {levels}"
            );
        }
    }
}

/// The bank's vectorised key loop gives each CoC the key of `KernelBank::key` (level by
/// `level_of`, near field after the far one), for halves, their neighbours, values past the
/// last level, zeros of both signs and NaN.
#[test]
fn bank_keys_into_matches_key() {
    let spec = KernelSpec::new(Aperture::Disc, 17);
    let lr = decompose(&kernel_image(&spec).unwrap()).unwrap();
    let bank = dof::KernelBank::new(&lr, 2, 7.9).unwrap();
    let mut values = vec![
        0.0f32,
        -0.0,
        f32::NAN,
        -f32::NAN,
        f32::INFINITY,
        -1e30,
        7.9,
        8.0,
    ];
    for k in 0..80 {
        let half = (k as f32 + 0.5) / 4.0;
        for v in [half, half.next_up(), half.next_down(), k as f32 / 4.0] {
            values.extend([v, -v]);
        }
    }
    let mut keys = vec![0; values.len()];
    bank.keys_into(&values, &mut keys);
    for (&c, &k) in values.iter().zip(&keys) {
        assert_eq!(k, bank.key(c), "{c}");
    }
}

/// `edges` marks exactly the pixels whose CoC differs from a 4-neighbour's by more than the
/// threshold (fig. 15), at the borders too, on images of one row, one column and more.
#[test]
fn edges_mark_jumps_to_any_four_neighbour() {
    for (w, h) in [(1, 1), (1, 7), (9, 1), (37, 21)] {
        let coc = test_coc(w, h, 4);
        let e = dof::edges(&coc, 1.5);
        for y in 0..h {
            for x in 0..w {
                let c = coc.get(x, y);
                let mut jump = false;
                for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if (0..w as i64).contains(&nx) && (0..h as i64).contains(&ny) {
                        jump |= (c - coc.get(nx as usize, ny as usize)).abs() > 1.5;
                    }
                }
                assert_eq!(e.get(x, y), f32::from(u8::from(jump)), "{w}x{h} at {x},{y}");
            }
        }
    }
}
