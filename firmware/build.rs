//! Linker scripts: esp-hal's `linkall.x` lays out the image, defmt's `defmt.x` keeps
//! the interned log strings, and embedded-test's script collects the on-target tests.
//! Here rather than in `.cargo/config.toml` so the firmware links the same from any
//! directory.

fn main() {
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").unwrap_or_default();
    if arch == "xtensa" {
        // The esp toolchain links Xtensa with GNU ld through gcc.
        println!("cargo:rustc-link-arg=-nostartfiles");
        println!("cargo:rustc-link-arg=-Wl,-Tlinkall.x");
    } else {
        println!("cargo:rustc-link-arg=-Tlinkall.x");
    }
    println!("cargo:rustc-link-arg=-Tdefmt.x");
    println!("cargo:rustc-link-arg-tests=-Tembedded-test.x");
    // embedded-test's macro looks at this cfg.
    println!("cargo::rustc-check-cfg=cfg(rust_analyzer)");
    println!("cargo:rerun-if-env-changed=CAN_BITRATE_KBIT");
}
