//! The base controller running: async tasks that own the hardware (through the traits
//! of [`hw`]) and move values between it and the core's [`Controller`]. They decide
//! nothing themselves; every decision is in `base-core`.
//!
//! ```text
//!   CanRx ──frames──┐                                  ┌──▶ can_tx ──▶ CanTx
//!   inputs (pins) ──┤                                  │
//!   battery, scale ─┼──▶ inputs ──▶ controller task ───┼──▶ drive_demand ──▶ drive link ◀──▶ RS-485
//!   drive link ─────┤    (queue)   (Controller::handle)│      (signal)          │
//!   BLE remote ─────┘                                  ├──▶ pending_writes ──▶ store ◀──▶ flash
//!                                                      └──▶ PC power switch pin
//!   controller, drive link, inputs ──check-in──▶ liveness ──▶ watchdog
//! ```
//!
//! Every task is an `async fn` generic over its hardware; [`run`] joins them into one
//! future. The chip shell spawns that future on its executor; the virtual robot runs
//! it under a virtual clock. Neither adds logic.

#![cfg_attr(not(test), no_std)]

// First, so that every module below can log.
#[macro_use]
mod fmt;

pub mod ble;
pub mod can;
pub mod channels;
#[cfg(feature = "classic")]
pub mod classic;
pub mod control;
pub mod drive_link;
pub mod hw;
pub mod hx711;
pub mod inputs;
pub mod liveness;
pub mod sensors;
pub mod store;
pub mod sync;
pub mod update;

use embassy_futures::join::{join, join4, join5};

use base_core::controller::{BootReport, Controller};
use base_core::drives::DriveSettings;
use base_core::panic_loop::Bluetooth;
use base_core::registers::{BootInfo, UpdateReset};

use crate::channels::Channels;
use crate::hw::{
    BatteryVoltage, CanRx, CanTx, InputPin, LoadCell, NorFlash, OutputPin, Rs485, Watchdog,
};
use crate::store::RegisterStore;

pub use inputs::{ActiveLevel, InputSettings};

/// Every piece of hardware the tasks use, as the board provides it.
pub struct Hardware<CR, CT, P, F, E, Z, B, S, V, L, W> {
    pub can_rx: CR,
    pub can_tx: CT,
    /// The RS-485 line to the drives.
    pub drives: P,
    /// The register store's flash and the byte range of its partition.
    pub flash: F,
    pub flash_range: core::ops::Range<u32>,
    pub estop: E,
    pub safety_zone: Z,
    pub button: B,
    /// The output that closes the PC's power switch (high = closed).
    pub pc_switch: S,
    pub battery: V,
    pub load_cell: L,
    pub watchdog: W,
    /// The chip's reset reason says the watchdog bit.
    pub reset_by_watchdog: bool,
    /// Whether the Bluetooth remote may start at this boot: off after a panic loop
    /// ([`base_core::panic_loop`]), which the controller reports.
    pub bluetooth: Bluetooth,
    /// A reset the firmware caused on purpose for an update (recorded before it reset,
    /// see [`base_core::update::trial::boot_cause`]).
    pub update_reset: UpdateReset,
}

/// What the board knows about its wiring and the drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Settings {
    pub drives: DriveSettings,
    pub inputs: InputSettings,
}

impl Settings {
    pub const DEFAULT: Settings = Settings {
        drives: DriveSettings::DEFAULT,
        inputs: InputSettings::DEFAULT,
    };
}

impl Default for Settings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Loads the registers, then runs every task forever.
pub async fn run<CR, CT, P, F, E, Z, B, S, V, L, W>(
    hardware: Hardware<CR, CT, P, F, E, Z, B, S, V, L, W>,
    settings: Settings,
    channels: &Channels,
) -> !
where
    CR: CanRx,
    CT: CanTx,
    P: Rs485,
    F: NorFlash,
    E: InputPin,
    Z: InputPin,
    B: InputPin,
    S: OutputPin,
    V: BatteryVoltage,
    L: LoadCell,
    W: Watchdog,
{
    let mut store = RegisterStore::new(hardware.flash, hardware.flash_range);
    let (registers, report) = store.load().await;
    info!(
        "registers: {=u16} stored, {=u16} rejected, {=u16} dropped, blank store: {=bool}, first boot: {=bool}",
        report.applied, report.rejected, report.dropped, report.blank, report.first_boot
    );
    if hardware.reset_by_watchdog {
        warn!("the watchdog reset the chip");
    }
    let boot = BootReport {
        flash_fault: report.flash_fault(),
        watchdog_reset: hardware.reset_by_watchdog,
        flash_erases: store.erases(),
        bluetooth_off_after_panics: hardware.bluetooth == Bluetooth::OffAfterPanics,
        boot_info: BootInfo {
            first_boot: report.first_boot,
            update_reset: hardware.update_reset,
        },
    };
    let controller = Controller::boot(control::core_now(), registers, &boot);
    let ((never, ..), ..) = join(
        join5(
            control::run(controller, channels.control_ends(), hardware.pc_switch),
            drive_link::run(hardware.drives, settings.drives, channels.drive_link_ends()),
            can::run_rx(hardware.can_rx, channels.inputs.sender(), &channels.update),
            can::run_tx(hardware.can_tx, &channels.can_tx, channels.inputs.sender()),
            inputs::run(
                inputs::InputPins {
                    estop: hardware.estop,
                    safety_zone: hardware.safety_zone,
                    button: hardware.button,
                },
                settings.inputs,
                channels.inputs.sender(),
                &channels.liveness,
            ),
        ),
        join4(
            store::run(
                &mut store,
                &channels.pending_writes,
                channels.inputs.sender(),
            ),
            sensors::run_battery(hardware.battery, channels.inputs.sender()),
            sensors::run_scale(hardware.load_cell, channels.inputs.sender()),
            liveness::run(hardware.watchdog, &channels.liveness),
        ),
    )
    .await;
    never
}
