//! `defocus`: the command-line tool. A thin layer over the library: parse flags (clap), turn
//! them into validated jobs (units converted, ranges checked), run, report.

mod args;
mod commands;
mod common;
mod devices;
mod kernel;
mod sequence;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    // Mesa's Vulkan device-selection layer only reorders the adapters (defocus chooses its own,
    // `--device`), and on a machine without a graphical login (no XDG_RUNTIME_DIR) it prints
    // "error: XDG_RUNTIME_DIR is invalid" on every run that looks for an adapter. Turned off
    // before any thread starts, unless the user set it.
    if std::env::var_os("NODEVICE_SELECT").is_none() {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
    // Ctrl-C or SIGTERM: remove the temporary files of unfinished outputs, then stop.
    let _ = ctrlc::set_handler(|| {
        defocus::output::interrupt();
        std::process::exit(130);
    });
    let cli = args::Cli::parse();
    match commands::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let chain: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            // Paths are escaped where they are formatted; this also catches names read from
            // files (materials, objects), so nothing reaches the terminal raw.
            common::eprint_line(&format!(
                "error: {}",
                defocus::error::shown(&chain.join(": "))
            ));
            ExitCode::FAILURE
        }
    }
}
