//! The virtual drives seen from the master's side of the line: the frames of
//! docs/drives.md written to the port, the replies read back and checked
//! with the firmware's own parser.

use base_core::modbus::{
    self, READ_WRITE_MULTIPLE, ReplyError, ShareReply, parse_read, parse_share_reply,
    parse_write_echo,
};
use embassy_time::{Duration, Instant, Timer, with_timeout};
use embedded_io_async::{Read, Write};
use proptest::prelude::*;
use virtual_robot::drives::{DrivesConfig, DrivesHandle, DrivesPort, Mounting, Reversal};
use virtual_robot::runtime::{block_on, now};

const GID: u8 = 15;
const LEFT: u8 = 1;
const RIGHT: u8 = 2;
/// Share read list: detected position, detected speed, present alarm, comm error.
const READ_LIST: [u32; 4] = [102, 103, 64, 86];
/// Share write list: op type, speed, acceleration, deceleration, trigger.
const WRITE_LIST: [u32; 5] = [45, 47, 48, 49, 51];
const ITEMS: usize = 4;
const ALARM_SLOT: usize = 2;

fn share_lists() -> [u32; 24] {
    let mut lists = [0; 24];
    lists[..4].copy_from_slice(&READ_LIST);
    lists[12..17].copy_from_slice(&WRITE_LIST);
    lists
}

/// The DDO fields of the write list for a continuous operation.
fn command(speed_rpm: i32, accel: u32, decel: u32) -> [u32; 5] {
    [16, speed_rpm as u32, accel, decel, 1]
}

fn drives() -> (DrivesPort, DrivesHandle) {
    DrivesPort::new(DrivesConfig::default())
}

/// Reads until the line has been quiet for 1 ms (well above C3.5 at 115200), or
/// nothing came within 50 ms. Every byte with the instant it became readable.
async fn receive_timed(port: &mut DrivesPort) -> Vec<(Instant, u8)> {
    let mut reply = Vec::new();
    let mut buf = [0u8; 64];
    let mut timeout = Duration::from_millis(50);
    while let Ok(Ok(count)) = with_timeout(timeout, port.read(&mut buf)).await {
        let at = now();
        reply.extend(buf[..count].iter().map(|&byte| (at, byte)));
        timeout = Duration::from_millis(1);
    }
    reply
}

async fn send(port: &mut DrivesPort, request: &[u8]) {
    port.write_all(request).await.unwrap();
    port.flush().await.unwrap();
}

/// The bytes of [`receive_timed`], without their instants.
async fn receive(port: &mut DrivesPort) -> Vec<u8> {
    receive_timed(port)
        .await
        .into_iter()
        .map(|(_, byte)| byte)
        .collect()
}

async fn transact(port: &mut DrivesPort, request: &[u8]) -> Vec<u8> {
    send(port, request).await;
    receive(port).await
}

async fn write(port: &mut DrivesPort, slave: u8, start: u16, values: &[u32]) {
    let reply = transact(port, &modbus::write_items(slave, start, values)).await;
    let count = 2 * values.len() as u16;
    assert_eq!(parse_write_echo(&reply, slave, start, count), Ok(()));
}

/// The start-up sequence (docs/drives.md) after the boot time: share group, share lists, S-ON on both drives.
async fn set_up(port: &mut DrivesPort) {
    Timer::after(DrivesConfig::default().boot_time).await;
    for slave in [LEFT, RIGHT] {
        write(port, slave, 0x0980, &[u32::from(GID), 2, u32::from(slave)]).await;
        write(port, slave, 0x0990, &share_lists()).await;
        write(port, slave, 0x007C, &[1]).await;
    }
}

/// One FC 17h cycle (docs/drives.md): commands both wheels and returns the raw reply.
async fn cycle_raw(port: &mut DrivesPort, left: [u32; 5], right: [u32; 5]) -> Vec<u8> {
    let request = modbus::share_read_write(GID, 0, ITEMS as u16, 0, &[&left, &right]);
    transact(port, &request).await
}

