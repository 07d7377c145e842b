//! Linker scripts: esp-hal's `linkall.x` lays out the image, defmt's `defmt.x` keeps
//! the interned log strings, and embedded-test's script collects the on-target tests.
//! Here rather than in `.cargo/config.toml` so the firmware links the same from any
//! directory. On the ESP32 the linker also wraps the Bluetooth controller's start so
//! that it runs in dual mode (see `board/esp32.rs`).

fn main() {
    let arch = std::env::var("CARGO_CFG_TARGET_ARCH").unwrap_or_default();
    if arch == "xtensa" {
        // The esp toolchain links Xtensa with GNU ld through gcc.
        println!("cargo:rustc-link-arg=-nostartfiles");
        println!("cargo:rustc-link-arg=-Wl,-Tlinkall.x");
        // esp-radio's calls of these two land in board/esp32.rs's `__wrap_…`
        // functions, which call the controller library's own as `__real_…`.
        if std::env::var_os("CARGO_FEATURE_BLE_ONLY").is_none() {
            println!("cargo:rustc-link-arg=-Wl,--wrap=btdm_controller_init");
            println!("cargo:rustc-link-arg=-Wl,--wrap=btdm_controller_enable");
        }
    } else {
        println!("cargo:rustc-link-arg=-Tlinkall.x");
    }
    println!("cargo:rustc-link-arg=-Tdefmt.x");
    println!("cargo:rustc-link-arg-tests=-Tembedded-test.x");
    // embedded-test's macro looks at this cfg.
    println!("cargo::rustc-check-cfg=cfg(rust_analyzer)");
    println!("cargo:rerun-if-env-changed=CAN_BITRATE_KBIT");
}
