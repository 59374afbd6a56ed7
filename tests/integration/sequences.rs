//! Tests: image sequences in `blur` and `render` (frame patterns, --frames, resuming, keyframed
//! focus and f-number), run as a compositor would.

use std::path::Path;

use defocus::image::{io, ColorImage, GrayImage};

use crate::cli::{defocus, s, stderr, temp_dir};

const W: usize = 48;
const H: usize = 24;

/// Depth of the three vertical bands of every test frame, in metres. The middle one is where a
/// rack focus from the first to the last is halfway in 1/distance: 1/2.4 = (1/1.5 + 1/6) / 2.
const BANDS_M: [f32; 3] = [1.5, 2.4, 6.0];

/// Writes frames `frames` of a colour pattern `c.####.exr` and a depth pattern `d.####.exr`
/// into `dir`: a checkerboard over three depth bands.
fn write_frames(dir: &Path, frames: &[i64]) {
    for &n in frames {
        let mut rgba = Vec::with_capacity(W * H);
        for y in 0..H {
            for x in 0..W {
                let v = if (x / 3 + y / 3 + n as usize).is_multiple_of(2) {
                    0.9
                } else {
                    0.1
                };
                rgba.push([v, v, v, 1.0]);
            }
        }
        let color = ColorImage::from_vec(W, H, rgba).unwrap();
        let depth: Vec<f32> = (0..W * H).map(|i| BANDS_M[(i % W) * 3 / W]).collect();
        let depth = GrayImage::from_vec(W, H, depth).unwrap();
        io::write_color(&dir.join(format!("c.{n:04}.exr")), &color).unwrap();
        io::write_depth_exr(&dir.join(format!("d.{n:04}.exr")), &depth).unwrap();
    }
}

/// The CoC radius in pixels at the centre of band `band` of a `--coc-out` file.
fn coc_at_band(path: &Path, band: usize) -> f32 {
    let coc = io::read_coc(path, None).unwrap();
    let x = band * W / 3 + W / 6;
    coc.pixels()[(H / 2) * W + x]
}

