//! The virtual CAN bus: frames both ways with their bus time, bus-off and recovery,
//! injected receive errors, and the acceptance filter.

use base_core::can::{RawFrame, id};
use base_runtime::hw::{BusState, CanError, CanRx, CanTx};
use embassy_futures::join::join;
use embassy_futures::select::{Either, select};
use embassy_time::{Duration, Timer};
use embedded_can::{ExtendedId, Frame, Id, StandardId};
use virtual_robot::can::{
    BITRATE_BPS, RECOVERY_BITS, SimFrame, VirtualCan, frame_time, recovery_time,
};
use virtual_robot::runtime::{block_on, now};

fn frame(id: u16, data: &[u8]) -> SimFrame {
    SimFrame::standard(id, data).unwrap()
}

fn us(micros: u64) -> Duration {
    Duration::from_micros(micros)
}

#[test]
fn frame_times_follow_the_documented_bit_counts() {
    // 111 bits of an 8-byte standard frame plus 24 worst-case stuff bits.
    assert_eq!(frame(0x0EA, &[0; 8]).wire_bits(), 135);
    assert_eq!(frame_time(&frame(0x0EA, &[0; 8])), us(270));
    // 47 bits without data, 8 stuff bits.
    assert_eq!(frame(0x006, &[]).wire_bits(), 55);
    let extended = SimFrame::new(ExtendedId::new(0x1234_5678).unwrap(), &[0; 8]).unwrap();
    // 131 bits plus 29 stuff bits.
    assert_eq!(extended.wire_bits(), 160);
    // A remote frame sends no data, whatever length it asks for.
    let remote = SimFrame::new_remote(StandardId::new(0x004).unwrap(), 8).unwrap();
    assert_eq!(remote.wire_bits(), 55);
    assert_eq!(BITRATE_BPS, 500_000);
}

#[test]
fn bus_off_recovery_takes_128_times_11_bit_times() {
    assert_eq!(RECOVERY_BITS, 1408);
    assert_eq!(recovery_time(), us(2816));
}

#[test]
fn sim_frames_follow_the_embedded_can_contract() {
    let data = SimFrame::standard(0x7FF, &[1, 2, 3]).unwrap();
    assert!(data.is_standard() && data.is_data_frame());
    assert_eq!(data.id(), Id::Standard(StandardId::MAX));
    assert_eq!((data.dlc(), data.data()), (3, &[1, 2, 3][..]));

    let remote = SimFrame::new_remote(ExtendedId::MAX, 5).unwrap();
    assert!(remote.is_extended() && remote.is_remote_frame());
    assert_eq!((remote.dlc(), remote.data()), (5, &[][..]));

    assert_eq!(SimFrame::standard(0x800, &[]), None);
    assert_eq!(SimFrame::standard(0x001, &[0; 9]), None);
    assert_eq!(SimFrame::new_remote(StandardId::ZERO, 9), None);
    // Same number, different kind of identifier: different frames.
    assert_ne!(
        SimFrame::new(StandardId::new(0x10).unwrap(), &[]),
        SimFrame::new(ExtendedId::new(0x10).unwrap(), &[])
    );
}

#[test]
fn sim_frames_convert_to_and_from_protocol_frames() {
    let raw = RawFrame::new(0x0C8, &[0xF4, 0x01, 0, 0, 3]).unwrap();
    let sim: SimFrame = raw.to_frame().unwrap();
    assert_eq!(sim.standard_id(), Some(0x0C8));
    assert_eq!(sim.data(), raw.data());
    assert_eq!(RawFrame::from_frame(&sim), Some(raw));
    let extended = SimFrame::new(ExtendedId::new(0x0C8).unwrap(), &[1]).unwrap();
    assert_eq!(RawFrame::from_frame(&extended), None);
    let remote = SimFrame::new_remote(StandardId::new(0x0C8).unwrap(), 1).unwrap();
    assert_eq!(RawFrame::from_frame(&remote), None);
}

