//! The simulator's console: one command per line on stdin acts on the robot's inputs
//! (the e-stop, the safety zone, the front button, the battery, the scale, the drives'
//! power and line, the controller's reset), so a developer or a script can play the
//! world around the controller.

/// The front button's hold time when `button press` names none: a short press, the
/// confirm after an e-stop.
pub const DEFAULT_PRESS_MS: u64 = 200;
/// The longest press `button press` accepts.
pub const MAX_PRESS_MS: u64 = 60_000;

/// The console commands, as `--help` and `help` show them.
pub const HELP: &str = "\
\x20 estop on|off           press (on) or release (off) the emergency stop
  zone on|off            someone enters (on) or leaves (off) the safety zone
  button press [MS]      press the front button for MS ms (default 200; hold
                         longer to switch the PC off, see the PC button timings)
  battery MV             the battery voltage, in mV (0-65535)
  weight G               the load on the scale, in g (may be negative)
  drives power on|off    switch the drives' power (off: they stop answering)
  drive left|right silent on|off
                         cut one drive from the RS-485 line (on) or reconnect it
                         (off): it keeps running its last command, unheard
  reboot [watchdog]      reset the controller alone, as its reset button or a
                         brown-out does: the drives run on until the new boot
                         stops them; watchdog: as a watchdog bite or a panic
                         (the status frame then shows watchdog_reset)
  panic                  the controller panics and resets; 3 panics in a row,
                         each within 30 s of boot, leave Bluetooth off
  status                 print everything the simulator knows, on five lines
  help                   this list
  quit                   stop the simulator";

/// One console command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ConsoleCommand {
    /// `true`: pressed.
    Estop(bool),
    /// `true`: someone is in the zone.
    SafetyZone(bool),
    ButtonPress {
        hold_ms: u64,
    },
    BatteryMillivolts(u16),
    WeightGrams(f64),
    DrivesPower(bool),
    /// One drive cut from the line (`true`) or back on it.
    DriveSilent {
        wheel: Side,
        silent: bool,
    },
    /// The controller resets; `by_watchdog`: its reset reason says watchdog.
    Reboot {
        by_watchdog: bool,
    },
    /// The controller panics (and so resets).
    Panic,
    Status,
    Help,
    Quit,
}

/// Which wheel's drive a command is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Left,
    Right,
}

impl Side {
    /// The drive's Modbus address (left 1, right 2, as the drive settings default).
    pub const fn slave(self) -> u8 {
        match self {
            Side::Left => 1,
            Side::Right => 2,
        }
    }
}

/// Why a console line was refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConsoleError {
    UnknownCommand(String),
    /// The command is known but its arguments are not what it takes.
    Usage(&'static str),
}

impl core::fmt::Display for ConsoleError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ConsoleError::UnknownCommand(word) => {
                write!(f, "unknown command {word:?} (type help for the list)")
            }
            ConsoleError::Usage(usage) => write!(f, "usage: {usage}"),
        }
    }
}

/// Parses one line. `Ok(None)` for a blank line or a `#` comment, so that command
/// files can be piped in.
pub fn parse_console_line(line: &str) -> Result<Option<ConsoleCommand>, ConsoleError> {
    let line = line.split('#').next().unwrap_or_default();
    let words: Vec<&str> = line.split_whitespace().collect();
    let command = match words.as_slice() {
        [] => return Ok(None),
        ["estop", state] => ConsoleCommand::Estop(on_off(state, "estop on|off")?),
        ["estop", ..] => return Err(ConsoleError::Usage("estop on|off")),
        ["zone", state] => ConsoleCommand::SafetyZone(on_off(state, "zone on|off")?),
        ["zone", ..] => return Err(ConsoleError::Usage("zone on|off")),
        ["button", "press"] => ConsoleCommand::ButtonPress {
            hold_ms: DEFAULT_PRESS_MS,
        },
        ["button", "press", hold_ms] => ConsoleCommand::ButtonPress {
            hold_ms: hold_ms
                .parse()
                .ok()
                .filter(|hold_ms| (1..=MAX_PRESS_MS).contains(hold_ms))
                .ok_or(ConsoleError::Usage("button press [MS], MS from 1 to 60000"))?,
        },
        ["button", ..] => return Err(ConsoleError::Usage("button press [MS]")),
        ["battery", millivolts] => ConsoleCommand::BatteryMillivolts(
            millivolts
                .parse()
                .map_err(|_| ConsoleError::Usage("battery MV, MV from 0 to 65535"))?,
        ),
        ["battery", ..] => return Err(ConsoleError::Usage("battery MV")),
        ["weight", grams] => ConsoleCommand::WeightGrams(
            grams
                .parse()
                .ok()
                .filter(|grams: &f64| grams.is_finite())
                .ok_or(ConsoleError::Usage("weight G, G a number of grams"))?,
        ),
        ["weight", ..] => return Err(ConsoleError::Usage("weight G")),
        ["drives", "power", state] => {
            ConsoleCommand::DrivesPower(on_off(state, "drives power on|off")?)
        }
        ["drives", ..] => return Err(ConsoleError::Usage("drives power on|off")),
        ["drive", side, "silent", state] => {
            const USAGE: &str = "drive left|right silent on|off";
            let wheel = match *side {
                "left" => Side::Left,
                "right" => Side::Right,
                _ => return Err(ConsoleError::Usage(USAGE)),
            };
            ConsoleCommand::DriveSilent {
                wheel,
                silent: on_off(state, USAGE)?,
            }
        }
        ["drive", ..] => return Err(ConsoleError::Usage("drive left|right silent on|off")),
        ["reboot"] => ConsoleCommand::Reboot { by_watchdog: false },
        ["reboot", "watchdog"] => ConsoleCommand::Reboot { by_watchdog: true },
        ["reboot", ..] => return Err(ConsoleError::Usage("reboot [watchdog]")),
        ["panic"] => ConsoleCommand::Panic,
        ["status"] => ConsoleCommand::Status,
        ["help"] => ConsoleCommand::Help,
        ["quit" | "exit"] => ConsoleCommand::Quit,
        ["status" | "help" | "quit" | "exit" | "panic", ..] => {
            return Err(ConsoleError::Usage(
                "status, help, quit and panic take no arguments",
            ));
        }
        [word, ..] => return Err(ConsoleError::UnknownCommand((*word).to_owned())),
    };
    Ok(Some(command))
}

