//! No reboot loop: a controller that keeps panicking soon after boot comes up with
//! Bluetooth off.
//!
//! A panic resets the chip. If something in radio range makes the Bluetooth stack panic
//! (the guard in `base_bluetooth::guard` exists so that nothing known can), it would do so
//! again after every boot, and the base would spend its life rebooting. This is the
//! decision: the panic handler writes each panic into a [`PanicHistory`] that survives
//! the reset (two words of RTC fast RAM on the chip, `board::panic_record` in the
//! firmware; the virtual robot's `RtcRam` in the simulator), and the boot reads it. With
//! Bluetooth off the remote task does not start (the runtime's `ble::wait_until_on`),
//! and the controller reports it in register 36, `bluetooth_off`.
//!
//! ```text
//!   panic at uptime < SHORT_LIFE_MS ──▶ short_panics + 1
//!   panic at uptime ≥ SHORT_LIFE_MS ──▶ short_panics = 0   (it ran a while: no loop)
//!   boot after anything but a panic ──▶ short_panics = 0   (power-on, watchdog, flashing)
//!   boot with short_panics ≥ LOOP_PANICS ──▶ Bluetooth off
//!   Bluetooth turned on by hand ──────▶ short_panics = 0
//! ```
//!
//! With [`LOOP_PANICS`] = 3 and [`SHORT_LIFE_MS`] = 30 s: three boots in a row that each
//! panic within 30 s of starting, so at most 90 s of looping, switch Bluetooth off. The
//! base stays fully controllable over CAN, and Bluetooth comes back on, without a
//! reboot, with a confirm press of the front button or a write of
//! [`crate::registers::BLUETOOTH_ON_KEY`] to the command register
//! ([`PanicHistory::turned_on`]).

use crate::time::Timestamp;

/// Panics in a row, each soon after boot, that switch Bluetooth off.
pub const LOOP_PANICS: u8 = 3;
/// A panic this soon after boot counts towards a loop, ms.
pub const SHORT_LIFE_MS: u64 = 30_000;

/// Whether the Bluetooth remote may start at this boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Bluetooth {
    On,
    /// Off after a panic loop, until turned on by hand.
    OffAfterPanics,
}

/// What the panic handler leaves for the next boot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PanicHistory {
    /// Panics in a row, each within [`SHORT_LIFE_MS`] of its boot.
    short_panics: u8,
    /// The last reset was a panic (set by the handler, read and cleared at boot).
    panicked: bool,
}

/// Marks a record written by this firmware (RAM that survives a reset holds noise
/// after power-on).
const MAGIC: u32 = 0xB1E0_0A11;

impl PanicHistory {
    /// The panic handler's entry, `uptime` since this boot.
    pub fn on_panic(&mut self, uptime: Timestamp) {
        self.short_panics = if uptime.as_millis() < SHORT_LIFE_MS {
            self.short_panics.saturating_add(1)
        } else {
            0
        };
        self.panicked = true;
    }

    /// The boot's decision; forgets the count unless this reset was a panic.
    pub fn at_boot(&mut self) -> Bluetooth {
        if !self.panicked {
            self.short_panics = 0;
        }
        self.panicked = false;
        if self.short_panics >= LOOP_PANICS {
            Bluetooth::OffAfterPanics
        } else {
            Bluetooth::On
        }
    }

    /// Bluetooth was turned on by hand: the count starts over.
    pub fn turned_on(&mut self) {
        self.short_panics = 0;
    }

    pub fn short_panics(&self) -> u8 {
        self.short_panics
    }

    /// Two words for RAM that survives a reset: a magic word, then the history with
    /// its complement (so noise is not read as a history).
    pub fn encode(&self) -> [u32; 2] {
        let value = u32::from(self.short_panics) | (u32::from(self.panicked) << 8);
        [MAGIC, value | (!value << 16)]
    }

    /// The history in `words`; an empty one for anything [`Self::encode`] did not write.
    pub fn decode(words: [u32; 2]) -> PanicHistory {
        let [magic, packed] = words;
        let value = packed & 0xFFFF;
        if magic != MAGIC || (packed >> 16) != (!value & 0xFFFF) || value > 0x1FF {
            return PanicHistory::default();
        }
        PanicHistory {
            short_panics: (value & 0xFF) as u8,
            panicked: value & 0x100 != 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Boots, then panics after `uptime_ms` (on the virtual clock of that boot), as many
    /// times as given; returns the decision of the boot after the last one.
    fn boots(history: &mut PanicHistory, panics_after_ms: &[u64]) -> Vec<Bluetooth> {
        panics_after_ms
            .iter()
            .map(|&uptime| {
                let decision = history.at_boot();
                history.on_panic(Timestamp::BOOT.plus_millis(uptime));
                // The reset: only the two words survive.
                *history = PanicHistory::decode(history.encode());
                decision
            })
            .collect()
    }

    use Bluetooth::{OffAfterPanics as Off, On};

    #[test]
    fn three_panics_soon_after_boot_switch_bluetooth_off_at_the_fourth_boot() {
        let mut history = PanicHistory::default();
        // The attacker in range: every boot died within 0.12 to 0.2 s.
        assert_eq!(boots(&mut history, &[120, 200, 150]), [On, On, On]);
        assert_eq!(history.at_boot(), Off);
        // It stays off across further resets that are panics (none comes from Bluetooth
        // now, but the count does not fall by itself).
        history.on_panic(Timestamp::from_millis(5_000));
        assert_eq!(history.at_boot(), Off);
    }

    #[test]
    fn a_boot_that_ran_30_s_or_a_reset_without_panic_starts_the_count_over() {
        let mut history = PanicHistory::default();
        assert_eq!(
            boots(&mut history, &[100, 29_999, 30_000, 100, 100]),
            [On; 5]
        );
        assert_eq!(history.short_panics(), 2);
        assert_eq!(history.at_boot(), On);
        // This boot ends without a panic (power-off, watchdog, flashing): the next
        // boot finds `panicked` false.
        assert_eq!(history.at_boot(), On);
        assert_eq!(history.short_panics(), 0);
        assert_eq!(boots(&mut history, &[100, 100]), [On, On]);
        assert_eq!(history.at_boot(), On, "two in a row are not a loop");
    }

    #[test]
    fn turning_bluetooth_on_by_hand_starts_the_count_over() {
        let mut history = PanicHistory::default();
        boots(&mut history, &[100, 100, 100]);
        assert_eq!(history.at_boot(), Off);
        history.turned_on();
        assert_eq!(boots(&mut history, &[100, 100]), [On, On]);
        assert_eq!(history.at_boot(), On);
    }

    #[test]
    fn noise_in_the_surviving_ram_is_no_history() {
        for words in [
            [0, 0],
            [0xFFFF_FFFF; 2],
            [MAGIC, 0x0003_0103],
            [MAGIC, 0xFFFF_0000],
        ] {
            assert_eq!(
                PanicHistory::decode(words),
                PanicHistory::default(),
                "{words:x?}"
            );
        }
        let mut history = PanicHistory::default();
        history.on_panic(Timestamp::from_millis(1));
        history.on_panic(Timestamp::from_millis(1));
        assert_eq!(PanicHistory::decode(history.encode()), history);
    }
}
