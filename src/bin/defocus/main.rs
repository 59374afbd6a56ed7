//! `defocus`: the command-line tool. A thin layer over the library: parse flags (clap), turn
//! them into validated jobs (units converted, ranges checked), run, report.

mod args;
mod commands;
mod common;
mod kernel;
mod sequence;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
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
