//! Tests: property-based corruption of valid files for every loader (truncation, byte flips,
//! huge counts): the loaders return errors, never panic; and through the command line, a bad
//! input gives exit code 1 with a message naming the file, leaves no output and changes no
//! input. Seeded, so every run tries the same cases.

use std::path::{Path, PathBuf};

use defocus::image::io::{self, DepthRead};
use defocus::image::{ColorImage, GrayImage};
use defocus::scene::load::read_scene_file;
use proptest::prelude::*;
use proptest::strategy::ValueTree;
use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};

use crate::cli::{defocus, s, stderr, temp_dir};

/// Cases per file kind on every run; `DEFOCUS_FUZZ_CASES=N cargo test --release fuzz` runs
/// N instead, for as long a search as wanted.
const CASES: u32 = 48;

/// [`CASES`], or the number `DEFOCUS_FUZZ_CASES` gives.
fn cases() -> u32 {
    std::env::var("DEFOCUS_FUZZ_CASES")
        .ok()
        .and_then(|v| v.trim().parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or(CASES)
}

/// How a valid file is damaged.
#[derive(Clone, Debug)]
enum Damage {
    /// Cut after this fraction of the bytes.
    Truncate(f64),
    /// XOR these (position fraction, mask) pairs into the bytes.
    Flip(Vec<(f64, u8)>),
    /// Overwrite four bytes at this position with a huge little-endian count.
    Huge(f64, u32),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        (0.0f64..1.0).prop_map(Damage::Truncate),
        prop::collection::vec((0.0f64..1.0, 1u8..=255), 1..8).prop_map(Damage::Flip),
        (
            0.0f64..1.0,
            prop_oneof![
                Just(u32::MAX),
                Just(0x7fff_ffff),
                Just(0x0100_0000),
                Just(65536)
            ]
        )
            .prop_map(|(p, v)| Damage::Huge(p, v)),
    ]
}

fn apply(bytes: &[u8], d: &Damage) -> Vec<u8> {
    let at = |f: f64, n: usize| ((f * n as f64) as usize).min(n.saturating_sub(1));
    let mut b = bytes.to_vec();
    match d {
        Damage::Truncate(f) => b.truncate(at(*f, bytes.len())),
        Damage::Flip(flips) => {
            for (f, m) in flips {
                let i = at(*f, b.len());
                b[i] ^= m;
            }
        }
        Damage::Huge(f, v) => {
            let i = at(*f, b.len().saturating_sub(4));
            let end = (i + 4).min(b.len());
            b[i..end].copy_from_slice(&v.to_le_bytes()[..end - i]);
        }
    }
    b
}

fn runner() -> TestRunner {
    TestRunner::new_with_rng(
        Config {
            cases: cases(),
            failure_persistence: None,
            ..Config::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &[7; 32]),
    )
}

/// Corrupts `valid` in many ways, writes each to `path` and calls `load`: it must not panic.
fn fuzz(valid: &[u8], path: &Path, load: impl Fn(&Path) -> bool) {
    runner()
        .run(&damage(), |d| {
            std::fs::write(path, apply(valid, &d)).unwrap();
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| load(path)));
            prop_assert!(outcome.is_ok(), "{d:?} made the loader panic");
            Ok(())
        })
        .unwrap();
}

/// Valid image files of every kind the readers take.
fn valid_images(dir: &Path) -> Vec<PathBuf> {
    let img = ColorImage::from_vec(
        7,
        5,
        (0..35).map(|i| [i as f32 / 35.0, 0.5, 2.0, 1.0]).collect(),
    )
    .unwrap();
    let mut out = Vec::new();
    for (name, opts) in [
        ("none.exr", io::ExrOptions::default()),
        (
            "zip.exr",
            io::ExrOptions {
                compression: io::ExrCompression::Zip,
                half: false,
                placement: None,
            },
        ),
        (
            "piz.exr",
            io::ExrOptions {
                compression: io::ExrCompression::Piz,
                half: true,
                placement: None,
            },
        ),
    ] {
        let p = dir.join(name);
        io::write_color_with(&p, &img, &opts).unwrap();
        out.push(p);
    }
    for name in ["c.png", "c.pfm"] {
        let p = dir.join(name);
        io::write_color(&p, &img).unwrap();
        out.push(p);
    }
    let p = dir.join("c16.png");
    io::write_png16(&p, &img).unwrap();
    out.push(p);
    let d = dir.join("z.exr");
    io::write_depth_exr(&d, &GrayImage::new(7, 5, 2.0)).unwrap();
    out.push(d);
    out
}