#[test]
fn blur_sequence_racks_focus_linearly_in_inverse_distance() {
    let dir = temp_dir("seq-rack");
    write_frames(&dir, &[1, 2, 3]);
    let o = defocus(&[
        "blur",
        "--color",
        s(&dir.join("c.####.exr")),
        "--depth",
        s(&dir.join("d.%04d.exr")),
        "--out",
        s(&dir.join("o.####.png")),
        "--coc-out",
        s(&dir.join("coc.@@@@.exr")),
        "--frames",
        "1-3",
        "--focus",
        "1:1.5,3:6",
        "--fstop",
        "2",
        // A long lens on a small frame: CoC of several pixels between the bands.
        "--sensor-width",
        "2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for n in 1..=3usize {
        assert!(dir.join(format!("o.{n:04}.png")).is_file());
        let coc = dir.join(format!("coc.{n:04}.exr"));
        // Frame n focuses on band n - 1: zero CoC there, a clear blur on the other bands.
        for band in 0..3 {
            let c = coc_at_band(&coc, band);
            if band == n - 1 {
                assert!(c.abs() < 0.05, "frame {n} band {band}: CoC {c} px");
            } else {
                assert!(c.abs() > 1.0, "frame {n} band {band}: CoC {c} px");
            }
        }
    }
}

#[test]
fn blur_sequence_finds_its_frames_on_disk_and_resumes() {
    let dir = temp_dir("seq-resume");
    write_frames(&dir, &[7, 8, 9]);
    let args = |extra: &[&str]| {
        let mut a = vec![
            "blur".to_string(),
            "--color".into(),
            s(&dir.join("c.####.exr")).into(),
            "--depth".into(),
            s(&dir.join("d.####.exr")).into(),
            "--out".into(),
            s(&dir.join("o.####.exr")).into(),
            "--focus".into(),
            "2".into(),
        ];
        a.extend(extra.iter().map(|e| e.to_string()));
        a
    };
    let run = |extra: &[&str]| {
        let a = args(extra);
        defocus(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let o = run(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    for n in 7..=9 {
        assert!(io::read_color(&dir.join(format!("o.{n:04}.exr"))).is_ok());
    }
    // A finished frame is kept as it is: here, another whole image in place of frame 8's
    // output.
    let marker = dir.join("o.0008.exr");
    io::write_color(&marker, &ColorImage::new(2, 1, [0.25, 0.5, 0.75, 1.0])).unwrap();
    let kept = std::fs::read(&marker).unwrap();
    let o = run(&[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(&marker).unwrap(), kept);
    // --overwrite renders it again.
    let o = run(&["--overwrite"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(io::image_size(&marker).unwrap(), (W, H));
}

/// Each output format, cut short in the ways a full disk, a killed copy or a crash after
/// `--no-fsync` leave it: a resumed sequence makes such a frame again and keeps the whole ones.
#[test]
fn a_resumed_sequence_makes_empty_and_truncated_outputs_again() {
    use std::os::unix::fs::MetadataExt;
    for ext in ["exr", "png", "pfm"] {
        let dir = temp_dir(&format!("seq-truncated-{ext}"));
        write_frames(&dir, &[1, 2, 3, 4, 5]);
        let out = |n: i64| dir.join(format!("o.{n:04}.{ext}"));
        let coc = |n: i64| dir.join(format!("k.{n:04}.exr"));
        let run = || {
            defocus(&[
                "blur",
                "--color",
                s(&dir.join("c.####.exr")),
                "--depth",
                s(&dir.join("d.####.exr")),
                "--out",
                s(&dir.join(format!("o.####.{ext}"))),
                "--coc-out",
                s(&dir.join("k.####.exr")),
                "--focus",
                "2",
            ])
        };
        let o = run();
        assert!(o.status.success(), "{ext}: {}", stderr(&o));
        let whole = std::fs::metadata(out(5)).unwrap().len();
        let whole_coc = std::fs::metadata(coc(5)).unwrap().len();
        // Frame 1: an empty output; 2: half of it; 3: all but its last byte; 4: its CoC map
        // without its last byte. Frame 5 stays whole.
        std::fs::write(out(1), b"").unwrap();
        for (path, len) in [
            (out(2), whole / 2),
            (out(3), whole - 1),
            (coc(4), whole_coc - 1),
        ] {
            let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
            f.set_len(len).unwrap();
        }
        let kept = std::fs::metadata(out(5)).unwrap().ino();
        let o = run();
        assert!(o.status.success(), "{ext}: {}", stderr(&o));
        let err = stderr(&o);
        for n in 1..=5 {
            assert_eq!(io::image_size(&out(n)).unwrap(), (W, H), "{ext} frame {n}");
            io::check_whole(&out(n)).unwrap();
            io::check_whole(&coc(n)).unwrap();
            assert!(io::read_color(&out(n)).is_ok(), "{ext} frame {n}");
            assert!(io::read_coc(&coc(n), None).is_ok(), "{ext} frame {n}");
        }
        for n in 1..=4 {
            assert!(
                err.contains(&format!("note: frame {n}: ")) && err.contains("not a whole image"),
                "{ext} frame {n}: {err}"
            );
        }
        assert!(!err.contains("frame 5"), "{ext}: {err}");
        // Frame 5 was kept, not written again (a write renames a new file into place).
        assert_eq!(std::fs::metadata(out(5)).unwrap().ino(), kept, "{ext}");
    }
}

#[test]
fn a_missing_frame_is_named_and_the_others_still_finish() {
    let dir = temp_dir("seq-missing");
    write_frames(&dir, &[1, 2, 3, 4]);
    std::fs::remove_file(dir.join("c.0003.exr")).unwrap();
    std::fs::write(dir.join("d.0002.exr"), b"not an exr").unwrap();
    let o = defocus(&[
        "blur",
        "--color",
        s(&dir.join("c.####.exr")),
        "--depth",
        s(&dir.join("d.####.exr")),
        "--out",
        s(&dir.join("o.####.png")),
        "--frames",
        "1-4",
    ]);
    assert!(!o.status.success());
    let err = stderr(&o);
    assert!(err.contains("c.0003.exr"), "{err}");
    assert!(err.contains("d.0002.exr"), "{err}");
    assert!(err.contains("2 of 4 frames failed"), "{err}");
    assert!(dir.join("o.0001.png").is_file());
    assert!(dir.join("o.0004.png").is_file());
    assert!(!dir.join("o.0002.png").exists());
    assert!(!dir.join("o.0003.png").exists());
}

#[test]
fn render_sequence_turns_the_aperture_ring_in_stops() {
    let dir = temp_dir("seq-render");
    let o = crate::cli::defocus(&[
        "render",
        "--scene",
        "lights",
        "--method",
        "pinhole",
        "--width",
        "32",
        "--height",
        "18",
        "--focal-length",
        "40",
        "--frames",
        "1-3",
        "--fstop",
        "1:2,3:8",
        "--out",
        s(&dir.join("r.####.png")),
        "--depth-out",
        s(&dir.join("z.####.exr")),
        "--verbose",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    // f/2, f/4 (halfway in stops) and f/8 of a 40 mm lens: radii 10, 5 and 2.5 mm.
    let radii: Vec<&str> = err
        .lines()
        .filter_map(|l| l.split("lens radius ").nth(1))
        .filter_map(|r| r.split(' ').next())
        .map(|r| r.trim_end_matches(','))
        .collect();
    assert_eq!(radii, ["0.01000", "0.00500", "0.00250"], "{err}");
    for n in 1..=3 {
        assert!(dir.join(format!("r.{n:04}.png")).is_file());
        assert!(dir.join(format!("z.{n:04}.exr")).is_file());
    }
}

#[test]
fn sequence_flags_without_a_sequence_are_refused_with_the_flag_named() {
    let dir = temp_dir("seq-refused");
    write_frames(&dir, &[1]);
    let path = |name: &str| s(&dir.join(name)).to_string();
    let (c, d) = (path("c.0001.exr"), path("d.0001.exr"));
    let (cs, ds) = (path("c.####.exr"), path("d.####.exr"));
    let (png, pngs) = (path("o.png"), path("o.####.png"));
    // (colour, depth, output, more flags, what the error names)
    let cases: Vec<(&str, &str, &str, &[&str], &str)> = vec![
        (&c, &d, &png, &["--focus", "1:2,5:3"], "--focus"),
        (&c, &d, &png, &["--fstop", "1:2,5:3"], "--fstop"),
        (&c, &d, &png, &["--frames", "1-3"], "--frames"),
        (&c, &d, &pngs, &[], "--out"),
        (&cs, &ds, &png, &[], "--out"),
        (&cs, &ds, &pngs, &["--frames", "1-x"], "--frames"),
        (&cs, &ds, &cs, &[], "outputs never overwrite inputs"),
    ];
    for (color, depth, out, more, expected) in cases {
        let mut all = vec!["blur", "--color", color, "--depth", depth, "--out", out];
        all.extend_from_slice(more);
        let o = defocus(&all);
        assert!(!o.status.success(), "{all:?}");
        let err = stderr(&o);
        assert!(err.contains(expected), "{all:?}: {err}");
        assert!(!dir.join("o.png").exists());
    }
    let o = defocus(&[
        "render",
        "--out",
        s(&dir.join("r.####.png")),
        "--width",
        "16",
        "--height",
        "9",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--frames"), "{}", stderr(&o));
}

/// The `openjd` command of the Open Job Description CLI: `DEFOCUS_OPENJD`, else the one
/// `scripts/test` installs into its virtual environment, else one on the PATH.
fn openjd() -> Option<std::path::PathBuf> {
    if let Some(p) = std::env::var_os("DEFOCUS_OPENJD") {
        return Some(p.into());
    }
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-venv/bin/openjd");
    if venv.is_file() {
        return Some(venv);
    }
    let on_path = std::process::Command::new("openjd")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    on_path.then(|| "openjd".into())
}

/// The farm template (`farm/openjd/defocus-blur.yaml`) run by `openjd run` as a farm would run
/// it: 5 frames in chunks of 2, each task one `defocus blur --frames A-B`; every frame is the
/// one a direct `defocus blur` writes, and a missing input frame fails its task.
#[test]
fn openjd_template_blurs_a_sequence_in_chunks() {
    let Some(openjd) = openjd() else {
        eprintln!(
            "skipped: the Open Job Description CLI is not installed (pip install openjd-cli, or \
             set DEFOCUS_OPENJD); scripts/test installs it"
        );
        return;
    };
    let dir = temp_dir("openjd");
    write_frames(&dir, &[1, 2, 3, 4, 5]);
    let template = Path::new(env!("CARGO_MANIFEST_DIR")).join("farm/openjd/defocus-blur.yaml");
    let run = |out: &str, last: i64| {
        std::process::Command::new(&openjd)
            .arg("run")
            .arg(&template)
            .args(["-p", &format!("Color={}", dir.join("c.####.exr").display())])
            .args(["-p", &format!("Depth={}", dir.join("d.####.exr").display())])
            .args(["-p", &format!("Out={}", dir.join(out).display())])
            .args(["-p", "FirstFrame=1", "-p", &format!("LastFrame={last}")])
            .args([
                "-p",
                "ChunkSize=2",
                "-p",
                "Args=--method hammon --focus 2.4 --fstop 2",
            ])
            .args(["-p", &format!("Defocus={}", env!("CARGO_BIN_EXE_defocus"))])
            .output()
            .unwrap()
    };
    let o = run("o.####.exr", 5);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stdout));
    let log = String::from_utf8_lossy(&o.stdout);
    for chunk in ["frames 1-2", "frames 3-4", "frames 5-5"] {
        assert!(log.contains(chunk), "no task for {chunk}: {log}");
    }
    let direct = dir.join("direct.exr");
    let d = defocus(&[
        "blur",
        "--color",
        s(&dir.join("c.0003.exr")),
        "--depth",
        s(&dir.join("d.0003.exr")),
        "--method",
        "hammon",
        "--focus",
        "2.4",
        "--fstop",
        "2",
        "--out",
        s(&direct),
    ]);
    assert!(d.status.success(), "{}", stderr(&d));
    for n in 1..=5 {
        assert!(dir.join(format!("o.{n:04}.exr")).is_file(), "frame {n}");
    }
    assert_eq!(
        std::fs::read(dir.join("o.0003.exr")).unwrap(),
        std::fs::read(&direct).unwrap()
    );
    // A frame missing from the input fails its task, and the run.
    std::fs::remove_file(dir.join("c.0004.exr")).unwrap();
    let o = run("p.####.exr", 4);
    assert!(
        !o.status.success(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("c.0004.exr"));
    std::fs::remove_dir_all(dir).unwrap();
}

/// A sequence in which one frame's output is another frame's input or output, or an input in
/// another spelling, is refused before any frame runs, naming both flags and frames; nothing is
/// written and no input changes.
#[test]
fn a_frame_output_that_is_another_frames_file_is_refused_before_any_frame() {
    let dir = temp_dir("seq-clash");
    let frames: Vec<i64> = (1..=20).collect();
    write_frames(&dir, &frames);
    // The same frames as `s#.exr` (one digit per frame up to 9), and one depth file.
    for &n in &frames {
        std::fs::copy(
            dir.join(format!("c.{n:04}.exr")),
            dir.join(format!("s{n}.exr")),
        )
        .unwrap();
    }
    std::fs::copy(dir.join("d.0001.exr"), dir.join("z.exr")).unwrap();
    std::fs::copy(dir.join("d.0001.exr"), dir.join("z5.exr")).unwrap();
    let link = dir.join("alias");
    std::os::unix::fs::symlink(&*dir, &link).unwrap();
    let p = |name: &str| s(&dir.join(name)).to_string();
    let dotted = format!("{}/./c.####.exr", s(&dir));
    let aliased = s(&link.join("c.####.exr")).to_string();
    // (flags after `blur`, what the error names)
    let cases: Vec<(Vec<String>, Vec<&str>)> = vec![
        (
            vec![
                "--color",
                &p("s#.exr"),
                "--depth",
                &p("z.exr"),
                "--frames",
                "1-20",
            ]
            .into_iter()
            .map(String::from)
            .chain([
                "--out".into(),
                p("s1#.exr"),
                "--coc-out".into(),
                p("k#.exr"),
            ])
            .collect(),
            vec![
                "--out",
                "frame 1 would",
                "s11.exr",
                "frame 11 of --color",
                "overwrite inputs",
            ],
        ),
        (
            vec![
                "--color".into(),
                p("c.####.exr"),
                "--depth".into(),
                p("d.####.exr"),
                "--frames".into(),
                "1-20".into(),
                "--out".into(),
                p("o#.exr"),
                "--coc-out".into(),
                p("o1#.exr"),
            ],
            vec![
                "--out",
                "frame 11 would",
                "o11.exr",
                "frame 1 of --coc-out",
                "each other",
            ],
        ),
        (
            vec![
                "--color".into(),
                p("c.####.exr"),
                "--depth".into(),
                p("d.####.exr"),
                "--out".into(),
                p("c.%04d.exr"),
            ],
            vec!["--out", "frame 1 of --color", "overwrite inputs"],
        ),
        (
            vec![
                "--color".into(),
                p("c.####.exr"),
                "--depth".into(),
                p("d.####.exr"),
                "--out".into(),
                dotted,
            ],
            vec!["--out", "of --color", "overwrite inputs"],
        ),
        (
            vec![
                "--color".into(),
                p("c.####.exr"),
                "--depth".into(),
                p("d.####.exr"),
                "--out".into(),
                aliased,
            ],
            vec!["--out", "of --color", "overwrite inputs"],
        ),
        (
            vec![
                "--color".into(),
                p("c.####.exr"),
                "--depth".into(),
                p("z5.exr"),
                "--frames".into(),
                "1-9".into(),
                "--out".into(),
                p("z#.exr"),
            ],
            vec![
                "--out",
                "frame 5 would",
                "z5.exr",
                "--depth",
                "overwrite inputs",
            ],
        ),
    ];
    let before: Vec<(String, Vec<u8>)> = std::fs::read_dir(&*dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file())
        .map(|p| (s(&p).to_string(), std::fs::read(&p).unwrap()))
        .collect();
    let count = before.len();
    for (flags, expected) in &cases {
        let mut args = vec!["blur", "--method", "hammon", "--focus", "2.4"];
        args.extend(flags.iter().map(String::as_str));
        let o = defocus(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{flags:?}: {e}");
        for x in expected {
            assert!(e.contains(x), "{flags:?}: no '{x}' in {e}");
        }
        assert!(!e.contains("kept"), "{flags:?}: {e}");
    }
    // Render: a frame's image is another frame's depth pass.
    let o = defocus(&[
        "render",
        "--width",
        "16",
        "--height",
        "9",
        "--frames",
        "1-12",
        "--out",
        &p("r#.exr"),
        "--depth-out",
        &p("r1#.exr"),
    ]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("frame 1 of --depth-out") && e.contains("r11.exr"),
        "{e}"
    );
    // Nothing was written, nothing changed.
    let after = std::fs::read_dir(&*dir)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().is_file())
        .count();
    assert_eq!(after, count, "a file was written");
    for (path, bytes) in &before {
        assert!(std::fs::read(path).unwrap() == *bytes, "{path} changed");
    }
}

/// The farm template's task script is fixed text: no parameter is pasted into it, so none can
/// be read as shell code.
#[test]
fn openjd_template_pastes_no_parameter_into_shell_text() {
    let template = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("farm/openjd/defocus-blur.yaml"),
    )
    .unwrap();
    let script = template
        .split("data: |")
        .nth(1)
        .expect("the template embeds its task script");
    assert!(
        !script.contains("{{"),
        "a parameter in the script: {script}"
    );
    for param in [
        "Color",
        "Depth",
        "Out",
        "Args",
        "Defocus",
        "LastFrame",
        "ChunkSize",
    ] {
        assert!(
            template.contains(&format!("- \"{{{{Param.{param}}}}}\"")),
            "{param} is not passed as an argument of its own"
        );
    }
}

/// The farm template with hostile names: folders named `x'$(touch PWNED)'y` and `bob's shot`,
/// flags holding `$(...)`, and negative frames. Every frame is written, and nothing is run.
#[test]
fn openjd_template_runs_no_shell_text_from_its_parameters() {
    let Some(openjd) = openjd() else {
        eprintln!(
            "skipped: the Open Job Description CLI is not installed (pip install openjd-cli, or \
             set DEFOCUS_OPENJD); scripts/test installs it"
        );
        return;
    };
    let base = temp_dir("openjd-hostile");
    let input = base.join("x'$(touch PWNED)'y");
    let output = base.join("bob's shot");
    std::fs::create_dir(&input).unwrap();
    std::fs::create_dir(&output).unwrap();
    // Frames -3 to -1: written as 1 to 3, then named as the pattern names negative frames.
    let frames = [-3, -2, -1];
    write_frames(&input, &[1, 2, 3]);
    for n in 1..=3 {
        for stem in ["c", "d"] {
            std::fs::rename(
                input.join(format!("{stem}.{n:04}.exr")),
                input.join(format!("{stem}.-{n:04}.exr")),
            )
            .unwrap();
        }
    }
    let template = Path::new(env!("CARGO_MANIFEST_DIR")).join("farm/openjd/defocus-blur.yaml");
    let run = |args: &str| {
        std::process::Command::new(&openjd)
            .current_dir(&*base)
            .arg("run")
            .arg(&template)
            .args([
                "-p",
                &format!("Color={}", input.join("c.####.exr").display()),
            ])
            .args([
                "-p",
                &format!("Depth={}", input.join("d.####.exr").display()),
            ])
            .args([
                "-p",
                &format!("Out={}", output.join("o.####.exr").display()),
            ])
            .args([
                "-p",
                "FirstFrame=-3",
                "-p",
                "LastFrame=-1",
                "-p",
                "ChunkSize=2",
            ])
            .args(["-p", &format!("Args={args}")])
            .args(["-p", &format!("Defocus={}", env!("CARGO_BIN_EXE_defocus"))])
            .output()
            .unwrap()
    };
    let o = run("--method hammon --focus 2.4");
    let log = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{log}");
    for n in frames {
        assert!(
            output.join(format!("o.-{:04}.exr", -n)).is_file(),
            "frame {n}: {log}"
        );
    }
    // A flag value that is shell code reaches defocus as text, and fails there.
    let o = run("--method hammon --focus $(touch${IFS}PWNED2) --fstop `touch${IFS}PWNED3`");
    assert!(
        !o.status.success(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let listed = |dir: &Path| -> Vec<String> {
        std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect()
    };
    for dir in [&*base, input.as_path(), output.as_path()] {
        let names = listed(dir);
        assert!(!names.iter().any(|n| n.starts_with("PWNED")), "{names:?}");
    }
}

#[test]
fn frames_and_keys_beyond_nine_digits_are_refused_naming_the_range() {
    let dir = temp_dir("seq-range");
    write_frames(&dir, &[1]);
    let (c, d, out) = (
        dir.join("c.####.exr"),
        dir.join("d.####.exr"),
        dir.join("o.####.exr"),
    );
    let blur = |more: &[&str]| {
        let mut a = vec!["blur", "--color", s(&c), "--depth", s(&d), "--out", s(&out)];
        a.extend_from_slice(more);
        defocus(&a)
    };
    for (more, flag) in [
        (
            &["--frames=-9223372036854775808-9223372036854775807"][..],
            "--frames",
        ),
        (&["--frames", "1000000000"], "--frames"),
        (
            &[
                "--frames",
                "1",
                "--focus=-9223372036854775808:2,9223372036854775807:3",
            ],
            "--focus",
        ),
        (
            &["--frames", "1", "--fstop", "-1000000000:2,1:4"],
            "--fstop",
        ),
    ] {
        let o = blur(more);
        // Refused (1, or 2 where the flag's own parser refuses it), not run nor a panic.
        assert!(
            matches!(o.status.code(), Some(1 | 2)),
            "{more:?}: {}",
            stderr(&o)
        );
        let err = stderr(&o);
        assert!(
            err.contains(flag) && err.contains("-999999999 to 999999999"),
            "{more:?}: {err}"
        );
    }
    // A file on disk whose number is beyond the range, found without --frames.
    std::fs::copy(dir.join("c.0001.exr"), dir.join("c.12345678901.exr")).unwrap();
    let o = blur(&[]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("c.12345678901.exr") && err.contains("-999999999 to 999999999"),
        "{err}"
    );
    // A padding of more digits than a frame could have.
    let o = defocus(&[
        "blur",
        "--color",
        s(&dir.join("c.%99999999999999999999d.exr")),
        "--depth",
        s(&dir.join("d.####.exr")),
        "--out",
        s(&dir.join("o.####.exr")),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("more than 32 digits"), "{}", stderr(&o));
    assert!(!dir.join("o.0001.exr").exists());
}

#[test]
fn negative_frames_and_keys_are_taken_as_the_docs_write_them() {
    let dir = temp_dir("seq-negative");
    let o = defocus(&[
        "render",
        "--scene",
        "lights",
        "--method",
        "pinhole",
        "--width",
        "16",
        "--height",
        "9",
        "--frames",
        "-5--1",
        "--focus",
        "-2:2,-1:3",
        "--fstop",
        "-5:2,-1:4",
        "--out",
        s(&dir.join("r.####.png")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    for n in 1..=5 {
        assert!(dir.join(format!("r.-{n:04}.png")).is_file(), "frame -{n}");
    }
    write_frames(&dir, &[1, 2]);
    let o = defocus(&[
        "blur",
        "--color",
        s(&dir.join("c.####.exr")),
        "--depth",
        s(&dir.join("d.####.exr")),
        "--out",
        s(&dir.join("o.####.exr")),
        "--frames",
        "-1-2",
        "--focus",
        "-1:2,2:3",
    ]);
    // Frames -1 and 0 have no input: they fail, named; 1 and 2 are written.
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("2 of 4 frames failed"),
        "{}",
        stderr(&o)
    );
    assert!(dir.join("o.0001.exr").is_file() && dir.join("o.0002.exr").is_file());
}

/// A sequence may have ten million frames: it keeps the first failures' errors, not all of
/// them, and counts the rest.
#[test]
fn a_sequence_keeps_the_first_hundred_errors_and_counts_the_rest() {
    let dir = temp_dir("seq-errors");
    let o = defocus(&[
        "blur",
        "--color",
        s(&dir.join("c.####.exr")),
        "--depth",
        s(&dir.join("d.####.exr")),
        "--out",
        s(&dir.join("o.####.exr")),
        "--frames",
        "1-150",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = stderr(&o);
    // Each error as it happens, then the summary of the first hundred and a count.
    assert_eq!(
        err.lines()
            .filter(|l| l.starts_with("error: frame "))
            .count(),
        150
    );
    let last = err.lines().last().unwrap();
    let first_hundred: Vec<String> = (1..=100).map(|n| n.to_string()).collect();
    assert!(
        last.contains("150 of 150 frames failed")
            && last.contains(&format!(
                "frames {}, and 50 more;",
                first_hundred.join(", ")
            )),
        "{last}"
    );
    let done = defocus::jobs::sequence::blur(
        &blur_args(&dir, "1-150"),
        &defocus::jobs::sequence::Events::none(),
    )
    .unwrap();
    assert_eq!(done.failed_count, 150);
    assert_eq!(done.failed.len(), defocus::jobs::sequence::ERRORS_KEPT);
    let frames: Vec<i64> = done.failed.iter().map(|(n, _)| *n).collect();
    assert_eq!(frames, (1..=100).collect::<Vec<i64>>());
}

/// `blur`'s flags for a sequence of `c.####.exr` and `d.####.exr` in `dir` into `o.####.exr`.
fn blur_args(dir: &Path, frames: &str) -> defocus::jobs::blur::BlurArgs {
    use clap::Parser;
    #[derive(Parser)]
    struct Flags {
        #[command(flatten)]
        args: defocus::jobs::blur::BlurArgs,
    }
    Flags::parse_from([
        "blur",
        "--color",
        s(&dir.join("c.####.exr")),
        "--depth",
        s(&dir.join("d.####.exr")),
        "--out",
        s(&dir.join("o.####.exr")),
        "--frames",
        frames,
    ])
    .args
}