fn on_off(word: &str, usage: &'static str) -> Result<bool, ConsoleError> {
    match word {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(ConsoleError::Usage(usage)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_command_parses() {
        for (line, command) in [
            ("estop on", ConsoleCommand::Estop(true)),
            ("  estop   off ", ConsoleCommand::Estop(false)),
            ("zone on", ConsoleCommand::SafetyZone(true)),
            (
                "button press",
                ConsoleCommand::ButtonPress {
                    hold_ms: DEFAULT_PRESS_MS,
                },
            ),
            (
                "button press 3500",
                ConsoleCommand::ButtonPress { hold_ms: 3_500 },
            ),
            ("battery 22100", ConsoleCommand::BatteryMillivolts(22_100)),
            ("weight 1250.5", ConsoleCommand::WeightGrams(1_250.5)),
            ("weight -40", ConsoleCommand::WeightGrams(-40.0)),
            ("drives power off", ConsoleCommand::DrivesPower(false)),
            (
                "drive right silent on",
                ConsoleCommand::DriveSilent {
                    wheel: Side::Right,
                    silent: true,
                },
            ),
            (
                "drive left silent off",
                ConsoleCommand::DriveSilent {
                    wheel: Side::Left,
                    silent: false,
                },
            ),
            ("reboot", ConsoleCommand::Reboot { by_watchdog: false }),
            (
                "reboot watchdog",
                ConsoleCommand::Reboot { by_watchdog: true },
            ),
            ("panic", ConsoleCommand::Panic),
            ("status # comments are allowed", ConsoleCommand::Status),
            ("help", ConsoleCommand::Help),
            ("quit", ConsoleCommand::Quit),
            ("exit", ConsoleCommand::Quit),
        ] {
            assert_eq!(parse_console_line(line), Ok(Some(command)), "{line}");
        }
    }

    #[test]
    fn the_help_is_indented_evenly_and_fits_80_columns() {
        for line in HELP.lines() {
            assert!(line.starts_with("  "), "{line:?}");
            assert!(line.len() <= 80, "{} columns: {line:?}", line.len());
        }
        assert!(HELP.contains("reboot [watchdog]"));
    }

    #[test]
    fn blank_lines_and_comments_do_nothing() {
        assert_eq!(parse_console_line(""), Ok(None));
        assert_eq!(parse_console_line("   "), Ok(None));
        assert_eq!(parse_console_line("# press the e-stop next"), Ok(None));
    }

    #[test]
    fn bad_lines_say_what_is_expected() {
        assert_eq!(
            parse_console_line("fly"),
            Err(ConsoleError::UnknownCommand("fly".into()))
        );
        for (line, usage) in [
            ("estop", "estop on|off"),
            ("estop maybe", "estop on|off"),
            ("zone on now", "zone on|off"),
            ("button", "button press [MS]"),
            ("button press 0", "button press [MS], MS from 1 to 60000"),
            (
                "button press 60001",
                "button press [MS], MS from 1 to 60000",
            ),
            ("button press -5", "button press [MS], MS from 1 to 60000"),
            ("battery 70000", "battery MV, MV from 0 to 65535"),
            ("battery", "battery MV"),
            ("weight heavy", "weight G, G a number of grams"),
            ("weight NaN", "weight G, G a number of grams"),
            ("drives power", "drives power on|off"),
            ("drives power 1", "drives power on|off"),
            ("drive middle silent on", "drive left|right silent on|off"),
            ("drive left silent", "drive left|right silent on|off"),
            ("drive left silent maybe", "drive left|right silent on|off"),
            ("reboot now", "reboot [watchdog]"),
            ("reboot watchdog twice", "reboot [watchdog]"),
            ("quit now", "status, help, quit and panic take no arguments"),
            (
                "panic now",
                "status, help, quit and panic take no arguments",
            ),
        ] {
            assert_eq!(
                parse_console_line(line),
                Err(ConsoleError::Usage(usage)),
                "{line}"
            );
        }
    }

    #[test]
    fn errors_read_as_sentences() {
        assert_eq!(
            ConsoleError::UnknownCommand("fly".into()).to_string(),
            "unknown command \"fly\" (type help for the list)"
        );
        assert_eq!(
            ConsoleError::Usage("estop on|off").to_string(),
            "usage: estop on|off"
        );
    }
}
