//! The base controller's firmware: initialises the chip, hands every peripheral to its
//! implementation of the library's hardware traits, and runs the library's tasks. The
//! board files (`board/`) say which pin does what.
#![no_std]
#![no_main]

use core::ops::Range;

use base_core::registers::UpdateReset;
use base_runtime::hx711::{Gain, Hx711};
use base_runtime::{Hardware, Settings, ble, channels::Channels};
use defmt::{error, info, warn};
use embassy_embedded_hal::adapter::BlockingAsync;
use embassy_futures::join::join3;
use esp_backtrace as _;
use esp_hal::clock::CpuClock;
use esp_hal::delay::Delay;
use esp_hal::efuse::{self, InterfaceMacAddress};
use esp_hal::gpio::{Input, InputConfig, Level, Output, OutputConfig, Pull};
use esp_hal::timer::timg::TimerGroup;
use esp_println as _;
use esp_radio::ble::controller::BleConnector;
use static_cell::StaticCell;

use base_controller_firmware::board::{
    self, BUTTON_PULL, ESTOP_PULL, SAFETY_ZONE_PULL, panic_record,
};
use base_controller_firmware::flash::{self, FlashPartition, SharedFlash};
use base_controller_firmware::rs485::Rs485Port;
use base_controller_firmware::watchdog::LivenessWatchdog;
use base_controller_firmware::{can, update, watchdog};

// The application descriptor the ESP-IDF bootloader checks before it starts the image.
// The app descriptor, with the version the build stamped (firmware/build.rs).
esp_bootloader_esp_idf::esp_app_desc!(
    env!("BASE_FIRMWARE_VERSION"),
    env!("CARGO_PKG_NAME"),
    esp_bootloader_esp_idf::BUILD_TIME,
    esp_bootloader_esp_idf::BUILD_DATE,
    esp_bootloader_esp_idf::ESP_IDF_COMPATIBLE_VERSION,
    esp_bootloader_esp_idf::MMU_PAGE_SIZE,
    0,
    u16::MAX,
    update::SECURITY_VERSION
);

/// The heap the radio's driver allocates from (nothing else allocates). trouble's
/// examples use 72 KiB on these chips.
const HEAP_SIZE: usize = 72 * 1024;
/// HCI command slots between trouble-host and the radio.
const HCI_SLOTS: usize = 20;

static CHANNELS: Channels = Channels::new();
static FLASH: StaticCell<SharedFlash> = StaticCell::new();

