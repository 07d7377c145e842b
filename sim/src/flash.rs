//! A NOR flash in RAM with the ESP32's geometry (esp-storage: 4-byte words, 4096-byte
//! pages), for the register store's tests. Clones share the bytes, so a test "reboots"
//! by building a new store over a clone; power cuts stop an operation part-way.
//!
//! NOR semantics are kept: an erase sets bytes to 0xFF, a write can only clear bits (the
//! new byte is `old & data`). Writing a word again is allowed, as on the ESP32's SPI
//! flash, hence [`MultiwriteNorFlash`].

use std::cell::RefCell;
use std::ops::Range;
use std::rc::Rc;

use embassy_time::Duration;

use embedded_storage_async::nor_flash::{
    ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

/// Bytes per read, as esp-storage without its `bytewise-read` feature.
pub const READ_SIZE: usize = 4;
/// Bytes per write (one flash word).
pub const WRITE_SIZE: usize = 4;
/// Bytes per erase (one sector).
pub const ERASE_SIZE: usize = 4096;
/// Bytes the flash programs at once (one page): a write takes a page time for each
/// page it touches.
pub const PROGRAM_PAGE: usize = 256;

/// How long flash operations stall the whole chip: esp-storage masks interrupts while
/// the flash erases or programs, so nothing else runs meanwhile.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FlashTiming {
    pub sector_erase: Duration,
    pub page_program: Duration,
}

impl FlashTiming {
    /// Operations take no time: the host tests' default.
    pub const INSTANT: Self = Self {
        sector_erase: Duration::from_ticks(0),
        page_program: Duration::from_ticks(0),
    };

    /// The typical times of the 4 MB SPI NOR flashes on ESP32 modules: 45 ms to erase
    /// a 4 KiB sector, 0.5 ms to program a 256-byte page (their datasheets give up to
    /// 400 ms and 3 ms as the worst).
    pub const TYPICAL: Self = Self {
        sector_erase: Duration::from_millis(45),
        page_program: Duration::from_micros(500),
    };
}

/// Why a flash operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlashError {
    /// The power is cut: see [`RamFlash::cut_power_after`].
    PowerCut,
    OutOfBounds,
    NotAligned,
}

impl NorFlashError for FlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FlashError::PowerCut => NorFlashErrorKind::Other,
            FlashError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            FlashError::NotAligned => NorFlashErrorKind::NotAligned,
        }
    }
}

/// What the flash has done since it was made (test tools such as [`RamFlash::corrupt`]
/// are not counted).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FlashStats {
    /// Read calls.
    pub reads: u64,
    /// Write calls.
    pub writes: u64,
    /// Pages erased completely.
    pub erases: u64,
    /// Bytes programmed by writes.
    pub bytes_programmed: u64,
    /// Bytes set to 0xFF by erases.
    pub bytes_erased: u64,
}

impl FlashStats {
    /// Bytes programmed or erased: the unit of [`RamFlash::cut_power_after`].
    pub fn steps(&self) -> u64 {
        self.bytes_programmed + self.bytes_erased
    }
}

struct Chip {
    bytes: Vec<u8>,
    powered: bool,
    /// Steps left before the power dies; `None`: no cut planned.
    budget: Option<u64>,
    stats: FlashStats,
    timing: FlashTiming,
    /// Bytes that read as a fixed value whatever is written or erased: see
    /// [`RamFlash::stick_byte`].
    stuck: Vec<(usize, u8)>,
}

impl Chip {
    /// One byte of a write or erase; false (and the power off) if the cut comes first.
    fn step(&mut self) -> bool {
        match &mut self.budget {
            Some(0) => {
                self.powered = false;
                self.budget = None;
                false
            }
            Some(left) => {
                *left -= 1;
                true
            }
            None => true,
        }
    }

