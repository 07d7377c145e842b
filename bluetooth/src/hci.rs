//! The HCI packets the Classic host sends and understands, as typed values and their
//! bytes (Bluetooth Core, Vol 4, Part E). Commands are encoded without the H4 packet
//! type byte (opcode, length, parameters); events are decoded from the same shape
//! (event code, length, parameters). Events the host has no use for decode to
//! [`Event::Other`]; a known event whose length does not match its parameters is a
//! [`HciError`], never a panic.

use heapless::Vec;

/// A device address as it travels on HCI: least significant byte first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BdAddr(pub [u8; 6]);

impl BdAddr {
    /// From the usual notation, most significant byte first (`AA:BB:…` order).
    pub const fn from_be(bytes: [u8; 6]) -> BdAddr {
        let [a, b, c, d, e, f] = bytes;
        BdAddr([f, e, d, c, b, a])
    }
}

/// A BR/EDR link key, as the controller hands it over after pairing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkKey(pub [u8; 16]);

/// A connection handle (12 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Handle(pub u16);

impl Handle {
    /// The handle in the 16 bits of an HCI field: its low 12 (an ACL header's top four
    /// are the packet's flags, an event's or a command's are reserved). The one place
    /// the guard, the splitter and the Classic host read a handle.
    pub const fn from_bits(bits: u16) -> Self {
        Self(bits & 0x0FFF)
    }

    /// The handle in a little-endian field of two bytes.
    pub const fn from_field(lo: u8, hi: u8) -> Self {
        Self::from_bits(u16::from_le_bytes([lo, hi]))
    }
}

/// Class of Device (24 bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClassOfDevice(pub u32);

impl ClassOfDevice {
    /// Major class Peripheral, minor class gamepad: what the DualShock 4 and the
    /// DualSense announce (0x002508 in pairing mode).
    pub fn is_gamepad(self) -> bool {
        let major = (self.0 >> 8) & 0x1F;
        let peripheral_type = (self.0 >> 2) & 0x0F;
        major == 0x05 && peripheral_type == 0x02
    }
}

/// Status codes the host acts on or sends (Core Vol 1, Part F).
pub mod status {
    pub const SUCCESS: u8 = 0x00;
    pub const PAGE_TIMEOUT: u8 = 0x04;
    pub const AUTHENTICATION_FAILURE: u8 = 0x05;
    pub const PIN_OR_KEY_MISSING: u8 = 0x06;
    pub const CONNECTION_TIMEOUT: u8 = 0x08;
    pub const REJECTED_LIMITED_RESOURCES: u8 = 0x0D;
    pub const REJECTED_SECURITY: u8 = 0x0E;
    pub const REJECTED_UNACCEPTABLE_ADDRESS: u8 = 0x0F;
    pub const REMOTE_USER_TERMINATED: u8 = 0x13;
    pub const PAIRING_NOT_ALLOWED: u8 = 0x18;
}

/// The General Inquiry Access Code's LAP: the pads in pairing mode answer it.
pub const GIAC: u32 = 0x9E_8B33;

/// Write Scan Enable's values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScanEnable {
    /// Connectable: a bonded pad may page us. Never discoverable: a pad finds the
    /// robot only by its bond.
    PageScan = 0x02,
}

