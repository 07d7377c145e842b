//! The safety rules the whole-robot tester checks, each written once, here, from
//! docs/behaviour.md (each links its paragraph). `oracle.rs` checks them on what the
//! robot does on its wires; docs/tests.md lists them for users.

use std::fmt;

/// A rule of docs/behaviour.md as the tester checks it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Rule {
    /// A wheel is commanded non-zero only while exactly one source in control has a
    /// fresh command (CAN velocity with a live enable; the one pad in control, link up,
    /// dead-man held after a release), never beyond `max_motor_vel` or, in the safety
    /// zone, `sec_motor_vel`; when that ends, zero is on the wire within 30 ms and
    /// both wheels stand within the stop's time at `stop_decel`.
    OneSourceMoves,
    /// E-stop active: zero on the wire within 8 ms, both wheels stopped within the
    /// e-stop's 300 ms, no feedback frame 0x0EA–0x0ED, and nothing moves until the
    /// e-stop is released and the front button pressed briefly.
    EmergencyStop,
    /// No motion while an update session or an image on trial holds the lock; a
    /// session ends 10 s after its PC fell silent, a trial after 120 s.
    UpdateLock,
    /// The status frame says `brakes_applied` only while both drives are de-excited,
    /// the brakes never close on a turning wheel, and nothing is written to flash
    /// while a drive is excited.
    BrakesAndFlash,
    /// The register store never loses a value silently (a reboot reads what was
    /// written, or reports the flash fault); every boot finds an image; only the
    /// confirmed image or, once, the one just activated boots, and never one that no
    /// trusted key signed.
    StoreAndBoot,
    /// Periodic frames come on time, the pose moves while the wheels do, the
    /// controller never panics or starves its watchdog, every fault the status frame
    /// reports is one that happened, and a drive turning against its command is found
    /// and stopped.
    FeedbackAndFaults,
}

impl Rule {
    pub const ALL: [Rule; 6] = [
        Rule::OneSourceMoves,
        Rule::EmergencyStop,
        Rule::UpdateLock,
        Rule::BrakesAndFlash,
        Rule::StoreAndBoot,
        Rule::FeedbackAndFaults,
    ];

    /// The rule's number in the issue and in docs/tests.md.
    pub fn number(self) -> u8 {
        match self {
            Rule::OneSourceMoves => 1,
            Rule::EmergencyStop => 2,
            Rule::UpdateLock => 3,
            Rule::BrakesAndFlash => 4,
            Rule::StoreAndBoot => 5,
            Rule::FeedbackAndFaults => 6,
        }
    }

    pub fn from_number(number: u8) -> Option<Rule> {
        Rule::ALL.into_iter().find(|rule| rule.number() == number)
    }

    /// Where docs/behaviour.md says it.
    pub fn paragraph(self) -> &'static str {
        match self {
            Rule::OneSourceMoves => "docs/behaviour.md#who-may-move-the-base",
            Rule::EmergencyStop => "docs/behaviour.md#emergency-stop",
            Rule::UpdateLock => "docs/behaviour.md#firmware-update-lock",
            Rule::BrakesAndFlash => "docs/behaviour.md#brakes-and-flash",
            Rule::StoreAndBoot => "docs/behaviour.md#registers-and-images-survive",
            Rule::FeedbackAndFaults => "docs/behaviour.md#feedback-and-faults",
        }
    }

    pub fn title(self) -> &'static str {
        match self {
            Rule::OneSourceMoves => "only one source with a fresh command moves the base",
            Rule::EmergencyStop => "the e-stop stops and holds the base",
            Rule::UpdateLock => "no motion under the update lock, no lock beyond its bound",
            Rule::BrakesAndFlash => "brakes and flash only while the drives are de-excited",
            Rule::StoreAndBoot => "no register value lost silently, an image always boots",
            Rule::FeedbackAndFaults => "feedback on time, no panic, only true faults",
        }
    }
}

