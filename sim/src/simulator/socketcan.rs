//! The simulator as a node on a Linux SocketCAN interface (`--socketcan vcan0`): the
//! controller's frames go out on it and its frames come in, so candump, cansend and
//! ros2_socketcan see the simulated controller as a real one on `can0`. Needs a
//! kernel with CAN (`AF_CAN`) and an interface that is up, e.g.
//! `ip link add vcan0 type vcan && ip link set vcan0 up`.

use std::io;
use std::sync::Arc;
use std::sync::mpsc::{SyncSender, TrySendError, sync_channel};
use std::thread;

use embedded_can::Frame as _;
use socketcan::{CanFrame, CanSocket, Socket};

use super::socketcand::Event;
use super::wire_queue::{NODE_TRANSMIT_QUEUE, NodeCredit};
use crate::can::SimFrame;
use crate::runtime::QueueSender;

/// The client number the hub knows the interface by (socketcand clients count from 1).
pub const NODE: u64 = 0;
/// Frames that may wait for the interface's transmit queue.
const QUEUE: usize = 1024;

/// The simulator's end of the interface, as the hub holds it.
pub struct SocketCanLink {
    pub interface: String,
    to_interface: SyncSender<SimFrame>,
}

/// Whether this kernel can open CAN sockets at all; the error says why not.
pub fn kernel_has_can() -> io::Result<()> {
    use nix::sys::socket::{AddressFamily, SockFlag, SockProtocol, SockType, socket};
    match socket(
        AddressFamily::Can,
        SockType::Raw,
        SockFlag::SOCK_CLOEXEC,
        SockProtocol::CanRaw,
    ) {
        Ok(_socket) => Ok(()),
        Err(errno) => Err(io::Error::new(
            io::Error::from(errno).kind(),
            format!(
                "this kernel has no CAN sockets (AF_CAN: {errno}); load the can and can-raw \
                 modules, or use a machine whose kernel has them"
            ),
        )),
    }
}

impl SocketCanLink {
    /// Opens `interface` and starts a reader (frames to the hub as [`Event::Frame`]
    /// from [`NODE`]) and a writer thread.
    pub fn join(interface: &str, events: QueueSender<Event>) -> io::Result<Self> {
        kernel_has_can().map_err(|error| {
            io::Error::new(error.kind(), format!("--socketcan {interface}: {error}"))
        })?;
        let socket = Arc::new(CanSocket::open(interface).map_err(|error| {
            let why = match error.raw_os_error() {
                Some(code) if code == nix::errno::Errno::ENODEV as i32 => {
                    format!("no interface {interface} (ip link add {interface} type vcan)")
                }
                _ => error.to_string(),
            };
            io::Error::new(error.kind(), format!("--socketcan {interface}: {why}"))
        })?);
        let reader = socket.clone();
        // While the interface's frames fill their queue for the wire, the socket is not
        // read (its receive buffer takes what comes meanwhile, as the kernel's does).
        let credit = NodeCredit::new(NODE_TRANSMIT_QUEUE);
        thread::Builder::new()
            .name("socketcan-reader".into())
            .spawn(move || {
                while let Ok(frame) = reader.read_frame() {
                    let frame = if frame.is_remote_frame() {
                        SimFrame::new_remote(frame.id(), frame.dlc())
                    } else {
                        SimFrame::new(frame.id(), frame.data())
                    };
                    if let Some(frame) = frame {
                        events.send(Event::Frame {
                            client: NODE,
                            frame,
                            credit: credit.take(),
                        });
                    }
                }
                events.send(Event::Left {
                    client: NODE,
                    why: "the SocketCAN interface failed".to_owned(),
                });
            })?;
        let (to_interface, frames) = sync_channel::<SimFrame>(QUEUE);
        thread::Builder::new()
            .name("socketcan-writer".into())
            .spawn(move || {
                for frame in frames {
                    let frame = if frame.is_remote_frame() {
                        CanFrame::new_remote(frame.id(), frame.dlc())
                    } else {
                        CanFrame::new(frame.id(), frame.data())
                    };
                    // A frame the interface refuses (bus-off, queue full) is lost, as
                    // it would be on the wire.
                    if let Some(frame) = frame {
                        let _ = socket.write_frame(&frame);
                    }
                }
            })?;
        Ok(Self {
            interface: interface.to_owned(),
            to_interface,
        })
    }

    /// Queues a frame for the interface; false if its queue is full.
    pub fn offer(&self, frame: SimFrame) -> bool {
        !matches!(
            self.to_interface.try_send(frame),
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_))
        )
    }
}
