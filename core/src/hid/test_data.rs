//! Report Maps of real pads, from `tests/data/hid/` (each file's first line says where
//! the bytes come from; its comments give the report layout and sample reports).

pub const XBOX_BLE: &str = include_str!("../../tests/data/hid/xbox-wireless-ble-fw5_045E-0B13.hex");
pub const XBOX_ONE_S_BREDR: &str =
    include_str!("../../tests/data/hid/xbox-one-s-fw4.8-bredr_045E-02FD.hex");
pub const EIGHTBITDO_WINDOWS: &str =
    include_str!("../../tests/data/hid/8bitdo-sn30pro-plus-windows-mode-bredr_045E-02E0.hex");

/// Hex bytes separated by white space; in a `.hex` file, `#` lines are comments.
pub fn hex(text: &str) -> Vec<u8> {
    text.lines()
        .filter(|line| !line.starts_with('#'))
        .flat_map(str::split_whitespace)
        .map(|pair| u8::from_str_radix(pair, 16).unwrap())
        .collect()
}
