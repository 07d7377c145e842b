//! The checks an app image passes before a byte of it is written to a slot: the ESP
//! image header (`espflash save-image` output), the chip it was built for, and the app
//! descriptor (`esp_app_desc!`) with the project name and version; once all of it has
//! arrived, the bootloader's own checks (segment layout, XOR checksum, appended
//! SHA-256), so an image the bootloader would skip is never activated.

use sha2::{Digest, Sha256};

use super::signature;

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
    /// The app descriptor's `secure_version`: the anti-rollback floor an image may
    /// raise (`update::signature`).
    pub security_version: u32,
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
            security_version: u32::from_le_bytes([desc[4], desc[5], desc[6], desc[7]]),
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
    let mut check = WholeImageCheck::new();
    check.feed(image);
    check.finish()
}

/// Which part of the image the next byte belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Part {
    /// The 24-byte image header.
    Header,
    /// The 8-byte header of segment `index` (load address, length).
    SegmentHeader {
        index: u8,
    },
    SegmentData {
        index: u8,
        left: u32,
    },
    /// Zeros up to the checksum byte, the last of a 16-byte block.
    Padding,
    Checksum,
    /// The appended SHA-256 of everything before it.
    Digest,
    /// What follows the digest (padding, or a signature block): not the bootloader's
    /// business; kept when it is short enough to be a signature block.
    Trailer,
    Refused(ImageError),
}

/// The same checks as [`verify_whole`], over an image that arrives in pieces (the
/// update session's windows), so the controller needs no copy of the whole image: feed
/// every byte in order, then [`finish`](Self::finish).
#[derive(Debug, Clone)]
pub struct WholeImageCheck {
    part: Part,
    /// The fixed-size part being collected: the image header, a segment header, the digest.
    held: [u8; SHA256_LEN],
    held_len: usize,
    seen: usize,
    segments: u8,
    hash_appended: bool,
    checksum: u8,
    hasher: Sha256,
    /// Bytes up to the end of the digest.
    image_len: usize,
    /// The first bytes after the digest, and how many came in all.
    trailer: [u8; signature::BLOCK_LEN],
    trailer_len: usize,
}

impl Default for WholeImageCheck {
    fn default() -> Self {
        Self::new()
    }
}

impl WholeImageCheck {
    pub fn new() -> Self {
        Self {
            part: Part::Header,
            held: [0; SHA256_LEN],
            held_len: 0,
            seen: 0,
            segments: 0,
            hash_appended: false,
            checksum: CHECKSUM_SEED,
            hasher: Sha256::new(),
            image_len: 0,
            trailer: [0; signature::BLOCK_LEN],
            trailer_len: 0,
        }
    }

    /// The next bytes of the image.
    pub fn feed(&mut self, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            let taken = match self.part {
                Part::Header => self.hold(bytes, 24),
                Part::SegmentHeader { .. } => self.hold(bytes, SEGMENT_HEADER_LEN),
                Part::SegmentData { left, .. } => bytes.len().min(left as usize),
                // Up to and including the checksum byte at the end of a 16-byte block.
                Part::Padding => bytes.len().min(15 - self.seen % 16),
                Part::Checksum => 1,
                Part::Digest => self.hold(bytes, SHA256_LEN),
                Part::Trailer | Part::Refused(_) => bytes.len(),
            };
            let (now, rest) = bytes.split_at(taken);
            match self.part {
                Part::Digest | Part::Refused(_) => {}
                Part::Trailer => self.keep_trailer(now),
                _ => self.hasher.update(now),
            }
            self.seen += taken;
            self.advance(now);
            bytes = rest;
        }
    }

    /// Copies up to a `len`-byte part into `held`; returns the bytes taken.
    fn hold(&mut self, bytes: &[u8], len: usize) -> usize {
        let taken = bytes.len().min(len - self.held_len);
        self.held[self.held_len..self.held_len + taken].copy_from_slice(&bytes[..taken]);
        self.held_len += taken;
        taken
    }

    fn keep_trailer(&mut self, bytes: &[u8]) {
        let room = self.trailer.len().saturating_sub(self.trailer_len);
        let kept = bytes.len().min(room);
        self.trailer[self.trailer_len..self.trailer_len + kept].copy_from_slice(&bytes[..kept]);
        self.trailer_len += bytes.len();
    }

    /// The part after `bytes`, the last ones taken from the current part.
    fn advance(&mut self, bytes: &[u8]) {
        let held_full = |len: usize| self.held_len == len;
        self.part = match self.part {
            Part::Header if held_full(24) => {
                self.segments = self.held[1];
                self.hash_appended = self.held[23] == 1;
                self.held_len = 0;
                if self.segments == 0 || self.segments > MAX_SEGMENTS {
                    Part::Refused(ImageError::BadSegments)
                } else {
                    Part::SegmentHeader { index: 0 }
                }
            }
            Part::SegmentHeader { index } if held_full(SEGMENT_HEADER_LEN) => {
                self.held_len = 0;
                let h = &self.held;
                let left = u32::from_le_bytes([h[4], h[5], h[6], h[7]]);
                self.after_segment_data(index, left)
            }
            Part::SegmentData { index, left } => {
                self.checksum = bytes.iter().fold(self.checksum, |sum, byte| sum ^ byte);
                self.after_segment_data(index, left - bytes.len() as u32)
            }
            Part::Padding if self.seen % 16 == 15 => Part::Checksum,
            Part::Checksum => {
                if bytes[0] != self.checksum {
                    Part::Refused(ImageError::BadChecksum)
                } else if !self.hash_appended {
                    Part::Refused(ImageError::BadDigest)
                } else {
                    Part::Digest
                }
            }
            Part::Digest if held_full(SHA256_LEN) => {
                if self.hasher.clone().finalize().as_slice() == self.held {
                    self.image_len = self.seen;
                    Part::Trailer
                } else {
                    Part::Refused(ImageError::BadDigest)
                }
            }
            unchanged => unchanged,
        };
    }

    fn after_segment_data(&self, index: u8, left: u32) -> Part {
        if left > 0 {
            Part::SegmentData { index, left }
        } else if index + 1 < self.segments {
            Part::SegmentHeader { index: index + 1 }
        } else if self.seen % 16 == 15 {
            Part::Checksum
        } else {
            Part::Padding
        }
    }

    /// The SHA-256 appended to an image that passed the checks so far, once it has
    /// arrived.
    pub fn digest(&self) -> Option<&[u8; SHA256_LEN]> {
        matches!(self.part, Part::Trailer).then_some(&self.held)
    }

    /// The bytes after the appended SHA-256, when there are at most a signature
    /// block's worth (more is not a signed image).
    pub fn trailer(&self) -> Option<&[u8]> {
        let short_enough = self.trailer_len <= self.trailer.len();
        (matches!(self.part, Part::Trailer) && short_enough)
            .then(|| &self.trailer[..self.trailer_len])
    }

    /// The verdict once every byte was fed: the image's length without trailing
    /// padding, or the first check it failed.
    pub fn finish(&self) -> Result<usize, ImageError> {
        if self.seen < PREFIX_LEN {
            return Err(ImageError::TooShort);
        }
        match self.part {
            Part::Trailer => Ok(self.image_len),
            Part::Refused(error) => Err(error),
            Part::Header | Part::SegmentHeader { .. } | Part::SegmentData { .. } => {
                Err(ImageError::BadSegments)
            }
            Part::Padding | Part::Checksum => Err(ImageError::BadChecksum),
            Part::Digest => Err(ImageError::BadDigest),
        }
    }
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

