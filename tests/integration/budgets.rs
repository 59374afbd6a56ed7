//! Tests: the memory budget (`--memory-budget`) holds on every path: a run stays within the
//! budget plus 64 MiB or is refused before it allocates, with an error naming what needs the
//! memory and the budget.
//!
//! A refused run's peak is measured too (a successful one reports it with `--timings json`):
//! [`peak_of`] runs `defocus` as the grandchild of a small probe process (this test binary run
//! again, [`peak_probe`]), because a child's peak resident size as `wait4` reports it includes
//! the peak of the process it was spawned from (Linux carries the spawning process's peak
//! across `exec`), and this test binary may be large while other tests run.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Output, Stdio};

use defocus::image::{io, ColorImage, GrayImage};

use crate::cli::{s, stderr, temp_dir};

/// The environment variable that turns [`peak_probe`] into the probe: a folder holding the
/// arguments of the run (`args`, one a line), where the probe writes what it saw.
const PROBE_VAR: &str = "DEFOCUS_TEST_PEAK_PROBE";

const MIB: u64 = 1 << 20;

/// A budget in GiB as bytes.
fn gib(budget: f64) -> u64 {
    (budget * (1u64 << 30) as f64) as u64
}

/// Not a test of its own: with [`PROBE_VAR`] set, runs `defocus` with the arguments of its
/// folder, waits for it with `wait4` and writes its standard output and error, its exit status
/// and its peak resident size in bytes (`stdout`, `stderr`, `status`, `peak`).
#[test]
fn peak_probe() {
    let Some(dir) = std::env::var_os(PROBE_VAR).map(PathBuf::from) else {
        return;
    };
    let args = std::fs::read_to_string(dir.join("args")).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_defocus"))
        .args(args.lines())
        .arg("--quiet")
        .stdout(std::fs::File::create(dir.join("stdout")).unwrap())
        .stderr(std::fs::File::create(dir.join("stderr")).unwrap())
        .spawn()
        .unwrap();
    let (status, peak) = wait_with_peak(child);
    std::fs::write(dir.join("status"), status.to_string()).unwrap();
    std::fs::write(dir.join("peak"), peak.to_string()).unwrap();
}

/// Waits for `child`: its raw wait status and its peak resident size in bytes.
#[cfg(target_os = "linux")]
fn wait_with_peak(child: std::process::Child) -> (i32, u64) {
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: an all-zero `rusage` is a valid value of the plain C struct.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: `status` and `usage` are valid for writes; `pid` is our own child, which
        // nothing else waits for.
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
        if r == pid {
            break;
        }
        assert_eq!(
            std::io::Error::last_os_error().kind(),
            std::io::ErrorKind::Interrupted
        );
    }
    (status, usage.ru_maxrss as u64 * 1024)
}

#[cfg(not(target_os = "linux"))]
fn wait_with_peak(mut child: std::process::Child) -> (i32, u64) {
    use std::os::unix::process::ExitStatusExt;
    (child.wait().unwrap().into_raw(), 0)
}

/// Runs `defocus args --quiet` through the probe, in a fresh folder under `dir`: its output
/// and, on Linux, its peak resident size in bytes (`None` elsewhere, with a note).
fn peak_of(dir: &Path, args: &[&str]) -> (Output, Option<u64>) {
    use std::os::unix::process::ExitStatusExt;
    use std::sync::atomic::{AtomicUsize, Ordering};
    static RUNS: AtomicUsize = AtomicUsize::new(0);
    let probe = dir.join(format!("probe-{}", RUNS.fetch_add(1, Ordering::Relaxed)));
    std::fs::create_dir_all(&probe).unwrap();
    std::fs::write(probe.join("args"), args.join("\n")).unwrap();
    let o = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "budgets::peak_probe",
            "--nocapture",
            "--test-threads",
            "1",
        ])
        .env(PROBE_VAR, &probe)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert!(o.status.success(), "the probe failed: {}", stderr(&o));
    let read = |name: &str| std::fs::read(probe.join(name)).unwrap();
    let text = |name: &str| String::from_utf8(read(name)).unwrap();
    let status: i32 = text("status").parse().unwrap();
    let peak: u64 = text("peak").parse().unwrap();
    let output = Output {
        status: ExitStatus::from_raw(status),
        stdout: read("stdout"),
        stderr: read("stderr"),
    };
    std::fs::remove_dir_all(&probe).unwrap();
    if !cfg!(target_os = "linux") {
        eprintln!("skipped the peak: no wait4 resident size on this system");
    }
    (output, cfg!(target_os = "linux").then_some(peak))
}

