//! Front button and PC power (docs/behaviour.md, Front button and PC power): owns what the button means, whether the
//! robot PC counts as on, and the pulse on the PC's power-switch contact. The input task
//! sends the debounced button edges, the CAN task the heartbeats (0x006 `01`), a timer
//! the ticks; the supervisor takes `confirm`, the shell drives the switch pin, and the
//! status frame reads `pc_on`.

use crate::time::Timestamp;

/// Timing of the button and the PC, from registers 21–23 plus two extensions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Params {
    /// Hold time that switches an off PC on (register 22 `start_PC`).
    pub start_pc_ms: u32,
    /// Hold time that switches a running PC off (register 23 `shutdown_PC`).
    pub shutdown_pc_ms: u32,
    /// The PC counts as off this long after its last heartbeat (register 21
    /// `heartbeat_time`).
    pub heartbeat_timeout_ms: u32,
    /// After we switched the PC on it counts as on this long even without heartbeats,
    /// so a second press while it boots does not switch it off again.
    pub boot_grace_ms: u32,
    /// How long the power-switch contact stays closed per pulse (0: until the next
    /// event). Keep it well below 4 s: holding an ATX power button that long forces the
    /// PC off.
    pub switch_pulse_ms: u32,
}

impl Params {
    /// Register defaults (21–23) plus: boot grace 120 s, enough for a PC to boot its OS
    /// and start the heartbeat sender; switch pulse 500 ms, a firm "press" of the
    /// PC's power button, far from the 4 s forced off.
    pub const DEFAULT: Params = Params {
        start_pc_ms: 3_000,
        shutdown_pc_ms: 8_000,
        heartbeat_timeout_ms: 5_000,
        boot_grace_ms: 120_000,
        switch_pulse_ms: 500,
    };
}

impl Default for Params {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What happened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// Debounced front button went down.
    ButtonPressed,
    /// Debounced front button went up.
    ButtonReleased,
    /// A PC heartbeat (0x006 `01`) arrived.
    Heartbeat,
    /// Time passed. Send one at least every few ms while the button is held or the
    /// contact is closed: hold times and pulse ends act on the first event at or after
    /// their deadline.
    Tick,
}

/// Level of the PC power-switch contact.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchLevel {
    Open,
    Closed,
}

/// What the shell has to do after one event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Effects {
    /// A short press was released: confirms an emergency (docs/behaviour.md).
    pub confirm: bool,
    /// Set the switch pin to this level; `None`: leave it.
    pub switch: Option<SwitchLevel>,
}

impl Effects {
    pub const NONE: Effects = Effects {
        confirm: false,
        switch: None,
    };
}

/// How far the current press has got. Each press acts at most once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HoldStage {
    /// Shorter than `start_pc_ms` so far: released now, it is a confirm.
    Short,
    /// `start_pc_ms` passed while the PC was on: waiting for `shutdown_pc_ms`.
    AwaitShutdown,
    /// Acted, or nothing left to do for this press.
    Done,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ButtonState {
    Released,
    Held { since: Timestamp, stage: HoldStage },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchState {
    Open,
    Closed { until: Timestamp },
}

/// What we believe about the PC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PcState {
    /// No heartbeat within the timeout, not booting.
    Off,
    /// We switched it on at `since`: on until `boot_grace_ms` has passed, and after that
    /// for as long as heartbeats keep coming.
    Booting {
        since: Timestamp,
        last_heartbeat: Option<Timestamp>,
    },
    /// Heartbeats: on until `heartbeat_timeout_ms` after the last one.
    Alive { last_heartbeat: Timestamp },
}

impl PcState {
    fn is_on(self, now: Timestamp, params: &Params) -> bool {
        let fresh = |hb: Timestamp| now.millis_since(hb) < u64::from(params.heartbeat_timeout_ms);
        match self {
            PcState::Off => false,
            PcState::Booting {
                since,
                last_heartbeat,
            } => {
                now.millis_since(since) < u64::from(params.boot_grace_ms)
                    || last_heartbeat.is_some_and(fresh)
            }
            PcState::Alive { last_heartbeat } => fresh(last_heartbeat),
        }
    }

