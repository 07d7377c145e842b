//! `info`: the controller in one shot: firmware and register-map versions, mode,
//! control source, flags, faults (flash among them), drive alarm, error counters,
//! battery, pose, and the connected remote with its battery.

use std::io::Write;
use std::time::{Duration, Instant};

use base_core::panic_loop::{LOOP_PANICS, SHORT_LIFE_MS};
use base_core::registers::{
    BLE_OFF_AFTER_HOST_STOPS, BLUETOOTH_ON_KEY, BootInfo, Charge, Reg, RemoteBattery, RemoteInfo,
    RemoteKind, UpdateReset,
};
use serde_json::{Value, json};

use crate::base::{Base, Error};
use crate::config::version_text;
use crate::firmware;
use crate::monitor::{fault_names, flag_names};
use crate::rejection;

/// The register map that brought `boot_info` (50).
const BOOT_INFO_REGMAP: u16 = 4;
/// How long the update's QUERY may take to tell the image's version: its replies come
/// within milliseconds; a firmware without the update never answers.
const IMAGE_QUERY_TIMEOUT: Duration = Duration::from_millis(500);

/// The `boot` line: how this boot came about, from `boot_info`.
fn boot_text(boot_info: Option<Option<BootInfo>>) -> String {
    let Some(read) = boot_info else {
        return "not reported by this firmware (no register 50)".to_owned();
    };
    let Some(info) = read else {
        return "boot_info holds bits this basectl does not know".to_owned();
    };
    let mut parts = Vec::new();
    if info.first_boot {
        parts.push("first boot: the register store was blank and now holds the defaults");
    }
    match info.update_reset {
        UpdateReset::None => {}
        UpdateReset::Activation => parts.push("started by an update (the new image's trial)"),
        UpdateReset::FailedTrial => {
            parts.push("rolled back: a new image's trial failed, the previous image runs")
        }
        UpdateReset::Refused => parts.push(
            "update refused: the bootloader did not load the image activated last, the previous image runs",
        ),
        UpdateReset::Held => parts.push(
            "HELD: an image nobody confirmed runs and nothing would roll it back; motion locked until `basectl firmware confirm` keeps it or `basectl firmware rollback` tries the other slot",
        ),
    }
    if parts.is_empty() {
        "normal".to_owned()
    } else {
        parts.join("; ")
    }
}

/// The longest `info` waits for the battery report (it comes every `volt_time`).
const LONGEST_LISTEN: Duration = Duration::from_secs(10);

/// The register map that brought `remote_kind` and `remote_battery` (34, 35): an
/// older firmware would refuse to read them.
const REMOTE_REGMAP: u16 = 4;

/// The Bluetooth remote's state, from `bluetooth_off` (36).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Bluetooth {
    On,
    OffAfterPanics,
    /// The BLE host stopped three times within a minute: BLE pads are off.
    BleOffAfterHostStops,
    /// A firmware older than register 36.
    Unknown,
}

impl Bluetooth {
    fn describe(self) -> String {
        match self {
            Bluetooth::On => "on".to_owned(),
            Bluetooth::OffAfterPanics => format!(
                "OFF after {LOOP_PANICS} panics, each within {} s of boot; turn it on with a \
                 confirm press of the front button or `basectl reg set command 0x{BLUETOOTH_ON_KEY:04X}`",
                SHORT_LIFE_MS / 1_000
            ),
            Bluetooth::BleOffAfterHostStops => format!(
                "BLE remote OFF: its host stopped 3 times within a minute (PlayStation pads \
                 still connect); turn it on with a confirm press of the front button or \
                 `basectl reg set command 0x{BLUETOOTH_ON_KEY:04X}`"
            ),
            Bluetooth::Unknown => "not reported by this firmware (no register 36)".to_owned(),
        }
    }
}

fn bluetooth_state(base: &mut Base) -> Result<Bluetooth, Error> {
    match base.read_register(Reg::BluetoothOff.address()) {
        Ok(0) => Ok(Bluetooth::On),
        Ok(BLE_OFF_AFTER_HOST_STOPS) => Ok(Bluetooth::BleOffAfterHostStops),
        // 1, and anything a later firmware may add: off.
        Ok(_) => Ok(Bluetooth::OffAfterPanics),
        Err(Error::ReadRefused { .. }) => Ok(Bluetooth::Unknown),
        Err(error) => Err(error),
    }
}

/// `boot_info`'s bits, or `None` from a firmware without register 50 (an early build
/// of register map 4 refuses to read it).
fn boot_info(base: &mut Base) -> Result<Option<Option<BootInfo>>, Error> {
    match base.read_register(Reg::BootInfo.address()) {
        Ok(bits) => Ok(Some(BootInfo::from_bits(bits))),
        Err(Error::ReadRefused { .. }) => Ok(None),
        Err(error) => Err(error),
    }
}

