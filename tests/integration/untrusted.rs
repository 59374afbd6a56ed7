//! Tests: untrusted scenes and shared folders (DESIGN.md, "Untrusted input"): a scene reads
//! only regular files of its own folder and no more than it declares; every output is staged
//! under a fresh name and never written through a planted link; names are printed escaped.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use defocus::image::{io, ColorImage};
use defocus::scene::load::{read_scene_file, read_scene_file_with, LoadOptions};
use serde_json::json;

use crate::cli::{defocus, s, stderr, temp_dir, TempFolder};

/// Longest a refused reference may take to be refused (a device read without end, or a FIFO
/// that blocks, takes forever).
const REFUSAL_TIMEOUT: Duration = Duration::from_secs(20);

/// Content of the files outside the scene's folder: must never appear in a message.
const SECRET: &str = "SECRET-LINE-7f3a";

/// Makes a FIFO with the system's `mkfifo`; `false` (with a printed reason) where there is none.
fn mkfifo(path: &Path) -> bool {
    match Command::new("mkfifo").arg(path).status() {
        Ok(s) if s.success() => true,
        other => {
            eprintln!(
                "skipped the FIFO case: mkfifo {} gave {other:?}",
                path.display()
            );
            false
        }
    }
}

fn symlink(target: &Path, link: &Path) {
    std::os::unix::fs::symlink(target, link).unwrap();
}

/// Loads `path` on another thread: the error, or `None` when it loaded; fails the test when
/// loading takes longer than [`REFUSAL_TIMEOUT`] (it blocked or read without end).
fn load_error(path: &Path, options: LoadOptions) -> Option<String> {
    let (tx, rx) = mpsc::channel();
    let p = path.to_path_buf();
    std::thread::spawn(move || {
        let _ = tx.send(
            read_scene_file_with(&p, &options)
                .err()
                .map(|e| e.to_string()),
        );
    });
    rx.recv_timeout(REFUSAL_TIMEOUT)
        .unwrap_or_else(|_| panic!("loading {} blocked or read without end", path.display()))
}

/// One triangle with uvs: the buffer (36 bytes of positions, 24 of uvs).
fn triangle_buffer() -> Vec<u8> {
    let p: [f32; 9] = [0.0, 0.0, -1.0, 1.0, 0.0, -1.0, 0.0, 1.0, -1.0];
    let uv: [f32; 6] = [0.0, 0.0, 1.0, 0.0, 0.0, 1.0];
    p.iter().chain(&uv).flat_map(|v| v.to_le_bytes()).collect()
}

/// A glTF of one triangle whose buffer is at `buffer_uri` and, with `image_uri`, whose material
/// has that base colour image.
fn triangle_gltf(buffer_uri: &str, image_uri: Option<&str>) -> String {
    let mut j = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0.0, 0.0, -1.0], "max": [1.0, 1.0, -1.0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 24},
        ],
        "buffers": [{"byteLength": 60, "uri": buffer_uri}],
    });
    if let Some(uri) = image_uri {
        j["meshes"][0]["primitives"][0]["material"] = json!(0);
        j["materials"] = json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
        j["textures"] = json!([{"source": 0}]);
        j["images"] = json!([{"uri": uri}]);
    }
    serde_json::to_string_pretty(&j).unwrap()
}

const TRIANGLE_OBJ: &str = "v 0 0 -1\nv 1 0 -1\nv 0 1 -1\nvt 0 0\nvt 1 0\nvt 0 1\n";

/// A scene folder `base/scene` with valid files in it (`ok.bin`, `ok.png`, `ok.mtl`), the
/// same files outside it (`base/outside.*`, plus a file of secrets), and links from inside
/// to outside. Returns (base, scene folder).
fn scene_folder(name: &str) -> (TempFolder, PathBuf) {
    let base = temp_dir(name);
    let scene = base.join("scene");
    std::fs::create_dir(&scene).unwrap();
    let png = ColorImage::new(2, 2, [0.5, 0.5, 0.5, 1.0]);
    for dir in [scene.as_path(), &base] {
        let stem = if dir == scene { "ok" } else { "outside" };
        std::fs::write(dir.join(format!("{stem}.bin")), triangle_buffer()).unwrap();
        io::write_color(&dir.join(format!("{stem}.png")), &png).unwrap();
        std::fs::write(dir.join(format!("{stem}.mtl")), "newmtl m\nKd 1 1 1\n").unwrap();
    }
    std::fs::write(base.join("secret.txt"), format!("{SECRET}\n").repeat(40)).unwrap();
    for ext in ["bin", "png", "mtl"] {
        symlink(
            &base.join(format!("outside.{ext}")),
            &scene.join(format!("link.{ext}")),
        );
    }
    symlink(Path::new("/dev/zero"), &scene.join("zero-link.bin"));
    (base, scene)
}

/// The references a hostile scene makes to a file with extension `ext`, each refused without
/// the opt-in: (case, reference as written in the scene).
fn refused_references(base: &Path, ext: &str) -> Vec<(&'static str, String)> {
    vec![
        ("../ escape", format!("../outside.{ext}")),
        (
            "absolute path",
            base.join(format!("outside.{ext}")).display().to_string(),
        ),
        ("link pointing out", format!("link.{ext}")),
        ("/proc/self/environ", "/proc/self/environ".to_string()),
        ("/dev/zero", "/dev/zero".to_string()),
        ("link to /dev/zero", "zero-link.bin".to_string()),
        ("secret file", "../secret.txt".to_string()),
    ]
}

/// Checks that `err` refuses `reference` in `field` as leaving the folder, names `scene`, and
/// shows nothing of the file.
fn assert_leaves(case: &str, err: &str, scene: &Path, field: &str) {
    let name = scene.file_name().unwrap().to_str().unwrap();
    assert!(err.contains(name), "{case}: does not name {name}: {err}");
    assert!(err.contains(field), "{case}: does not name {field}: {err}");
    assert!(
        err.contains("leaves the scene's folder") && err.contains("--allow-external-files"),
        "{case}: {err}"
    );
    assert!(!err.contains(SECRET), "{case}: leaks the file: {err}");
    assert!(!err.contains("bytes"), "{case}: gives a size: {err}");
}

