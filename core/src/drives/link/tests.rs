//! Table tests of the drive link: every transition of the diagram in the module
//! documentation, as rows of (time, what the line did) → (next request or wait, reports).
//!
//! A [`Bench`] plays both drives: it answers each request the way a drive with the
//! given alarm, share setup and feedback would, or stays silent, or garbles.

use super::*;
use crate::kinematics::WheelCommand;
use crate::modbus::{READ_HOLDING, READ_WRITE_MULTIPLE, WRITE_MULTIPLE, crc16};

const SETTINGS: DriveSettings = DriveSettings::DEFAULT;
const WRITE: u8 = WRITE_MULTIPLE;
const READ: u8 = READ_HOLDING;
const GROUP: u8 = 15;

/// What the line does with the request that is out, or what else happens.
#[derive(Debug, Clone, Copy)]
enum Line {
    /// Both drives as set up: each answers correctly.
    Answer,
    /// No byte comes back.
    Silent,
    /// A reply with a broken CRC.
    Garbled,
    /// The wait's moment came.
    Timer,
    /// The controller's new demand.
    Demand(DriveDemand),
}

/// What the link must do next: send (address, function, start register), wait until
/// a moment, or carry on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Then {
    Send(u8, u8, u16),
    WaitUntil(u64),
    CarryOn,
}

use Line::{Answer, Garbled, Silent, Timer};
use Then::{CarryOn, Send, WaitUntil};

struct Bench {
    link: DriveLink,
    settings: DriveSettings,
    /// The request that is out.
    out: Option<Request>,
    /// Present alarm of each drive; `alarm_after_reset` is what stays after a reset.
    alarm: [u32; 2],
    alarm_after_reset: [u32; 2],
    /// Whether each drive still has its share setup (it loses it on a power cycle).
    configured: [bool; 2],
    /// Each drive's share read items in 17h replies: position, speed, alarm, comm error.
    feedback: [[u32; 4]; 2],
}

impl Bench {
    fn boot_at(now: u64, settings: DriveSettings) -> (Self, Effects) {
        let (link, effects) = DriveLink::boot(at(now), &settings);
        let mut bench = Self {
            link,
            settings,
            out: None,
            alarm: [0; 2],
            alarm_after_reset: [0; 2],
            configured: [true; 2],
            feedback: [[0; 4]; 2],
        };
        bench.remember(&effects);
        (bench, effects)
    }

    fn boot() -> Self {
        Self::boot_at(0, SETTINGS).0
    }

    fn remember(&mut self, effects: &Effects) {
        match &effects.next {
            Some(Next::Send(request)) => self.out = Some(request.clone()),
            Some(Next::WaitUntil(_)) => self.out = None,
            None => {}
        }
    }

    fn step(&mut self, now: u64, line: Line) -> Effects {
        let reply;
        let event = match line {
            Answer => {
                reply = self.reply();
                Event::Reply(Ok(&reply[..]))
            }
            Silent => Event::Reply(Err(TransferError::NoReply)),
            Garbled => {
                reply = {
                    let mut bytes = self.reply();
                    let last = bytes.len() - 1;
                    bytes[last] ^= 0xFF;
                    bytes
                };
                Event::Reply(Ok(&reply[..]))
            }
            Timer => Event::Timer,
            Line::Demand(demand) => Event::Demand(demand),
        };
        let effects = self.link.step(at(now), event, &self.settings);
        self.remember(&effects);
        effects
    }

    /// Runs `rows` of (time, line) → (then, reports) and checks each.
    fn run(&mut self, rows: &[(u64, Line, Then, &[Input])]) {
        for (row, &(now, line, then, reports)) in rows.iter().enumerate() {
            let effects = self.step(now, line);
            assert_eq!(
                describe(&effects.next),
                then,
                "row {row}: {line:?} at {now} ms, state now {:?}",
                self.link.state()
            );
            assert_eq!(effects.reports[..], reports[..], "row {row}: reports");
        }
    }

    /// Answers up to the cycle: one hold round, the setups, the group check.
    fn set_up(&mut self, now: u64) -> Effects {
        for _ in 0..40 {
            let effects = self.step(now, Answer);
            if matches!(self.link.state(), State::Writing { .. }) {
                return effects;
            }
        }
        panic!("no cycle after 40 answers: {:?}", self.link.state());
    }

    /// A bench whose drives are set up at 1000 ms, its first exchange out.
    fn cycling() -> Self {
        let mut bench = Self::boot();
        // The boot round, before the power-up wait: then the pause.
        for _ in 0..6 {
            bench.step(0, Answer);
        }
        bench.step(1_000, Timer);
        bench.set_up(1_000);
        bench
    }

    /// The drives' alarm reset: what stays is `alarm_after_reset`.
    fn reset_alarms(&mut self) {
        self.alarm = self.alarm_after_reset;
    }

    /// What is out, as a row's `Then`.
    fn out(&self) -> Then {
        describe(&self.out.clone().map(Next::Send))
    }

    fn request(&self) -> &Request {
        self.out.as_ref().expect("a request is out")
    }

    /// The reply a drive (or the group) would send to the request that is out.
    fn reply(&self) -> std::vec::Vec<u8> {
        let request = &self.request().frame;
        let (address, function) = (request[0], request[1]);
        let start = u16::from_be_bytes([request[2], request[3]]);
        let index = usize::from(address.saturating_sub(1)).min(1);
        match (address, function) {
            (GROUP, READ_HOLDING) => self.share_reply(READ_HOLDING),
            (GROUP, READ_WRITE_MULTIPLE) => self.share_reply(READ_WRITE_MULTIPLE),
            (_, WRITE_MULTIPLE) => with_crc(request[..6].to_vec()),
            (_, READ_HOLDING) => {
                let values: std::vec::Vec<u32> = match start {
                    reg::PRESENT_ALARM => {
                        vec![self.alarm[index]]
                    }
                    reg::SHARE_CONTROL if self.configured[index] => {
                        vec![u32::from(GROUP), 2, index as u32 + 1]
                    }
                    reg::SHARE_CONTROL => vec![0, 0, 0],
                    other => panic!("a read of {other:#x} the bench does not know"),
                };
                let mut body = vec![address, READ_HOLDING, 4 * values.len() as u8];
                for value in values {
                    body.extend_from_slice(&value.to_be_bytes());
                }
                with_crc(body)
            }
            other => panic!("a request the bench does not know: {other:?}"),
        }
    }

