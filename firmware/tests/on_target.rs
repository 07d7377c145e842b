//! On-target tests: the firmware's own code against the real chip. They need a board
//! on a debug probe (the C3's and C6's built-in USB-JTAG will do) and probe-rs:
//! `cargo test-esp32c3` (see the README). Run them on a bench board, not on the
//! robot: the CAN test sends frames, and the flash test writes a register (and puts
//! its value back).
#![no_std]
#![no_main]

use defmt_rtt as _;
// The radio driver in the firmware's dependencies needs a global allocator to link;
// these tests allocate nothing.
use esp_alloc as _;
use esp_backtrace as _;

esp_bootloader_esp_idf::esp_app_desc!();

#[embedded_test::tests(default_timeout = 10)]
mod tests {
    use base_controller_firmware::flash::{self, SharedFlash};
    use base_controller_firmware::{board, can};
    use base_core::can::filter::COMMAND_FILTERS;
    use base_core::can::id;
    use base_core::registers::Reg;
    use base_runtime::store::RegisterStore;
    use embassy_embedded_hal::adapter::BlockingAsync;
    use embassy_futures::block_on;
    use esp_hal::peripherals::Peripherals;
    use esp_hal::time::{Duration, Instant};
    use esp_hal::twai::{BaudRate, EspTwaiFrame, StandardId, TwaiConfiguration, TwaiMode};
    use static_cell::StaticCell;

    #[init]
    fn init() -> Peripherals {
        esp_hal::init(esp_hal::Config::default())
    }

    /// The partition table espflash wrote has the register store's partition, and a
    /// value written through the library's store on it is what a fresh load reads.
    #[test]
    fn a_register_written_to_the_partition_survives_a_reload(peripherals: Peripherals) {
        static FLASH: StaticCell<SharedFlash> = StaticCell::new();
        let mut board = board::take(peripherals);
        let found = flash::find(&mut board.flash, flash::REGISTERS);
        assert!(found.is_some(), "no registers partition");
        let shared = FLASH.init(SharedFlash::new(BlockingAsync::new(board.flash)));
        let (partition, range) = flash::partition(shared, flash::REGISTERS, found);

        block_on(async {
            let mut store = RegisterStore::new(partition.clone(), range.clone());
            let (before, _) = store.load().await;
            let original = before.get(Reg::BattFullMv);
            let changed = if original == 25_600 { 25_500 } else { 25_600 };
            store
                .write(Reg::BattFullMv.address(), changed)
                .await
                .unwrap();

            let mut reloaded = RegisterStore::new(partition.clone(), range.clone());
            let (after, report) = reloaded.load().await;
            assert_eq!(after.get(Reg::BattFullMv), changed);
            assert_eq!(report.rejected, 0);

            reloaded
                .write(Reg::BattFullMv.address(), original)
                .await
                .unwrap();
        });
    }

    /// The TWAI's acceptance filter, set from the library's filters, passes exactly the
    /// IDs the library's model of it accepts: every command, and none of the reports
    /// the model rejects. The controller receives its own frames in self-test mode,
    /// looped back inside the chip.
    #[test]
    fn the_hardware_filter_passes_what_the_library_filter_accepts(peripherals: Peripherals) {
        let board = board::take(peripherals);
        // SAFETY: the pin is used for nothing else in this test.
        let (rx, tx) = unsafe { board.can_tx.split() };
        let mut config =
            TwaiConfiguration::new(board.twai, rx, tx, BaudRate::B500K, TwaiMode::SelfTest);
        config.set_filter(can::command_filter());
        let mut twai = config.start();

        for &raw in id::COMMANDS.iter().chain(id::REPORTS.iter()) {
            let id = StandardId::new(raw).unwrap();
            let frame = EspTwaiFrame::new_self_reception(id, &[0x01]).unwrap();
            nb::block!(twai.transmit(&frame)).unwrap();

            let deadline = Instant::now() + Duration::from_millis(10);
            let received = loop {
                match twai.receive() {
                    Ok(frame) => break Some(frame),
                    Err(nb::Error::WouldBlock) if Instant::now() < deadline => {}
                    Err(nb::Error::WouldBlock) => break None,
                    Err(nb::Error::Other(error)) => panic!("{:?}", error),
                }
            };
            let accepted = COMMAND_FILTERS.iter().any(|filter| filter.accepts(raw));
            defmt::assert_eq!(received.is_some(), accepted, "ID {=u16:#x}", raw);
        }
    }

    /// How long the ed25519 check FINISH makes for a build with a key takes on this
    /// chip (docs/flashing.md quotes it), and that it passes a good signature and
    /// refuses a changed one.
    #[test]
    fn an_image_signature_is_checked_and_timed() {
        use base_core::update::signature::{self, Trust};
        let secret = [7; 32];
        let digest = [0x5A; 32];
        let keys = [signature::public_key(&secret)];
        let block = signature::sign_digest(&digest, &secret, 0);
        let started = Instant::now();
        let verdict = signature::check(Trust::Keys(&keys), Some(&block), &digest, 0, 0);
        let took = started.elapsed();
        defmt::assert!(verdict.is_ok());
        defmt::info!("ed25519 check at FINISH: {=u64} us", took.as_micros());
        let mut changed = digest;
        changed[0] ^= 1;
        let verdict = signature::check(Trust::Keys(&keys), Some(&block), &changed, 0, 0);
        defmt::assert!(verdict.is_err());
    }
}
