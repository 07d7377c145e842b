//! The HID Report Map (a USB HID report descriptor, HID 1.11 §6.2.2) as a table of
//! input fields per report ID: where each field sits in the report, how wide its
//! elements are, their logical range and their usages. Output and Feature items are
//! walked but not kept: the gamepad code only reads inputs, and writes its one output
//! (rumble) as raw bytes.

use heapless::Vec;

#[cfg(test)]
mod tests;

/// Input reports (distinct report IDs) one map may declare. The test maps have one to
/// three.
pub const MAX_INPUT_REPORTS: usize = 16;

/// Input fields (Input items, padding included) over all reports. The test maps have
/// at most 15.
pub const MAX_INPUT_FIELDS: usize = 64;

/// Usages and usage ranges over all input fields, plus those of the Output or Feature
/// item being read. Stadia's button field alone lists 15 single usages.
pub const MAX_USAGES: usize = 128;

/// Longest input report in bytes, report ID excluded. Gamepad reports are 10 to 16
/// bytes; anything much longer is not a gamepad report we could use.
pub const MAX_REPORT_BYTES: usize = 64;

/// Depth of the Push/Pop stack of global states.
pub const MAX_PUSH_DEPTH: usize = 4;

/// Widest element (Report Size) of an input field, in bits: elements are read into
/// 32 bits.
pub const MAX_REPORT_SIZE_BITS: u32 = 32;

const MAX_REPORT_BITS: u32 = MAX_REPORT_BYTES as u32 * 8;

// A field's usage span stores pool indices as u16.
const _: () = assert!(MAX_USAGES <= u16::MAX as usize);

/// Why a Report Map was refused. The map comes from the pad, so any of these can
/// happen with a buggy or hostile device; none of them panics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DescriptorError {
    /// An item's header announces more data bytes than the map has left.
    TruncatedItem,
    /// An Input item with a Report Size of 0 or above [`MAX_REPORT_SIZE_BITS`].
    ReportSizeInvalid,
    /// An input report longer than [`MAX_REPORT_BYTES`].
    ReportTooLong,
    /// A Report ID of 0 (reserved) or above 255.
    ReportIdOutOfRange,
    /// A Usage Page above 0xFFFF.
    UsagePageOutOfRange,
    /// More nested Push items than [`MAX_PUSH_DEPTH`].
    PushOverflow,
    /// A Pop item with no Push before it.
    PopWithoutPush,
    /// A Usage Maximum below its Usage Minimum, or the two on different usage pages.
    BadUsageRange,
    /// A Delimiter that opens an open set or closes a closed one.
    DelimiterMismatch,
    /// An End Collection with no open Collection.
    UnbalancedCollection,
    /// More input reports than [`MAX_INPUT_REPORTS`].
    TooManyReports,
    /// More input fields than [`MAX_INPUT_FIELDS`].
    TooManyFields,
    /// More usages than [`MAX_USAGES`].
    TooManyUsages,
    /// A valid map without a stick, trigger, hat or named button in any input report.
    NotAGamepad,
}

/// A usage: the usage page in the high 16 bits, the usage ID in the low 16 bits (the
/// "extended usage" of HID 1.11 §6.2.2.8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Usage(pub u32);

impl Usage {
    pub const fn new(page: u16, id: u16) -> Usage {
        Usage((page as u32) << 16 | id as u32)
    }

    pub const fn page(self) -> u16 {
        (self.0 >> 16) as u16
    }

    pub const fn id(self) -> u16 {
        self.0 as u16
    }
}

/// Consecutive usages on one page, `first..=last`; a single Usage item is a range of one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct UsageRange {
    first: Usage,
    last: Usage,
}

impl UsageRange {
    const fn single(usage: Usage) -> UsageRange {
        UsageRange {
            first: usage,
            last: usage,
        }
    }

    /// At most 65 536: both ends are on one page.
    const fn len(self) -> u32 {
        self.last.0 - self.first.0 + 1
    }
}

/// The data bits of an Input item (HID 1.11 §6.2.2.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FieldFlags(pub u32);

impl FieldFlags {
    /// Padding or a fixed value: nothing to read.
    pub const fn is_constant(self) -> bool {
        self.0 & 0b01 != 0
    }

    /// Each element reports the value of its own usage (a button's state, an axis).
    pub const fn is_variable(self) -> bool {
        self.0 & 0b10 != 0
    }

    /// Each element holds an index into the usage list: the usages that are active.
    pub const fn is_array(self) -> bool {
        !self.is_variable()
    }
}

/// Where a field's usages sit in the map's usage pool.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct UsageSpan {
    start: u16,
    len: u16,
}

