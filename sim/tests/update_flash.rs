//! The update task's flash work next to the control cycle: the chip runs nothing while
//! its flash erases or programs, so the task yields after the erase and after each
//! page, and a control cycle that fell due meanwhile runs there instead of after the
//! whole window's flash work. And the order of an otadata entry's program operations.

use core::cell::RefCell;

use base_core::update::otadata::Slot;
use base_core::update::partitions;
use base_runtime::update::UpdateFlash;
use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Instant, Timer};
use embedded_storage_async::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use virtual_robot::flash::{FlashTiming, RamFlash};
use virtual_robot::runtime::{block_on, now};

/// The longest time between the runs of a task that wants to run every millisecond,
/// while one 4 KiB window is erased, written and read back.
fn longest_gap_while_a_window_is_written(timing: FlashTiming) -> Duration {
    let flash = RamFlash::new(partitions::FLASH_SIZE as usize);
    flash.set_timing(timing);
    let mut update_flash = UpdateFlash::new(flash.clone(), Slot::Ota0);
    let window = [0x5A; 4096];
    let runs: RefCell<Vec<Instant>> = RefCell::new(vec![now()]);
    let written = block_on(async {
        let cycle = async {
            loop {
                Timer::after_millis(1).await;
                runs.borrow_mut().push(now());
            }
        };
        match select(cycle, update_flash.write_window(0, &window)).await {
            Either::First(never) => never,
            Either::Second(written) => written,
        }
    });
    assert_eq!(written, Ok(()));
    let ota_1 = partitions::slot(Slot::Ota1);
    assert_eq!(flash.contents(ota_1.offset..ota_1.offset + 4096), window);
    let runs = runs.into_inner();
    let end = now();
    runs.iter()
        .zip(runs.iter().skip(1).chain([&end]))
        .map(|(a, b)| *b - *a)
        .max()
        .unwrap()
}

#[test]
fn a_control_cycle_due_during_a_window_write_waits_for_one_erase_not_the_whole_write() {
    let timing = FlashTiming::TYPICAL;
    let gap = longest_gap_while_a_window_is_written(timing);
    // The erase alone (45 ms) and the cycle's own millisecond; before the task yielded,
    // the erase and the 16 pages went in one stall: 53 ms.
    assert!(
        gap <= timing.sector_erase + Duration::from_millis(1),
        "the cycle waited {} µs",
        gap.as_micros()
    );
    assert!(gap >= timing.sector_erase);
}

/// One operation on the flash, as the update task made it.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Op {
    Erase(u32),
    Write(u32, usize),
    Read(u32, usize),
}

/// A flash that records the operations made on it.
struct Recording {
    flash: RamFlash,
    ops: std::rc::Rc<RefCell<Vec<Op>>>,
}

impl ErrorType for Recording {
    type Error = virtual_robot::flash::FlashError;
}

impl ReadNorFlash for Recording {
    const READ_SIZE: usize = RamFlash::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.ops.borrow_mut().push(Op::Read(offset, bytes.len()));
        self.flash.read(offset, bytes).await
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for Recording {
    const WRITE_SIZE: usize = RamFlash::WRITE_SIZE;
    const ERASE_SIZE: usize = RamFlash::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.ops.borrow_mut().push(Op::Erase(from));
        self.flash.erase(from, to).await
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        self.ops.borrow_mut().push(Op::Write(offset, bytes.len()));
        self.flash.write(offset, bytes).await
    }
}

/// An otadata entry is programmed in two operations, the CRC last and only after the
/// rest read back: a cut while the first is programmed leaves an entry the bootloader
/// ignores, never a valid one with its state word unprogrammed.
#[test]
fn an_otadata_entry_is_programmed_with_its_crc_last() {
    use base_core::update::otadata::{Entry, OtaState, SectorWrite};

    let ops = std::rc::Rc::new(RefCell::new(Vec::new()));
    let flash = Recording {
        flash: RamFlash::new(partitions::FLASH_SIZE as usize),
        ops: ops.clone(),
    };
    let mut update_flash = UpdateFlash::new(flash, Slot::Ota1);
    let write = SectorWrite {
        sector: 1,
        entry: Entry::new(2, OtaState::Aborted),
    };
    block_on(update_flash.write_otadata(write)).unwrap();
    let sector = partitions::OTADATA.offset + 4096;
    let writes: Vec<Op> = ops
        .borrow()
        .iter()
        .filter(|op| !matches!(op, Op::Read(..)))
        .cloned()
        .collect();
    assert_eq!(
        writes,
        [
            Op::Erase(sector),
            Op::Write(sector, 28),
            Op::Write(sector + 28, 4)
        ]
    );
    // The first operation is read back before the CRC is programmed.
    let ops = ops.borrow();
    let first = ops
        .iter()
        .position(|op| *op == Op::Write(sector, 28))
        .unwrap();
    let crc = ops
        .iter()
        .position(|op| *op == Op::Write(sector + 28, 4))
        .unwrap();
    assert!(
        ops[first..crc]
            .iter()
            .any(|op| matches!(op, Op::Read(at, len) if *at == sector && *len >= 28)),
        "{ops:?}"
    );
}
