//! Any bytes as a PlayStation pad's interrupt- or control-channel payload, decoded as
//! a DualShock 4 and as a DualSense. Neither decoder may panic; a decoded state stays
//! within its ranges, and every payload is counted exactly once, decoded or refused.
#![no_main]

use base_core::hid::playstation::{PadDecoder, PadKind, check_full_mode_feature};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|payload: &[u8]| {
    for kind in [PadKind::DualShock4, PadKind::DualSense] {
        let mut decoder = PadDecoder::new(kind);
        if let Ok(report) = decoder.decode(payload) {
            let state = report.state;
            for stick in [state.left_x, state.left_y, state.right_x, state.right_y] {
                assert!((-1.0..=1.0).contains(&stick));
            }
            for trigger in [state.left_trigger, state.right_trigger] {
                assert!((0.0..=1.0).contains(&trigger));
            }
            if let Some(battery) = report.battery {
                assert!(battery.percent <= 100);
            }
        }
        let counters = decoder.counters();
        assert_eq!(counters.full + counters.short + counters.refused(), 1);
    }
    let _ = check_full_mode_feature(payload);
});