    /// Drop what has expired by `now`, so the state says what is true now.
    fn settle(self, now: Timestamp, params: &Params) -> PcState {
        let after_grace = match self {
            PcState::Booting {
                since,
                last_heartbeat,
            } if now.millis_since(since) >= u64::from(params.boot_grace_ms) => match last_heartbeat
            {
                Some(last_heartbeat) => PcState::Alive { last_heartbeat },
                None => PcState::Off,
            },
            other => other,
        };
        match after_grace {
            PcState::Alive { .. } if !after_grace.is_on(now, params) => PcState::Off,
            other => other,
        }
    }

    fn heartbeat(self, now: Timestamp) -> PcState {
        match self {
            PcState::Booting { since, .. } => PcState::Booting {
                since,
                last_heartbeat: Some(now),
            },
            PcState::Off | PcState::Alive { .. } => PcState::Alive {
                last_heartbeat: now,
            },
        }
    }

    /// After our shutdown pulse only heartbeats keep the PC "on": the boot grace ends.
    fn after_shutdown_pulse(self) -> PcState {
        match self {
            PcState::Booting {
                last_heartbeat: Some(last_heartbeat),
                ..
            }
            | PcState::Alive { last_heartbeat } => PcState::Alive { last_heartbeat },
            PcState::Booting {
                last_heartbeat: None,
                ..
            }
            | PcState::Off => PcState::Off,
        }
    }
}

/// The whole state of the button / PC-power logic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerState {
    pub button: ButtonState,
    pub switch: SwitchState,
    pub pc: PcState,
}

impl PowerState {
    /// At boot the button is up, the contact open and the PC unknown, i.e. off until its
    /// first heartbeat. A PC that kept running through a controller reset sends one
    /// within 2 s (0.5 Hz minimum), well before a 3 s hold could switch it "on".
    pub const INITIAL: PowerState = PowerState {
        button: ButtonState::Released,
        switch: SwitchState::Open,
        pc: PcState::Off,
    };
}

/// One step of the front-button / PC-power state machine. Pure: all time comes in as
/// `now`.
///
/// ```text
///  button:                      release (< start_pc): confirm
///            press             ┌────────────────────────────────────────────┐
///  Released ──────▶ Held{Short}┤ start_pc reached, PC off: pulse ─▶ Held{Done}
///     ▲                        │ start_pc reached, PC on ───▶ Held{AwaitShutdown}
///     │                        └─────────────────────────────────────┬──────┘
///     │                           shutdown_pc reached: PC on: pulse ─▶ Held{Done}
///     │                                                PC off: ───────▶ Held{Done}
///     └──────────── release (from any Held stage; only Short confirms)
///
///  pc:   Off ── heartbeat ──▶ Alive{last} ── no heartbeat for heartbeat_timeout ──▶ Off
///         │ on-pulse                ▲
///         ▼                         │ boot_grace over, a heartbeat came
///        Booting{since, last?} ─────┘  (none came: ─▶ Off)
///        shutdown pulse: Booting ─▶ Alive{last} if a heartbeat came, else Off
///
///  switch: Open ── pulse ──▶ Closed{until = now + switch_pulse} ── until reached ──▶ Open
/// ```
///
/// Rules (docs/behaviour.md, and the decisions it leaves open):
/// - Hold times act when they are reached, not on release; one action per press.
/// - Whether the PC is on is judged at the moment a hold time is reached: at
///   `start_pc_ms` an off PC is switched on (and holding on to 8 s does nothing more);
///   a PC that is on then is switched off only if it is still on at `shutdown_pc_ms`,
///   so a PC that died during the hold is not switched back on by a "shutdown".
/// - The PC is on while a heartbeat is younger than `heartbeat_timeout_ms`, or during
///   `boot_grace_ms` after our on-pulse. During the grace a 3 s press does nothing and
///   an 8 s press switches the PC off (that is what a person holding 8 s wants).
/// - After our shutdown pulse the grace ends and the PC stays "on" exactly as long as
///   its heartbeats keep coming: the OS is still shutting down, and the button keeps
///   meaning "off" until the PC has really gone quiet. Another 8 s hold in that time
///   sends another pulse (for a PC that ignored the first one).
fn next(state: PowerState, now: Timestamp, event: Event, params: &Params) -> (PowerState, Effects) {
    let mut out = Effects::NONE;
    let mut pc = state.pc.settle(now, params);
    let mut switch = state.switch;

    // Deadlines that passed before this event come first: a release at 3.1 s of a
    // press whose 3 s tick was missed still switches the PC on, and does not confirm.
    if let SwitchState::Closed { until } = switch
        && now >= until
    {
        switch = SwitchState::Open;
        out.switch = Some(SwitchLevel::Open);
    }

    let mut button = state.button;
    if let ButtonState::Held { since, mut stage } = button {
        let held_ms = now.millis_since(since);
        let mut pulse = false;
        if stage == HoldStage::Short && held_ms >= u64::from(params.start_pc_ms) {
            if pc.is_on(now, params) {
                stage = HoldStage::AwaitShutdown;
            } else {
                pulse = true;
                pc = PcState::Booting {
                    since: now,
                    last_heartbeat: None,
                };
                stage = HoldStage::Done;
            }
        }
        if stage == HoldStage::AwaitShutdown && held_ms >= u64::from(params.shutdown_pc_ms) {
            if pc.is_on(now, params) {
                pulse = true;
                pc = pc.after_shutdown_pulse();
            }
            stage = HoldStage::Done;
        }
        if pulse {
            switch = SwitchState::Closed {
                until: now.plus_millis(u64::from(params.switch_pulse_ms)),
            };
            out.switch = Some(SwitchLevel::Closed);
        }
        button = ButtonState::Held { since, stage };
    }

    match event {
        Event::Tick => {}
        Event::Heartbeat => pc = pc.heartbeat(now),
        Event::ButtonPressed => {
            // A second "pressed" without a release in between is a duplicate edge; the
            // press keeps its original start.
            if button == ButtonState::Released {
                button = ButtonState::Held {
                    since: now,
                    stage: HoldStage::Short,
                };
            }
        }
        Event::ButtonReleased => {
            if let ButtonState::Held { stage, .. } = button {
                out.confirm = stage == HoldStage::Short;
            }
            button = ButtonState::Released;
        }
    }

    (PowerState { button, switch, pc }, out)
}