    /// A share group reply: each member's items asked for, followed by the CRC so far.
    fn share_reply(&self, function: u8) -> std::vec::Vec<u8> {
        let request = &self.request().frame;
        // Two registers per item, one more per member for its check word.
        let first = usize::from(u16::from_be_bytes([request[2], request[3]]) / 2);
        let count = usize::from(u16::from_be_bytes([request[4], request[5]]));
        let items = (count / 2 - 1) / 2;
        let mut reply = vec![GROUP, function, 2 * (4 * items as u8 + 2)];
        for member in self.feedback {
            for value in &member[first..first + items] {
                reply.extend_from_slice(&value.to_be_bytes());
            }
            reply = with_crc(reply);
        }
        reply
    }
}

fn with_crc(mut body: std::vec::Vec<u8>) -> std::vec::Vec<u8> {
    let crc = crc16(&body);
    body.extend_from_slice(&crc.to_le_bytes());
    body
}

fn at(ms: u64) -> Timestamp {
    Timestamp::from_millis(ms)
}

fn describe(next: &Option<Next>) -> Then {
    match next {
        None => CarryOn,
        Some(Next::WaitUntil(at)) => WaitUntil(at.as_millis()),
        Some(Next::Send(request)) => {
            let frame = &request.frame;
            Send(frame[0], frame[1], u16::from_be_bytes([frame[2], frame[3]]))
        }
    }
}

fn demand(rpm: i32, excite: bool, setup_requests: u32) -> DriveDemand {
    DriveDemand {
        wheels: WheelCommand {
            rpm: MotorRpm {
                left: rpm,
                right: -rpm,
            },
            left_accel: 700,
            right_accel: 700,
        },
        excite,
        setup_requests,
        cycle_ms: 50,
        stop_decel: 4_500,
        feedback_due_at: None,
    }
}

/// The 32-bit items of a unicast write request (FC 10h).
fn written_items(request: &Request) -> std::vec::Vec<u32> {
    let frame = &request.frame;
    frame[7..frame.len() - 2]
        .chunks(4)
        .map(|item| u32::from_be_bytes([item[0], item[1], item[2], item[3]]))
        .collect()
}

/// The speeds of a command write to the group: member 1's and member 2's first item.
fn command_speeds(request: &Request) -> (i32, i32) {
    let items = written_items(request);
    let per_member = reg::SHARE_WRITE_LIST.len();
    (items[0] as i32, items[per_member] as i32)
}

const HOLD_LEFT: [Then; 3] = [
    Send(1, WRITE, reg::DDO_OPERATION_TYPE),
    Send(1, WRITE, reg::DDO_TRIGGER),
    Send(1, WRITE, reg::DRIVER_INPUT_COMMAND),
];
const HOLD_RIGHT_ZERO: Then = Send(2, WRITE, reg::DDO_OPERATION_TYPE);
const COMMAND: Then = Send(GROUP, WRITE, 0);
const BLIND_ZERO: Then = Send(0, WRITE, reg::DDO_OPERATION_TYPE);
const READ_FEEDBACK: Then = Send(GROUP, READ, 0);
/// The alarm part of the feedback read: item 2 of the share read list.
const READ_ALARMS: Then = Send(GROUP, READ, 4);
const BROADCAST_ZERO: Then = Send(0, WRITE, reg::DDO_SPEED);

#[test]
fn the_first_request_after_boot_is_zero_speed_with_stop_decel_to_the_left_drive() {
    let (bench, effects) = Bench::boot_at(0, SETTINGS);
    assert_eq!(describe(&effects.next), HOLD_LEFT[0]);
    assert!(effects.reports.is_empty());
    // Operation type, position, speed 0, estop_decel twice (the register default).
    assert_eq!(written_items(bench.request()), [16, 0, 0, 4_500, 4_500]);
}

#[test]
fn a_hold_round_writes_zero_trigger_and_s_off_to_each_drive_then_pauses_before_the_power_up_wait() {
    let mut bench = Bench::boot();
    bench.run(&[
        (5, Answer, HOLD_LEFT[1], &[]),
        (10, Answer, HOLD_LEFT[2], &[]),
        (15, Answer, HOLD_RIGHT_ZERO, &[]),
        (20, Answer, Send(2, WRITE, reg::DDO_TRIGGER), &[]),
        (25, Answer, Send(2, WRITE, reg::DRIVER_INPUT_COMMAND), &[]),
        // Both answered, but the drives had no 1000 ms to power up yet.
        (30, Answer, WaitUntil(80), &[]),
        (230, Timer, HOLD_LEFT[0], &[]),
    ]);
    assert_eq!(written_items(bench.request()), [16, 0, 0, 4_500, 4_500]);
}

#[test]
fn a_silent_drive_is_skipped_and_the_answering_one_is_still_held() {
    let mut bench = Bench::boot();
    bench.run(&[
        (5, Silent, HOLD_RIGHT_ZERO, &[]),
        (10, Answer, Send(2, WRITE, reg::DDO_TRIGGER), &[]),
        (15, Answer, Send(2, WRITE, reg::DRIVER_INPUT_COMMAND), &[]),
        (20, Answer, WaitUntil(70), &[]),
    ]);
}

#[test]
fn a_garbled_hold_reply_is_counted_and_the_round_goes_on_with_the_next_drive() {
    let mut bench = Bench::boot();
    bench.run(&[
        (5, Answer, HOLD_LEFT[1], &[]),
        (10, Garbled, HOLD_RIGHT_ZERO, &[Input::ModbusError]),
    ]);
}

#[test]
fn a_new_demand_ends_the_pause_at_once_and_its_stop_decel_is_used() {
    let mut bench = Bench::boot();
    for _ in 0..6 {
        bench.step(0, Answer);
    }
    let mut gentler = demand(0, false, 0);
    gentler.stop_decel = 2_000;
    bench.run(&[(40, Line::Demand(gentler), HOLD_LEFT[0], &[])]);
    assert_eq!(written_items(bench.request()), [16, 0, 0, 2_000, 2_000]);
}

