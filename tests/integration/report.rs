//! Tests: `defocus compare` reports (every method against the reference).

use std::path::Path;
use std::process::Command;

use crate::cli::{defocus, s, stderr, temp_dir};

/// A small report of `poisson` and `splat` on `lights` (96x54, `reference` at 16 samples) into
/// `out`, with these `--sweep`s.
fn small_sweep_report(out: &Path, sweeps: &[&str]) -> std::process::Output {
    let mut a = vec![
        "compare",
        "--scene",
        "lights",
        "--methods",
        "poisson,splat",
        "--width",
        "96",
        "--height",
        "54",
        "--reference-samples",
        "16",
        "--out",
        s(out),
    ];
    for sw in sweeps {
        a.extend(["--sweep", sw]);
    }
    defocus(&a)
}

fn results(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("results.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

#[test]
fn report_numbers_equal_compare_of_the_written_images() {
    let dir = temp_dir("report-numbers");
    let out = dir.join("report");
    // Two methods on railing at 160x90: a few seconds.
    let o = defocus(&[
        "compare",
        "--scene",
        "railing",
        "--methods",
        "lowrank,multilayer",
        "--width",
        "160",
        "--height",
        "90",
        "--reference-samples",
        "64",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = results(&out);
    let runs = r["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    for run in runs {
        assert_eq!(run["status"], "ok", "{run}");
        let exr = out.join(run["image_exr"].as_str().unwrap());
        let o = defocus(&["compare", s(&exr), s(&out.join("reference.exr")), "--json"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let m: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        for (a, b) in [("psnr_db", "psnr"), ("ssim", "ssim"), ("mse", "mse")] {
            let (x, y) = (run[a].as_f64().unwrap(), m[b].as_f64().unwrap());
            assert!((x - y).abs() <= 1e-12 * y.abs().max(1.0), "{a}: {x} vs {y}");
        }
        assert!(out.join(run["image_png"].as_str().unwrap()).is_file());
        assert!(out.join(run["error_map_png"].as_str().unwrap()).is_file());
        assert!(run["total_ms"].as_f64().unwrap() > 0.0);
    }
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains("<svg") && html.contains("id=\"results\""));
    // Self-contained: no address to fetch.
    for fetch in ["src=\"http", "href=\"http", "url(http", "src=\"//"] {
        assert!(!html.contains(fetch), "the page fetches {fetch}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn report_sweeps_settings_and_refuses_a_bad_sweep_value_before_rendering() {
    let dir = temp_dir("report-sweep");
    let out = dir.join("report");
    let run = |sweeps: &[&str]| small_sweep_report(&out, sweeps);
    // Every sweep value is checked before the first render: nothing is written.
    for (sweep, named) in [
        ("taps=0,8", "--sweep taps=0"),
        ("samples=0", "--sweep samples=0"),
        ("samples=nan", "--sweep samples=nan"),
        ("merge=two", "--sweep merge=two"),
    ] {
        let o = run(&["merge=1,2", sweep]);
        assert_eq!(o.status.code(), Some(1), "{sweep}: {}", stderr(&o));
        assert!(stderr(&o).contains(named), "{sweep}: {}", stderr(&o));
        assert!(
            !out.join("index.html").exists(),
            "{sweep}: a report was written"
        );
        assert!(
            !out.join("reference.exr").exists(),
            "{sweep}: the reference was rendered"
        );
    }
    let o = run(&["taps=4,8", "merge=1,2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = results(&out);
    let runs = r["runs"].as_array().unwrap();
    let labels: Vec<&str> = runs.iter().map(|r| r["label"].as_str().unwrap()).collect();
    assert_eq!(
        labels,
        [
            "poisson-taps4",
            "poisson-taps8",
            "splat-merge1",
            "splat-merge2"
        ]
    );
    for run in runs {
        assert_eq!(run["status"], "ok", "{run}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// A sweep value beyond what any run could take, and a sweep key that no run takes, are
/// refused before the reference is rendered, and no folder is left behind.
#[test]
fn sweep_values_out_of_range_and_keys_no_run_takes_are_refused_up_front() {
    let dir = temp_dir("report-sweep-range");
    let out = dir.join("report");
    for (methods, sweep, named) in [
        ("lowrank", "rank=100000", "expected at most 129"),
        ("lowrank", "lowrank.rank=3,200", "--sweep rank=200"),
        (
            "reference",
            "samples=0",
            "no method among --methods (reference) takes 'samples'",
        ),
        ("hammon,reference", "layers=1,4", "takes 'layers'"),
    ] {
        let o = defocus(&[
            "compare",
            "--scene",
            "lights",
            "--methods",
            methods,
            "--width",
            "32",
            "--height",
            "18",
            "--reference-samples",
            "4",
            "--sweep",
            sweep,
            "--out",
            s(&out),
        ]);
        assert_eq!(o.status.code(), Some(1), "{sweep}: {}", stderr(&o));
        let err = stderr(&o);
        assert!(
            err.contains(named) && err.contains("--sweep"),
            "{sweep}: {err}"
        );
        assert!(!out.exists(), "{sweep}: a folder was left");
    }
}

#[test]
fn a_sweep_named_for_one_method_leaves_the_others_at_their_defaults() {
    let dir = temp_dir("report-sweep-scoped");
    let out = dir.join("report");
    let run = |sweep: &str| small_sweep_report(&out, &[sweep]);
    // `samples` is a setting of both; named for splat, poisson runs once at its own.
    let o = run("splat.samples=8,16");
    assert!(o.status.success(), "{}", stderr(&o));
    let r = results(&out);
    let labels: Vec<&str> = r["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["label"].as_str().unwrap())
        .collect();
    assert_eq!(labels, ["poisson", "splat-samples8", "splat-samples16"]);
    std::fs::remove_dir_all(&out).unwrap();
    // A method the key does not belong to, or one the report does not run, is refused before
    // anything is rendered, naming the sweep, the method and what was expected.
    for (sweep, named) in [
        (
            "poisson.merge=2",
            "'merge' is not a setting of method 'poisson' (it is one of: splat)",
        ),
        (
            "nope.samples=4",
            "'samples' is not a setting of method 'nope'",
        ),
        (
            "multiview.layers=4",
            "method 'multiview' is not among --methods (poisson,splat)",
        ),
    ] {
        let o = run(sweep);
        assert_eq!(o.status.code(), Some(1), "{sweep}: {}", stderr(&o));
        assert!(stderr(&o).contains(named), "{sweep}: {}", stderr(&o));
        assert!(stderr(&o).contains(sweep), "{sweep}: {}", stderr(&o));
        assert!(!out.join("reference.exr").exists(), "{sweep}: rendered");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn frame_report_lists_scene_methods_as_not_applicable() {
    let dir = temp_dir("report-frame");
    let (frame, depth, truth) = (dir.join("f.exr"), dir.join("z.exr"), dir.join("t.exr"));
    let common = ["--width", "64", "--height", "36"];
    let mut a = vec![
        "render",
        "--method",
        "pinhole",
        "--samples",
        "4",
        "--out",
        s(&frame),
    ];
    a.extend(["--depth-out", s(&depth)]);
    a.extend(common);
    assert!(defocus(&a).status.success());
    let mut b = vec!["render", "--samples", "16", "--out", s(&truth)];
    b.extend(common);
    assert!(defocus(&b).status.success());
    let out = dir.join("report");
    let o = defocus(&[
        "compare",
        "--color",
        s(&frame),
        "--depth",
        s(&depth),
        "--truth",
        s(&truth),
        "--focus",
        "2.5",
        "--fstop",
        "2",
        "--methods",
        "hammon,multilayer,multiview",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = results(&out);
    let runs = r["runs"].as_array().unwrap();
    assert_eq!(runs[0]["status"], "ok");
    // multilayer runs on the frame's fragment lists; multiview needs the scene's layers.
    assert_eq!(runs[1]["status"], "ok");
    assert_eq!(runs[2]["status"], "not applicable");
    assert!(runs[2]["error"].as_str().unwrap().contains("scene"));
    std::fs::remove_dir_all(dir).unwrap();
}

/// Debian's Chromium, if the machine has it.
fn chromium() -> Option<String> {
    for c in ["/usr/bin/chromium", "/usr/bin/chromium-browser"] {
        if Path::new(c).is_file() {
            return Some(c.to_string());
        }
    }
    None
}

#[test]
fn report_page_loads_every_image_in_a_real_browser() {
    let Some(browser) = chromium() else {
        eprintln!("skipped: no chromium on this machine (.ci/run installs Debian's package)");
        return;
    };
    let dir = temp_dir("report-browser");
    let out = dir.join("report");
    let o = defocus(&[
        "compare",
        "--scene",
        "railing",
        "--methods",
        "hammon,splat,multiview",
        "--width",
        "160",
        "--height",
        "90",
        "--reference-samples",
        "32",
        "--sweep",
        "samples=8,16",
        "--frontier",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let runs = results(&out)["runs"].as_array().unwrap().len();
    let page = format!("file://{}", out.join("index.html").display());
    let profile = dir.join("profile");
    let flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--virtual-time-budget=5000",
    ];
    let dom = Command::new(&browser)
        .args(flags)
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--dump-dom")
        .arg(&page)
        .output()
        .expect("run chromium");
    let dom = String::from_utf8_lossy(&dom.stdout);
    // Every image decoded (naturalWidth > 0), counted by the page itself on load.
    let attr = dom
        .split("data-images-loaded=\"")
        .nth(1)
        .and_then(|t| t.split('"').next())
        .unwrap_or_else(|| panic!("no load mark in the DOM: {}", &dom[..dom.len().min(400)]));
    let (loaded, total) = attr.split_once('/').unwrap();
    assert_eq!(loaded, total, "images loaded: {attr}");
    // reference + legend + image and error map per run.
    assert_eq!(total.parse::<usize>().unwrap(), 2 + 2 * runs);
    assert_eq!(dom.matches("class=\"run\"").count(), runs);
    assert!(dom.contains("<svg"), "the plot is present");
    // The frontier: its table, and its curve's labels in the plot.
    assert!(
        dom.contains("id=\"frontier\""),
        "the frontier table is present"
    );
    for n in [4, 8, 16] {
        assert!(
            dom.contains(&format!("ref {n}")),
            "the curve's point {n} is labelled"
        );
    }
    let shot = dir.join("screenshot.png");
    let o = Command::new(&browser)
        .args(flags)
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg("--window-size=1200,1600")
        .arg(&page)
        .output()
        .expect("run chromium");
    assert!(
        shot.is_file(),
        "screenshot: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("screenshot kept in {}", shot.display());
}

/// `--frontier` runs `reference` at the sample counts below the ground truth's, with another
/// seed, and marks each run on or behind the frontier by the definition: behind when a
/// `reference` run is both at least as fast and at least as good.
#[test]
fn frontier_marks_each_run_on_or_behind_reference_at_fewer_samples() {
    let dir = temp_dir("report-frontier");
    let out = dir.join("report");
    let o = defocus(&[
        "compare",
        "--scene",
        "lights",
        "--methods",
        "hammon,gaussian,multilayer",
        "--width",
        "96",
        "--height",
        "54",
        "--reference-samples",
        "64",
        "--frontier",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r = results(&out);
    let points = r["frontier"].as_array().unwrap();
    let samples: Vec<u64> = points
        .iter()
        .map(|p| p["samples"].as_u64().unwrap())
        .collect();
    assert_eq!(samples, [4, 8, 16, 32], "below the truth's 64");
    for p in points {
        assert_ne!(p["seed"], serde_json::json!(0), "the truth's seed");
        assert!(p["psnr_db"].as_f64().unwrap() > 10.0, "{p}");
    }
    // More samples are closer to the truth.
    let psnr: Vec<f64> = points
        .iter()
        .map(|p| p["psnr_db"].as_f64().unwrap())
        .collect();
    assert!(psnr[3] > psnr[0], "{psnr:?}");
    for run in r["runs"].as_array().unwrap() {
        let (t, q) = (
            run["total_ms"].as_f64().unwrap(),
            run["psnr_db"].as_f64().unwrap(),
        );
        let beaten = points
            .iter()
            .any(|p| p["total_ms"].as_f64().unwrap() <= t && p["psnr_db"].as_f64().unwrap() >= q);
        let verdict = run["frontier"].as_str().unwrap();
        assert_eq!(verdict.starts_with("behind"), beaten, "{run}");
        assert_eq!(verdict == "on", !beaten, "{run}");
    }
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains("id=\"frontier\"") && html.contains("ref 16"));
    // A frame has no scene to render the frontier from.
    let o = defocus(&[
        "compare",
        "--color",
        "c.exr",
        "--depth",
        "z.exr",
        "--truth",
        "t.exr",
        "--frontier",
        "--out",
        s(&out),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--scene"), "{}", stderr(&o));
    std::fs::remove_dir_all(dir).unwrap();
}
