//! The flash layout of a 4 MB board, as `firmware/partitions.csv` declares it: the
//! register store and the Bluetooth bonds where they always were (their contents
//! survive the move to A/B slots), two app slots and the OTA data. The update task,
//! the boot-time trial and the simulator's flash all take their offsets from here, so
//! they cannot disagree about where a slot starts.

use super::otadata::{SECTOR_LEN, Slot};

/// One partition: where it starts and how long it is, in bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Partition {
    pub name: &'static str,
    pub offset: u32,
    pub len: u32,
}

impl Partition {
    pub const fn end(&self) -> u32 {
        self.offset + self.len
    }

    pub const fn range(&self) -> core::ops::Range<u32> {
        self.offset..self.end()
    }
}

/// The whole flash chip.
pub const FLASH_SIZE: u32 = 0x40_0000;

pub const REGISTERS: Partition = Partition {
    name: "registers",
    offset: 0x9000,
    len: 0x4000,
};
pub const BONDS: Partition = Partition {
    name: "bonds",
    offset: 0xD000,
    len: 0x3000,
};
pub const OTA_0: Partition = Partition {
    name: "ota_0",
    offset: 0x1_0000,
    len: 0x1F_0000,
};
pub const OTA_1: Partition = Partition {
    name: "ota_1",
    offset: 0x20_0000,
    len: 0x1F_0000,
};
pub const OTADATA: Partition = Partition {
    name: "otadata",
    offset: 0x3F_0000,
    len: 2 * SECTOR_LEN,
};

/// Every partition, in flash order.
pub const TABLE: [Partition; 5] = [REGISTERS, BONDS, OTA_0, OTA_1, OTADATA];

/// The bytes an app slot holds: the largest image an update may write.
pub const SLOT_LEN: u32 = OTA_0.len;

/// The partition of an app slot.
pub const fn slot(slot: Slot) -> Partition {
    match slot {
        Slot::Ota0 => OTA_0,
        Slot::Ota1 => OTA_1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partitions_are_sector_aligned_in_order_and_inside_the_chip() {
        for window in TABLE.windows(2) {
            assert!(window[0].end() <= window[1].offset, "{window:?} overlap");
        }
        for partition in TABLE {
            // The range the flash code writes in: exactly the partition's bytes.
            let range = partition.range();
            assert_eq!(
                (range.start, range.len()),
                (partition.offset, partition.len as usize)
            );
            assert_eq!(partition.offset % SECTOR_LEN, 0, "{partition:?}");
            assert_eq!(partition.len % SECTOR_LEN, 0, "{partition:?}");
            assert!(partition.end() <= FLASH_SIZE, "{partition:?}");
        }
    }

    #[test]
    fn app_slots_start_on_a_64_kib_boundary_as_the_bootloader_maps_them() {
        for partition in [OTA_0, OTA_1] {
            assert_eq!(partition.offset % 0x1_0000, 0, "{partition:?}");
            assert_eq!(partition.len, SLOT_LEN);
        }
        assert_eq!(slot(Slot::Ota0), OTA_0);
        assert_eq!(slot(Slot::Ota1), OTA_1);
    }

    #[test]
    fn the_register_store_and_the_bonds_keep_their_offsets() {
        assert_eq!((REGISTERS.offset, REGISTERS.len), (0x9000, 0x4000));
        assert_eq!((BONDS.offset, BONDS.len), (0xD000, 0x3000));
    }
}