async fn cycle(port: &mut DrivesPort, left: [u32; 5], right: [u32; 5]) -> ShareReply {
    let reply = cycle_raw(port, left, right).await;
    parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, 2, ITEMS).unwrap()
}

async fn read_alarm(port: &mut DrivesPort, slave: u8) -> Result<u32, ReplyError> {
    let reply = transact(port, &modbus::read_items(slave, 0x0080, 1)).await;
    parse_read(&reply, slave, 1).map(|values| values[0])
}

fn assert_close(actual: f64, expected: f64, tolerance: f64) {
    assert!(
        (actual - expected).abs() <= tolerance,
        "{actual} is not within {tolerance} of {expected}"
    );
}

#[test]
fn share_setup_then_read_write_cycle_answers_in_the_parsers_format() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        let reply = cycle_raw(
            &mut port,
            command(600, 1000, 1000),
            command(-600, 1000, 1000),
        )
        .await;
        assert_eq!(reply.len(), 41, "two members, check words and trailer");
        assert_eq!(
            &reply[39..],
            &[0, 0],
            "the trailer closes an already closed frame"
        );
        let share = parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, 2, ITEMS).unwrap();
        // The write runs before the read, so the motors have just started.
        assert_eq!(share.member(0), &[0, 0, 0, 0]);
        assert_eq!(share.member(1), &[0, 0, 0, 0]);
    });
    for slave in [LEFT, RIGHT] {
        let drive = handle.drive(slave);
        assert!(drive.servo_on);
        assert!(drive.share.is_member());
        assert_eq!(drive.share.global_id, u32::from(GID));
        assert_eq!(drive.share.local_id, u32::from(slave));
        assert_eq!(&drive.share.read_list[..4], &READ_LIST);
        assert_eq!(&drive.share.write_list[..5], &WRITE_LIST);
    }
    assert_eq!(handle.drive(LEFT).command.unwrap().speed_rpm, 600);
    assert_eq!(handle.drive(RIGHT).command.unwrap().speed_rpm, -600);
}

#[test]
fn share_write_is_echoed_and_share_read_returns_both_members() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        let left = command(300, 10_000, 10_000);
        let right = command(-300, 10_000, 10_000);
        let reply = transact(&mut port, &modbus::share_write(GID, 0, &[&left, &right])).await;
        assert_eq!(parse_write_echo(&reply, GID, 0, 20), Ok(()));
        Timer::after_secs(1).await;
        let reply = transact(&mut port, &modbus::share_read(GID, 0, ITEMS as u16, 2)).await;
        let share = parse_share_reply(&reply, GID, modbus::READ_HOLDING, 2, ITEMS).unwrap();
        assert_eq!(share.member(0)[1], 300);
        assert_eq!(share.member(1)[1], (-300i32) as u32);
        // 30 ms ramp, then 300 r/min = 180 000 counts/s until the read was taken.
        let applied = handle.drive(LEFT).last_command_at.unwrap();
        let read_at =
            handle.requests().last().unwrap().at + DrivesConfig::default().silent_interval();
        let seconds = (read_at - applied).as_micros() as f64 / 1e6;
        let expected = 180_000.0 * seconds - 600.0 * 0.5 * 300.0 * 0.03;
        assert_close(f64::from(share.member(0)[0] as i32), expected, 1.0);
        assert_close(f64::from(share.member(1)[0] as i32), -expected, 1.0);
    });
}

