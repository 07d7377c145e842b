//! `basectl --help`: the commissioning CLI; everything but parsing lives in the library.

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let cli = basectl::cli::Cli::parse();
    match basectl::cli::run(cli, &mut std::io::stdout()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("basectl: {error}");
            ExitCode::FAILURE
        }
    }
}