pub fn info(base: &mut Base, json_output: bool, out: &mut dyn Write) -> Result<(), Error> {
    let [firmware, regmap, volt_time] =
        base.read_registers([Reg::FwVersion, Reg::RegmapVersion, Reg::VoltTime])?;
    let boot_info = if regmap >= BOOT_INFO_REGMAP {
        boot_info(base)?
    } else {
        None
    };
    let remote = if regmap >= REMOTE_REGMAP {
        Some(base.read_registers([Reg::RemoteKind, Reg::RemoteBattery])?)
    } else {
        None
    };
    let bluetooth = bluetooth_state(base)?;
    // The whole version the image carries (its build stamp); a firmware without the
    // update does not answer QUERY.
    let running = firmware::query(base.bus(), IMAGE_QUERY_TIMEOUT).ok();
    let image = running.as_ref().map(|running| running.version.clone());
    let status = base.next_status()?;
    // The battery report comes every volt_time (5 s by default): wait for one.
    let listen = (Duration::from_millis(u64::from(volt_time)) + Duration::from_millis(500))
        .min(LONGEST_LISTEN);
    let deadline = Instant::now() + listen;
    while base.battery().is_none() || base.pose().is_none() {
        let remaining = deadline.saturating_duration_since(Instant::now());
        if remaining.is_zero() {
            break;
        }
        if base.next_report(remaining)?.is_none() {
            break;
        }
    }
    let flags = flag_names(&status.flags);
    let faults = fault_names(&status.faults);
    let last_rejection = rejection::name(status.last_rejection)
        .map_or_else(|| format!("0x{:02X}", status.last_rejection), str::to_owned);
    let battery = base.battery();
    let pose = base.pose();
    if json_output {
        let object = json!({
            "firmware_version": version_text(firmware),
            "firmware_image": image,
            "update_signatures_required": running.as_ref().map(|running| running.signatures_required),
            "security_version": running.as_ref().map(|running| running.security_version),
            "regmap_version": regmap,
            "mode": format!("{:?}", status.mode),
            "control": format!("{:?}", status.control),
            "flags": flags,
            "faults": faults,
            "flash_ok": !status.faults.flash,
            "first_boot": boot_info.flatten().map(|info| info.first_boot),
            "boot": boot_text(boot_info),
            "drive_alarm": status.drive_alarm,
            "rejected_count": status.rejected_count,
            "last_rejection": if status.last_rejection == 0 { None } else { Some(last_rejection) },
            "last_rejection_subject": status.last_rejection_subject,
            "modbus_errors": status.modbus_errors,
            "battery_percent": battery.map(|(percent, _)| percent),
            "battery_mv": battery.map(|(_, millivolts)| millivolts),
            "pose": pose.map(|pose| json!({"x_mm": pose.x_mm, "y_mm": pose.y_mm, "heading_mrad": pose.heading_mrad})),
            "weight_g": base.weight_g(),
            "remote": remote_json(remote),
            "bluetooth_off_after_panics": match bluetooth {
                Bluetooth::On | Bluetooth::BleOffAfterHostStops => Some(false),
                Bluetooth::OffAfterPanics => Some(true),
                Bluetooth::Unknown => None,
            },
            "ble_off_after_host_stops": match bluetooth {
                Bluetooth::Unknown => None,
                other => Some(other == Bluetooth::BleOffAfterHostStops),
            },
        });
        writeln!(out, "{object}")?;
        return Ok(());
    }
    let list = |names: &[&str]| {
        if names.is_empty() {
            "none".to_owned()
        } else {
            names.join(", ")
        }
    };
    let image = image.map_or_else(String::new, |version| format!(", image {version}"));
    writeln!(out, "firmware        {}{image}", version_text(firmware))?;
    writeln!(out, "register map    {regmap}")?;
    writeln!(out, "boot            {}", boot_text(boot_info))?;
    if let Some(running) = &running {
        writeln!(out, "updates         {}", running.trust_text())?;
    }
    writeln!(
        out,
        "mode            {:?} (control: {:?})",
        status.mode, status.control
    )?;
    writeln!(out, "flags           {}", list(&flags))?;
    writeln!(out, "faults          {}", list(&faults))?;
    writeln!(
        out,
        "flash           {}",
        if status.faults.flash {
            "FAULT (registers may be lost at power-off)"
        } else {
            "ok"
        }
    )?;
    writeln!(
        out,
        "drives          {}; last alarm code 0x{:02X}",
        if status.faults.left_drive_silent || status.faults.right_drive_silent {
            "not answering"
        } else if status.faults.left_drive_alarm || status.faults.right_drive_alarm {
            "ALARM"
        } else {
            "ok"
        },
        status.drive_alarm
    )?;
    writeln!(out, "bluetooth       {}", bluetooth.describe())?;
    writeln!(out, "modbus errors   {}", status.modbus_errors)?;
    writeln!(
        out,
        "rejected frames {} (last: {})",
        status.rejected_count,
        if status.last_rejection == 0 {
            "none".to_owned()
        } else {
            format!(
                "{last_rejection} on 0x{:02X}",
                status.last_rejection_subject
            )
        }
    )?;
    match battery {
        Some((percent, millivolts)) => {
            writeln!(out, "battery         {millivolts} mV, {percent} %")?
        }
        None => writeln!(
            out,
            "battery         no report within {} ms",
            listen.as_millis()
        )?,
    }
    match pose {
        Some(pose) => writeln!(
            out,
            "pose            x {} mm, y {} mm, heading {} mrad",
            pose.x_mm, pose.y_mm, pose.heading_mrad
        )?,
        None => writeln!(
            out,
            "pose            no report within {} ms",
            listen.as_millis()
        )?,
    }
    writeln!(out, "remote          {}", remote_text(remote, regmap))?;
    Ok(())
}