#[test]
fn speed_ramps_at_the_commanded_rates() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        cycle(
            &mut port,
            command(600, 1000, 2000),
            command(-600, 1000, 2000),
        )
        .await;
        let applied = handle.drive(LEFT).last_command_at.unwrap();
        Timer::at(applied + Duration::from_millis(300)).await;
        assert_close(handle.drive(LEFT).speed_rpm, 300.0, 1e-6);
        assert_close(handle.drive(RIGHT).speed_rpm, -300.0, 1e-6);
        Timer::at(applied + Duration::from_secs(1)).await;
        assert_close(handle.drive(LEFT).speed_rpm, 600.0, 1e-9);

        // Reversing: down at the deceleration rate to 0, then up at the acceleration.
        cycle(
            &mut port,
            command(-600, 1000, 2000),
            command(600, 1000, 2000),
        )
        .await;
        let applied = handle.drive(LEFT).last_command_at.unwrap();
        Timer::at(applied + Duration::from_millis(150)).await;
        assert_close(handle.drive(LEFT).speed_rpm, 300.0, 1e-6);
        Timer::at(applied + Duration::from_millis(600)).await;
        assert_close(handle.drive(LEFT).speed_rpm, -300.0, 1e-6);
        assert_close(handle.drive(RIGHT).speed_rpm, 300.0, 1e-6);
    });
}

/// A drive whose direction parameter is at the other value: commanded +600 r/min, it
/// reports position and speed at −600, the two agreeing. `Motion` turns its shaft
/// backwards; `Feedback` turns it forwards and reports it backwards, its counter
/// running on from where it was.
#[test]
fn a_reversed_drive_reports_position_and_speed_against_its_command() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        let start = cycle(&mut port, command(0, 1000, 1000), command(0, 1000, 1000)).await;
        assert_eq!(start.member(1)[0], 0);
        handle.set_reversed(LEFT, Some(Reversal::Motion));
        handle.set_reversed(RIGHT, Some(Reversal::Feedback));
        cycle(
            &mut port,
            command(600, 1000, 1000),
            command(600, 1000, 1000),
        )
        .await;
        let applied = handle.drive(LEFT).last_command_at.unwrap();
        Timer::at(applied + Duration::from_millis(1_000)).await;
        let first = cycle(
            &mut port,
            command(600, 1000, 1000),
            command(600, 1000, 1000),
        )
        .await;
        let first_at = now();
        Timer::after(Duration::from_millis(100)).await;
        let second = cycle(
            &mut port,
            command(600, 1000, 1000),
            command(600, 1000, 1000),
        )
        .await;
        // Both transactions take the same time, so their ends are as far apart as the
        // moments they read.
        let elapsed_s = (now() - first_at).as_micros() as f64 / 1e6;
        for member in [0, 1] {
            let speed = second.member(member)[1] as i32;
            assert_eq!(speed, -600, "member {member} reports its speed reversed");
            let counted =
                (second.member(member)[0] as i32).wrapping_sub(first.member(member)[0] as i32);
            // 600 r/min: 10 revolutions of 36 000 counts per second.
            assert_close(f64::from(counted), -360_000.0 * elapsed_s, 2.0);
        }
    });
    assert_close(handle.drive(LEFT).speed_rpm, -600.0, 1e-9);
    assert_close(handle.drive(RIGHT).speed_rpm, 600.0, 1e-9);
}

#[test]
fn counts_integrate_the_speed_as_each_drive_sees_its_shaft() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        cycle(
            &mut port,
            command(600, 1000, 1000),
            command(-600, 1000, 1000),
        )
        .await;
        let applied = handle.drive(LEFT).last_command_at.unwrap();
        // 0.6 s ramp at 300 r/min on average, then 1 s at 600 r/min: 13 revolutions.
        Timer::at(applied + Duration::from_millis(1600)).await;
        let left = handle.drive(LEFT);
        let right = handle.drive(RIGHT);
        assert_close(f64::from(left.position_counts), 468_000.0, 1.0);
        assert_close(f64::from(right.position_counts), -468_000.0, 1.0);
        assert_eq!(right.mounting, Mounting::Mirrored);
        assert_close(left.forward_revolutions(), 13.0, 1e-6);
        assert_close(right.forward_revolutions(), 13.0, 1e-6);
        assert_close(right.forward_rpm(), 600.0, 1e-9);
    });
}

