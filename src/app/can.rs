//! The CAN tasks: receive frames into the input queue, and send what the controller
//! queued. A bus-off is reported and recovered from here; the controller never waits
//! for the bus.

use embassy_time::Timer;
use embedded_can::{Frame, Id, StandardId};

use crate::can::RawFrame;
use crate::controller::Input;
use crate::hw::{BusState, CanError, CanRx, CanTx};

use super::channels::Channels;

/// After a receive error, wait this long before the next attempt, so a controller
/// that keeps failing cannot starve the other tasks.
const ERROR_BACKOFF_MS: u64 = 10;

pub async fn run_rx<R: CanRx>(mut rx: R, channels: &Channels) -> ! {
    loop {
        match rx.receive().await {
            Ok(frame) => {
                // Extended and remote frames are not part of the protocol.
                if let Some(raw) = to_raw(&frame) {
                    channels.inputs.send(Input::CanFrame(raw)).await;
                }
            }
            Err(error) => {
                if matches!(error, CanError::Overrun | CanError::BusOff) {
                    channels.inputs.send(Input::CanBusFault).await;
                }
                Timer::after_millis(ERROR_BACKOFF_MS).await;
            }
        }
    }
}

pub async fn run_tx<T: CanTx>(mut tx: T, channels: &Channels) -> ! {
    loop {
        let raw = channels.can_tx.receive().await;
        if tx.state() == BusState::Off {
            recover(&mut tx, channels).await;
        }
        let Some(frame) = from_raw::<T::Frame>(&raw) else {
            continue;
        };
        if let Err(CanError::BusOff) = tx.transmit(&frame).await {
            // This frame is lost with the bus; the next period sends fresh values.
            recover(&mut tx, channels).await;
        }
    }
}

async fn recover<T: CanTx>(tx: &mut T, channels: &Channels) {
    warn!("CAN bus-off: recovering");
    channels.inputs.send(Input::CanBusFault).await;
    tx.recover().await;
    info!("CAN back on the bus");
}

/// A standard data frame as the codec's frame; `None` for anything else.
pub fn to_raw<F: Frame>(frame: &F) -> Option<RawFrame> {
    match frame.id() {
        Id::Standard(id) if frame.is_data_frame() => RawFrame::new(id.as_raw(), frame.data()),
        _ => None,
    }
}

/// The codec's frame as the driver's frame type.
pub fn from_raw<F: Frame>(raw: &RawFrame) -> Option<F> {
    F::new(StandardId::new(raw.id())?, raw.data())
}