/// Asserts that a run under a budget of `budget` GiB stayed within it plus 64 MiB (the
/// program itself), printing the figures.
fn assert_within(what: &str, peak: Option<u64>, budget: f64) {
    let Some(peak) = peak else {
        return;
    };
    let limit = gib(budget) + 64 * MIB;
    eprintln!(
        "{what}: peak {} MiB, budget {budget} GiB + 64 MiB = {} MiB",
        peak / MIB,
        limit / MIB
    );
    assert!(peak <= limit, "{what}: peak {peak} bytes > {limit}");
}

/// Asserts that `o` is a refusal for the memory budget of `budget` GiB that names `names` (the
/// file, the method or what needs the memory), and that `outputs` were not written.
fn assert_refused(what: &str, o: &Output, budget: f64, names: &[&str], outputs: &[&Path]) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(1), "{what}: {e}");
    assert!(
        e.contains(&format!("budget of {budget:.2} GiB")),
        "{what}: the budget is not named: {e}"
    );
    for n in names {
        assert!(e.contains(n), "{what}: '{n}' is not named: {e}");
    }
    assert!(!e.contains("panicked"), "{what}: {e}");
    for p in outputs {
        assert!(!p.exists(), "{what}: {} was written", p.display());
    }
}

/// A `w` x `h` frame of one colour at one depth, written to `dir` as EXR (uncompressed, as
/// `io::write_color` writes): its colour and depth files.
fn flat_frame(dir: &Path, w: usize, h: usize, depth_m: f32) -> (PathBuf, PathBuf) {
    let (c, d) = (dir.join("c.exr"), dir.join("z.exr"));
    io::write_color(&c, &ColorImage::new(w, h, [0.5, 0.4, 0.3, 1.0])).unwrap();
    io::write_depth_exr(&d, &GrayImage::new(w, h, depth_m)).unwrap();
    (c, d)
}

/// `splat` counts everything it allocates, not only its tile lists: at 2048x2048 with a CoC of
/// 12.7 px everywhere (50 mm f/2.8 on 36 mm, focus 1 m, depth 2 m), its frame's estimate (0.34
/// GiB) and its 30 million tile-list entries (0.23 GiB) are each within a budget of 0.4 GiB, but
/// the frame, the fragments, the lists and the blended image together are not (the run took
/// 0.63 GiB): it is refused, before the lists are allocated, naming splat and the budget. A
/// smaller frame runs, within the budget.
#[test]
fn splat_counts_its_frame_fragments_and_lists_against_the_budget() {
    let dir = temp_dir("budget-splat-all");
    let out = dir.join("o.exr");
    let (c, d) = flat_frame(&dir, 2048, 2048, 2.0);
    let blur = |budget: &str| {
        peak_of(
            &dir,
            &[
                "--memory-budget",
                budget,
                "blur",
                "--color",
                s(&c),
                "--depth",
                s(&d),
                "--focus",
                "1",
                "--method",
                "splat",
                "--out",
                s(&out),
            ],
        )
    };
    let (o, peak) = blur("0.4");
    assert_refused("splat 2048x2048", &o, 0.4, &["splat at 2048x2048"], &[&out]);
    assert_within("refused splat 2048x2048", peak, 0.4);
    // A frame of a sixteenth of the pixels, over the same files, fits: it runs, within the
    // budget.
    flat_frame(&dir, 512, 512, 2.0);
    let (o, peak) = blur("0.4");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_within("splat 512x512", peak, 0.4);
}

