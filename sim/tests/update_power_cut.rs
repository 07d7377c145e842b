//! A whole firmware update's flash writes on the RAM flash laid out by
//! `firmware/partitions.csv`, with the power cut at every one of them: the transfer of
//! the new image into the inactive slot (4 KiB windows: erase, write, read back), the
//! activation, the bootloader's own otadata writes, the new image's arming and its
//! confirm. After every cut the bootloader (the core's boot model, both variants) starts
//! an image, the running image and the `registers` and `bonds` partitions are byte for
//! byte as before, and running the update again from there succeeds.
//!
//! The writer here is the test's own, as small as the steps it models; the decisions
//! (which sector, which sequence number, which state) are the core's `otadata`, `trial`
//! and `boot` code.

use std::ops::Range;

use base_core::update::boot::{Bootloader, boot};
use base_core::update::otadata::{ENTRY_LEN, OtaData, SECTOR_LEN, SectorWrite, Slot};
use base_core::update::trial::{StartRole, confirm, on_start};
use embedded_storage_async::nor_flash::{NorFlash, ReadNorFlash};
use virtual_robot::flash::{FlashError, RamFlash};
use virtual_robot::runtime::block_on;

const FLASH_SIZE: usize = 4 * 1024 * 1024;
/// The images: 10 windows each, enough for cuts in the first, a middle and the last.
const IMAGE_LEN: usize = 10 * WINDOW;
/// The unit of the transfer: one flash sector.
const WINDOW: usize = SECTOR_LEN as usize;

/// The partitions this test needs, from the table espflash writes.
struct Layout {
    registers: Range<u32>,
    bonds: Range<u32>,
    slots: [Range<u32>; 2],
    otadata: Range<u32>,
}

fn layout() -> Layout {
    let csv = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../firmware/partitions.csv"
    ))
    .expect("firmware/partitions.csv");
    let find = |label: &str| -> Range<u32> {
        let row = csv
            .lines()
            .filter(|line| !line.trim_start().starts_with('#'))
            .map(|line| line.split(',').map(str::trim).collect::<Vec<_>>())
            .find(|fields| fields[0] == label)
            .unwrap_or_else(|| panic!("no `{label}` in partitions.csv"));
        let number = |text: &str| u32::from_str_radix(text.trim_start_matches("0x"), 16).unwrap();
        let offset = number(row[3]);
        offset..offset + number(row[4])
    };
    Layout {
        registers: find("registers"),
        bonds: find("bonds"),
        slots: [find("ota_0"), find("ota_1")],
        otadata: find("otadata"),
    }
}

/// An image's bytes; `seed` tells the images apart.
fn image(seed: u8) -> Vec<u8> {
    (0..IMAGE_LEN)
        .map(|i| (i as u8).wrapping_mul(31) ^ seed)
        .collect()
}

/// The robot's flash and what the test knows of it.
struct Robot {
    flash: RamFlash,
    layout: Layout,
    /// The images a slot may hold; one that holds anything else fails the bootloader's
    /// checks (its SHA-256 over the whole image).
    known_images: Vec<Vec<u8>>,
    bootloader: Bootloader,
}

impl Robot {
    fn read(&self, range: Range<u32>) -> Vec<u8> {
        self.flash.contents(range)
    }

    fn otadata(&self) -> OtaData {
        let sector = |index: u32| -> [u8; ENTRY_LEN] {
            let start = self.layout.otadata.start + index * SECTOR_LEN;
            self.read(start..start + ENTRY_LEN as u32)
                .try_into()
                .unwrap()
        };
        OtaData::decode(&sector(0), &sector(1))
    }

    /// One otadata sector rewritten: erase, then program the entry.
    fn write_otadata(&mut self, write: SectorWrite) -> Result<(), FlashError> {
        let start = self.layout.otadata.start + write.sector as u32 * SECTOR_LEN;
        block_on(async {
            self.flash.erase(start, start + SECTOR_LEN).await?;
            self.flash.write(start, &write.entry.encode()).await
        })
    }

    fn image_ok(&self) -> [bool; 2] {
        [0, 1].map(|slot| {
            let start = self.layout.slots[slot].start;
            let held = self.read(start..start + IMAGE_LEN as u32);
            self.known_images.contains(&held)
        })
    }

    /// A reset: the bootloader chooses and records; the image it starts arms itself if
    /// it is on trial and confirms after its health checks (every image here is
    /// healthy). Returns the slot that runs.
    fn reset_and_run(&mut self) -> Result<Option<Slot>, FlashError> {
        let outcome = boot(&self.otadata(), self.image_ok(), self.bootloader);
        for write in outcome.writes {
            self.write_otadata(write)?;
        }
        let Some(running) = outcome.started else {
            return Ok(None);
        };
        let start = on_start(&self.otadata(), running);
        if let Some(first) = start.write {
            self.write_otadata(first)?;
        }
        match start.role {
            StartRole::Trial | StartRole::PendingVerify => {
                self.write_otadata(confirm(&self.otadata(), running).unwrap())?;
            }
            StartRole::Confirmed | StartRole::LastResort => {}
        }
        Ok(Some(running))
    }

    /// The update as the controller runs it while `running` runs: each window erased,
    /// written and read back in the other slot, then the activation.
    fn update(&mut self, running: Slot, new_image: &[u8]) -> Result<(), FlashError> {
        let target = running.other();
        let slot = self.layout.slots[target.index()].clone();
        for (index, window) in new_image.chunks(WINDOW).enumerate() {
            let start = slot.start + (index * WINDOW) as u32;
            block_on(async {
                self.flash.erase(start, start + SECTOR_LEN).await?;
                self.flash.write(start, window).await?;
                let mut back = vec![0; window.len()];
                self.flash.read(start, &mut back).await?;
                assert_eq!(back, window, "read-back of window {index}");
                Ok::<(), FlashError>(())
            })?;
        }
        let activation = self.otadata().activate(target).unwrap();
        self.write_otadata(activation)
    }
}

