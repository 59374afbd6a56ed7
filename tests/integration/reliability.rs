//! Tests: bad inputs and colliding outputs, as a hostile user would try them.

use defocus::image::{io, ColorImage, GrayImage};

use crate::cli::{defocus, s, stderr, temp_dir};

/// A small frame and its depth, written to `dir`.
fn frame(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let (c, d) = (dir.join("c.exr"), dir.join("z.exr"));
    let color = ColorImage::new(8, 6, [0.5, 0.25, 0.125, 1.0]);
    io::write_color(&c, &color).unwrap();
    io::write_depth_exr(&d, &GrayImage::new(8, 6, 3.0)).unwrap();
    (c, d)
}

fn files_in(dir: &std::path::Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn absurd_thread_counts_are_refused_at_once() {
    for n in ["0", "20000"] {
        let o = defocus(&["--threads", n, "render", "--width", "8", "--height", "8"]);
        assert_eq!(o.status.code(), Some(1), "{n}");
        assert!(stderr(&o).contains("--threads"), "{}", stderr(&o));
    }
}

#[test]
fn two_outputs_at_one_path_are_refused_before_any_work() {
    let dir = temp_dir("collide");
    let x = dir.join("x.exr");
    let o = defocus(&[
        "render",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        s(&x),
        "--depth-out",
        s(&x),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("--out and --depth-out"),
        "{}",
        stderr(&o)
    );
    // The same file written two ways.
    let other = format!("{}/./x.exr", dir.display());
    let o = defocus(&[
        "render",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        s(&x),
        "--depth-out",
        &other,
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let k = dir.join("k.png");
    let f = dir.join("f.png");
    let img = dir.join("in.png");
    io::write_color(&img, &ColorImage::new(8, 8, [0.5; 4])).unwrap();
    for args in [
        vec![
            "kernel",
            "--size",
            "17",
            "--rank",
            "1..3",
            "--out",
            s(&k),
            "--approx-out",
            s(&k),
        ],
        vec![
            "kernel",
            "--size",
            "17",
            "--rank",
            "1..3",
            "--filter",
            s(&img),
            "--filter-out",
            s(&f),
            "--full-2d-out",
            s(&f),
        ],
    ] {
        let o = defocus(&args);
        assert_eq!(o.status.code(), Some(1), "{args:?}");
        assert!(stderr(&o).contains("both name"), "{}", stderr(&o));
    }
    assert_eq!(files_in(&dir), vec!["in.png"]);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_failing_second_output_leaves_no_first_output() {
    let dir = temp_dir("half-written");
    // A folder where the second output should go.
    let blocked = dir.join("blocked.exr");
    std::fs::create_dir(&blocked).unwrap();
    let out = dir.join("r.png");
    let o = defocus(&[
        "render",
        "--method",
        "pinhole",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        s(&out),
        "--depth-out",
        s(&blocked),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let (c, d) = frame(&dir);
    let b = dir.join("b.exr");
    let o = defocus(&[
        "blur",
        "--color",
        s(&c),
        "--depth",
        s(&d),
        "--focus",
        "2",
        "--out",
        s(&b),
        "--coc-out",
        s(&blocked),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let blocked_png = dir.join("blocked.png");
    std::fs::create_dir(&blocked_png).unwrap();
    let k = dir.join("k.png");
    let o = defocus(&[
        "kernel",
        "--size",
        "17",
        "--rank",
        "1..2",
        "--out",
        s(&k),
        "--approx-out",
        s(&blocked_png),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    // Only the inputs and the blocking folders: no output, no temporary file.
    assert_eq!(
        files_in(&dir),
        vec!["blocked.exr", "blocked.png", "c.exr", "z.exr"]
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn non_finite_colour_is_refused_with_its_place_or_sanitized_on_request() {
    let dir = temp_dir("nan-colour");
    let (c, d) = frame(&dir);
    let mut color = io::read_color(&c).unwrap();
    color.pixels_mut()[2 * 8 + 3][1] = f32::NAN;
    color.pixels_mut()[4 * 8 + 1][0] = f32::INFINITY;
    io::write_color(&c, &color).unwrap();
    let out = dir.join("o.exr");
    for method in ["hammon", "lowrank", "gaussian", "poisson", "splat"] {
        let o = defocus(&[
            "blur",
            "--color",
            s(&c),
            "--depth",
            s(&d),
            "--focus",
            "2",
            "--method",
            method,
            "--out",
            s(&out),
        ]);
        assert_eq!(o.status.code(), Some(1), "{method}");
        let e = stderr(&o);
        assert!(
            e.contains("c.exr") && e.contains("channel G") && e.contains("(3, 2)"),
            "{e}"
        );
        assert!(!out.exists());
    }
    let o = defocus(&[
        "blur",
        "--color",
        s(&c),
        "--depth",
        s(&d),
        "--focus",
        "2",
        "--sanitize",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("2 pixel(s)"), "{}", stderr(&o));
    let img = io::read_color(&out).unwrap();
    assert!(img.pixels().iter().flatten().all(|v| v.is_finite()));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn compare_refuses_non_finite_images_instead_of_claiming_a_match() {
    let dir = temp_dir("nan-compare");
    let (a, b) = (dir.join("a.exr"), dir.join("b.exr"));
    let mut img = ColorImage::new(4, 4, [0.0, 0.0, 0.0, 1.0]);
    io::write_color(&b, &img).unwrap();
    img.pixels_mut()[5] = [f32::NAN, 0.0, 0.0, 1.0];
    io::write_color(&a, &img).unwrap();
    for json in [false, true] {
        let mut args = vec!["compare", s(&a), s(&b)];
        if json {
            args.push("--json");
        }
        let o = defocus(&args);
        assert_eq!(o.status.code(), Some(1));
        assert!(o.stdout.is_empty(), "no numbers are printed");
        assert!(
            stderr(&o).contains("a.exr") && stderr(&o).contains("NaN"),
            "{}",
            stderr(&o)
        );
    }
    // The library's metrics refuse too.
    let clean = io::read_color(&b).unwrap();
    assert!(defocus::metrics::compare(&img, &clean).is_err());
    assert!(defocus::metrics::psnr_srgb(&clean, &img).is_err());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn errors_name_the_real_cause() {
    let dir = temp_dir("real-cause");
    let out = dir.join("o.png");
    let cases: [(&str, &str, &str); 4] = [
        (
            "big.obj",
            "v 1e38 0 0\nv 0 1e38 0\nv 0 0 -1e38\nf 1 2 3\n",
            "beyond",
        ),
        (
            "degenerate.obj",
            "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n",
            "zero area",
        ),
        ("empty.obj", "# nothing\n", "no triangles"),
        ("two.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n", "line 3"),
    ];
    for (name, text, needle) in cases {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        let o = defocus(&[
            "render",
            "--scene",
            s(&p),
            "--width",
            "8",
            "--height",
            "8",
            "--out",
            s(&out),
        ]);
        assert_eq!(o.status.code(), Some(1), "{name}");
        let e = stderr(&o);
        assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
        assert!(
            !e.contains("invalid camera"),
            "{name} blamed the camera: {e}"
        );
    }
    // MTL errors name the library and the line.
    std::fs::write(dir.join("m.mtl"), "newmtl a\nKd 1 x 1\n").unwrap();
    let mtl_obj = dir.join("with-mtl.obj");
    std::fs::write(
        &mtl_obj,
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nusemtl a\nf 1 2 3\n",
    )
    .unwrap();
    let o = defocus(&["render", "--scene", s(&mtl_obj), "--out", s(&out)]);
    let e = stderr(&o);
    assert!(
        e.contains("m.mtl") && e.contains("line 2") && e.contains("Kd"),
        "{e}"
    );
    let o = defocus(&["render", "--look-from", "1e30,0,0", "--out", s(&out)]);
    assert!(
        stderr(&o).contains("--look-from") && !stderr(&o).contains("up"),
        "{}",
        stderr(&o)
    );
    // The kernel's default ranks fit its size.
    let o = defocus(&["kernel", "--size", "9"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // Aperture errors list every shape.
    let o = defocus(&["render", "--aperture", "hexagon", "--out", s(&out)]);
    for shape in ["disc", "poly:", "star", "heart", "ring", "image:"] {
        assert!(stderr(&o).contains(shape), "{shape}: {}", stderr(&o));
    }
    // A PNG named .exr is read as the PNG it is; a missing file's OS error is printed once.
    let png = dir.join("shot.exr");
    io::write_color(&dir.join("shot.png"), &ColorImage::new(4, 4, [0.5; 4])).unwrap();
    std::fs::copy(dir.join("shot.png"), &png).unwrap();
    let o = defocus(&["compare", s(&png), s(&dir.join("shot.png"))]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = defocus(&["compare", s(&dir.join("missing.exr")), s(&png)]);
    assert_eq!(stderr(&o).matches("os error").count(), 1, "{}", stderr(&o));
    // A scene path without an extension.
    let bare = dir.join("scene");
    std::fs::write(&bare, "v 0 0 0\n").unwrap();
    let o = defocus(&["render", "--scene", s(&bare), "--out", s(&out)]);
    assert!(stderr(&o).contains("no extension"), "{}", stderr(&o));
    assert!(!out.exists());
    std::fs::remove_dir_all(dir).unwrap();
}

/// The layered methods plan their peak memory before they allocate: at the largest frame with
/// their largest options they are refused at once, naming what to lower; at 1280x720 with their
/// defaults they stay far inside the 16 GiB budget.
#[test]
fn layered_methods_refuse_frames_beyond_the_memory_budget() {
    let dir = temp_dir("budget");
    let out = dir.join("o.png");
    let big = ["--width", "8192", "--height", "8192", "--out", s(&out)];
    for (method, extra, needle) in [
        ("multilayer", vec!["--fragments", "16"], "--fragments"),
        ("splat", vec!["--layers", "16"], "--layers"),
        ("multiview", vec!["--layer-spacing", "0.25"], "--layers"),
    ] {
        let mut args = vec!["render", "--method", method];
        args.extend(extra);
        args.extend(big);
        let o = defocus(&args);
        assert_eq!(o.status.code(), Some(1), "{method}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(e.contains("GiB") && e.contains(needle), "{method}: {e}");
        assert!(!out.exists());
    }
    // A smaller budget is honoured too.
    let o = defocus(&[
        "--memory-budget",
        "0.001",
        "render",
        "--method",
        "multilayer",
        "--width",
        "320",
        "--height",
        "180",
        "--out",
        s(&out),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    // Defaults at 1280x720: well inside the default budget.
    let lens = defocus::scene::builtin::load("railing")
        .unwrap()
        .defaults
        .unwrap()
        .camera
        .thin_lens()
        .unwrap();
    let ml = defocus::methods::multilayer::peak_bytes(&lens, &Default::default());
    let mv = defocus::methods::multiview::peak_bytes(&lens, 16);
    for b in [ml, mv] {
        assert!(b < defocus::budget::DEFAULT_BUDGET_BYTES / 16, "{b}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// Every method estimates its peak before it allocates and refuses a frame beyond the
/// budget, naming the budget and what to lower, with no output; so does decoding an image whose
/// small file claims a huge size, and comparing two.
#[test]
fn every_method_refuses_a_frame_beyond_the_memory_budget_before_rendering() {
    let dir = temp_dir("budget-all");
    let out = dir.join("o.exr");
    for id in defocus::methods::registry::ids() {
        let o = defocus(&[
            "--memory-budget",
            "0.25",
            "render",
            "--method",
            id,
            "--width",
            "4096",
            "--height",
            "4096",
            "--out",
            s(&out),
        ]);
        assert_eq!(o.status.code(), Some(1), "{id}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(
            e.contains("budget of 0.25 GiB") && e.contains("lower"),
            "{id}: {e}"
        );
        assert!(!out.exists(), "{id}");
    }
    // A 4096x4096 PNG of one colour is a small file that decodes to 256 MiB and more.
    let png = dir.join("flat.png");
    image::RgbImage::from_pixel(4096, 4096, image::Rgb([90, 90, 90]))
        .save(&png)
        .unwrap();
    assert!(std::fs::metadata(&png).unwrap().len() < 1 << 20);
    let o = defocus(&["--memory-budget", "0.25", "compare", s(&png), s(&png)]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("flat.png") && e.contains("budget"), "{e}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// Whether this system reports a process's largest resident size (`VmHWM`); prints why not.
fn resident_peak_reported() -> bool {
    let ok = std::fs::read_to_string("/proc/self/status").is_ok_and(|s| s.contains("VmHWM"));
    if !ok {
        eprintln!("skipped: no /proc/self/status VmHWM on this system");
    }
    ok
}

/// `render --scene S --method M` at 640x360 with `extra` flags into `out`: its `--timings
/// json` object (which holds `max_rss_bytes`).
fn render_timings(
    scene: &str,
    method: &str,
    extra: &[&str],
    out: &std::path::Path,
) -> serde_json::Value {
    let mut args = vec![
        "render",
        "--scene",
        scene,
        "--method",
        method,
        "--width",
        "640",
        "--height",
        "360",
        "--timings",
        "json",
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    let o = defocus(&args);
    assert!(o.status.success(), "{scene} {method}: {}", stderr(&o));
    serde_json::from_slice(&o.stdout).expect("json")
}

/// The measured peak of `what` is at most its estimate and at least a quarter of it.
fn assert_peak_within(what: &str, json: &serde_json::Value, estimate: u64) {
    let rss = json["max_rss_bytes"].as_u64().expect("max_rss_bytes");
    eprintln!("{what}: resident peak {rss} bytes, estimate {estimate}");
    assert!(rss <= estimate, "{what}: {rss} > {estimate}");
    assert!(rss * 4 >= estimate, "{what}: {rss} is far below {estimate}");
}

/// A built-in scene and its own camera at `w` x `h`.
fn builtin_at(name: &str, w: usize, h: usize) -> (defocus::scene::Scene, defocus::lens::Camera) {
    let scene = defocus::scene::builtin::load(name).unwrap();
    let mut camera = scene.defaults.clone().unwrap().camera;
    camera.width_px = w;
    camera.height_px = h;
    (scene, camera)
}

/// The estimate a method is held to is an upper bound of what it takes, and not a wild one:
/// at its defaults on `railing` at 640x360, the process's largest resident size (reported by
/// `--timings json`, Linux only) is at most the estimate and at least a quarter of it.
#[test]
fn estimated_peak_memory_bounds_the_measured_peak_of_every_frame_method() {
    if !resident_peak_reported() {
        return;
    }
    let dir = temp_dir("budget-peak");
    let out = dir.join("o.exr");
    for id in [
        "reference",
        "pinhole",
        "hammon",
        "lowrank",
        "gaussian",
        "poisson",
    ] {
        let json = render_timings("railing", id, &["--samples", "4"], &out);
        let settings = defocus::methods::registry::MethodSettings::default_for(id).unwrap();
        let estimate = defocus::methods::registry::peak_bytes(&settings, 640, 360);
        assert_peak_within(id, &json, estimate);
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// A reader of the output that has gone (`defocus compare a b | head -1`) ends the command
/// quietly, not in a panic; a standard output that cannot be written (a full disk) is an error.
#[test]
fn output_to_a_closed_pipe_is_no_panic_and_to_a_full_device_an_error() {
    let dir = temp_dir("pipe");
    let img = dir.join("a.exr");
    io::write_color(&img, &ColorImage::new(8, 8, [0.5; 4])).unwrap();
    for args in [
        vec!["compare", s(&img), s(&img)],
        vec!["kernel", "--size", "9", "--json"],
    ] {
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_defocus"))
            .args(&args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let o = child.wait_with_output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!e.contains("panicked"), "{args:?}: {e}");
        assert_eq!(o.status.code(), Some(0), "{args:?}: {e}");
    }
    if let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_defocus"))
            .args(["compare", s(&img), s(&img)])
            .stdout(full)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(1));
        assert!(stderr(&o).contains("standard output"), "{}", stderr(&o));
    } else {
        eprintln!("skipped the full-device case: no /dev/full here");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// The layered methods are held to their own estimates, made before they allocate from the
/// frame grown by its guard band: `multilayer`'s fragment lists and levels, `multiview`'s
/// layers for the layer count its CoC range gives. At their defaults on `railing` and `grass`
/// at 640x360, the measured peak lies at or below the fixed part, the frame and that estimate,
/// and at least a quarter of it. (`splat`'s tile lists are counted from its fragments before
/// they are allocated: the next test.)
#[test]
fn layered_methods_stay_within_their_own_memory_estimates() {
    use defocus::methods::registry::{self, MethodSettings};
    use defocus::methods::{multilayer, multiview};
    use defocus::raster::PreparedScene;
    if !resident_peak_reported() {
        return;
    }
    let dir = temp_dir("budget-layered");
    let out = dir.join("o.exr");
    for name in ["railing", "grass"] {
        let (scene, camera) = builtin_at(name, 640, 360);
        let frame = camera.thin_lens().unwrap();
        let prepared = PreparedScene::new(&scene, &camera.camera_from_world).unwrap();
        for id in ["multilayer", "multiview"] {
            let settings = MethodSettings::default_for(id).unwrap();
            let own = match &settings {
                MethodSettings::Multilayer(s) => {
                    let lens = frame.with_guard_band(s.input.guard_band_px(&prepared, &frame));
                    multilayer::peak_bytes(&lens, s)
                }
                MethodSettings::Multiview(s) => {
                    let lens = frame.with_guard_band(s.input.guard_band_px(&prepared, &frame));
                    let range = multiview::coc_range(&prepared, &lens);
                    let layers = multiview::spacing_for(lens, s, range).layers;
                    multiview::peak_bytes(&lens, layers)
                }
                _ => unreachable!(),
            };
            let estimate = registry::peak_bytes(&settings, 640, 360) + own;
            let json = render_timings(name, id, &[], &out);
            assert_peak_within(&format!("{name} {id}"), &json, estimate);
        }
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// `splat` at its defaults (one layer, on the 16-sample pinhole frame) is held to the frame's
/// estimate plus what it counts before allocating: its fragments and its tile lists (counted
/// from the fragments, then held twice while they are laid out: the chunks' runs and the
/// lists). At 640x360 on `railing` and `grass` the measured peak lies at or below that, and at
/// least a quarter of it.
#[test]
fn splat_stays_within_its_frame_estimate_and_counted_lists() {
    use defocus::methods::registry::{self, MethodSettings, SceneOptions};
    if !resident_peak_reported() {
        return;
    }
    let dir = temp_dir("budget-splat");
    let out = dir.join("o.exr");
    for name in ["railing", "grass"] {
        let (scene, camera) = builtin_at(name, 640, 360);
        let settings = MethodSettings::default_for("splat").unwrap();
        let run = registry::run_scene(
            &settings,
            &scene,
            &camera,
            &SceneOptions::default(),
            &mut |_, _| {},
        )
        .unwrap();
        let counted = run.memory_bytes.expect("splat reports its storage") as u64;
        let estimate = registry::peak_bytes(&settings, 640, 360) + 2 * counted;
        let json = render_timings(name, "splat", &[], &out);
        assert_eq!(
            json["memory_bytes"].as_u64(),
            Some(counted),
            "{name}: the CLI's run is the one estimated"
        );
        assert_peak_within(&format!("{name} splat"), &json, estimate);
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--no-fsync` only skips the wait for the disk: the output is the same file, written whole
/// through a staged file and a rename (no staged file is left beside it).
#[test]
fn no_fsync_writes_the_same_output_whole() {
    let dir = temp_dir("nofsync");
    let (c, d) = frame(&dir);
    let (a, b) = (dir.join("a.exr"), dir.join("b.exr"));
    for (out, extra) in [(&a, None), (&b, Some("--no-fsync"))] {
        let mut args = vec!["blur", "--color", s(&c), "--depth", s(&d), "--focus", "2"];
        args.extend(["--method", "hammon", "--out", s(out)]);
        args.extend(extra);
        let o = defocus(&args);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    }
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert_eq!(files_in(&dir), ["a.exr", "b.exr", "c.exr", "z.exr"]);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A standard error whose reader has gone (`defocus render ... 2>&1 | head -1`, a log
/// collector that died) is no panic: each command ends with its own exit status, 0 when it
/// succeeded and 1 when it failed.
#[test]
fn a_closed_standard_error_is_no_panic_and_keeps_the_exit_status() {
    use std::os::fd::{FromRawFd, OwnedFd};
    let dir = temp_dir("closed-stderr");
    let (c, d) = frame(&dir);
    let out = dir.join("o.exr");
    let report = dir.join("report");
    let cases: Vec<(Vec<&str>, i32)> = vec![
        // Success, with lines on standard error (timings, the report's path).
        (
            vec![
                "render",
                "--width",
                "8",
                "--height",
                "6",
                "--samples",
                "2",
                "--timings",
                "--out",
                s(&out),
            ],
            0,
        ),
        (
            vec![
                "blur",
                "--color",
                s(&c),
                "--depth",
                s(&d),
                "--focus",
                "2",
                "--timings",
                "--out",
                s(&out),
            ],
            0,
        ),
        (
            vec![
                "compare",
                "--color",
                s(&c),
                "--depth",
                s(&d),
                "--truth",
                s(&c),
                "--methods",
                "hammon",
                "--out",
                s(&report),
            ],
            0,
        ),
        // Failure: the error line itself cannot be written.
        (
            vec![
                "blur",
                "--color",
                "missing.exr",
                "--depth",
                s(&d),
                "--out",
                s(&out),
            ],
            1,
        ),
        (vec!["render", "--width", "0", "--out", s(&out)], 1),
    ];
    for (args, code) in cases {
        let mut fds = [0; 2];
        // SAFETY: `fds` has room for the two descriptors pipe writes.
        assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
        // SAFETY: both descriptors were just created and are owned here, once each.
        let (read, write) = unsafe { (OwnedFd::from_raw_fd(fds[0]), OwnedFd::from_raw_fd(fds[1])) };
        // The reader is gone before the command starts: every write to stderr fails.
        drop(read);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_defocus"))
            .args(&args)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::from(write))
            .status()
            .unwrap();
        assert_eq!(o.code(), Some(code), "{args:?}");
    }
}

#[test]
fn an_invalid_memory_budget_in_the_environment_is_refused_naming_it() {
    let dir = temp_dir("budget-env");
    let out = dir.join("o.png");
    let run = |value: &str, extra: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_defocus"))
            .env("DEFOCUS_MEMORY_BUDGET_GIB", value)
            .args(extra)
            .args(["render", "--width", "8", "--height", "6", "--out", s(&out)])
            .arg("--quiet")
            .output()
            .unwrap()
    };
    for value in ["0", "-1", "nan", "inf", "abc", "", "1e7"] {
        let o = run(value, &[]);
        assert_eq!(o.status.code(), Some(1), "{value:?}");
        let err = stderr(&o);
        assert!(
            err.contains("DEFOCUS_MEMORY_BUDGET_GIB")
                && err.contains("expected a number of GiB greater than 0"),
            "{value:?}: {err}"
        );
        assert!(!out.exists(), "{value:?}");
    }
    // A good value, and --memory-budget over a bad one, run.
    let o = run(" 0.5 ", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run("abc", &["--memory-budget", "2"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// A process killed outright (SIGKILL) leaves its staged files: the next output written into
/// that folder removes those of processes that are gone, and no other file.
#[test]
fn staged_files_of_a_killed_process_are_removed_beside_the_next_output() {
    let dir = temp_dir("stale-staged");
    let (c, d) = frame(&dir);
    // A writer killed half-way through an output.
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(["render", "--width", "4", "--height", "4", "--out"])
        .arg(dir.join("never.png"))
        .spawn()
        .unwrap();
    let gone = child.id();
    child.kill().unwrap();
    child.wait().unwrap();
    let stale = format!(".defocus-{gone}-0123456789abcdef.tmp");
    std::fs::write(dir.join(&stale), b"half an image").unwrap();
    // Files that only look alike, and one of a process that still runs (this one).
    let alive = format!(".defocus-{}-0123456789abcdef.tmp", std::process::id());
    let others = [
        alive.as_str(),
        ".defocus-12-xyz.tmp",
        "defocus-1-0123456789abcdef.tmp",
        ".defocus-lock",
    ];
    for name in others {
        std::fs::write(dir.join(name), b"keep").unwrap();
    }
    let o = defocus(&[
        "blur",
        "--color",
        s(&c),
        "--depth",
        s(&d),
        "--focus",
        "2",
        "--out",
        s(&dir.join("b.exr")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let files = files_in(&dir);
    assert!(!files.contains(&stale), "{files:?}");
    for name in others {
        assert!(files.iter().any(|f| f == name), "{name}: {files:?}");
    }
    assert!(files.iter().any(|f| f == "b.exr"), "{files:?}");
}
