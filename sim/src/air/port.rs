//! A host's end of a controller in the air: H4 bytes both ways, in memory, on the
//! caller's executor. The robot's Bluetooth hosts and each BLE pad's host read and
//! write through one of these, as they would through a UART.
//!
//! ```text
//!   host ──H4──▶ AirWriter ─▶ AirState::host_bytes (commands answered at once, ACL onto the air)
//!   host ◀─H4── AirReader ◀─ HostPort::to_host ◀── events and ACL packets, now or when due
//! ```

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::poll_fn;
use std::rc::Rc;
use std::task::{Poll, Waker};

use bt_hci::controller::ExternalController;
use bt_hci_serial::SerialTransport;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;

use super::state::{AirState, DeviceId};
use crate::ble::HciError;

/// H4 packet types.
pub const H4_COMMAND: u8 = 0x01;
pub const H4_ACL: u8 = 0x02;
pub const H4_EVENT: u8 = 0x04;

/// The bytes between one controller and its host.
#[derive(Default)]
pub struct HostPort {
    to_host: VecDeque<u8>,
    reader: Option<Waker>,
    from_host: Vec<u8>,
}

/// One whole packet a host sent.
pub enum FromHost {
    /// Opcode and parameters.
    Command(u16, Vec<u8>),
    /// Handle (12 bits), packet boundary flag, data.
    Acl(u16, u8, Vec<u8>),
}

impl HostPort {
    /// Hands the host a whole H4 packet.
    pub fn send(&mut self, packet: &[u8]) {
        self.to_host.extend(packet);
        if let Some(waker) = self.reader.take() {
            waker.wake();
        }
    }

    /// Takes the host's bytes; returns the whole packets among them. Bytes that begin
    /// no packet a host may send are dropped with what follows them (`garbage` counts
    /// them), as a UART controller resynchronises after a framing error.
    pub fn take_bytes(&mut self, bytes: &[u8], garbage: &mut u32) -> Vec<FromHost> {
        self.from_host.extend_from_slice(bytes);
        let mut packets = Vec::new();
        loop {
            let length = match self.from_host.as_slice() {
                [H4_COMMAND, _, _, len, ..] => 4 + usize::from(*len),
                [H4_ACL, _, _, lo, hi, ..] => 5 + usize::from(u16::from_le_bytes([*lo, *hi])),
                [] | [H4_COMMAND, ..] | [H4_ACL, ..] => break,
                [_, ..] => {
                    *garbage += 1;
                    self.from_host.clear();
                    break;
                }
            };
            if self.from_host.len() < length {
                break;
            }
            let packet: Vec<u8> = self.from_host.drain(..length).collect();
            packets.push(if packet[0] == H4_COMMAND {
                FromHost::Command(
                    u16::from_le_bytes([packet[1], packet[2]]),
                    packet[4..].to_vec(),
                )
            } else {
                let header = u16::from_le_bytes([packet[1], packet[2]]);
                FromHost::Acl(
                    header & 0x0FFF,
                    ((header >> 12) & 0b11) as u8,
                    packet[5..].to_vec(),
                )
            });
        }
        packets
    }
}

/// The host's reading end of a device's port.
pub struct AirReader {
    pub(super) air: Rc<RefCell<AirState>>,
    pub(super) device: DeviceId,
    /// The port's generation: a robot that rebooted has a new port, and the old
    /// reader then waits for ever (its host is gone too).
    pub(super) generation: u32,
}

/// The host's writing end of a device's port.
pub struct AirWriter {
    pub(super) air: Rc<RefCell<AirState>>,
    pub(super) device: DeviceId,
    pub(super) generation: u32,
}

/// A controller in the air as its host's transport: the same type a UART-attached
/// controller gives (bt-hci-serial's), over the in-memory port.
pub type AirTransport = SerialTransport<NoopRawMutex, AirReader, AirWriter>;

/// A BLE pad's controller as its trouble-host stack takes it.
pub type AirController = ExternalController<AirTransport, 8>;

impl embedded_io::ErrorType for AirReader {
    type Error = HciError;
}

impl embedded_io::ErrorType for AirWriter {
    type Error = HciError;
}

impl embedded_io_async::Read for AirReader {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, HciError> {
        if buf.is_empty() {
            return Ok(0);
        }
        poll_fn(|cx| {
            let mut air = self.air.borrow_mut();
            let Some(port) = air.port(self.device, self.generation) else {
                // A port of a controller that was powered off: nothing comes any more.
                return Poll::Pending;
            };
            if port.to_host.is_empty() {
                port.reader = Some(cx.waker().clone());
                return Poll::Pending;
            }
            let n = buf.len().min(port.to_host.len());
            for (to, from) in buf.iter_mut().zip(port.to_host.drain(..n)) {
                *to = from;
            }
            Poll::Ready(Ok(n))
        })
        .await
    }
}

impl embedded_io_async::Write for AirWriter {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, HciError> {
        self.air
            .borrow_mut()
            .host_bytes(self.device, self.generation, buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), HciError> {
        Ok(())
    }
}
