//! HCI event packets as a controller sends them, for the tests: built byte by byte
//! from the specification's parameter tables, independently of the decoder.

use crate::hci::{BdAddr, Handle, LinkKey};

pub const PAD: BdAddr = BdAddr([0x55, 0x44, 0x33, 0x22, 0x11, 0xC0]);
pub const STRANGER: BdAddr = BdAddr([0x01, 0x02, 0x03, 0x04, 0x05, 0x06]);
pub const KEY: LinkKey = LinkKey([0x5A; 16]);
pub const NEW_KEY: LinkKey = LinkKey([0xA5; 16]);
pub const HANDLE: Handle = Handle(0x0042);

fn event(code: u8, params: &[u8]) -> Vec<u8> {
    let mut packet = vec![code, params.len() as u8];
    packet.extend_from_slice(params);
    packet
}

fn with_addr(addr: BdAddr, rest: &[u8]) -> Vec<u8> {
    let mut params = addr.0.to_vec();
    params.extend_from_slice(rest);
    params
}

pub fn command_complete(opcode: u16, return_params: &[u8]) -> Vec<u8> {
    let mut params = vec![1];
    params.extend_from_slice(&opcode.to_le_bytes());
    params.extend_from_slice(return_params);
    event(0x0E, &params)
}

pub fn command_status(status: u8, opcode: u16) -> Vec<u8> {
    let [o0, o1] = opcode.to_le_bytes();
    event(0x0F, &[status, 1, o0, o1])
}

pub fn inquiry_result(addr: BdAddr, class: u32) -> Vec<u8> {
    let mut params = vec![1];
    params.extend_from_slice(&addr.0);
    params.push(0x01); // page scan repetition mode R1
    params.extend_from_slice(&[0, 0]);
    params.extend_from_slice(&class.to_le_bytes()[..3]);
    params.extend_from_slice(&0x1234u16.to_le_bytes());
    event(0x02, &params)
}

pub fn inquiry_complete() -> Vec<u8> {
    event(0x01, &[0])
}

pub fn connection_request(addr: BdAddr) -> Vec<u8> {
    event(0x04, &with_addr(addr, &[0x08, 0x25, 0x00, 0x01]))
}

pub fn connection_complete(status: u8, addr: BdAddr) -> Vec<u8> {
    let mut params = vec![status];
    params.extend_from_slice(&HANDLE.0.to_le_bytes());
    params.extend_from_slice(&addr.0);
    params.extend_from_slice(&[0x01, 0x00]);
    event(0x03, &params)
}

pub fn role_change(addr: BdAddr, central: bool) -> Vec<u8> {
    let mut params = vec![0];
    params.extend_from_slice(&with_addr(addr, &[u8::from(!central)]));
    event(0x12, &params)
}

pub fn link_key_request(addr: BdAddr) -> Vec<u8> {
    event(0x17, &addr.0)
}

pub fn link_key_notification(addr: BdAddr, key: LinkKey) -> Vec<u8> {
    let mut rest = key.0.to_vec();
    rest.push(0x04); // unauthenticated combination key, P-192
    event(0x18, &with_addr(addr, &rest))
}

pub fn io_capability_request(addr: BdAddr) -> Vec<u8> {
    event(0x31, &addr.0)
}

pub fn user_confirmation_request(addr: BdAddr) -> Vec<u8> {
    event(0x33, &with_addr(addr, &[0x40, 0xE2, 0x01, 0x00]))
}

pub fn pin_code_request(addr: BdAddr) -> Vec<u8> {
    event(0x16, &addr.0)
}

pub fn authentication_complete(status: u8) -> Vec<u8> {
    let [h0, h1] = HANDLE.0.to_le_bytes();
    event(0x06, &[status, h0, h1])
}

pub fn encryption_change(enabled: bool) -> Vec<u8> {
    let [h0, h1] = HANDLE.0.to_le_bytes();
    event(0x08, &[0, h0, h1, u8::from(enabled)])
}

pub fn disconnection_complete(reason: u8) -> Vec<u8> {
    let [h0, h1] = HANDLE.0.to_le_bytes();
    event(0x05, &[0, h0, h1, reason])
}

pub fn completed_packets(count: u16) -> Vec<u8> {
    let [h0, h1] = HANDLE.0.to_le_bytes();
    let [c0, c1] = count.to_le_bytes();
    event(0x13, &[1, h0, h1, c0, c1])
}

pub fn hardware_error() -> Vec<u8> {
    event(0x10, &[0x01])
}

/// An ACL packet from the controller carrying one whole L2CAP frame.
pub fn acl_frame(cid: u16, payload: &[u8]) -> Vec<u8> {
    let frame_len = 4 + payload.len() as u16;
    let mut packet = (HANDLE.0 | 0x2000).to_le_bytes().to_vec();
    packet.extend_from_slice(&frame_len.to_le_bytes());
    packet.extend_from_slice(&(payload.len() as u16).to_le_bytes());
    packet.extend_from_slice(&cid.to_le_bytes());
    packet.extend_from_slice(payload);
    packet
}
