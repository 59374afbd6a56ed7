//! Tests: the post-process commands run as a user would: `blur` on colour + depth files,
//! `render --method hammon|lowrank|gaussian|poisson`, and `kernel`.

use std::path::{Path, PathBuf};
use std::process::Command;

use defocus::image::io::{ExrOptions, Placement};
use defocus::image::{io, ColorImage, GrayImage};

use crate::cli::{defocus, s, stderr, temp_dir};

const W: usize = 48;
const H: usize = 32;

/// The lens flags of the frame tests: f_px = 200/36*48 = 267 px, lens radius 0.1 m, focus at
/// 2 m: C(10 m) = 10.7 px.
const LENS: [&str; 6] = ["--focus", "2", "--fstop", "1", "--focal-length", "200"];

/// A frame with a bright square on a dark far wall (depth 10 m) and an in-focus left half
/// (depth 2 m): colour and depth written as a Blender-style multilayer EXR.
fn write_frame(path: &Path) -> (ColorImage, GrayImage) {
    let mut color = ColorImage::new(W, H, [0.05, 0.05, 0.05, 1.0]);
    let mut depth = GrayImage::new(W, H, 10.0);
    for y in 0..H {
        for x in 0..W {
            if x < W / 2 {
                *color.get_mut(x, y) = if (x / 4 + y / 4) % 2 == 0 {
                    [0.8, 0.8, 0.8, 1.0]
                } else {
                    [0.1, 0.1, 0.1, 1.0]
                };
                *depth.get_mut(x, y) = 2.0;
            } else if (34..38).contains(&x) && (14..18).contains(&y) {
                *color.get_mut(x, y) = [20.0, 20.0, 20.0, 1.0];
            }
        }
    }
    let ch = |c: usize| -> Vec<f32> { color.pixels().iter().map(|p| p[c]).collect() };
    let (r, g, b, a) = (ch(0), ch(1), ch(2), ch(3));
    io::write_exr_layers(
        path,
        W,
        H,
        &[
            ("ViewLayer.Combined.R", &r),
            ("ViewLayer.Combined.G", &g),
            ("ViewLayer.Combined.B", &b),
            ("ViewLayer.Combined.A", &a),
            ("ViewLayer.Depth.Z", depth.pixels()),
        ],
    )
    .unwrap();
    (color, depth)
}

fn sum_rgb(img: &ColorImage) -> f64 {
    img.pixels()
        .iter()
        .map(|p| (p[0] + p[1] + p[2]) as f64)
        .sum()
}

