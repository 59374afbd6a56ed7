//! `defocus`: the command-line tool. A thin layer over the library: parse flags (clap), turn
//! them into validated jobs (units converted, ranges checked), run, report.

mod args;
mod blur;
mod commands;
mod common;
mod kernel;
mod post;
mod report;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = args::Cli::parse();
    match commands::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let chain: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            eprintln!("error: {}", chain.join(": "));
            ExitCode::FAILURE
        }
    }
}