#[test]
fn position_counter_wraps_like_a_32_bit_register() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        cycle(
            &mut port,
            command(4000, 100_000, 100_000),
            command(0, 1000, 1000),
        )
        .await;
        let applied = handle.drive(LEFT).last_command_at.unwrap();
        Timer::at(applied + Duration::from_secs(1000)).await;
        // 48 000 counts of ramp (0.04 s), then 2.4 M counts/s.
        let unwrapped: i64 = 48_000 + 2_400_000 * 1000 - 2_400_000 * 4 / 100;
        let expected = unwrapped as i32;
        assert!(expected < 0, "the counter has wrapped");
        let counts = handle.drive(LEFT).position_counts;
        assert!(
            counts.wrapping_sub(expected).abs() <= 1,
            "{counts} vs {expected}"
        );
    });
}

#[test]
fn power_cut_loses_the_setup_and_restarts_the_counters() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        cycle(
            &mut port,
            command(600, 1000, 1000),
            command(-600, 1000, 1000),
        )
        .await;
        Timer::after_secs(2).await;
        assert!(handle.drive(LEFT).position_counts > 0);

        handle.power(false);
        let request = modbus::share_read(GID, 0, ITEMS as u16, 2);
        assert_eq!(transact(&mut port, &request).await, [0u8; 0]);
        Timer::after_millis(100).await;
        assert_eq!(
            handle.drive(LEFT).speed_rpm,
            0.0,
            "the brake holds the wheel"
        );

        handle.power(true);
        assert_eq!(read_alarm(&mut port, LEFT).await, Err(ReplyError::TooShort));
        Timer::after_secs(1).await;
        assert_eq!(read_alarm(&mut port, LEFT).await, Ok(0));
        assert_eq!(
            transact(&mut port, &request).await,
            [0u8; 0],
            "the share group is gone"
        );
        for slave in [LEFT, RIGHT] {
            let drive = handle.drive(slave);
            assert_eq!(drive.position_counts, 0);
            assert!(!drive.servo_on);
            assert!(!drive.share.is_member());
            assert_eq!(drive.command, None);
        }
        // Set up again, the cycle works and the counts start from 0.
        set_up(&mut port).await;
        let share = cycle(&mut port, command(0, 1000, 1000), command(0, 1000, 1000)).await;
        assert_eq!(share.member(0)[0], 0);
    });
}

#[test]
fn drives_answer_only_after_the_boot_time() {
    let (mut port, _handle) = drives();
    block_on(async {
        Timer::after_millis(900).await;
        assert!(read_alarm(&mut port, LEFT).await.is_err());
        Timer::after_millis(100).await;
        assert_eq!(read_alarm(&mut port, LEFT).await, Ok(0));
    });
}

#[test]
fn share_request_before_the_setup_is_ignored() {
    let (mut port, handle) = drives();
    block_on(async {
        Timer::after_secs(1).await;
        let reply = cycle_raw(
            &mut port,
            command(600, 1000, 1000),
            command(600, 1000, 1000),
        )
        .await;
        assert_eq!(reply, [0u8; 0]);
    });
    assert_eq!(handle.drive(LEFT).command, None);
}

#[test]
fn a_silent_second_member_ends_the_share_reply_after_the_first() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        handle.set_silent(RIGHT, true);
        let reply = cycle_raw(
            &mut port,
            command(100, 1000, 1000),
            command(-100, 1000, 1000),
        )
        .await;
        assert_eq!(
            parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, 2, ITEMS).map(|_| ()),
            Err(ReplyError::PartialShare { answered: 1 })
        );
        assert_eq!(
            handle.drive(RIGHT).command,
            None,
            "a cut-off drive hears nothing"
        );
        assert!(!handle.drive(RIGHT).listening);
    });
}