/// A `w` x `h` PNG of one colour: a small file that decodes to `w * h * 16` bytes and more.
fn flat_png(path: &Path, w: u32, h: u32) {
    image::RgbImage::from_pixel(w, h, image::Rgb([90, 120, 150]))
        .save(path)
        .unwrap();
}

/// `compare A B` counts both images and its scratch (96 bytes a pixel at 2048x2048: 0.38 GiB),
/// from the headers, before either image is decoded: under a budget of 0.3 GiB it is refused,
/// naming both files, where it counted only the scratch (64 bytes a pixel) after decoding
/// and ran.
#[test]
fn compare_counts_both_images_and_is_refused_before_decoding() {
    let dir = temp_dir("budget-compare");
    let (a, b) = (dir.join("a.png"), dir.join("b.png"));
    flat_png(&a, 2048, 2048);
    flat_png(&b, 2048, 2048);
    let (o, peak) = peak_of(&dir, &["--memory-budget", "0.3", "compare", s(&a), s(&b)]);
    assert_refused("compare", &o, 0.3, &["comparing", "a.png", "b.png"], &[]);
    assert_within("refused compare", peak, 0.3);
    // The estimate bounds what a comparison takes: at 512x512 the run's peak is within the
    // process's fixed part and it.
    flat_png(&a, 512, 512);
    flat_png(&b, 512, 512);
    let (o, peak) = peak_of(&dir, &["compare", s(&a), s(&b)]);
    assert!(o.status.success(), "{}", stderr(&o));
    if let Some(peak) = peak {
        let estimate = defocus::metrics::compare_peak_bytes(512, 512);
        assert!(peak <= 64 * MIB + estimate, "{peak} > 64 MiB + {estimate}");
    }
}

/// `blur --tilt-shift` is held to `lowrank`'s estimate (a CoC map in place of the depth), and
/// `kernel --filter` to the filters' and the metrics' peak, both from the image's header: at
/// 2048x2048 under 0.3 GiB both are refused, naming the image, where both ran without any
/// estimate (`kernel --filter --full-2d-out` to 0.44 GiB).
#[test]
fn tilt_shift_and_kernel_filter_are_held_to_estimates() {
    let dir = temp_dir("budget-tilt-kernel");
    let png = dir.join("photo.png");
    flat_png(&png, 2048, 2048);
    let out = dir.join("o.png");
    let (o, peak) = peak_of(
        &dir,
        &[
            "--memory-budget",
            "0.3",
            "blur",
            "--color",
            s(&png),
            "--tilt-shift",
            "--out",
            s(&out),
        ],
    );
    assert_refused("tilt-shift", &o, 0.3, &["lowrank", "photo.png"], &[&out]);
    assert_within("refused tilt-shift", peak, 0.3);
    let full = dir.join("full.png");
    let (o, peak) = peak_of(
        &dir,
        &[
            "--memory-budget",
            "0.3",
            "kernel",
            "--size",
            "9",
            "--filter",
            s(&png),
            "--filter-out",
            s(&out),
            "--full-2d-out",
            s(&full),
        ],
    );
    assert_refused("kernel --filter", &o, 0.3, &["photo.png"], &[&out, &full]);
    assert_within("refused kernel --filter", peak, 0.3);
}

/// Writes a `w` x `h` OpenEXR file of `channels` half-float channels (`Z` = 2 m, and others),
/// ZIP-compressed: a small file whose channels all decode.
fn many_channel_exr(path: &Path, w: usize, h: usize, channels: usize) {
    use exr::prelude::*;
    let list: SmallVec<[AnyChannel<FlatSamples>; 4]> = (0..channels)
        .map(|i| {
            let name = if i == 0 {
                "Z".to_string()
            } else {
                format!("aov{i:02}")
            };
            AnyChannel::new(
                name.as_str(),
                FlatSamples::F16(vec![f16::from_f32(2.0); w * h]),
            )
        })
        .collect();
    let layer = Layer::new(
        (w, h),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(list),
    );
    Image::from_layer(layer).write().to_file(path).unwrap();
}

