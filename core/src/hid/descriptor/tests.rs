use super::{
    DescriptorError, MAX_INPUT_FIELDS, MAX_INPUT_REPORTS, MAX_PUSH_DEPTH, MAX_REPORT_BYTES,
    MAX_USAGES, ReportMap, Usage,
};
use crate::hid::test_data::{EIGHTBITDO_WINDOWS, XBOX_BLE, XBOX_ONE_S_BREDR, hex};
use proptest::prelude::*;

// ---- Real maps: report sizes and fields ---------------------------------------------

#[test]
fn xbox_ble_map_has_one_16_byte_input_report() {
    let bytes = hex(XBOX_BLE);
    assert_eq!(bytes.len(), 283);
    let map = ReportMap::parse(&bytes).unwrap();
    // Report 3 (rumble) is an output report.
    assert_eq!(map.input_report_ids().collect::<Vec<_>>(), [1]);
    assert_eq!(map.input_report_len(1), Some(16));
    assert_eq!(map.input_report_len(3), None);
}

#[test]
fn xbox_one_s_bredr_map_has_gamepad_home_and_battery_reports() {
    let bytes = hex(XBOX_ONE_S_BREDR);
    assert_eq!(bytes.len(), 334);
    let map = ReportMap::parse(&bytes).unwrap();
    assert_eq!(map.input_report_ids().collect::<Vec<_>>(), [1, 2, 4]);
    assert_eq!(map.input_report_len(1), Some(16));
    assert_eq!(map.input_report_len(2), Some(1));
    assert_eq!(map.input_report_len(4), Some(1));
}

#[test]
fn eightbitdo_windows_map_with_its_stray_trailing_zero_parses() {
    let bytes = hex(EIGHTBITDO_WINDOWS);
    assert_eq!((bytes.len(), bytes.last()), (307, Some(&0x00)));
    let map = ReportMap::parse(&bytes).unwrap();
    assert_eq!(map.input_report_ids().collect::<Vec<_>>(), [1, 2, 4]);
    assert_eq!(map.input_report_len(1), Some(15));
    assert_eq!(map.input_report_len(2), Some(1));
    assert_eq!(map.input_report_len(4), Some(1));
}

#[test]
fn xbox_ble_fields_sit_where_the_layout_comment_says() {
    let map = ReportMap::parse(&hex(XBOX_BLE)).unwrap();
    let data_fields: Vec<(u16, u8, u16)> = map
        .fields_of(1)
        .filter(|field| !field.flags.is_constant())
        .map(|field| (field.bit_offset, field.bit_size, field.count))
        .collect();
    assert_eq!(
        data_fields,
        [
            (0, 16, 2),   // LX, LY
            (32, 16, 2),  // RX, RY (Z, Rz)
            (64, 10, 1),  // LT
            (80, 10, 1),  // RT
            (96, 4, 1),   // hat
            (104, 1, 15), // buttons
            (120, 1, 1),  // Share
        ]
    );
    let sticks = map.fields_of(1).next().unwrap();
    assert_eq!((sticks.logical_min, sticks.logical_max), (0, 65535));
    assert!(sticks.flags.is_variable());
}

// ---- Descriptor items -------------------------------------------------------------

/// One 1-bit input field (`75 01 95 01 81 02`).
const ONE_BIT_INPUT: [u8; 6] = [0x75, 0x01, 0x95, 0x01, 0x81, 0x02];

fn parse_error(descriptor: &[u8]) -> Option<DescriptorError> {
    ReportMap::parse(descriptor).err()
}

#[test]
fn truncated_items_are_rejected() {
    let truncated: [&[u8]; 6] = [
        &[0x05],                   // Usage Page without its byte
        &[0x26, 0xFF],             // 2-byte Logical Maximum with one
        &[0x27, 0xFF, 0xFF, 0x00], // 4-byte item with three
        &[0xFE],                   // long item without its header
        &[0xFE, 0x04, 0x00, 0x01], // long item with 1 of 4 data bytes
        &[0x05, 0x01, 0x09],       // last item cut
    ];
    for descriptor in truncated {
        assert_eq!(
            parse_error(descriptor),
            Some(DescriptorError::TruncatedItem),
            "{descriptor:02x?}"
        );
    }
}

#[test]
fn long_items_are_skipped() {
    let descriptor = [&[0xFE, 0x02, 0x10, 0xAA, 0xBB][..], &ONE_BIT_INPUT].concat();
    let map = ReportMap::parse(&descriptor).unwrap();
    assert_eq!(map.input_report_len(0), Some(1));
}

#[test]
fn report_size_must_be_1_to_32_bits() {
    let input_of_size = |bits: u8| [0x75, bits, 0x95, 0x01, 0x81, 0x02];
    assert_eq!(
        parse_error(&input_of_size(0)),
        Some(DescriptorError::ReportSizeInvalid)
    );
    assert_eq!(
        parse_error(&input_of_size(33)),
        Some(DescriptorError::ReportSizeInvalid)
    );
    let widest = ReportMap::parse(&input_of_size(32)).unwrap();
    assert_eq!(widest.input_report_len(0), Some(4));
}