#[test]
fn corrupted_images_are_errors_not_panics() {
    let dir = temp_dir("fuzz-images");
    for valid in valid_images(&dir) {
        let bytes = std::fs::read(&valid).unwrap();
        let ext = valid.extension().unwrap().to_str().unwrap().to_string();
        let bad = dir.join(format!("bad.{ext}"));
        fuzz(&bytes, &bad, |p| {
            let a = io::read_color(p).is_ok();
            let b = io::read_depth(p, &DepthRead::default()).is_ok();
            a || b
        });
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn corrupted_scenes_are_errors_not_panics() {
    let dir = temp_dir("fuzz-scenes");
    let g = crate::scene_files::valid_textured();
    let glb = std::fs::read(g.write_glb(&dir, "valid")).unwrap();
    fuzz(&glb, &dir.join("bad.glb"), |p| read_scene_file(p).is_ok());
    let gltf = std::fs::read(g.write_embedded(&dir, "valid")).unwrap();
    fuzz(&gltf, &dir.join("bad.gltf"), |p| read_scene_file(p).is_ok());
    let obj = b"# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";
    fuzz(obj, &dir.join("bad.obj"), |p| read_scene_file(p).is_ok());
    // A material library: the OBJ is sound, its MTL damaged.
    let with_mtl = b"mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nusemtl m\nf 1/1 2/2 3/3\n";
    let obj_path = dir.join("uses.obj");
    std::fs::write(&obj_path, with_mtl).unwrap();
    let mtl = b"newmtl m\nKd 0.8 0.2 0.1\nKe 0 0 0\nd 1\nNs 10\n";
    fuzz(mtl, &dir.join("bad.mtl"), |_| {
        read_scene_file(&obj_path).is_ok()
    });
    std::fs::remove_dir_all(dir).unwrap();
}

/// Through the command line: a damaged input is an error that names it; nothing is written and
/// the input is unchanged.
#[test]
fn corrupted_inputs_fail_cleanly_through_the_command_line() {
    let dir = temp_dir("fuzz-cli");
    let valid = valid_images(&dir);
    let out = dir.join("out.exr");
    let mut runner = runner();
    let mut tried = 0;
    for v in valid.iter().filter(|p| p.extension().unwrap() == "exr") {
        let bytes = std::fs::read(v).unwrap();
        for _ in 0..6 {
            let d = damage().new_tree(&mut runner).unwrap().current();
            let bad = dir.join("bad.exr");
            let damaged = apply(&bytes, &d);
            std::fs::write(&bad, &damaged).unwrap();
            let o = defocus(&[
                "blur",
                "--color",
                s(&bad),
                "--depth",
                s(&valid[6]),
                "--focus",
                "2",
                "--out",
                s(&out),
            ]);
            if !o.status.success() {
                assert_eq!(o.status.code(), Some(1), "{d:?}: {}", stderr(&o));
                assert!(stderr(&o).contains("bad.exr"), "{d:?}: {}", stderr(&o));
                assert!(!out.exists(), "{d:?} left an output");
            } else {
                let _ = std::fs::remove_file(&out);
            }
            assert_eq!(std::fs::read(&bad).unwrap(), damaged, "the input changed");
            tried += 1;
        }
    }
    assert!(tried > 0);
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// Absurd values for numeric flags: exit code 1 and a message naming the flag, quickly.
#[test]
fn absurd_numeric_flags_are_refused_naming_the_flag() {
    let dir = temp_dir("fuzz-flags");
    let out = dir.join("o.png");
    let cases: &[(&[&str], &str)] = &[
        (&["--width", "0"], "width"),
        (&["--width", "99999999"], "width"),
        (&["--samples", "0"], "--samples"),
        (&["--fstop", "-1"], "f-number"),
        (&["--fstop", "nan"], "fstop"),
        (&["--focal-length", "1e30"], "focal"),
        (&["--focus", "-3"], "focus"),
        (&["--method", "lowrank", "--max-coc", "1e9"], "max CoC"),
        (&["--method", "poisson", "--taps", "100000"], "taps"),
        (
            &["--method", "multilayer", "--fragments", "99"],
            "fragments",
        ),
        (&["--method", "multilayer", "--epsilon", "-1"], "epsilon"),
        (&["--method", "multiview", "--layers", "1000"], "layers"),
        (
            &["--method", "multiview", "--layer-spacing", "0"],
            "spacing",
        ),
        (&["--method", "splat", "--merge", "3"], "merge"),
        (&["--method", "splat", "--group", "nan"], "group"),
        // Flags of a method that is not run are checked all the same.
        (&["--method", "hammon", "--max-coc", "nan"], "max CoC"),
        (&["--method", "pinhole", "--epsilon", "-1"], "epsilon"),
        (&["--method", "reference", "--merge", "3"], "merge"),
        (
            &["--method", "hammon", "--filter-steps", "0/0"],
            "filter-steps",
        ),
    ];
    for (args, needle) in cases {
        let mut a = vec!["render", "--out", s(&out)];
        a.extend_from_slice(args);
        let o = defocus(&a);
        assert!(!o.status.success(), "{args:?} was accepted");
        let e = stderr(&o).to_lowercase();
        assert!(e.contains(&needle.to_lowercase()), "{args:?}: {e}");
        assert!(!out.exists());
    }
    std::fs::remove_dir_all(dir).unwrap();
}
