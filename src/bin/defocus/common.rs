//! What the commands share that is the command line's own: progress bars, printing and timing
//! reports. The flags' parsers and the jobs are the library's (`defocus::jobs`); this file
//! imports no other file of the binary.

use defocus::timing::{Clock, Timings};
use indicatif::{ProgressBar, ProgressStyle};

pub use defocus::jobs::flags::*;
pub use defocus::options::parse_aperture;

/// `--timings` of one finished frame, if asked.
pub fn report_done(format: Option<TimingFormat>, done: &FrameDone) -> anyhow::Result<()> {
    report_timings(
        format,
        done.method,
        &done.device,
        done.width,
        done.height,
        &done.timings,
        done.memory_bytes,
    )
}

/// Prints `text` and a newline on standard error. A standard error that cannot be written (its
/// reader has gone, as in `defocus render ... 2>&1 | head -1`, or a log collector died) drops
/// the line: never a panic, never a failure of its own, so the command keeps its exit status.
/// Every line the command line prints on standard error goes through here.
pub fn eprint_line(text: &str) {
    use std::io::Write as _;
    let mut err = std::io::stderr().lock();
    let _ = writeln!(err, "{text}");
}

/// Prints a line a job notes (a warning or a remark about its input) on standard error (see
/// [`eprint_line`]).
pub fn print_note(line: String) {
    eprint_line(&line);
}

pub fn progress_bar(quiet: bool, total: u64, unit: &str) -> ProgressBar {
    if quiet || total <= 1 {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(total);
    let template = format!(
        "{{spinner}} [{{elapsed_precise}}] {{wide_bar}} {{pos}}/{{len}} {unit} (eta {{eta}})"
    );
    if let Ok(style) = ProgressStyle::with_template(&template) {
        bar.set_style(style);
    }
    bar
}

/// Prints a command's output (`text` and a newline) on standard output. A reader that has gone
/// (`defocus compare a b | head -1`) is not an error: the rest is dropped, as other tools do,
/// instead of a panic; any other failure to write is.
pub fn print_output(text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}").and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(anyhow::anyhow!(
            "could not write the output to standard output: {e}"
        )),
        _ => Ok(()),
    }
}

/// The process's largest resident size so far (`VmHWM` of `/proc/self/status`), where the
/// system reports it (Linux); `None` elsewhere.
pub fn resident_peak_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// `--timings`: the method, the device it ran on (`cpu` or the GPU adapter's label), the size
/// and each pass, as a table on stderr or one JSON object on stdout. A pass not timed by the
/// wall clock (a GPU pass) says how it was timed.
pub fn report_timings(
    format: Option<TimingFormat>,
    method: &str,
    device: &str,
    width: usize,
    height: usize,
    timings: &Timings,
    memory_bytes: Option<usize>,
) -> anyhow::Result<()> {
    match format {
        None => {}
        Some(TimingFormat::Table) => {
            let name_width = timings
                .passes
                .iter()
                .map(|p| p.name.len())
                .max()
                .unwrap_or(4)
                .max(5);
            let clocked = timings.passes.iter().any(|p| p.clock != Clock::Wall);
            let mut table = vec![
                format!("{method} {width}x{height}"),
                format!("device: {device}"),
                format!(
                    "{:<name_width$} {:>10}{}",
                    "pass",
                    "ms",
                    if clocked { "  clock" } else { "" }
                ),
            ];
            for p in &timings.passes {
                let clock = if clocked {
                    format!("  {}", p.clock.name())
                } else {
                    String::new()
                };
                table.push(format!("{:<name_width$} {:>10.2}{clock}", p.name, p.ms));
            }
            table.push(format!(
                "{:<name_width$} {:>10.2}",
                "total",
                timings.total_ms()
            ));
            if let Some(b) = memory_bytes {
                table.push(format!(
                    "{:<name_width$} {:>10.1}",
                    "peak MiB",
                    b as f64 / 1048576.0
                ));
            }
            if let Some(b) = resident_peak_bytes() {
                table.push(format!(
                    "{:<name_width$} {:>10.1}",
                    "max RSS MiB",
                    b as f64 / 1048576.0
                ));
            }
            eprint_line(&table.join("\n"));
        }
        Some(TimingFormat::Json) => {
            let value = serde_json::json!({
                "method": method,
                "device": device,
                "width": width,
                "height": height,
                "passes": timings.passes,
                "total_ms": timings.total_ms(),
                "memory_bytes": memory_bytes,
                "max_rss_bytes": resident_peak_bytes(),
            });
            print_output(&value.to_string())?;
        }
    }
    Ok(())
}

/// Most worker threads `--threads` accepts (a thread per core of the largest machines, with
/// room; more only adds start-up time and memory).
pub const MAX_THREADS: usize = 512;
