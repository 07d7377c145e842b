//! Two pads at once: the BLE task and the PlayStation pad's task (Bluetooth Classic)
//! may each have a bonded pad connected, but exactly one pad controls the base
//! (docs/behaviour.md, "Who may move the base"). The arbiter decides which one, from
//! the links the tasks report; the remote ([`super::Remote`]) and the supervisor only
//! ever hear of the pad in control.
//!
//! The rule: **the first pad connected controls**, until its link goes down. Then the
//! other pad, if it is connected, takes over as a fresh connection: the base has
//! braked for the lost pad first, and the new pad's dead-man must be seen released
//! before it drives, as after any connection. Reports of the pad not in control are
//! dropped (counted), so its buttons neither arm nor hold nor release anything, and a
//! switch-off (L2 + Home, AFK) goes to the pad in control alone.
//!
//! One thing of a waiting pad is kept: whether its latest report held the dead-man. A
//! BLE pad reports only when something on it changes, so a dead-man pressed while it
//! waited is not reported again when the pad takes over; unknown, it would let CAN
//! drive on under the hand that holds it. Handed over, it counts as held from the first
//! moment: it takes control from CAN and stops the base, and must still be released
//! before the pad drives.
//!
//! ```text
//!   link up of P, nobody in control ──────────▶ P in control (Connected)
//!   link up of P, the other in control ───────▶ P waits (its reports dropped)
//!   link down of the pad in control ──────────▶ Disconnected; the other, if up: Connected
//!   link down of a waiting pad ───────────────▶ nothing for the remote
//! ```

use super::DEAD_MAN;
use crate::gamepad::GamepadState;
use crate::registers::{RemoteInfo, RemoteKind};

/// Which remote task a link or report comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Pad {
    /// A BLE gamepad (HID over GATT), from the BLE task.
    Ble = 0,
    /// A PlayStation pad over Bluetooth Classic, from the Classic task.
    Classic = 1,
}

impl Pad {
    pub const ALL: [Pad; 2] = [Pad::Ble, Pad::Classic];

    const fn other(self) -> Pad {
        match self {
            Pad::Ble => Pad::Classic,
            Pad::Classic => Pad::Ble,
        }
    }

    const fn index(self) -> usize {
        self as usize
    }
}

/// What one task last said of its pad.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct PadLink {
    bonded: bool,
    connected: bool,
    /// The kind and battery the task reported while connected (the Classic task does;
    /// the BLE task reports none).
    info: Option<RemoteInfo>,
    /// The latest report while the pad waited held its dead-man.
    waiting_dead_man_held: bool,
}

/// What a link change means for the remote: the pad in control went away, another
/// took control, or both (a hand-over).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Handover {
    /// The pad in control went down: the remote is disconnected (a held dead-man brakes).
    pub lost: bool,
    /// A pad takes control now: the remote is connected afresh.
    pub gained: bool,
    /// The pad taking control held its dead-man in its latest report while it waited:
    /// the remote must hear it held from the start.
    pub dead_man_held: bool,
}

/// See the module documentation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PadArbiter {
    links: [PadLink; 2],
    in_control: Option<Pad>,
    /// Reports of a pad not in control, dropped since boot (wraps).
    dropped_reports: u32,
}

impl PadArbiter {
    pub const fn new() -> Self {
        Self {
            links: [PadLink {
                bonded: false,
                connected: false,
                info: None,
                waiting_dead_man_held: false,
            }; 2],
            in_control: None,
            dropped_reports: 0,
        }
    }

    /// A task reports its pad's link; returns what it changes for the remote.
    pub fn link(&mut self, pad: Pad, bonded: bool, connected: bool) -> Handover {
        let link = &mut self.links[pad.index()];
        link.bonded = bonded;
        link.connected = connected;
        if !connected {
            link.info = None;
            link.waiting_dead_man_held = false;
        }
        let mut handover = Handover::default();
        match self.in_control {
            None if connected => {
                self.in_control = Some(pad);
                handover.gained = true;
            }
            Some(owner) if owner == pad && !connected => {
                handover.lost = true;
                let other = pad.other();
                let other_link = &mut self.links[other.index()];
                if other_link.connected {
                    self.in_control = Some(other);
                    handover.gained = true;
                    handover.dead_man_held = other_link.waiting_dead_man_held;
                    other_link.waiting_dead_man_held = false;
                } else {
                    self.in_control = None;
                }
            }
            _ => {}
        }
        handover
    }