#[test]
fn input_report_over_64_bytes_is_rejected() {
    let bytes_input = |count: u8| [0x75, 0x08, 0x95, count, 0x81, 0x02];
    let largest = ReportMap::parse(&bytes_input(64)).unwrap();
    assert_eq!(largest.input_report_len(0), Some(MAX_REPORT_BYTES));
    assert_eq!(
        parse_error(&[bytes_input(32), bytes_input(33)].concat()),
        Some(DescriptorError::ReportTooLong)
    );
    // A huge count must not overflow on its way to the check.
    assert_eq!(
        parse_error(&[0x75, 0x20, 0x97, 0xFF, 0xFF, 0xFF, 0xFF, 0x81, 0x02]),
        Some(DescriptorError::ReportTooLong)
    );
}

#[test]
fn report_id_must_be_1_to_255() {
    assert_eq!(
        parse_error(&[0x85, 0x00]),
        Some(DescriptorError::ReportIdOutOfRange)
    );
    assert_eq!(
        parse_error(&[0x86, 0x00, 0x01]),
        Some(DescriptorError::ReportIdOutOfRange)
    );
    let map = ReportMap::parse(&[&[0x86, 0xFF, 0x00][..], &ONE_BIT_INPUT].concat()).unwrap();
    assert_eq!(map.input_report_ids().collect::<Vec<_>>(), [255]);
}

#[test]
fn usage_page_above_16_bits_is_rejected() {
    assert_eq!(
        parse_error(&[0x07, 0x00, 0x00, 0x01, 0x00]),
        Some(DescriptorError::UsagePageOutOfRange)
    );
}

#[test]
fn push_stack_is_limited_and_pop_needs_a_push() {
    let push = 0xA4;
    let pop = 0xB4;
    assert!(ReportMap::parse(&[push; MAX_PUSH_DEPTH]).is_ok());
    assert_eq!(
        parse_error(&[push; MAX_PUSH_DEPTH + 1]),
        Some(DescriptorError::PushOverflow)
    );
    assert_eq!(parse_error(&[pop]), Some(DescriptorError::PopWithoutPush));
    assert_eq!(
        parse_error(&[push, pop, pop]),
        Some(DescriptorError::PopWithoutPush)
    );
}

#[test]
fn pop_restores_the_pushed_globals() {
    // Size 8, push, size 16, pop: the input is 8 bits wide.
    let descriptor = [0x75, 0x08, 0x95, 0x01, 0xA4, 0x75, 0x10, 0xB4, 0x81, 0x02];
    let map = ReportMap::parse(&descriptor).unwrap();
    assert_eq!(map.fields().next().map(|field| field.bit_size), Some(8));
}

#[test]
fn usage_range_must_not_be_inverted_or_span_pages() {
    assert_eq!(
        parse_error(&[0x19, 0x05, 0x29, 0x01]),
        Some(DescriptorError::BadUsageRange)
    );
    // Minimum on the Button page, maximum on Generic Desktop.
    assert_eq!(
        parse_error(&[0x05, 0x09, 0x19, 0x01, 0x05, 0x01, 0x29, 0x05]),
        Some(DescriptorError::BadUsageRange)
    );
}

#[test]
fn usage_range_may_give_its_maximum_first() {
    let descriptor = [&[
        0x05, 0x09, 0x29, 0x03, 0x19, 0x01, 0x75, 0x01, 0x95, 0x03, 0x81, 0x02,
    ][..]]
    .concat();
    let map = ReportMap::parse(&descriptor).unwrap();
    let field = map.fields().next().unwrap();
    let usages = map.usages(field);
    let buttons = (0..3).map(|element| usages.of_element(element));
    assert!(buttons.eq((1..=3).map(|id| Some(Usage::new(0x09, id)))));
}

#[test]
fn extended_usage_carries_its_own_page() {
    // On the Button page, a 4-byte usage: Generic Desktop X.
    let descriptor = [
        0x05, 0x09, 0x0B, 0x30, 0x00, 0x01, 0x00, 0x75, 0x08, 0x95, 0x01, 0x81, 0x02,
    ];
    let map = ReportMap::parse(&descriptor).unwrap();
    let field = map.fields().next().unwrap();
    assert_eq!(map.usages(field).get(0), Some(Usage::new(0x01, 0x30)));
}

#[test]
fn variable_elements_past_the_usage_list_take_the_last_usage() {
    let descriptor = [0x09, 0x30, 0x09, 0x31, 0x75, 0x08, 0x95, 0x03, 0x81, 0x02];
    let map = ReportMap::parse(&descriptor).unwrap();
    let field = map.fields().next().unwrap();
    let usages = map.usages(field);
    assert_eq!(usages.of_element(2), Some(Usage::new(0, 0x31)));
    assert_eq!(usages.get(2), None);
}

