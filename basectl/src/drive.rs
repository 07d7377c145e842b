//! `drive`: keyboard teleop that moves the base only while a key is held.
//!
//! Terminals report key presses, never releases, but a held key repeats. So a
//! movement key drives for [`FIRST_HOLD`] after its press (longer than the usual
//! auto-repeat delay) and for [`REPEAT_HOLD`] after each repeat; when the repeats
//! stop, the key was let go and the command drops to zero. Nothing is latched.
//!
//! After an e-stop, a drive fault, any mode but standby or driving, or a lapse of the
//! enable, the command is zero and stays zero until the keys have been let go and a
//! key is pressed anew: a key still held from before never starts the base again.
//! The screen shows the command, the measured speed, the pose, mode and faults live.

use std::io::Write;
use std::time::{Duration, Instant};

use base_core::can::{Command, Mode, Status};
use crossterm::event::{self, Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use crossterm::terminal;

use crate::base::{Base, Error, Pose};
use crate::bus::exit;

/// Enable and velocity go out this often.
const SEND_PERIOD: Duration = Duration::from_millis(100);
/// A first press drives this long: keyboards start repeating after 250–600 ms.
pub const FIRST_HOLD: Duration = Duration::from_millis(650);
/// Each repeat drives this long: repeats come every 30–50 ms while a key is held.
pub const REPEAT_HOLD: Duration = Duration::from_millis(150);
/// Without a status frame this long, the base's state is unknown: no motion.
const STATUS_STALE: Duration = Duration::from_millis(2500);

/// The speeds a held key drives at, and how `+`/`-` change them.
#[derive(Debug, Clone, Copy)]
pub struct Speeds {
    pub linear_mm_s: i16,
    pub rotation_mrad_s: i16,
    pub max_linear_mm_s: i16,
    pub max_rotation_mrad_s: i16,
}

/// Where a key drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    Forward,
    Backward,
    /// Counter-clockwise seen from above.
    Left,
    /// Clockwise seen from above.
    Right,
}

/// What a key asks for.
#[derive(Debug, PartialEq, Eq)]
enum KeyAction {
    Move(Direction),
    Stop,
    Faster,
    Slower,
    Quit,
    Ignore,
}

fn key_action(key: &KeyEvent) -> KeyAction {
    if key.kind == KeyEventKind::Release {
        return KeyAction::Ignore;
    }
    let ctrl_c = key.modifiers.contains(KeyModifiers::CONTROL) && key.code == KeyCode::Char('c');
    match key.code {
        _ if ctrl_c => KeyAction::Quit,
        KeyCode::Char('q') | KeyCode::Esc => KeyAction::Quit,
        KeyCode::Char(' ') => KeyAction::Stop,
        KeyCode::Char('+' | '=') => KeyAction::Faster,
        KeyCode::Char('-') => KeyAction::Slower,
        KeyCode::Up | KeyCode::Char('w') => KeyAction::Move(Direction::Forward),
        KeyCode::Down | KeyCode::Char('s') => KeyAction::Move(Direction::Backward),
        KeyCode::Left | KeyCode::Char('a') => KeyAction::Move(Direction::Left),
        KeyCode::Right | KeyCode::Char('d') => KeyAction::Move(Direction::Right),
        // Anything else stops, as in teleop_twist_keyboard.
        _ => KeyAction::Stop,
    }
}

/// Why the base may not move now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Block {
    NoStatus,
    Estop,
    Mode(Mode),
    DriveFault,
    EnableLost,
}

impl Block {
    fn describe(&self) -> String {
        match self {
            Block::NoStatus => "no status frame from the base controller".to_owned(),
            Block::Estop => "e-stop pressed".to_owned(),
            Block::Mode(mode) => format!("mode {mode:?}"),
            Block::DriveFault => "drive fault".to_owned(),
            Block::EnableLost => "the controller does not see the enable".to_owned(),
        }
    }
}

/// What the status frame says about driving.
pub fn block_from(status: &Status) -> Option<Block> {
    let faults = status.faults;
    if status.flags.estop_pressed {
        Some(Block::Estop)
    } else if faults.left_drive_silent
        || faults.left_drive_alarm
        || faults.right_drive_silent
        || faults.right_drive_alarm
    {
        Some(Block::DriveFault)
    } else if !matches!(status.mode, Mode::Standby | Mode::Active) {
        Some(Block::Mode(status.mode))
    } else {
        None
    }
}

/// The key-hold logic, apart from the terminal and the bus.
#[derive(Debug, Default)]
pub struct Teleop {
    /// The key being held: its direction, its last press or repeat, and whether
    /// repeats have come.
    held: Option<(Direction, Instant, bool)>,
    last_key: Option<Instant>,
    /// Set by a block: keys must be let go before a press counts again.
    need_release: bool,
}