    /// Whether a report of `pad` reaches the remote: only the pad in control's does.
    /// A report that does not is counted, and a connected waiting pad's dead-man is
    /// kept for a hand-over.
    pub fn admit_report(&mut self, pad: Pad, state: &GamepadState) -> bool {
        let admitted = self.in_control == Some(pad);
        if !admitted {
            self.dropped_reports = self.dropped_reports.wrapping_add(1);
            let link = &mut self.links[pad.index()];
            if link.connected {
                link.waiting_dead_man_held = state.buttons.contains(DEAD_MAN);
            }
        }
        admitted
    }

    /// A task reports its connected pad's kind and battery.
    pub fn set_info(&mut self, pad: Pad, info: RemoteInfo) {
        self.links[pad.index()].info = Some(info);
    }

    /// The pad in control, if any.
    pub fn in_control(&self) -> Option<Pad> {
        self.in_control
    }

    /// A pad is bonded on either task.
    pub fn bonded(&self) -> bool {
        self.links.iter().any(|link| link.bonded)
    }

    /// A pad controls the remote (so one is connected).
    pub fn connected(&self) -> bool {
        self.in_control.is_some()
    }

    /// Both pads are connected: one of them waits.
    pub fn both_connected(&self) -> bool {
        self.links.iter().all(|link| link.connected)
    }

    /// The pad in control's kind and battery for `remote_kind`/`remote_battery`: what its
    /// task reported, a BLE pad when the BLE task's (it reports none), nothing while a
    /// PlayStation pad has not told its kind yet or no pad is in control.
    pub fn info(&self) -> RemoteInfo {
        match self.in_control {
            Some(pad) => match (pad, self.links[pad.index()].info) {
                (_, Some(info)) => info,
                (Pad::Ble, None) => RemoteInfo {
                    kind: RemoteKind::BlePad,
                    battery: None,
                },
                (Pad::Classic, None) => RemoteInfo::NONE,
            },
            None => RemoteInfo::NONE,
        }
    }

    /// Reports of a pad not in control dropped since boot.
    pub fn dropped_reports(&self) -> u32 {
        self.dropped_reports
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hid::playstation::PadKind;

    /// What the remote hears of one link change.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum Heard {
        Nothing,
        Connected,
        Disconnected,
        /// Disconnected, then connected again: the other pad took over.
        HandedOver,
    }

    fn heard(handover: Handover) -> Heard {
        assert!(!handover.dead_man_held, "no report held a dead-man");
        match (handover.lost, handover.gained) {
            (false, false) => Heard::Nothing,
            (false, true) => Heard::Connected,
            (true, false) => Heard::Disconnected,
            (true, true) => Heard::HandedOver,
        }
    }

    #[test]
    fn the_first_pad_connected_controls_and_the_other_takes_over_only_when_it_leaves() {
        use Heard::*;
        use Pad::*;
        // (pad, connected) → what the remote hears, the pad in control afterwards,
        // whether each pad's report gets through (BLE, Classic).
        let table = [
            (Ble, true, Connected, Some(Ble), (true, false)),
            // The second pad waits: its reports are dropped.
            (Classic, true, Nothing, Some(Ble), (true, false)),
            // A repeated link report of the pad in control changes nothing.
            (Ble, true, Nothing, Some(Ble), (true, false)),
            // The pad in control leaves: the remote hears a loss, then the waiting pad
            // as a new connection.
            (Ble, false, HandedOver, Some(Classic), (false, true)),
            // The first pad comes back: it waits now.
            (Ble, true, Nothing, Some(Classic), (false, true)),
            // The waiting pad leaves: nothing for the remote.
            (Ble, false, Nothing, Some(Classic), (false, true)),
            // The last pad leaves: the remote is disconnected, nobody controls.
            (Classic, false, Disconnected, None, (false, false)),
            // A link-down of a pad that was never up changes nothing.
            (Classic, false, Nothing, None, (false, false)),
            (Classic, true, Connected, Some(Classic), (false, true)),
        ];
        let mut arbiter = PadArbiter::new();
        for (row, (pad, connected, expected, in_control, admitted)) in table.into_iter().enumerate()
        {
            let handover = arbiter.link(pad, true, connected);
            assert_eq!(heard(handover), expected, "row {row}");
            assert_eq!(arbiter.in_control(), in_control, "row {row}");
            assert_eq!(arbiter.connected(), in_control.is_some(), "row {row}");
            let released = GamepadState::default();
            let got = (
                arbiter.admit_report(Ble, &released),
                arbiter.admit_report(Classic, &released),
            );
            assert_eq!(got, admitted, "row {row}");
        }
    }

