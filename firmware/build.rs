//! Linker scripts: esp-hal's `linkall.x` lays out the image, defmt's `defmt.x` keeps
//! the interned log strings, and embedded-test's script collects the on-target tests.
//! Here rather than in `.cargo/config.toml` so the firmware links the same from any
//! directory. On the ESP32 the linker also wraps the Bluetooth controller's start so
//! that it runs in dual mode (see `board/esp32.rs`). It also stamps the image's
//! version (`BASE_FIRMWARE_VERSION`, see [`firmware_version`]).

use std::process::Command;

fn main() {
    let version = firmware_version();
    assert!(
        version.len() <= 31,
        "firmware version {version:?} is longer than the app descriptor's 31 bytes"
    );
    println!("cargo:rustc-env=BASE_FIRMWARE_VERSION={version}");
    println!("cargo:rerun-if-env-changed=BASE_FIRMWARE_VERSION");
    write_update_trust();

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

/// `OUT_DIR/update_trust.rs` (included by `src/update.rs`): the public keys whose
/// signed images an update may activate, from `BASE_UPDATE_KEY` (PEM files, as
/// `basectl firmware keygen` writes them, separated by `:`; none: a development build,
/// which takes unsigned images), and the image's security version from
/// `BASE_SECURITY_VERSION` (0 to 255, default 0), which goes into its app descriptor.
fn write_update_trust() {
    println!("cargo:rerun-if-env-changed=BASE_UPDATE_KEY");
    println!("cargo:rerun-if-env-changed=BASE_SECURITY_VERSION");
    let keys: Vec<[u8; 32]> = std::env::var("BASE_UPDATE_KEY")
        .unwrap_or_default()
        .split(':')
        .filter(|path| !path.is_empty())
        .map(|path| {
            println!("cargo:rerun-if-changed={path}");
            let text = std::fs::read_to_string(path)
                .unwrap_or_else(|error| panic!("BASE_UPDATE_KEY {path}: {error}"));
            let key = ed25519_compact::PublicKey::from_pem(&text)
                .and_then(|key| key.validate().map(|()| key))
                .unwrap_or_else(|error| {
                    panic!("BASE_UPDATE_KEY {path}: not an ed25519 public key in PEM: {error}")
                });
            *key
        })
        .collect();
    let security_version: u32 = match std::env::var("BASE_SECURITY_VERSION") {
        Ok(text) => text
            .parse()
            .ok()
            .filter(|version| *version <= 255)
            .unwrap_or_else(|| panic!("BASE_SECURITY_VERSION {text:?}: a number from 0 to 255")),
        Err(_) => 0,
    };
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets it"));
    let code = format!(
        "/// The public keys of signed images an update may activate.\n\
         pub const UPDATE_KEYS: &[[u8; 32]] = &{keys:?};\n\
         /// This image's security version: no update goes below it unless its owner\n\
         /// signed the downgrade.\n\
         pub const SECURITY_VERSION: u32 = {security_version};\n"
    );
    std::fs::write(out.join("update_trust.rs"), code).expect("OUT_DIR is writable");
}

/// The version the image carries (its app descriptor, QUERY's VERSION, `basectl
/// info`): `BASE_FIRMWARE_VERSION` as given for a release build; otherwise the crate's
/// version with the build as semver metadata, `0.1.0+412.g7efef4d`: the number of
/// commits, the commit, and `.dirty` for uncommitted changes. The update's downgrade
/// check compares the number when the releases are equal (docs/protocol.md,
/// "Versions"); a build outside a git checkout is `+unknown` and has none.
fn firmware_version() -> String {
    if let Ok(version) = std::env::var("BASE_FIRMWARE_VERSION") {
        return version;
    }
    let release = std::env::var("CARGO_PKG_VERSION").expect("cargo sets it");
    let git = |args: &[&str]| {
        Command::new("git")
            .args(args)
            .output()
            .ok()
            .filter(|output| output.status.success())
            .map(|output| String::from_utf8_lossy(&output.stdout).trim().to_owned())
    };
    let (Some(count), Some(commit)) = (
        git(&["rev-list", "--count", "HEAD"]),
        git(&["rev-parse", "--short=7", "HEAD"]),
    ) else {
        return format!("{release}+unknown");
    };
    // A new commit, a checkout or a change to a tracked file builds a new stamp.
    for path in ["HEAD", "index"] {
        if let Some(file) = git(&["rev-parse", "--git-path", path]) {
            println!("cargo:rerun-if-changed={file}");
        }
    }
    if let Some(refs) = git(&["rev-parse", "--git-common-dir"]) {
        println!("cargo:rerun-if-changed={refs}/refs/heads");
    }
    let dirty = git(&["status", "--porcelain", "--untracked-files=no"])
        .is_some_and(|changes| !changes.is_empty());
    let dirty = if dirty { ".dirty" } else { "" };
    format!("{release}+{count}.g{commit}{dirty}")
}
