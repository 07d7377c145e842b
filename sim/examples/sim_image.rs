//! Writes a synthetic firmware image for the simulator: a valid ESP app image for its
//! chip whose version chooses what the virtual firmware does after an update
//! (`-sim-panic`: panics at boot; `-sim-noconfirm`: never takes a CONFIRM), with the
//! security version given (0 when not). Sign it with `basectl firmware sign`.
//!
//! `cargo run -p virtual-robot --example sim_image -- [--security-version N] VERSION FILE [KIB]`

use std::process::ExitCode;

use base_runtime::update::PROJECT;
use virtual_robot::app_flash::{SIM_CHIP, TYPICAL_PAYLOAD, secured_image};

const USAGE: &str = "usage: sim_image [--security-version N] VERSION FILE [KIB]";

fn main() -> ExitCode {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut security_version = 0;
    if args.first().map(String::as_str) == Some("--security-version") {
        match args.get(1).map(|n| n.parse::<u32>()) {
            Some(Ok(n)) => security_version = n,
            _ => {
                eprintln!("--security-version needs a number\n{USAGE}");
                return ExitCode::FAILURE;
            }
        }
        args.drain(..2);
    }
    let (version, path) = match args.as_slice() {
        [version, path] | [version, path, _] => (version, path),
        _ => {
            eprintln!("{USAGE}");
            return ExitCode::FAILURE;
        }
    };
    let payload = match args.get(2).map(|kib| kib.parse::<usize>()) {
        None => TYPICAL_PAYLOAD,
        Some(Ok(kib)) => kib * 1024,
        Some(Err(error)) => {
            eprintln!("KIB: {error}");
            return ExitCode::FAILURE;
        }
    };
    let image = secured_image(SIM_CHIP, PROJECT, version, security_version, payload);
    if let Err(error) = std::fs::write(path, &image) {
        eprintln!("{path}: {error}");
        return ExitCode::FAILURE;
    }
    println!(
        "{path}: firmware {version}, security version {security_version}, {} bytes",
        image.len()
    );
    ExitCode::SUCCESS
}
