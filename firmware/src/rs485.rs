//! The RS-485 line to the drives: a UART plus the transceiver's driver-enable pin.
//! esp-hal's UART has no RS-485 mode, so direction control is here: the driver is
//! enabled before the first byte and released once `flush` has seen the last stop bit
//! leave, which is the [`Rs485`] contract.

use base_core::drives::{LineSettings, Parity};
use base_runtime::hw::Rs485;
use embedded_io_async::{ErrorType, Read, Write};
use esp_hal::Async;
use esp_hal::gpio::{AnyPin, Level, Output, OutputConfig};
use esp_hal::peripherals::UART1;
use esp_hal::uart::{self, ConfigError, IoError, RxConfig, StopBits, Uart};

/// The UART hands received bytes over after this many idle character times. Short,
/// so a reply reaches the master well inside the Modbus 3.5-character frame gap.
const RX_IDLE_CHARS: u8 = 3;

pub struct Rs485Port {
    uart: Uart<'static, Async>,
    driver_enable: Output<'static>,
}

impl Rs485Port {
    pub fn new(
        uart: UART1<'static>,
        tx: AnyPin<'static>,
        rx: AnyPin<'static>,
        driver_enable: AnyPin<'static>,
        line: &LineSettings,
    ) -> Result<Self, ConfigError> {
        let config = uart::Config::default()
            .with_baudrate(line.baud)
            .with_parity(match line.parity {
                Parity::None => uart::Parity::None,
                Parity::Even => uart::Parity::Even,
                Parity::Odd => uart::Parity::Odd,
            })
            .with_stop_bits(if line.stop_bits == 2 {
                StopBits::_2
            } else {
                StopBits::_1
            })
            .with_rx(RxConfig::default().with_timeout(RX_IDLE_CHARS));
        let uart = Uart::new(uart, config)?
            .with_tx(tx)
            .with_rx(rx)
            .into_async();
        Ok(Self {
            uart,
            // Receiving until we send.
            driver_enable: Output::new(driver_enable, Level::Low, OutputConfig::default()),
        })
    }
}

impl ErrorType for Rs485Port {
    type Error = IoError;
}

impl Read for Rs485Port {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, IoError> {
        Read::read(&mut self.uart, buf).await
    }
}

impl Write for Rs485Port {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, IoError> {
        self.driver_enable.set_high();
        Write::write(&mut self.uart, buf).await
    }

    async fn flush(&mut self) -> Result<(), IoError> {
        let flushed = Write::flush(&mut self.uart).await;
        // Release the line even after an error, so the drives' replies get through.
        self.driver_enable.set_low();
        flushed
    }
}

impl Rs485 for Rs485Port {}
