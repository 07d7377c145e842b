//! The checks an app image passes before a byte of it is written to a slot: the ESP
//! image header (`espflash save-image` output), the chip it was built for, and the app
//! descriptor (`esp_app_desc!`) with the project name and version; once all of it has
//! arrived, the bootloader's own checks (segment layout, XOR checksum, appended
//! SHA-256), so an image the bootloader would skip is never activated.

use sha2::{Digest, Sha256};

/// The image header's first byte.
pub const IMAGE_MAGIC: u8 = 0xE9;
/// The app descriptor's first word.
pub const APP_DESC_MAGIC: u32 = 0xABCD_5432;
/// Header (24 bytes), the first segment's header (8), the app descriptor (256).
pub const PREFIX_LEN: usize = 24 + 8 + APP_DESC_LEN;
const APP_DESC_LEN: usize = 256;
const SEGMENT_HEADER_LEN: usize = 8;
/// The bootloader loads at most this many segments.
const MAX_SEGMENTS: u8 = 16;
const CHECKSUM_SEED: u8 = 0xEF;
pub const SHA256_LEN: usize = 32;

/// The chips this firmware builds for, by the image header's chip id.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Chip {
    Esp32,
    Esp32c3,
    Esp32c6,
}

impl Chip {
    pub const fn id(self) -> u16 {
        match self {
            Self::Esp32 => 0,
            Self::Esp32c3 => 5,
            Self::Esp32c6 => 13,
        }
    }

    pub const fn from_id(id: u16) -> Option<Self> {
        match id {
            0 => Some(Self::Esp32),
            5 => Some(Self::Esp32c3),
            13 => Some(Self::Esp32c6),
            _ => None,
        }
    }

    pub const fn name(self) -> &'static str {
        match self {
            Self::Esp32 => "esp32",
            Self::Esp32c3 => "esp32c3",
            Self::Esp32c6 => "esp32c6",
        }
    }
}

/// Why an image is refused. The codes go on the wire in the update's replies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ImageError {
    /// Shorter than a header and an app descriptor.
    TooShort,
    /// Not an ESP app image (first byte not 0xE9).
    BadMagic,
    /// Built for another chip (its chip id).
    WrongChip(u16),
    /// No app descriptor at the start of the first segment.
    NoAppDescriptor,
    /// Another project's firmware.
    WrongProject,
    /// Larger than the slot.
    TooLarge,
    /// The segments run past the end, or there are none or too many.
    BadSegments,
    /// The XOR checksum after the segments is wrong.
    BadChecksum,
    /// The SHA-256 appended by the image tool does not match, or is missing.
    BadDigest,
}

impl ImageError {
    /// A stable code for the wire.
    pub const fn code(self) -> u8 {
        match self {
            Self::TooShort => 1,
            Self::BadMagic => 2,
            Self::WrongChip(_) => 3,
            Self::NoAppDescriptor => 4,
            Self::WrongProject => 5,
            Self::TooLarge => 6,
            Self::BadSegments => 7,
            Self::BadChecksum => 8,
            Self::BadDigest => 9,
        }
    }
}

/// A fixed-size, NUL-padded string from the app descriptor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DescText<const N: usize>(pub [u8; N]);

impl<const N: usize> DescText<N> {
    /// The text up to the first NUL; `"?"` when it is not UTF-8.
    pub fn as_str(&self) -> &str {
        let end = self.0.iter().position(|&b| b == 0).unwrap_or(N);
        core::str::from_utf8(&self.0[..end]).unwrap_or("?")
    }
}

/// What the first [`PREFIX_LEN`] bytes of an image say about it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImageInfo {
    pub chip: Chip,
    pub segments: u8,
    /// Whether the image tool appended a SHA-256 of the image.
    pub hash_appended: bool,
    pub version: DescText<32>,
    pub project: DescText<32>,
}