impl Teleop {
    /// A movement key came (a press or an auto-repeat).
    pub fn key(&mut self, direction: Direction, now: Instant) {
        self.last_key = Some(now);
        if self.need_release {
            return;
        }
        self.held = match self.held {
            Some((held, last, _)) if held == direction && now - last <= FIRST_HOLD => {
                Some((direction, now, true))
            }
            _ => Some((direction, now, false)),
        };
    }

    /// Space or any other key: stop now.
    pub fn stop(&mut self) {
        self.held = None;
    }

    /// The direction to drive now, if any. `block` is why the base may not move.
    pub fn direction(&mut self, now: Instant, block: Option<&Block>) -> Option<Direction> {
        if block.is_some() {
            self.held = None;
            self.need_release = true;
            return None;
        }
        if self.need_release {
            if self
                .last_key
                .is_some_and(|last| now.saturating_duration_since(last) <= REPEAT_HOLD)
            {
                return None;
            }
            self.need_release = false;
        }
        if let Some((direction, last, repeating)) = self.held {
            let window = if repeating { REPEAT_HOLD } else { FIRST_HOLD };
            if now.saturating_duration_since(last) <= window {
                return Some(direction);
            }
            self.held = None;
        }
        None
    }

    pub fn waiting_for_release(&self) -> bool {
        self.need_release
    }
}

/// The velocity for `direction` at `speeds`.
pub fn velocity(direction: Option<Direction>, speeds: &Speeds) -> (i16, i16) {
    match direction {
        None => (0, 0),
        Some(Direction::Forward) => (speeds.linear_mm_s, 0),
        Some(Direction::Backward) => (-speeds.linear_mm_s, 0),
        // + rotation is clockwise, which is to the right seen from above.
        Some(Direction::Right) => (0, speeds.rotation_mrad_s),
        Some(Direction::Left) => (0, -speeds.rotation_mrad_s),
    }
}

/// Leaves raw mode however `drive` ends, error, panic and SIGTERM included.
struct RawMode {
    _restore: exit::Registration,
}

impl RawMode {
    fn enter() -> Result<Self, Error> {
        terminal::enable_raw_mode()?;
        Ok(Self {
            _restore: exit::register(Box::new(|| {
                // Nothing more can be done if the terminal refuses; `reset` can.
                let _ = terminal::disable_raw_mode();
            })),
        })
    }
}

pub fn drive(base: &mut Base, mut speeds: Speeds, out: &mut dyn Write) -> Result<(), Error> {
    let raw_mode = RawMode::enter()?;
    let result = drive_loop(base, &mut speeds, out);
    // Stop before anything else: the base must not drive on while the enable lapses.
    let stopped = base
        .send(Command::Velocity {
            linear_mm_s: 0,
            rotation_mrad_s: 0,
        })
        .and_then(|()| base.send(Command::Enable { refresh: false }));
    drop(raw_mode);
    writeln!(out)?;
    result.and(stopped)
}

/// The measured speed, from the pose reports.
#[derive(Default)]
struct Measured {
    last: Option<(Instant, Pose)>,
    linear_mm_s: f64,
    rotation_mrad_s: f64,
}

impl Measured {
    fn update(&mut self, pose: Pose, now: Instant) {
        if let Some((at, last)) = self.last {
            let seconds = now.duration_since(at).as_secs_f64();
            if seconds < 0.2 {
                return;
            }
            let (dx, dy) = (
                f64::from(pose.x_mm - last.x_mm),
                f64::from(pose.y_mm - last.y_mm),
            );
            let heading_rad = f64::from(last.heading_mrad) / 1000.0;
            // The displacement along the heading: negative when backing up.
            let along = dx * heading_rad.cos() + dy * heading_rad.sin();
            self.linear_mm_s = dx.hypot(dy).copysign(along) / seconds;
            self.rotation_mrad_s = f64::from(pose.heading_mrad - last.heading_mrad) / seconds;
        }
        self.last = Some((now, pose));
    }
}

