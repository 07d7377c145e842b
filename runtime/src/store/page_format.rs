//! sequential-storage's item layout, read back to count the damaged items it skips
//! without saying so. This is the one place that knows the crate's private page
//! format, and it is pinned to sequential-storage 8.0.x in Cargo.toml: a newer
//! format must be read here first. The store's tests (`sim/tests/store.rs`) write
//! through sequential-storage and count with this module, so a changed format shows as
//! healthy stores reported damaged, or damaged ones reported healthy.

use core::ops::Range;

use embedded_storage_async::nor_flash::NorFlash;

use super::WorkBuffer;

/// Counts the items sequential-storage skips as damaged in the pages it reads, which its
/// API does not report. Follows sequential-storage 8's layout (`item.rs`): a page is
/// in use when its first word is marked; from its second word on it holds items of an
/// 8-byte header (data CRC-32, length, CRC-16 of the length) and word-padded data. A
/// header whose length CRC fails is skipped one word at a time, as sequential-storage
/// does; a run of such words counts once. `sim/tests/store.rs` checks that an intact
/// store scans clean after thousands of writes, so a format change shows there.
pub(super) async fn count_damaged<F: NorFlash>(
    flash: &mut F,
    range: &Range<u32>,
) -> Result<u16, F::Error> {
    const HEADER_LEN: u32 = 8;
    let word = F::READ_SIZE.max(F::WRITE_SIZE) as u32;
    let header_len = HEADER_LEN.next_multiple_of(word);
    let page_size = F::ERASE_SIZE as u32;
    let mut buffer = WorkBuffer([0; 32]);
    let chunk_len = (buffer.0.len() as u32 / word) * word;
    let mut damaged: u16 = 0;

    let mut page = range.start;
    while page < range.end {
        let page_end = page + page_size;
        // Only pages whose start marker is written hold items. A page with just its end
        // marker is one whose erase was cut short: sequential-storage erases it again and
        // it held nothing still current.
        if !is_marked(flash, page, &mut buffer.0).await? {
            page = page_end;
            continue;
        }
        let data_end = page_end - word;
        let mut address = page + word;
        let mut in_garbage = false;
        while address + header_len <= data_end {
            let header = &mut buffer.0[..header_len as usize];
            flash.read(address, header).await?;
            if header.iter().all(|&byte| byte == 0xFF) {
                break;
            }
            let length = u16::from_le_bytes([header[4], header[5]]);
            let length_crc = u16::from_le_bytes([header[6], header[7]]);
            let data_crc = u32::from_le_bytes([header[0], header[1], header[2], header[3]]);
            let data_address = address + header_len;
            let next = data_address + u32::from(length).next_multiple_of(word);
            if length_crc != item_crc16(&header[4..6]) || next > data_end {
                if !in_garbage {
                    damaged = damaged.saturating_add(1);
                    in_garbage = true;
                }
                address += word;
                continue;
            }
            in_garbage = false;
            // A data CRC of 0 marks an item sequential-storage erased on purpose.
            if data_crc != 0 {
                let mut crc = ItemCrc32::new();
                let mut offset = 0;
                while offset < u32::from(length) {
                    let left = u32::from(length) - offset;
                    let read_len = left.next_multiple_of(word).min(chunk_len);
                    let chunk = &mut buffer.0[..read_len as usize];
                    flash.read(data_address + offset, chunk).await?;
                    crc.update(&chunk[..left.min(read_len) as usize]);
                    offset += read_len;
                }
                if crc.finish() != data_crc {
                    damaged = damaged.saturating_add(1);
                }
            }
            address = next;
        }
        page = page_end;
    }
    Ok(damaged)
}

/// What [`leftovers`] found in a page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum PageCheck {
    /// A state word is marked: sequential-storage uses the page and owns its content.
    InUse,
    /// Both state words read erased and so does every other byte.
    Blank,
    /// Both state words read erased, so sequential-storage would open the page and
    /// write items into it as if it were blank, but other bytes are not erased.
    Leftovers,
}