    fn check(&self, offset: u32, len: usize, align: usize) -> Result<Range<usize>, FlashError> {
        if !self.powered {
            return Err(FlashError::PowerCut);
        }
        let start = offset as usize;
        if !start.is_multiple_of(align) || !len.is_multiple_of(align) {
            return Err(FlashError::NotAligned);
        }
        let end = start.checked_add(len).ok_or(FlashError::OutOfBounds)?;
        if end > self.bytes.len() {
            return Err(FlashError::OutOfBounds);
        }
        Ok(start..end)
    }

    /// A stuck byte keeps its value through every write and erase.
    fn apply_stuck(&mut self) {
        for &(index, value) in &self.stuck {
            self.bytes[index] = value;
        }
    }
}

/// A NOR flash in RAM; clones share the bytes. Single-threaded, like the executor.
#[derive(Clone)]
pub struct RamFlash {
    chip: Rc<RefCell<Chip>>,
}

impl RamFlash {
    /// An erased flash of `size` bytes, a whole number of pages.
    ///
    /// # Panics
    /// If `size` is not a multiple of [`ERASE_SIZE`].
    pub fn new(size: usize) -> Self {
        assert!(
            size.is_multiple_of(ERASE_SIZE),
            "flash size must be whole pages"
        );
        Self::from_bytes(vec![0xFF; size])
    }

    /// A flash holding `image`, e.g. bytes saved from an earlier run.
    ///
    /// # Panics
    /// If `image` is not a whole number of pages.
    pub fn from_image(image: Vec<u8>) -> Self {
        assert!(
            image.len().is_multiple_of(ERASE_SIZE),
            "flash size must be whole pages"
        );
        Self::from_bytes(image)
    }

    fn from_bytes(bytes: Vec<u8>) -> Self {
        Self {
            chip: Rc::new(RefCell::new(Chip {
                bytes,
                powered: true,
                budget: None,
                stats: FlashStats::default(),
                timing: FlashTiming::INSTANT,
                stuck: Vec::new(),
            })),
        }
    }

    /// Makes every page erase stall the whole chip for `stall` (the virtual clock jumps,
    /// nothing else runs), as esp-storage does by masking interrupts during a sector
    /// erase: typically 45 ms, up to 400 ms by the flash datasheets.
    pub fn set_erase_stall(&self, stall: Duration) {
        self.chip.borrow_mut().timing.sector_erase = stall;
    }

    /// Makes erases and writes stall the whole chip as `timing` says.
    pub fn set_timing(&self, timing: FlashTiming) {
        self.chip.borrow_mut().timing = timing;
    }

    /// A separate chip with the same bytes (powered, counters at zero), for trying
    /// something without touching this one.
    pub fn independent_copy(&self) -> Self {
        let chip = self.chip.borrow();
        let copy = Self::from_bytes(chip.bytes.clone());
        copy.chip.borrow_mut().stuck = chip.stuck.clone();
        copy
    }

    /// Lets the next `steps` bytes be programmed or erased; the power dies before the
    /// one after. The write or erase in progress then keeps what it did so far (a
    /// prefix, possibly part of a word) and fails, and so does every operation, reads
    /// included, until [`Self::restore_power`].
    pub fn cut_power_after(&self, steps: u64) {
        self.chip.borrow_mut().budget = Some(steps);
    }

    /// Cuts the power at once: every operation fails until [`Self::restore_power`].
    pub fn cut_power_now(&self) {
        let mut chip = self.chip.borrow_mut();
        chip.powered = false;
        chip.budget = None;
    }

    /// Power is back, with no cut planned.
    pub fn restore_power(&self) {
        let mut chip = self.chip.borrow_mut();
        chip.powered = true;
        chip.budget = None;
    }

    pub fn is_powered(&self) -> bool {
        self.chip.borrow().powered
    }

    /// Overwrites bytes as they are, ignoring NOR rules and power: damage.
    ///
    /// # Panics
    /// If the bytes do not lie inside the flash.
    pub fn corrupt(&self, offset: u32, bytes: &[u8]) {
        let start = offset as usize;
        self.chip.borrow_mut().bytes[start..start + bytes.len()].copy_from_slice(bytes);
    }

