//! Tests: the `defocus` command line, run as a user would.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use defocus::image::io;

/// Runs the `defocus` binary with `args` and `--quiet`.
pub(crate) fn defocus(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(args)
        .arg("--quiet")
        .output()
        .expect("run defocus")
}

/// A fresh, empty temporary folder for one test (names are unique across the CLI tests).
pub(crate) fn temp_dir(name: &str) -> TempFolder {
    TempFolder::new(&format!("defocus-cli-{}-{name}", std::process::id()))
}

/// A temporary folder, removed when dropped unless the test is failing (it is then kept, to
/// look at): the tests' outputs do not pile up in the system's temporary folder.
pub(crate) struct TempFolder(PathBuf);

impl TempFolder {
    /// The folder `name` in the system's temporary folder, emptied.
    pub(crate) fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(name);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }
}

impl std::ops::Deref for TempFolder {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempFolder {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempFolder {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// The path as a command-line argument.
pub(crate) fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Runs `defocus render` with `args` and `--out out`, checks that it succeeded, and reads the
/// image it wrote.
pub(crate) fn render_image(args: &[&str], out: &Path) -> defocus::image::ColorImage {
    let mut all = vec!["render"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", s(out)]);
    let o = defocus(&all);
    assert!(o.status.success(), "{}", stderr(&o));
    io::read_color(out).unwrap()
}

/// Runs `defocus render` with `args` and `flag value`, which it must refuse, naming `flag` and
/// `choices`, without writing its output (in `dir`).
fn render_refuses(args: &[&str], flag: &str, value: &str, choices: &str, dir: &Path) {
    let out = dir.join("refused.exr");
    let o = defocus(&[&["render"][..], args, &[flag, value, "--out", s(&out)]].concat());
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains(flag) && err.contains(choices), "{err}");
    assert!(!out.exists());
}

/// What the command printed on stderr.
pub(crate) fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn render_writes_the_default_scene_with_depth_and_json_timings() {
    let dir = temp_dir("render");
    let out = dir.join("r.exr");
    let depth = dir.join("z.exr");
    let o = defocus(&[
        "render",
        "--width",
        "64",
        "--height",
        "36",
        "--samples",
        "4",
        "--out",
        s(&out),
        "--depth-out",
        s(&depth),
        "--timings",
        "json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let img = io::read_color(&out).unwrap();
    assert_eq!((img.width(), img.height()), (64, 36));
    let z = io::read_depth(&depth, &Default::default()).unwrap();
    assert_eq!((z.width(), z.height()), (64, 36));
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).expect("one JSON object");
    assert_eq!(json["method"], "reference");
    assert_eq!(json["width"], 64);
    assert!(json["passes"]
        .as_array()
        .unwrap()
        .iter()
        .any(|p| p["name"] == "reference/raster"));
    assert!(json["total_ms"].as_f64().unwrap() > 0.0);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn bad_lens_parameters_fail_with_a_clear_error_and_no_output() {
    let dir = temp_dir("badlens");
    let out = dir.join("r.png");
    for (flag, value, needle) in [
        ("--fstop", "0", "f-number"),
        ("--fstop", "-2", "f-number"),
        ("--focus", "0", "focus"),
        ("--focus", "5000", "far plane"),
        ("--width", "0", "image size"),
        ("--samples", "0", "samples"),
        ("--aperture", "poly:1", "blades"),
    ] {
        let mut args = vec!["render", flag, value, "--out", s(&out)];
        for (size_flag, size) in [("--width", "32"), ("--height", "18")] {
            if flag != size_flag {
                args.extend([size_flag, size]);
            }
        }
        let o = defocus(&args);
        assert!(!o.status.success(), "{flag} {value} should fail");
        let e = stderr(&o);
        assert!(
            e.contains(needle),
            "{flag} {value}: '{e}' should mention {needle}"
        );
        assert!(!e.contains("panicked"), "{e}");
        assert!(!out.exists(), "no output after an error");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn unsupported_output_format_is_refused_before_rendering() {
    let dir = temp_dir("badext");
    let out = dir.join("r.jpg");
    let o = defocus(&["render", "--out", s(&out)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains(".exr"), "{}", stderr(&o));
    assert!(!out.exists());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn compare_of_an_image_with_itself_is_infinite_psnr_and_ssim_one() {
    let dir = temp_dir("compare");
    let a = dir.join("a.exr");
    let o = defocus(&[
        "render",
        "--method",
        "pinhole",
        "--width",
        "48",
        "--height",
        "32",
        "--out",
        s(&a),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = defocus(&["compare", s(&a), s(&a)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.lines().any(|l| l == "psnr: inf"), "{text}");
    assert!(text.lines().any(|l| l == "ssim: 1.000000"), "{text}");
    assert!(text.lines().any(|l| l.starts_with("mse: 0")), "{text}");
    let o = defocus(&["compare", s(&a), s(&a), "--json"]);
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(json["ssim"], 1.0);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn compare_reports_size_mismatch_and_corrupt_files_without_writing_the_diff() {
    let dir = temp_dir("compare-bad");
    let a = dir.join("a.png");
    let b = dir.join("b.png");
    let diff = dir.join("d.png");
    assert!(defocus(&[
        "render",
        "--method",
        "pinhole",
        "--width",
        "40",
        "--height",
        "30",
        "--out",
        s(&a)
    ])
    .status
    .success());
    assert!(defocus(&[
        "render",
        "--method",
        "pinhole",
        "--width",
        "30",
        "--height",
        "40",
        "--out",
        s(&b)
    ])
    .status
    .success());
    let o = defocus(&["compare", s(&a), s(&b), "--diff", s(&diff)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("mismatch"), "{}", stderr(&o));
    assert!(!diff.exists());
    // Truncated PNG.
    let bytes = std::fs::read(&a).unwrap();
    let cut = dir.join("cut.png");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let o = defocus(&["compare", s(&cut), s(&a), "--diff", s(&diff)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("cut.png"), "{}", stderr(&o));
    assert!(!diff.exists());
    // Missing file.
    let o = defocus(&["compare", s(&dir.join("missing.exr")), s(&a)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("missing.exr"), "{}", stderr(&o));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_diff_map_never_overwrites_an_input() {
    let dir = temp_dir("overwrite");
    let a = dir.join("a.png");
    assert!(defocus(&[
        "render",
        "--method",
        "pinhole",
        "--width",
        "40",
        "--height",
        "30",
        "--out",
        s(&a)
    ])
    .status
    .success());
    let before = std::fs::read(&a).unwrap();
    let o = defocus(&["compare", s(&a), s(&a), "--diff", s(&a)]);
    assert!(!o.status.success());
    assert_eq!(std::fs::read(&a).unwrap(), before);
    std::fs::remove_dir_all(dir).unwrap();
}

/// `render --method multiview` reads its cones in the tent mipmap by default, `--cone-mipmap
/// box` in the paper's (another image), and refuses an unknown filter, naming the flag and the
/// choices.
#[test]
fn multiview_takes_a_cone_mipmap_and_refuses_an_unknown_one() {
    let dir = temp_dir("cone-mipmap");
    let size = [
        "--width",
        "96",
        "--height",
        "54",
        "--method",
        "multiview",
        "--samples",
        "8",
    ];
    let run =
        |extra: &[&str], name: &str| render_image(&[&size[..], extra].concat(), &dir.join(name));
    let default = run(&[], "default.exr");
    let tent = run(&["--cone-mipmap", "tent"], "tent.exr");
    let boxed = run(&["--cone-mipmap", "box"], "box.exr");
    assert_eq!(default, tent);
    assert_ne!(default, boxed);
    render_refuses(&size, "--cone-mipmap", "cubic", "box, tent", &dir);
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--texture-lookups`: `multiview` looks minified textures up at every covered sample by
/// default and `multilayer` once a quadrant (each flag value gives the other's image), and an
/// unknown value is refused, naming the flag and the choices.
#[test]
fn the_layered_methods_take_texture_lookups_and_refuse_an_unknown_one() {
    let dir = temp_dir("texture-lookups");
    for (method, default) in [("multiview", "sample"), ("multilayer", "quadrant")] {
        let size = [
            "--width",
            "96",
            "--height",
            "54",
            "--method",
            method,
            "--samples",
            "8",
        ];
        let run = |extra: &[&str], name: &str| {
            render_image(
                &[&size[..], extra].concat(),
                &dir.join(format!("{method}-{name}")),
            )
        };
        let other = if default == "sample" {
            "quadrant"
        } else {
            "sample"
        };
        let plain = run(&[], "default.exr");
        assert!(
            plain == run(&["--texture-lookups", default], "same.exr"),
            "{method}"
        );
        assert!(
            plain != run(&["--texture-lookups", other], "other.exr"),
            "{method}"
        );
        render_refuses(
            &size,
            "--texture-lookups",
            "trilinear",
            "quadrant, sample",
            &dir,
        );
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// `render --method multiview --layer-origin focus` takes the focus-centred layers (another
/// image than the default `near`, which is the paper's), and an unknown origin is refused,
/// naming the flag and the choices.
#[test]
fn multiview_takes_a_layer_origin_and_refuses_an_unknown_one() {
    let dir = temp_dir("layer-origin");
    // Wide open, so the near railing lies several spacings in front of the focal plane.
    let size = "--width 160 --height 90 --method multiview --samples 8 --fstop 1";
    let size: Vec<&str> = size.split(' ').collect();
    let run =
        |extra: &[&str], name: &str| render_image(&[&size[..], extra].concat(), &dir.join(name));
    let default = run(&[], "default.exr");
    assert!(default == run(&["--layer-origin", "near"], "near.exr"));
    assert!(default != run(&["--layer-origin", "focus"], "focus.exr"));
    render_refuses(&size, "--layer-origin", "far", "near, focus", &dir);
}

/// `--ml-bokeh full` is taken by `render --method multilayer` (its images are tested in
/// `multilayer.rs`), and an unknown bokeh is refused, naming the flag and the choices.
#[test]
fn multilayer_takes_full_bokeh_and_refuses_an_unknown_one() {
    let dir = temp_dir("ml-bokeh");
    let out = dir.join("full.exr");
    let size = ["--width", "96", "--height", "54", "--method", "multilayer"];
    let full = render_image(&[&size[..], &["--ml-bokeh", "full"]].concat(), &out);
    assert_eq!((full.width(), full.height()), (96, 54));
    render_refuses(&size, "--ml-bokeh", "round", "box, shape, full", &dir);
}
