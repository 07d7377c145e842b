//! The hardware traits: everything the tasks need from the board, and the only way
//! they reach hardware. The chip shell implements them with esp-hal; the virtual robot
//! (`sim/`) implements them in memory. Where a standard embedded trait fits, it is
//! used as is: `embedded-can` frames, `embedded-io-async` byte streams,
//! `embedded-storage-async` flash, `embedded-hal` pins.
//!
//! The async traits are used from one executor thread, so their futures need not be
//! `Send`; that is why `async_fn_in_trait` is allowed here.
#![allow(async_fn_in_trait)]

pub use embedded_can::Frame as CanFrame;
pub use embedded_hal::digital::{InputPin, OutputPin};
pub use embedded_io_async::{Read, Write};
pub use embedded_storage_async::nor_flash::NorFlash;

/// The CAN controller's view of the bus, for recovery decisions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BusState {
    /// Sending and receiving normally.
    Active,
    /// Error counters are high; the controller still sends, but only passive error flags.
    Passive,
    /// The controller left the bus after too many transmit errors and needs a restart.
    Off,
}

/// Why a CAN operation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CanError {
    /// The controller is bus-off; call [`CanTx::recover`].
    BusOff,
    /// Received frames were lost (receive FIFO overrun).
    Overrun,
    /// Any other bus error (stuff, form, CRC, acknowledge).
    Bus,
}

/// The receive half of the CAN controller.
pub trait CanRx {
    type Frame: CanFrame;
    /// The next frame that passed the acceptance filter.
    async fn receive(&mut self) -> Result<Self::Frame, CanError>;
}

/// The transmit half of the CAN controller.
pub trait CanTx {
    type Frame: CanFrame;
    /// Queues one frame and waits until the controller took it.
    async fn transmit(&mut self, frame: &Self::Frame) -> Result<(), CanError>;
    fn state(&mut self) -> BusState;
    /// Starts bus-off recovery (128 × 11 recessive bits); returns once the controller
    /// is back on the bus.
    async fn recover(&mut self);
}

/// The RS-485 line to the drives: a half-duplex byte stream.
///
/// Contract: `write` queues bytes for sending, and `flush` returns only when the last
/// stop bit has left the wire and the transceiver listens again (direction control
/// belongs to the implementation: the UART's RS-485 mode or a DE/RE pin). `read`
/// returns whatever arrived and waits when nothing has; the master bounds every read
/// with a timeout.
pub trait Rs485: Read + Write {}

/// The battery voltage, in mV at the battery (the board applies its divider).
pub trait BatteryVoltage {
    async fn read_millivolts(&mut self) -> Result<u16, SensorError>;
}

/// One raw reading of the load cell's ADC (24-bit, sign-extended).
pub trait LoadCell {
    async fn read_raw(&mut self) -> Result<i32, SensorError>;
}

/// A sensor did not deliver a reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SensorError {
    /// No answer in time (e.g. the HX711 never signalled ready).
    Timeout,
    /// The converter answered with an impossible value.
    Invalid,
}

/// The hardware watchdog. Feeding it is the liveness task's job alone.
pub trait Watchdog {
    fn feed(&mut self);
}