    /// A defective cell: the byte at `offset` reads `value` from now on, whatever is
    /// written or erased (a stuck byte). Copies made later carry the defect too.
    ///
    /// # Panics
    /// If `offset` is outside the flash.
    pub fn stick_byte(&self, offset: u32, value: u8) {
        let mut chip = self.chip.borrow_mut();
        let index = offset as usize;
        assert!(index < chip.bytes.len(), "stuck byte outside the flash");
        chip.stuck.retain(|&(stuck, _)| stuck != index);
        chip.stuck.push((index, value));
        chip.apply_stuck();
    }

    /// Sets every byte to 0xFF, ignoring power; not counted.
    pub fn erase_all(&self) {
        self.chip.borrow_mut().bytes.fill(0xFF);
    }

    /// A copy of the bytes in `range`.
    pub fn contents(&self, range: Range<u32>) -> Vec<u8> {
        self.chip.borrow().bytes[range.start as usize..range.end as usize].to_vec()
    }

    pub fn stats(&self) -> FlashStats {
        self.chip.borrow().stats
    }

    pub fn size(&self) -> usize {
        self.chip.borrow().bytes.len()
    }
}

impl ErrorType for RamFlash {
    type Error = FlashError;
}

impl ReadNorFlash for RamFlash {
    const READ_SIZE: usize = READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashError> {
        let mut chip = self.chip.borrow_mut();
        let range = chip.check(offset, bytes.len(), READ_SIZE)?;
        bytes.copy_from_slice(&chip.bytes[range]);
        chip.stats.reads += 1;
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.size()
    }
}

impl NorFlash for RamFlash {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashError> {
        let mut chip = self.chip.borrow_mut();
        let len = (to as usize)
            .checked_sub(from as usize)
            .ok_or(FlashError::OutOfBounds)?;
        let range = chip.check(from, len, ERASE_SIZE)?;
        // Byte by byte from the start of each page: an erase cut short leaves the
        // page's start erased and its end (with sequential-storage's end marker) not.
        for index in range {
            if !chip.step() {
                chip.apply_stuck();
                return Err(FlashError::PowerCut);
            }
            chip.bytes[index] = 0xFF;
            chip.stats.bytes_erased += 1;
            if (index + 1).is_multiple_of(ERASE_SIZE) {
                chip.stats.erases += 1;
                crate::runtime::stall(chip.timing.sector_erase);
            }
        }
        chip.apply_stuck();
        Ok(())
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashError> {
        let mut chip = self.chip.borrow_mut();
        let range = chip.check(offset, bytes.len(), WRITE_SIZE)?;
        chip.stats.writes += 1;
        let pages = range.end.div_ceil(PROGRAM_PAGE) - range.start / PROGRAM_PAGE;
        crate::runtime::stall(chip.timing.page_program * pages as u32);
        for (index, &byte) in range.zip(bytes) {
            if !chip.step() {
                chip.apply_stuck();
                return Err(FlashError::PowerCut);
            }
            // NOR programming only clears bits.
            chip.bytes[index] &= byte;
            chip.stats.bytes_programmed += 1;
        }
        chip.apply_stuck();
        Ok(())
    }
}

/// The ESP32's SPI flash may program a word again (clearing more bits).
impl MultiwriteNorFlash for RamFlash {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::block_on;

    #[test]
    fn erase_sets_ff_and_write_only_clears_bits() {
        let mut flash = RamFlash::new(2 * ERASE_SIZE);
        block_on(async {
            flash.write(0, &[0x0F, 0xF0, 0x00, 0xFF]).await.unwrap();
            flash.write(0, &[0x3C, 0x3C, 0xFF, 0x00]).await.unwrap();
            let mut word = [0; 4];
            flash.read(0, &mut word).await.unwrap();
            assert_eq!(word, [0x0C, 0x30, 0x00, 0x00]);
            flash.erase(0, ERASE_SIZE as u32).await.unwrap();
            flash.read(0, &mut word).await.unwrap();
            assert_eq!(word, [0xFF; 4]);
        });
        assert_eq!(flash.stats().erases, 1);
        assert_eq!(flash.stats().writes, 2);
    }

