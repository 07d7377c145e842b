//! A scripted Bluetooth controller in memory, for the random-stream test and the fuzz
//! target: it answers every HCI command the host sends, connects when the host asks
//! (and encrypts when it asks), and then hands the host whatever packets the test
//! gives it, good or malformed, as a controller would pass on a peer's packets.
//!
//! No thread, no socket: it runs on the caller's executor, so with the virtual clock
//! (`crate::runtime::block_on`) a whole reconnect back-off costs no wall time.
//!
//! ```text
//!   host ──H4──▶ FakeWriter ─▶ Fake::on_command ─▶ Command Complete / Status,
//!                                                   LE Connection Complete, Encryption Change
//!   host ◀─H4── FakeReader ◀─ to_host ◀──────────── and, once connected, the script's packets
//! ```

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::poll_fn;
use std::rc::Rc;
use std::task::{Poll, Waker};

use bt_hci::controller::ExternalController;
use bt_hci_serial::SerialTransport;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;

use crate::ble::{HCI_SLOTS, HciError};

const CMD: u8 = 0x01;
const ACL: u8 = 0x02;
const EVENT: u8 = 0x04;

const EVENT_DISCONNECTION_COMPLETE: u8 = 0x05;
const EVENT_ENCRYPTION_CHANGE: u8 = 0x08;
const EVENT_COMMAND_COMPLETE: u8 = 0x0E;
const EVENT_COMMAND_STATUS: u8 = 0x0F;
const EVENT_LE_META: u8 = 0x3E;

const OP_DISCONNECT: u16 = 0x0406;
const OP_LE_CREATE_CONNECTION: u16 = 0x200D;
const OP_LE_CREATE_CONNECTION_CANCEL: u16 = 0x200E;
const OP_LE_ENABLE_ENCRYPTION: u16 = 0x2019;
const OP_LE_ADD_DEVICE_TO_FILTER_ACCEPT_LIST: u16 = 0x2011;
const OP_LE_SET_SCAN_ENABLE: u16 = 0x200C;

/// The pad the fake advertises while the host scans: random static address, and
/// advertising data with the flags and the gamepad appearance.
const PAD_ADDRESS: [u8; 6] = [0x55, 0x44, 0x33, 0x22, 0x11, 0xC1];
const PAD_ADVERTISING: [u8; 7] = [0x02, 0x01, 0x06, 0x03, 0x19, 0xC4, 0x03];

/// What the fake has done, for the test to check it ran at all.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FakeStats {
    /// HCI commands the host sent (zero: the host never touched the radio).
    pub commands: u32,
    pub connections: u32,
    pub packets_delivered: u32,
    pub disconnects_by_host: u32,
}

#[derive(Default)]
struct Fake {
    to_host: VecDeque<u8>,
    reader: Option<Waker>,
    from_host: Vec<u8>,
    /// H4 packets (type byte first) to deliver on the next link, in order.
    script: VecDeque<Vec<u8>>,
    /// The open link's handle.
    link: Option<u16>,
    /// The last address put on the filter accept list (type, address).
    accepted: Option<(u8, Vec<u8>)>,
    next_handle: u16,
    stats: FakeStats,
}

impl Fake {
    fn send(&mut self, packet: &[u8]) {
        self.to_host.extend(packet);
        if let Some(waker) = self.reader.take() {
            waker.wake();
        }
    }

    fn event(&mut self, code: u8, params: &[u8]) {
        let mut packet = vec![EVENT, code, params.len() as u8];
        packet.extend_from_slice(params);
        self.send(&packet);
    }

    fn complete(&mut self, opcode: u16, return_params: &[u8]) {
        let mut params = vec![1];
        params.extend_from_slice(&opcode.to_le_bytes());
        params.push(0);
        params.extend_from_slice(return_params);
        self.event(EVENT_COMMAND_COMPLETE, &params);
    }

    fn status(&mut self, opcode: u16, status: u8) {
        let [lo, hi] = opcode.to_le_bytes();
        self.event(EVENT_COMMAND_STATUS, &[status, 1, lo, hi]);
    }