impl ImageInfo {
    /// Reads the header and the app descriptor and checks that this image is this
    /// project's firmware for `chip`.
    pub fn parse(prefix: &[u8], chip: Chip, project: &str) -> Result<Self, ImageError> {
        if prefix.len() < PREFIX_LEN {
            return Err(ImageError::TooShort);
        }
        if prefix[0] != IMAGE_MAGIC {
            return Err(ImageError::BadMagic);
        }
        let chip_id = u16::from_le_bytes([prefix[12], prefix[13]]);
        if chip_id != chip.id() {
            return Err(ImageError::WrongChip(chip_id));
        }
        let segments = prefix[1];
        if segments == 0 || segments > MAX_SEGMENTS {
            return Err(ImageError::BadSegments);
        }
        let desc = &prefix[24 + SEGMENT_HEADER_LEN..PREFIX_LEN];
        if u32::from_le_bytes([desc[0], desc[1], desc[2], desc[3]]) != APP_DESC_MAGIC {
            return Err(ImageError::NoAppDescriptor);
        }
        let text = |at: usize| {
            let mut bytes = [0u8; 32];
            bytes.copy_from_slice(&desc[at..at + 32]);
            DescText(bytes)
        };
        let info = Self {
            chip,
            segments,
            hash_appended: prefix[23] == 1,
            version: text(16),
            project: text(48),
        };
        if info.project.as_str() != project {
            return Err(ImageError::WrongProject);
        }
        Ok(info)
    }
}

/// The bootloader's checks over a whole image: the segments fit, the XOR checksum in the
/// last byte of the 16-byte-aligned block after them matches, and the appended SHA-256
/// (which this firmware requires) matches everything before it. Returns the image's
/// length without trailing padding.
pub fn verify_whole(image: &[u8], slot_len: usize) -> Result<usize, ImageError> {
    if image.len() > slot_len {
        return Err(ImageError::TooLarge);
    }
    if image.len() < PREFIX_LEN {
        return Err(ImageError::TooShort);
    }
    let segments = image[1];
    let mut at = 24;
    let mut checksum = CHECKSUM_SEED;
    for _ in 0..segments {
        let header = image
            .get(at..at + SEGMENT_HEADER_LEN)
            .ok_or(ImageError::BadSegments)?;
        let len = u32::from_le_bytes([header[4], header[5], header[6], header[7]]) as usize;
        at += SEGMENT_HEADER_LEN;
        let data = image
            .get(at..at.checked_add(len).ok_or(ImageError::BadSegments)?)
            .ok_or(ImageError::BadSegments)?;
        checksum = data.iter().fold(checksum, |sum, byte| sum ^ byte);
        at += len;
    }
    // The checksum is the last byte of the 16-byte block the segments end in.
    let checksum_at = at | 0xF;
    let stored = *image.get(checksum_at).ok_or(ImageError::BadChecksum)?;
    if stored != checksum {
        return Err(ImageError::BadChecksum);
    }
    let hashed_len = checksum_at + 1;
    if image[23] != 1 {
        return Err(ImageError::BadDigest);
    }
    let digest = image
        .get(hashed_len..hashed_len + SHA256_LEN)
        .ok_or(ImageError::BadDigest)?;
    if Sha256::digest(&image[..hashed_len]).as_slice() != digest {
        return Err(ImageError::BadDigest);
    }
    Ok(hashed_len + SHA256_LEN)
}

