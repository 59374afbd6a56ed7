//! Running the parsed command line: global settings, then each subcommand's job.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use defocus::error::shown;
use defocus::image::io;
use defocus::metrics;

use crate::args::{Cli, Command};
use crate::common::{check_output, IMAGE_EXTENSIONS, MAX_THREADS};
use crate::render::RenderJob;
use crate::report::CompareArgs;

/// Runs the parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    if let Some(g) = cli.memory_budget {
        if !(g.is_finite() && g > 0.0 && g <= 1e6) {
            bail!("invalid --memory-budget {g}: expected a number of GiB greater than 0");
        }
        std::env::set_var("DEFOCUS_MEMORY_BUDGET_GIB", g.to_string());
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
            let job = RenderJob::try_from(args)?;
            job.run(cli.quiet)
        }
        Command::Blur(args) => {
            if crate::sequence::is_blur_sequence(&args)? {
                return crate::sequence::blur(&args, cli.quiet);
            }
            crate::blur::BlurJob::try_from(args.as_ref())?.run()
        }
        Command::Compare(args) => {
            if args.is_report() {
                crate::report::run(&args, cli.quiet)
            } else {
                compare(&args)
            }
        }
        Command::Kernel(args) => crate::kernel::run(&args),
    }
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