/// The commands of the Classic host.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command {
    Reset,
    ReadBufferSize,
    /// The event mask, bit n enables event code n + 1.
    SetEventMask(u64),
    WriteSimplePairingMode {
        enabled: bool,
    },
    WriteClassOfDevice(ClassOfDevice),
    /// In baseband slots of 0.625 ms.
    WritePageTimeout {
        slots: u16,
    },
    /// Bit 0 role switch, bit 2 sniff mode.
    WriteDefaultLinkPolicy {
        settings: u16,
    },
    WriteScanEnable(ScanEnable),
    /// `length` in units of 1.28 s.
    Inquiry {
        lap: u32,
        length: u8,
        max_responses: u8,
    },
    InquiryCancel,
    CreateConnection {
        addr: BdAddr,
        page_scan_repetition_mode: u8,
        clock_offset: u16,
        allow_role_switch: bool,
    },
    CreateConnectionCancel(BdAddr),
    /// Accepted as central: the controller switches roles while connecting.
    AcceptConnectionRequest(BdAddr),
    RejectConnectionRequest {
        addr: BdAddr,
        reason: u8,
    },
    Disconnect {
        handle: Handle,
        reason: u8,
    },
    LinkKeyRequestReply {
        addr: BdAddr,
        key: LinkKey,
    },
    LinkKeyRequestNegativeReply(BdAddr),
    PinCodeRequestNegativeReply(BdAddr),
    AuthenticationRequested(Handle),
    SetConnectionEncryption {
        handle: Handle,
        enabled: bool,
    },
    /// Answered with no input and no output: Just Works, general bonding, no MITM.
    IoCapabilityRequestReply(BdAddr),
    IoCapabilityRequestNegativeReply {
        addr: BdAddr,
        reason: u8,
    },
    UserConfirmationRequestReply(BdAddr),
    UserConfirmationRequestNegativeReply(BdAddr),
    SwitchRoleToCentral(BdAddr),
    /// In baseband slots of 0.625 ms; only the central may set it.
    WriteLinkSupervisionTimeout {
        handle: Handle,
        slots: u16,
    },
}

/// An encoded command: opcode (LE), parameter length, parameters.
pub type CommandPacket = Vec<u8, 32>;

impl Command {
    pub fn opcode(&self) -> u16 {
        const fn op(ogf: u16, ocf: u16) -> u16 {
            (ogf << 10) | ocf
        }
        match self {
            Command::Inquiry { .. } => op(0x01, 0x0001),
            Command::InquiryCancel => op(0x01, 0x0002),
            Command::CreateConnection { .. } => op(0x01, 0x0005),
            Command::Disconnect { .. } => op(0x01, 0x0006),
            Command::CreateConnectionCancel(_) => op(0x01, 0x0008),
            Command::AcceptConnectionRequest(_) => op(0x01, 0x0009),
            Command::RejectConnectionRequest { .. } => op(0x01, 0x000A),
            Command::LinkKeyRequestReply { .. } => op(0x01, 0x000B),
            Command::LinkKeyRequestNegativeReply(_) => op(0x01, 0x000C),
            Command::PinCodeRequestNegativeReply(_) => op(0x01, 0x000E),
            Command::AuthenticationRequested(_) => op(0x01, 0x0011),
            Command::SetConnectionEncryption { .. } => op(0x01, 0x0013),
            Command::IoCapabilityRequestReply(_) => op(0x01, 0x002B),
            Command::UserConfirmationRequestReply(_) => op(0x01, 0x002C),
            Command::UserConfirmationRequestNegativeReply(_) => op(0x01, 0x002D),
            Command::IoCapabilityRequestNegativeReply { .. } => op(0x01, 0x0034),
            Command::SwitchRoleToCentral(_) => op(0x02, 0x000B),
            Command::WriteDefaultLinkPolicy { .. } => op(0x02, 0x000F),
            Command::SetEventMask(_) => op(0x03, 0x0001),
            Command::Reset => op(0x03, 0x0003),
            Command::WritePageTimeout { .. } => op(0x03, 0x0018),
            Command::WriteScanEnable(_) => op(0x03, 0x001A),
            Command::WriteClassOfDevice(_) => op(0x03, 0x0024),
            Command::WriteLinkSupervisionTimeout { .. } => op(0x03, 0x0037),
            Command::WriteSimplePairingMode { .. } => op(0x03, 0x0056),
            Command::ReadBufferSize => op(0x04, 0x0005),
        }
    }