#[test]
fn gltf_uris_leaving_the_scene_folder_are_refused_without_showing_the_file() {
    let (base, scene) = scene_folder("gltf-escape");
    let ok = scene.join("ok.gltf");
    std::fs::write(&ok, triangle_gltf("ok.bin", Some("ok.png"))).unwrap();
    read_scene_file(&ok).expect("the contained scene loads");
    for (case, reference) in refused_references(&base, "bin") {
        let path = scene.join("buffer.gltf");
        std::fs::write(&path, triangle_gltf(&reference, None)).unwrap();
        let err = load_error(&path, LoadOptions::default()).expect("refused");
        assert_leaves(case, &err, &path, "buffers[0].uri");
    }
    for (case, reference) in refused_references(&base, "png") {
        let path = scene.join("image.gltf");
        std::fs::write(&path, triangle_gltf("ok.bin", Some(&reference))).unwrap();
        let err = load_error(&path, LoadOptions::default()).expect("refused");
        assert_leaves(case, &err, &path, "images[0].uri");
    }
    std::fs::remove_dir_all(base).unwrap();
}

#[test]
fn obj_libraries_and_maps_leaving_the_scene_folder_are_refused_without_showing_the_file() {
    let (base, scene) = scene_folder("obj-escape");
    let ok = scene.join("ok.obj");
    std::fs::write(
        &ok,
        format!("mtllib ok.mtl\n{TRIANGLE_OBJ}usemtl m\nf 1/1 2/2 3/3\n"),
    )
    .unwrap();
    read_scene_file(&ok).expect("the contained scene loads");
    for (case, reference) in refused_references(&base, "mtl") {
        let path = scene.join("lib.obj");
        std::fs::write(
            &path,
            format!("mtllib {reference}\n{TRIANGLE_OBJ}f 1 2 3\n"),
        )
        .unwrap();
        let err = load_error(&path, LoadOptions::default()).expect("refused");
        assert_leaves(case, &err, &path, "mtllib");
    }
    for key in ["map_Kd", "map_d", "map_Ke"] {
        for (case, reference) in refused_references(&base, "png") {
            std::fs::write(
                scene.join("maps.mtl"),
                format!("newmtl m\n{key} {reference}\n"),
            )
            .unwrap();
            let path = scene.join("maps.obj");
            std::fs::write(
                &path,
                format!("mtllib maps.mtl\n{TRIANGLE_OBJ}usemtl m\nf 1/1 2/2 3/3\n"),
            )
            .unwrap();
            let err = load_error(&path, LoadOptions::default()).expect("refused");
            assert_leaves(case, &err, &path, &format!("material 'm': {key}"));
        }
    }
    std::fs::remove_dir_all(base).unwrap();
}

#[test]
fn fifos_and_devices_are_refused_as_not_regular_files_without_blocking() {
    let (base, scene) = scene_folder("not-regular");
    let allow = LoadOptions {
        allow_external_files: true,
    };
    let fifo = mkfifo(&scene.join("pipe"));
    // (scene file, its text, options, field): each names a FIFO or a device.
    let mut cases: Vec<(&str, String, LoadOptions, &str)> = vec![
        (
            "zero.gltf",
            triangle_gltf("/dev/zero", None),
            allow,
            "buffers[0].uri",
        ),
        (
            "zero-image.gltf",
            triangle_gltf("ok.bin", Some("/dev/zero")),
            allow,
            "images[0].uri",
        ),
        (
            "zero.obj",
            format!("mtllib /dev/zero\n{TRIANGLE_OBJ}f 1 2 3\n"),
            allow,
            "mtllib",
        ),
        (
            "folder.gltf",
            triangle_gltf(".", None),
            LoadOptions::default(),
            "buffers[0].uri",
        ),
    ];
    if fifo {
        cases.extend([
            (
                "pipe.gltf",
                triangle_gltf("pipe", None),
                LoadOptions::default(),
                "buffers[0].uri",
            ),
            (
                "pipe-image.gltf",
                triangle_gltf("ok.bin", Some("pipe")),
                LoadOptions::default(),
                "images[0].uri",
            ),
            (
                "pipe.obj",
                format!("mtllib pipe\n{TRIANGLE_OBJ}f 1 2 3\n"),
                LoadOptions::default(),
                "mtllib",
            ),
        ]);
    }
    for (name, text, options, field) in cases {
        let path = scene.join(name);
        std::fs::write(&path, text).unwrap();
        let start = Instant::now();
        let err = load_error(&path, options).expect("refused");
        assert!(
            err.contains(name) && err.contains(field) && err.contains("not a regular file"),
            "{name}: {err}"
        );
        assert!(start.elapsed() < Duration::from_secs(5), "{name}: slow");
    }
    if fifo {
        std::fs::write(scene.join("pipe.mtl"), "newmtl m\nmap_Kd pipe\n").unwrap();
        let path = scene.join("pipe-map.obj");
        std::fs::write(
            &path,
            format!("mtllib pipe.mtl\n{TRIANGLE_OBJ}usemtl m\nf 1/1 2/2 3/3\n"),
        )
        .unwrap();
        let err = load_error(&path, LoadOptions::default()).expect("refused");
        assert!(
            err.contains("map_Kd") && err.contains("not a regular file"),
            "{err}"
        );
        // The scene file itself may not be a FIFO either.
        let scene_fifo = scene.join("fifo.gltf");
        if mkfifo(&scene_fifo) {
            let err = load_error(&scene_fifo, LoadOptions::default()).expect("refused");
            assert!(err.contains("not a regular file"), "{err}");
        }
    }
    std::fs::remove_dir_all(base).unwrap();
}

#[test]
fn allow_external_files_reads_files_outside_the_scene_folder() {
    let (base, scene) = scene_folder("allow-external");
    let outside_bin = base.join("outside.bin").display().to_string();
    let outside_png = base.join("outside.png").display().to_string();
    let gltf = scene.join("abs.gltf");
    std::fs::write(&gltf, triangle_gltf(&outside_bin, Some(&outside_png))).unwrap();
    let obj = scene.join("abs.obj");
    std::fs::write(
        &obj,
        format!("mtllib ../outside.mtl\n{TRIANGLE_OBJ}usemtl m\nf 1/1 2/2 3/3\n"),
    )
    .unwrap();
    let allow = LoadOptions {
        allow_external_files: true,
    };
    for path in [&gltf, &obj] {
        assert!(read_scene_file(path).is_err(), "{}", path.display());
        let file = read_scene_file_with(path, &allow).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.scene.triangle_count(), 1);
    }
    // The same from the command line, with and without the flag.
    let out = base.join("r.png");
    let args = [
        "render",
        "--scene",
        s(&gltf),
        "--method",
        "pinhole",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        s(&out),
    ];
    let o = defocus(&args);
    assert_eq!(o.status.code(), Some(1));
    assert!(
        stderr(&o).contains("--allow-external-files"),
        "{}",
        stderr(&o)
    );
    assert!(!out.exists());
    let o = defocus(&[&args[..], &["--allow-external-files"][..]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.is_file());
    std::fs::remove_dir_all(base).unwrap();
}