#[test]
fn a_silent_first_member_silences_the_second_which_still_executes() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        handle.set_silent(LEFT, true);
        let reply = cycle_raw(
            &mut port,
            command(100, 1000, 1000),
            command(-100, 1000, 1000),
        )
        .await;
        assert_eq!(reply, [0u8; 0]);
        assert_eq!(handle.drive(RIGHT).command.unwrap().speed_rpm, -100);
        assert_eq!(handle.drive(LEFT).command, None);

        handle.set_silent(LEFT, false);
        let share = cycle(
            &mut port,
            command(100, 1000, 1000),
            command(-100, 1000, 1000),
        )
        .await;
        assert_eq!(share.members(), 2);
    });
}

#[test]
fn alarm_stops_the_motor_until_reset_and_a_new_command() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        cycle(
            &mut port,
            command(600, 1000, 1000),
            command(-600, 1000, 1000),
        )
        .await;
        Timer::after_secs(1).await;
        handle.raise_alarm(LEFT, 0x30);
        Timer::after_millis(100).await;
        assert_eq!(handle.drive(LEFT).speed_rpm, 0.0, "the brake stopped it");
        assert_close(handle.drive(RIGHT).speed_rpm, -600.0, 1e-9);

        let share = cycle(
            &mut port,
            command(600, 1000, 1000),
            command(-600, 1000, 1000),
        )
        .await;
        assert_eq!(share.member(0)[ALARM_SLOT], 0x30);
        assert_eq!(share.member(1)[ALARM_SLOT], 0);
        Timer::after_millis(500).await;
        assert_eq!(
            handle.drive(LEFT).speed_rpm,
            0.0,
            "commands do not run during an alarm"
        );

        // The alarm reset: write 1 (the 0 → 1 edge resets), then 0.
        let reset = transact(&mut port, &modbus::write_items(LEFT, 0x0180, &[1])).await;
        assert_eq!(parse_write_echo(&reset, LEFT, 0x0180, 2), Ok(()));
        assert_eq!(read_alarm(&mut port, LEFT).await, Ok(0));
        Timer::after_millis(500).await;
        assert_eq!(
            handle.drive(LEFT).speed_rpm,
            0.0,
            "no command runs after the reset"
        );

        cycle(
            &mut port,
            command(600, 1000, 1000),
            command(-600, 1000, 1000),
        )
        .await;
        Timer::after_millis(300).await;
        assert!(handle.drive(LEFT).speed_rpm > 250.0);
    });
}

#[test]
fn alarm_reset_needs_the_0_to_1_edge() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        handle.raise_alarm(RIGHT, 0x30);
        write(&mut port, RIGHT, 0x0180, &[1]).await;
        assert_eq!(read_alarm(&mut port, RIGHT).await, Ok(0));
        handle.raise_alarm(RIGHT, 0x30);
        write(&mut port, RIGHT, 0x0180, &[1]).await;
        assert_eq!(
            read_alarm(&mut port, RIGHT).await,
            Ok(0x30),
            "still 1: no edge"
        );
        write(&mut port, RIGHT, 0x0180, &[0]).await;
        write(&mut port, RIGHT, 0x0180, &[1]).await;
        assert_eq!(read_alarm(&mut port, RIGHT).await, Ok(0));
    });
}

#[test]
fn garbled_replies_fail_their_checks() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        handle.garble_next_replies(2);
        assert_eq!(read_alarm(&mut port, LEFT).await, Err(ReplyError::BadCrc));
        let reply = cycle_raw(&mut port, command(0, 1000, 1000), command(0, 1000, 1000)).await;
        assert_eq!(reply.len(), 41);
        assert!(matches!(
            parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, 2, ITEMS),
            Err(ReplyError::BadCheck { .. })
        ));
        assert_eq!(
            read_alarm(&mut port, LEFT).await,
            Ok(0),
            "only two were garbled"
        );
    });
}

