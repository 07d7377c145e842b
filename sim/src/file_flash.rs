//! A flash whose bytes are kept in a file, for the simulator: the register store's
//! records survive a restart, as on the board. It is a [`RamFlash`] that writes the
//! bytes each write and erase changed to the file.

use std::io;
use std::ops::Range;
use std::path::{Path, PathBuf};

use embedded_storage_async::nor_flash::{
    ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};

use crate::flash::{ERASE_SIZE, FlashError, FlashTiming, RamFlash};

/// Why a file-backed flash operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileFlashError {
    Flash(FlashError),
    /// The bytes changed in memory but could not be saved to the file.
    Save(io::ErrorKind),
}

impl NorFlashError for FileFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            FileFlashError::Flash(error) => error.kind(),
            FileFlashError::Save(_) => NorFlashErrorKind::Other,
        }
    }
}

/// A NOR flash in RAM, saved to `path` after every change. Clones share the bytes
/// and the file, as each boot of the controller shares the chip's flash.
#[derive(Clone)]
pub struct FileFlash {
    flash: RamFlash,
    path: PathBuf,
}

impl FileFlash {
    /// Loads the flash from `path`, or makes an erased flash of `size` bytes there if
    /// the file does not exist yet (creating its directory).
    ///
    /// Fails if the file cannot be read or written, or holds another number of bytes
    /// than `size`: that is not this flash, so it is left alone.
    ///
    /// # Panics
    /// If `size` is not a whole number of pages.
    pub fn open(path: &Path, size: usize) -> io::Result<Self> {
        assert!(
            size.is_multiple_of(ERASE_SIZE),
            "flash size must be whole pages"
        );
        let image = match std::fs::read(path) {
            Ok(image) if image.len() == size => image,
            Ok(image) => {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!(
                        "{} holds {} bytes, not the {size} of the flash",
                        path.display(),
                        image.len()
                    ),
                ));
            }
            Err(error) if error.kind() == io::ErrorKind::NotFound => {
                if let Some(directory) = path.parent() {
                    std::fs::create_dir_all(directory)?;
                }
                let erased = vec![0xFF; size];
                std::fs::write(path, &erased)?;
                erased
            }
            Err(error) => return Err(error),
        };
        Ok(Self {
            flash: RamFlash::from_image(image),
            path: path.to_owned(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Makes erases and writes stall the whole chip as `timing` says.
    pub fn set_timing(&self, timing: FlashTiming) {
        self.flash.set_timing(timing);
    }

    /// Writes the bytes of `range` to the file, where they belong.
    fn save(&self, range: Range<u32>) -> Result<(), FileFlashError> {
        use std::os::unix::fs::FileExt;
        let bytes = self.flash.contents(range.clone());
        std::fs::OpenOptions::new()
            .write(true)
            .open(&self.path)
            .and_then(|file| file.write_all_at(&bytes, u64::from(range.start)))
            .map_err(|error| FileFlashError::Save(error.kind()))
    }
}

impl ErrorType for FileFlash {
    type Error = FileFlashError;
}

impl ReadNorFlash for FileFlash {
    const READ_SIZE: usize = RamFlash::READ_SIZE;

    async fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FileFlashError> {
        self.flash
            .read(offset, bytes)
            .await
            .map_err(FileFlashError::Flash)
    }

    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = RamFlash::WRITE_SIZE;
    const ERASE_SIZE: usize = RamFlash::ERASE_SIZE;

    async fn erase(&mut self, from: u32, to: u32) -> Result<(), FileFlashError> {
        self.flash
            .erase(from, to)
            .await
            .map_err(FileFlashError::Flash)?;
        self.save(from..to)
    }

    async fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FileFlashError> {
        self.flash
            .write(offset, bytes)
            .await
            .map_err(FileFlashError::Flash)?;
        self.save(offset..offset + bytes.len() as u32)
    }
}

impl MultiwriteNorFlash for FileFlash {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::block_on;

    /// A flash file path in a scratch directory (removed when dropped), under a
    /// folder that is not there yet, as the default one in the cache directory may not.
    fn scratch_path() -> (tempfile::TempDir, PathBuf) {
        let directory = tempfile::tempdir().unwrap();
        let path = directory.path().join("new").join("flash.bin");
        (directory, path)
    }

    #[test]
    fn written_bytes_are_there_after_reopening() {
        let (_directory, path) = scratch_path();
        let mut flash = FileFlash::open(&path, ERASE_SIZE).unwrap();
        block_on(flash.write(8, &[1, 2, 3, 4])).unwrap();
        drop(flash);
        let mut reopened = FileFlash::open(&path, ERASE_SIZE).unwrap();
        let mut word = [0; 4];
        block_on(reopened.read(8, &mut word)).unwrap();
        assert_eq!(word, [1, 2, 3, 4]);
        block_on(reopened.erase(0, ERASE_SIZE as u32)).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), vec![0xFF; ERASE_SIZE]);
    }

    #[test]
    fn a_file_of_another_size_is_refused_and_left_alone() {
        let (_directory, path) = scratch_path();
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, [0u8; 100]).unwrap();
        let error = FileFlash::open(&path, ERASE_SIZE).err().unwrap();
        assert_eq!(error.kind(), io::ErrorKind::InvalidData);
        assert_eq!(std::fs::read(&path).unwrap(), [0u8; 100]);
    }
}