/// Checks the page at `page`: sequential-storage 8 keeps its state in the page's first
/// and last word and takes a page whose words are both unmarked for erased.
pub(super) async fn leftovers<F: NorFlash>(
    flash: &mut F,
    page: u32,
    page_size: u32,
) -> Result<PageCheck, F::Error> {
    let mut buffer = WorkBuffer([0; 32]);
    let word = F::READ_SIZE.max(F::WRITE_SIZE) as u32;
    if is_marked(flash, page, &mut buffer.0).await?
        || is_marked(flash, page + page_size - word, &mut buffer.0).await?
    {
        return Ok(PageCheck::InUse);
    }
    let chunk_len = (buffer.0.len() as u32 / word) * word;
    let mut address = page;
    while address < page + page_size {
        let len = chunk_len.min(page + page_size - address);
        let chunk = &mut buffer.0[..len as usize];
        flash.read(address, chunk).await?;
        if chunk.iter().any(|&byte| byte != 0xFF) {
            return Ok(PageCheck::Leftovers);
        }
        address += len;
    }
    Ok(PageCheck::Blank)
}

/// Whether the page's first word carries sequential-storage's marker: at least 4 of its
/// bits cleared (the crate tolerates bit flips in the marker).
async fn is_marked<F: NorFlash>(
    flash: &mut F,
    page: u32,
    buffer: &mut [u8],
) -> Result<bool, F::Error> {
    let marker = &mut buffer[..F::READ_SIZE];
    flash.read(page, marker).await?;
    Ok(marker.iter().map(|byte| byte.count_zeros()).sum::<u32>() >= 4)
}

/// sequential-storage's CRC of the item length (CRC-16F/4.2, never 0xFFFF).
fn item_crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &byte in data {
        crc ^= u16::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0x1A2E
            } else {
                crc >> 1
            };
        }
    }
    match crc ^ 0xFFFF {
        0xFFFF => 0xFFFE,
        crc => crc,
    }
}

/// sequential-storage's CRC of the item data: CRC-32C from 0xEEEEEEEE, adjusted so that
/// it is never 0 (the erased mark) and its first byte is never 0x00 or 0xFF.
struct ItemCrc32(u32);

impl ItemCrc32 {
    fn new() -> Self {
        Self(0xEEEE_EEEE)
    }

    fn update(&mut self, data: &[u8]) {
        for &byte in data {
            self.0 ^= u32::from(byte);
            for _ in 0..8 {
                self.0 = if self.0 & 1 == 1 {
                    (self.0 >> 1) ^ 0x82F6_3B78
                } else {
                    self.0 >> 1
                };
            }
        }
    }

    fn finish(&self) -> u32 {
        match !self.0 {
            0 => 1,
            crc if matches!(crc.to_le_bytes()[0], 0x00 | 0xFF) => crc ^ 1,
            crc => crc,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn item_crc16_never_gives_the_erased_value() {
        // Every two-byte length: the erased 0xFFFF must be impossible.
        for length in 0..=u16::MAX {
            assert_ne!(item_crc16(&length.to_le_bytes()), 0xFFFF);
        }
    }

    #[test]
    fn item_crc32_is_crc32c_from_eeeeeeee_with_the_adjustments() {
        // CRC-32C ("123456789") is 0xE3069283 from the standard 0xFFFFFFFF init; the same
        // engine from that init must give it.
        let mut standard = ItemCrc32(0xFFFF_FFFF);
        standard.update(b"123456789");
        assert_eq!(!standard.0, 0xE306_9283);
        for data in [&b""[..], b"\x00", b"\xFF\xFF\xFF", b"register store"] {
            let mut crc = ItemCrc32::new();
            crc.update(data);
            let value = crc.finish();
            assert_ne!(value, 0);
            assert!(!matches!(value.to_le_bytes()[0], 0x00 | 0xFF));
        }
    }
}
