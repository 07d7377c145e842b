//! CAN on the TWAI controller: the receive and transmit halves as the library's
//! [`CanRx`] and [`CanTx`], with the acceptance filters of
//! [`base_core::can::filter`] and the bit rate chosen at build time.

use base_core::can::filter::COMMAND_FILTERS;
use base_runtime::hw::{BusState, CanError, CanRx, CanTx};
use embassy_time::Timer;
use esp_hal::Async;
use esp_hal::gpio::AnyPin;
use esp_hal::peripherals::TWAI0;
use esp_hal::twai::filter::DualStandardFilter;
use esp_hal::twai::{
    BaudRate, ErrorKind, EspTwaiError, EspTwaiFrame, StandardId, TwaiConfiguration, TwaiMode,
    TwaiRx, TwaiTx,
};

/// The bus bit rate in kbit/s: 500 (the manual's) unless `CAN_BITRATE_KBIT` is set when
/// building.
pub const BIT_RATE_KBIT: u16 = match option_env!("CAN_BITRATE_KBIT") {
    None => 500,
    Some(kbit) => match kbit.as_bytes() {
        b"125" => 125,
        b"250" => 250,
        b"500" => 500,
        b"1000" => 1000,
        _ => panic!("CAN_BITRATE_KBIT must be 125, 250, 500 or 1000"),
    },
};

const BIT_RATE: BaudRate = match BIT_RATE_KBIT {
    125 => BaudRate::B125K,
    250 => BaudRate::B250K,
    1000 => BaudRate::B1000K,
    _ => BaudRate::B500K,
};

/// How often recovery looks whether the controller is back on the bus. Recovery takes
/// 128 × 11 recessive bits: 2.8 ms at 500 kbit/s on an idle bus.
const RECOVERY_POLL_MS: u64 = 1;

/// Starts the controller on the bus and splits it into the two halves the tasks own.
pub fn start(twai: TWAI0<'static>, tx: AnyPin<'static>, rx: AnyPin<'static>) -> (Receiver, Sender) {
    let mut config = TwaiConfiguration::new(twai, rx, tx, BIT_RATE, TwaiMode::Normal).into_async();
    config.set_filter(command_filter());
    let (rx, tx) = config.start().split();
    (Receiver { rx }, Sender { tx })
}

/// The TWAI's dual filter mode from the protocol's two command filters: data frames
/// only, any payload.
pub fn command_filter() -> DualStandardFilter {
    let [first, second] = COMMAND_FILTERS;
    DualStandardFilter::new_from_code_mask(
        standard(first.code),
        standard(first.mask),
        false,
        true,
        0,
        0,
        standard(second.code),
        standard(second.mask),
        false,
        true,
    )
}

/// Filter bits as an ID; they are 11 bits wide by construction, so the fallback is
/// never taken.
fn standard(bits: u16) -> StandardId {
    StandardId::new(bits & StandardId::MAX.as_raw()).unwrap_or(StandardId::ZERO)
}

pub struct Receiver {
    rx: TwaiRx<'static, Async>,
}

pub struct Sender {
    tx: TwaiTx<'static, Async>,
}

impl CanRx for Receiver {
    type Frame = EspTwaiFrame;

    async fn receive(&mut self) -> Result<EspTwaiFrame, CanError> {
        self.rx.receive_async().await.map_err(can_error)
    }
}

impl CanTx for Sender {
    type Frame = EspTwaiFrame;

    async fn transmit(&mut self, frame: &EspTwaiFrame) -> Result<(), CanError> {
        self.tx.transmit_async(frame).await.map_err(can_error)
    }

    // esp-hal's split halves do not expose the error state or the recovery (only the
    // unsplit `Twai` does), so these two read and write the controller's registers
    // exactly as `Twai::is_bus_off` and `Twai::initiate_recovery` do.
    fn state(&mut self) -> BusState {
        let regs = TWAI0::regs();
        if regs.status().read().bus_off_st().bit_is_set() {
            BusState::Off
        } else if regs.tx_err_cnt().read().tx_err_cnt().bits() >= 128
            || regs.rx_err_cnt().read().rx_err_cnt().bits() >= 128
        {
            BusState::Passive
        } else {
            BusState::Active
        }
    }

    async fn recover(&mut self) {
        let regs = TWAI0::regs();
        if regs.status().read().bus_off_st().bit_is_set() {
            // Bus-off parks the controller in reset mode; leaving it starts recovery.
            regs.mode().modify(|_, w| w.reset_mode().set_bit());
            regs.mode().modify(|_, w| w.reset_mode().clear_bit());
        }
        while regs.status().read().bus_off_st().bit_is_set() {
            Timer::after_millis(RECOVERY_POLL_MS).await;
        }
    }
}

fn can_error(error: EspTwaiError) -> CanError {
    match error {
        EspTwaiError::BusOff => CanError::BusOff,
        EspTwaiError::EmbeddedHAL(ErrorKind::Overrun) => CanError::Overrun,
        _ => CanError::Bus,
    }
}