    /// Takes the host's bytes and answers each complete H4 packet.
    fn on_bytes(&mut self, bytes: &[u8]) {
        self.from_host.extend_from_slice(bytes);
        loop {
            let length = match self.from_host.as_slice() {
                [CMD, _, _, len, ..] => 4 + usize::from(*len),
                [ACL, _, _, lo, hi, ..] => 5 + usize::from(u16::from_le_bytes([*lo, *hi])),
                [] => return,
                [_, ..] if self.from_host.len() < 5 => return,
                // Nothing else comes from a host; drop it.
                _ => {
                    self.from_host.clear();
                    return;
                }
            };
            if self.from_host.len() < length {
                return;
            }
            let packet: Vec<u8> = self.from_host.drain(..length).collect();
            if packet[0] == CMD {
                self.on_command(u16::from_le_bytes([packet[1], packet[2]]), &packet[4..]);
            }
        }
    }

    fn on_command(&mut self, opcode: u16, params: &[u8]) {
        self.stats.commands += 1;
        match opcode {
            OP_LE_CREATE_CONNECTION => {
                self.status(opcode, 0);
                // The peer: from the filter accept list (policy 1), or as asked for.
                let (kind, address) = match (params.get(4), params.get(5..12)) {
                    (Some(1), _) => self.accepted.clone().unwrap_or((0, vec![0; 6])),
                    (_, Some([kind, address @ ..])) => (*kind, address.to_vec()),
                    _ => (0, vec![0; 6]),
                };
                self.next_handle = (self.next_handle + 1) % 0x0EFF;
                let handle = 0x0040 + self.next_handle;
                self.link = Some(handle);
                self.stats.connections += 1;
                let mut complete = vec![0x01, 0x00];
                complete.extend_from_slice(&handle.to_le_bytes());
                complete.extend_from_slice(&[0x00, kind]);
                complete.extend_from_slice(&address);
                // Interval 7.5 ms, latency 0, supervision 500 ms, accuracy.
                complete.extend_from_slice(&[0x06, 0x00, 0x00, 0x00, 0x32, 0x00, 0x00]);
                self.event(EVENT_LE_META, &complete);
                self.deliver_script();
            }
            OP_LE_CREATE_CONNECTION_CANCEL => self.complete(opcode, &[]),
            OP_LE_SET_SCAN_ENABLE => {
                self.complete(opcode, &[]);
                if params.first() == Some(&1) {
                    // One connectable advertisement of a gamepad (LE Advertising Report).
                    let mut report = vec![0x02, 1, 0x00, 0x01];
                    report.extend_from_slice(&PAD_ADDRESS);
                    report.push(PAD_ADVERTISING.len() as u8);
                    report.extend_from_slice(&PAD_ADVERTISING);
                    report.push(0xC4);
                    self.event(EVENT_LE_META, &report);
                }
            }
            OP_LE_ADD_DEVICE_TO_FILTER_ACCEPT_LIST => {
                if let Some([kind, address @ ..]) = params.get(..7) {
                    self.accepted = Some((*kind, address.to_vec()));
                }
                self.complete(opcode, &[]);
            }
            OP_LE_ENABLE_ENCRYPTION => {
                self.status(opcode, 0);
                if let Some([lo, hi]) = params.get(..2).map(|p| [p[0], p[1]]) {
                    self.event(EVENT_ENCRYPTION_CHANGE, &[0, lo, hi, 1]);
                }
            }
            OP_DISCONNECT => {
                self.status(opcode, 0);
                if let Some(handle) = self.link.take() {
                    self.stats.disconnects_by_host += 1;
                    let [lo, hi] = handle.to_le_bytes();
                    self.event(EVENT_DISCONNECTION_COMPLETE, &[0, lo, hi, 0x16]);
                }
            }
            _ => {
                let return_params = return_params(opcode);
                self.complete(opcode, &return_params);
            }
        }
    }

    /// The script's packets, on the new link's handle (an ACL packet's handle bytes are
    /// replaced; its flags are kept).
    fn deliver_script(&mut self) {
        let Some(handle) = self.link else { return };
        while let Some(mut packet) = self.script.pop_front() {
            if packet.first() == Some(&ACL) && packet.len() >= 3 {
                let flags = packet[2] & 0xF0;
                let [lo, hi] = handle.to_le_bytes();
                packet[1] = lo;
                packet[2] = hi | flags;
            }
            self.stats.packets_delivered += 1;
            self.send(&packet);
        }
    }
}