    pub fn encode(&self) -> CommandPacket {
        let mut params: Vec<u8, 29> = Vec::new();
        // The longest parameters (Link Key Request Reply) are 22 bytes: every push fits.
        let mut put = |bytes: &[u8]| {
            let _ = params.extend_from_slice(bytes);
        };
        match *self {
            Command::Reset | Command::ReadBufferSize | Command::InquiryCancel => {}
            Command::SetEventMask(mask) => put(&mask.to_le_bytes()),
            Command::WriteSimplePairingMode { enabled } => put(&[u8::from(enabled)]),
            Command::WriteClassOfDevice(class) => put(&class.0.to_le_bytes()[..3]),
            Command::WritePageTimeout { slots } => put(&slots.to_le_bytes()),
            Command::WriteDefaultLinkPolicy { settings } => put(&settings.to_le_bytes()),
            Command::WriteScanEnable(scan) => put(&[scan as u8]),
            Command::Inquiry {
                lap,
                length,
                max_responses,
            } => {
                put(&lap.to_le_bytes()[..3]);
                put(&[length, max_responses]);
            }
            Command::CreateConnection {
                addr,
                page_scan_repetition_mode,
                clock_offset,
                allow_role_switch,
            } => {
                put(&addr.0);
                // DM1, DH1, DM3, DH3, DM5, DH5: every ACL packet type.
                put(&0xCC18u16.to_le_bytes());
                put(&[page_scan_repetition_mode, 0]);
                put(&clock_offset.to_le_bytes());
                put(&[u8::from(allow_role_switch)]);
            }
            Command::AcceptConnectionRequest(addr) => {
                put(&addr.0);
                // Role 0x00: become the central.
                put(&[0x00]);
            }
            Command::RejectConnectionRequest { addr, reason } => {
                put(&addr.0);
                put(&[reason]);
            }
            Command::Disconnect { handle, reason } => {
                put(&handle.0.to_le_bytes());
                put(&[reason]);
            }
            Command::LinkKeyRequestReply { addr, key } => {
                put(&addr.0);
                put(&key.0);
            }
            Command::CreateConnectionCancel(addr)
            | Command::LinkKeyRequestNegativeReply(addr)
            | Command::PinCodeRequestNegativeReply(addr)
            | Command::UserConfirmationRequestReply(addr)
            | Command::UserConfirmationRequestNegativeReply(addr) => put(&addr.0),
            Command::AuthenticationRequested(handle) => put(&handle.0.to_le_bytes()),
            Command::SetConnectionEncryption { handle, enabled } => {
                put(&handle.0.to_le_bytes());
                put(&[u8::from(enabled)]);
            }
            Command::IoCapabilityRequestReply(addr) => {
                put(&addr.0);
                // NoInputNoOutput, no OOB data, general bonding without MITM protection.
                put(&[0x03, 0x00, 0x04]);
            }
            Command::IoCapabilityRequestNegativeReply { addr, reason } => {
                put(&addr.0);
                put(&[reason]);
            }
            Command::SwitchRoleToCentral(addr) => {
                put(&addr.0);
                put(&[0x00]);
            }
            Command::WriteLinkSupervisionTimeout { handle, slots } => {
                put(&handle.0.to_le_bytes());
                put(&slots.to_le_bytes());
            }
        }
        let mut packet = CommandPacket::new();
        let _ = packet.extend_from_slice(&self.opcode().to_le_bytes());
        let _ = packet.push(params.len() as u8);
        let _ = packet.extend_from_slice(&params);
        packet
    }
}

/// Why an HCI event was not decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HciError {
    /// Shorter than an event header, or than its own length field says.
    Truncated,
    /// The length field does not fit the parameters the event must carry.
    BadLength { code: u8, length: u8 },
}

/// One device found by an inquiry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InquiryResponse {
    pub addr: BdAddr,
    pub page_scan_repetition_mode: u8,
    pub class: ClassOfDevice,
    pub clock_offset: u16,
}

/// How many responses of one Inquiry Result event are kept; the rest are dropped
/// (the controller sends one per event in practice).
pub const MAX_INQUIRY_RESPONSES: usize = 4;

/// How many handles of one Number Of Completed Packets event are kept (one link here).
pub const MAX_COMPLETED_HANDLES: usize = 4;

