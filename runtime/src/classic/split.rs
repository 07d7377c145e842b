//! The HCI splitter's task side: one HCI transport, two hosts. The BLE host reads and
//! writes through [`LeTransport`] (it wraps the controller's transport and is what
//! trouble-host's `ExternalController` is built on); the Classic task through
//! [`ClassicPort`]. Every packet the controller sends is read by the BLE host's
//! reader (trouble-host reads all the time) and routed by the core's
//! [`Splitter`]: the Classic host's packets are queued for the Classic task, never
//! shown to the BLE host.

use core::cell::RefCell;
use core::convert::Infallible;

use bt_hci::transport::{PacketToController, PacketToHost, Transport};
use bt_hci::{PacketKind, ReadHciError};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::channel::Channel;
use heapless::Vec;

use base_bluetooth::split::{Counters, Route, Sender, Splitter};

/// The longest HCI packet body (an event's 255 parameter bytes plus its header, or an
/// ACL packet of the controller's buffer) and its header.
pub const PACKET_MAX: usize = 259 + 4;
/// Classic links followed at once (the host serves one pad; room for a stranger's
/// page while it does).
const CLASSIC_LINKS: usize = 4;
/// Commands of both hosts waiting for their answer.
const PENDING_COMMANDS: usize = 16;
/// Packets queued for the Classic task: a burst of reports while it steps the host.
const CLASSIC_QUEUE: usize = 8;

/// A packet for the Classic host.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ClassicPacket {
    /// An event: code, length, parameters.
    Event(Vec<u8, PACKET_MAX>),
    /// An ACL packet: header, payload.
    Acl(Vec<u8, PACKET_MAX>),
    /// The BLE host reset the controller: set it up again.
    ControllerReset,
}

/// The splitter's state, shared by the BLE host's transport and the Classic task.
pub struct SplitState {
    splitter: Mutex<NoopRawMutex, RefCell<Splitter<CLASSIC_LINKS, PENDING_COMMANDS>>>,
    to_classic: Channel<NoopRawMutex, ClassicPacket, CLASSIC_QUEUE>,
}

impl Default for SplitState {
    fn default() -> Self {
        Self::new()
    }
}

impl SplitState {
    pub const fn new() -> Self {
        Self {
            splitter: Mutex::new(RefCell::new(Splitter::new())),
            to_classic: Channel::new(),
        }
    }

    pub fn counters(&self) -> Counters {
        self.splitter.lock(|splitter| splitter.borrow().counters())
    }

    fn with<R>(&self, f: impl FnOnce(&mut Splitter<CLASSIC_LINKS, PENDING_COMMANDS>) -> R) -> R {
        self.splitter.lock(|splitter| f(&mut splitter.borrow_mut()))
    }
}

/// One packet as the controller sent it: kind, header and body.
struct RawPacket<'d> {
    kind: PacketKind,
    /// Header and body; empty for a packet longer than the read buffer (read to its
    /// end and thrown away, so that the next packet starts where it should).
    bytes: &'d [u8],
    /// Its length as its header announces it.
    announced: usize,
}

/// Reads the `len` bytes of a packet too long for `buf` and throws them away.
fn skip<R: embedded_io::Read>(
    reader: &mut R,
    buf: &mut [u8],
    mut len: usize,
) -> Result<(), ReadHciError<R::Error>> {
    while len > 0 {
        let chunk = len.min(buf.len());
        reader.read_exact(&mut buf[..chunk])?;
        len -= chunk;
    }
    Ok(())
}

async fn skip_async<R: embedded_io_async::Read>(
    reader: &mut R,
    buf: &mut [u8],
    mut len: usize,
) -> Result<(), ReadHciError<R::Error>> {
    while len > 0 {
        let chunk = len.min(buf.len());
        reader.read_exact(&mut buf[..chunk]).await?;
        len -= chunk;
    }
    Ok(())
}

/// The header length of each packet kind and where its body length is.
fn header(kind: PacketKind) -> Result<usize, ()> {
    match kind {
        PacketKind::Event | PacketKind::SyncData => {
            Ok(if kind == PacketKind::Event { 2 } else { 3 })
        }
        PacketKind::AclData | PacketKind::IsoData => Ok(4),
        PacketKind::Cmd => Err(()),
    }
}

fn body_len(kind: PacketKind, header: &[u8]) -> usize {
    match kind {
        PacketKind::Event => usize::from(header[1]),
        PacketKind::SyncData => usize::from(header[2]),
        PacketKind::IsoData => usize::from(u16::from_le_bytes([header[2], header[3]]) & 0x3FFF),
        _ => usize::from(u16::from_le_bytes([header[2], header[3]])),
    }
}

