//! `drive`: keyboard teleop. Arrows or WASD change the speed in steps, space stops,
//! q quits; the enable (every 100 ms) and the velocity are sent for the person.

use std::io::Write;
use std::time::{Duration, Instant};

use base_core::can::Command;
use crossterm::event::{self, Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use crossterm::terminal;

use crate::controller::{Controller, Error};

const ENABLE_PERIOD: Duration = Duration::from_millis(100);

/// The speed steps one key press makes, and the limits.
#[derive(Debug, Clone, Copy)]
pub struct Steps {
    pub linear_mm_s: i16,
    pub rotation_mrad_s: i16,
    pub max_linear_mm_s: i16,
    pub max_rotation_mrad_s: i16,
}

/// Leaves raw mode however `drive` ends, error and panic included.
struct RawMode;

impl RawMode {
    fn enter() -> Result<Self, Error> {
        terminal::enable_raw_mode()?;
        Ok(Self)
    }
}

impl Drop for RawMode {
    fn drop(&mut self) {
        // Nothing more can be done if the terminal refuses; the shell's `reset` can.
        let _ = terminal::disable_raw_mode();
    }
}

/// What a key asks for.
#[derive(Debug, PartialEq, Eq)]
enum KeyAction {
    Change { linear: i16, rotation: i16 },
    Stop,
    Quit,
    Ignore,
}

fn key_action(key: &KeyEvent, steps: &Steps) -> KeyAction {
    if key.kind == KeyEventKind::Release {
        return KeyAction::Ignore;
    }
    let ctrl_c = key.modifiers.contains(KeyModifiers::CONTROL) && key.code == KeyCode::Char('c');
    match key.code {
        _ if ctrl_c => KeyAction::Quit,
        KeyCode::Char('q') | KeyCode::Esc => KeyAction::Quit,
        KeyCode::Char(' ') => KeyAction::Stop,
        KeyCode::Up | KeyCode::Char('w') => KeyAction::Change {
            linear: steps.linear_mm_s,
            rotation: 0,
        },
        KeyCode::Down | KeyCode::Char('s') => KeyAction::Change {
            linear: -steps.linear_mm_s,
            rotation: 0,
        },
        // + rotation is clockwise, which is to the right seen from above.
        KeyCode::Right | KeyCode::Char('d') => KeyAction::Change {
            linear: 0,
            rotation: steps.rotation_mrad_s,
        },
        KeyCode::Left | KeyCode::Char('a') => KeyAction::Change {
            linear: 0,
            rotation: -steps.rotation_mrad_s,
        },
        _ => KeyAction::Ignore,
    }
}

pub fn drive(controller: &mut Controller, steps: Steps, out: &mut dyn Write) -> Result<(), Error> {
    writeln!(out, "arrows/WASD: speed in steps, space: stop, q: quit")?;
    let raw_mode = RawMode::enter()?;
    let result = drive_loop(controller, &steps, out);
    // Stop before anything else: the base must not drive on while the enable lapses.
    let stopped = controller
        .send(Command::Velocity {
            linear_mm_s: 0,
            rotation_mrad_s: 0,
        })
        .and_then(|()| controller.send(Command::Enable { refresh: false }));
    drop(raw_mode);
    writeln!(out)?;
    result.and(stopped)
}

fn drive_loop(
    controller: &mut Controller,
    steps: &Steps,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let (mut linear, mut rotation) = (0i16, 0i16);
    loop {
        let next_enable = Instant::now() + ENABLE_PERIOD;
        controller.send(Command::Enable { refresh: true })?;
        controller.send(Command::Velocity {
            linear_mm_s: linear,
            rotation_mrad_s: rotation,
        })?;
        while event::poll(next_enable.saturating_duration_since(Instant::now()))? {
            if let Event::Key(key) = event::read()? {
                match key_action(&key, steps) {
                    KeyAction::Change {
                        linear: dl,
                        rotation: dr,
                    } => {
                        linear = linear
                            .saturating_add(dl)
                            .clamp(-steps.max_linear_mm_s, steps.max_linear_mm_s);
                        rotation = rotation
                            .saturating_add(dr)
                            .clamp(-steps.max_rotation_mrad_s, steps.max_rotation_mrad_s);
                    }
                    KeyAction::Stop => (linear, rotation) = (0, 0),
                    KeyAction::Quit => return Ok(()),
                    KeyAction::Ignore => {}
                }
            }
        }
        while controller.next_report(Duration::ZERO)?.is_some() {}
        let pose = controller.pose().unwrap_or_default();
        let mode = controller
            .status()
            .map(|status| format!("{:?}", status.mode))
            .unwrap_or_else(|| "?".to_owned());
        write!(
            out,
            "\r\x1b[Kcommand {linear} mm/s {rotation} mrad/s | x {} mm y {} mm heading {} mrad | mode {mode}",
            pose.x_mm, pose.y_mm, pose.heading_mrad
        )?;
        out.flush()?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STEPS: Steps = Steps {
        linear_mm_s: 100,
        rotation_mrad_s: 200,
        max_linear_mm_s: 500,
        max_rotation_mrad_s: 1000,
    };

    fn press(code: KeyCode) -> KeyAction {
        key_action(&KeyEvent::new(code, KeyModifiers::NONE), &STEPS)
    }

    #[test]
    fn arrows_and_wasd_change_speed_space_stops_q_quits() {
        assert_eq!(
            press(KeyCode::Up),
            KeyAction::Change {
                linear: 100,
                rotation: 0
            }
        );
        assert_eq!(
            press(KeyCode::Char('s')),
            KeyAction::Change {
                linear: -100,
                rotation: 0
            }
        );
        assert_eq!(
            press(KeyCode::Right),
            KeyAction::Change {
                linear: 0,
                rotation: 200
            }
        );
        assert_eq!(
            press(KeyCode::Char('a')),
            KeyAction::Change {
                linear: 0,
                rotation: -200
            }
        );
        assert_eq!(press(KeyCode::Char(' ')), KeyAction::Stop);
        assert_eq!(press(KeyCode::Char('q')), KeyAction::Quit);
        assert_eq!(press(KeyCode::Char('x')), KeyAction::Ignore);
        let ctrl_c = KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL);
        assert_eq!(key_action(&ctrl_c, &STEPS), KeyAction::Quit);
    }
}