#[test]
fn firmware_frames_reach_the_pc_after_their_bus_time_with_timestamps() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    let start = now();
    let frames = [
        frame(id::WEIGHT, &[1, 2]),
        frame(id::POSITION, &[0; 8]),
        frame(id::STATUS, &[9]),
    ];
    block_on(async {
        for f in &frames {
            tx.transmit(f).await.unwrap();
        }
    });
    // Back to back: each frame ends one frame time after the previous one.
    let mut end = start;
    let sent = peer.take_sent();
    assert_eq!(sent.len(), 3);
    for (sent, f) in sent.iter().zip(&frames) {
        end += frame_time(f);
        assert_eq!((sent.at, sent.frame), (end, *f));
    }
    assert_eq!(now(), end);
    // The log and the receive queue are independent views of the same frames.
    assert_eq!(peer.take_sent(), vec![]);
    assert_eq!(peer.try_receive(), Some(frames[0]));
    assert_eq!(peer.try_receive(), Some(frames[1]));
    assert_eq!(peer.try_receive(), Some(frames[2]));
    assert_eq!(peer.try_receive(), None);
}

#[test]
fn the_pc_receive_waits_for_the_firmware_frame() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    let start = now();
    let f = frame(id::BATTERY, &[80, 0x30, 0x75]);
    let (received, ()) = block_on(join(peer.receive(), async {
        Timer::after_millis(5).await;
        tx.transmit(&f).await.unwrap();
    }));
    assert_eq!(received, f);
    assert_eq!(now(), start + Duration::from_millis(5) + frame_time(&f));
}

#[test]
fn pc_frames_reach_the_firmware_when_sent() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    let start = now();
    let (received, ()) = block_on(join(rx.receive(), async {
        Timer::after_millis(7).await;
        peer.send(id::HEARTBEAT, &[1]);
    }));
    assert_eq!(received, Ok(frame(id::HEARTBEAT, &[1])));
    assert_eq!(now(), start + Duration::from_millis(7));
}

#[test]
fn a_transmitted_pc_frame_reaches_the_firmware_after_its_bus_time() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    let start = now();
    let f = frame(id::UPDATE_DATA, &[0; 8]);
    let (received, sent) = block_on(join(rx.receive(), peer.transmit(f, start)));
    assert_eq!(received, Ok(f));
    assert_eq!(sent, start + us(270));
    assert_eq!(now(), start + us(270));
    let logged: Vec<_> = peer.sent_by_pc().iter().map(|s| (s.at, s.frame)).collect();
    assert_eq!(logged, [(start + us(270), f)]);
}

#[test]
fn pc_and_firmware_frames_take_turns_on_one_wire() {
    let (mut rx, mut tx, peer) = VirtualCan::new();
    let start = now();
    let data = frame(id::UPDATE_DATA, &[0; 8]);
    let status = frame(id::STATUS, &[0; 8]);
    // The PC's frame is offered first, so the firmware's waits for the wire.
    let (pc_sent, (firmware_sent, received)) = block_on(join(
        peer.transmit(data, start),
        join(
            async {
                tx.transmit(&status).await.unwrap();
                now()
            },
            rx.receive(),
        ),
    ));
    assert_eq!(received, Ok(data));
    assert_eq!(pc_sent, start + us(270));
    assert_eq!(firmware_sent, start + us(540));
    // And a PC frame offered while the firmware's is on the wire follows it.
    let later = now();
    let (_, pc_sent) = block_on(join(tx.transmit(&status), async {
        Timer::after(us(100)).await;
        peer.transmit(data, now()).await
    }));
    assert_eq!(pc_sent, later + us(540));
}

#[test]
fn a_stream_from_the_pc_runs_at_the_bus_rate_even_when_its_sender_is_late() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    let start = now();
    let f = frame(id::UPDATE_DATA, &[0; 8]);
    block_on(async {
        // The interface had ten frames at `start`; the loop that puts them on the
        // wire gets to them 1 ms late, as a wall clock may.
        Timer::after_millis(1).await;
        for _ in 0..10 {
            peer.transmit(f, start).await;
        }
    });
    let ends: Vec<_> = peer.sent_by_pc().iter().map(|s| s.at - start).collect();
    let back_to_back: Vec<_> = (1..=10).map(|n| us(270 * n)).collect();
    assert_eq!(ends, back_to_back);
    assert_eq!(now(), start + us(2700));
    for _ in 0..10 {
        assert_eq!(block_on(rx.receive()), Ok(f));
    }
}

#[test]
fn pc_frames_are_logged_with_their_send_time_even_when_filtered_out() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    rx.accept_only_standard(&[id::HEARTBEAT]);
    let start = now();
    block_on(async {
        peer.send(id::HEARTBEAT, &[1]);
        Timer::after_millis(3).await;
        peer.send(id::WEIGHT, &[2]);
    });
    let logged: Vec<_> = peer
        .sent_by_pc()
        .iter()
        .map(|sent| (sent.at - start, sent.frame))
        .collect();
    assert_eq!(
        logged,
        [
            (Duration::from_millis(0), frame(id::HEARTBEAT, &[1])),
            (Duration::from_millis(3), frame(id::WEIGHT, &[2])),
        ]
    );
    assert_eq!(peer.filtered_out(), 1);
    // The firmware's log holds only what the firmware sent.
    assert_eq!(peer.sent(), vec![]);
}