/// `blur` holds its inputs and its method to the budget from the images' headers, before
/// any pixel is decoded: `--method lowrank` at 2048x2048 under 0.3 GiB is refused with the
/// peak of a run refused at its very first check (it decoded both images first, then refused),
/// and a depth file of 24 half-float channels counts them all, as stored and as floats (it
/// counted 32 bytes a pixel, decoded 0.14 GiB of channels under a budget of 0.14 and ran
/// `hammon`).
#[test]
fn blur_is_refused_from_the_headers_before_decoding() {
    let dir = temp_dir("budget-blur-headers");
    let color = dir.join("c.png");
    let depth = dir.join("z.exr");
    let out = dir.join("o.exr");
    flat_png(&color, 2048, 2048);
    io::write_depth_exr(&depth, &GrayImage::new(2048, 2048, 2.0)).unwrap();
    let blur = |budget: &str, method: &str| {
        peak_of(
            &dir,
            &[
                "--memory-budget",
                budget,
                "blur",
                "--color",
                s(&color),
                "--depth",
                s(&depth),
                "--method",
                method,
                "--out",
                s(&out),
            ],
        )
    };
    // The floor: a budget below any decode is refused at the first check.
    let (o, floor) = blur("0.001", "lowrank");
    assert_refused("blur at 0.001 GiB", &o, 0.001, &["c.png"], &[&out]);
    let (o, peak) = blur("0.3", "lowrank");
    assert_refused("blur lowrank", &o, 0.3, &["lowrank", "c.png"], &[&out]);
    if let (Some(floor), Some(peak)) = (floor, peak) {
        eprintln!(
            "refused lowrank: peak {} MiB, floor {} MiB",
            peak / MIB,
            floor / MIB
        );
        assert!(
            peak <= floor + 16 * MIB,
            "decoded before refusing: peak {peak} bytes, {floor} when refused at once"
        );
    }
    // 24 channels of depth at 1024x1024: 0.18 GiB to decode beside the colour, where hammon
    // alone would fit.
    flat_png(&color, 1024, 1024);
    many_channel_exr(&depth, 1024, 1024, 24);
    let (o, peak) = blur("0.14", "hammon");
    assert_refused("24-channel depth", &o, 0.14, &["z.exr"], &[&out]);
    if let (Some(floor), Some(peak)) = (floor, peak) {
        assert!(
            peak <= floor + 16 * MIB,
            "decoded before refusing: {peak} bytes"
        );
    }
}

/// Asserts that a refused run allocated nothing of note before its refusal: its peak is within
/// 16 MiB of `floor`, the peak of the same command refused at its first check.
fn assert_refused_before_allocating(what: &str, peak: Option<u64>, floor: Option<u64>) {
    if let (Some(peak), Some(floor)) = (peak, floor) {
        eprintln!("{what}: peak {} MiB, floor {} MiB", peak / MIB, floor / MIB);
        assert!(
            peak <= floor + 16 * MIB,
            "{what}: allocated before refusing: peak {peak} bytes, {floor} when refused at once"
        );
    }
}

/// `--focus auto` and `--focus-pixel` render a pinhole view of the whole frame: the run is
/// refused before that render when its method would be (hammon at 2048x2048 under 0.1 GiB), as
/// a run with a set focus is, with no more memory (it rendered an 84 MB G-buffer first).
#[test]
fn autofocus_is_refused_before_it_renders() {
    let dir = temp_dir("budget-autofocus");
    let out = dir.join("o.exr");
    let render = |focus: &[&str]| {
        let mut args = vec![
            "--memory-budget",
            "0.1",
            "render",
            "--scene",
            "railing",
            "--method",
            "hammon",
            "--width",
            "2048",
            "--height",
            "2048",
            "--out",
            s(&out),
        ];
        args.extend_from_slice(focus);
        peak_of(&dir, &args)
    };
    let (o, floor) = render(&["--focus", "2"]);
    assert_refused("set focus", &o, 0.1, &["hammon at 2048x2048"], &[&out]);
    for focus in [&["--focus", "auto"][..], &["--focus-pixel", "100,100"]] {
        let (o, peak) = render(focus);
        let what = focus.join(" ");
        assert_refused(&what, &o, 0.1, &["hammon at 2048x2048"], &[&out]);
        assert_refused_before_allocating(&what, peak, floor);
    }
}

