//! Tests: the library's registry of methods, and `render` / `blur` running through it.

use defocus::image::io::{self, ExrCompression, ExrOptions};
use defocus::image::ColorImage;
use defocus::methods::registry::{self, InputKind, MethodSettings, METHODS};
use defocus::metrics;

use crate::cli::{defocus, s, stderr, temp_dir};

/// Pixels of a render compared between `render` and `blur` may differ by this much (linear):
/// `--depth-out` writes 1e10 m where nothing was hit, which `render` keeps as +inf, and the CoC
/// of the two differs by about 1e-10 px there.
const RENDER_BLUR_TOLERANCE: f32 = 1e-4;

#[test]
fn registry_lists_every_method_with_its_input_kind() {
    let want = [
        ("pinhole", InputKind::SceneViews),
        ("reference", InputKind::SceneViews),
        ("hammon", InputKind::PinholeFrame),
        ("lowrank", InputKind::PinholeFrame),
        ("gaussian", InputKind::PinholeFrame),
        ("poisson", InputKind::PinholeFrame),
        ("multilayer", InputKind::FragmentLists),
    ];
    for (id, input) in want {
        let m = registry::find(id).unwrap();
        assert_eq!(m.input, input, "{id}");
        assert!(!m.description.is_empty());
    }
    for m in METHODS {
        assert_eq!(MethodSettings::default_for(m.id).unwrap().id(), m.id);
        assert_eq!(m.input.needs_scene(), m.input != InputKind::PinholeFrame);
    }
    let mut ids = registry::ids();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), METHODS.len(), "ids are unique");
}

fn max_abs_diff(a: &ColorImage, b: &ColorImage) -> f32 {
    a.pixels()
        .iter()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..4).map(move |k| (p[k] - q[k]).abs()))
        .fold(0.0, f32::max)
}