/// The events the Classic host understands.
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    InquiryComplete {
        status: u8,
    },
    InquiryResult(Vec<InquiryResponse, MAX_INQUIRY_RESPONSES>),
    ConnectionComplete {
        status: u8,
        handle: Handle,
        addr: BdAddr,
        encrypted: bool,
    },
    ConnectionRequest {
        addr: BdAddr,
        class: ClassOfDevice,
        /// 0x01: ACL (an SCO request is refused).
        link_type: u8,
    },
    DisconnectionComplete {
        status: u8,
        handle: Handle,
        reason: u8,
    },
    AuthenticationComplete {
        status: u8,
        handle: Handle,
    },
    EncryptionChange {
        status: u8,
        handle: Handle,
        enabled: bool,
    },
    CommandComplete {
        credits: u8,
        opcode: u16,
        status: u8,
        /// Read Buffer Size's answer: ACL packet length and count.
        acl_buffers: Option<AclBuffers>,
    },
    CommandStatus {
        status: u8,
        credits: u8,
        opcode: u16,
    },
    HardwareError {
        code: u8,
    },
    RoleChange {
        status: u8,
        addr: BdAddr,
        central: bool,
    },
    NumberOfCompletedPackets(Vec<(Handle, u16), MAX_COMPLETED_HANDLES>),
    PinCodeRequest(BdAddr),
    LinkKeyRequest(BdAddr),
    LinkKeyNotification {
        addr: BdAddr,
        key: LinkKey,
        key_type: u8,
    },
    IoCapabilityRequest(BdAddr),
    UserConfirmationRequest(BdAddr),
    SimplePairingComplete {
        status: u8,
        addr: BdAddr,
    },
    /// Any other event: well-formed as far as we know, and of no use to the host.
    Other {
        code: u8,
    },
}

/// The controller's ACL buffers, from Read Buffer Size.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AclBuffers {
    /// The longest ACL payload the controller takes, in bytes.
    pub packet_len: u16,
    /// How many ACL packets it buffers.
    pub packets: u16,
}

/// A cursor over event parameters that fails instead of panicking.
struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        if self.bytes.len() < n {
            return None;
        }
        let (head, rest) = self.bytes.split_at(n);
        self.bytes = rest;
        Some(head)
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1).map(|b| b[0])
    }
    fn u16(&mut self) -> Option<u16> {
        self.take(2).map(|b| u16::from_le_bytes([b[0], b[1]]))
    }
    fn u24(&mut self) -> Option<u32> {
        self.take(3)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], 0]))
    }
    fn addr(&mut self) -> Option<BdAddr> {
        let b = self.take(6)?;
        Some(BdAddr([b[0], b[1], b[2], b[3], b[4], b[5]]))
    }
    fn handle(&mut self) -> Option<Handle> {
        self.u16().map(Handle::from_bits)
    }
    fn key(&mut self) -> Option<LinkKey> {
        let mut key = [0; 16];
        key.copy_from_slice(self.take(16)?);
        Some(LinkKey(key))
    }
}

impl Event {
    /// Decodes an event packet: code, length, parameters. Bytes past the length are
    /// refused as a bad length, as are parameters shorter than the event's fixed ones.
    pub fn decode(packet: &[u8]) -> Result<Event, HciError> {
        let [code, length, params @ ..] = packet else {
            return Err(HciError::Truncated);
        };
        if params.len() != usize::from(*length) {
            return Err(HciError::Truncated);
        }
        let (code, length) = (*code, *length);
        let mut r = Reader { bytes: params };
        let event = Self::parameters(code, &mut r).ok_or(HciError::BadLength { code, length })?;
        // Command Complete carries the command's own return parameters, and events
        // of no use to us are not checked: only the others must be used up exactly.
        let open_ended = matches!(event, Event::CommandComplete { .. } | Event::Other { .. });
        if !open_ended && !r.bytes.is_empty() {
            return Err(HciError::BadLength { code, length });
        }
        Ok(event)
    }