#[test]
fn reply_timing_is_the_response_delay_plus_one_char_time_per_byte() {
    let config = DrivesConfig::default();
    let char_time = config.char_time();
    assert_eq!(char_time, Duration::from_micros(96));
    assert_eq!(config.response_delay(), Duration::from_micros(336 + 3000));
    let (mut port, _handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        let request = modbus::share_read_write(
            GID,
            0,
            ITEMS as u16,
            0,
            &[&command(0, 1000, 1000), &command(0, 1000, 1000)],
        );
        assert_eq!(request.len(), 53);
        let started = now();
        send(&mut port, &request).await;
        let sent = now();
        assert_eq!(sent - started, char_time * 53);

        let reply = receive_timed(&mut port).await;
        assert_eq!(reply.len(), 41);
        for (index, (at, _)) in reply.iter().enumerate() {
            let expected = sent + config.response_delay() + char_time * (index as u32 + 1);
            assert_eq!(*at, expected, "byte {index}");
        }
    });
}

#[test]
fn share_reply_without_trailer_when_configured() {
    let config = DrivesConfig {
        share_trailer: false,
        ..DrivesConfig::default()
    };
    let (mut port, _handle) = DrivesPort::new(config);
    block_on(async {
        set_up(&mut port).await;
        let reply = cycle_raw(&mut port, command(0, 1000, 1000), command(0, 1000, 1000)).await;
        assert_eq!(reply.len(), 39);
        assert!(parse_share_reply(&reply, GID, READ_WRITE_MULTIPLE, 2, ITEMS).is_ok());
    });
}

#[test]
fn unknown_registers_and_bad_values_answer_exceptions() {
    let (mut port, handle) = drives();
    block_on(async {
        Timer::after_secs(1).await;
        let reply = transact(&mut port, &modbus::read_items(LEFT, 0x0200, 1)).await;
        assert_eq!(parse_read(&reply, LEFT, 1), Err(ReplyError::Exception(2)));
        assert_eq!(handle.drive(LEFT).communication_error, 0x88);
        // The detected position is read-only.
        let reply = transact(&mut port, &modbus::write_items(LEFT, 0x00CC, &[0])).await;
        assert_eq!(
            parse_write_echo(&reply, LEFT, 0x00CC, 2),
            Err(ReplyError::Exception(2))
        );
        // An acceleration rate of 0 is out of range.
        let reply = transact(&mut port, &modbus::write_items(LEFT, 0x0060, &[0])).await;
        assert_eq!(
            parse_write_echo(&reply, LEFT, 0x0060, 2),
            Err(ReplyError::Exception(3))
        );
        assert_eq!(handle.drive(LEFT).communication_error, 0x8C);
        // A share list entry must name an item the drive has.
        let reply = transact(&mut port, &modbus::write_items(LEFT, 0x0990, &[999])).await;
        assert_eq!(
            parse_write_echo(&reply, LEFT, 0x0990, 2),
            Err(ReplyError::Exception(3))
        );
        // FC 06h is not supported.
        let reply = transact(&mut port, &with_crc(&[LEFT, 0x06, 0x00, 0x7C, 0x00, 0x01])).await;
        assert_eq!(reply, with_crc(&[LEFT, 0x86, 0x01]));
    });
}

fn with_crc(body: &[u8]) -> Vec<u8> {
    let mut frame = body.to_vec();
    frame.extend_from_slice(&modbus::crc16(body).to_le_bytes());
    frame
}

#[test]
fn malformed_requests_get_no_reply_and_are_counted() {
    let (mut port, handle) = drives();
    block_on(async {
        Timer::after_secs(1).await;
        let mut bad_crc = modbus::read_items(LEFT, 0x0080, 1).to_vec();
        bad_crc[7] ^= 0x01;
        assert_eq!(transact(&mut port, &bad_crc).await, [0u8; 0]);
        // A good CRC around a read with a byte too many.
        let too_long = with_crc(&[LEFT, 0x03, 0x00, 0x80, 0x00, 0x02, 0x00]);
        assert_eq!(transact(&mut port, &too_long).await, [0u8; 0]);
    });
    let left = handle.drive(LEFT);
    let right = handle.drive(RIGHT);
    assert_eq!(left.malformed_requests, 2);
    assert_eq!(
        right.malformed_requests, 1,
        "only the CRC failure concerns everyone"
    );
    assert_eq!(right.communication_error, 0x84);
    assert_eq!(handle.request_count(), 2);
}

