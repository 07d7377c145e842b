//! The PlayStation pad's light bar shows the base's mode, so the person holding the pad
//! sees at a glance whether the base will drive: one colour per [`BaseLight`].
//!
//! Two decisions, both pure:
//!
//! - [`BaseLight::of`]: the base's state (the supervisor's mode, whether the dead-man
//!   has control, whether someone is in the safety zone) → the light. What stops the
//!   base wins: emergency, then fault, then not ready, then the safety zone, then the
//!   dead-man; otherwise ready.
//! - [`LightBar`]: when to send the light to the pad. An output report goes out when the
//!   light changes, at most one per [`LightBarParams::min_interval_ms`], and again every
//!   [`LightBarParams::refresh_ms`] while nothing changes, so a pad that missed one
//!   (or reset its light) shows the truth again soon. A change that comes too soon is
//!   not dropped: the newest light goes out as soon as the interval has passed, on the
//!   first step from then on ([`LightBar::next_due`] says when).
//!
//! ```text
//!                 Connected(kind)
//!   NoPad ────────────────────────▶ Showing (report now)
//!     ▲                               │ light changed and min_interval passed,
//!     │        Disconnected           │ or refresh passed → report, stay
//!     └───────────────────────────────┘
//! ```
//!
//! The reports come from [`OutputBuilder`], one per connection (it numbers the
//! DualSense's reports and ends its start-up light in the first one). Rumble stays off.

use super::playstation::{OUTPUT_REPORT_LEN, OutputBuilder, PadKind, PadOutput, Rgb};
use crate::can::Mode;
use crate::supervisor::Supervisor;
use crate::time::Timestamp;

/// What the light bar shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BaseLight {
    /// Drives not ready yet: starting, or recovering after a confirm press.
    NotReady,
    /// The base may drive: hold the dead-man (R1) to drive with the pad.
    Ready,
    /// The dead-man is held: the pad has control (it drives once armed).
    DeadMan,
    /// Someone is in the safety zone: the base drives only at the safety-zone limits.
    SafetyZone,
    /// The e-stop is pressed, or released and waiting for the confirm press.
    Emergency,
    /// A drive fault is latched, waiting for the confirm press.
    Fault,
}

impl BaseLight {
    /// The light for the base's state; see the module documentation for the order.
    pub fn of(mode: Mode, remote_in_control: bool, safety_zone: bool) -> BaseLight {
        match mode {
            Mode::Emergency | Mode::AwaitingConfirm => BaseLight::Emergency,
            Mode::Fault => BaseLight::Fault,
            Mode::Starting | Mode::Recovering => BaseLight::NotReady,
            Mode::Standby | Mode::Active if safety_zone => BaseLight::SafetyZone,
            Mode::Standby | Mode::Active if remote_in_control => BaseLight::DeadMan,
            Mode::Standby | Mode::Active => BaseLight::Ready,
        }
    }

    /// [`BaseLight::of`] the supervisor's current state.
    pub fn from_supervisor(supervisor: &Supervisor) -> BaseLight {
        BaseLight::of(
            supervisor.mode(),
            supervisor.remote_in_control(),
            supervisor.safety_zone(),
        )
    }

    /// The colour on the pad; `docs/remote.md` has the same table for users.
    pub const fn colour(self) -> Rgb {
        match self {
            BaseLight::NotReady => Rgb::new(64, 64, 64),
            BaseLight::Ready => Rgb::new(0, 255, 0),
            BaseLight::DeadMan => Rgb::new(0, 0, 255),
            BaseLight::SafetyZone => Rgb::new(255, 160, 0),
            BaseLight::Emergency => Rgb::new(255, 0, 0),
            BaseLight::Fault => Rgb::new(255, 0, 255),
        }
    }
}

/// How often the light bar may and must be sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LightBarParams {
    /// At most one report per this many ms: a mode that flickers (a chattering
    /// safety-zone input) costs the link at most ten reports a second.
    pub min_interval_ms: u64,
    /// The light is sent again after this many ms without a change.
    pub refresh_ms: u64,
}

/// 100 ms and 5 s: the light follows a change within a tenth of a second, and the
/// refresh adds one 79-byte report every 5 s to a link that carries 250 input reports
/// a second the other way.
pub const LIGHT_BAR_PARAMS: LightBarParams = LightBarParams {
    min_interval_ms: 100,
    refresh_ms: 5_000,
};