/// A glTF scene of `nodes` instances of one mesh whose buffer is `buffer` (`bytes` long, the
/// positions of `triangles` separate triangles), with `image` as the base colour texture of its
/// material when given (the mesh then has texture coordinates, all 0, after its positions).
fn instanced_gltf(buffer: &str, triangles: usize, nodes: usize, image: Option<&str>) -> String {
    let vertices = 3 * triangles;
    let mut primitive = serde_json::json!({"attributes": {"POSITION": 0}});
    let mut accessors = vec![serde_json::json!({
        "bufferView": 0, "componentType": 5126, "count": vertices, "type": "VEC3",
        "min": [-0.5, -0.5, -2.0], "max": [0.5, 0.5, -1.0],
    })];
    let mut views = vec![serde_json::json!({"buffer": 0, "byteLength": vertices * 12})];
    let mut bytes = vertices * 12;
    let mut gltf = serde_json::json!({});
    if let Some(image) = image {
        primitive["attributes"]["TEXCOORD_0"] = serde_json::json!(1);
        primitive["material"] = serde_json::json!(0);
        accessors.push(serde_json::json!({
            "bufferView": 1, "componentType": 5126, "count": vertices, "type": "VEC2",
        }));
        views.push(serde_json::json!({
            "buffer": 0, "byteOffset": bytes, "byteLength": vertices * 8,
        }));
        bytes += vertices * 8;
        gltf["materials"] =
            serde_json::json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
        gltf["textures"] = serde_json::json!([{"source": 0}]);
        gltf["images"] = serde_json::json!([{"uri": image}]);
    }
    gltf["asset"] = serde_json::json!({"version": "2.0"});
    gltf["scene"] = serde_json::json!(0);
    gltf["scenes"] = serde_json::json!([{"nodes": (0..nodes).collect::<Vec<_>>()}]);
    gltf["nodes"] = serde_json::json!(vec![serde_json::json!({"mesh": 0}); nodes]);
    gltf["meshes"] = serde_json::json!([{"primitives": [primitive]}]);
    gltf["accessors"] = serde_json::json!(accessors);
    gltf["bufferViews"] = serde_json::json!(views);
    gltf["buffers"] = serde_json::json!([{"byteLength": bytes, "uri": buffer}]);
    gltf.to_string()
}

