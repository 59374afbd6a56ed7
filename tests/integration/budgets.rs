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
        e.contains(&format!("budget of {budget:.1} GiB")),
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
/// 12.7 px everywhere (50 mm f/2.8 on 36 mm, focus 1 m, depth 2 m), its 30 million tile-list
/// entries take 0.23 GiB, within a budget of 0.3 GiB, but the frame, the fragments and the
/// blended image bring the run to twice that: it is refused, before the lists are allocated,
/// naming splat and the budget. A smaller frame within the budget runs and stays within it.
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
    let (o, peak) = blur("0.3");
    assert_refused("splat 2048x2048", &o, 0.3, &["splat at 2048x2048"], &[&out]);
    assert_within("refused splat 2048x2048", peak, 0.3);
    // A frame of a sixteenth of the pixels, over the same files, fits: it runs, within the
    // budget.
    flat_frame(&dir, 512, 512, 2.0);
    let (o, peak) = blur("0.3");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_within("splat 512x512", peak, 0.3);
}