/// What happened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// A PlayStation pad's HID channels are open: it can take output reports.
    Connected(PadKind),
    /// The pad's link ended.
    Disconnected,
    /// The base's light now (sent on every change, or on every step: an unchanged light
    /// is no change).
    Base(BaseLight),
    /// Time passed.
    Tick,
}

/// What must happen now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Effects {
    /// An output report to send on the pad's HID interrupt channel, header and CRC
    /// included.
    pub report: Option<[u8; OUTPUT_REPORT_LEN]>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    NoPad,
    Showing {
        builder: OutputBuilder,
        /// The light in the last report and when it was sent.
        shown: BaseLight,
        sent: Timestamp,
    },
}

/// The light bar of the connected PlayStation pad; see the module documentation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LightBar {
    state: State,
    /// The base's latest light, kept while no pad is connected so that a pad that
    /// connects gets the right one at once.
    wanted: BaseLight,
}

impl Default for LightBar {
    fn default() -> Self {
        Self::new()
    }
}

impl LightBar {
    pub const fn new() -> LightBar {
        LightBar {
            state: State::NoPad,
            wanted: BaseLight::NotReady,
        }
    }

    pub fn step(&mut self, now: Timestamp, event: Event, params: &LightBarParams) -> Effects {
        match event {
            Event::Base(light) => self.wanted = light,
            Event::Disconnected => self.state = State::NoPad,
            Event::Connected(kind) => {
                let mut builder = OutputBuilder::new(kind);
                let report = light_report(&mut builder, self.wanted);
                self.state = State::Showing {
                    builder,
                    shown: self.wanted,
                    sent: now,
                };
                return Effects {
                    report: Some(report),
                };
            }
            Event::Tick => {}
        }
        let wanted = self.wanted;
        let State::Showing {
            builder,
            shown,
            sent,
        } = &mut self.state
        else {
            return Effects::default();
        };
        let since = now.millis_since(*sent);
        let due = if *shown == wanted {
            since >= params.refresh_ms
        } else {
            since >= params.min_interval_ms
        };
        if !due {
            return Effects::default();
        }
        let report = light_report(builder, wanted);
        *shown = wanted;
        *sent = now;
        Effects {
            report: Some(report),
        }
    }

    /// When the next report is due if nothing else happens: the end of the interval
    /// for a change that waits, else the refresh. `None` without a pad.
    pub fn next_due(&self, params: &LightBarParams) -> Option<Timestamp> {
        match self.state {
            State::NoPad => None,
            State::Showing { shown, sent, .. } if shown != self.wanted => {
                Some(sent.plus_millis(params.min_interval_ms))
            }
            State::Showing { sent, .. } => Some(sent.plus_millis(params.refresh_ms)),
        }
    }

    /// The light the pad was last sent, `None` without a pad.
    pub fn shown(&self) -> Option<BaseLight> {
        match self.state {
            State::NoPad => None,
            State::Showing { shown, .. } => Some(shown),
        }
    }
}