/// Builds a valid image around `payload` (one segment, whose data starts with an app
/// descriptor), for the tests.
/// The real images come from `espflash save-image`.
#[cfg(test)]
pub fn synthetic_image(
    chip: Chip,
    project: &str,
    version: &str,
    payload: &[u8],
) -> std::vec::Vec<u8> {
    let mut data = std::vec![0u8; APP_DESC_LEN];
    data[0..4].copy_from_slice(&APP_DESC_MAGIC.to_le_bytes());
    data[16..16 + version.len().min(31)]
        .copy_from_slice(&version.as_bytes()[..version.len().min(31)]);
    data[48..48 + project.len().min(31)]
        .copy_from_slice(&project.as_bytes()[..project.len().min(31)]);
    data.extend_from_slice(payload);

    let mut image = std::vec![0u8; 24];
    image[0] = IMAGE_MAGIC;
    image[1] = 1;
    image[12..14].copy_from_slice(&chip.id().to_le_bytes());
    image[23] = 1;
    image.extend_from_slice(&0x3C00_0020u32.to_le_bytes());
    image.extend_from_slice(&(data.len() as u32).to_le_bytes());
    let checksum = data.iter().fold(CHECKSUM_SEED, |sum, byte| sum ^ byte);
    image.extend_from_slice(&data);
    while image.len() % 16 != 15 {
        image.push(0);
    }
    image.push(checksum);
    let digest = Sha256::digest(&image);
    image.extend_from_slice(&digest);
    image
}

#[cfg(test)]
mod tests {
    use super::*;

    const PROJECT: &str = "base-controller";

    #[test]
    fn a_well_formed_image_passes_every_check() {
        let image = synthetic_image(Chip::Esp32c3, PROJECT, "0.2.0", &[1, 2, 3, 4, 5]);
        let info = ImageInfo::parse(&image, Chip::Esp32c3, PROJECT).unwrap();
        assert_eq!(info.version.as_str(), "0.2.0");
        assert_eq!(info.project.as_str(), PROJECT);
        assert!(info.hash_appended);
        assert_eq!(verify_whole(&image, 0x1F_0000), Ok(image.len()));
    }

    #[test]
    fn the_header_checks_refuse_other_files_chips_and_projects() {
        let image = synthetic_image(Chip::Esp32c3, PROJECT, "0.2.0", &[]);
        assert_eq!(
            ImageInfo::parse(&image[..100], Chip::Esp32c3, PROJECT),
            Err(ImageError::TooShort)
        );
        let mut not_an_image = image.clone();
        not_an_image[0] = 0x7F;
        assert_eq!(
            ImageInfo::parse(&not_an_image, Chip::Esp32c3, PROJECT),
            Err(ImageError::BadMagic)
        );
        assert_eq!(
            ImageInfo::parse(&image, Chip::Esp32c6, PROJECT),
            Err(ImageError::WrongChip(5))
        );
        assert_eq!(
            ImageInfo::parse(&image, Chip::Esp32c3, "other"),
            Err(ImageError::WrongProject)
        );
        let mut no_desc = image.clone();
        no_desc[32] ^= 0xFF;
        assert_eq!(
            ImageInfo::parse(&no_desc, Chip::Esp32c3, PROJECT),
            Err(ImageError::NoAppDescriptor)
        );
    }

    #[test]
    fn any_flipped_byte_or_truncation_fails_the_whole_image_check() {
        let image = synthetic_image(Chip::Esp32c6, PROJECT, "1.0.0", &[9; 40]);
        for at in 0..image.len() {
            let mut corrupt = image.clone();
            corrupt[at] ^= 0x01;
            // A flip in the header's flash fields or padding is caught by the digest.
            assert!(
                verify_whole(&corrupt, 0x1F_0000).is_err(),
                "flip at {at} passed"
            );
        }
        for len in 0..image.len() {
            assert!(
                verify_whole(&image[..len], 0x1F_0000).is_err(),
                "truncated to {len} passed"
            );
        }
        assert_eq!(
            verify_whole(&image, image.len() - 1),
            Err(ImageError::TooLarge)
        );
    }

    #[test]
    fn a_segment_length_past_the_end_is_refused_without_panicking() {
        let mut image = synthetic_image(Chip::Esp32c3, PROJECT, "0.2.0", &[]);
        image[28..32].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            verify_whole(&image, 0x1F_0000),
            Err(ImageError::BadSegments)
        );
    }
}
