//! ESP32 (the robot's board: ESP32-DevKitC with an ESP32-WROOM-32 module, 4 MB flash).
//!
//! Kept free: GPIO6–11 (SPI flash), GPIO1/3 (UART0: flashing and the defmt log over
//! the devkit's USB bridge), the strapping pins GPIO0, 2, 5, 12 and 15, and ADC2's
//! pins for analog use (ADC2 is the radio's). The input-only pins GPIO34–39 have no
//! internal pulls, so only the battery's analog input uses one of them.
//!
//! Built with the `esp` toolchain (espup); docs/flashing.md walks through it. CI type-checks
//! and lints it without espup (`.ci/esp32-check`).
//!
//! The radio runs in dual mode (BLE and Bluetooth Classic at once) so that PlayStation
//! pads can connect beside BLE pads: see [`bt_dual_mode`].

use esp_hal::analog::adc::{Adc, AdcConfig, Attenuation};
use esp_hal::peripherals::{FLASH, GPIO34, Peripherals};
use esp_hal::rtc_cntl::SocResetReason;
use esp_storage::FlashStorage;

use super::{BATTERY_DIVIDER, Board};
use crate::battery::BatteryAdc;

pub const CHIP: &str = "ESP32";

/// GPIO34 is ADC1 channel 6. esp-hal has no calibration scheme for the original ESP32,
/// so the reading is raw (12 bits).
pub type Battery = BatteryAdc<GPIO34<'static>, ()>;

/// At 11 dB the ESP32's ADC spans about 0–3.1 V over 0–4095 and is close to linear
/// between 0.15 and 2.45 V, where the battery divider keeps the pin. Uncalibrated
/// parts differ by a few percent: trim with the battery registers if needed.
fn raw_to_pin_millivolts(raw: u16) -> u16 {
    (u32::from(raw) * 3_100 / 4_095) as u16
}

pub fn take(p: Peripherals) -> Board {
    let mut adc_config = AdcConfig::new();
    let battery_pin = adc_config.enable_pin(p.GPIO34, Attenuation::_11dB);
    let battery = BatteryAdc::new(
        Adc::new(p.ADC1, adc_config),
        battery_pin,
        raw_to_pin_millivolts,
        BATTERY_DIVIDER,
    );
    Board {
        twai: p.TWAI0,
        can_tx: p.GPIO25.into(),
        can_rx: p.GPIO26.into(),
        drives_uart: p.UART1,
        drives_tx: p.GPIO17.into(),
        drives_rx: p.GPIO16.into(),
        drives_de: p.GPIO4.into(),
        hx711_dout: p.GPIO19.into(),
        hx711_sck: p.GPIO18.into(),
        battery,
        estop: p.GPIO27.into(),
        safety_zone: p.GPIO32.into(),
        button: p.GPIO33.into(),
        pc_switch: p.GPIO23.into(),
        status_led: p.GPIO22.into(),
        bt: p.BT,
        flash: flash_storage(p.FLASH),
        rtc: p.RTC_TIMER,
        timg0: p.TIMG0,
        scheduler_interrupt: p.FROM_CPU_INTR0,
    }
}