impl<'d> PacketToHost<'d> for RawPacket<'d> {
    fn read_hci<R: embedded_io::Read>(
        kind: PacketKind,
        reader: &mut R,
        buf: &'d mut [u8],
    ) -> Result<Self, ReadHciError<R::Error>> {
        let head = header(kind).map_err(|()| ReadHciError::InvalidValue)?;
        if buf.len() < head {
            return Err(ReadHciError::BufferTooSmall);
        }
        reader.read_exact(&mut buf[..head])?;
        let len = head + body_len(kind, &buf[..head]);
        if buf.len() < len {
            skip(reader, buf, len - head)?;
            return Ok(RawPacket {
                kind,
                bytes: &[],
                announced: len,
            });
        }
        reader.read_exact(&mut buf[head..len])?;
        Ok(RawPacket {
            kind,
            bytes: &buf[..len],
            announced: len,
        })
    }

    async fn read_hci_async<R: embedded_io_async::Read>(
        kind: PacketKind,
        reader: &mut R,
        buf: &'d mut [u8],
    ) -> Result<Self, ReadHciError<R::Error>> {
        let head = header(kind).map_err(|()| ReadHciError::InvalidValue)?;
        if buf.len() < head {
            return Err(ReadHciError::BufferTooSmall);
        }
        reader.read_exact(&mut buf[..head]).await?;
        let len = head + body_len(kind, &buf[..head]);
        if buf.len() < len {
            skip_async(reader, buf, len - head).await?;
            return Ok(RawPacket {
                kind,
                bytes: &[],
                announced: len,
            });
        }
        reader.read_exact(&mut buf[head..len]).await?;
        Ok(RawPacket {
            kind,
            bytes: &buf[..len],
            announced: len,
        })
    }
}

/// A command packet as bytes (opcode, length, parameters).
struct RawCommand<'a>(&'a [u8]);
/// An ACL packet as bytes (header, payload).
struct RawAcl<'a>(&'a [u8]);

macro_rules! raw_packet_to_controller {
    ($name:ident, $kind:expr) => {
        impl PacketToController for $name<'_> {
            const KIND: PacketKind = $kind;

            fn size(&self) -> usize {
                self.0.len()
            }

            fn write_hci<W: embedded_io::Write>(&self, mut writer: W) -> Result<(), W::Error> {
                writer.write_all(self.0)
            }

            async fn write_hci_async<W: embedded_io_async::Write>(
                &self,
                mut writer: W,
            ) -> Result<(), W::Error> {
                writer.write_all(self.0).await
            }
        }
    };
}

raw_packet_to_controller!(RawCommand, PacketKind::Cmd);
raw_packet_to_controller!(RawAcl, PacketKind::AclData);

/// The controller's transport as the BLE host sees it.
pub struct LeTransport<'a, T> {
    inner: &'a T,
    state: &'a SplitState,
}

impl<'a, T> LeTransport<'a, T> {
    pub fn new(inner: &'a T, state: &'a SplitState) -> Self {
        Self { inner, state }
    }
}

impl<T: embedded_io::ErrorType> embedded_io::ErrorType for LeTransport<'_, T> {
    type Error = T::Error;
}

/// `bytes` (a whole packet of `kind`) as the packet type the host reads.
fn reparse<'d, P: PacketToHost<'d>, E: From<ReadHciError<Infallible>>>(
    kind: PacketKind,
    bytes: &[u8],
    rx: &'d mut [u8],
) -> Result<P, E> {
    let mut reader = bytes;
    P::read_hci(kind, &mut reader, rx).map_err(E::from)
}

fn copy(bytes: &[u8]) -> Vec<u8, PACKET_MAX> {
    // No packet is longer: the read buffer is this long.
    Vec::from_slice(&bytes[..bytes.len().min(PACKET_MAX)]).unwrap_or_default()
}