#[test]
fn after_the_power_up_wait_both_answering_starts_the_setup_of_the_left_drive() {
    let mut bench = Bench::boot();
    for _ in 0..6 {
        bench.step(0, Answer);
    }
    bench.run(&[
        (1_000, Timer, HOLD_LEFT[0], &[]),
        (1_000, Answer, HOLD_LEFT[1], &[]),
        (1_000, Answer, HOLD_LEFT[2], &[]),
        (1_000, Answer, HOLD_RIGHT_ZERO, &[]),
        (1_000, Answer, Send(2, WRITE, reg::DDO_TRIGGER), &[]),
        (
            1_000,
            Answer,
            Send(2, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
        (1_000, Answer, Send(1, WRITE, reg::SHARE_CONTROL), &[]),
    ]);
    assert_eq!(written_items(bench.request()), [15, 2, 1]);
}

#[test]
fn a_drive_silent_after_the_power_up_wait_is_reported_once_after_n_rounds() {
    let (mut bench, _) = Bench::boot_at(1_000, SETTINGS);
    let right_silent_round = |now: u64| -> [(u64, Line, Then, &'static [Input]); 4] {
        [
            (now, Answer, HOLD_LEFT[1], &[]),
            (now, Answer, HOLD_LEFT[2], &[]),
            (now, Answer, HOLD_RIGHT_ZERO, &[]),
            (now, Silent, WaitUntil(now + 50), &[]),
        ]
    };
    // The power-up wait ends at 2000 ms.
    bench.run(&right_silent_round(1_000));
    bench.run(&[(1_200, Timer, HOLD_LEFT[0], &[])]);
    bench.run(&right_silent_round(2_000)[..3]);
    bench.run(&[(2_000, Silent, WaitUntil(2_050), &[])]);
    bench.run(&[(2_200, Timer, HOLD_LEFT[0], &[])]);
    bench.run(&right_silent_round(2_200)[..3]);
    bench.run(&[(2_200, Silent, WaitUntil(2_250), &[])]);
    bench.run(&[(2_400, Timer, HOLD_LEFT[0], &[])]);
    bench.run(&right_silent_round(2_400)[..3]);
    bench.run(&[(
        2_400,
        Silent,
        WaitUntil(2_450),
        &[Input::DriveSilent(Wheel::Right)],
    )]);
    // Reported once, not every round.
    bench.run(&[(2_600, Timer, HOLD_LEFT[0], &[])]);
    bench.run(&right_silent_round(2_600)[..3]);
    bench.run(&[(2_600, Silent, WaitUntil(2_650), &[])]);
}

#[test]
fn the_setup_writes_share_control_lists_comm_timeout_checks_the_alarm_and_leaves_s_off() {
    let mut bench = Bench::boot();
    for _ in 0..6 {
        bench.step(0, Answer);
    }
    bench.step(1_000, Timer);
    for _ in 0..6 {
        bench.step(1_000, Answer);
    }
    bench.run(&[
        (1_001, Answer, Send(1, WRITE, reg::SHARE_LISTS), &[]),
        (1_002, Answer, Send(1, WRITE, reg::COMM_TIMEOUT), &[]),
    ]);
    assert_eq!(written_items(bench.request()), [150]);
    bench.run(&[
        (1_003, Answer, Send(1, READ, reg::PRESENT_ALARM), &[]),
        (
            1_004,
            Answer,
            Send(1, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
    ]);
    assert_eq!(written_items(bench.request()), [0]);
    bench.run(&[
        (1_005, Answer, Send(2, WRITE, reg::SHARE_CONTROL), &[]),
        (1_006, Answer, Send(2, WRITE, reg::SHARE_LISTS), &[]),
        (1_007, Answer, Send(2, WRITE, reg::COMM_TIMEOUT), &[]),
        (1_008, Answer, Send(2, READ, reg::PRESENT_ALARM), &[]),
        (
            1_009,
            Answer,
            Send(2, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
        (1_010, Answer, Send(GROUP, READ, 0), &[]),
        // The group answers: ready, and the first command goes out at once, at zero.
        (1_011, Answer, COMMAND, &[Input::DrivesReady]),
    ]);
    assert_eq!(command_speeds(bench.request()), (0, 0));
}

/// Settings the firmware refuses (here the drives' timeout off, and one beyond its
/// range) never get the drives set up: the link holds them round after round, stopped
/// and de-excited, and reports nothing that would make the base ready.
#[test]
fn with_refused_settings_the_drives_are_held_and_never_set_up() {
    for timeout_ms in [0, 181] {
        let settings = DriveSettings {
            drive_comm_timeout_ms: timeout_ms,
            ..SETTINGS
        };
        let (mut bench, _) = Bench::boot_at(0, settings);
        let mut now = 0;
        while now < 5_000 {
            let line = if bench.out.is_some() { Answer } else { Timer };
            let effects = bench.step(now, line);
            assert!(effects.reports.is_empty(), "{timeout_ms} ms: {effects:?}");
            if let Some(request) = &bench.out {
                let register = u16::from_be_bytes([request.frame[2], request.frame[3]]);
                assert!(
                    [
                        reg::DDO_OPERATION_TYPE,
                        reg::DDO_TRIGGER,
                        reg::DRIVER_INPUT_COMMAND
                    ]
                    .contains(&register),
                    "{timeout_ms} ms: only holds, not {register:#06x} at {now} ms"
                );
            }
            now += 5;
        }
        assert!(
            matches!(
                bench.link.state(),
                State::Holding { .. } | State::HoldPause { .. }
            ),
            "{timeout_ms} ms: {:?}",
            bench.link.state()
        );
        assert!(bench.link.brakes_confirmed(), "the holds' S-OFF answered");
    }
}

/// A bench at boot + 1000 ms whose left drive's present-alarm read is out.
fn at_the_left_alarm_read(alarm: u32, after_reset: u32) -> Bench {
    let mut bench = Bench::boot();
    bench.alarm = [alarm, 0];
    bench.alarm_after_reset = [after_reset, 0];
    for _ in 0..9 {
        bench.step(1_000, Answer);
    }
    assert_eq!(bench.out(), Send(1, READ, reg::PRESENT_ALARM));
    bench
}

#[test]
fn an_alarm_found_in_the_setup_is_reset_with_a_rising_edge_and_read_again() {
    let mut bench = at_the_left_alarm_read(0x85, 0);
    bench.run(&[(1_000, Answer, Send(1, WRITE, reg::ALARM_RESET), &[])]);
    assert_eq!(written_items(bench.request()), [1]);
    bench.run(&[(1_000, Answer, Send(1, WRITE, reg::ALARM_RESET), &[])]);
    assert_eq!(written_items(bench.request()), [0]);
    bench.reset_alarms();
    bench.run(&[
        (1_000, Answer, Send(1, READ, reg::PRESENT_ALARM), &[]),
        (
            1_000,
            Answer,
            Send(1, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
    ]);
}

#[test]
fn an_alarm_that_stays_after_the_reset_is_reported_and_the_setup_waits_a_poll_interval() {
    let mut bench = at_the_left_alarm_read(0x85, 0x30);
    bench.step(1_000, Answer);
    bench.step(1_000, Answer);
    bench.reset_alarms();
    bench.run(&[
        (1_000, Answer, Send(1, READ, reg::PRESENT_ALARM), &[]),
        // Reported as the alarm it is, not as a line error.
        (
            1_000,
            Answer,
            WaitUntil(1_050),
            &[Input::DriveAlarm {
                wheel: Wheel::Left,
                code: 0x30,
            }],
        ),
        // And held again before the next try.
        (1_200, Timer, HOLD_LEFT[0], &[]),
    ]);
}

#[test]
fn a_setup_step_that_fails_on_the_line_is_counted_and_retried_after_a_hold() {
    for step in 0..5 {
        let mut bench = Bench::boot();
        for _ in 0..6 + step {
            bench.step(1_000, Answer);
        }
        assert!(
            matches!(bench.link.state(), State::SettingUp { .. }),
            "{:?}",
            bench.link.state()
        );
        bench.run(&[
            (1_000, Silent, WaitUntil(1_050), &[Input::ModbusError]),
            (1_200, Timer, HOLD_LEFT[0], &[]),
        ]);
        let mut bench = Bench::boot();
        for _ in 0..6 + step {
            bench.step(1_000, Answer);
        }
        bench.run(&[(1_000, Garbled, WaitUntil(1_050), &[Input::ModbusError])]);
    }
}

#[test]
fn a_group_that_does_not_answer_the_check_fails_the_setup() {
    let mut bench = Bench::boot();
    for _ in 0..6 + 10 {
        bench.step(1_000, Answer);
    }
    assert_eq!(bench.link.state(), State::CheckingGroup);
    bench.run(&[
        (1_000, Silent, WaitUntil(1_050), &[Input::ModbusError]),
        (1_200, Timer, HOLD_LEFT[0], &[]),
    ]);
}

fn feedback_of(bench: &Bench) -> Input {
    let [left, right] = bench.feedback;
    Input::DriveFeedback {
        counts: EncoderCounts {
            left: left[0] as i32,
            right: right[0] as i32,
        },
        rpm: MotorRpm {
            left: left[1] as i32,
            right: right[1] as i32,
        },
    }
}

#[test]
fn the_cycle_reads_the_feedback_once_per_loop_end_delay_and_reports_it() {
    let mut bench = Bench::cycling();
    bench.feedback = [
        [1_000, 30, 0, 0],
        [(-1_000i32) as u32, (-30i32) as u32, 0, 0],
    ];
    let feedback = feedback_of(&bench);
    bench.run(&[
        // The first command (zero) was written; the first read follows at once.
        (1_002, Answer, READ_FEEDBACK, &[]),
        (1_004, Answer, READ_ALARMS, &[feedback]),
        (1_004, Answer, WaitUntil(1_050), &[]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        // A late reply does not shift the schedule.
        (1_060, Answer, READ_ALARMS, &[feedback]),
        (1_062, Answer, WaitUntil(1_100), &[]),
        (1_100, Timer, READ_FEEDBACK, &[]),
        // A stall: the next read goes out at once and the schedule restarts from it.
        (1_180, Answer, READ_ALARMS, &[feedback]),
        (1_182, Answer, READ_FEEDBACK, &[]),
        (1_184, Answer, READ_ALARMS, &[feedback]),
        (1_185, Answer, WaitUntil(1_230), &[]),
    ]);
}

/// The old rule "a new demand sends a cycle at once" moved the next cycle a full period
/// on with every demand: a PC changing its speed every 20 ms pushed the cycle seconds
/// ahead, the line went quiet when it stopped, and the drives' timeout tripped.
#[test]
fn commands_at_any_rate_go_out_at_once_and_never_move_the_read() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.step(1_005, Line::Demand(demand(0, true, 0)));
    bench.step(1_006, Answer);
    // Excited at 1007, settled from 1057; the zero with the new rates is written.
    bench.step(1_007, Answer);
    bench.step(1_008, Answer);
    let feedback = feedback_of(&bench);
    let mut next_read = 1_050;
    // A new speed every 20 ms (100 and 110 in turn) for a second.
    for k in 0..50 {
        let now = 1_065 + 20 * k;
        if now >= next_read {
            bench.run(&[
                (next_read, Timer, READ_FEEDBACK, &[]),
                (next_read + 2, Answer, READ_ALARMS, &[feedback]),
                (next_read + 3, Answer, WaitUntil(next_read + 50), &[]),
            ]);
            next_read += 50;
        }
        let rpm = if k % 2 == 0 { 100 } else { 110 };
        bench.run(&[(now, Line::Demand(demand(rpm, true, 0)), COMMAND, &[])]);
        assert_eq!(command_speeds(bench.request()), (rpm, -rpm));
        bench.run(&[(now + 2, Answer, WaitUntil(next_read), &[])]);
    }
    // After the last command the reads go on at their period.
    assert_eq!(next_read, 2_050);
    bench.run(&[
        (2_050, Timer, READ_FEEDBACK, &[]),
        (2_052, Answer, READ_ALARMS, &[feedback]),
        (2_052, Answer, WaitUntil(2_100), &[]),
    ]);
}

#[test]
fn a_new_alarm_in_the_cycle_is_reported_once() {
    let mut bench = Bench::cycling();
    bench.feedback[1][2] = 0x30;
    bench.step(1_002, Answer);
    bench.run(&[
        (1_004, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (
            1_005,
            Answer,
            WaitUntil(1_050),
            &[Input::DriveAlarm {
                wheel: Wheel::Right,
                code: 0x30,
            }],
        ),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_052, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_053, Answer, WaitUntil(1_100), &[]),
    ]);
}

#[test]
fn a_new_demand_goes_out_at_once_and_waits_for_the_settle_after_s_on() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.run(&[
        // Excite and drive: S-ON to both first.
        (
            1_010,
            Line::Demand(demand(600, true, 0)),
            Send(1, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
    ]);
    assert_eq!(written_items(bench.request()), [reg::S_ON]);
    bench.run(&[
        (
            1_012,
            Answer,
            Send(2, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
        // Excited at 1014: zero (with the new rates) until 1064.
        (1_014, Answer, COMMAND, &[]),
    ]);
    assert_eq!(command_speeds(bench.request()), (0, 0));
    assert!(bench.link.excited());
    // The read keeps its moment; the held-back speed goes out at the settle.
    bench.run(&[
        (1_016, Answer, WaitUntil(1_050), &[]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_052, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_052, Answer, WaitUntil(1_064), &[]),
        (1_064, Timer, COMMAND, &[]),
    ]);
    assert_eq!(command_speeds(bench.request()), (600, -600));
    // Once written, the same demand again writes nothing.
    bench.run(&[
        (1_066, Answer, WaitUntil(1_100), &[]),
        (
            1_070,
            Line::Demand(demand(600, true, 0)),
            WaitUntil(1_100),
            &[],
        ),
    ]);
}

#[test]
fn a_command_that_comes_while_the_read_is_out_goes_out_right_after_it() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.run(&[
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_051, Line::Demand(demand(0, false, 0)), CarryOn, &[]),
        // The command goes before the alarm part of the read.
        (1_053, Answer, COMMAND, &[feedback_of(&bench)]),
        (1_055, Answer, READ_ALARMS, &[]),
        (1_057, Answer, WaitUntil(1_100), &[]),
    ]);
}

#[test]
fn dropping_the_excitation_writes_s_off_to_both_before_the_command() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.step(1_010, Line::Demand(demand(0, true, 0)));
    bench.step(1_010, Answer);
    bench.step(1_010, Answer);
    bench.step(1_012, Answer);
    bench.run(&[(
        1_020,
        Line::Demand(demand(0, false, 0)),
        Send(1, WRITE, reg::DRIVER_INPUT_COMMAND),
        &[],
    )]);
    assert_eq!(written_items(bench.request()), [0]);
    bench.run(&[
        (
            1_022,
            Answer,
            Send(2, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
        (1_024, Answer, WaitUntil(1_050), &[]),
    ]);
    assert!(!bench.link.excited());
}

#[test]
fn a_failed_s_on_write_is_retried_after_the_next_read_and_the_drives_stay_de_excited() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.step(1_010, Line::Demand(demand(600, true, 0)));
    bench.run(&[
        (
            1_012,
            Answer,
            Send(2, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
        (1_037, Silent, WaitUntil(1_050), &[Input::ModbusError]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_052, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        // Then both again.
        (
            1_054,
            Answer,
            Send(1, WRITE, reg::DRIVER_INPUT_COMMAND),
            &[],
        ),
    ]);
    assert!(!bench.link.excited());
}

#[test]
fn failed_reads_below_n_are_counted_and_a_good_one_clears_the_count() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.run(&[
        (1_027, Silent, WaitUntil(1_050), &[Input::ModbusError]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_075, Garbled, WaitUntil(1_100), &[Input::ModbusError]),
        (1_100, Timer, READ_FEEDBACK, &[]),
        (1_102, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_102, Answer, WaitUntil(1_150), &[]),
        (1_150, Timer, READ_FEEDBACK, &[]),
        (1_175, Silent, WaitUntil(1_200), &[Input::ModbusError]),
        (1_200, Timer, READ_FEEDBACK, &[]),
        (1_225, Silent, WaitUntil(1_250), &[Input::ModbusError]),
    ]);
}

/// Without replies an echo-based hold would never send its trigger, and its valid
/// frames would keep the drives' own timeout from ever tripping: the blind stop needs
/// no reply and ends in silence.
#[test]
fn the_nth_failed_read_stops_both_drives_blind_then_falls_silent() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.run(&[
        (1_027, Silent, WaitUntil(1_050), &[Input::ModbusError]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_075, Silent, WaitUntil(1_100), &[Input::ModbusError]),
        (1_100, Timer, READ_FEEDBACK, &[]),
        (1_125, Garbled, BLIND_ZERO, &[Input::ModbusError]),
    ]);
    blind_stop_from(&mut bench, 1_125);
    // Demands change nothing until the silence is over.
    bench.run(&[
        (1_400, Line::Demand(demand(600, true, 0)), CarryOn, &[]),
        (1_410, Timer, Send(1, READ, reg::SHARE_CONTROL), &[]),
    ]);
}

#[test]
fn the_nth_failed_command_write_stops_both_drives_blind_while_the_reads_pass() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    // Driving, excited.
    bench.step(1_010, Line::Demand(demand(600, true, 0)));
    bench.step(1_010, Answer);
    bench.step(1_010, Answer);
    bench.run(&[
        // The zero for the settle fails; the read goes first, then the write again.
        (1_035, Garbled, WaitUntil(1_050), &[Input::ModbusError]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_052, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_052, Answer, COMMAND, &[]),
        (1_077, Silent, WaitUntil(1_100), &[Input::ModbusError]),
        (1_100, Timer, READ_FEEDBACK, &[]),
        (1_102, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_102, Answer, COMMAND, &[]),
        (1_127, Silent, BLIND_ZERO, &[Input::ModbusError]),
    ]);
    blind_stop_from(&mut bench, 1_127);
}

/// A bench whose cycle failed N times; after the blind stop and the silence the left
/// drive's probe is out.
fn probing() -> Bench {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.run(&[
        (1_027, Silent, WaitUntil(1_050), &[Input::ModbusError]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_075, Silent, WaitUntil(1_100), &[Input::ModbusError]),
        (1_100, Timer, READ_FEEDBACK, &[]),
        (1_125, Silent, BLIND_ZERO, &[Input::ModbusError]),
    ]);
    blind_stop_from(&mut bench, 1_125);
    bench.run(&[(1_410, Timer, Send(1, READ, reg::SHARE_CONTROL), &[])]);
    assert_eq!(
        bench.link.state(),
        State::Probing {
            wheel: Wheel::Left,
            lost: false
        }
    );
    bench
}

/// The blind stop that starts at `since` with the first zero out: zero three times,
/// then silence for the drives' timeout (300 ms) and 100 ms more; the wait for it is
/// out at the end, at `since` + 435.
fn blind_stop_from(bench: &mut Bench, since: u64) {
    let fields = [16, 0, 0, 4_500, 4_500, 1_000, 1];
    assert_eq!(written_items(bench.request()), fields);
    bench.run(&[
        (since + 5, Answer, BLIND_ZERO, &[]),
        (since + 10, Answer, BLIND_ZERO, &[]),
        (since + 35, Silent, WaitUntil(since + 285), &[]),
    ]);
    assert!(!bench.link.excited());
}

#[test]
fn a_probe_that_finds_a_drive_silent_reports_that_drive_and_holds_until_a_setup_request() {
    let mut bench = probing();
    bench.run(&[
        (1_140, Answer, Send(2, READ, reg::SHARE_CONTROL), &[]),
        (
            1_165,
            Silent,
            HOLD_LEFT[0],
            &[Input::DriveSilent(Wheel::Right)],
        ),
    ]);
    for _ in 0..5 {
        bench.step(1_170, Answer);
    }
    bench.run(&[
        (1_170, Answer, WaitUntil(1_220), &[]),
        (1_370, Timer, HOLD_LEFT[0], &[]),
    ]);
}

#[test]
fn a_probe_that_finds_a_drive_without_its_share_setup_reports_it_lost() {
    let mut bench = probing();
    bench.configured[0] = false;
    bench.run(&[(
        1_140,
        Answer,
        Send(2, READ, reg::SHARE_CONTROL),
        &[Input::DriveSilent(Wheel::Left)],
    )]);
}

#[test]
fn a_garbled_probe_is_counted_and_the_drive_reported_lost() {
    let mut bench = probing();
    bench.run(&[(
        1_140,
        Garbled,
        Send(2, READ, reg::SHARE_CONTROL),
        &[Input::ModbusError, Input::DriveSilent(Wheel::Left)],
    )]);
}

#[test]
fn both_drives_answering_alone_while_the_group_fails_reports_both() {
    let mut bench = probing();
    bench.run(&[
        (1_140, Answer, Send(2, READ, reg::SHARE_CONTROL), &[]),
        (
            1_141,
            Answer,
            HOLD_LEFT[0],
            &[
                Input::DriveSilent(Wheel::Left),
                Input::DriveSilent(Wheel::Right),
            ],
        ),
    ]);
}

#[test]
fn drives_that_come_back_stay_held_until_the_controller_asks_for_a_setup() {
    let mut bench = probing();
    bench.step(1_140, Answer);
    bench.step(1_141, Answer);
    for round in 0..3 {
        let now = 1_141 + 200 * round;
        for _ in 0..5 {
            bench.step(now, Answer);
        }
        bench.run(&[
            (now, Answer, WaitUntil(now + 50), &[]),
            (now + 200, Timer, HOLD_LEFT[0], &[]),
        ]);
    }
    for _ in 0..5 {
        bench.step(1_741, Answer);
    }
    bench.step(1_741, Answer);
    // The recovery: a setup request ends the pause, and the setup follows the round.
    bench.run(&[(1_800, Line::Demand(demand(0, false, 1)), HOLD_LEFT[0], &[])]);
    for _ in 0..5 {
        bench.step(1_800, Answer);
    }
    bench.run(&[(1_800, Answer, Send(1, WRITE, reg::SHARE_CONTROL), &[])]);
}

#[test]
fn a_setup_request_while_cycling_ends_the_cycle_with_a_hold_and_a_new_setup() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.run(&[(1_010, Line::Demand(demand(0, false, 1)), HOLD_LEFT[0], &[])]);
    for _ in 0..5 {
        bench.step(1_010, Answer);
    }
    bench.run(&[(1_010, Answer, Send(1, WRITE, reg::SHARE_CONTROL), &[])]);
    bench.set_up(1_010);
    // Served: the next cycles go on.
    bench.run(&[
        (1_012, Answer, READ_FEEDBACK, &[]),
        (1_014, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_014, Answer, WaitUntil(1_060), &[]),
    ]);
}

#[test]
fn the_cycle_never_waits_longer_than_a_third_of_the_drives_comm_timeout() {
    let mut bench = Bench::cycling();
    let mut slow = demand(0, false, 0);
    slow.cycle_ms = 500;
    bench.step(1_002, Answer);
    bench.step(1_010, Line::Demand(slow));
    bench.run(&[
        (1_012, Answer, COMMAND, &[feedback_of(&bench)]),
        (1_014, Answer, READ_ALARMS, &[]),
        (1_016, Answer, WaitUntil(1_050), &[]),
    ]);
    // A third of the drives' 150 ms.
    assert_eq!(cycle_period_ms(500, &SETTINGS), 50);
    assert_eq!(cycle_period_ms(30, &SETTINGS), 30);
}

#[test]
fn a_demand_while_a_request_is_out_is_kept_for_the_next_request() {
    let mut bench = Bench::boot();
    let mut gentler = demand(0, false, 0);
    gentler.stop_decel = 2_000;
    bench.run(&[(1, Line::Demand(gentler), CarryOn, &[])]);
    bench.run(&[
        (2, Answer, HOLD_LEFT[1], &[]),
        (3, Answer, HOLD_LEFT[2], &[]),
    ]);
    bench.run(&[(4, Answer, HOLD_RIGHT_ZERO, &[])]);
    assert_eq!(written_items(bench.request()), [16, 0, 0, 2_000, 2_000]);
}

#[test]
fn a_timer_while_a_request_is_out_and_a_reply_while_waiting_change_nothing() {
    let mut bench = Bench::boot();
    bench.run(&[(1, Timer, CarryOn, &[])]);
    for _ in 0..6 {
        bench.step(2, Answer);
    }
    let waiting = bench.link.state();
    let effects = bench
        .link
        .step(at(3), Event::Reply(Ok(&[1, 2, 3])), &SETTINGS);
    assert_eq!(describe(&effects.next), CarryOn);
    assert!(effects.reports.is_empty());
    assert_eq!(bench.link.state(), waiting);
}

fn with_accel(accel: u32) -> DriveDemand {
    let mut demand = demand(0, false, 0);
    demand.wheels.left_accel = accel;
    demand.wheels.right_accel = accel;
    demand
}

#[test]
fn a_due_read_waits_for_one_write_at_most() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.run(&[
        (1_049, Line::Demand(with_accel(700)), COMMAND, &[]),
        (1_051, Line::Demand(with_accel(800)), CarryOn, &[]),
        // The read is due: one more command may go first, not two.
        (1_053, Answer, COMMAND, &[]),
        (1_054, Line::Demand(with_accel(900)), CarryOn, &[]),
        (1_055, Answer, READ_FEEDBACK, &[]),
        // The alarm part is due as well: one command may go before it.
        (1_057, Answer, COMMAND, &[feedback_of(&bench)]),
        (1_059, Answer, READ_ALARMS, &[]),
        (1_061, Answer, WaitUntil(1_100), &[]),
    ]);
}

#[test]
fn the_read_moves_to_half_a_cycle_before_the_controllers_position_frame() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    let mut timed = with_accel(700);
    timed.feedback_due_at = Some(at(1_130));
    bench.run(&[
        (1_003, Line::Demand(timed), CarryOn, &[]),
        (1_004, Answer, COMMAND, &[feedback_of(&bench)]),
        (1_006, Answer, READ_ALARMS, &[]),
        // Frames at 1080, 1130, ...: reads at 1055, 1105, ...
        (1_008, Answer, WaitUntil(1_055), &[]),
        (1_055, Timer, READ_FEEDBACK, &[]),
        (1_057, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_057, Answer, WaitUntil(1_105), &[]),
    ]);
    // A frame phase that moves is followed by at most half a cycle at a time.
    timed.feedback_due_at = Some(at(1_105));
    bench.run(&[
        (1_060, Line::Demand(timed), WaitUntil(1_105), &[]),
        (1_105, Timer, READ_FEEDBACK, &[]),
        (1_107, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_107, Answer, WaitUntil(1_130), &[]),
    ]);
}

/// Drives set up and excited at 1010 ms, then nothing answers any more: returns once
/// the blind stop fell silent, with the time.
fn excited_then_the_line_dies() -> (Bench, u64) {
    let (mut bench, _) = Bench::boot_at(0, SETTINGS);
    for _ in 0..6 {
        bench.step(0, Answer);
    }
    bench.step(1_000, Timer);
    bench.set_up(1_000);
    assert!(
        bench.link.brakes_confirmed(),
        "the setup's S-OFF was answered"
    );
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.step(1_010, Line::Demand(demand(600, true, 0)));
    assert!(!bench.link.brakes_confirmed(), "S-ON is out: unknown");
    bench.step(1_012, Answer);
    bench.step(1_014, Answer);
    assert!(bench.link.excited());
    for now in (1_020..3_000).step_by(5) {
        if let State::StoppingBlind {
            step: BlindStep::Silent,
            ..
        } = bench.link.state()
        {
            return (bench, now);
        }
        let line = if bench.out.is_some() { Silent } else { Timer };
        bench.step(now, line);
        assert!(!bench.link.brakes_confirmed(), "{now} ms: nothing answered");
    }
    panic!("no blind stop: {:?}", bench.link.state());
}

/// A drive that cannot be heard counts as excited, its wheel as turning, until its
/// own communication timeout has surely tripped.
#[test]
fn brakes_are_confirmed_by_an_answered_s_off_or_by_silence_beyond_the_drives_timeout() {
    let (mut bench, silent_at) = excited_then_the_line_dies();
    assert!(!bench.link.brakes_confirmed(), "silence only started");
    bench.step(silent_at + 250, Timer);
    assert!(
        bench.link.brakes_confirmed(),
        "every drive's 150 ms tripped"
    );
}

/// A bench whose drives run at 600 r/min (acknowledged) at 1066 ms, nothing out.
fn driving_at_600() -> Bench {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.step(1_010, Line::Demand(demand(600, true, 0)));
    bench.step(1_012, Answer);
    bench.step(1_014, Answer);
    bench.run(&[
        (1_016, Answer, WaitUntil(1_050), &[]),
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_052, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_053, Answer, WaitUntil(1_064), &[]),
        (1_064, Timer, COMMAND, &[]),
        (1_066, Answer, WaitUntil(1_100), &[]),
    ]);
    bench
}

fn emergency_zero() -> DriveDemand {
    let mut stop = demand(0, true, 0);
    stop.wheels.left_accel = 4_500;
    stop.wheels.right_accel = 3_000;
    stop
}

#[test]
fn an_emergency_zero_goes_out_first_by_broadcast_then_by_the_acknowledged_group_write() {
    let mut bench = driving_at_600();
    bench.run(&[(1_070, Line::Demand(emergency_zero()), BROADCAST_ZERO, &[])]);
    // Speed 0, both rates the stronger wheel's, torque limit 100 %, trigger.
    assert_eq!(written_items(bench.request()), [0, 4_500, 4_500, 1_000, 1]);
    bench.run(&[(1_071, Answer, COMMAND, &[])]);
    assert_eq!(command_speeds(bench.request()), (0, 0));
    // Each wheel's own rate in the group write.
    assert_eq!(written_items(bench.request())[1], 4_500);
    assert_eq!(written_items(bench.request())[5], 3_000);
    bench.run(&[
        (1_076, Answer, WaitUntil(1_100), &[]),
        // The same stop again sends nothing.
        (1_080, Line::Demand(emergency_zero()), WaitUntil(1_100), &[]),
    ]);
}

#[test]
fn an_emergency_zero_that_comes_during_the_read_goes_out_before_the_rest_of_the_feedback() {
    let mut bench = driving_at_600();
    bench.run(&[
        (1_100, Timer, READ_FEEDBACK, &[]),
        (1_101, Line::Demand(emergency_zero()), CarryOn, &[]),
        (1_102, Answer, BROADCAST_ZERO, &[feedback_of(&bench)]),
        // The acknowledged zero may go before the alarm part, as any one write.
        (1_103, Answer, COMMAND, &[]),
        (1_105, Answer, READ_ALARMS, &[]),
    ]);
}

/// Where a hand-over stop meets the e-stop (found by the whole-robot simulation
/// tester, seed 39): the drives already brake to zero at the PC's gentle rate when the
/// e-stop comes. The e-stop's rate goes out first, by broadcast, not after the feedback
/// read; and again at the next e-stop after another gentle zero.
#[test]
fn an_emergency_zero_after_a_gentle_zero_still_goes_out_first_by_broadcast() {
    let mut bench = driving_at_600();
    bench.run(&[
        (1_070, Line::Demand(demand(0, true, 0)), COMMAND, &[]),
        (1_072, Answer, WaitUntil(1_100), &[]),
        (1_080, Line::Demand(emergency_zero()), BROADCAST_ZERO, &[]),
        (1_081, Answer, COMMAND, &[]),
        (1_083, Answer, WaitUntil(1_100), &[]),
        (1_090, Line::Demand(demand(0, true, 0)), COMMAND, &[]),
        (1_092, Answer, WaitUntil(1_100), &[]),
        (1_095, Line::Demand(emergency_zero()), BROADCAST_ZERO, &[]),
    ]);
}

#[test]
fn a_stop_with_the_pcs_own_gentler_rate_is_an_ordinary_command() {
    let mut bench = driving_at_600();
    bench.run(&[(1_070, Line::Demand(demand(0, true, 0)), COMMAND, &[])]);
    assert_eq!(command_speeds(bench.request()), (0, 0));
}

#[test]
fn the_nth_failed_alarm_read_stops_both_drives_blind() {
    let mut bench = driving_at_600();
    bench.run(&[
        (1_100, Timer, READ_FEEDBACK, &[]),
        (1_102, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_127, Silent, WaitUntil(1_150), &[Input::ModbusError]),
        (1_150, Timer, READ_FEEDBACK, &[]),
        (1_152, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_177, Garbled, WaitUntil(1_200), &[Input::ModbusError]),
        (1_200, Timer, READ_FEEDBACK, &[]),
        (1_202, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_227, Silent, BLIND_ZERO, &[Input::ModbusError]),
    ]);
}

const RESET_ALARM_LEFT: Then = Send(1, WRITE, reg::ALARM_RESET);
const RESET_ALARM_RIGHT: Then = Send(2, WRITE, reg::ALARM_RESET);

/// A flash erase at rest stalls the chip (up to 400 ms) beyond the drives' timeout
/// (150 ms): both drives raise alarm 85h. The link's own silence caused it while both
/// drives were confirmed de-excited, so it resets the alarm and counts it.
#[test]
fn an_alarm_85h_after_the_links_own_stall_at_rest_is_reset_and_counted() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    assert!(bench.link.brakes_confirmed());
    bench.feedback[0][2] = reg::ALARM_COMM_TIMEOUT;
    bench.feedback[1][2] = reg::ALARM_COMM_TIMEOUT;
    bench.run(&[
        // The chip stalled from 1010 to 1400.
        (1_400, Timer, READ_FEEDBACK, &[]),
        (1_402, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (
            1_404,
            Answer,
            RESET_ALARM_LEFT,
            &[Input::ModbusError, Input::ModbusError],
        ),
    ]);
    assert_eq!(written_items(bench.request()), [1]);
    bench.run(&[(1_406, Answer, RESET_ALARM_LEFT, &[])]);
    assert_eq!(written_items(bench.request()), [0]);
    bench.feedback[0][2] = 0;
    bench.feedback[1][2] = 0;
    bench.run(&[
        (1_408, Answer, RESET_ALARM_RIGHT, &[]),
        (1_410, Answer, RESET_ALARM_RIGHT, &[]),
        (1_412, Answer, READ_FEEDBACK, &[]),
        (1_414, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_416, Answer, WaitUntil(1_452), &[]),
    ]);
}

#[test]
fn an_alarm_85h_that_stays_after_the_reset_is_reported() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.feedback[0][2] = reg::ALARM_COMM_TIMEOUT;
    bench.run(&[
        (1_400, Timer, READ_FEEDBACK, &[]),
        (1_402, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_404, Answer, RESET_ALARM_LEFT, &[Input::ModbusError]),
        (1_406, Answer, RESET_ALARM_LEFT, &[]),
        (1_408, Answer, READ_FEEDBACK, &[]),
        (1_410, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (
            1_412,
            Answer,
            WaitUntil(1_452),
            &[Input::DriveAlarm {
                wheel: Wheel::Left,
                code: 0x85,
            }],
        ),
    ]);
}

/// Without a stall, or with a drive that may turn, an alarm 85h is a fault like any.
#[test]
fn an_alarm_85h_without_a_stall_or_while_excited_is_reported() {
    let alarm = Input::DriveAlarm {
        wheel: Wheel::Right,
        code: 0x85,
    };
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.step(1_004, Answer);
    bench.feedback[1][2] = reg::ALARM_COMM_TIMEOUT;
    bench.run(&[
        (1_050, Timer, READ_FEEDBACK, &[]),
        (1_052, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_054, Answer, WaitUntil(1_100), &[alarm]),
    ]);

    let mut bench = driving_at_600();
    bench.feedback[1][2] = reg::ALARM_COMM_TIMEOUT;
    bench.run(&[
        (1_400, Timer, READ_FEEDBACK, &[]),
        (1_402, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_404, Answer, READ_FEEDBACK, &[alarm]),
    ]);
}

/// The stall may fall while the alarm read is out: its reply was read before the
/// drives tripped, so only the next alarm read can show what the stall caused.
#[test]
fn a_stall_during_the_alarm_read_excuses_the_next_alarm_read() {
    let mut bench = Bench::cycling();
    bench.step(1_002, Answer);
    bench.step(1_004, Answer);
    bench.run(&[
        // The alarm read went out at 1004; the chip stalled until 1400.
        (1_400, Answer, READ_FEEDBACK, &[]),
    ]);
    bench.feedback[0][2] = reg::ALARM_COMM_TIMEOUT;
    bench.run(&[
        (1_402, Answer, READ_ALARMS, &[feedback_of(&bench)]),
        (1_404, Answer, RESET_ALARM_LEFT, &[Input::ModbusError]),
    ]);
}
