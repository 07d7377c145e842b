use super::*;

const H: Handle = Handle(0x0042);

/// An L2CAP frame of `payload_len` bytes on CID 0x0041, payload counting up.
fn frame(payload_len: usize) -> std::vec::Vec<u8> {
    let mut frame = (payload_len as u16).to_le_bytes().to_vec();
    frame.extend_from_slice(&0x0041u16.to_le_bytes());
    frame.extend((0..payload_len).map(|i| i as u8));
    frame
}

#[test]
fn packets_split_into_handle_boundary_and_payload() {
    assert_eq!(
        split(&[0x42, 0x20, 0x02, 0x00, 0xAA, 0xBB]),
        Ok((H, Boundary::First, &[0xAA, 0xBB][..]))
    );
    assert_eq!(
        split(&[0x42, 0x10, 0x01, 0x00, 0xAA]),
        Ok((H, Boundary::Continuing, &[0xAA][..]))
    );
    let table: [(&[u8], AclError); 4] = [
        (&[0x42, 0x20, 0x02], AclError::Truncated),
        (&[0x42, 0x20, 0x02, 0x00, 0xAA], AclError::Truncated),
        // Broadcast flag, reserved boundary value.
        (&[0x42, 0x60, 0x00, 0x00], AclError::BadFlags),
        (&[0x42, 0x30, 0x00, 0x00], AclError::BadFlags),
    ];
    for (packet, error) in table {
        assert_eq!(split(packet), Err(error), "{packet:02x?}");
    }
}

#[test]
fn a_frame_in_three_pieces_is_whole_after_the_last() {
    let whole = frame(79);
    let mut reassembler = Reassembler::new();
    assert_eq!(reassembler.push(Boundary::First, &whole[..1]), Ok(None));
    assert_eq!(
        reassembler.push(Boundary::Continuing, &whole[1..40]),
        Ok(None)
    );
    assert_eq!(
        reassembler.push(Boundary::Continuing, &whole[40..]),
        Ok(Some(&whole[..]))
    );
    // The next frame starts afresh.
    let small = frame(3);
    assert_eq!(
        reassembler.push(Boundary::First, &small),
        Ok(Some(&small[..]))
    );
}

#[test]
fn pieces_out_of_order_or_too_long_are_refused() {
    let mut reassembler = Reassembler::new();
    assert_eq!(
        reassembler.push(Boundary::Continuing, &[1, 2]),
        Err(AclError::OutOfSequence)
    );
    // A frame that says it is longer than our MTU.
    let huge = frame(usize::from(crate::RECEIVE_MTU) + 1);
    assert_eq!(
        reassembler.push(Boundary::First, &huge[..10]),
        Err(AclError::TooLong)
    );
    // Pieces that overrun the length they announced.
    let small = frame(3);
    assert_eq!(reassembler.push(Boundary::First, &small[..5]), Ok(None));
    assert_eq!(
        reassembler.push(Boundary::Continuing, &[0, 0, 0]),
        Err(AclError::TooLong)
    );
    // A new frame while one is unfinished: the old one is abandoned and counted.
    let whole = frame(10);
    assert_eq!(reassembler.push(Boundary::First, &whole[..6]), Ok(None));
    assert_eq!(
        reassembler.push(Boundary::First, &small),
        Ok(Some(&small[..]))
    );
    assert_eq!(reassembler.abandoned(), 1);
}

#[test]
fn frames_are_cut_to_the_controllers_packet_length_and_wait_for_free_buffers() {
    let mut sender = AclSender::new();
    sender.set_buffers(AclBuffers {
        packet_len: 27,
        packets: 2,
    });
    let whole = frame(79); // 83 bytes: 27 + 27 + 27 + 2
    sender.queue(H, &whole).unwrap();
    let first = sender.next_packet().unwrap();
    assert_eq!(&first[..4], &[0x42, 0x00, 27, 0]);
    assert_eq!(&first[4..], &whole[..27]);
    let second = sender.next_packet().unwrap();
    assert_eq!(&second[..4], &[0x42, 0x10, 27, 0]);
    // Both buffers in use: nothing more until the controller completes one.
    assert_eq!(sender.next_packet(), None);
    sender.completed(2);
    assert_eq!(sender.next_packet().unwrap()[4..], whole[54..81]);
    let last = sender.next_packet().unwrap();
    assert_eq!(&last[..4], &[0x42, 0x10, 2, 0]);
    assert_eq!(&last[4..], &whole[81..]);
    assert_eq!(sender.queued(), 0);
}

#[test]
fn the_queue_is_bounded_and_a_closed_link_frees_everything() {
    let mut sender = AclSender::new();
    for _ in 0..TX_QUEUE {
        sender.queue(H, &frame(4)).unwrap();
    }
    assert_eq!(sender.queue(H, &frame(4)), Err(SendError::QueueFull));
    assert_eq!(
        sender.queue(H, &frame(MAX_TX_FRAME)),
        Err(SendError::TooLong)
    );
    assert!(sender.next_packet().is_some());
    assert_eq!(sender.next_packet(), None);
    sender.link_closed(H);
    assert_eq!(sender.queued(), 0);
    // The buffer the closed link held counts as free again.
    sender.queue(H, &frame(4)).unwrap();
    assert!(sender.next_packet().is_some());
}

#[test]
fn completions_never_exceed_the_controllers_buffers() {
    let mut sender = AclSender::new();
    sender.set_buffers(AclBuffers {
        packet_len: 100,
        packets: 1,
    });
    sender.completed(50);
    sender.queue(H, &frame(4)).unwrap();
    sender.queue(H, &frame(4)).unwrap();
    assert!(sender.next_packet().is_some());
    assert_eq!(sender.next_packet(), None);
}