/// Makes a [`synthetic_image`] whose bytes were changed pass the bootloader's checks
/// again (its XOR checksum and appended SHA-256), as a forger would, for the tests.
#[cfg(test)]
pub fn reseal(image: &mut [u8]) {
    let data_len = u32::from_le_bytes([image[28], image[29], image[30], image[31]]) as usize;
    let digest_at = image.len() - SHA256_LEN;
    let data = &image[24 + SEGMENT_HEADER_LEN..24 + SEGMENT_HEADER_LEN + data_len];
    let checksum = data.iter().fold(CHECKSUM_SEED, |sum, byte| sum ^ byte);
    image[digest_at - 1] = checksum;
    let digest = Sha256::digest(&image[..digest_at]);
    image[digest_at..].copy_from_slice(&digest);
}

/// A [`synthetic_image`] with the app descriptor's `secure_version` set, for the tests.
#[cfg(test)]
pub fn with_security_version(mut image: std::vec::Vec<u8>, version: u32) -> std::vec::Vec<u8> {
    let at = 24 + SEGMENT_HEADER_LEN + 4;
    image[at..at + 4].copy_from_slice(&version.to_le_bytes());
    reseal(&mut image);
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
    fn the_check_in_pieces_gives_the_same_verdict_as_over_the_whole_image() {
        let image = synthetic_image(Chip::Esp32c3, PROJECT, "1.0.0", &[7; 300]);
        let mut bad_checksum = image.clone();
        bad_checksum[100] ^= 0x10;
        let mut with_trailer = image.clone();
        with_trailer.extend_from_slice(&[0xFF; 40]);
        for bytes in [
            &image,
            &bad_checksum,
            &with_trailer,
            &image[..image.len() - 1],
        ] {
            let whole = verify_whole(bytes, 0x1F_0000);
            for piece in [1, 7, 16, 33, 4096] {
                let mut check = WholeImageCheck::new();
                bytes.chunks(piece).for_each(|chunk| check.feed(chunk));
                assert_eq!(check.finish(), whole, "pieces of {piece}");
            }
        }
        assert_eq!(verify_whole(&with_trailer, 0x1F_0000), Ok(image.len()));
    }

    #[test]
    fn what_follows_the_digest_is_handed_on_only_when_it_can_be_a_signature_block() {
        let image = synthetic_image(Chip::Esp32c3, PROJECT, "1.0.0", &[3; 100]);
        let fed = |bytes: &[u8]| {
            let mut check = WholeImageCheck::new();
            check.feed(bytes);
            check
        };
        let block = [0xB5; signature::BLOCK_LEN];
        let signed = fed(&[&image[..], &block].concat());
        assert_eq!(signed.trailer(), Some(&block[..]));
        assert_eq!(
            signed.digest().map(|d| &d[..]),
            Some(&image[image.len() - SHA256_LEN..])
        );
        // More than a block after the digest: padding, not a signature.
        let padded = fed(&[&image[..], &[0xFF; 200]].concat());
        assert_eq!(padded.finish(), Ok(image.len()));
        assert_eq!(padded.trailer(), None);
        // An image that failed a check hands on neither.
        let mut broken = [&image[..], &block].concat();
        broken[40] ^= 1;
        let broken = fed(&broken);
        assert!(broken.finish().is_err());
        assert_eq!((broken.trailer(), broken.digest()), (None, None));
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