#[test]
fn a_buffer_file_is_read_only_up_to_its_declared_length() {
    let (base, scene) = scene_folder("byte-length");
    // A buffer file followed by much more: only byteLength bytes are the buffer's.
    let mut long = triangle_buffer();
    long.extend(std::iter::repeat_n(7u8, 1 << 20));
    std::fs::write(scene.join("long.bin"), long).unwrap();
    let path = scene.join("long.gltf");
    std::fs::write(&path, triangle_gltf("long.bin", None)).unwrap();
    assert_eq!(read_scene_file(&path).unwrap().scene.triangle_count(), 1);
    // A short one is an error naming the buffer and both lengths (the scene may read it).
    std::fs::write(scene.join("short.bin"), &triangle_buffer()[..20]).unwrap();
    let path = scene.join("short.gltf");
    std::fs::write(&path, triangle_gltf("short.bin", None)).unwrap();
    let err = read_scene_file(&path).unwrap_err().to_string();
    assert!(err.contains("buffer 0") && err.contains("60"), "{err}");
    std::fs::remove_dir_all(base).unwrap();
}

// ---------------------------------------------------------------------------------------------
// Outputs
// ---------------------------------------------------------------------------------------------

/// Files in `dir`, sorted.
fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn links_planted_in_a_report_folder_are_not_written_through() {
    let base = temp_dir("planted");
    let dir = base.join("report");
    std::fs::create_dir(&dir).unwrap();
    let victim = base.join("victim");
    std::fs::write(&victim, "precious").unwrap();
    // The old fixed staging names, and the targets themselves.
    for name in [
        "index.tmp-write",
        "results.tmp-write",
        "index.html",
        "results.json",
        "reference.png",
        "pinhole.exr",
    ] {
        symlink(&victim, &dir.join(name));
    }
    let o = defocus(&[
        "compare",
        "--scene",
        "railing",
        "--methods",
        "pinhole",
        "--width",
        "32",
        "--height",
        "18",
        "--reference-samples",
        "2",
        "--out",
        s(&dir),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
    for name in ["index.html", "results.json", "reference.png", "pinhole.exr"] {
        let meta = std::fs::symlink_metadata(dir.join(name)).unwrap();
        assert!(meta.is_file(), "{name} is still a link");
    }
    assert!(std::fs::read_to_string(dir.join("index.html"))
        .unwrap()
        .contains("<html"));
    // No staged file is left behind.
    assert!(
        !files_in(&dir).iter().any(|f| f.starts_with(".defocus-")),
        "{:?}",
        files_in(&dir)
    );
    std::fs::remove_dir_all(base).unwrap();
}

#[test]
fn an_output_name_of_250_bytes_is_written() {
    let dir = temp_dir("long-name");
    let name = format!("{}.png", "n".repeat(246));
    assert_eq!(name.len(), 250);
    let out = dir.join(&name);
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
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(files_in(&dir), vec![name]);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn an_output_that_is_a_fifo_a_device_link_or_a_folder_is_refused_naming_it() {
    let dir = temp_dir("device-out");
    let pipe = dir.join("pipe.png");
    let null_link = dir.join("null.png");
    symlink(Path::new("/dev/null"), &null_link);
    let folder = dir.join("folder.png");
    std::fs::create_dir(&folder).unwrap();
    let mut targets = vec![
        (null_link.clone(), "not a regular file"),
        (folder, "folder"),
    ];
    if mkfifo(&pipe) {
        targets.push((pipe.clone(), "not a regular file"));
    }
    for (target, needle) in &targets {
        let o = defocus(&[
            "render",
            "--method",
            "pinhole",
            "--width",
            "8",
            "--height",
            "8",
            "--out",
            s(target),
        ]);
        assert_eq!(o.status.code(), Some(1), "{}", target.display());
        let e = stderr(&o);
        let name = target.file_name().unwrap().to_str().unwrap();
        assert!(e.contains(name) && e.contains(needle), "{e}");
    }
    // The library refuses them too, and leaves them as they were.
    let img = ColorImage::new(2, 2, [0.5; 4]);
    for (target, _) in &targets {
        let err = io::write_color(target, &img).unwrap_err().to_string();
        assert!(
            err.contains(target.file_name().unwrap().to_str().unwrap()),
            "{err}"
        );
    }
    assert!(std::fs::symlink_metadata(&null_link)
        .unwrap()
        .file_type()
        .is_symlink());
    assert!(!files_in(&dir).iter().any(|f| f.starts_with(".defocus-")));
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn write_errors_name_the_target_not_the_staged_file() {
    let dir = temp_dir("names-target");
    let target = dir.join("no-such-folder").join("out.png");
    let err = io::write_color(&target, &ColorImage::new(2, 2, [0.5; 4]))
        .unwrap_err()
        .to_string();
    assert!(err.contains("no-such-folder/out.png"), "{err}");
    assert!(!err.contains(".defocus-"), "{err}");
    std::fs::remove_dir_all(dir).unwrap();
}

// ---------------------------------------------------------------------------------------------
// Messages
// ---------------------------------------------------------------------------------------------

#[test]
fn control_characters_in_file_names_and_uris_are_escaped_in_errors() {
    let dir = temp_dir("control-names");
    // A newline that would forge a second error line, and an escape sequence that recolours.
    let path = dir.join("evil\nerror: forged\x1b[31m.obj");
    std::fs::write(&path, "v 0 0 0\nv 1 0 0\nf 1 2\n").unwrap();
    let o = defocus(&[
        "render",
        "--scene",
        s(&path),
        "--out",
        s(&dir.join("o.png")),
    ]);
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(e.contains("evil\\nerror: forged\\x1b[31m.obj"), "{e}");
    assert!(!e.contains('\x1b'), "{e:?}");
    assert!(!e.lines().any(|l| l.starts_with("error: forged")), "{e}");
    // A URI from inside a scene file, in the library's own message.
    let gltf = dir.join("uri.gltf");
    std::fs::write(&gltf, triangle_gltf("a\u{1b}]0;pwned\u{7}\nb.bin", None)).unwrap();
    let err = read_scene_file(&gltf).unwrap_err().to_string();
    assert!(err.contains("a\\x1b]0;pwned\\x07\\nb.bin"), "{err}");
    assert!(!err.chars().any(|c| c.is_control()), "{err:?}");
    std::fs::remove_dir_all(dir).unwrap();
}

// ---------------------------------------------------------------------------------------------
// Interrupts
// ---------------------------------------------------------------------------------------------

/// Interrupts per signal, spread over the second half of a run and a little after, where the
/// outputs are written and committed: 120 such interrupts of today's main left one new output
/// beside an old one twice (and staged files twice).
const INTERRUPTS: usize = 45;

#[test]
fn an_interrupt_leaves_both_outputs_old_or_both_new_and_no_staged_file() {
    let dir = temp_dir("interrupt");
    let (out, depth) = (dir.join("r.exr"), dir.join("z.exr"));
    let old = |dir: &Path| {
        io::write_color(&dir.join("r.exr"), &ColorImage::new(4, 4, [0.5; 4])).unwrap();
        io::write_depth_exr(
            &dir.join("z.exr"),
            &defocus::image::GrayImage::new(4, 4, 2.0),
        )
        .unwrap();
    };
    let size = "512";
    let args = [
        "render",
        "--method",
        "pinhole",
        "--width",
        size,
        "--height",
        size,
        "--out",
        s(&out),
        "--depth-out",
        s(&depth),
        "--quiet",
    ];
    let start = Instant::now();
    let o = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let run = start.elapsed();
    let mut outcomes = [0usize; 2];
    for i in 0..2 * INTERRUPTS {
        old(&dir);
        let signal = if i % 2 == 0 { "-TERM" } else { "-INT" };
        let mut child = Command::new(env!("CARGO_BIN_EXE_defocus"))
            .args(args)
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(run.mul_f64(0.5 + 0.7 * (i / 2) as f64 / INTERRUPTS as f64));
        let killed = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status();
        if !matches!(killed, Ok(s) if s.success()) {
            // The run had already ended: nothing was interrupted.
            let _ = child.wait();
        }
        let _ = child.wait().unwrap();
        let width_r = io::read_color(&out).unwrap().width();
        let width_z = io::read_depth(&depth, &Default::default()).unwrap().width();
        assert_eq!(
            width_r, width_z,
            "interrupt {i}: one output old, the other new"
        );
        outcomes[usize::from(width_r == 512)] += 1;
        let left: Vec<String> = files_in(&dir)
            .into_iter()
            .filter(|f| f.starts_with(".defocus-"))
            .collect();
        assert!(left.is_empty(), "interrupt {i} left {left:?}");
    }
    eprintln!(
        "interrupted runs: {} kept the old outputs, {} wrote new ones",
        outcomes[0], outcomes[1]
    );
    assert!(outcomes[0] > 0, "no run was interrupted before its commit");
    std::fs::remove_dir_all(dir).unwrap();
}

/// A report run twice into one folder: the second replaces the first's images and leaves no
/// image of the first; files of the user's own in the folder, and files a planted
/// `results.json` names outside it, are left alone.
#[test]
fn a_second_report_into_one_folder_replaces_the_first_without_mixing() {
    let dir = temp_dir("report-twice");
    let out = dir.join("report");
    let compare = |methods: &str| {
        let o = defocus(&[
            "compare",
            "--scene",
            "lights",
            "--methods",
            methods,
            "--width",
            "48",
            "--height",
            "32",
            "--reference-samples",
            "8",
            "--out",
            s(&out),
        ]);
        assert!(o.status.success(), "{methods}: {}", stderr(&o));
    };
    compare("hammon,gaussian");
    assert!(out.join("hammon.png").exists() && out.join("gaussian.exr").exists());
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let victim = dir.join("victim.png");
    std::fs::write(&victim, "keep").unwrap();
    // A results.json that names a file outside the folder, and the folder's own notes.
    let planted = std::fs::read_to_string(out.join("results.json"))
        .unwrap()
        .replace("\"hammon.png\"", "\"../victim.png\"")
        .replace("\"gaussian.png\"", "\"notes.txt\"");
    std::fs::write(out.join("results.json"), planted).unwrap();
    compare("poisson");
    let files = files_in(&out);
    for gone in [
        "gaussian.exr",
        "gaussian-error.png",
        "hammon.exr",
        "hammon-error.png",
    ] {
        assert!(
            !files.iter().any(|f| f == gone),
            "{gone} is left: {files:?}"
        );
    }
    for kept in [
        "poisson.png",
        "poisson.exr",
        "reference.png",
        "index.html",
        "notes.txt",
    ] {
        assert!(
            files.iter().any(|f| f == kept),
            "{kept} is missing: {files:?}"
        );
    }
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep");
    let index = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(index.contains("poisson") && !index.contains("gaussian.png"));
    let staged: Vec<String> = files
        .into_iter()
        .filter(|f| f.starts_with(".defocus-"))
        .collect();
    assert!(staged.is_empty(), "{staged:?}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// An interrupted report leaves the report that was there, whole, and no staged file.
#[test]
fn an_interrupted_report_leaves_the_old_report_and_no_staged_file() {
    let dir = temp_dir("report-interrupt");
    let out = dir.join("report");
    let args = |methods: &'static str| {
        [
            "compare",
            "--scene",
            "railing",
            "--methods",
            methods,
            "--width",
            "320",
            "--height",
            "180",
            "--reference-samples",
            "64",
            "--quiet",
            "--out",
            s(&out),
        ]
        .map(String::from)
    };
    let o = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(args("hammon"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let start = Instant::now();
    let o = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(args("hammon,lowrank,gaussian"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    let run = start.elapsed();
    // Back to the first report, then interrupt the bigger one at points through its run.
    let mut kept = 0;
    for i in 0..6 {
        let o = Command::new(env!("CARGO_BIN_EXE_defocus"))
            .args(args("hammon"))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        let mut child = Command::new(env!("CARGO_BIN_EXE_defocus"))
            .args(args("hammon,lowrank,gaussian"))
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(run.mul_f64(0.15 + 0.15 * i as f64));
        let signal = if i % 2 == 0 { "-TERM" } else { "-INT" };
        let _ = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status();
        let _ = child.wait().unwrap();
        let files = files_in(&out);
        let staged: Vec<&String> = files
            .iter()
            .filter(|f| f.starts_with(".defocus-"))
            .collect();
        assert!(staged.is_empty(), "interrupt {i} left {staged:?}");
        let index = std::fs::read_to_string(out.join("index.html")).unwrap();
        if !index.contains("lowrank") {
            // The old report, whole: none of the new run's images.
            kept += 1;
            assert!(
                !files
                    .iter()
                    .any(|f| f.starts_with("lowrank") || f.starts_with("gaussian")),
                "interrupt {i}: the old report with new images {files:?}"
            );
        } else {
            for f in ["lowrank.png", "gaussian.png", "hammon.png"] {
                assert!(files.iter().any(|g| g == f), "interrupt {i}: {f} missing");
            }
        }
    }
    assert!(kept > 0, "no run was interrupted before its commit");
    std::fs::remove_dir_all(dir).unwrap();
}

/// A report that cannot be written in full (the disk fills: here a file-size limit makes
/// writes fail past 32 KiB) fails naming a file, leaves the report that was there, and no
/// staged file.
#[test]
fn a_report_on_a_full_disk_fails_and_leaves_the_old_report() {
    if Command::new("sh")
        .arg("-c")
        .arg("ulimit -f 1")
        .status()
        .map(|s| !s.success())
        .unwrap_or(true)
    {
        eprintln!("skipped: no sh with ulimit -f here");
        return;
    }
    let dir = temp_dir("report-full");
    let out = dir.join("report");
    let compare = |limit: Option<&str>| {
        let cmd = format!(
            "trap '' XFSZ; {} exec \"$0\" compare --scene lights --methods hammon,gaussian \
             --width 160 --height 90 --reference-samples 8 --quiet --out \"$1\"",
            limit.map(|k| format!("ulimit -f {k};")).unwrap_or_default()
        );
        Command::new("sh")
            .arg("-c")
            .arg(cmd)
            .arg(env!("CARGO_BIN_EXE_defocus"))
            .arg(&out)
            .output()
            .unwrap()
    };
    let o = compare(None);
    assert!(o.status.success(), "{}", stderr(&o));
    let before: Vec<(String, Vec<u8>)> = files_in(&out)
        .into_iter()
        .map(|f| {
            let bytes = std::fs::read(out.join(&f)).unwrap();
            (f, bytes)
        })
        .collect();
    // 512-byte blocks: 32 KiB, less than the report's EXR images (160x90x16 bytes).
    let o = compare(Some("64"));
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("report/reference.exr") && !e.contains(".defocus-"),
        "{e}"
    );
    let after: Vec<(String, Vec<u8>)> = files_in(&out)
        .into_iter()
        .map(|f| {
            let bytes = std::fs::read(out.join(&f)).unwrap();
            (f, bytes)
        })
        .collect();
    assert_eq!(
        before.iter().map(|f| &f.0).collect::<Vec<_>>(),
        after.iter().map(|f| &f.0).collect::<Vec<_>>(),
        "the folder's files changed"
    );
    assert!(before == after, "a file of the old report changed");
    std::fs::remove_dir_all(dir).unwrap();
}

// ---------------------------------------------------------------------------------------------
// Images named on the command line
// ---------------------------------------------------------------------------------------------

/// A 32x24 frame (colour, depth) and its truth, written into `dir` as `c.exr`, `z.exr` and
/// `truth.exr`.
fn small_frame(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (c, z, t) = (dir.join("c.exr"), dir.join("z.exr"), dir.join("truth.exr"));
    let color = ColorImage::from_vec(
        32,
        24,
        (0..32 * 24)
            .map(|i| {
                let v = if (i % 32 / 4 + i / 32 / 4) % 2 == 0 {
                    0.8
                } else {
                    0.1
                };
                [v, v, v, 1.0]
            })
            .collect(),
    )
    .unwrap();
    io::write_color(&c, &color).unwrap();
    io::write_depth_exr(&z, &defocus::image::GrayImage::new(32, 24, 3.0)).unwrap();
    io::write_color(&t, &color).unwrap();
    (c, z, t)
}

/// Runs defocus with `args` (without `--quiet`), failing the test when it takes longer than
/// [`REFUSAL_TIMEOUT`] (it waits on a FIFO); its exit code and standard error.
fn run_within_timeout(args: &[&str]) -> (Option<i32>, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut e = String::new();
            std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut e).unwrap();
            return (status.code(), e);
        }
        if start.elapsed() > REFUSAL_TIMEOUT {
            let _ = child.kill();
            panic!("{args:?} blocked");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A FIFO given where an image is read (each flag, `compare A B`, a frame of a sequence, and
/// the library's reader, which Python calls) is refused at once, naming it and the flag, not
/// waited on for ever.
#[test]
fn a_fifo_given_as_an_image_is_refused_without_blocking() {
    let base = temp_dir("fifo-images");
    let frame = small_frame(&base);
    let fifo = base.join("pipe.exr");
    if !mkfifo(&fifo) {
        return;
    }
    let (c, z, t) = (s(&frame.0), s(&frame.1), s(&frame.2));
    let p = s(&fifo);
    let out = base.join("o.exr");
    let o = s(&out);
    let image = format!("image:{p}");
    let r = base.join("R");
    let rr = s(&r);
    // Sequence frames 1 and 3 are files, frame 2 a FIFO.
    std::fs::copy(&frame.0, base.join("f.0001.exr")).unwrap();
    std::fs::copy(&frame.0, base.join("f.0003.exr")).unwrap();
    assert!(mkfifo(&base.join("f.0002.exr")));
    let seq = base.join("f.####.exr");
    let seq_out = base.join("g.####.exr");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["blur", "--color", p, "--depth", z, "--out", o],
            "--color",
        ),
        (
            vec!["blur", "--color", c, "--depth", p, "--out", o],
            "--depth",
        ),
        (
            vec![
                "blur",
                "--color",
                c,
                "--depth",
                z,
                "--aperture",
                &image,
                "--out",
                o,
            ],
            "--aperture",
        ),
        (
            vec![
                "compare",
                "--color",
                c,
                "--depth",
                z,
                "--truth",
                p,
                "--methods",
                "hammon",
                "--out",
                rr,
            ],
            "--truth",
        ),
        (
            vec![
                "compare",
                "--color",
                p,
                "--depth",
                z,
                "--truth",
                t,
                "--methods",
                "hammon",
                "--out",
                rr,
            ],
            "--color",
        ),
        (vec!["compare", c, p], "pipe.exr"),
        (vec!["compare", p, c], "pipe.exr"),
        (
            vec!["kernel", "--filter", p, "--filter-out", o, "--size", "9"],
            "--filter",
        ),
        (
            vec![
                "blur",
                "--color",
                s(&seq),
                "--depth",
                z,
                "--frames",
                "1-3",
                "--out",
                s(&seq_out),
            ],
            "f.0002.exr",
        ),
    ];
    for (args, flag) in &cases {
        let (code, e) = run_within_timeout(args);
        assert_eq!(code, Some(1), "{args:?}: {e}");
        assert!(
            e.contains(flag) && e.contains("FIFO") && !e.contains("panicked"),
            "{args:?}: {e}"
        );
        assert!(!out.exists(), "{args:?}");
    }
    // The sequence's other frames are written.
    assert!(base.join("g.0001.exr").is_file() && base.join("g.0003.exr").is_file());
    // The library's readers, which the Python package calls.
    let (tx, rx) = mpsc::channel();
    let f = fifo.clone();
    std::thread::spawn(move || {
        let _ = tx.send((
            io::read_color(&f).err().map(|e| e.to_string()),
            io::image_size(&f).err().map(|e| e.to_string()),
        ));
    });
    let (color, size) = rx
        .recv_timeout(REFUSAL_TIMEOUT)
        .expect("read_color blocked");
    for e in [color, size] {
        let e = e.expect("refused");
        assert!(e.contains("pipe.exr") && e.contains("FIFO"), "{e}");
    }
}

// ---------------------------------------------------------------------------------------------
// Report folders shared with inputs, other files and other reports
// ---------------------------------------------------------------------------------------------

/// `compare` on the small frame into `out` with `methods`; `replace` gives other values to
/// some of `--color`, `--depth` and `--truth`, or more flags.
fn frame_report(
    frame: &(PathBuf, PathBuf, PathBuf),
    out: &Path,
    methods: &str,
    replace: &[&str],
) -> std::process::Output {
    let mut args = vec!["compare", "--methods", methods, "--out", s(out)];
    for (flag, path) in [
        ("--color", &frame.0),
        ("--depth", &frame.1),
        ("--truth", &frame.2),
    ] {
        if !replace.contains(&flag) {
            args.extend([flag, s(path)]);
        }
    }
    args.extend_from_slice(replace);
    defocus(&args)
}

/// An input that lies in the report folder under a name the report writes (its truth as
/// `reference.exr`, a colour image as `METHOD.png`, a lens preset as `results.json`, a texture
/// a scene reads) is refused before anything is rendered, naming the flag, the input and the
/// report's file, whatever the spelling; the input is left as it was.
#[test]
fn inputs_under_the_names_a_report_writes_are_refused_before_rendering() {
    let base = temp_dir("report-inputs");
    let frame = small_frame(&base);
    let r = base.join("R");
    std::fs::create_dir(&r).unwrap();
    std::fs::copy(&frame.2, r.join("reference.exr")).unwrap();
    io::write_color(&r.join("hammon.png"), &ColorImage::new(32, 24, [0.5; 4])).unwrap();
    io::write_color(&r.join("reference.png"), &ColorImage::new(9, 9, [1.0; 4])).unwrap();
    std::fs::copy(&frame.0, r.join("hammon-error.png")).unwrap();
    std::fs::write(r.join("results.json"), "{\"description\": \"mine\"}").unwrap();
    let linked = base.join("linked.exr");
    std::fs::copy(&frame.2, &linked).unwrap();
    std::fs::hard_link(&linked, r.join("grid.png")).unwrap();
    std::fs::create_dir(base.join("alias")).unwrap();
    symlink(&r, &base.join("link-to-R"));
    let in_r = |name: &str| s(&r.join(name)).to_string();
    let dotted = s(&base.join("alias/../R/./reference.exr")).to_string();
    let through_link = s(&base.join("link-to-R/reference.exr")).to_string();
    let cases: Vec<(Vec<String>, &str, &str)> = vec![
        (
            vec!["--truth".into(), in_r("reference.exr")],
            "--truth",
            "reference.exr",
        ),
        (vec!["--truth".into(), dotted], "--truth", "reference.exr"),
        (
            vec!["--truth".into(), through_link],
            "--truth",
            "reference.exr",
        ),
        (
            vec!["--color".into(), in_r("hammon.png")],
            "--color",
            "hammon.png",
        ),
        (
            vec!["--depth".into(), in_r("reference.exr")],
            "--depth",
            "reference.exr",
        ),
        (
            vec![
                "--aperture".into(),
                format!("image:{}", in_r("reference.png")),
            ],
            "--aperture",
            "reference.png",
        ),
        (
            vec!["--lens".into(), in_r("results.json")],
            "--lens",
            "results.json",
        ),
        // A hard link to the truth, under the contact sheet's name.
        (
            vec!["--truth".into(), s(&linked).to_string()],
            "--truth",
            "grid.png",
        ),
    ];
    let before: Vec<(String, Vec<u8>)> = files_in(&r)
        .into_iter()
        .filter(|f| !f.starts_with("link"))
        .map(|f| (f.clone(), std::fs::read(r.join(&f)).unwrap()))
        .collect();
    for (more, flag, name) in &cases {
        let more: Vec<&str> = more.iter().map(String::as_str).collect();
        let o = frame_report(&frame, &r, "hammon", &more);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{more:?}: {e}");
        assert!(
            e.contains(flag) && e.contains(name) && e.contains("would replace"),
            "{more:?}: {e}"
        );
        assert!(
            !r.join("index.html").exists(),
            "{more:?}: a report was written"
        );
    }
    for (f, bytes) in &before {
        assert!(
            std::fs::read(r.join(f)).unwrap() == *bytes,
            "{f} was changed"
        );
    }
    // A scene's own files: a texture named as the report names a method's image.
    let scene = base.join("S");
    std::fs::create_dir(&scene).unwrap();
    io::write_color(&scene.join("hammon.png"), &ColorImage::new(2, 2, [0.5; 4])).unwrap();
    std::fs::write(scene.join("m.mtl"), "newmtl m\nmap_Kd hammon.png\n").unwrap();
    std::fs::write(
        scene.join("s.obj"),
        format!("mtllib m.mtl\n{TRIANGLE_OBJ}usemtl m\nf 1/1 2/2 3/3\n"),
    )
    .unwrap();
    let png = std::fs::read(scene.join("hammon.png")).unwrap();
    let o = defocus(&[
        "compare",
        "--scene",
        s(&scene.join("s.obj")),
        "--methods",
        "hammon",
        "--width",
        "32",
        "--height",
        "24",
        "--reference-samples",
        "2",
        "--out",
        s(&scene),
    ]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("--scene") && e.contains("hammon.png"), "{e}");
    assert_eq!(std::fs::read(scene.join("hammon.png")).unwrap(), png);
    assert!(!scene.join("index.html").exists());
}

/// The clean-up of a report removes only images the report before it wrote and recorded, as
/// they were written: never the user's files that a `results.json` it did not write names, nor
/// an image changed since, nor an input of the report.
#[test]
fn a_report_removes_only_the_images_an_earlier_report_recorded_unchanged() {
    let base = temp_dir("report-cleanup");
    let frame = small_frame(&base);
    let r = base.join("R");
    std::fs::create_dir(&r).unwrap();
    // The user's own images, and a results.json from elsewhere that names them.
    io::write_color(&r.join("photo.png"), &ColorImage::new(4, 4, [0.3; 4])).unwrap();
    io::write_color(&r.join("holiday.exr"), &ColorImage::new(4, 4, [0.6; 4])).unwrap();
    std::fs::write(
        r.join("results.json"),
        serde_json::to_string(&json!({
            "reference": {"image_png": "photo.png", "image_exr": "holiday.exr"},
            "runs": [{"image_png": "photo.png", "image_exr": "holiday.exr",
                      "error_map_png": "photo.png"}],
            "files": [{"name": "photo.png", "bytes": 1, "sha256": "00"},
                      {"name": "holiday.exr"}],
        }))
        .unwrap(),
    )
    .unwrap();
    let o = frame_report(&frame, &r, "hammon", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(r.join("photo.png").is_file() && r.join("holiday.exr").is_file());
    // Each image written is recorded with its size and hash.
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(r.join("results.json")).unwrap()).unwrap();
    let recorded: Vec<&str> = results["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["name"].as_str().unwrap())
        .collect();
    for name in [
        "reference.exr",
        "hammon.png",
        "hammon-error.png",
        "grid.png",
    ] {
        assert!(
            recorded.contains(&name),
            "{name} not recorded: {recorded:?}"
        );
    }
    let hammon = results["files"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["name"] == "hammon.exr")
        .unwrap();
    assert_eq!(
        hammon["bytes"].as_u64(),
        Some(std::fs::metadata(r.join("hammon.exr")).unwrap().len())
    );
    assert_eq!(hammon["sha256"].as_str().unwrap().len(), 64);
    // A recorded image changed since is kept; one as written is removed; an input is kept.
    io::write_color(&r.join("hammon.png"), &ColorImage::new(4, 4, [0.9; 4])).unwrap();
    let o = frame_report(
        &frame,
        &r,
        "gaussian",
        &["--color", s(&r.join("hammon.exr"))],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let files = files_in(&r);
    for kept in [
        "photo.png",
        "holiday.exr",
        "hammon.png",
        "hammon.exr",
        "gaussian.png",
    ] {
        assert!(files.iter().any(|f| f == kept), "{kept} is gone: {files:?}");
    }
    assert!(
        !files.iter().any(|f| f == "hammon-error.png"),
        "hammon-error.png is left: {files:?}"
    );
}

/// Every image a report folder's `results.json` names exists, and every image in the folder
/// is one it names (the report is whole).
fn assert_whole_report(dir: &Path) {
    let results: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("results.json")).unwrap()).unwrap();
    let named: Vec<String> = results["files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["name"].as_str().unwrap().to_string())
        .collect();
    let files = files_in(dir);
    for n in &named {
        assert!(
            files.contains(n),
            "results.json names {n}, which is gone: {files:?}"
        );
    }
    for f in files
        .iter()
        .filter(|f| f.ends_with(".png") || f.ends_with(".exr"))
    {
        assert!(named.contains(f), "{f} is not in results.json: {named:?}");
    }
}

/// A report waits while another holds the folder's lock (it says so), and finishes whole once
/// the lock is released.
#[test]
fn a_report_waits_for_the_lock_of_its_folder() {
    use std::io::BufRead;
    let base = temp_dir("report-lock");
    let frame = small_frame(&base);
    let r = base.join("R");
    std::fs::create_dir(&r).unwrap();
    let lock = defocus::output::FolderLock::acquire(&r, || panic!("the folder is free")).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args([
            "compare",
            "--color",
            s(&frame.0),
            "--depth",
            s(&frame.1),
            "--truth",
            s(&frame.2),
            "--methods",
            "hammon",
            "--quiet",
            "--out",
            s(&r),
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let (tx, rx) = mpsc::channel();
    let err = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(err).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let said_waiting = |rx: &mpsc::Receiver<String>| loop {
        match rx.recv_timeout(Duration::from_secs(120)) {
            Ok(line) if line.contains("waiting") => break line,
            Ok(_) => {}
            Err(_) => panic!("the report did not say it waits for the locked folder"),
        }
    };
    let waiting = said_waiting(&rx);
    assert!(waiting.contains(s(&r)), "{waiting}");
    std::thread::sleep(Duration::from_millis(300));
    assert!(child.try_wait().unwrap().is_none(), "it did not wait");
    assert!(!r.join("results.json").exists());
    drop(lock);
    assert!(child.wait().unwrap().success());
    assert_whole_report(&r);
}

/// Reports run at once into one folder, each with other methods, leave one whole report.
#[test]
fn reports_run_at_once_into_one_folder_leave_one_whole_report() {
    let base = temp_dir("report-race");
    let frame = small_frame(&base);
    let r = base.join("R");
    for _ in 0..3 {
        let spawn = |methods: &str| {
            Command::new(env!("CARGO_BIN_EXE_defocus"))
                .args([
                    "compare",
                    "--color",
                    s(&frame.0),
                    "--depth",
                    s(&frame.1),
                    "--truth",
                    s(&frame.2),
                    "--methods",
                    methods,
                    "--quiet",
                    "--out",
                    s(&r),
                ])
                .stderr(std::process::Stdio::null())
                .spawn()
                .unwrap()
        };
        let mut a = spawn("hammon,gaussian");
        let mut b = spawn("poisson");
        assert!(a.wait().unwrap().success() && b.wait().unwrap().success());
        assert_whole_report(&r);
    }
}

// ---------------------------------------------------------------------------------------------
// Names from files in notes, and inputs that are no file
// ---------------------------------------------------------------------------------------------

/// A name that would retitle the terminal, ring its bell and forge a line: as read from a file.
const EVIL_NAME: &str = "x\u{1b}]0;pwned\u{7}\nerror: forged";

/// Its escaped form, as every message must show it.
const EVIL_SHOWN: &str = "x\\x1b]0;pwned\\x07\\nerror: forged";

fn assert_escaped(what: &str, err: &str) {
    assert!(err.contains(EVIL_SHOWN), "{what}: {err}");
    assert!(
        !err.chars().any(|c| c.is_control() && c != '\n'),
        "{what}: {err:?}"
    );
    assert!(
        !err.lines().any(|l| l.starts_with("error: forged")),
        "{what}: {err}"
    );
}

#[test]
fn names_read_from_files_are_escaped_in_notes() {
    let dir = temp_dir("names-in-notes");
    // A glTF orthographic camera's name, in the note that says it is skipped (shown even with
    // --quiet).
    std::fs::write(dir.join("t.bin"), triangle_buffer()).unwrap();
    let mut gltf: serde_json::Value = serde_json::from_str(&triangle_gltf("t.bin", None)).unwrap();
    gltf["scenes"][0]["nodes"] = json!([0, 1]);
    gltf["nodes"] = json!([{"mesh": 0}, {"camera": 0, "name": EVIL_NAME}]);
    gltf["cameras"] = json!([{"type": "orthographic",
        "orthographic": {"xmag": 1.0, "ymag": 1.0, "znear": 0.1, "zfar": 10.0}}]);
    let scene = dir.join("ortho.gltf");
    std::fs::write(&scene, gltf.to_string()).unwrap();
    let o = defocus(&[
        "render",
        "--scene",
        s(&scene),
        "--width",
        "8",
        "--height",
        "6",
        "--out",
        s(&dir.join("o.png")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_escaped("orthographic camera", &stderr(&o));
    // EXR channel names, in --verbose's notes: a colour layer and a depth channel.
    let (w, h) = (8, 6);
    let v = vec![0.5f32; w * h];
    let z = vec![2.0f32; w * h];
    let (r, g, b) = (
        format!("{EVIL_NAME}.R"),
        format!("{EVIL_NAME}.G"),
        format!("{EVIL_NAME}.B"),
    );
    let depth_name = format!("{EVIL_NAME}.Z");
    let exr = dir.join("layers.exr");
    io::write_exr_layers(
        &exr,
        w,
        h,
        &[
            (r.as_str(), &v),
            (g.as_str(), &v),
            (b.as_str(), &v),
            (depth_name.as_str(), &z),
        ],
    )
    .unwrap();
    let o = defocus(&[
        "blur",
        "--color",
        s(&exr),
        "--depth",
        s(&exr),
        "--focus",
        "2",
        "--verbose",
        "--out",
        s(&dir.join("b.exr")),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("channels") && err.contains("channel "),
        "{err}"
    );
    assert_escaped("EXR channel names", &err);
}

#[test]
fn a_lens_path_that_is_no_file_is_named_as_what_it_is() {
    let dir = temp_dir("lens-kinds");
    let folder = dir.join("lens.json");
    std::fs::create_dir(&folder).unwrap();
    let dangling = dir.join("dangling.json");
    symlink(&dir.join("gone.json"), &dangling);
    let fifo = dir.join("fifo.json");
    let mut cases = vec![
        (folder, "a folder"),
        (PathBuf::from("/dev/null"), "a device"),
        (dangling, "a link to nothing"),
    ];
    if mkfifo(&fifo) {
        cases.push((fifo, "a FIFO"));
    }
    for (path, kind) in cases {
        let (code, err) = run_within_timeout(&[
            "render",
            "--width",
            "8",
            "--height",
            "6",
            "--lens",
            s(&path),
            "--out",
            s(&dir.join("o.png")),
        ]);
        assert_eq!(code, Some(1), "{kind}: {err}");
        assert!(
            err.contains("--lens") && err.contains(s(&path)) && err.contains(kind),
            "{kind}: {err}"
        );
        assert!(!err.contains("unknown lens preset"), "{kind}: {err}");
    }
    // A name that is nothing on disk is still an unknown preset, with the presets listed.
    let (code, err) = run_within_timeout(&[
        "render",
        "--lens",
        "no-such-lens",
        "--out",
        s(&dir.join("o.png")),
    ]);
    assert_eq!(code, Some(1));
    assert!(
        err.contains("unknown lens preset") && err.contains("anamorphic-2x"),
        "{err}"
    );
}

#[test]
fn a_refused_report_leaves_no_folder_it_made() {
    let base = temp_dir("report-refused-folder");
    let (c, z, _) = small_frame(&base);
    // A truth of another size is refused once the report has read it, after its folder had
    // to exist for the runs' checks.
    let truth = base.join("small-truth.exr");
    io::write_color(&truth, &ColorImage::new(4, 4, [0.5, 0.5, 0.5, 1.0])).unwrap();
    let out = base.join("new").join("report");
    let o = defocus(&[
        "compare",
        "--color",
        s(&c),
        "--depth",
        s(&z),
        "--truth",
        s(&truth),
        "--methods",
        "hammon",
        "--out",
        s(&out),
    ]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("expected the same size"),
        "{}",
        stderr(&o)
    );
    assert!(!base.join("new").exists(), "{:?}", files_in(&base));
    // A folder that was there before stays, empty as it was.
    std::fs::create_dir(base.join("mine")).unwrap();
    let o = defocus(&[
        "compare",
        "--color",
        s(&c),
        "--depth",
        s(&z),
        "--truth",
        s(&truth),
        "--methods",
        "hammon",
        "--out",
        s(&base.join("mine")),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(base.join("mine").is_dir());
}

#[test]
fn a_coc_map_beyond_any_blur_is_refused_naming_the_file_and_the_value() {
    let dir = temp_dir("coc-huge");
    let (c, _, _) = small_frame(&dir);
    let mut radii = vec![1.0f32; 32 * 24];
    radii[3 * 32 + 5] = 3.4e38;
    let map = dir.join("coc.exr");
    io::write_exr_layers(&map, 32, 24, &[("CoC", &radii)]).unwrap();
    for method in ["hammon", "lowrank", "gaussian", "poisson", "splat"] {
        let o = defocus(&[
            "blur",
            "--color",
            s(&c),
            "--depth",
            s(&map),
            "--depth-kind",
            "coc",
            "--method",
            method,
            "--out",
            s(&dir.join("o.exr")),
        ]);
        assert_eq!(o.status.code(), Some(1), "{method}");
        let err = stderr(&o);
        assert!(
            err.contains(s(&map)) && err.contains("(x 5, y 3) = 3.4e38"),
            "{method}: {err}"
        );
        assert!(!err.contains("NaN"), "{method}: {err}");
    }
}