/// One Input item: `count` elements of `bit_size` bits from `bit_offset` on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Field {
    /// The report the field belongs to; 0 when the map declares no report IDs (as the
    /// HOGP Report Reference then says too).
    pub report_id: u8,
    /// Start of the first element in the report payload (report ID byte excluded),
    /// in bits, least significant bit of byte 0 first.
    pub bit_offset: u16,
    /// Report Size: bits per element, 1 to [`MAX_REPORT_SIZE_BITS`].
    pub bit_size: u8,
    /// Report Count: number of elements.
    pub count: u16,
    /// Elements are signed (two's complement) exactly when this is negative.
    pub logical_min: i64,
    pub logical_max: i64,
    pub flags: FieldFlags,
    usages: UsageSpan,
}

impl Field {
    /// The value of `element` in `payload`, sign-extended when the logical range is
    /// signed; `None` if the payload ends before the element or there is no such element.
    pub fn read(&self, payload: &[u8], element: u16) -> Option<i64> {
        if element >= self.count {
            return None;
        }
        let size = usize::from(self.bit_size);
        let start = usize::from(self.bit_offset) + usize::from(element) * size;
        // At most 5 bytes: 32 bits starting at bit 7 of a byte.
        let bytes = payload.get(start / 8..(start + size).div_ceil(8))?;
        let spanned = bytes
            .iter()
            .enumerate()
            .fold(0u64, |acc, (k, byte)| acc | u64::from(*byte) << (8 * k));
        let raw = (spanned >> (start % 8)) & ((1u64 << size) - 1);
        Some(if self.logical_min < 0 {
            let unused = 64 - size;
            ((raw << unused) as i64) >> unused
        } else {
            raw as i64
        })
    }
}

/// The usages of one field, ranges included, in descriptor order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Usages<'a>(&'a [UsageRange]);

impl Usages<'_> {
    /// The `index`-th usage with ranges expanded: what an Array field's element names
    /// when its value is `logical_min + index`.
    pub fn get(&self, index: u32) -> Option<Usage> {
        let mut index = index;
        for range in self.0 {
            if index < range.len() {
                return Some(Usage(range.first.0 + index));
            }
            index -= range.len();
        }
        None
    }

    /// The usage of a Variable field's `element`. Elements past the end of the list
    /// take the last usage (HID 1.11 §6.2.2.8).
    pub fn of_element(&self, element: u16) -> Option<Usage> {
        self.get(u32::from(element))
            .or_else(|| self.0.last().map(|range| range.last))
    }

    pub fn contains(&self, usage: Usage) -> bool {
        self.0
            .iter()
            .any(|range| (range.first..=range.last).contains(&usage))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct InputReport {
    id: u8,
    bits: u16,
}

/// A parsed Report Map: the input reports and their fields.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReportMap {
    reports: Vec<InputReport, MAX_INPUT_REPORTS>,
    fields: Vec<Field, MAX_INPUT_FIELDS>,
    usages: Vec<UsageRange, MAX_USAGES>,
}

impl ReportMap {
    /// Reads every item of `descriptor`. Long items are skipped (none are defined);
    /// unknown short items too, which also covers the stray trailing 0x00 of some maps.
    pub fn parse(descriptor: &[u8]) -> Result<ReportMap, DescriptorError> {
        let mut parser = Parser::default();
        let mut rest = descriptor;
        while let Some((&prefix, after)) = rest.split_first() {
            if prefix == LONG_ITEM_PREFIX {
                let [data_len, _long_tag, data @ ..] = after else {
                    return Err(DescriptorError::TruncatedItem);
                };
                rest = data
                    .get(usize::from(*data_len)..)
                    .ok_or(DescriptorError::TruncatedItem)?;
                continue;
            }
            let data_len = match prefix & 0b11 {
                3 => 4,
                len => usize::from(len),
            };
            let (data, after_data) = after
                .split_at_checked(data_len)
                .ok_or(DescriptorError::TruncatedItem)?;
            rest = after_data;
            let data = ItemData::from_le_bytes(data);
            let tag = prefix >> 4;
            match (prefix >> 2) & 0b11 {
                0 => parser.main_item(tag, data)?,
                1 => parser.global_item(tag, data)?,
                2 => parser.local_item(tag, data)?,
                _ => {}
            }
        }
        Ok(parser.map)
    }

    /// Every input report the map declares, in the order they first appear.
    pub fn input_report_ids(&self) -> impl Iterator<Item = u8> + '_ {
        self.reports.iter().map(|report| report.id)
    }

    /// Length in bytes of the input report `report_id` without its ID byte: the HOGP
    /// notification length.
    pub fn input_report_len(&self, report_id: u8) -> Option<usize> {
        self.reports
            .iter()
            .find(|report| report.id == report_id)
            .map(|report| usize::from(report.bits).div_ceil(8))
    }

    /// Every input field of every report, in descriptor order.
    pub fn fields(&self) -> impl Iterator<Item = &Field> + '_ {
        self.fields.iter()
    }

    /// The input fields of one report, in descriptor order.
    pub fn fields_of(&self, report_id: u8) -> impl Iterator<Item = &Field> + '_ {
        self.fields
            .iter()
            .filter(move |field| field.report_id == report_id)
    }

    /// The usages of `field`, a field of this map.
    pub fn usages(&self, field: &Field) -> Usages<'_> {
        let start = usize::from(field.usages.start);
        let end = start + usize::from(field.usages.len);
        Usages(self.usages.get(start..end).unwrap_or(&[]))
    }
}

