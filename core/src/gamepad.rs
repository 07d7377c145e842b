//! One gamepad's state, normalised: what the HID decoder ([`crate::hid`]) produces from
//! any pad's reports and what the remote mapping ([`crate::remote`]) turns into
//! driving. Names follow the Xbox layout (the BLE pads we support); the PlayStation
//! names of the contract are in brackets.

/// Sticks and triggers in fixed ranges, buttons as named bits, the D-pad as four bits.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GamepadState {
    /// Left stick, −1.0 (left) … 1.0 (right), dead zone already applied.
    pub left_x: f32,
    /// Left stick, −1.0 (pulled back) … 1.0 (pushed forward), dead zone applied.
    pub left_y: f32,
    pub right_x: f32,
    pub right_y: f32,
    /// Triggers, 0.0 (released) … 1.0 (fully pulled). Pads with digital triggers
    /// report 0.0 or 1.0.
    pub left_trigger: f32,
    pub right_trigger: f32,
    pub buttons: Buttons,
    pub dpad: Dpad,
}

/// Named buttons as bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Buttons(pub u16);

impl Buttons {
    /// A (PlayStation: Cross).
    pub const A: Buttons = Buttons(1 << 0);
    /// B (PlayStation: Circle).
    pub const B: Buttons = Buttons(1 << 1);
    /// X (PlayStation: Square).
    pub const X: Buttons = Buttons(1 << 2);
    /// Y (PlayStation: Triangle).
    pub const Y: Buttons = Buttons(1 << 3);
    /// Left bumper LB (PlayStation: L1).
    pub const LEFT_BUMPER: Buttons = Buttons(1 << 4);
    /// Right bumper RB (PlayStation: R1): the dead-man.
    pub const RIGHT_BUMPER: Buttons = Buttons(1 << 5);
    /// View (PlayStation: Share, older pads: Select).
    pub const VIEW: Buttons = Buttons(1 << 6);
    /// Menu (PlayStation: Options, older pads: Start).
    pub const MENU: Buttons = Buttons(1 << 7);
    /// Xbox / Home (PlayStation: PS).
    pub const HOME: Buttons = Buttons(1 << 8);
    /// Left stick pressed (PlayStation: L3).
    pub const LEFT_STICK: Buttons = Buttons(1 << 9);
    /// Right stick pressed (PlayStation: R3).
    pub const RIGHT_STICK: Buttons = Buttons(1 << 10);
    /// Share / capture.
    pub const SHARE: Buttons = Buttons(1 << 11);

    pub const NONE: Buttons = Buttons(0);

    pub const fn contains(self, other: Buttons) -> bool {
        self.0 & other.0 == other.0 && other.0 != 0
    }

    pub const fn with(self, other: Buttons) -> Buttons {
        Buttons(self.0 | other.0)
    }
}

/// The D-pad (a hat switch on most pads) as its four directions; a diagonal sets two.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Dpad {
    pub up: bool,
    pub down: bool,
    pub left: bool,
    pub right: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buttons_combine_and_test_as_sets() {
        let held = Buttons::RIGHT_BUMPER.with(Buttons::MENU);
        assert!(held.contains(Buttons::RIGHT_BUMPER));
        assert!(held.contains(Buttons::MENU));
        assert!(held.contains(Buttons::RIGHT_BUMPER.with(Buttons::MENU)));
        assert!(!held.contains(Buttons::HOME));
        assert!(!held.contains(Buttons::NONE));
    }
}