#[test]
fn blur_runs_every_method_on_a_multilayer_exr_and_keeps_the_focused_half_sharp() {
    let dir = temp_dir("methods");
    let frame = dir.join("frame.exr");
    let (color, _) = write_frame(&frame);
    for method in ["hammon", "lowrank", "gaussian", "poisson"] {
        let out = dir.join(format!("{method}.exr"));
        let o = defocus(&[
            "blur",
            "--color",
            s(&frame),
            "--depth",
            s(&frame),
            "--method",
            method,
            "--focus",
            "2",
            // f_px = 200/36*48 = 267 px, lens radius 0.1 m: C(10 m) = 10.7 px.
            "--fstop",
            "1",
            "--focal-length",
            "200",
            "--out",
            s(&out),
            "--timings",
            "json",
        ]);
        assert!(o.status.success(), "{method}: {}", stderr(&o));
        let json: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
        assert_eq!(json["method"], method);
        // Reading and writing are timed apart from the method's own passes.
        let names: Vec<&str> = json["passes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["name"].as_str().unwrap())
            .collect();
        assert!(
            names.contains(&"io/read") && names.contains(&"io/write"),
            "{names:?}"
        );
        let own = names
            .iter()
            .filter(|n| n.starts_with(&format!("{method}/")));
        assert!(own.count() >= 2, "{method}: {names:?}");
        let img = io::read_color(&out).unwrap();
        assert_eq!((img.width(), img.height()), (W, H));
        // The in-focus checker, away from the depth edge, is unchanged.
        for y in 0..H {
            for x in 0..W / 2 - 6 {
                let (a, b) = (img.get(x, y), color.get(x, y));
                for c in 0..3 {
                    assert!(
                        (a[c] - b[c]).abs() < 2e-3,
                        "{method}: in-focus pixel ({x}, {y}) changed: {a:?} vs {b:?}"
                    );
                }
            }
        }
        // The bright square far behind focus is spread out: its peak drops.
        let peak = (14..18)
            .flat_map(|y| (34..38).map(move |x| (x, y)))
            .map(|(x, y)| img.get(x, y)[0])
            .fold(0.0f32, f32::max);
        assert!(
            peak < 15.0,
            "{method}: far square not blurred (peak {peak})"
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn blur_verbose_names_the_channels_it_found() {
    let dir = temp_dir("verbose");
    let frame = dir.join("frame.exr");
    write_frame(&frame);
    let out = dir.join("o.exr");
    let o = defocus(&[
        "blur",
        "--color",
        s(&frame),
        "--depth",
        s(&frame),
        "--out",
        s(&out),
        "--verbose",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("ViewLayer.Combined.R"), "{e}");
    assert!(e.contains("ViewLayer.Depth.Z"), "{e}");
    // --focus auto is the default and says what it chose: the square's wall at the centre.
    assert!(e.contains("focus: "), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn tilt_shift_blurs_outside_the_band_and_conserves_a_constant_image() {
    let dir = temp_dir("tilt");
    // A horizontal stripe pattern: sharp in the band, averaged out far from it.
    let mut photo = ColorImage::new(64, 64, [0.0; 4]);
    for y in 0..64 {
        for x in 0..64 {
            let v = if x % 2 == 0 { 1.0 } else { 0.0 };
            *photo.get_mut(x, y) = [v, v, v, 1.0];
        }
    }
    let input = dir.join("photo.exr");
    io::write_color(&input, &photo).unwrap();
    let out = dir.join("tilt.exr");
    let o = defocus(&[
        "blur",
        "--color",
        s(&input),
        "--tilt-shift",
        "centre=0.5,width=0.2,blur=6,ramp=0.1",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = io::read_color(&out).unwrap();
    // Inside the band (rows 26..38) the stripes keep full contrast.
    for x in 8..56 {
        assert!((img.get(x, 32)[0] - photo.get(x, 32)[0]).abs() < 1e-3);
    }
    // Far from the band the stripes are averaged towards 0.5.
    for x in 8..56 {
        let v = img.get(x, 2)[0];
        assert!((v - 0.5).abs() < 0.1, "row 2, x {x}: {v}");
    }
    // Energy is kept: the mean stays the same.
    let (a, b) = (sum_rgb(&img), sum_rgb(&photo));
    assert!((a - b).abs() / b < 0.02, "{a} vs {b}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn blur_bad_inputs_fail_with_a_clear_error_and_no_output() {
    let dir = temp_dir("bad");
    let frame = dir.join("frame.exr");
    write_frame(&frame);
    let small = dir.join("small.pfm");
    let mut pfm = b"Pf\n4 4\n-1.0\n".to_vec();
    pfm.extend((0..16).flat_map(|_| 1.0f32.to_le_bytes()));
    std::fs::write(&small, pfm).unwrap();
    let mut nan_depth = GrayImage::new(W, H, 3.0);
    *nan_depth.get_mut(5, 7) = f32::NAN;
    let nan = dir.join("nan.exr");
    io::write_depth_exr(&nan, &nan_depth).unwrap();
    let mut neg_depth = GrayImage::new(W, H, 3.0);
    *neg_depth.get_mut(1, 2) = -1.0;
    let neg = dir.join("neg.exr");
    io::write_depth_exr(&neg, &neg_depth).unwrap();
    let truncated = dir.join("truncated.exr");
    let bytes = std::fs::read(&frame).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
    let out = dir.join("o.exr");
    let f = s(&frame);
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--color", f, "--depth", s(&small)], "size mismatch"),
        (vec!["--color", f, "--depth", s(&nan)], "NaN"),
        (vec!["--color", f, "--depth", s(&neg)], "not positive"),
        (
            vec!["--color", s(&truncated), "--depth", f],
            "truncated.exr",
        ),
        (vec!["--color", f, "--depth", "missing.exr"], "missing.exr"),
        (vec!["--color", f, "--depth", f, "--fstop", "0"], "f-number"),
        (vec!["--color", f, "--depth", f, "--focus", "-1"], "focus"),
        (
            vec![
                "--color", f, "--depth", f, "--method", "lowrank", "--rank", "0",
            ],
            "rank",
        ),
        (
            vec![
                "--color", f, "--depth", f, "--method", "poisson", "--taps", "0",
            ],
            "--taps",
        ),
        (
            vec!["--color", f, "--depth", f, "--aperture", "poly:2"],
            "blades",
        ),
        (
            vec!["--color", f, "--depth", f, "--coc", "artist"],
            "--artist-near",
        ),
        (vec!["--color", f, "--tilt-shift", "width=-1"], "tilt-shift"),
        (
            vec!["--color", f, "--tilt-shift", "--method", "hammon"],
            "lowrank",
        ),
    ];
    for (args, needle) in cases {
        let mut all = vec!["blur"];
        all.extend(&args);
        all.extend(["--out", s(&out)]);
        let o = defocus(&all);
        let e = stderr(&o);
        assert!(!o.status.success(), "{args:?} should fail");
        assert!(
            e.contains(needle),
            "{args:?}: '{e}' should mention {needle}"
        );
        assert!(!e.contains("panicked"), "{e}");
        assert!(!out.exists(), "{args:?}: no output after an error");
    }
    // An input is never overwritten.
    let o = defocus(&["blur", "--color", f, "--depth", f, "--out", f]);
    assert!(!o.status.success());
    assert_eq!(std::fs::read(&frame).unwrap(), bytes, "input untouched");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn render_runs_post_process_methods_on_the_pinhole_frame() {
    let dir = temp_dir("post-render");
    let pin = dir.join("pin.exr");
    let o = defocus(&[
        "render",
        "--method",
        "pinhole",
        "--width",
        "64",
        "--height",
        "36",
        "--out",
        s(&pin),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let pinhole = io::read_color(&pin).unwrap();
    for method in ["hammon", "lowrank", "gaussian", "poisson"] {
        let out = dir.join(format!("{method}.exr"));
        let o = defocus(&[
            "render",
            "--method",
            method,
            "--width",
            "64",
            "--height",
            "36",
            "--out",
            s(&out),
            "--timings",
            "json",
        ]);
        assert!(o.status.success(), "{method}: {}", stderr(&o));
        let json: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
        let names: Vec<&str> = json["passes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["name"].as_str().unwrap())
            .collect();
        assert!(names.iter().any(|n| n.starts_with("pinhole/")), "{names:?}");
        assert!(
            names.iter().any(|n| n.starts_with(&format!("{method}/"))),
            "{names:?}"
        );
        let img = io::read_color(&out).unwrap();
        assert_eq!((img.width(), img.height()), (64, 36));
        let diff: f32 = img
            .pixels()
            .iter()
            .zip(pinhole.pixels())
            .map(|(a, b)| (a[0] - b[0]).abs())
            .sum();
        assert!(diff > 1.0, "{method}: the railing scene should be blurred");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn kernel_reports_errors_that_fall_with_rank_and_writes_images() {
    let dir = temp_dir("kernel");
    let k = dir.join("k.png");
    let k3 = dir.join("k3.exr");
    let o = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args([
            "kernel",
            "--aperture",
            "poly:6",
            "--size",
            "33",
            "--rank",
            "1..4",
            "--json",
            "--out",
            s(&k),
            "--approx-out",
            s(&k3),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    let errors: Vec<f64> = json["ranks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["relative_error"].as_f64().unwrap())
        .collect();
    assert_eq!(errors.len(), 4);
    assert!(errors.windows(2).all(|w| w[1] < w[0]), "{errors:?}");
    // Eq. 4 from the printed singular values.
    let sv: Vec<f64> = json["singular_values"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let total: f64 = sv.iter().map(|s| s * s).sum();
    let tail: f64 = sv.iter().skip(2).map(|s| s * s).sum();
    assert!((errors[1] - (tail / total).sqrt()).abs() < 1e-9);
    let kimg = io::read_color(&k).unwrap();
    assert_eq!((kimg.width(), kimg.height()), (33, 33));
    assert!(io::read_color(&k3).is_ok());
    // A rank above the kernel's size is refused.
    let o = defocus(&["kernel", "--size", "5", "--rank", "6"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("at most rank 5"), "{}", stderr(&o));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn output_files_are_byte_identical_with_one_and_two_threads() {
    let dir = temp_dir("threads");
    for method in ["reference", "lowrank", "poisson", "hammon"] {
        let files: Vec<Vec<u8>> = ["1", "2"]
            .iter()
            .map(|threads| {
                let out = dir.join(format!("{method}-{threads}.exr"));
                let o = defocus(&[
                    "render",
                    "--scene",
                    "lights",
                    "--method",
                    method,
                    "--samples",
                    "8",
                    "--width",
                    "96",
                    "--height",
                    "54",
                    "--threads",
                    threads,
                    "--out",
                    s(&out),
                ]);
                assert!(o.status.success(), "{method}: {}", stderr(&o));
                std::fs::read(&out).unwrap()
            })
            .collect();
        assert!(
            files[0] == files[1],
            "{method}: output differs between 1 and 2 threads"
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn blur_takes_png_colour_with_16_bit_png_or_pfm_depth_and_a_depth_scale() {
    let dir = temp_dir("png");
    let exr = dir.join("frame.exr");
    let (color, depth) = write_frame(&exr);
    let png = dir.join("frame.png");
    io::write_color(
        &png,
        &color.map(|p| [p[0].min(1.0), p[1].min(1.0), p[2].min(1.0), 1.0]),
    )
    .unwrap();
    // 16-bit grey PNG: value / 65535 * 20 m = depth.
    let z16 = dir.join("z16.png");
    let raw: Vec<u16> = depth
        .pixels()
        .iter()
        .map(|z| (z / 20.0 * 65535.0).round() as u16)
        .collect();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(W as u32, H as u32, raw)
        .unwrap()
        .save(&z16)
        .unwrap();
    // PFM in centimetres (bottom row first, as the format stores it).
    let zpfm = dir.join("z.pfm");
    let mut pfm = format!("Pf\n{W} {H}\n-1.0\n").into_bytes();
    for y in (0..H).rev() {
        for x in 0..W {
            pfm.extend((depth.get(x, y) * 100.0).to_le_bytes());
        }
    }
    std::fs::write(&zpfm, pfm).unwrap();
    let mut outputs = Vec::new();
    for (z, scale) in [(&z16, "20"), (&zpfm, "0.01")] {
        let out = dir.join(format!("{}.exr", z.file_stem().unwrap().to_str().unwrap()));
        let mut args = vec![
            "blur",
            "--color",
            s(&png),
            "--depth",
            s(z),
            "--depth-scale",
            scale,
        ];
        args.extend(LENS);
        args.extend(["--method", "gaussian", "--out", s(&out)]);
        let o = defocus(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        outputs.push(io::read_color(&out).unwrap());
    }
    // Both depth files say the same thing, so the results agree (to the 16-bit quantisation).
    let max_diff = outputs[0]
        .pixels()
        .iter()
        .zip(outputs[1].pixels())
        .map(|(a, b)| (a[0] - b[0]).abs())
        .fold(0.0f32, f32::max);
    assert!(max_diff < 1e-3, "PNG and PFM depth disagree by {max_diff}");
    // And the far half is blurred: the bright square's neighbour brightens.
    assert!(outputs[0].get(39, 16)[0] > color.get(39, 16)[0] + 0.05);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn blur_writes_the_signed_coc_map_of_the_thin_lens() {
    let dir = temp_dir("cocout");
    let frame = dir.join("frame.exr");
    write_frame(&frame);
    let (out, coc) = (dir.join("o.exr"), dir.join("coc.exr"));
    let o = defocus(&[
        "blur",
        "--color",
        s(&frame),
        "--depth",
        s(&frame),
        "--focus",
        "2",
        "--fstop",
        "1",
        "--focal-length",
        "200",
        "--out",
        s(&out),
        "--coc-out",
        s(&coc),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let ch = io::read_exr_channels(&coc).unwrap();
    let c = ch.find("CoC").expect("channel CoC");
    // f_px = 200 / 36 * 48 px, lens radius 0.2 m / 2 = 0.1 m: C(z) = f_px E (1/2 - 1/z).
    let expected_far = 200.0 / 36.0 * 48.0 * 0.1 * (0.5 - 0.1);
    assert_eq!(c[0], 0.0, "the in-focus half has no blur");
    assert!(
        (c[W - 1] - expected_far).abs() < 1e-3,
        "{} vs {expected_far}",
        c[W - 1]
    );
    // The same file for both outputs is refused.
    let o = defocus(&[
        "blur",
        "--color",
        s(&frame),
        "--depth",
        s(&frame),
        "--out",
        s(&coc),
        "--coc-out",
        s(&coc),
    ]);
    assert!(!o.status.success());
    std::fs::remove_dir_all(dir).unwrap();
}

/// A NaN in the image to filter is refused naming the file and the pixel (a filter would
/// spread it over its whole kernel), unless --sanitize sets it to 0.
#[test]
fn kernel_filter_refuses_nan_colour_unless_sanitized() {
    let dir = temp_dir("kfilter-nan");
    let mut img = ColorImage::new(33, 33, [0.5, 0.5, 0.5, 1.0]);
    *img.get_mut(7, 9) = [f32::NAN, 0.5, 0.5, 1.0];
    let input = dir.join("nan.exr");
    io::write_color(&input, &img).unwrap();
    let out = dir.join("out.exr");
    let args = |sanitize: bool| {
        let mut a = vec![
            "kernel",
            "--size",
            "9",
            "--filter",
            s(&input),
            "--filter-out",
            s(&out),
        ];
        if sanitize {
            a.push("--sanitize");
        }
        defocus(&a)
    };
    let o = args(false);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("nan.exr") && e.contains("(7, 9)"), "{e}");
    assert!(!out.exists());
    let o = args(true);
    assert!(o.status.success(), "{}", stderr(&o));
    let blurred = io::read_color(&out).unwrap();
    assert!(blurred
        .pixels()
        .iter()
        .all(|p| p.iter().all(|v| v.is_finite())));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn kernel_filter_blurs_an_image_with_the_low_rank_and_the_full_kernel() {
    let dir = temp_dir("kfilter");
    // One bright pixel on black: the full 2D blur is the kernel itself, and energy is kept.
    let mut img = ColorImage::new(41, 41, [0.0, 0.0, 0.0, 1.0]);
    *img.get_mut(20, 20) = [100.0, 100.0, 100.0, 1.0];
    let input = dir.join("dot.exr");
    io::write_color(&input, &img).unwrap();
    let (low, full) = (dir.join("low.exr"), dir.join("full.exr"));
    let kernel = [
        "kernel",
        "--aperture",
        "poly:6",
        "--size",
        "21",
        "--rank",
        "3",
    ];
    let o = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(kernel)
        .args([
            "--json",
            "--filter",
            s(&input),
            "--filter-out",
            s(&low),
            "--full-2d-out",
            s(&full),
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert!(json["filter"]["separable_ms"].as_f64().unwrap() >= 0.0);
    let (low, full) = (
        io::read_color(&low).unwrap(),
        io::read_color(&full).unwrap(),
    );
    let energy = |im: &ColorImage| im.pixels().iter().map(|p| p[0] as f64).sum::<f64>();
    assert!((energy(&full) - 100.0).abs() < 1e-3, "{}", energy(&full));
    assert!((energy(&low) - 100.0).abs() < 1.0, "{}", energy(&low));
    // The full blur of a dot is a hexagon 21 px across: nothing beyond 10.5 px of the centre.
    for y in 0..41 {
        for x in 0..41 {
            let r = ((x as f32 - 20.0).powi(2) + (y as f32 - 20.0).powi(2)).sqrt();
            if r > 11.5 {
                assert!(full.get(x, y)[0].abs() < 1e-6, "({x}, {y})");
            }
        }
    }
    // Rank 3 approximates it: the error is eq. 4's relative error, about 0.14 for 6 blades.
    let diff: f64 = low
        .pixels()
        .iter()
        .zip(full.pixels())
        .map(|(a, b)| ((a[0] - b[0]) as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let norm: f64 = full
        .pixels()
        .iter()
        .map(|p| (p[0] as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let e3 = json["ranks"][0]["relative_error"].as_f64().unwrap();
    assert!(
        (diff / norm - e3).abs() < 0.02,
        "{} vs eq. 4 {e3}",
        diff / norm
    );
    // Fig. 2's order of passes gives the same blur but for rounding.
    let fig2 = dir.join("fig2.exr");
    let o = defocus(
        &[
            &kernel[..],
            &[
                "--filter",
                s(&input),
                "--filter-out",
                s(&fig2),
                "--schedule",
                "fig2",
            ],
        ]
        .concat(),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let fig2 = io::read_color(&fig2).unwrap();
    let most = low
        .pixels()
        .iter()
        .zip(fig2.pixels())
        .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
        .fold(0.0f32, f32::max);
    assert!(most < 1e-5, "banded and fig. 2 differ by {most}");
    let bad = dir.join("bad.exr");
    let o = defocus(&[
        "kernel",
        "--size",
        "5",
        "--filter",
        s(&input),
        "--filter-out",
        s(&bad),
        "--schedule",
        "diagonal",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("fig2"), "{}", stderr(&o));
    assert!(!bad.exists());
    std::fs::remove_dir_all(dir).unwrap();
}

/// Writes depth as a grey PFM (bottom row first, as the format stores it).
fn write_depth_pfm(path: &Path, depth: &GrayImage) {
    let (w, h) = (depth.width(), depth.height());
    let mut pfm = format!("Pf\n{w} {h}\n-1.0\n").into_bytes();
    for y in (0..h).rev() {
        for &z in depth.row(y) {
            pfm.extend(z.to_le_bytes());
        }
    }
    std::fs::write(path, pfm).unwrap();
}

/// The part of the frame the data-window tests cut: 36x24 pixels from (6, 4).
const PART: (usize, usize, usize, usize) = (6, 4, 36, 24);
/// The frame of those tests: it starts at (100, 50) in the file's coordinates.
const PART_FRAME: Placement = Placement {
    data_origin: (100, 50),
    display_origin: (100, 50),
    display_size: (W, H),
};
/// The part's place in that frame.
const PART_PLACED: Placement = Placement {
    data_origin: (106, 54),
    display_origin: (100, 50),
    display_size: (W, H),
};

/// Writes the [`PART`] of the frame: its colour as an EXR with the part's data window in the
/// frame's display window, and its depth as a PFM (no window). Returns both paths.
fn write_part(dir: &Path, color: &ColorImage, depth: &GrayImage) -> (PathBuf, PathBuf) {
    let color_part = dir.join("color_part.exr");
    let options = ExrOptions {
        placement: Some(PART_PLACED),
        ..ExrOptions::default()
    };
    io::write_color_with(&color_part, &crop(color, PART), &options).unwrap();
    let depth_part = dir.join("depth_part.pfm");
    write_depth_pfm(&depth_part, &crop(depth, PART));
    (color_part, depth_part)
}

/// The `(x0, y0, w, h)` part of `img`.
fn crop<P: Copy + Send + Sync>(
    img: &defocus::image::Image<P>,
    (x0, y0, w, h): (usize, usize, usize, usize),
) -> defocus::image::Image<P> {
    let rows = (y0..y0 + h).flat_map(|y| img.row(y)[x0..x0 + w].iter().copied());
    defocus::image::Image::from_vec(w, h, rows.collect()).unwrap()
}

/// An OpenEXR colour image whose data window is part of its display window (a compositor's
/// bounding box): the output keeps both windows, and depth for the whole frame (as an EXR with
/// its own windows, or as a PFM the size of the frame) is cut to the colour's pixels at their
/// place, which gives the same image as depth cut by hand.
#[test]
fn blur_keeps_an_exr_data_window_in_its_frame_and_cuts_depth_to_it() {
    let dir = temp_dir("window");
    let frame_exr = dir.join("frame.exr");
    let (color, depth) = write_frame(&frame_exr);
    // The frame starts at (100, 50) in the file's coordinates; the colour holds its part from
    // (6, 4), 36x24 pixels.
    let (part, frame, placed) = (PART, PART_FRAME, PART_PLACED);
    let (color_part, depth_part) = write_part(&dir, &color, &depth);
    assert_eq!(io::read_exr_placement(&color_part).unwrap(), Some(placed));
    let depth_frame = dir.join("depth_frame.exr");
    io::write_exr_layers_placed(&depth_frame, W, H, &[("Z", depth.pixels())], Some(frame)).unwrap();
    let depth_frame_pfm = dir.join("depth_frame.pfm");
    write_depth_pfm(&depth_frame_pfm, &depth);

    let run = |depth: &Path, out: &Path, coc_out: Option<&Path>| {
        let mut args = vec!["blur", "--color", s(&color_part), "--depth", s(depth)];
        args.extend(["--method", "hammon", "--out", s(out)]);
        args.extend(LENS);
        if let Some(c) = coc_out {
            args.extend(["--coc-out", s(c)]);
        }
        defocus(&args)
    };
    // The whole frame's CoC: the part's must be its crop (the focal length in pixels is the
    // frame's, not the part's).
    let (full_out, full_coc) = (dir.join("full.exr"), dir.join("full_coc.exr"));
    let mut args = vec!["blur", "--color", s(&frame_exr), "--depth", s(&frame_exr)];
    args.extend(["--method", "hammon", "--out", s(&full_out)]);
    args.extend(["--coc-out", s(&full_coc)]);
    args.extend(LENS);
    let o = defocus(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let full = io::read_exr_channels(&full_coc).unwrap();
    let full = GrayImage::from_vec(W, H, full.find("CoC").unwrap().to_vec()).unwrap();
    let full_part = crop(&full, part);
    let by_hand = dir.join("by_hand.exr");
    let o = run(&depth_part, &by_hand, None);
    assert!(o.status.success(), "{}", stderr(&o));
    let expected = io::read_color(&by_hand).unwrap();
    assert_eq!((expected.width(), expected.height()), (36, 24));
    assert_eq!(io::read_exr_placement(&by_hand).unwrap(), Some(placed));
    for depth in [&depth_frame, &depth_frame_pfm] {
        let (out, coc) = (dir.join("out.exr"), dir.join("coc.exr"));
        let o = run(depth, &out, Some(&coc));
        assert!(o.status.success(), "{}: {}", depth.display(), stderr(&o));
        assert_eq!(
            io::read_color(&out).unwrap(),
            expected,
            "{}",
            depth.display()
        );
        assert_eq!(io::read_exr_placement(&out).unwrap(), Some(placed));
        assert_eq!(io::read_exr_placement(&coc).unwrap(), Some(placed));
        let part_coc = io::read_exr_channels(&coc).unwrap();
        for (a, b) in part_coc.find("CoC").unwrap().iter().zip(full_part.pixels()) {
            assert!(
                (a - b).abs() < 1e-4 * (1.0 + b.abs()),
                "CoC {a} px, whole frame {b} px"
            );
        }
    }
    // A PNG output cannot hold the place: it says so, and holds the pixels.
    let png = dir.join("out.png");
    let o = run(&depth_frame, &png, None);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("write .exr to keep it"),
        "{}",
        stderr(&o)
    );
    // Depth that misses some colour pixels is refused, naming both windows, and writes nothing.
    let depth_small = dir.join("depth_small.exr");
    let small = Placement {
        data_origin: (110, 54),
        ..frame
    };
    io::write_exr_layers_placed(
        &depth_small,
        36,
        24,
        &[("Z", crop(&depth, part).pixels())],
        Some(small),
    )
    .unwrap();
    let refused = dir.join("refused.exr");
    let o = run(&depth_small, &refused, None);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("36x24 pixels from (110, 54)") && e.contains("36x24 pixels from (106, 54)"),
        "{e}"
    );
    assert!(!refused.exists());
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--depth-kind inverse` reads 1 / depth (Nuke's ScanlineRender depth, 0 for infinitely far):
/// the same image as the depth itself.
#[test]
fn blur_reads_inverse_depth_as_nuke_writes_it() {
    let dir = temp_dir("inverse");
    let frame = dir.join("frame.exr");
    let (_, depth) = write_frame(&frame);
    // The right half is the sky: no surface, 0 in inverse depth and +inf in depth.
    let sky = |x: usize| x >= W - 4;
    let inverse: Vec<f32> = (0..W * H)
        .map(|i| {
            if sky(i % W) {
                0.0
            } else {
                1.0 / depth.pixels()[i]
            }
        })
        .collect();
    let direct: Vec<f32> = inverse
        .iter()
        .map(|&v| if v == 0.0 { f32::INFINITY } else { 1.0 / v })
        .collect();
    let (inv_path, direct_path) = (dir.join("inverse.exr"), dir.join("direct.exr"));
    io::write_exr_layers(&inv_path, W, H, &[("depth.Z", &inverse)]).unwrap();
    io::write_exr_layers(&direct_path, W, H, &[("depth.Z", &direct)]).unwrap();
    let mut outputs = Vec::new();
    for (depth, kind) in [(&inv_path, "inverse"), (&direct_path, "view")] {
        let out = dir.join(format!("{kind}-out.exr"));
        let mut args = vec!["blur", "--color", s(&frame), "--depth", s(depth)];
        args.extend([
            "--depth-kind",
            kind,
            "--method",
            "lowrank",
            "--out",
            s(&out),
        ]);
        args.extend(LENS);
        let o = defocus(&args);
        assert!(o.status.success(), "{kind}: {}", stderr(&o));
        outputs.push(io::read_color(&out).unwrap());
    }
    assert_eq!(outputs[0], outputs[1]);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A stereo disparity map (Middlebury 2006 Aloe: 8-bit disparity in pixels at this size, larger
/// = nearer, 0 = unknown) is inverse depth up to a constant disparity offset, which cancels in
/// the CoC. With `--depth-kind inverse` and `--depth-scale` = f B / 255, every pixel's CoC is
/// the thin lens's `f E (1/focus - 1/z)` with `1/z = d / (f B)`, that is `E (d_focus - d) / B`
/// pixels; unknown pixels (0) are far: `E d_focus / B`.
#[test]
fn a_stereo_disparity_map_read_as_inverse_depth_gives_the_thin_lens_coc() {
    let Some(assets) = crate::shared_assets() else {
        return;
    };
    let aloe = assets.join("rgbd/middlebury2006_aloe");
    let (photo, disparity) = (aloe.join("aloeL.jpg"), aloe.join("aloeGT.png"));
    let d = image::open(&disparity).unwrap().to_luma8();
    let width = d.width() as f32;
    // Middlebury 2006, full size: focal length 3740 px, baseline 0.16 m.
    let (f_px, baseline_m) = (3740.0f32, 0.16f32);
    let (d_focus, fstop) = (100.0f32, 2.0f32);
    // A lens of the camera's focal length in pixels on a 36 mm sensor.
    let focal_mm = 36.0 * f_px / width;
    let lens_radius_m = focal_mm / 1000.0 / (2.0 * fstop);
    let dir = temp_dir("disparity");
    let (out, coc) = (dir.join("o.png"), dir.join("coc.exr"));
    let arg = |v: f32| v.to_string();
    let (scale, focus, focal) = (
        arg(f_px * baseline_m / 255.0),
        arg(f_px * baseline_m / d_focus),
        arg(focal_mm),
    );
    let o = defocus(&[
        "blur",
        "--color",
        s(&photo),
        "--depth",
        s(&disparity),
        "--depth-kind",
        "inverse",
        "--depth-scale",
        &scale,
        "--focal-length",
        &focal,
        "--sensor-width",
        "36",
        "--fstop",
        "2",
        "--focus",
        &focus,
        "--out",
        s(&out),
        "--coc-out",
        s(&coc),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let ch = io::read_exr_channels(&coc).unwrap();
    let c = ch.find("CoC").expect("channel CoC");
    let per_disparity_px = lens_radius_m / baseline_m;
    for (i, (&got, p)) in c.iter().zip(d.pixels()).enumerate() {
        let d = f32::from(p.0[0]);
        let expected = per_disparity_px * (d_focus - d);
        assert!(
            (got - expected).abs() < 1e-3 + 1e-4 * expected.abs(),
            "pixel {i}, disparity {d}: CoC {got} px, expected {expected}"
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--focus-pixel X,Y` focuses on the depth around that pixel of the frame: for an EXR whose
/// data window is part of its display window, X,Y count from the display window's corner.
#[test]
fn blur_focus_pixel_focuses_on_the_depth_there_in_frame_coordinates() {
    let dir = temp_dir("focuspixel");
    let frame = dir.join("frame.exr");
    let (color, depth) = write_frame(&frame);
    let focus = |color: &Path, depth: &Path, pixel: &str| {
        let out = dir.join("o.exr");
        defocus(&[
            "blur",
            "--color",
            s(color),
            "--depth",
            s(depth),
            "--focus-pixel",
            pixel,
            "--out",
            s(&out),
        ])
    };
    // The left half is at 2 m, the right half at 10 m.
    for (pixel, metres) in [("5,5", "2.0000"), ("40,20", "10.0000")] {
        let o = focus(&frame, &frame, pixel);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!("focus: {metres} m")),
            "{}",
            stderr(&o)
        );
    }
    let o = focus(&frame, &frame, "48,5");
    assert!(!o.status.success() && stderr(&o).contains("--focus-pixel 48,5: outside the image"));
    // The colour's 36x24 pixels from (6, 4) of the frame, with the depth of those pixels.
    let (color_part, depth_part) = write_part(&dir, &color, &depth);
    // Frame column 20 is in the 2 m half, 30 in the 10 m half; (5, 5) is outside the part.
    for (pixel, metres) in [("20,10", "2.0000"), ("30,10", "10.0000")] {
        let o = focus(&color_part, &depth_part, pixel);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(
            stderr(&o).contains(&format!("focus: {metres} m")),
            "{pixel}: {}",
            stderr(&o)
        );
    }
    let o = focus(&color_part, &depth_part, "5,5");
    assert!(
        !o.status.success() && stderr(&o).contains("outside the image"),
        "{}",
        stderr(&o)
    );
    // Not with --focus.
    let out = dir.join("both.exr");
    let o = defocus(&[
        "blur",
        "--color",
        s(&frame),
        "--depth",
        s(&frame),
        "--focus",
        "3",
        "--focus-pixel",
        "5,5",
        "--out",
        s(&out),
    ]);
    assert!(!o.status.success() && !out.exists());
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--depth-kind coc` takes the signed CoC map that `--coc-out` writes as the blur itself: the
/// same image as from the depth it came from, for a gather and the low-rank filter; its
/// `--depth-scale` scales the radii; `--focus` and a PNG map are refused.
#[test]
fn blur_takes_a_coc_map_as_the_blur_itself() {
    let dir = temp_dir("cocmap");
    let frame = dir.join("frame.exr");
    write_frame(&frame);
    let coc = dir.join("coc.exr");
    for method in ["hammon", "lowrank"] {
        let from_depth = dir.join(format!("{method}-depth.exr"));
        let mut args = vec!["blur", "--color", s(&frame), "--depth", s(&frame)];
        args.extend([
            "--method",
            method,
            "--out",
            s(&from_depth),
            "--coc-out",
            s(&coc),
        ]);
        args.extend(LENS);
        let o = defocus(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let from_coc = dir.join(format!("{method}-coc.exr"));
        let o = defocus(&[
            "blur",
            "--color",
            s(&frame),
            "--depth",
            s(&coc),
            "--depth-kind",
            "coc",
            "--method",
            method,
            "--out",
            s(&from_coc),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let (a, b) = (
            io::read_color(&from_depth).unwrap(),
            io::read_color(&from_coc).unwrap(),
        );
        for (i, (p, q)) in a.pixels().iter().zip(b.pixels()).enumerate() {
            for c in 0..4 {
                assert!(
                    (p[c] - q[c]).abs() < 1e-4 * (1.0 + p[c].abs()),
                    "{method}, pixel {i}: {p:?} from depth, {q:?} from the CoC map"
                );
            }
        }
    }
    // Twice the radii: the CoC written back is twice the map.
    let (out, coc2) = (dir.join("twice.exr"), dir.join("coc2.exr"));
    let o = defocus(&[
        "blur",
        "--color",
        s(&frame),
        "--depth",
        s(&coc),
        "--depth-kind",
        "coc",
        "--depth-scale",
        "2",
        "--out",
        s(&out),
        "--coc-out",
        s(&coc2),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let once = io::read_exr_channels(&coc).unwrap();
    let twice = io::read_exr_channels(&coc2).unwrap();
    for (a, b) in once
        .find("CoC")
        .unwrap()
        .iter()
        .zip(twice.find("CoC").unwrap())
    {
        assert!((2.0 * a - b).abs() < 1e-3 * (1.0 + b.abs()), "{a} -> {b}");
    }
    // Refused, each with its reason and no output: radii that the scale makes infinite, a
    // --focus (the map sets the blur), a PNG map (it cannot hold signed radii).
    let png = dir.join("coc.png");
    io::write_color(&png, &ColorImage::new(W, H, [0.5, 0.5, 0.5, 1.0])).unwrap();
    let no = dir.join("no.exr");
    let refusals: [(&Path, &[&str], &str); 3] = [
        (
            &coc,
            &["--depth-scale", "1e38"],
            "expected finite signed radii",
        ),
        (&coc, &["--focus", "3"], "--depth-kind coc"),
        (&png, &[], "signed radii"),
    ];
    for (map, extra, reason) in refusals {
        let mut args = vec!["blur", "--color", s(&frame), "--depth", s(map)];
        args.extend(["--depth-kind", "coc", "--out", s(&no)]);
        args.extend(extra);
        let o = defocus(&args);
        assert!(
            !o.status.success() && stderr(&o).contains(reason),
            "{}",
            stderr(&o)
        );
    }
    assert!(!dir.join("no.exr").exists());
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--zero-depth-is-far`: a background of depth 0 blurs as the far distance it stands for, the
/// same image as +inf there; without the flag it is refused and nothing is written.
#[test]
fn blur_reads_zero_depth_as_far_when_told() {
    let dir = temp_dir("zerofar");
    let frame = dir.join("frame.exr");
    let (_, depth) = write_frame(&frame);
    let background = |i: usize| i % W >= W - 4;
    let with = |v: f32| -> Vec<f32> {
        (0..W * H)
            .map(|i| if background(i) { v } else { depth.pixels()[i] })
            .collect()
    };
    let (zero, inf) = (dir.join("zero.exr"), dir.join("inf.exr"));
    io::write_exr_layers(&zero, W, H, &[("Z", &with(0.0))]).unwrap();
    io::write_exr_layers(&inf, W, H, &[("Z", &with(f32::INFINITY))]).unwrap();
    let run = |depth: &Path, out: &Path, zero_is_far: bool| {
        let mut args = vec![
            "blur",
            "--color",
            s(&frame),
            "--depth",
            s(depth),
            "--out",
            s(out),
        ];
        args.extend(LENS);
        if zero_is_far {
            args.push("--zero-depth-is-far");
        }
        defocus(&args)
    };
    let (a, b) = (dir.join("a.exr"), dir.join("b.exr"));
    let o = run(&zero, &a, false);
    assert!(
        !o.status.success() && stderr(&o).contains("--zero-depth-is-far"),
        "{}",
        stderr(&o)
    );
    assert!(!a.exists());
    for (depth, out) in [(&zero, &a), (&inf, &b)] {
        let o = run(depth, out, true);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    assert_eq!(io::read_color(&a).unwrap(), io::read_color(&b).unwrap());
    std::fs::remove_dir_all(dir).unwrap();
}

/// On an 8-bit sRGB frame of `lights`, where every light clips at 1.0, `--highlights` brings
/// the bokeh's energy back: against the blur of the HDR frame, the blur of the 8-bit frame
/// gains in PSNR and its energy comes closer.
#[test]
fn highlights_bring_back_the_energy_of_clipped_lights() {
    let dir = temp_dir("highlights");
    let (hdr, png, depth) = (dir.join("hdr.exr"), dir.join("ldr.png"), dir.join("z.exr"));
    let o = defocus(&[
        "render",
        "--scene",
        "lights",
        "--method",
        "pinhole",
        "--width",
        "160",
        "--height",
        "90",
        "--samples",
        "4",
        "--out",
        s(&hdr),
        "--depth-out",
        s(&depth),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    // The same frame as an 8-bit photo: every light clips at 1.0.
    let frame = io::read_color(&hdr).unwrap();
    let brightest = frame
        .pixels()
        .iter()
        .map(|p| p[0].max(p[1]).max(p[2]))
        .fold(0.0, f32::max);
    assert!(brightest > 4.0, "the lights are HDR: {brightest}");
    io::write_color(&png, &frame).unwrap();
    let blur = |input: &Path, out: &Path, extra: &[&str]| {
        let mut args = vec![
            "blur",
            "--color",
            s(input),
            "--depth",
            s(&depth),
            "--method",
            "lowrank",
            "--focus",
            "auto",
            "--fstop",
            "1.4",
            "--out",
            s(out),
        ];
        args.extend_from_slice(extra);
        let o = defocus(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        io::read_color(out).unwrap()
    };
    let truth = blur(&hdr, &dir.join("t.exr"), &[]);
    let plain = blur(&png, &dir.join("a.exr"), &[]);
    let lifted = blur(&png, &dir.join("b.exr"), &["--highlights", "0.9,8"]);
    let psnr = |img: &ColorImage| defocus::metrics::compare(img, &truth).unwrap().psnr_db;
    let (e_truth, e_plain, e_lifted) = (sum_rgb(&truth), sum_rgb(&plain), sum_rgb(&lifted));
    eprintln!(
        "psnr plain {:.2} lifted {:.2}; energy truth {e_truth:.0} plain {e_plain:.0} lifted {e_lifted:.0}",
        psnr(&plain),
        psnr(&lifted)
    );
    assert!(psnr(&lifted) > psnr(&plain) + 1.0);
    assert!((e_lifted - e_truth).abs() < 0.5 * (e_plain - e_truth).abs());
    // A threshold of 1 or more is refused, naming the flag.
    let bad = defocus(&[
        "blur",
        "--color",
        s(&png),
        "--depth",
        s(&depth),
        "--highlights",
        "1.5,2",
        "--out",
        s(&dir.join("c.exr")),
    ]);
    assert!(!bad.status.success() && stderr(&bad).contains("--highlights"));
}