impl<T> Transport for LeTransport<'_, T>
where
    T: Transport,
    T::Error: From<ReadHciError<Infallible>>,
{
    async fn read<'d, P: PacketToHost<'d>>(&self, rx: &'d mut [u8]) -> Result<P, T::Error> {
        loop {
            let mut buffer = [0u8; PACKET_MAX];
            let packet: RawPacket<'_> = self.inner.read(&mut buffer).await?;
            // A packet longer than the splitter's buffer, or than the BLE host's (an
            // ACL packet beyond the hosts' Host Buffer Size, from a controller that
            // does not cut them): read to its end and dropped, counted. An error
            // here would stop both hosts.
            if !self
                .state
                .with(|split| split.admit(packet.announced, PACKET_MAX))
            {
                warn!(
                    "remote: dropped an HCI packet of {=usize} bytes from the controller, splitter {}",
                    packet.announced,
                    self.state.counters()
                );
                continue;
            }
            let bytes = packet.bytes;
            let route = match packet.kind {
                PacketKind::Event => {
                    let (code, params) = (bytes[0], &bytes[2..]);
                    let route = self.state.with(|split| split.route_event(code, params));
                    if route == Route::Both && code == 0x13 {
                        // Number of Completed Packets: each host its own handles.
                        let mut share = [0u8; PACKET_MAX];
                        let classic = self.state.with(|split| {
                            split.completed_packets_for(params, Sender::Classic, &mut share[2..])
                        });
                        if let Some(len) = classic {
                            share[0] = code;
                            share[1] = len as u8;
                            self.state
                                .to_classic
                                .send(ClassicPacket::Event(copy(&share[..2 + len])))
                                .await;
                        }
                        let le = self.state.with(|split| {
                            split.completed_packets_for(params, Sender::Le, &mut share[2..])
                        });
                        match le {
                            Some(len) => {
                                share[0] = code;
                                share[1] = len as u8;
                                return reparse(PacketKind::Event, &share[..2 + len], rx);
                            }
                            None => continue,
                        }
                    }
                    route
                }
                PacketKind::AclData => {
                    let handle = u16::from_le_bytes([bytes[0], bytes[1]]);
                    self.state.with(|split| split.route_acl(handle))
                }
                _ => Route::Le,
            };
            match route {
                Route::Le if !self.state.with(|split| split.admit(bytes.len(), rx.len())) => {
                    warn!(
                        "remote: dropped an HCI packet of {=usize} bytes, longer than the BLE host reads",
                        bytes.len()
                    );
                }
                Route::Le => return reparse(packet.kind, bytes, rx),
                Route::Classic => {
                    let copied = copy(bytes);
                    let to_classic = if packet.kind == PacketKind::Event {
                        ClassicPacket::Event(copied)
                    } else {
                        ClassicPacket::Acl(copied)
                    };
                    self.state.to_classic.send(to_classic).await;
                }
                Route::Both => {
                    // The answer to the BLE host's Reset, a credit update, a hardware
                    // error: the Classic host learns of it, the BLE host reads it.
                    let is_reset_answer =
                        bytes[0] == 0x0E && bytes.get(3..5) == Some(&[0x03, 0x0C]);
                    let to_classic = if is_reset_answer {
                        ClassicPacket::ControllerReset
                    } else {
                        ClassicPacket::Event(copy(bytes))
                    };
                    self.state.to_classic.send(to_classic).await;
                    return reparse(packet.kind, bytes, rx);
                }
            }
        }
    }

    async fn write<P: PacketToController>(&self, tx: &P) -> Result<(), T::Error> {
        if P::KIND != PacketKind::Cmd {
            return self.inner.write(tx).await;
        }
        let mut bytes = [0u8; PACKET_MAX];
        let len = tx.size().min(PACKET_MAX);
        // A command longer than a packet cannot exist; a write that fails leaves zeros,
        // which the controller refuses.
        let _ = tx.write_hci(&mut bytes[..len]);
        let command = &mut bytes[..len];
        self.state.with(|split| {
            // The Classic host's events on top of the BLE host's.
            split.patch_command(command, base_bluetooth::hci::EVENT_MASK);
            split.command_sent(Sender::Le, command);
        });
        self.inner.write(&RawCommand(command)).await
    }
}

/// The Classic task's end of the splitter.
pub struct ClassicPort<'a, T> {
    inner: &'a T,
    state: &'a SplitState,
}

impl<'a, T: Transport> ClassicPort<'a, T> {
    pub fn new(inner: &'a T, state: &'a SplitState) -> Self {
        Self { inner, state }
    }

    /// The next packet for the Classic host.
    pub async fn receive(&self) -> ClassicPacket {
        self.state.to_classic.receive().await
    }

    /// Sends a command packet of the Classic host.
    pub async fn send_command(&self, command: &[u8]) -> Result<(), T::Error> {
        self.state
            .with(|split| split.command_sent(Sender::Classic, command));
        self.inner.write(&RawCommand(command)).await
    }

    /// Sends an ACL packet of the Classic host.
    pub async fn send_acl(&self, packet: &[u8]) -> Result<(), T::Error> {
        self.inner.write(&RawAcl(packet)).await
    }
}