impl fmt::Display for Rule {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "rule {} ({}; {})",
            self.number(),
            self.title(),
            self.paragraph()
        )
    }
}

/// The bounds the rules state, from docs/behaviour.md and docs/figures.md.
pub mod bounds {
    /// A command reaches both drives within 10 ms (figures: at most 8.6 ms, the pad's
    /// at most 15 ms); a lapse is seen on the next 10 ms control tick. Zero must be on
    /// the wire this long after a source's command ended.
    pub const ZERO_AFTER_END_US: u64 = 30_000;
    /// A non-zero order this long after the last moment a source could ask for it
    /// has no source: the command path's worst latency with margin.
    pub const COMMAND_LATENCY_US: u64 = 20_000;
    /// E-stop edge → zero speed on the wire (docs/figures.md, the goal), plus the
    /// input sampling.
    pub const ESTOP_ZERO_US: u64 = 8_000 + INPUT_SAMPLE_US;
    /// The firmware samples the e-stop and the zone this often: it learns of an edge
    /// up to this long after it.
    pub const INPUT_SAMPLE_US: u64 = 200;
    /// A command write (41 bytes at 115200 baud, applied 4.3 ms after its first byte)
    /// may have started before the firmware knew of the e-stop: up to one input sample
    /// and the controller's reaction (a CAN frame taken first; 0.3 ms with margin)
    /// after the edge. It finishes first.
    pub const COMMAND_WRITE_US: u64 = 4_300 + INPUT_SAMPLE_US + 300;
    /// After such a write: its echo, the 29-byte emergency zero and the drives' C3.5.
    pub const ZERO_AFTER_WRITE_US: u64 = 6_000;
    /// Near standstill the slower wheel may creep this fast a little longer than the
    /// faster one's stop (its share of a change measured half a cycle earlier).
    pub const CREEP_RPM: f64 = 10.0;
    /// The e-stop's deceleration stops `max_motor_vel` within 300 ms (the register
    /// rule `estop_decel` × 0.3 s ≥ `max_motor_vel`).
    pub const ESTOP_STOP_US: u64 = 300_000;
    /// The gentlest stop but the e-stop: `stop_decel`'s minimum, (1/min)/s.
    pub const STOP_DECEL_FLOOR: f64 = 2_000.0;
    /// A wheel counts as standing at or below this motor speed (docs/behaviour.md,
    /// "Standstill": 2 1/min), plus the wheel model's rounding.
    pub const AT_REST_RPM: f64 = 3.0;
    /// When the controller cannot reach a drive (cut from the line, a garbled line, a
    /// reset), the drive's own communication timeout (150 ms) and its brake stop it:
    /// this much more time for the stop.
    pub const UNREACHABLE_US: u64 = 400_000;
    /// A status frame is built this long before it leaves the bus at most (the
    /// transmit queue's 32 frames).
    pub const FRAME_QUEUE_US: u64 = 30_000;
    /// Periodic frames may be late by one flash erase (45 ms typical) and the bus.
    pub const PERIOD_SLACK_US: u64 = 70_000;
    /// A wheel turns against its command when it does so at this motor speed or more
    /// (docs/behaviour.md, "A wheel turning against its command": 40 1/min).
    pub const AGAINST_RPM: f64 = 40.0;
    /// Such a wheel, its command keeping one sign, is found within two 100 ms windows
    /// and stopped by the next cycle: this long with as much again for slack.
    pub const AGAINST_FOUND_US: u64 = 600_000;
    /// An update session ends 10 s after its PC's last frame (docs/protocol.md).
    pub const SESSION_SILENCE_US: u64 = 10_000_000;
    /// An image on trial rejects itself 120 s after its boot without CONFIRM.
    pub const TRIAL_US: u64 = 120_000_000;
    /// A fault reported within this long after something that can cause it is one
    /// that happened (the status frame comes once a second).
    pub const FAULT_CAUSE_US: u64 = 3_000_000;
}