#[test]
fn broadcast_executes_on_both_without_a_reply() {
    let (mut port, handle) = drives();
    block_on(async {
        Timer::after_secs(1).await;
        let reply = transact(&mut port, &modbus::write_items(0, 0x007C, &[1])).await;
        assert_eq!(reply, [0u8; 0]);
    });
    assert!(handle.drive(LEFT).servo_on);
    assert!(handle.drive(RIGHT).servo_on);
}

#[test]
fn communication_timeout_raises_alarm_85_and_stops_the_motor() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        for slave in [LEFT, RIGHT] {
            write(&mut port, slave, 0x138A, &[300]).await;
        }
        cycle(
            &mut port,
            command(600, 1000, 1000),
            command(-600, 1000, 1000),
        )
        .await;
        let last_traffic = handle.requests().last().unwrap().at;
        Timer::at(last_traffic + Duration::from_millis(200)).await;
        assert_eq!(handle.drive(LEFT).alarm, 0);
        Timer::at(last_traffic + Duration::from_millis(400)).await;
        assert_eq!(handle.drive(LEFT).alarm, 0x85);
        assert_eq!(handle.drive(RIGHT).alarm, 0x85);
        assert_eq!(handle.drive(LEFT).speed_rpm, 0.0);
        assert_eq!(read_alarm(&mut port, LEFT).await, Ok(0x85));
    });
}

#[test]
fn request_log_shows_the_setup_frames_with_their_times() {
    let (mut port, handle) = drives();
    let mut flushed = Vec::new();
    block_on(async {
        Timer::after_secs(1).await;
        for slave in [LEFT, RIGHT] {
            let request = modbus::write_items(slave, 0x0980, &[15, 2, u32::from(slave)]);
            send(&mut port, &request).await;
            flushed.push(now());
            receive_timed(&mut port).await;
        }
    });
    let log = handle.requests();
    assert_eq!(log.len(), 2);
    assert_eq!(
        log[0].bytes,
        [
            0x01, 0x10, 0x09, 0x80, 0x00, 0x06, 0x0C, 0x00, 0x00, 0x00, 0x0F, 0x00, 0x00, 0x00,
            0x02, 0x00, 0x00, 0x00, 0x01, 0x44, 0xD5
        ]
    );
    assert_eq!(log[1].bytes[0], RIGHT);
    assert_eq!(log[0].at, flushed[0]);
    assert_eq!(log[1].at, flushed[1]);
    let config = DrivesConfig::default();
    assert_eq!(log[0].at - log[0].started, config.char_time() * 21);
}

#[test]
fn reply_log_shows_each_echo_as_the_master_read_it() {
    let (mut port, handle) = drives();
    let mut received = Vec::new();
    block_on(async {
        Timer::after_secs(1).await;
        for slave in [LEFT, RIGHT] {
            let request = modbus::write_items(slave, 0x0980, &[15, 2, u32::from(slave)]);
            send(&mut port, &request).await;
            received.push(receive_timed(&mut port).await);
        }
    });
    let config = DrivesConfig::default();
    let requests = handle.requests();
    let replies = handle.replies();
    assert_eq!(replies.len(), 2);
    for ((reply, request), read) in replies.iter().zip(&requests).zip(&received) {
        let bytes: Vec<u8> = read.iter().map(|&(_, byte)| byte).collect();
        assert_eq!(reply.bytes, bytes);
        assert_eq!(reply.started, request.at + config.response_delay());
        assert_eq!(Some(reply.at), read.last().map(|&(at, _)| at));
    }
}