    #[test]
    fn reports_of_the_waiting_pad_are_counted() {
        let mut arbiter = PadArbiter::new();
        arbiter.link(Pad::Classic, true, true);
        arbiter.link(Pad::Ble, true, true);
        let released = GamepadState::default();
        for _ in 0..3 {
            assert!(!arbiter.admit_report(Pad::Ble, &released));
            assert!(arbiter.admit_report(Pad::Classic, &released));
        }
        assert_eq!(arbiter.dropped_reports(), 3);
        assert!(arbiter.both_connected());
    }

    #[test]
    fn the_waiting_pad_s_latest_dead_man_is_handed_over_and_forgotten_when_it_leaves() {
        let held = GamepadState {
            buttons: DEAD_MAN,
            ..GamepadState::default()
        };
        let released = GamepadState::default();
        let mut arbiter = PadArbiter::new();
        arbiter.link(Pad::Ble, true, true);
        arbiter.link(Pad::Classic, true, true);
        // (report of the waiting PlayStation pad) → the hand-over carries a held dead-man
        let cases = [
            (&[held][..], true),
            (&[held, released][..], false),
            (&[released, held][..], true),
            (&[][..], false),
        ];
        for (reports, expected) in cases {
            for report in reports {
                assert!(!arbiter.admit_report(Pad::Classic, report));
            }
            let handover = arbiter.link(Pad::Ble, true, false);
            assert!(handover.lost && handover.gained, "{reports:?}");
            assert_eq!(handover.dead_man_held, expected, "{reports:?}");
            // Back to the start: the BLE pad in control, the PlayStation pad waiting.
            arbiter.link(Pad::Classic, true, false);
            arbiter.link(Pad::Ble, true, true);
            arbiter.link(Pad::Classic, true, true);
        }
        // A waiting pad that left takes nothing along when it comes back.
        assert!(!arbiter.admit_report(Pad::Classic, &held));
        arbiter.link(Pad::Classic, true, false);
        arbiter.link(Pad::Classic, true, true);
        assert!(!arbiter.link(Pad::Ble, true, false).dead_man_held);
        // Nor does a report of a pad whose link is down (the BLE pad's, now).
        assert!(!arbiter.admit_report(Pad::Ble, &held));
        arbiter.link(Pad::Ble, true, true);
        assert!(!arbiter.link(Pad::Classic, true, false).dead_man_held);
    }

    #[test]
    fn bonded_is_either_task_s_bond() {
        let mut arbiter = PadArbiter::new();
        arbiter.link(Pad::Ble, false, false);
        arbiter.link(Pad::Classic, true, false);
        assert!(arbiter.bonded());
        arbiter.link(Pad::Classic, false, false);
        assert!(!arbiter.bonded());
    }

    #[test]
    fn the_registers_show_the_pad_in_control_and_forget_a_pad_that_left() {
        let dual_sense = RemoteInfo::playstation(PadKind::DualSense, None);
        let ble_pad = RemoteInfo {
            kind: RemoteKind::BlePad,
            battery: None,
        };
        let mut arbiter = PadArbiter::new();
        // A PlayStation pad before its first full report tells nothing yet.
        arbiter.link(Pad::Classic, true, true);
        assert_eq!(arbiter.info(), RemoteInfo::NONE);
        arbiter.set_info(Pad::Classic, dual_sense);
        assert_eq!(arbiter.info(), dual_sense);
        // A BLE pad waiting beside it does not show.
        arbiter.link(Pad::Ble, true, true);
        assert_eq!(arbiter.info(), dual_sense);
        // The PlayStation pad leaves: the BLE pad controls and shows.
        arbiter.link(Pad::Classic, true, false);
        assert_eq!(arbiter.info(), ble_pad);
        // Back, it waits, and its old kind is forgotten until it reports again.
        arbiter.link(Pad::Ble, true, false);
        arbiter.link(Pad::Classic, true, true);
        assert_eq!(arbiter.info(), RemoteInfo::NONE);
        arbiter.link(Pad::Classic, true, false);
        assert_eq!(arbiter.info(), RemoteInfo::NONE);
    }
}