/// The button / PC-power state machine as the controller holds it; `next` has
/// the transition diagram and the rules.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PowerControl {
    state: PowerState,
}

impl PowerControl {
    pub const fn new() -> Self {
        Self {
            state: PowerState::INITIAL,
        }
    }

    /// Handles one event at `now` and returns what must happen. New register values
    /// (`params`) take effect at once; a running press keeps its start time.
    pub fn step(&mut self, now: Timestamp, event: Event, params: &Params) -> Effects {
        let (state, effects) = next(self.state, now, event, params);
        self.state = state;
        effects
    }

    /// Whether the PC counts as on at `now` (heartbeat fresh or boot grace running),
    /// for the status frame.
    pub fn pc_on(&self, now: Timestamp, params: &Params) -> bool {
        self.state.pc.is_on(now, params)
    }

    pub fn state(&self) -> PowerState {
        self.state
    }
}

impl Default for PowerControl {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use Event::{ButtonPressed as Press, ButtonReleased as Release, Heartbeat as Hb, Tick};
    use proptest::prelude::*;

    const NONE: Effects = Effects::NONE;
    const CONFIRM: Effects = Effects {
        confirm: true,
        switch: None,
    };
    const CLOSE: Effects = Effects {
        confirm: false,
        switch: Some(SwitchLevel::Closed),
    };
    const OPEN: Effects = Effects {
        confirm: false,
        switch: Some(SwitchLevel::Open),
    };

    /// Short, distinct numbers so a table row reads at a glance.
    const PARAMS: Params = Params {
        start_pc_ms: 3_000,
        shutdown_pc_ms: 8_000,
        heartbeat_timeout_ms: 5_000,
        boot_grace_ms: 60_000,
        switch_pulse_ms: 500,
    };

    /// Run a scenario table of (time ms, event) → expected outputs, plus `pc_on` after
    /// the event where given.
    fn run(control: &mut PowerControl, rows: &[(u64, Event, Effects)]) {
        run_with(control, &PARAMS, rows);
    }