fn drive_loop(base: &mut Base, speeds: &mut Speeds, out: &mut dyn Write) -> Result<(), Error> {
    let mut teleop = Teleop::default();
    let mut measured = Measured::default();
    let mut last_status: Option<(Instant, Status)> = None;
    let mut moving_since: Option<Instant> = None;
    let mut next_send = Instant::now();
    loop {
        let now = Instant::now();
        // Keys first, without waiting.
        while event::poll(Duration::ZERO)? {
            if let Event::Key(key) = event::read()? {
                match key_action(&key) {
                    KeyAction::Move(direction) => teleop.key(direction, now),
                    KeyAction::Stop => teleop.stop(),
                    KeyAction::Faster => change_speed(speeds, 1),
                    KeyAction::Slower => change_speed(speeds, -1),
                    KeyAction::Quit => return Ok(()),
                    KeyAction::Ignore => {}
                }
            }
        }
        // Then the bus, for a few ms: every report goes into the picture.
        if let Some(report) = base.next_report(Duration::from_millis(5))? {
            if let base_core::can::Report::Status(status) = report {
                last_status = Some((Instant::now(), status));
            }
            if let Some(pose) = base.pose() {
                measured.update(pose, Instant::now());
            }
        }
        if now < next_send {
            continue;
        }
        next_send = now + SEND_PERIOD;
        let block = match last_status {
            None => Some(Block::NoStatus),
            Some((at, _)) if at.elapsed() > STATUS_STALE => Some(Block::NoStatus),
            Some((at, status)) => block_from(&status).or_else(|| {
                // Moving for a while, yet the newest status says no fresh enable.
                let lapsed = !status.flags.enable_fresh
                    && moving_since.is_some_and(|since| at > since + Duration::from_millis(500));
                lapsed.then_some(Block::EnableLost)
            }),
        };
        let direction = teleop.direction(now, block.as_ref());
        let (linear, rotation) = velocity(direction, speeds);
        moving_since = match (direction, moving_since) {
            (Some(_), Some(since)) => Some(since),
            (Some(_), None) => Some(now),
            (None, _) => None,
        };
        base.send(Command::Enable { refresh: true })?;
        base.send(Command::Velocity {
            linear_mm_s: linear,
            rotation_mrad_s: rotation,
        })?;
        draw(
            out,
            &Screen {
                speeds,
                linear,
                rotation,
                measured: &measured,
                pose: base.pose(),
                status: last_status.map(|(_, status)| status),
                battery: base.battery(),
                block: block.as_ref(),
                waiting_for_release: teleop.waiting_for_release(),
            },
        )?;
    }
}

fn change_speed(speeds: &mut Speeds, sign: i16) {
    let step = |value: i16, max: i16| (value + sign * (max / 10).max(1)).clamp(max / 10, max);
    speeds.linear_mm_s = step(speeds.linear_mm_s, speeds.max_linear_mm_s);
    speeds.rotation_mrad_s = step(speeds.rotation_mrad_s, speeds.max_rotation_mrad_s);
}

struct Screen<'a> {
    speeds: &'a Speeds,
    linear: i16,
    rotation: i16,
    measured: &'a Measured,
    pose: Option<Pose>,
    status: Option<Status>,
    battery: Option<(u8, u16)>,
    block: Option<&'a Block>,
    waiting_for_release: bool,
}

