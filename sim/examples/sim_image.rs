//! Writes a synthetic firmware image for the simulator: a valid ESP app image for its
//! chip whose version chooses what the virtual firmware does after an update
//! (`-sim-panic`: panics at boot; `-sim-noconfirm`: never takes a CONFIRM).
//!
//! `cargo run -p virtual-robot --example sim_image -- VERSION FILE [KIB]`

use std::process::ExitCode;

use virtual_robot::app_flash::{TYPICAL_PAYLOAD, sim_image};

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (version, path) = match args.as_slice() {
        [version, path] | [version, path, _] => (version, path),
        _ => {
            eprintln!("usage: sim_image VERSION FILE [KIB]");
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
    let image = sim_image(version, payload);
    if let Err(error) = std::fs::write(path, &image) {
        eprintln!("{path}: {error}");
        return ExitCode::FAILURE;
    }
    println!("{path}: firmware {version}, {} bytes", image.len());
    ExitCode::SUCCESS
}
