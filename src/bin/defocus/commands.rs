//! Running the parsed command line: global settings, then each subcommand's job.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use defocus::error::shown;
use defocus::image::io;
use defocus::metrics;

use defocus::jobs::blur::BlurJob;
use defocus::jobs::render::RenderJob;
use defocus::jobs::report::{self, CompareArgs};

use crate::args::{Cli, Command};
use crate::common::{
    check_output, eprint_line, print_note, progress_bar, report_done, IMAGE_EXTENSIONS, MAX_THREADS,
};

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.memory_budget {
        Some(g) => {
            if defocus::budget::gib_to_bytes(g).is_none() {
                bail!(
                    "invalid --memory-budget {g}: expected a number of GiB greater than 0 and at \
                     most {}",
                    defocus::budget::MAX_BUDGET_GIB
                );
            }
            std::env::set_var(defocus::budget::BUDGET_VARIABLE, g.to_string());
        }
        // A bad value in the environment is refused before any work, not at the first check.
        None => {
            defocus::budget::budget_bytes()?;
        }
    }
    if cli.no_fsync {
        defocus::output::set_durable(false);
    }
    if let Some(n) = cli.threads {
        if !(1..=MAX_THREADS).contains(&n) {
            bail!("invalid --threads {n}: expected 1 to {MAX_THREADS}");
        }
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("could not start the thread pool")?;
    }
    match cli.command {
        Command::Render(args) => {
            if crate::sequence::is_render_sequence(&args)? {
                return crate::sequence::render(args, cli.quiet);
            }
            render(args, cli.quiet)
        }
        Command::Blur(args) => {
            if crate::sequence::is_blur_sequence(&args)? {
                return crate::sequence::blur(&args, cli.quiet);
            }
            let job = BlurJob::new(args.as_ref(), &mut print_note)?;
            let format = job.timing_format();
            let done = job.execute()?;
            report_done(format, &done)
        }
        Command::Compare(args) => {
            if args.is_report() {
                write_report(&args, cli.quiet)
            } else {
                compare(&args)
            }
        }
        Command::Kernel(args) => crate::kernel::run(&args),
        Command::Devices(args) => crate::devices::run(&args),
        Command::Bench(args) => bench(&args, cli.quiet),
    }
}

/// `bench`: a progress bar of its runs, the JSON on standard output (and in `--out`).
fn bench(args: &defocus::jobs::bench::BenchArgs, quiet: bool) -> Result<()> {
    if let Some(out) = &args.out {
        check_output(out, "--out", &["json"])?;
    }
    let bar = progress_bar(quiet, 2, "runs");
    let value = defocus::jobs::bench::run(args, &mut |p| {
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
        bar.set_message(p.running.to_string());
    });
    bar.finish_and_clear();
    let text = serde_json::to_string_pretty(&value?)?;
    if let Some(out) = &args.out {
        defocus::output::write_file(out, |w| {
            use std::io::Write as _;
            w.write_all(text.as_bytes())
                .and_then(|()| w.write_all(b"\n"))
                .map_err(|e| defocus::Error::io(out, e))
        })?;
    }
    crate::common::print_output(&text)
}

/// `render`: the job, a progress bar of its views, the timings.
fn render(args: defocus::jobs::render::RenderArgs, quiet: bool) -> Result<()> {
    let job = RenderJob::new(args, &mut print_note)?;
    let format = job.timing_format();
    let bar = progress_bar(quiet, job.views() as u64, "views");
    let done = job.execute(&mut |done, _| bar.set_position(done as u64), &mut |line| {
        bar.suspend(|| print_note(line))
    })?;
    bar.finish_and_clear();
    report_done(format, &done)
}

/// `compare --scene`/`--color`: the report, a progress bar of its runs. The report is written
/// either way; a failed run still makes the command fail, so that a script does not take a
/// report of errors for results.
fn write_report(args: &CompareArgs, quiet: bool) -> Result<()> {
    // At least the reference and one method: the length is set from the first progress.
    let bar = progress_bar(quiet, 2, "methods");
    let written = report::write(
        args,
        &mut |p| {
            bar.set_length(p.total);
            bar.set_position(p.done);
            bar.set_message(p.running.to_string());
        },
        &mut |line| bar.suspend(|| print_note(line)),
    );
    bar.finish_and_clear();
    let written = written?;
    eprint_line(&format!("report: {}", shown(&written.index_html)));
    if !written.failed.is_empty() {
        bail!(
            "{} of {} runs failed: {} (their errors are in the report)",
            written.failed.len(),
            written.runs,
            written.failed.join(", ")
        );
    }
    Ok(())
}

/// `compare A B` with both images given.
struct TwoImages {
    a: PathBuf,
    b: PathBuf,
    diff: Option<PathBuf>,
    json: bool,
}

fn compare(args: &CompareArgs) -> Result<()> {
    let (Some(a_path), Some(b_path)) = (&args.a, &args.b) else {
        bail!("compare needs two images A B, or a report: --scene NAME --out DIR, or --color C --depth D --truth T --out DIR");
    };
    let args = TwoImages {
        a: a_path.clone(),
        b: b_path.clone(),
        diff: args.diff.clone(),
        json: args.json,
    };
    let args = &args;
    if let Some(diff) = &args.diff {
        check_output(diff, "--diff", IMAGE_EXTENSIONS)?;
        io::ensure_not_same_file(&args.a, diff)?;
        io::ensure_not_same_file(&args.b, diff)?;
    }
    // Sizes and the memory budget from the headers, before any pixel is decoded.
    metrics::check_files(&args.a, &args.b)?;
    let a = io::read_color(&args.a)?;
    let b = io::read_color(&args.b)?;
    io::check_finite_color(&args.a, &a)?;
    io::check_finite_color(&args.b, &b)?;
    if !a.same_size(&b) {
        bail!(
            "size mismatch: {} is {}x{} but {} is {}x{}",
            shown(&args.a),
            a.width(),
            a.height(),
            shown(&args.b),
            b.width(),
            b.height()
        );
    }
    let m = metrics::compare(&a, &b)?;
    if let Some(diff) = &args.diff {
        io::write_color(diff, &metrics::error_map(&a, &b)?)?;
    }
    let text = if args.json {
        serde_json::json!({
            "mse": m.mse_linear,
            "psnr": if m.psnr_db.is_finite() { serde_json::json!(m.psnr_db) } else { serde_json::json!("inf") },
            "ssim": m.ssim,
        })
        .to_string()
    } else {
        format!(
            "mse: {:.6e}\npsnr: {}\nssim: {:.6}",
            m.mse_linear,
            if m.psnr_db.is_finite() {
                format!("{:.4}", m.psnr_db)
            } else {
                "inf".to_string()
            },
            m.ssim
        )
    };
    crate::common::print_output(&text)
}