#[test]
fn new_speed_instant_marks_when_the_drive_took_the_request() {
    let (mut port, handle) = drives();
    let config = DrivesConfig::default();
    block_on(async {
        set_up(&mut port).await;
        let request = modbus::share_write(
            GID,
            0,
            &[&command(100, 1000, 1000), &command(-100, 1000, 1000)],
        );
        send(&mut port, &request).await;
        let sent = now();
        receive_timed(&mut port).await;
        let taken = sent + config.silent_interval();
        assert_eq!(handle.drive(LEFT).last_new_speed_at, Some(taken));
        assert_eq!(handle.drive(RIGHT).last_new_speed_at, Some(taken));

        // The same speed again moves the command instant, not the new-speed instant.
        Timer::after_millis(20).await;
        send(&mut port, &request).await;
        let again = now() + config.silent_interval();
        receive_timed(&mut port).await;
        assert_eq!(handle.drive(LEFT).last_new_speed_at, Some(taken));
        assert_eq!(handle.drive(LEFT).last_command_at, Some(again));
    });
}

#[test]
fn a_request_sent_over_a_reply_collides() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        send(&mut port, &modbus::share_read(GID, 0, ITEMS as u16, 2)).await;
        // The reply starts after 3.3 ms; talk into it.
        Timer::after_millis(4).await;
        send(&mut port, &modbus::read_items(LEFT, 0x0080, 1)).await;
        let reply = receive(&mut port).await;
        assert!(parse_share_reply(&reply, GID, modbus::READ_HOLDING, 2, ITEMS).is_err());
        assert_ne!(reply.len(), 9, "the alarm read was not answered");
    });
    assert_eq!(handle.collisions(), 1);
}

#[test]
fn two_drives_answering_at_once_garble_each_other() {
    let (mut port, handle) = drives();
    block_on(async {
        set_up(&mut port).await;
        send(&mut port, &modbus::share_read(GID, 0, ITEMS as u16, 2)).await;
        // A second request inside the first reply's response delay: both get answered,
        // and the two replies overlap on the line.
        Timer::after_micros(500).await;
        send(&mut port, &modbus::read_items(RIGHT, 0x0080, 1)).await;
        let reply = receive(&mut port).await;
        assert_eq!(reply.len(), 41 + 9);
        assert!(parse_share_reply(&reply[..41], GID, modbus::READ_HOLDING, 2, ITEMS).is_err());
        assert!(parse_read(&reply[41..], RIGHT, 1).is_err());
    });
    assert_eq!(handle.collisions(), 0, "the requests themselves were clean");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn garbage_on_the_line_never_breaks_the_drives(
        frames in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..80), 1..6),
        lead in any::<u8>(),
    ) {
        let (mut port, _handle) = drives();
        let answered = block_on(async {
            set_up(&mut port).await;
            for frame in &frames {
                // A leading address that is one of ours now and then, to get past it.
                let mut frame = frame.clone();
                if let Some(first) = frame.first_mut() {
                    *first = [LEFT, RIGHT, GID, 0, *first][usize::from(lead % 5)];
                }
                send(&mut port, &frame).await;
                receive_timed(&mut port).await;
            }
            read_alarm(&mut port, LEFT).await
        });
        prop_assert!(answered.is_ok(), "{answered:?}");
    }

    #[test]
    fn crc_valid_random_requests_never_break_the_drives(
        bodies in prop::collection::vec(prop::collection::vec(any::<u8>(), 1..70), 1..6),
        addresses in prop::collection::vec(prop::sample::select(vec![0u8, LEFT, RIGHT, GID]), 6),
        functions in prop::collection::vec(prop::sample::select(vec![0x03u8, 0x10, 0x17, 0x06]), 6),
    ) {
        let (mut port, _handle) = drives();
        let answered = block_on(async {
            set_up(&mut port).await;
            for (index, body) in bodies.iter().enumerate() {
                let mut frame = vec![addresses[index], functions[index]];
                frame.extend_from_slice(body);
                send(&mut port, &with_crc(&frame)).await;
                receive_timed(&mut port).await;
            }
            read_alarm(&mut port, RIGHT).await
        });
        // Random writes may have raised the share number or cleared S-ON, but the
        // drive must still answer a plain read.
        prop_assert!(answered.is_ok(), "{answered:?}");
    }
}