    #[test]
    fn clones_share_bytes_and_copies_do_not() {
        let mut flash = RamFlash::new(ERASE_SIZE);
        let clone = flash.clone();
        let copy = flash.independent_copy();
        block_on(flash.write(8, &[0; 4])).unwrap();
        assert_eq!(clone.contents(8..12), [0; 4]);
        assert_eq!(copy.contents(8..12), [0xFF; 4]);
    }

    #[test]
    fn a_power_cut_keeps_a_prefix_and_fails_everything_after() {
        let mut flash = RamFlash::new(ERASE_SIZE);
        flash.cut_power_after(6);
        block_on(async {
            assert_eq!(flash.write(0, &[0; 8]).await, Err(FlashError::PowerCut));
            assert!(!flash.is_powered());
            assert_eq!(flash.read(0, &mut [0; 4]).await, Err(FlashError::PowerCut));
            assert_eq!(
                flash.erase(0, ERASE_SIZE as u32).await,
                Err(FlashError::PowerCut)
            );
        });
        assert_eq!(flash.contents(0..8), [0, 0, 0, 0, 0, 0, 0xFF, 0xFF]);
        flash.restore_power();
        block_on(flash.write(4, &[0; 4])).unwrap();
        assert_eq!(flash.contents(0..8), [0; 8]);
    }

    #[test]
    fn an_erase_cut_short_leaves_the_page_end() {
        let mut flash = RamFlash::new(ERASE_SIZE);
        flash.corrupt(0, &[0; ERASE_SIZE]);
        flash.cut_power_after(100);
        assert_eq!(
            block_on(flash.erase(0, ERASE_SIZE as u32)),
            Err(FlashError::PowerCut)
        );
        assert_eq!(flash.contents(0..100), vec![0xFF; 100]);
        assert_eq!(
            flash.contents(100..ERASE_SIZE as u32),
            vec![0; ERASE_SIZE - 100]
        );
        assert_eq!(flash.stats().erases, 0);
    }

    #[test]
    fn a_stuck_byte_keeps_its_value_through_writes_and_erases() {
        let mut flash = RamFlash::new(ERASE_SIZE);
        flash.stick_byte(5, 0xA5);
        block_on(async {
            flash.write(4, &[0; 4]).await.unwrap();
            assert_eq!(flash.contents(4..8), [0, 0xA5, 0, 0]);
            flash.erase(0, ERASE_SIZE as u32).await.unwrap();
        });
        assert_eq!(flash.contents(4..8), [0xFF, 0xA5, 0xFF, 0xFF]);
        assert_eq!(flash.independent_copy().contents(5..6), [0xA5]);
    }

    #[test]
    fn misaligned_and_out_of_range_access_is_refused() {
        let mut flash = RamFlash::new(ERASE_SIZE);
        block_on(async {
            assert_eq!(flash.write(2, &[0; 4]).await, Err(FlashError::NotAligned));
            assert_eq!(flash.write(0, &[0; 3]).await, Err(FlashError::NotAligned));
            assert_eq!(
                flash.read(1, &mut [0; 4]).await,
                Err(FlashError::NotAligned)
            );
            assert_eq!(
                flash.write(ERASE_SIZE as u32, &[0; 4]).await,
                Err(FlashError::OutOfBounds)
            );
            assert_eq!(flash.erase(0, 100).await, Err(FlashError::NotAligned));
            assert_eq!(
                flash.erase(ERASE_SIZE as u32, 0).await,
                Err(FlashError::OutOfBounds)
            );
        });
        assert_eq!(flash.stats().bytes_programmed, 0);
    }
}
