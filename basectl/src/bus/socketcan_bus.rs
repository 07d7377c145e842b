//! A Linux SocketCAN interface (`can0`, `slcan0`, `vcan0`). Its bit rate is the
//! interface's (`ip link set can0 type can bitrate 500000`), not basectl's.

use std::time::Duration;

use base_core::can::RawFrame;
use socketcan::{CanFrame, CanSocket, Socket};

use super::{Bus, BusError};

pub struct SocketCanBus {
    socket: CanSocket,
    interface: String,
}

impl SocketCanBus {
    pub fn open(interface: &str) -> Result<Self, BusError> {
        let socket = CanSocket::open(interface).map_err(|source| BusError::Io {
            what: format!("cannot open the CAN interface {interface} (is it up?)"),
            source,
        })?;
        Ok(Self {
            socket,
            interface: interface.to_owned(),
        })
    }
}

impl Bus for SocketCanBus {
    fn send(&mut self, frame: &RawFrame) -> Result<(), BusError> {
        self.socket
            .write_frame(
                &frame
                    .to_frame::<CanFrame>()
                    .expect("a RawFrame has an 11-bit ID and at most 8 bytes"),
            )
            .map_err(|source| BusError::Io {
                what: format!("cannot send on {}", self.interface),
                source,
            })
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<RawFrame>, BusError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let remaining = deadline.saturating_duration_since(std::time::Instant::now());
            if remaining.is_zero() {
                return Ok(None);
            }
            match self.socket.read_frame_timeout(remaining) {
                Ok(frame) => {
                    if let Some(frame) = RawFrame::from_frame(&frame) {
                        return Ok(Some(frame));
                    }
                }
                Err(error)
                    if matches!(
                        error.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Ok(None);
                }
                Err(source) => {
                    return Err(BusError::Io {
                        what: format!("cannot read from {}", self.interface),
                        source,
                    });
                }
            }
        }
    }
}