#[test]
fn render_and_blur_give_the_same_image_for_every_post_process_method() {
    let dir = temp_dir("render-blur");
    let (w, h) = ("96", "54");
    let lens = [
        "--focus",
        "2.5",
        "--fstop",
        "2",
        "--focal-length",
        "50",
        "--sensor-width",
        "36",
    ];
    let frame = dir.join("frame.exr");
    let depth = dir.join("depth.exr");
    let mut args = vec![
        "render",
        "--method",
        "pinhole",
        "--samples",
        "16",
        "--width",
        w,
        "--height",
        h,
        "--out",
    ];
    args.extend([s(&frame), "--depth-out", s(&depth)]);
    let o = defocus(&args);
    assert!(o.status.success(), "{}", stderr(&o));
    let post: Vec<&str> = METHODS
        .iter()
        .filter(|m| m.input == InputKind::PinholeFrame)
        .map(|m| m.id)
        .collect();
    assert!(post.len() >= 4);
    for id in post {
        let rendered = dir.join(format!("{id}-render.exr"));
        let blurred = dir.join(format!("{id}-blur.exr"));
        let mut r = vec!["render", "--method", id, "--width", w, "--height", h];
        r.extend(lens);
        r.extend(["--out", s(&rendered)]);
        let o = defocus(&r);
        assert!(o.status.success(), "{id}: {}", stderr(&o));
        let mut b = vec!["blur", "--method", id, "--color", s(&frame)];
        b.extend(["--depth", s(&depth)]);
        b.extend(lens);
        b.extend(["--out", s(&blurred)]);
        let o = defocus(&b);
        assert!(o.status.success(), "{id}: {}", stderr(&o));
        let (a, b) = (
            io::read_color(&rendered).unwrap(),
            io::read_color(&blurred).unwrap(),
        );
        let d = max_abs_diff(&a, &b);
        assert!(d <= RENDER_BLUR_TOLERANCE, "{id}: max difference {d}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn blur_refuses_a_method_that_needs_a_scene_with_exit_code_1() {
    let dir = temp_dir("blur-scene-only");
    let frame = dir.join("frame.exr");
    let depth = dir.join("depth.exr");
    let o = defocus(&[
        "render",
        "--method",
        "pinhole",
        "--width",
        "16",
        "--height",
        "9",
        "--out",
        s(&frame),
        "--depth-out",
        s(&depth),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for m in METHODS.iter().filter(|m| !m.input.takes_frame()) {
        let out = dir.join("out.exr");
        let o = defocus(&[
            "blur",
            "--method",
            m.id,
            "--color",
            s(&frame),
            "--depth",
            s(&depth),
            "--out",
            s(&out),
        ]);
        assert_eq!(o.status.code(), Some(1), "{}", m.id);
        let e = stderr(&o);
        assert!(e.contains(m.id) && e.contains("defocus render"), "{e}");
        assert!(!out.exists());
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// In-focus region of `railing` (the chart board between the bars' blur), where anti-aliasing
/// is all that separates the default frame from a 256-sample one.
#[test]
fn default_lowrank_render_matches_a_256_sample_frame_in_focus() {
    // Measured: 16 samples give 42.9 dB against 256 over the whole 640x360 pinhole frame.
    const MIN_PSNR_DB: f64 = 37.0;
    let dir = temp_dir("lowrank-aa");
    let (w, h) = ("320", "180");
    let default = dir.join("default.exr");
    let many = dir.join("many.exr");
    let o = defocus(&[
        "render",
        "--method",
        "lowrank",
        "--width",
        w,
        "--height",
        h,
        "--out",
        s(&default),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = defocus(&[
        "render",
        "--method",
        "lowrank",
        "--samples",
        "256",
        "--width",
        w,
        "--height",
        h,
        "--out",
        s(&many),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let crop = |img: &ColorImage| {
        // Top band of the board above the railing's horizontal bar: in focus.
        let (x0, y0, cw, ch) = (120, 30, 80, 30);
        let data = (y0..y0 + ch)
            .flat_map(|y| (x0..x0 + cw).map(move |x| (x, y)))
            .map(|(x, y)| img.get(x, y))
            .collect();
        ColorImage::from_vec(cw, ch, data).unwrap()
    };
    let a = crop(&io::read_color(&default).unwrap());
    let b = crop(&io::read_color(&many).unwrap());
    let one = dir.join("one.exr");
    let o = defocus(&[
        "render",
        "--method",
        "lowrank",
        "--samples",
        "1",
        "--width",
        w,
        "--height",
        h,
        "--out",
        s(&one),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let c = crop(&io::read_color(&one).unwrap());
    let psnr = metrics::compare(&a, &b).unwrap().psnr_db;
    let psnr_one = metrics::compare(&c, &b).unwrap().psnr_db;
    eprintln!("in-focus crop: default {psnr:.2} dB, 1 sample {psnr_one:.2} dB against 256");
    assert!(psnr >= MIN_PSNR_DB, "{psnr}");
    assert!(
        psnr > psnr_one + 3.0,
        "anti-aliasing must matter here: {psnr} vs {psnr_one}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn exr_written_with_every_compression_reads_back_bit_identical() {
    let dir = temp_dir("exr-compression");
    let (w, h) = (37, 23);
    let data = (0..w * h)
        .map(|i| {
            let x = i as f32;
            [x.sin() * 3.0, (x * 0.37).cos() * 1e4, 1.0 / (x + 1.0), 0.5]
        })
        .collect();
    let img = ColorImage::from_vec(w, h, data).unwrap();
    for compression in ExrCompression::ALL {
        let path = dir.join(format!("{}.exr", compression.name()));
        let o = ExrOptions {
            compression,
            half: false,
            placement: None,
        };
        io::write_color_with(&path, &img, &o).unwrap();
        let back = io::read_color(&path).unwrap();
        assert_eq!(back, img, "{}", compression.name());
        // Half floats: within half precision.
        let o = ExrOptions {
            compression,
            half: true,
            placement: None,
        };
        io::write_color_with(&path, &img, &o).unwrap();
        let back = io::read_color(&path).unwrap();
        for (p, q) in back.pixels().iter().zip(img.pixels()) {
            for k in 0..4 {
                assert!(
                    (p[k] - q[k]).abs() <= q[k].abs() * 1e-3 + 1e-4,
                    "{p:?} {q:?}"
                );
            }
        }
    }
    std::fs::remove_dir_all(dir).unwrap();
}