fn kind_name(kind: RemoteKind) -> &'static str {
    match kind {
        RemoteKind::None => "none",
        RemoteKind::BlePad => "BLE pad",
        RemoteKind::DualShock4 => "DualShock 4",
        RemoteKind::DualSense => "DualSense",
    }
}

fn charge_name(charge: Charge) -> &'static str {
    match charge {
        Charge::LevelOnly => "",
        Charge::Discharging => " (on battery)",
        Charge::Charging => " (charging)",
        Charge::Full => " (charged)",
        Charge::Fault => " (CHARGING FAULT)",
    }
}

/// The `remote` line from `remote_kind` and `remote_battery`; `registers` is `None` when
/// the firmware's register map (`regmap`) has no such registers.
fn remote_text(registers: Option<[u16; 2]>, regmap: u16) -> String {
    let Some([kind, battery]) = registers else {
        return format!("not reported (register map {regmap}, needs {REMOTE_REGMAP})");
    };
    let Some(remote) = RemoteInfo::from_registers(kind, battery) else {
        return format!("unknown kind {kind} (a newer firmware?)");
    };
    match (remote.kind, remote.battery) {
        (RemoteKind::None, _) => "none connected".to_owned(),
        (kind, None) => format!("{}, battery not known", kind_name(kind)),
        (kind, Some(RemoteBattery { percent, charge })) => format!(
            "{}, battery {percent} %{}",
            kind_name(kind),
            charge_name(charge)
        ),
    }
}

/// `info --json`'s `remote`: `null` when the firmware does not report it, else the
/// kind (`None`, `BlePad`, `DualShock4`, `DualSense`, or the unknown code) and the
/// battery (`null` when not known).
fn remote_json(registers: Option<[u16; 2]>) -> Value {
    let Some([kind, battery]) = registers else {
        return Value::Null;
    };
    let Some(remote) = RemoteInfo::from_registers(kind, battery) else {
        return json!({ "kind": kind, "battery": null });
    };
    json!({
        "kind": format!("{:?}", remote.kind),
        "battery": remote.battery.map(|battery| json!({
            "percent": battery.percent,
            "charge": format!("{:?}", battery.charge),
        })),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_remote_line_names_the_pad_and_its_battery() {
        // (remote_kind, remote_battery) → the line
        let table = [
            ([0, 0], "none connected"),
            ([1, 0], "BLE pad, battery not known"),
            ([1, 0x0137], "BLE pad, battery 55 %"),
            ([2, 0x0250], "DualShock 4, battery 80 % (on battery)"),
            ([3, 0x0323], "DualSense, battery 35 % (charging)"),
            ([3, 0x0464], "DualSense, battery 100 % (charged)"),
            ([3, 0x0500], "DualSense, battery 0 % (CHARGING FAULT)"),
            // A battery value the firmware never writes reads as not known.
            ([2, 0x0900], "DualShock 4, battery not known"),
            ([9, 0], "unknown kind 9 (a newer firmware?)"),
        ];
        for (registers, line) in table {
            assert_eq!(remote_text(Some(registers), 4), line, "{registers:04X?}");
        }
        assert_eq!(
            remote_text(None, 3),
            "not reported (register map 3, needs 4)"
        );
    }

    #[test]
    fn the_boot_line_says_what_an_update_did() {
        let line = |bits| boot_text(Some(BootInfo::from_bits(bits)));
        assert_eq!(line(0), "normal");
        assert!(line(0b10).starts_with("started by an update"));
        assert!(line(0b100).starts_with("rolled back"));
        // A refused image: the previous one runs, nothing is on trial.
        assert_eq!(
            line(0b1000),
            "update refused: the bootloader did not load the image activated last, \
             the previous image runs"
        );
        assert!(line(0b1001).starts_with("first boot"));
        assert!(line(0b1_0000).starts_with("HELD"));
        assert_eq!(
            line(0b1100),
            "boot_info holds bits this basectl does not know"
        );
    }

    #[test]
    fn the_remote_in_json_has_kind_and_battery_or_null() {
        assert_eq!(remote_json(None), Value::Null);
        assert_eq!(
            remote_json(Some([0, 0])),
            json!({"kind": "None", "battery": null})
        );
        assert_eq!(
            remote_json(Some([3, 0x0323])),
            json!({"kind": "DualSense", "battery": {"percent": 35, "charge": "Charging"}})
        );
        assert_eq!(
            remote_json(Some([1, 0x0137])),
            json!({"kind": "BlePad", "battery": {"percent": 55, "charge": "LevelOnly"}})
        );
        assert_eq!(
            remote_json(Some([7, 0])),
            json!({"kind": 7, "battery": null})
        );
    }
}
