//! The `aift` command line: a thin layer over the library.
//!
//! Exit codes: 0 success, 2 bad input (the message names the file and the field), 1 internal
//! error (an output could not be written, a bug).

mod args;
mod commands;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = args::Cli::parse();
    match commands::dispatch(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            eprintln!("error: {:#}", failure.error);
            ExitCode::from(failure.code)
        }
    }
}