#[test]
fn sent_frames_can_be_picked_by_id() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    block_on(async {
        tx.transmit(&frame(id::WEIGHT, &[1])).await.unwrap();
        tx.transmit(&frame(id::STATUS, &[2])).await.unwrap();
        tx.transmit(&frame(id::WEIGHT, &[3])).await.unwrap();
    });
    let weights: Vec<_> = peer
        .sent_with_id(id::WEIGHT)
        .iter()
        .map(|sent| sent.frame.data()[0])
        .collect();
    assert_eq!(weights, [1, 3]);
    // Picking does not consume the log.
    assert_eq!(peer.sent().len(), 3);
}

#[test]
fn a_queue_of_frames_takes_the_sum_of_their_bus_times() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    let f = frame(id::POSITION, &[0; 8]);
    let start = now();
    // A 1 ms slot fits only three 270 µs frames; the rest must wait.
    let in_time = block_on(async {
        let mut in_time = 0;
        let deadline = start + Duration::from_millis(1);
        for _ in 0..10 {
            match select(tx.transmit(&f), Timer::at(deadline)).await {
                Either::First(result) => {
                    result.unwrap();
                    in_time += 1;
                }
                Either::Second(()) => break,
            }
        }
        in_time
    });
    assert_eq!(in_time, 3);
    assert_eq!(peer.sent().len(), 3);
}

#[test]
fn bus_off_fails_transmits_until_recovered() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    let f = frame(id::STATUS, &[0; 6]);
    assert_eq!(tx.state(), BusState::Active);
    peer.force_bus_off();
    assert_eq!(tx.state(), BusState::Off);
    let start = now();
    block_on(async {
        assert_eq!(tx.transmit(&f).await, Err(CanError::BusOff));
        assert_eq!(tx.transmit(&f).await, Err(CanError::BusOff));
        tx.recover().await;
    });
    assert_eq!(now(), start + recovery_time());
    assert_eq!(tx.state(), BusState::Active);
    assert_eq!(peer.recoveries(), 1);
    assert_eq!(peer.sent(), vec![]);

    block_on(tx.transmit(&f)).unwrap();
    assert_eq!(peer.sent().len(), 1);
}

#[test]
fn recover_on_a_working_bus_returns_at_once_and_counts_nothing() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    let start = now();
    block_on(tx.recover());
    assert_eq!(now(), start);
    assert_eq!(peer.recoveries(), 0);
}

#[test]
fn recoveries_are_counted() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    for expected in 1..=3 {
        peer.force_bus_off();
        block_on(tx.recover());
        assert_eq!(peer.recoveries(), expected);
    }
}

#[test]
fn going_bus_off_mid_frame_loses_the_frame() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    let f = frame(id::POSITION, &[0; 8]);
    let (result, ()) = block_on(join(tx.transmit(&f), async {
        Timer::after(us(100)).await;
        peer.force_bus_off();
    }));
    assert_eq!(result, Err(CanError::BusOff));
    assert_eq!(peer.try_receive(), None);
    assert_eq!(peer.sent(), vec![]);
}

#[test]
fn a_bus_off_controller_receives_nothing() {
    let (mut rx, mut tx, peer) = VirtualCan::new();
    peer.force_bus_off();
    peer.send(id::HEARTBEAT, &[1]);
    assert_eq!(peer.lost_while_bus_off(), 1);
    block_on(tx.recover());
    peer.send(id::HEARTBEAT, &[2]);
    assert_eq!(block_on(rx.receive()), Ok(frame(id::HEARTBEAT, &[2])));
}

#[test]
fn error_passive_is_reported_and_frames_still_flow() {
    let (_rx, mut tx, peer) = VirtualCan::new();
    peer.set_error_passive(true);
    assert_eq!(tx.state(), BusState::Passive);
    block_on(tx.transmit(&frame(id::STATUS, &[1]))).unwrap();
    assert_eq!(peer.sent().len(), 1);
    peer.set_error_passive(false);
    assert_eq!(tx.state(), BusState::Active);
}