/// The return parameters (after the status) of the commands whose answer carries
/// more than a status; every other command succeeds with its status alone.
fn return_params(opcode: u16) -> Vec<u8> {
    match opcode {
        // LE Read Buffer Size: 27-byte ACL packets, 8 of them.
        0x2002 => vec![27, 0, 8],
        // LE Read Buffer Size v2: the same, no ISO buffers.
        0x2060 => vec![27, 0, 8, 0, 0, 0],
        // LE Rand.
        0x2018 => vec![0x5A, 0x3C, 0x96, 0x0F, 0xE1, 0x2D, 0x78, 0xB4],
        // LE Read Filter Accept List Size.
        0x200F => vec![4],
        // Read BD_ADDR.
        0x1009 => vec![1, 2, 3, 4, 5, 6],
        // Read Local Version Information.
        0x1001 => vec![0x0C, 0, 0, 0x0C, 0xFF, 0xFF, 0, 0],
        // Read Local Supported Commands: everything.
        0x1002 => vec![0xFF; 64],
        // Read Local Supported Features, LE Read Local Supported Features.
        0x1003 | 0x2003 => vec![0; 8],
        // Read RSSI: handle, RSSI.
        0x1405 => vec![0x40, 0, 0xC4],
        // LE Set Data Length, LE Remote Connection Parameter Request (Negative) Reply.
        0x2020..=0x2022 => vec![0x40, 0],
        _ => Vec::new(),
    }
}

/// The host's end of the fake: reads what the controller sends.
pub struct FakeReader(Rc<RefCell<Fake>>);
/// The host's end of the fake: writes commands and data to the controller.
pub struct FakeWriter(Rc<RefCell<Fake>>);
/// The test's handle: scripts packets and reads the statistics.
#[derive(Clone)]
pub struct FakeHandle(Rc<RefCell<Fake>>);

/// The controller trouble-host drives, over the fake.
pub type FakeController =
    ExternalController<SerialTransport<NoopRawMutex, FakeReader, FakeWriter>, HCI_SLOTS>;

/// A fresh fake controller, and the handle to script it.
pub fn fake_controller() -> (FakeController, FakeHandle) {
    let fake = Rc::new(RefCell::new(Fake::default()));
    let controller = ExternalController::new(SerialTransport::new(
        FakeReader(fake.clone()),
        FakeWriter(fake.clone()),
    ));
    (controller, FakeHandle(fake))
}

impl FakeHandle {
    /// Packets (H4, type byte first) the next link delivers as soon as it is made; at
    /// once if a link is open.
    pub fn script(&self, packets: impl IntoIterator<Item = Vec<u8>>) {
        let mut fake = self.0.borrow_mut();
        fake.script.extend(packets);
        if fake.link.is_some() {
            fake.deliver_script();
        }
    }

    /// The peer drops the link (if one is open).
    pub fn peer_disconnects(&self) {
        let mut fake = self.0.borrow_mut();
        if let Some(handle) = fake.link.take() {
            let [lo, hi] = handle.to_le_bytes();
            fake.event(EVENT_DISCONNECTION_COMPLETE, &[0, lo, hi, 0x13]);
        }
    }

    pub fn stats(&self) -> FakeStats {
        self.0.borrow().stats
    }

    /// Whether every scripted packet went to the host.
    pub fn script_done(&self) -> bool {
        let fake = self.0.borrow();
        fake.script.is_empty() && fake.to_host.is_empty()
    }

    pub fn connected(&self) -> bool {
        self.0.borrow().link.is_some()
    }
}

impl embedded_io::ErrorType for FakeReader {
    type Error = HciError;
}

impl embedded_io::ErrorType for FakeWriter {
    type Error = HciError;
}

impl embedded_io_async::Read for FakeReader {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, HciError> {
        if buf.is_empty() {
            return Ok(0);
        }
        poll_fn(|cx| {
            let mut fake = self.0.borrow_mut();
            if fake.to_host.is_empty() {
                fake.reader = Some(cx.waker().clone());
                return Poll::Pending;
            }
            let n = buf.len().min(fake.to_host.len());
            for (to, from) in buf.iter_mut().zip(fake.to_host.drain(..n)) {
                *to = from;
            }
            Poll::Ready(Ok(n))
        })
        .await
    }
}

impl embedded_io_async::Write for FakeWriter {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, HciError> {
        self.0.borrow_mut().on_bytes(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), HciError> {
        Ok(())
    }
}