/// A robot migrated over USB: the old image in ota_0, otadata erased, a register store
/// and a bond with contents; booted once, so the bootloader recorded ota_0.
fn migrated_robot(bootloader: Bootloader) -> (Robot, Vec<u8>) {
    let layout = layout();
    let flash = RamFlash::new(FLASH_SIZE);
    let old = image(0xA5);
    flash.corrupt(layout.slots[0].start, &old);
    for (range, seed) in [(&layout.registers, 0x11u8), (&layout.bonds, 0x22)] {
        let contents: Vec<u8> = (0..range.len()).map(|i| (i as u8) ^ seed).collect();
        flash.corrupt(range.start, &contents);
    }
    let mut robot = Robot {
        flash,
        layout,
        known_images: vec![old.clone(), image(0x5A)],
        bootloader,
    };
    assert_eq!(robot.reset_and_run(), Ok(Some(Slot::Ota0)));
    (robot, old)
}

/// The whole update of a migrated robot and the boot after it, without a cut: the
/// flash steps (bytes programmed or erased) at the start of each operation, and the
/// operation's length in steps.
fn operations(bootloader: Bootloader) -> Vec<(u64, u64)> {
    let (mut robot, _) = migrated_robot(bootloader);
    let before = robot.flash.stats().steps();
    robot.update(Slot::Ota0, &image(0x5A)).unwrap();
    assert_eq!(robot.reset_and_run(), Ok(Some(Slot::Ota1)));
    let total = robot.flash.stats().steps() - before;
    // Every operation here is a whole sector erased or a whole window or entry
    // programmed; walk them by replaying with a recorder.
    let mut starts = Vec::new();
    let mut offset = 0;
    for _ in 0..IMAGE_LEN / WINDOW {
        starts.push((offset, SECTOR_LEN as u64));
        offset += SECTOR_LEN as u64;
        starts.push((offset, WINDOW as u64));
        offset += WINDOW as u64;
    }
    while offset < total {
        // The otadata writes after the transfer: erase a sector, program an entry.
        starts.push((offset, SECTOR_LEN as u64));
        offset += SECTOR_LEN as u64;
        starts.push((offset, ENTRY_LEN as u64));
        offset += ENTRY_LEN as u64;
    }
    assert_eq!(offset, total, "the operations add up to the update's steps");
    starts
}

fn sweep(bootloader: Bootloader) -> usize {
    let operations = operations(bootloader);
    // Activation, the arming (or a rollback bootloader's mark) and the confirm at least.
    assert!(
        operations.len() >= 2 * (IMAGE_LEN / WINDOW) + 6,
        "{operations:?}"
    );
    let mut cuts = 0;
    for (start, len) in operations {
        for into in [0, 1, len / 2, len - 1] {
            let (mut robot, old) = migrated_robot(bootloader);
            let kept = [
                robot.read(robot.layout.registers.clone()),
                robot.read(robot.layout.bonds.clone()),
            ];
            let context = format!("{bootloader:?}, cut {into} steps into the operation at {start}");
            robot.flash.cut_power_after(start + into);
            let cut = robot
                .update(Slot::Ota0, &image(0x5A))
                .and_then(|()| robot.reset_and_run().map(|_| ()));
            assert_eq!(cut, Err(FlashError::PowerCut), "{context}: no cut happened");
            cuts += 1;
            robot.flash.restore_power();

            let running = robot.reset_and_run().unwrap();
            assert!(running.is_some(), "{context}: no image boots");
            assert_eq!(
                robot.read(
                    robot.layout.slots[0].start..robot.layout.slots[0].start + IMAGE_LEN as u32
                ),
                old,
                "{context}: the old image was touched"
            );
            assert_eq!(
                [
                    robot.read(robot.layout.registers.clone()),
                    robot.read(robot.layout.bonds.clone()),
                ],
                kept,
                "{context}: registers or bonds changed"
            );

            // From wherever the cut left it, the update run again gets the new image
            // running and confirmed.
            let running = running.unwrap();
            if robot.read(
                robot.layout.slots[running.index()].start
                    ..robot.layout.slots[running.index()].start + IMAGE_LEN as u32,
            ) == old
            {
                robot.update(running, &image(0x5A)).unwrap();
                let new_slot = robot.reset_and_run().unwrap();
                assert_eq!(new_slot, Some(running.other()), "{context}: the rerun");
            }
            let settled = robot.reset_and_run().unwrap().unwrap();
            let held = robot.read(
                robot.layout.slots[settled.index()].start
                    ..robot.layout.slots[settled.index()].start + IMAGE_LEN as u32,
            );
            assert_eq!(
                held,
                image(0x5A),
                "{context}: the new image runs in the end"
            );
            assert!(
                on_start(&robot.otadata(), settled).role == StartRole::Confirmed,
                "{context}: the new image is confirmed"
            );
        }
    }
    cuts
}

#[test]
fn a_power_cut_at_any_write_of_an_update_leaves_a_booting_image_and_the_stores_intact() {
    let cuts = sweep(Bootloader::Plain);
    assert!(cuts > 80, "{cuts} cuts");
}

#[test]
fn the_same_with_a_bootloader_that_has_rollback() {
    let cuts = sweep(Bootloader::Rollback);
    assert!(cuts > 80, "{cuts} cuts");
}
