//! Tests: the command line's jobs called from the library (`defocus::jobs`), as the Python
//! package calls them: plain values in and out, nothing printed.

use clap::Parser;
use defocus::jobs::blur::{BlurArgs, BlurJob};
use defocus::jobs::render::{RenderArgs, RenderJob};
use defocus::jobs::report::{self, CompareArgs};

use crate::cli::{s, temp_dir};

/// Flags parsed into one of the jobs' argument sets, as the command line parses them.
#[derive(Parser)]
#[command(no_binary_name = true)]
struct Flags<T: clap::Args> {
    #[command(flatten)]
    args: T,
}

fn parse<T: clap::Args>(flags: &[&str]) -> T {
    Flags::<T>::try_parse_from(flags).unwrap().args
}

#[test]
fn report_is_written_by_a_library_call_and_its_numbers_are_on_disk() {
    let dir = temp_dir("jobs-report");
    let out = dir.join("report");
    let args: CompareArgs = parse(&[
        "--scene",
        "glass",
        "--methods",
        "pinhole,hammon",
        "--width",
        "96",
        "--height",
        "54",
        "--reference-samples",
        "16",
        "--out",
        s(&out),
    ]);
    let (mut steps, mut notes) = (Vec::new(), Vec::new());
    let written = report::write(&args, &mut |p| steps.push((p.done, p.total)), &mut |n| {
        notes.push(n)
    })
    .unwrap();
    assert_eq!(written.index_html, out.join("index.html"));
    assert!(written.index_html.is_file());
    assert!(written.failed.is_empty(), "{:?}", written.failed);
    // Progress counts every run to the end: the ground truth's, then the two methods'.
    assert_eq!(steps.first(), Some(&(0, 3)), "{steps:?}");
    assert_eq!(steps.last(), Some(&(3, 3)), "{steps:?}");
    // The values returned are the file written.
    let on_disk: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap()).unwrap();
    assert_eq!(written.results, on_disk);
    let runs = on_disk["runs"].as_array().unwrap();
    assert_eq!(runs.len(), 2);
    assert!(
        runs.iter().all(|r| r["psnr_db"].as_f64().unwrap() > 15.0),
        "{runs:?}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_report_without_input_and_a_bad_blur_are_errors_not_panics() {
    let dir = temp_dir("jobs-errors");
    let args: CompareArgs = parse(&["--out", s(&dir.join("r"))]);
    let e = report::write(&args, &mut |_| {}, &mut |_| {}).unwrap_err();
    assert!(e.to_string().contains("--scene"), "{e}");
    let missing = dir.join("missing.exr");
    let args: BlurArgs = parse(&[
        "--color",
        s(&missing),
        "--depth",
        s(&missing),
        "--out",
        s(&dir.join("o.exr")),
    ]);
    let e = BlurJob::new(&args, &mut |_| {}).err().unwrap();
    assert!(format!("{e:#}").contains("missing.exr"), "{e:#}");
    assert!(!dir.join("o.exr").exists());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn render_job_gives_its_image_and_progress_without_writing_until_executed() {
    let dir = temp_dir("jobs-render");
    let out = dir.join("pinhole.exr");
    let args: RenderArgs = parse(&[
        "--scene",
        "glass",
        "--method",
        "reference",
        "--samples",
        "4",
        "--width",
        "48",
        "--height",
        "27",
        "--out",
        s(&out),
    ]);
    let job = RenderJob::new(args, &mut |_| {}).unwrap();
    assert_eq!(job.views(), 4);
    let mut last = (0, 0);
    let image = job
        .compute(&mut |done, all| last = (done, all))
        .unwrap()
        .image;
    assert_eq!((image.width(), image.height()), (48, 27));
    assert_eq!(last, (4, 4));
    assert!(!out.exists(), "compute writes nothing");
    job.execute(&mut |_, _| {}, &mut |_| {}).unwrap();
    assert!(out.is_file());
    std::fs::remove_dir_all(dir).unwrap();
}
