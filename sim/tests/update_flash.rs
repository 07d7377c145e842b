//! The update task's flash work next to the control cycle: the chip runs nothing while
//! its flash erases or programs, so the task yields after the erase and after each
//! page, and a control cycle that fell due meanwhile runs there instead of after the
//! whole window's flash work.

use core::cell::RefCell;

use base_core::update::otadata::Slot;
use base_core::update::partitions;
use base_runtime::update::UpdateFlash;
use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Instant, Timer};
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