#[test]
fn logical_maximum_is_unsigned_unless_the_minimum_is_negative() {
    // `25 FF` means 255 after `15 00`, and −1 after `15 80`.
    let unsigned = [0x15, 0x00, 0x25, 0xFF, 0x75, 0x08, 0x95, 0x01, 0x81, 0x02];
    let signed = [0x15, 0x80, 0x25, 0xFF, 0x75, 0x08, 0x95, 0x01, 0x81, 0x02];
    let range = |descriptor: &[u8]| {
        let map = ReportMap::parse(descriptor).unwrap();
        let field = map.fields().next().copied().unwrap();
        (field.logical_min, field.logical_max)
    };
    assert_eq!(range(&unsigned), (0, 255));
    assert_eq!(range(&signed), (-128, -1));
}

#[test]
fn only_the_first_usage_of_a_delimiter_set_counts() {
    // Set {X, Y} then Z: the two elements are X and Z.
    let descriptor = [
        0xA9, 0x01, 0x09, 0x30, 0x09, 0x31, 0xA9, 0x00, 0x09, 0x32, 0x75, 0x08, 0x95, 0x02, 0x81,
        0x02,
    ];
    let map = ReportMap::parse(&descriptor).unwrap();
    let field = map.fields().next().unwrap();
    let usages = map.usages(field);
    assert_eq!(usages.get(0), Some(Usage::new(0, 0x30)));
    assert_eq!(usages.get(1), Some(Usage::new(0, 0x32)));
    assert_eq!(usages.get(2), None);
}

#[test]
fn unbalanced_delimiters_and_collections_are_rejected() {
    assert_eq!(
        parse_error(&[0xA9, 0x00]),
        Some(DescriptorError::DelimiterMismatch)
    );
    assert_eq!(
        parse_error(&[0xA9, 0x01, 0xA9, 0x01]),
        Some(DescriptorError::DelimiterMismatch)
    );
    assert_eq!(
        parse_error(&[0xA1, 0x01, 0xC0, 0xC0]),
        Some(DescriptorError::UnbalancedCollection)
    );
}

#[test]
fn local_usages_apply_only_to_the_next_main_item() {
    // Usage X on an output item, then an input without usages.
    let descriptor = [0x09, 0x30, 0x75, 0x08, 0x95, 0x01, 0x91, 0x02, 0x81, 0x02];
    let map = ReportMap::parse(&descriptor).unwrap();
    let field = map.fields().next().unwrap();
    assert_eq!(map.usages(field).of_element(0), None);
}

#[test]
fn too_many_input_fields_are_rejected() {
    let fields = |count: usize| [&ONE_BIT_INPUT[..4], &[0x81, 0x02].repeat(count)].concat();
    let map = ReportMap::parse(&fields(MAX_INPUT_FIELDS)).unwrap();
    assert_eq!(map.fields().count(), MAX_INPUT_FIELDS);
    assert_eq!(
        parse_error(&fields(MAX_INPUT_FIELDS + 1)),
        Some(DescriptorError::TooManyFields)
    );
}

#[test]
fn too_many_input_reports_are_rejected() {
    let reports = |count: u8| -> Vec<u8> {
        let ids = (1..=count).flat_map(|id| [0x85, id, 0x81, 0x02]);
        ONE_BIT_INPUT[..4].iter().copied().chain(ids).collect()
    };
    let map = ReportMap::parse(&reports(MAX_INPUT_REPORTS as u8)).unwrap();
    assert_eq!(map.input_report_ids().count(), MAX_INPUT_REPORTS);
    assert_eq!(
        parse_error(&reports(MAX_INPUT_REPORTS as u8 + 1)),
        Some(DescriptorError::TooManyReports)
    );
}

#[test]
fn too_many_usages_are_rejected() {
    let usages = |count: usize| [[0x09, 0x01].repeat(count), ONE_BIT_INPUT.to_vec()].concat();
    assert!(ReportMap::parse(&usages(MAX_USAGES)).is_ok());
    assert_eq!(
        parse_error(&usages(MAX_USAGES + 1)),
        Some(DescriptorError::TooManyUsages)
    );
}

// ---- Properties -------------------------------------------------------------------

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic_the_parser(
        descriptor in proptest::collection::vec(any::<u8>(), 0..400),
    ) {
        let _ = ReportMap::parse(&descriptor);
    }

    #[test]
    fn damaged_real_maps_never_panic_the_parser(
        file in prop::sample::select(vec![XBOX_BLE, XBOX_ONE_S_BREDR, EIGHTBITDO_WINDOWS]),
        damage in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
    ) {
        let mut descriptor = hex(file);
        for (at, byte) in damage {
            let at = at.index(descriptor.len());
            descriptor[at] = byte;
        }
        descriptor.truncate(cut.index(descriptor.len() + 1));
        if let Ok(map) = ReportMap::parse(&descriptor) {
            for id in map.input_report_ids() {
                prop_assert!(map.input_report_len(id).is_some_and(|len| len <= MAX_REPORT_BYTES));
            }
        }
    }
}