    fn run_with(control: &mut PowerControl, params: &Params, rows: &[(u64, Event, Effects)]) {
        for (i, &(t, event, expected)) in rows.iter().enumerate() {
            let got = control.step(Timestamp::from_millis(t), event, params);
            assert_eq!(got, expected, "row {i}: {event:?} at {t} ms");
        }
    }

    fn fresh() -> PowerControl {
        PowerControl::new()
    }

    /// A PC that has been sending heartbeats every 2 s since boot, up to `until_ms`.
    fn with_heartbeats(control: &mut PowerControl, until_ms: u64) {
        for t in (0..=until_ms).step_by(2_000) {
            control.step(Timestamp::from_millis(t), Hb, &PARAMS);
        }
    }

    #[test]
    fn hold_3s_with_pc_off_pulses_at_exactly_3000ms_not_on_release() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (10_000, Press, NONE),
                (12_999, Tick, NONE),
                (13_000, Tick, CLOSE),
                (13_200, Tick, NONE),
                (13_499, Tick, NONE),
                (13_500, Tick, OPEN),
                (14_000, Release, NONE),
                (15_000, Tick, NONE),
            ],
        );
        assert!(c.pc_on(Timestamp::from_millis(15_000), &PARAMS));
    }

    #[test]
    fn release_at_2900ms_confirms_and_does_not_pulse() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (2_000, Tick, NONE),
                (2_900, Release, CONFIRM),
                (3_000, Tick, NONE),
                (10_000, Tick, NONE),
            ],
        );
        assert!(!c.pc_on(Timestamp::from_millis(10_000), &PARAMS));
    }

    #[test]
    fn very_short_press_confirms() {
        let mut c = fresh();
        run(&mut c, &[(500, Press, NONE), (580, Release, CONFIRM)]);
    }

    #[test]
    fn hold_8s_with_pc_on_pulses_at_8000ms() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Hb, NONE),
                (0, Press, NONE),
                (2_000, Hb, NONE),
                (3_000, Tick, NONE), // start_PC reached, PC on: nothing
                (4_000, Hb, NONE),
                (6_000, Hb, NONE),
                (7_999, Tick, NONE),
                (8_000, Tick, CLOSE),
                (8_000, Hb, NONE),
                (8_499, Tick, NONE),
                (8_500, Tick, OPEN),
                (9_000, Release, NONE),
            ],
        );
    }

    #[test]
    fn hold_3s_with_pc_on_does_nothing_and_does_not_confirm() {
        let mut c = fresh();
        with_heartbeats(&mut c, 10_000);
        run(
            &mut c,
            &[
                (10_500, Press, NONE),
                (13_500, Tick, NONE),
                (14_000, Release, NONE),
                (20_000, Tick, NONE),
            ],
        );
    }

    #[test]
    fn holding_on_past_8s_after_switching_on_does_not_switch_off_again() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (3_000, Tick, CLOSE),
                (3_500, Tick, OPEN),
                (5_000, Hb, NONE), // a fast PC already sends heartbeats
                (7_000, Hb, NONE),
                (8_000, Tick, NONE),
                (9_000, Hb, NONE),
                (20_000, Tick, NONE),
                (20_100, Release, NONE),
            ],
        );
    }

    #[test]
    fn second_3s_press_during_boot_grace_does_nothing() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (3_000, Tick, CLOSE),
                (3_100, Release, NONE),
                (3_500, Tick, OPEN),
                // No heartbeat yet: the PC is still booting.
                (20_000, Press, NONE),
                (23_000, Tick, NONE),
                (23_500, Release, NONE),
            ],
        );
        assert!(c.pc_on(Timestamp::from_millis(23_500), &PARAMS));
    }

    #[test]
    fn hold_8s_during_boot_grace_switches_the_pc_off() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (3_000, Tick, CLOSE),
                (3_100, Release, NONE),
                (3_500, Tick, OPEN),
                (20_000, Press, NONE),
                (23_000, Tick, NONE),
                (28_000, Tick, CLOSE),
                (28_500, Tick, OPEN),
                (29_000, Release, NONE),
            ],
        );
        // No heartbeat ever came, so without the grace nothing keeps it "on".
        assert!(!c.pc_on(Timestamp::from_millis(29_000), &PARAMS));
    }

    #[test]
    fn boot_grace_keeps_the_pc_on_until_it_ends_without_heartbeats() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (3_000, Tick, CLOSE),
                (3_100, Release, NONE),
                (3_500, Tick, OPEN),
            ],
        );
        for (t, on) in [(3_000, true), (62_999, true), (63_000, false)] {
            assert_eq!(c.pc_on(Timestamp::from_millis(t), &PARAMS), on, "at {t} ms");
        }
        // Grace over without a heartbeat: the PC did not start; 3 s tries again.
        run(&mut c, &[(70_000, Press, NONE), (73_000, Tick, CLOSE)]);
    }

    #[test]
    fn heartbeats_keep_a_booted_pc_on_after_the_grace() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (3_000, Tick, CLOSE),
                (3_100, Release, NONE),
            ],
        );
        for t in (40_000..=80_000).step_by(2_000) {
            c.step(Timestamp::from_millis(t), Hb, &PARAMS);
        }
        assert!(c.pc_on(Timestamp::from_millis(84_999), &PARAMS));
        assert!(!c.pc_on(Timestamp::from_millis(85_000), &PARAMS));
    }

    #[test]
    fn heartbeat_lapse_turns_the_pc_off() {
        let mut c = fresh();
        assert!(!c.pc_on(Timestamp::from_millis(0), &PARAMS));
        run(&mut c, &[(1_000, Hb, NONE), (3_000, Hb, NONE)]);
        for (t, on) in [
            (3_000, true),
            (7_999, true),
            (8_000, false),
            (60_000, false),
        ] {
            assert_eq!(c.pc_on(Timestamp::from_millis(t), &PARAMS), on, "at {t} ms");
        }
        // Now off, a 3 s hold switches it on.
        run(&mut c, &[(9_000, Press, NONE), (12_000, Tick, CLOSE)]);
    }

    #[test]
    fn pc_switched_on_elsewhere_counts_as_on_from_its_first_heartbeat() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (1_000, Hb, NONE),
                (3_000, Tick, NONE),
                (3_500, Release, NONE),
            ],
        );
    }

    #[test]
    fn pc_dying_during_an_8s_hold_is_not_switched_back_on() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Hb, NONE),
                (1_000, Press, NONE),
                (2_000, Hb, NONE), // last heartbeat: off from 7 000 ms
                (4_000, Tick, NONE),
                (7_000, Tick, NONE),
                (9_000, Tick, NONE),
                (12_000, Release, NONE),
            ],
        );
    }

    #[test]
    fn after_a_shutdown_pulse_the_pc_counts_on_until_heartbeats_stop() {
        let mut c = fresh();
        with_heartbeats(&mut c, 8_000);
        run(
            &mut c,
            &[
                (8_500, Press, NONE),
                (10_000, Hb, NONE),
                (11_500, Tick, NONE),
                (12_000, Hb, NONE),
                (14_000, Hb, NONE),
                (16_000, Hb, NONE),
                (16_500, Tick, CLOSE),
                (17_000, Tick, OPEN),
                (17_100, Release, NONE),
                (18_000, Hb, NONE), // the OS is still shutting down
                (20_000, Hb, NONE), // last one
            ],
        );
        assert!(c.pc_on(Timestamp::from_millis(24_999), &PARAMS));
        assert!(!c.pc_on(Timestamp::from_millis(25_000), &PARAMS));
        // Gone quiet: the next 3 s press switches it on again.
        run(&mut c, &[(26_000, Press, NONE), (29_000, Tick, CLOSE)]);
    }

    #[test]
    fn another_8s_hold_resends_the_shutdown_pulse_to_a_pc_that_ignored_it() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Hb, NONE),
                (0, Press, NONE),
                (2_000, Hb, NONE),
                (3_000, Tick, NONE),
                (4_000, Hb, NONE),
                (6_000, Hb, NONE),
                (8_000, Tick, CLOSE),
                (8_000, Hb, NONE),
                (8_500, Tick, OPEN),
                (9_000, Release, NONE),
                // The PC keeps sending heartbeats: it ignored the request.
                (10_000, Hb, NONE),
                (10_000, Press, NONE),
                (12_000, Hb, NONE),
                (13_000, Tick, NONE),
                (14_000, Hb, NONE),
                (16_000, Hb, NONE),
                (18_000, Tick, CLOSE),
                (18_000, Hb, NONE),
                (18_500, Tick, OPEN),
                (19_000, Release, NONE),
            ],
        );
    }

    #[test]
    fn pulse_lasts_switch_pulse_ms() {
        for pulse_ms in [100u32, 500, 1_500] {
            let mut c = PowerControl::new();
            let params = Params {
                switch_pulse_ms: pulse_ms,
                ..PARAMS
            };
            let end = 3_000 + u64::from(pulse_ms);
            run_with(
                &mut c,
                &params,
                &[
                    (0, Press, NONE),
                    (3_000, Tick, CLOSE),
                    (end - 1, Tick, NONE),
                    (end, Tick, OPEN),
                ],
            );
        }
    }

    #[test]
    fn one_action_per_press_even_if_the_pc_goes_off_during_the_hold() {
        // Switched on at 3 s; the PC is "on" through the grace, so 8 s would be a
        // shutdown; but this press already acted.
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (3_000, Tick, CLOSE),
                (3_500, Tick, OPEN),
                (8_000, Tick, NONE),
                (70_000, Tick, NONE), // grace over, PC "off": still this press
                (73_000, Tick, NONE),
                (80_000, Release, NONE),
            ],
        );
    }

    #[test]
    fn a_missed_tick_is_caught_up_by_the_release() {
        let mut c = fresh();
        run(
            &mut c,
            &[
                (0, Press, NONE),
                (3_100, Release, CLOSE),
                (3_600, Tick, OPEN),
            ],
        );
    }

    #[test]
    fn duplicate_press_edge_keeps_the_original_start() {
        let mut c = fresh();
        run(
            &mut c,
            &[(0, Press, NONE), (2_000, Press, NONE), (3_000, Tick, CLOSE)],
        );
    }

    #[test]
    fn release_without_press_does_nothing() {
        let mut c = fresh();
        run(&mut c, &[(0, Release, NONE), (10, Tick, NONE)]);
    }

    #[derive(Debug, Clone, Copy)]
    enum Input {
        Press,
        Release,
        Heartbeat,
        Tick,
    }

    fn input() -> impl Strategy<Value = (u64, Input)> {
        (
            1u64..3_000,
            prop_oneof![
                Just(Input::Press),
                Just(Input::Release),
                Just(Input::Heartbeat),
                Just(Input::Tick),
                Just(Input::Tick),
            ],
        )
    }

    proptest! {
        #[test]
        fn at_most_one_pulse_per_press_and_every_pulse_ends(
            inputs in proptest::collection::vec(input(), 1..200),
        ) {
            let mut c = fresh();
            let mut t = 0u64;
            let mut closes_this_press = 0u32;
            let mut closed_at: Option<u64> = None;
            for (gap, input) in inputs {
                t += gap;
                let event = match input {
                    Input::Press => Press,
                    Input::Release => Release,
                    Input::Heartbeat => Hb,
                    Input::Tick => Tick,
                };
                if matches!(event, Event::ButtonPressed)
                    && c.state().button == ButtonState::Released
                {
                    closes_this_press = 0;
                }
                let out = c.step(Timestamp::from_millis(t), event, &PARAMS);
                match out.switch {
                    Some(SwitchLevel::Closed) => {
                        closes_this_press += 1;
                        closed_at = Some(t);
                    }
                    Some(SwitchLevel::Open) => {
                        let since = closed_at.take();
                        prop_assert!(since.is_some(), "opened without a pulse at {} ms", t);
                        prop_assert!(t - since.unwrap_or(t) >= u64::from(PARAMS.switch_pulse_ms));
                    }
                    None => {}
                }
                prop_assert!(closes_this_press <= 1, "second pulse in one press at {} ms", t);
                if let Some(since) = closed_at {
                    // Still closed only while the pulse lasts.
                    prop_assert!(t - since < u64::from(PARAMS.switch_pulse_ms));
                }
                prop_assert!(!(out.confirm && out.switch == Some(SwitchLevel::Closed)));
            }
        }
    }
}
