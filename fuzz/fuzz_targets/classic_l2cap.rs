//! Any bytes as an L2CAP signalling C-frame: the decoder may not panic, and every
//! command it accepts encodes back to bytes that decode to the same command.
#![no_main]

use base_bluetooth::l2cap::{self, Signal};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|frame: &[u8]| {
    for command in l2cap::commands(frame).flatten() {
        // The host never sends a Configuration Request/Response with options other
        // than the MTU and an unknown type, nor echo data: compare what it keeps.
        let encoded = l2cap::encode(&command);
        let decoded = l2cap::commands(&encoded).next().expect("one command");
        let decoded = decoded.expect("what we encode decodes");
        assert_eq!(decoded.identifier, command.identifier);
        match (command.signal, decoded.signal) {
            (
                Signal::ConfigurationRequest { options: a, .. },
                Signal::ConfigurationRequest { options: b, .. },
            )
            | (
                Signal::ConfigurationResponse { options: a, .. },
                Signal::ConfigurationResponse { options: b, .. },
            ) => {
                assert_eq!(a.mtu, b.mtu);
                assert_eq!(a.unknown, b.unknown);
            }
            (sent, back) => assert_eq!(sent, back),
        }
    }
    let _ = l2cap::split_frame(frame);
});