/// Redraws the screen in place (raw mode: lines end in CR LF).
fn draw(out: &mut dyn Write, screen: &Screen) -> Result<(), Error> {
    let mut text = String::from("\x1b[H\x1b[J");
    let mut line = |line: String| {
        text.push_str(&line);
        text.push_str("\r\n");
    };
    line("basectl drive: hold w/s or arrows to drive, a/d to turn; release to stop".into());
    line("space or any other key stops, +/- speed, q quits".into());
    line(String::new());
    line(format!(
        "speed      {} mm/s, {} mrad/s while a key is held",
        screen.speeds.linear_mm_s, screen.speeds.rotation_mrad_s
    ));
    line(format!(
        "command    {:5} mm/s  {:5} mrad/s{}",
        screen.linear,
        screen.rotation,
        if (screen.linear, screen.rotation) == (0, 0) {
            "  (stopped)"
        } else {
            "  MOVING"
        }
    ));
    line(format!(
        "measured   {:5.0} mm/s  {:5.0} mrad/s",
        screen.measured.linear_mm_s, screen.measured.rotation_mrad_s
    ));
    line(match screen.pose {
        Some(pose) => format!(
            "pose       x {} mm  y {} mm  heading {} mrad",
            pose.x_mm, pose.y_mm, pose.heading_mrad
        ),
        None => "pose       -".into(),
    });
    line(match screen.status {
        Some(status) => {
            let faults = crate::monitor::fault_names(&status.faults);
            format!(
                "mode       {:?}  control {:?}  faults {}",
                status.mode,
                status.control,
                if faults.is_empty() {
                    "none".to_owned()
                } else {
                    faults.join(",")
                }
            )
        }
        None => "mode       - (no status frame yet)".into(),
    });
    line(match screen.battery {
        Some((percent, millivolts)) => format!("battery    {millivolts} mV  {percent} %"),
        None => "battery    -".into(),
    });
    line(match (screen.block, screen.waiting_for_release) {
        (Some(block), _) => format!("STOPPED: {}", block.describe()),
        (None, true) => "STOPPED: let go of the keys, then press one to drive again".into(),
        (None, false) => String::new(),
    });
    out.write_all(text.as_bytes())?;
    out.flush()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPEEDS: Speeds = Speeds {
        linear_mm_s: 300,
        rotation_mrad_s: 800,
        max_linear_mm_s: 500,
        max_rotation_mrad_s: 1500,
    };

    fn ms(start: Instant, ms: u64) -> Instant {
        start + Duration::from_millis(ms)
    }

    #[test]
    fn keys_map_to_directions_and_anything_else_stops() {
        let press = |code| key_action(&KeyEvent::new(code, KeyModifiers::NONE));
        assert_eq!(press(KeyCode::Up), KeyAction::Move(Direction::Forward));
        assert_eq!(
            press(KeyCode::Char('s')),
            KeyAction::Move(Direction::Backward)
        );
        assert_eq!(press(KeyCode::Char('a')), KeyAction::Move(Direction::Left));
        assert_eq!(press(KeyCode::Right), KeyAction::Move(Direction::Right));
        assert_eq!(press(KeyCode::Char(' ')), KeyAction::Stop);
        assert_eq!(press(KeyCode::Char('x')), KeyAction::Stop);
        assert_eq!(press(KeyCode::Char('q')), KeyAction::Quit);
        let ctrl_c = KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL);
        assert_eq!(key_action(&ctrl_c), KeyAction::Quit);
        assert_eq!(velocity(Some(Direction::Left), &SPEEDS), (0, -800));
    }

    #[test]
    fn a_held_key_drives_and_letting_go_stops_within_the_repeat_window() {
        let start = Instant::now();
        let mut teleop = Teleop::default();
        teleop.key(Direction::Forward, start);
        // Before the keyboard starts repeating, the first press keeps driving.
        assert_eq!(
            teleop.direction(ms(start, 400), None),
            Some(Direction::Forward)
        );
        for repeat in 0..20 {
            let at = 500 + repeat * 40;
            teleop.key(Direction::Forward, ms(start, at));
            assert_eq!(
                teleop.direction(ms(start, at + 20), None),
                Some(Direction::Forward)
            );
        }
        // Last repeat at 1260 ms: stopped once the repeat window has passed.
        assert_eq!(
            teleop.direction(ms(start, 1400), None),
            Some(Direction::Forward)
        );
        assert_eq!(teleop.direction(ms(start, 1420), None), None);
        assert_eq!(
            teleop.direction(ms(start, 3000), None),
            None,
            "nothing is latched"
        );
    }

    #[test]
    fn a_single_tap_drives_only_for_the_first_hold() {
        let start = Instant::now();
        let mut teleop = Teleop::default();
        teleop.key(Direction::Right, start);
        assert_eq!(
            teleop.direction(ms(start, 600), None),
            Some(Direction::Right)
        );
        assert_eq!(teleop.direction(ms(start, 700), None), None);
    }

    #[test]
    fn after_an_estop_a_key_still_held_never_restarts_the_base() {
        let start = Instant::now();
        let mut teleop = Teleop::default();
        teleop.key(Direction::Forward, start);
        assert!(teleop.direction(ms(start, 50), None).is_some());
        // E-stop while the key is held: zero at once.
        assert_eq!(teleop.direction(ms(start, 100), Some(&Block::Estop)), None);
        // The key keeps repeating through the release and the confirm press.
        for at in (140..3000).step_by(40) {
            teleop.key(Direction::Forward, ms(start, at));
            let block = (at < 2000).then_some(Block::Mode(Mode::AwaitingConfirm));
            assert_eq!(
                teleop.direction(ms(start, at + 10), block.as_ref()),
                None,
                "{at} ms"
            );
        }
        // Let go (no key for longer than the repeat window), then a new press drives.
        assert_eq!(teleop.direction(ms(start, 3200), None), None);
        assert!(!teleop.waiting_for_release());
        teleop.key(Direction::Forward, ms(start, 3300));
        assert_eq!(
            teleop.direction(ms(start, 3310), None),
            Some(Direction::Forward)
        );
    }

    #[test]
    fn the_status_blocks_on_estop_drive_faults_and_modes_other_than_standby_and_active() {
        let mut status = Status {
            mode: Mode::Active,
            ..Status::default()
        };
        assert_eq!(block_from(&status), None);
        status.mode = Mode::Fault;
        assert_eq!(block_from(&status), Some(Block::Mode(Mode::Fault)));
        status.mode = Mode::Standby;
        status.faults.right_drive_alarm = true;
        assert_eq!(block_from(&status), Some(Block::DriveFault));
        status.flags.estop_pressed = true;
        assert_eq!(block_from(&status), Some(Block::Estop));
    }
}
