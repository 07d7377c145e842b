//! BLE gamepads (HID over GATT): the pad's Report Map parsed into input fields
//! ([`ReportMap`]), and its input reports decoded into a [`GamepadState`] by usage
//! ([`GamepadLayout`]). The BLE task feeds it the Report Map and each notification; the
//! remote mapping reads the states. No I/O, no time, no allocation. The PlayStation
//! pads over Bluetooth Classic have fixed layouts instead: [`playstation`].
//!
//! Hand-written rather than taken from a crate: the HID report descriptor parsers on
//! crates.io need `alloc` (hidreport, hidparser, hid-report) or `std` (hid-decode), and
//! usbd-hid-descriptors only builds descriptors. Fixed capacities ([`MAX_INPUT_FIELDS`]
//! and the other limits) bound the memory; a map over them is refused.
//!
//! [`GamepadState`]: crate::gamepad::GamepadState

mod descriptor;
mod layout;
pub mod light_bar;
pub mod playstation;
#[cfg(test)]
mod test_data;

pub use descriptor::{
    DescriptorError, Field, FieldFlags, MAX_INPUT_FIELDS, MAX_INPUT_REPORTS, MAX_PUSH_DEPTH,
    MAX_REPORT_BYTES, MAX_REPORT_SIZE_BITS, MAX_USAGES, ReportMap, Usage, Usages,
};
pub use layout::{GamepadLayout, ReportError, STICK_DEAD_ZONE, VidPid};
