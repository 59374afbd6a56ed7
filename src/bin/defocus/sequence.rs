//! Image sequences on the command line: the library's sequence jobs
//! (`defocus::jobs::sequence`) with one progress bar of frames, errors printed as frames fail,
//! a summary, `--timings`, and an exit code that says when some frame failed.

use anyhow::{bail, Result};
use defocus::error::shown;
use defocus::jobs::sequence::{self, Events, Finished};
use defocus::timing::Timings;
use indicatif::{ProgressBar, ProgressStyle};

use defocus::jobs::blur::BlurArgs;
use defocus::jobs::render::RenderArgs;

use crate::common::{eprint_line, print_note, resident_peak_bytes, FrameDone, TimingFormat};

pub use defocus::jobs::sequence::{is_blur_sequence, is_render_sequence};

/// `blur` over a sequence.
pub fn blur(a: &BlurArgs, quiet: bool) -> Result<()> {
    let timings = a.timings;
    shown_run("blur", quiet, timings, |events| sequence::blur(a, events))
}

/// `render` over a sequence.
pub fn render(a: RenderArgs, quiet: bool) -> Result<()> {
    let timings = a.timings;
    shown_run("render", quiet, timings, |events| {
        sequence::render(a, events)
    })
}

/// A progress bar of frames, with the rate and the time left (its length is set when the
/// frames to run are known).
fn frames_bar(quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(0);
    let template =
        "{spinner} [{elapsed_precise}] {wide_bar} {pos}/{len} frames ({per_sec}, eta {eta}) {msg}";
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style);
    }
    bar
}

/// Runs a sequence job with a progress bar, prints each failure as it happens and a summary at
/// the end, and fails when any frame failed.
fn shown_run(
    command: &str,
    quiet: bool,
    timings: Option<TimingFormat>,
    job: impl FnOnce(&Events) -> Result<Finished>,
) -> Result<()> {
    let bar = frames_bar(quiet);
    let events = Events {
        start: &|todo, kept| {
            if !kept.is_empty() && !quiet {
                bar.suspend(|| {
                    eprint_line(&format!(
                        "{command}: {} of {} frames have their outputs already and are kept \
                         (--overwrite replaces them)",
                        kept.len(),
                        todo.len() + kept.len()
                    ))
                });
            }
            if todo.is_empty() {
                bar.finish_and_clear();
            } else {
                bar.set_length(todo.len() as u64);
                bar.reset_eta();
            }
        },
        frame: &|n, r| {
            if let Err(e) = r {
                bar.suspend(|| eprint_line(&format!("error: frame {n}: {}", describe(e))));
            }
            bar.inc(1);
        },
        note: &|line| bar.suspend(|| print_note(line)),
    };
    let done = job(&events)?;
    bar.finish_and_clear();
    let todo = done.written.len() + done.failed_count;
    if todo == 0 {
        return Ok(());
    }
    if !quiet {
        eprint_line(&format!(
            "{}: {} frame(s) written, {} kept, {} failed, in {:.1} s ({:.2} frames/s)",
            done.command,
            done.written.len(),
            done.kept.len(),
            done.failed_count,
            done.wall_s,
            done.frames_per_second()
        ));
    }
    if let (Some(format), Some(last)) = (timings, &done.last) {
        report_sequence_timings(format, last, &done.timings, done.written.len(), done.wall_s)?;
    }
    if done.failed_count > 0 {
        let mut list: Vec<String> = done.failed.iter().map(|(n, _)| n.to_string()).collect();
        let more = done.failed_count - done.failed.len();
        if more > 0 {
            list.push(format!("and {more} more"));
        }
        bail!(
            "{} of {} frames failed (frames {}; each error is above); the other frames are written",
            done.failed_count,
            todo,
            list.join(", ")
        );
    }
    Ok(())
}

/// An error's chain on one line, escaped for the terminal as `main` does.
fn describe(e: &anyhow::Error) -> String {
    let chain: Vec<String> = e.chain().map(|c| c.to_string()).collect();
    shown(&chain.join(": "))
}

/// `--timings` of a sequence: every pass summed over the written frames, and the wall time.
fn report_sequence_timings(
    format: TimingFormat,
    last: &FrameDone,
    total: &Timings,
    written: usize,
    wall_s: f64,
) -> Result<()> {
    match format {
        TimingFormat::Table => {
            crate::common::report_timings(
                Some(format),
                last.method,
                &last.device,
                last.width,
                last.height,
                total,
                None,
            )?;
            eprint_line(&format!(
                "{written} frames (passes summed over them), wall {:.1} s, {:.2} frames/s",
                wall_s,
                written as f64 / wall_s.max(1e-9)
            ));
        }
        TimingFormat::Json => {
            let value = serde_json::json!({
                "method": last.method,
                "device": last.device,
                "width": last.width,
                "height": last.height,
                "frames": written,
                "passes": total.passes,
                "total_ms": total.total_ms(),
                "wall_ms": wall_s * 1e3,
                "frames_per_second": written as f64 / wall_s.max(1e-9),
                "max_rss_bytes": resident_peak_bytes(),
            });
            crate::common::print_output(&value.to_string())?;
        }
    }
    Ok(())
}