#[esp_rtos::main]
async fn main(_spawner: embassy_executor::Spawner) {
    // The radio wants the fastest clock.
    let mut peripherals = esp_hal::init(esp_hal::Config::default().with_cpu_clock(CpuClock::max()));
    // First of all, before anything that can fail: esp_hal::init stopped the
    // bootloader's watchdog, so ours guards the start from here, and a new image arms
    // its trial, so that a panic or a hang anywhere below boots the previous image.
    watchdog::guard_start(peripherals.RTC_TIMER.reborrow());
    let armed = update::arm_first(peripherals.FLASH.reborrow()).await;
    esp_alloc::heap_allocator!(size: HEAP_SIZE);
    let reset_reason = esp_hal::system::reset_reason();
    // A software reset is the panic handler's (see `custom_halt`).
    let bluetooth = panic_record::at_boot(board::reset_by_software(reset_reason));
    let mut board = board::take(peripherals);
    let watchdog = LivenessWatchdog::start(board.rtc, board.status_led);
    esp_rtos::start(
        TimerGroup::new(board.timg0).timer0,
        board.scheduler_interrupt,
    );
    info!(
        "base controller {} on {}, CAN at {} kbit/s, reset reason {}",
        env!("BASE_FIRMWARE_VERSION"),
        board::CHIP,
        can::BIT_RATE_KBIT,
        defmt::Debug2Format(&reset_reason)
    );

    let settings = Settings {
        inputs: board::INPUTS,
        ..Settings::DEFAULT
    };

    let registers = flash::find(&mut board.flash, flash::REGISTERS);
    let bonds = flash::find(&mut board.flash, flash::BONDS);
    for (spec, found) in [(flash::REGISTERS, &registers), (flash::BONDS, &bonds)] {
        if found.is_none() {
            error!(
                "no `{}` partition: flash with firmware/partitions.csv",
                spec.label
            );
        }
    }
    let shared_flash = FLASH.init(SharedFlash::new(BlockingAsync::new(board.flash)));
    let (flash, flash_range) = flash::partition(shared_flash, flash::REGISTERS, registers);
    let (bond_flash, bond_range) = flash::partition(shared_flash, flash::BONDS, bonds);

    // Updates over CAN, with what the arming found (above); the record of an update's
    // reset before this boot becomes `boot_info`. Without an app slot (a board still
    // on the old partition table) there are no updates.
    let mut update_flash = None;
    let mut update_reset = UpdateReset::None;
    if let Some((slot, started)) = armed {
        let whole = embassy_embedded_hal::flash::partition::Partition::new(
            shared_flash,
            0,
            base_core::update::partitions::FLASH_SIZE,
        );
        let flash = base_runtime::update::UpdateFlash::new(whole, slot);
        base_runtime::update::report_start(&started);
        CHANNELS.update.lock_at_start(&started);
        let boot = update::boot_cause(&started, slot);
        update_reset = boot.cause;
        update_flash = Some((flash, started, boot.trial_owner));
    }

    let (can_rx, can_tx) = can::start(board.twai, board.can_tx, board.can_rx);
    let drives = match Rs485Port::new(
        board.drives_uart,
        board.drives_tx,
        board.drives_rx,
        board.drives_de,
        &settings.drives.line,
    ) {
        Ok(port) => port,
        // Only an impossible baud rate fails, and DriveSettings fixes the rate at build
        // time: a build error in all but name.
        Err(error) => panic!("drive UART: {:?}", error),
    };

    let input = |pin, pull: Pull| Input::new(pin, InputConfig::default().with_pull(pull));
    let hardware = Hardware {
        can_rx,
        can_tx,
        drives,
        flash,
        flash_range,
        estop: input(board.estop, ESTOP_PULL),
        safety_zone: input(board.safety_zone, SAFETY_ZONE_PULL),
        button: input(board.button, BUTTON_PULL),
        pc_switch: Output::new(board.pc_switch, Level::Low, OutputConfig::default()),
        battery: board.battery,
        load_cell: Hx711::new(
            Input::new(board.hx711_dout, InputConfig::default()),
            Output::new(board.hx711_sck, Level::Low, OutputConfig::default()),
            Delay::new(),
            Gain::ChannelA128,
        ),
        watchdog,
        // A software reset is a panic (see `custom_halt`) unless an update caused it (the
        // activation, or a trial that failed): the status frame reports a panic as an
        // abnormal reset, `boot_info` the update's resets.
        reset_by_watchdog: update_reset == UpdateReset::None
            && (board::reset_by_watchdog(reset_reason) || board::reset_by_software(reset_reason)),
        bluetooth,
        update_reset,
    };
    if hardware.reset_by_watchdog {
        warn!(
            "last reset by a watchdog (timeout {} ms) or a panic",
            watchdog::TIMEOUT.as_millis()
        );
    }

    let remote = async {
        // After a panic loop the radio stays untouched until Bluetooth is turned on.
        ble::wait_until_on(
            bluetooth,
            &CHANNELS.remote_requests,
            panic_record::turned_on,
        )
        .await;
        match BleConnector::new(board.bt, Default::default()) {
            Ok(connector) => {
                let mac = efuse::interface_mac_address(InterfaceMacAddress::Bluetooth);
                let address = ble::random_static_address(mac.as_bytes());
                run_remote(connector, address, bond_flash, bond_range).await
            }
            Err(error) => {
                // Without the radio the base still drives over CAN; the status frame
                // shows no remote.
                error!("Bluetooth radio: {}", defmt::Debug2Format(&error));
                core::future::pending::<()>().await
            }
        }
    };
    // The update task returns when the chip must restart (activated or rolled back):
    // the cause is recorded for the next boot first.
    let update = async {
        let Some((mut flash, started, trial_owner)) = update_flash else {
            return core::future::pending().await;
        };
        let config = base_runtime::update::UpdateConfig {
            chip: update::CHIP,
            project: base_runtime::update::PROJECT,
            version: env!("BASE_FIRMWARE_VERSION"),
            security_version: update::SECURITY_VERSION,
            trust: update::TRUST,
            trial_deadline_ms: base_runtime::update::TRIAL_DEADLINE_MS,
        };
        let reset = base_runtime::update::run(
            &mut flash,
            started,
            trial_owner,
            &config,
            &CHANNELS.update,
            &CHANNELS.can_tx,
        )
        .await;
        info!("update: {}: restarting", reset);
        update::record_reset(reset);
        esp_hal::system::software_reset()
    };
    let (never, (), ()) = join3(
        base_runtime::run(hardware, settings, &CHANNELS),
        remote,
        update,
    )
    .await;
    never
}

/// The remote on the ESP32's dual-mode radio (`board/esp32.rs`): BLE pads and
/// PlayStation pads over Classic, both hosts on the one HCI through the splitter.
#[cfg(all(feature = "esp32", not(feature = "ble-only")))]
async fn run_remote(
    connector: BleConnector<'_>,
    address: [u8; 6],
    bond_flash: FlashPartition,
    bond_range: Range<u32>,
) -> ! {
    base_runtime::classic::run_both::<_, _, HCI_SLOTS>(
        &connector,
        address,
        bond_flash,
        bond_range,
        CHANNELS.remote_ends(),
    )
    .await
}

/// The remote on a BLE-only radio (ESP32-C3, ESP32-C6, the ESP32 built `ble-only`).
#[cfg(not(all(feature = "esp32", not(feature = "ble-only"))))]
async fn run_remote(
    connector: BleConnector<'_>,
    address: [u8; 6],
    bond_flash: FlashPartition,
    bond_range: Range<u32>,
) -> ! {
    let controller: trouble_host::prelude::ExternalController<_, HCI_SLOTS> =
        trouble_host::prelude::ExternalController::new(connector);
    ble::run(
        controller,
        address,
        bond_flash,
        bond_range,
        CHANNELS.remote_ends(),
    )
    .await
}
