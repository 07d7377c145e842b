//! Any bytes as a gamepad's Report Map and reports: the first four are the VID and PID
//! (LE) that pick a button order, the next two (LE) the length of the map, the rest
//! after the map the report payload. Neither the parser nor the decoder may panic, and
//! every decoded state must stay within its ranges.
#![no_main]

use base_core::hid::{GamepadLayout, ReportMap, VidPid};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let [
        vid_lsb,
        vid_msb,
        pid_lsb,
        pid_msb,
        len_lsb,
        len_msb,
        rest @ ..,
    ] = input
    else {
        return;
    };
    let ids = VidPid::new(
        u16::from_le_bytes([*vid_lsb, *vid_msb]),
        u16::from_le_bytes([*pid_lsb, *pid_msb]),
    );
    let map_len = usize::from(u16::from_le_bytes([*len_lsb, *len_msb])).min(rest.len());
    let (report_map, payload) = rest.split_at(map_len);

    let parsed = ReportMap::parse(report_map);
    let Ok(mut layout) = GamepadLayout::parse(report_map, Some(ids)) else {
        return;
    };
    assert!(parsed.is_ok());
    let report_ids: Vec<u8> = layout.input_report_ids().collect();
    for report_id in report_ids {
        let Ok(Some(state)) = layout.decode(report_id, payload) else {
            continue;
        };
        for stick in [state.left_x, state.left_y, state.right_x, state.right_y] {
            assert!((-1.0..=1.0).contains(&stick));
        }
        for trigger in [state.left_trigger, state.right_trigger] {
            assert!((0.0..=1.0).contains(&trigger));
        }
        let expected = layout.report_map().input_report_len(report_id);
        assert!(expected.is_some_and(|len| payload.len() >= len));
    }
});