/// The output report that sets `light`, rumble off.
fn light_report(builder: &mut OutputBuilder, light: BaseLight) -> [u8; OUTPUT_REPORT_LEN] {
    builder.build(&PadOutput {
        light_bar: light.colour(),
        ..PadOutput::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hid::playstation::{HEADER_OUTPUT, crc32};
    use crate::kinematics::SafetyLimits;
    use crate::supervisor::{self, Params};

    const PARAMS: LightBarParams = LIGHT_BAR_PARAMS;

    fn at(ms: u64) -> Timestamp {
        Timestamp::from_millis(ms)
    }

    /// The colour a report sets, after checking its header, ID and CRC: what the pad
    /// would show.
    fn colour_in(kind: PadKind, report: &[u8; OUTPUT_REPORT_LEN]) -> Rgb {
        assert_eq!(report[0], HEADER_OUTPUT);
        assert_eq!(report[1], kind.full_report_id());
        let crc = u32::from_le_bytes(report[75..79].try_into().unwrap());
        assert_eq!(crc, crc32(HEADER_OUTPUT, &report[1..75]), "CRC");
        let at = match kind {
            PadKind::DualShock4 => 9,
            PadKind::DualSense => 48,
        };
        Rgb::new(report[at], report[at + 1], report[at + 2])
    }

    #[test]
    fn the_light_follows_the_mode_and_what_stops_the_base_wins() {
        use BaseLight::*;
        // (mode, dead-man in control, safety zone occupied) → light
        let table = [
            (Mode::Starting, false, false, NotReady),
            (Mode::Starting, true, true, NotReady),
            (Mode::Recovering, true, false, NotReady),
            (Mode::Standby, false, false, Ready),
            (Mode::Active, false, false, Ready),
            (Mode::Standby, true, false, DeadMan),
            (Mode::Active, true, false, DeadMan),
            (Mode::Standby, false, true, SafetyZone),
            (Mode::Active, true, true, SafetyZone),
            (Mode::Emergency, false, false, Emergency),
            (Mode::Emergency, true, true, Emergency),
            (Mode::AwaitingConfirm, true, false, Emergency),
            (Mode::Fault, false, false, Fault),
            (Mode::Fault, true, true, Fault),
        ];
        for (mode, dead_man, zone, light) in table {
            assert_eq!(
                BaseLight::of(mode, dead_man, zone),
                light,
                "{mode:?} dead-man {dead_man} zone {zone}"
            );
        }
    }

    #[test]
    fn every_light_has_its_own_colour_and_none_is_dark() {
        use BaseLight::*;
        let all = [NotReady, Ready, DeadMan, SafetyZone, Emergency, Fault];
        for (i, a) in all.iter().enumerate() {
            assert_ne!(a.colour(), Rgb::default(), "{a:?} is dark");
            for b in &all[i + 1..] {
                assert_ne!(a.colour(), b.colour(), "{a:?} and {b:?}");
            }
        }
        assert_eq!(Emergency.colour(), Rgb::new(255, 0, 0));
    }

    #[test]
    fn the_supervisors_emergency_shows_red() {
        let params = Params {
            enable_timeout_ms: 500,
            cmd_timeout_ms: 0,
            disable_time_ms: 300,
            can_accel: 700,
            remote_accel: 350,
            remote_release_accel: 500,
            estop_decel: 4500,
            stop_decel: 2000,
            safety_limits: SafetyLimits {
                linear_mm_s: 200,
                rotation_mrad_s: 100,
            },
        };
        let mut supervisor = Supervisor::new();
        assert_eq!(BaseLight::from_supervisor(&supervisor), BaseLight::NotReady);
        supervisor.step(at(0), supervisor::Event::DrivesReady, &params);
        assert_eq!(BaseLight::from_supervisor(&supervisor), BaseLight::Ready);
        supervisor.step(
            at(10),
            supervisor::Event::SafetyZone { occupied: true },
            &params,
        );
        assert_eq!(
            BaseLight::from_supervisor(&supervisor),
            BaseLight::SafetyZone
        );
        supervisor.step(at(20), supervisor::Event::Estop { pressed: true }, &params);
        assert_eq!(
            BaseLight::from_supervisor(&supervisor),
            BaseLight::Emergency
        );
    }

    /// (time, event) → the colour of the report sent, if any.
    fn run(kind: PadKind, table: &[(u64, Event, Option<BaseLight>)]) {
        let mut light_bar = LightBar::new();
        for &(ms, event, expected) in table {
            let effects = light_bar.step(at(ms), event, &PARAMS);
            assert_eq!(
                effects.report.map(|report| colour_in(kind, &report)),
                expected.map(BaseLight::colour),
                "at {ms} ms after {event:?}"
            );
        }
    }

    #[test]
    fn a_change_is_sent_at_once_or_when_the_interval_has_passed_and_refreshed_every_5_s() {
        use BaseLight::*;
        use Event::*;
        let dual_shock = PadKind::DualShock4;
        run(
            dual_shock,
            &[
                // The light is known before the pad connects: it gets it at once.
                (0, Base(Ready), None),
                (10, Connected(dual_shock), Some(Ready)),
                (50, Base(Ready), None),
                // Within 100 ms of the last report: the change waits ...
                (60, Base(DeadMan), None),
                (109, Tick, None),
                // ... and goes out when the interval has passed.
                (110, Tick, Some(DeadMan)),
                (111, Tick, None),
                // Long after the last report: at once.
                (400, Base(Emergency), Some(Emergency)),
                // A flicker that is back before the interval ends sends nothing.
                (420, Base(Ready), None),
                (450, Base(Emergency), None),
                (500, Tick, None),
                (600, Tick, None),
                // No change for 5 s: the same light again.
                (5_399, Tick, None),
                (5_400, Tick, Some(Emergency)),
                (5_500, Base(Emergency), None),
                (10_400, Base(Emergency), Some(Emergency)),
            ],
        );
    }

    #[test]
    fn without_a_pad_nothing_is_sent_and_a_new_pad_gets_the_latest_light() {
        use BaseLight::*;
        use Event::*;
        let dual_sense = PadKind::DualSense;
        run(
            dual_sense,
            &[
                (0, Tick, None),
                (10, Base(Fault), None),
                (20, Connected(dual_sense), Some(Fault)),
                (30, Disconnected, None),
                (40, Base(Emergency), None),
                (6_000, Tick, None),
                // Reconnected within 100 ms of the old pad's last report: sent anyway,
                // the interval is per connection.
                (6_010, Connected(dual_sense), Some(Emergency)),
                (6_020, Base(SafetyZone), None),
                (6_110, Base(SafetyZone), Some(SafetyZone)),
            ],
        );
    }

    #[test]
    fn a_chattering_mode_costs_at_most_ten_reports_a_second_and_ends_on_the_truth() {
        let mut light_bar = LightBar::new();
        let kind = PadKind::DualShock4;
        let mut reports = Vec::new();
        let mut light = BaseLight::Ready;
        if let Some(report) = light_bar
            .step(at(0), Event::Connected(kind), &PARAMS)
            .report
        {
            reports.push((0, report));
        }
        // The safety-zone input chatters every 10 ms for 10 s.
        for ms in (10..10_000).step_by(10) {
            light = if (ms / 10) % 2 == 0 {
                BaseLight::SafetyZone
            } else {
                BaseLight::Ready
            };
            if let Some(report) = light_bar.step(at(ms), Event::Base(light), &PARAMS).report {
                reports.push((ms, report));
            }
        }
        assert!(reports.len() <= 101, "{} reports in 10 s", reports.len());
        for pair in reports.windows(2) {
            assert!(
                pair[1].0 - pair[0].0 >= PARAMS.min_interval_ms,
                "{}",
                pair[1].0
            );
        }
        // It settles: the last light is on the pad, or goes out once the interval
        // has passed.
        let (last_sent, last_report) = *reports.last().unwrap();
        if light_bar.shown() != Some(light) {
            let due = light_bar.next_due(&PARAMS).unwrap();
            assert_eq!(due, at(last_sent + PARAMS.min_interval_ms));
            let report = light_bar.step(due, Event::Tick, &PARAMS).report.unwrap();
            assert_eq!(colour_in(kind, &report), light.colour());
        } else {
            assert_eq!(colour_in(kind, &last_report), light.colour());
        }
        assert_eq!(light_bar.shown(), Some(light));
    }

    #[test]
    fn next_due_is_the_interval_end_for_a_waiting_change_else_the_refresh() {
        let mut light_bar = LightBar::new();
        assert_eq!(light_bar.next_due(&PARAMS), None);
        light_bar.step(at(1_000), Event::Connected(PadKind::DualSense), &PARAMS);
        assert_eq!(light_bar.next_due(&PARAMS), Some(at(6_000)));
        light_bar.step(at(1_050), Event::Base(BaseLight::DeadMan), &PARAMS);
        assert_eq!(light_bar.next_due(&PARAMS), Some(at(1_100)));
        light_bar.step(at(1_100), Event::Tick, &PARAMS);
        assert_eq!(light_bar.next_due(&PARAMS), Some(at(6_100)));
        light_bar.step(at(1_200), Event::Disconnected, &PARAMS);
        assert_eq!(light_bar.next_due(&PARAMS), None);
        assert_eq!(light_bar.shown(), None);
    }

    #[test]
    fn the_dualsense_reports_are_numbered_and_only_the_first_ends_the_start_up_light() {
        let mut light_bar = LightBar::new();
        let first = light_bar
            .step(at(0), Event::Connected(PadKind::DualSense), &PARAMS)
            .report
            .unwrap();
        let second = light_bar
            .step(at(5_000), Event::Tick, &PARAMS)
            .report
            .unwrap();
        assert_eq!((first[2], second[2]), (0x00, 0x10), "sequence numbers");
        assert_eq!((first[42], first[45]), (0x02, 0x02), "start-up light ended");
        assert_eq!((second[42], second[45]), (0, 0));
        // Rumble off in both.
        assert_eq!([first[6], first[7], second[6], second[7]], [0; 4]);
    }
}