/// The prefix byte of a long item: `[0xFE, data length, long tag, data…]`.
const LONG_ITEM_PREFIX: u8 = 0xFE;

/// An item's 0, 1, 2 or 4 data bytes, little endian.
#[derive(Debug, Clone, Copy, Default)]
struct ItemData {
    raw: u32,
    len: usize,
}

impl ItemData {
    fn from_le_bytes(bytes: &[u8]) -> ItemData {
        let raw = bytes
            .iter()
            .rev()
            .fold(0u32, |acc, byte| acc << 8 | u32::from(*byte));
        ItemData {
            raw,
            len: bytes.len(),
        }
    }

    fn signed(self) -> i32 {
        match self.len {
            1 => i32::from(self.raw as u8 as i8),
            2 => i32::from(self.raw as u16 as i16),
            _ => self.raw as i32,
        }
    }
}

/// The global items in force (HID 1.11 §6.2.2.7), saved and restored by Push and Pop.
#[derive(Debug, Clone, Copy, Default)]
struct Globals {
    usage_page: u16,
    logical_min: i32,
    /// Kept as read: whether it is signed depends on Logical Minimum, which may come
    /// after it.
    logical_max: ItemData,
    report_size: u32,
    report_count: u32,
    report_id: u8,
}

impl Globals {
    /// Logical Maximum is read as signed only when Logical Minimum is negative, as
    /// Linux's HID core does: pads write 0..255 as `15 00 25 FF`, which read signed
    /// would be 0..−1.
    fn logical_max(&self) -> i64 {
        if self.logical_min < 0 {
            i64::from(self.logical_max.signed())
        } else {
            i64::from(self.logical_max.raw)
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
enum Delimiter {
    #[default]
    Closed,
    /// In an open set only the first usage counts: the others are alternatives for
    /// the same control.
    Open { first_taken: bool },
}

#[derive(Default)]
struct Parser {
    map: ReportMap,
    globals: Globals,
    pushed: Vec<Globals, MAX_PUSH_DEPTH>,
    open_collections: usize,
    /// The local usages of the next Main item are `map.usages[local_usages_start..]`.
    local_usages_start: usize,
    usage_min: Option<Usage>,
    usage_max: Option<Usage>,
    delimiter: Delimiter,
}

impl Parser {
    fn main_item(&mut self, tag: u8, data: ItemData) -> Result<(), DescriptorError> {
        let kept_usages = match tag {
            INPUT => self.input(data)?,
            COLLECTION => {
                self.open_collections += 1;
                false
            }
            END_COLLECTION => {
                self.open_collections = self
                    .open_collections
                    .checked_sub(1)
                    .ok_or(DescriptorError::UnbalancedCollection)?;
                false
            }
            // Output, Feature and reserved tags.
            _ => false,
        };
        // Local items describe only the next Main item.
        if !kept_usages {
            self.map.usages.truncate(self.local_usages_start);
        }
        self.local_usages_start = self.map.usages.len();
        self.usage_min = None;
        self.usage_max = None;
        self.delimiter = Delimiter::Closed;
        Ok(())
    }

    /// Adds the field of an Input item; `Ok(true)` if it took the local usages.
    fn input(&mut self, flags: ItemData) -> Result<bool, DescriptorError> {
        let globals = self.globals;
        if globals.report_size == 0 || globals.report_size > MAX_REPORT_SIZE_BITS {
            return Err(DescriptorError::ReportSizeInvalid);
        }
        if globals.report_count == 0 {
            return Ok(false);
        }
        let report_index = self.report_index(globals.report_id)?;
        let report = &mut self.map.reports[report_index];
        let bits = u64::from(globals.report_size) * u64::from(globals.report_count);
        let end = u64::from(report.bits) + bits;
        if end > u64::from(MAX_REPORT_BITS) {
            return Err(DescriptorError::ReportTooLong);
        }
        let bit_offset = report.bits;
        // Both fit: `end` is at most MAX_REPORT_BITS, so the count is too.
        report.bits = end as u16;
        let field = Field {
            report_id: globals.report_id,
            bit_offset,
            bit_size: globals.report_size as u8,
            count: globals.report_count as u16,
            logical_min: i64::from(globals.logical_min),
            logical_max: globals.logical_max(),
            flags: FieldFlags(flags.raw),
            usages: UsageSpan {
                start: self.local_usages_start as u16,
                len: (self.map.usages.len() - self.local_usages_start) as u16,
            },
        };
        self.map
            .fields
            .push(field)
            .map_err(|_| DescriptorError::TooManyFields)?;
        Ok(true)
    }

    /// Index of the input report `id` in the map, added if new.
    fn report_index(&mut self, id: u8) -> Result<usize, DescriptorError> {
        let reports = &mut self.map.reports;
        if let Some(index) = reports.iter().position(|report| report.id == id) {
            return Ok(index);
        }
        reports
            .push(InputReport { id, bits: 0 })
            .map_err(|_| DescriptorError::TooManyReports)?;
        Ok(reports.len() - 1)
    }

    fn global_item(&mut self, tag: u8, data: ItemData) -> Result<(), DescriptorError> {
        let globals = &mut self.globals;
        match tag {
            USAGE_PAGE => {
                globals.usage_page =
                    u16::try_from(data.raw).map_err(|_| DescriptorError::UsagePageOutOfRange)?;
            }
            LOGICAL_MINIMUM => globals.logical_min = data.signed(),
            LOGICAL_MAXIMUM => globals.logical_max = data,
            REPORT_SIZE => globals.report_size = data.raw,
            REPORT_ID => {
                globals.report_id = match u8::try_from(data.raw) {
                    Ok(id) if id != 0 => id,
                    _ => return Err(DescriptorError::ReportIdOutOfRange),
                };
            }
            REPORT_COUNT => globals.report_count = data.raw,
            PUSH => self
                .pushed
                .push(*globals)
                .map_err(|_| DescriptorError::PushOverflow)?,
            POP => *globals = self.pushed.pop().ok_or(DescriptorError::PopWithoutPush)?,
            // Physical Minimum/Maximum, Unit Exponent and Unit give the physical meaning
            // of a value; the decoder scales by the logical range alone.
            _ => {}
        }
        Ok(())
    }

    fn local_item(&mut self, tag: u8, data: ItemData) -> Result<(), DescriptorError> {
        // A 4-byte usage carries its own page; a shorter one takes the current page.
        let usage = if data.len == 4 {
            Usage(data.raw)
        } else {
            Usage(u32::from(self.globals.usage_page) << 16 | data.raw)
        };
        match tag {
            USAGE => self.add_usages(UsageRange::single(usage))?,
            USAGE_MINIMUM => {
                self.usage_min = Some(usage);
                self.complete_usage_range()?;
            }
            USAGE_MAXIMUM => {
                self.usage_max = Some(usage);
                self.complete_usage_range()?;
            }
            DELIMITER => {
                self.delimiter = match (data.raw, self.delimiter) {
                    (1, Delimiter::Closed) => Delimiter::Open { first_taken: false },
                    (0, Delimiter::Open { .. }) => Delimiter::Closed,
                    _ => return Err(DescriptorError::DelimiterMismatch),
                };
            }
            // Designator and string indices name controls for people.
            _ => {}
        }
        Ok(())
    }

    /// A usage range is complete once both its ends are known, in either order.
    fn complete_usage_range(&mut self) -> Result<(), DescriptorError> {
        let (Some(first), Some(last)) = (self.usage_min, self.usage_max) else {
            return Ok(());
        };
        if first.page() != last.page() || last < first {
            return Err(DescriptorError::BadUsageRange);
        }
        self.usage_min = None;
        self.usage_max = None;
        self.add_usages(UsageRange { first, last })
    }

    fn add_usages(&mut self, range: UsageRange) -> Result<(), DescriptorError> {
        match self.delimiter {
            Delimiter::Open { first_taken: true } => return Ok(()),
            Delimiter::Open { first_taken: false } => {
                self.delimiter = Delimiter::Open { first_taken: true };
            }
            Delimiter::Closed => {}
        }
        self.map
            .usages
            .push(range)
            .map_err(|_| DescriptorError::TooManyUsages)
    }
}

// Item tags (HID 1.11 §6.2.2.4, §6.2.2.7, §6.2.2.8).
const INPUT: u8 = 0x8;
const COLLECTION: u8 = 0xA;
const END_COLLECTION: u8 = 0xC;

const USAGE_PAGE: u8 = 0x0;
const LOGICAL_MINIMUM: u8 = 0x1;
const LOGICAL_MAXIMUM: u8 = 0x2;
const REPORT_SIZE: u8 = 0x7;
const REPORT_ID: u8 = 0x8;
const REPORT_COUNT: u8 = 0x9;
const PUSH: u8 = 0xA;
const POP: u8 = 0xB;

const USAGE: u8 = 0x0;
const USAGE_MINIMUM: u8 = 0x1;
const USAGE_MAXIMUM: u8 = 0x2;
const DELIMITER: u8 = 0xA;