    fn parameters(code: u8, r: &mut Reader<'_>) -> Option<Event> {
        Some(match code {
            0x01 => Event::InquiryComplete { status: r.u8()? },
            0x02 => {
                let count = usize::from(r.u8()?);
                let addrs = r.take(6 * count)?;
                let modes = r.take(count)?;
                r.take(2 * count)?; // reserved
                let classes = r.take(3 * count)?;
                let offsets = r.take(2 * count)?;
                let mut responses = Vec::new();
                for i in 0..count.min(MAX_INQUIRY_RESPONSES) {
                    let a = &addrs[6 * i..6 * i + 6];
                    let c = &classes[3 * i..3 * i + 3];
                    let o = &offsets[2 * i..2 * i + 2];
                    let _ = responses.push(InquiryResponse {
                        addr: BdAddr([a[0], a[1], a[2], a[3], a[4], a[5]]),
                        page_scan_repetition_mode: modes[i],
                        class: ClassOfDevice(u32::from_le_bytes([c[0], c[1], c[2], 0])),
                        clock_offset: u16::from_le_bytes([o[0], o[1]]),
                    });
                }
                Event::InquiryResult(responses)
            }
            0x03 => {
                let status = r.u8()?;
                let handle = r.handle()?;
                let addr = r.addr()?;
                let _link_type = r.u8()?;
                let encrypted = r.u8()? != 0;
                Event::ConnectionComplete {
                    status,
                    handle,
                    addr,
                    encrypted,
                }
            }
            0x04 => Event::ConnectionRequest {
                addr: r.addr()?,
                class: ClassOfDevice(r.u24()?),
                link_type: r.u8()?,
            },
            0x05 => Event::DisconnectionComplete {
                status: r.u8()?,
                handle: r.handle()?,
                reason: r.u8()?,
            },
            0x06 => Event::AuthenticationComplete {
                status: r.u8()?,
                handle: r.handle()?,
            },
            0x08 => Event::EncryptionChange {
                status: r.u8()?,
                handle: r.handle()?,
                enabled: r.u8()? != 0,
            },
            0x0E => {
                let credits = r.u8()?;
                let opcode = r.u16()?;
                // A No-Op Command Complete (opcode 0) only returns credits.
                let status = if opcode == 0 { 0 } else { r.u8()? };
                let acl_buffers = if opcode == Command::ReadBufferSize.opcode() && status == 0 {
                    let packet_len = r.u16()?;
                    let _sco_len = r.u8()?;
                    let packets = r.u16()?;
                    let _sco_packets = r.u16()?;
                    Some(AclBuffers {
                        packet_len,
                        packets,
                    })
                } else {
                    None
                };
                Event::CommandComplete {
                    credits,
                    opcode,
                    status,
                    acl_buffers,
                }
            }
            0x0F => Event::CommandStatus {
                status: r.u8()?,
                credits: r.u8()?,
                opcode: r.u16()?,
            },
            0x10 => Event::HardwareError { code: r.u8()? },
            0x12 => Event::RoleChange {
                status: r.u8()?,
                addr: r.addr()?,
                central: r.u8()? == 0x00,
            },
            0x13 => {
                let count = usize::from(r.u8()?);
                let mut completed = Vec::new();
                for _ in 0..count {
                    let entry = (r.handle()?, r.u16()?);
                    // More handles than links: the extra ones cannot be ours.
                    let _ = completed.push(entry);
                }
                Event::NumberOfCompletedPackets(completed)
            }
            0x16 => Event::PinCodeRequest(r.addr()?),
            0x17 => Event::LinkKeyRequest(r.addr()?),
            0x18 => Event::LinkKeyNotification {
                addr: r.addr()?,
                key: r.key()?,
                key_type: r.u8()?,
            },
            0x31 => Event::IoCapabilityRequest(r.addr()?),
            0x33 => {
                let addr = r.addr()?;
                let _numeric_value = r.u16()?;
                let _ = r.u16()?;
                Event::UserConfirmationRequest(addr)
            }
            0x36 => Event::SimplePairingComplete {
                status: r.u8()?,
                addr: r.addr()?,
            },
            code => Event::Other { code },
        })
    }
}

/// The events the host enables with Set Event Mask: the defaults (bits 0-44 less
/// the reserved ones, as after a reset) plus Simple Pairing's (bits 48-55).
pub const EVENT_MASK: u64 = 0x00FF_1FFF_FFFF_FFFF;

#[cfg(test)]
mod tests;