#[test]
fn an_injected_overrun_comes_out_where_it_happened() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    peer.send(id::HEARTBEAT, &[1]);
    peer.inject_rx_error(CanError::Overrun);
    peer.send(id::HEARTBEAT, &[2]);
    block_on(async {
        assert_eq!(rx.receive().await, Ok(frame(id::HEARTBEAT, &[1])));
        assert_eq!(rx.receive().await, Err(CanError::Overrun));
        assert_eq!(rx.receive().await, Ok(frame(id::HEARTBEAT, &[2])));
    });
}

#[test]
fn an_injected_error_wakes_a_waiting_receive() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    let start = now();
    let (received, ()) = block_on(join(rx.receive(), async {
        Timer::after_millis(3).await;
        peer.inject_rx_error(CanError::Bus);
    }));
    assert_eq!(received, Err(CanError::Bus));
    assert_eq!(now(), start + Duration::from_millis(3));
}

#[test]
fn the_acceptance_filter_drops_foreign_ids() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    rx.accept_only_standard(&id::COMMANDS);
    peer.send(0x123, &[1]);
    peer.send(id::WEIGHT, &[2]);
    // Same number as the heartbeat, but extended: a different identifier.
    peer.send_frame(
        SimFrame::new(ExtendedId::new(u32::from(id::HEARTBEAT)).unwrap(), &[3]).unwrap(),
    );
    peer.send(id::HEARTBEAT, &[4]);
    assert_eq!(peer.filtered_out(), 3);
    assert_eq!(block_on(rx.receive()), Ok(frame(id::HEARTBEAT, &[4])));

    rx.accept_all();
    peer.send(0x123, &[5]);
    assert_eq!(block_on(rx.receive()), Ok(frame(0x123, &[5])));
    assert_eq!(peer.filtered_out(), 3);
}

#[test]
fn extended_and_remote_frames_reach_an_unfiltered_firmware() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    let extended = SimFrame::new(ExtendedId::new(0x1ABC_DEF0).unwrap(), &[1, 2]).unwrap();
    let remote = SimFrame::new_remote(StandardId::new(id::REGISTER_READ).unwrap(), 4).unwrap();
    peer.send_frame(extended);
    peer.send_frame(remote);
    block_on(async {
        assert_eq!(rx.receive().await, Ok(extended));
        assert_eq!(rx.receive().await, Ok(remote));
    });
}

#[test]
fn a_filter_may_list_extended_ids() {
    let (mut rx, _tx, peer) = VirtualCan::new();
    let wanted = ExtendedId::new(0x1ABC_DEF0).unwrap();
    rx.accept_only([Id::Extended(wanted)]);
    peer.send(0x0F0, &[]);
    let extended = SimFrame::new(wanted, &[7]).unwrap();
    peer.send_frame(extended);
    assert_eq!(block_on(rx.receive()), Ok(extended));
    assert_eq!(peer.filtered_out(), 1);
}

#[test]
#[should_panic(expected = "not an 11-bit CAN identifier")]
fn a_standard_filter_refuses_ids_wider_than_11_bits() {
    let (mut rx, _tx, _peer) = VirtualCan::new();
    rx.accept_only_standard(&[0x800]);
}

#[test]
fn a_controller_reset_clears_its_node_and_keeps_the_pc_on_the_same_bus() {
    let (mut rx, mut tx, peer) = VirtualCan::new();
    let pc = peer.clone();
    rx.accept_only_standard(&[id::HEARTBEAT]);
    block_on(tx.transmit(&frame(0x0EE, &[1]))).unwrap();
    // Unread when the chip resets: lost with it.
    peer.send(id::HEARTBEAT, &[1]);
    peer.force_bus_off();
    peer.set_error_passive(true);
    drop((rx, tx));

    let (mut rx, mut tx) = peer.reset_controller();
    assert_eq!(tx.state(), BusState::Active);
    // No filter any more: a frame the old filter refused comes through.
    pc.send(0x123, &[2]);
    assert_eq!(block_on(rx.receive()), Ok(frame(0x123, &[2])));
    block_on(tx.transmit(&frame(0x0EE, &[3]))).unwrap();
    // The PC's clone gets both boots' frames, in order.
    block_on(async {
        assert_eq!(pc.receive().await, frame(0x0EE, &[1]));
        assert_eq!(pc.receive().await, frame(0x0EE, &[3]));
    });
    assert_eq!(pc.sent_with_id(0x0EE).len(), 2);
}