/// The flash, set up for this chip. The second core is not started, but a flash write
/// must never run while it fetches from flash: park it if it ever runs.
pub fn flash_storage(flash: FLASH<'_>) -> FlashStorage<'_> {
    FlashStorage::new(flash).multicore_auto_park()
}

/// Whether a watchdog caused the last reset.
pub fn reset_by_watchdog(reason: Option<SocResetReason>) -> bool {
    use SocResetReason::*;
    matches!(
        reason,
        Some(CoreMwdt0 | CoreMwdt1 | CoreRtcWdt | CpuMwdt0 | Cpu0RtcWdt | SysRtcWdt)
    )
}

/// A software reset: the panic handler's (the firmware does not reset itself otherwise).
pub fn reset_by_software(reason: Option<SocResetReason>) -> bool {
    use SocResetReason::*;
    matches!(reason, Some(CoreSw | Cpu0Sw))
}

/// Bluetooth dual mode on the ESP32.
///
/// esp-radio starts the ESP32's Bluetooth controller for BLE only: it fills the
/// controller's configuration with mode BLE and no Classic links, and enables it with
/// mode BLE. The controller library it links (`libbtdm_app.a`) has the whole Classic
/// controller, and esp-hal already keeps the Classic controller's memory free. So
/// instead of carrying a changed copy of esp-radio, the build script asks the linker to
/// wrap the two controller calls (`--wrap=btdm_controller_init`,
/// `--wrap=btdm_controller_enable`): esp-radio's calls land in the two functions below,
/// which change the mode and the Classic fields and then call the library's own
/// functions (`__real_…`). Nothing else in esp-radio changes; BLE works as before.
///
/// The configuration type is the one esp-radio fills: `esp_bt_controller_config_t`
/// from the same `esp-wifi-sys-esp32` bindings (one version in the build; check
/// `firmware/Cargo.lock` when esp-radio moves). docs/decisions.md says why this way
/// and docs/remote.md what only a board can prove.
#[cfg(not(feature = "ble-only"))]
mod bt_dual_mode {
    use core::sync::atomic::{AtomicBool, Ordering};

    use esp_wifi_sys_esp32::include::{
        esp_bt_controller_config_t, esp_bt_mode_t, esp_bt_mode_t_ESP_BT_MODE_BLE,
        esp_bt_mode_t_ESP_BT_MODE_BTDM,
    };

    /// Classic (BR/EDR) links the controller keeps room for: one pad, and one more so
    /// that a second pad paging us while the first is connected can be refused properly
    /// instead of finding no room. The controller accepts 1 to 7.
    pub const CLASSIC_LINKS: u8 = 2;

    /// Synchronous (voice) links: none. The Classic memory esp-hal keeps free and
    /// esp-radio clears at start assumes none; each would need about 1 KiB more.
    pub const VOICE_LINKS: u8 = 0;

    unsafe extern "C" {
        fn __real_btdm_controller_init(
            config_mask: u32,
            config: *mut esp_bt_controller_config_t,
        ) -> i32;
        fn __real_btdm_controller_enable(mode: esp_bt_mode_t) -> i32;
    }

    /// The Classic fields of a BLE-only configuration set for dual mode; the BLE
    /// fields stay what esp-radio chose.
    pub fn dual_mode(ble_only: esp_bt_controller_config_t) -> esp_bt_controller_config_t {
        esp_bt_controller_config_t {
            mode: esp_bt_mode_t_ESP_BT_MODE_BTDM as u8,
            bt_max_acl_conn: CLASSIC_LINKS,
            bt_max_sync_conn: VOICE_LINKS,
            // The controller reports a legacy (pre-Secure Simple Pairing) authentication
            // with a vendor event, so the host can refuse it (the BIAS attack); ESP-IDF
            // turns it on for Classic and dual mode.
            bt_legacy_auth_vs_evt: true,
            ..ble_only
        }
    }

    /// Whether the controller was started in dual mode, for the enable that follows.
    static DUAL_MODE: AtomicBool = AtomicBool::new(false);

    /// esp-radio's `btdm_controller_init`, after `--wrap`. Should the controller refuse
    /// dual mode, it is started again with esp-radio's BLE-only configuration: esp-radio
    /// panics on a failed start, and a panic at every boot would keep the base from
    /// driving over CAN too.
    ///
    /// # Safety
    ///
    /// Only the linker calls this, in place of the library's function and with its
    /// arguments: `config` points to a filled configuration.
    #[unsafe(no_mangle)]
    unsafe extern "C" fn __wrap_btdm_controller_init(
        config_mask: u32,
        config: *const esp_bt_controller_config_t,
    ) -> i32 {
        // SAFETY: esp-radio passes its own, filled configuration; it is only read, and
        // the controller copies ours during the call (esp-radio's is a local too).
        let mut ble_only = unsafe { config.read() };
        let mut dual = dual_mode(ble_only);
        // SAFETY: the library's own function with a valid configuration.
        let result = unsafe { __real_btdm_controller_init(config_mask, &mut dual) };
        if result == 0 {
            DUAL_MODE.store(true, Ordering::Relaxed);
            defmt::info!(
                "Bluetooth controller in dual mode: BLE and {} Classic links",
                CLASSIC_LINKS
            );
            return result;
        }
        defmt::error!(
            "Bluetooth controller refused dual mode ({}): BLE only, no PlayStation pads",
            result
        );
        // SAFETY: as above, with esp-radio's own configuration.
        unsafe { __real_btdm_controller_init(config_mask, &mut ble_only) }
    }

    /// esp-radio's `btdm_controller_enable(BLE)`, after `--wrap`: the controller must be
    /// enabled with the mode it was started with.
    ///
    /// # Safety
    ///
    /// Only the linker calls this, in place of the library's function.
    #[unsafe(no_mangle)]
    unsafe extern "C" fn __wrap_btdm_controller_enable(mode: esp_bt_mode_t) -> i32 {
        let mode = if mode == esp_bt_mode_t_ESP_BT_MODE_BLE && DUAL_MODE.load(Ordering::Relaxed) {
            esp_bt_mode_t_ESP_BT_MODE_BTDM
        } else {
            mode
        };
        // SAFETY: the library's own function, called once after its init as before.
        unsafe { __real_btdm_controller_enable(mode) }
    }
}