/// The buffer of [`instanced_gltf`]: `triangles` small triangles spread over a square at 1 to
/// 2 m, then (with `uvs`) texture coordinates of 0.
fn triangles_buffer(triangles: usize, uvs: bool) -> Vec<u8> {
    let mut out = Vec::with_capacity(triangles * (36 + if uvs { 24 } else { 0 }));
    let side = (triangles as f32).sqrt().ceil() as usize;
    for t in 0..triangles {
        let (x, y) = ((t % side) as f32, (t / side) as f32);
        let (x, y) = (x / side as f32 - 0.5, y / side as f32 - 0.5);
        let z = -1.0 - t as f32 / triangles as f32;
        let d = 0.5 / side as f32;
        for v in [[x, y, z], [x + d, y, z], [x, y + d, z]] {
            for c in v {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    if uvs {
        out.resize(out.len() + triangles * 24, 0);
    }
    out
}

/// A scene's meshes and decoded textures are counted against the budget as they are made,
/// and the triangles a render makes of them before it renders:
/// - a texture of a few kilobytes that decodes to 4096x4096 is refused from its header (it was
///   decoded, 0.4 GiB, under a budget of 0.1, and the render ran);
/// - 300 instances of a mesh of 10,000 triangles (0.14 GiB of meshes) are refused while they
///   are made, under 0.1 GiB;
/// - 150 of them load under 0.25 GiB, but their camera-space copy and set-up triangles do not
///   fit beside them: the render is refused before it prepares the scene (it ran to 0.6 GiB).
#[test]
fn scene_meshes_and_textures_are_counted_before_they_are_made() {
    let dir = temp_dir("budget-scene");
    let out = dir.join("o.exr");
    std::fs::write(dir.join("small.bin"), triangles_buffer(1, true)).unwrap();
    flat_png(&dir.join("wall.png"), 4096, 4096);
    assert!(std::fs::metadata(dir.join("wall.png")).unwrap().len() < 1 << 20);
    let scene = dir.join("textured.gltf");
    std::fs::write(&scene, instanced_gltf("small.bin", 1, 1, Some("wall.png"))).unwrap();
    let render = |scene: &Path, budget: &str| {
        peak_of(
            &dir,
            &[
                "--memory-budget",
                budget,
                "render",
                "--scene",
                s(scene),
                "--method",
                "pinhole",
                "--width",
                "64",
                "--height",
                "64",
                "--out",
                s(&out),
            ],
        )
    };
    let (o, peak) = render(&scene, "0.1");
    assert_refused(
        "texture",
        &o,
        0.1,
        &["textured.gltf", "wall.png", "4096x4096"],
        &[&out],
    );
    assert_within("refused texture", peak, 0.1);

    std::fs::write(dir.join("mesh.bin"), triangles_buffer(10_000, false)).unwrap();
    let many = dir.join("many.gltf");
    std::fs::write(&many, instanced_gltf("mesh.bin", 10_000, 300, None)).unwrap();
    let (o, peak) = render(&many, "0.1");
    assert_refused(
        "300 instances",
        &o,
        0.1,
        &["many.gltf", "instance"],
        &[&out],
    );
    assert_within("refused 300 instances", peak, 0.1);

    let half = dir.join("half.gltf");
    std::fs::write(&half, instanced_gltf("mesh.bin", 10_000, 150, None)).unwrap();
    let (o, peak) = render(&half, "0.25");
    assert_refused(
        "150 instances",
        &o,
        0.25,
        &["pinhole at 64x64", "1500000 triangles"],
        &[&out],
    );
    assert_within("refused 150 instances", peak, 0.25);
}

/// Files are judged by their size before they are read: a scene file, an MTL library or a
/// glTF buffer (its declared length) beyond the budget, a scene file beyond 4 GiB and a lens
/// preset beyond 1 MiB are refused, naming the file, with no more memory than a run refused at
/// once (they were read whole first: 0.3 GiB, 4 GiB, 0.2 GiB). Sparse files: no disk is used.
#[test]
fn files_are_refused_from_their_size_before_they_are_read() {
    let dir = temp_dir("budget-files");
    let out = dir.join("o.exr");
    let sparse = |name: &str, bytes: u64| {
        let path = dir.join(name);
        std::fs::File::create(&path)
            .unwrap()
            .set_len(bytes)
            .unwrap();
        path
    };
    let render = |budget: &str, extra: &[&str]| {
        let mut args = vec![
            "--memory-budget",
            budget,
            "render",
            "--width",
            "16",
            "--height",
            "16",
            "--out",
            s(&out),
        ];
        args.extend_from_slice(extra);
        peak_of(&dir, &args)
    };
    // The floor: a scene file that is not there.
    let (o, floor) = render("0.1", &["--scene", s(&dir.join("none.gltf"))]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));

    let big = sparse("big.gltf", 300 << 20);
    let (o, peak) = render("0.1", &["--scene", s(&big)]);
    assert_refused("300 MB scene", &o, 0.1, &["big.gltf"], &[&out]);
    assert_refused_before_allocating("300 MB scene", peak, floor);

    let giant = sparse("giant.gltf", 5 << 30);
    let (o, peak) = render("0.1", &["--scene", s(&giant)]);
    let e = stderr(&o);
    assert!(
        e.contains("giant.gltf") && e.contains("larger than 4 GiB"),
        "{e}"
    );
    assert_refused_before_allocating("5 GB scene", peak, floor);

    sparse("huge.mtl", 300 << 20);
    let obj = dir.join("m.obj");
    std::fs::write(
        &obj,
        "mtllib huge.mtl\nv 0 0 -1\nv 1 0 -1\nv 0 1 -1\nf 1 2 3\n",
    )
    .unwrap();
    let (o, peak) = render("0.1", &["--scene", s(&obj)]);
    assert_refused(
        "300 MB MTL",
        &o,
        0.1,
        &["m.obj", "mtllib", "huge.mtl"],
        &[&out],
    );
    assert_refused_before_allocating("300 MB MTL", peak, floor);

    // A buffer whose declared length is 300 MB, in a file as long.
    sparse("data.bin", 300 << 20);
    let scene = dir.join("declared.gltf");
    let mut gltf: serde_json::Value =
        serde_json::from_str(&instanced_gltf("data.bin", 1, 1, None)).unwrap();
    gltf["buffers"][0]["byteLength"] = serde_json::json!(300u64 << 20);
    std::fs::write(&scene, gltf.to_string()).unwrap();
    let (o, peak) = render("0.1", &["--scene", s(&scene)]);
    assert_refused(
        "300 MB buffer",
        &o,
        0.1,
        &["declared.gltf", "buffers[0]", "data.bin"],
        &[&out],
    );
    assert_refused_before_allocating("300 MB buffer", peak, floor);

    // A lens preset: the floor is a run with a preset file that is not one.
    let small = dir.join("small.json");
    std::fs::write(&small, "{}").unwrap();
    let (o, floor) = render("0.1", &["--scene", "railing", "--lens", s(&small)]);
    assert!(stderr(&o).contains("not a lens preset"), "{}", stderr(&o));
    let lens = sparse("lens.json", 200 << 20);
    let (o, peak) = render("0.1", &["--scene", "railing", "--lens", s(&lens)]);
    let e = stderr(&o);
    assert!(e.contains("lens.json") && e.contains("larger than"), "{e}");
    assert!(!out.exists());
    assert_refused_before_allocating("200 MB lens preset", peak, floor);
}

/// A `results.json` in a report's folder that is far larger than any report's is judged by
/// its size: the report does not read it (it read its first 64 MiB) and takes no more memory
/// than with none.
#[test]
fn a_huge_results_json_is_not_read() {
    let dir = temp_dir("budget-results");
    let report = dir.join("report");
    let run = || {
        peak_of(
            &dir,
            &[
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
                s(&report),
            ],
        )
    };
    let (o, floor) = run();
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::File::create(report.join("results.json"))
        .unwrap()
        .set_len(3 << 30)
        .unwrap();
    let (o, peak) = run();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_refused_before_allocating("report beside a 3 GB results.json", peak, floor);
}

/// `--occlusion fill` counts its layers with the method's own estimate: at 1024x1024 a budget
/// that holds `hammon`'s run and the frame's reads with 100 bytes a pixel to spare runs it with
/// `--occlusion none`, and refuses it with `--occlusion fill` (its layers, pyramids and second
/// image need 160 more), before decomposing, naming the option.
#[test]
fn occlusion_fill_counts_its_layers_against_the_budget() {
    let dir = temp_dir("budget-fill");
    let (w, h) = (1024usize, 1024usize);
    // The left half near (0.5 m), so that the decomposition has work to do.
    let (c, _) = flat_frame(&dir, w, h, 2.0);
    let z = dir.join("near.exr");
    io::write_depth_exr(
        &z,
        &GrayImage::from_vec(
            w,
            h,
            (0..w * h)
                .map(|i| if i % w < w / 2 { 0.5 } else { 2.0 })
                .collect(),
        )
        .unwrap(),
    )
    .unwrap();
    let settings = defocus::methods::registry::MethodSettings::default_for("hammon").unwrap();
    let estimate = defocus::methods::registry::peak_bytes(&settings, w, h);
    let budget = (estimate + (w * h) as u64 * 100) as f64 / (1u64 << 30) as f64;
    let budget = format!("{budget:.3}");
    let out = dir.join("o.exr");
    let run = |method: &str, occlusion: &str| {
        crate::cli::defocus(&[
            "--memory-budget",
            &budget,
            "blur",
            "--color",
            s(&c),
            "--depth",
            s(&z),
            "--method",
            method,
            "--occlusion",
            occlusion,
            "--out",
            s(&out),
        ])
    };
    let o = run("hammon", "none");
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::remove_file(&out).unwrap();
    let budget: f64 = budget.parse().unwrap();
    let o = run("hammon", "fill");
    assert_refused(
        "hammon --occlusion fill",
        &o,
        budget,
        &["hammon", "--occlusion fill"],
        &[&out],
    );
}

/// A scene of many triangles that each cover the whole frame (a 200 mm lens on the scene's
/// "frame all" camera): its estimate (the scene, its copy, one view's set-up triangles at one
/// tile-list entry each) is within the budget, but every triangle enters all 240 tiles of a
/// 1280x720 frame, 500,000 triangles 120 million entries (0.45 GiB). Before, the run went past
/// 0.6 GiB under a budget of 0.3; now the view is refused before its lists are allocated,
/// naming the entries. A tenth of them at 64x36 (one tile) runs, within the budget.
#[test]
fn tile_lists_of_large_triangles_are_counted_against_the_budget() {
    let dir = temp_dir("budget-big-triangles");
    let out = dir.join("o.exr");
    let obj = dir.join("big.obj");
    let mut text = String::from("v -3 -3 -5\nv 3 -3 -5\nv 0 3 -5\n");
    text.push_str(&"f 1 2 3\n".repeat(500_000));
    std::fs::write(&obj, text).unwrap();
    let render = |w: &str, h: &str| {
        peak_of(
            &dir,
            &[
                "--memory-budget",
                "0.3",
                "render",
                "--scene",
                s(&obj),
                "--method",
                "pinhole",
                "--focal-length",
                "200",
                "--width",
                w,
                "--height",
                h,
                "--out",
                s(&out),
            ],
        )
    };
    let (o, peak) = render("1280", "720");
    assert_refused(
        "500,000 frame-sized triangles",
        &o,
        0.3,
        &["tile-list entries", "500000 triangles"],
        &[&out],
    );
    assert_within("refused frame-sized triangles", peak, 0.3);
    // A tenth of the triangles at 64x36 (one tile each) runs, within the budget.
    let mut text = String::from("v -3 -3 -5\nv 3 -3 -5\nv 0 3 -5\n");
    text.push_str(&"f 1 2 3\n".repeat(50_000));
    std::fs::write(&obj, text).unwrap();
    let (o, peak) = render("64", "36");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_within("frame-sized triangles at 64x36", peak, 0.3);
}

/// `multilayer` counts the scene it holds beside its lists: a scene with a 2048x2048 texture
/// (0.08 GiB decoded with its mip levels) and the lists and levels of a 1280x720 frame (0.18
/// GiB at four fragments a pixel) are each within a budget of 0.25 GiB, and were each checked
/// alone, so the run went ahead; together they are not, and the run is refused before it
/// collects, naming multilayer. `multiview` counts the scene beside its layers the same way.
#[test]
fn layered_methods_count_the_scene_beside_their_lists() {
    let dir = temp_dir("budget-layered-scene");
    let out = dir.join("o.exr");
    std::fs::write(dir.join("small.bin"), triangles_buffer(1, true)).unwrap();
    flat_png(&dir.join("wall.png"), 2048, 2048);
    let scene = dir.join("textured.gltf");
    std::fs::write(&scene, instanced_gltf("small.bin", 1, 1, Some("wall.png"))).unwrap();
    let render = |method: &str, budget: &str, w: &str, h: &str| {
        peak_of(
            &dir,
            &[
                "--memory-budget",
                budget,
                "render",
                "--scene",
                s(&scene),
                "--method",
                method,
                "--width",
                w,
                "--height",
                h,
                "--out",
                s(&out),
            ],
        )
    };
    let (o, peak) = render("multilayer", "0.25", "1280", "720");
    eprintln!("{}", stderr(&o));
    assert_refused(
        "multilayer beside its scene",
        &o,
        0.25,
        &["multilayer at"],
        &[&out],
    );
    assert_within("refused multilayer beside its scene", peak, 0.25);
    let (o, peak) = render("multilayer", "0.25", "320", "180");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_within("multilayer at 320x180 beside its scene", peak, 0.25);
}
