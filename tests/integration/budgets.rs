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
