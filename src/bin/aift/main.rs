//! The `aift` command line: a thin layer over the library.
//!
//! Exit codes: 0 success, 2 bad input (the message names the file and the field), 1 internal
//! error (an output could not be written, a bug).

#[macro_use]
mod output;
mod args;
mod commands;
#[cfg(test)]
mod doc_commands;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = args::Cli::parse();
    if let Some(warning) = aift::init_thread_pool() {
        errln!("warning: {warning}");
    }
    let result = commands::dispatch(cli);
    let stdout_failure = output::finish();
    match result {
        Err(failure) => {
            let mut chain = failure.error.chain();
            let mut text = chain.next().map(|e| e.to_string()).unwrap_or_default();
            for cause in chain {
                aift::push_cause(&mut text, &cause.to_string());
            }
            errln!("error: {text}");
            ExitCode::from(failure.code)
        }
        Ok(()) => match stdout_failure {
            Some(e) => {
                errln!("error: writing to stdout: {e}");
                ExitCode::from(1)
            }
            None => ExitCode::SUCCESS,
        },
    }
}
