//! The hardware watchdog: the RTC watchdog, which resets the whole chip, fed only by
//! the library's liveness task. Each feed also toggles the status LED, so a steady
//! 1 Hz blink means every critical task is alive, and a LED that stops blinking means
//! the watchdog is about to reset the chip.

use base_runtime::hw::Watchdog;
use esp_hal::gpio::{AnyPin, Level, Output, OutputConfig};
use esp_hal::peripherals::RTC_TIMER;
use esp_hal::rtc_cntl::{Rtc, Rwdt, RwdtStage, RwdtStageAction};
use esp_hal::time::Duration;

/// Four liveness periods (500 ms each): one late check-in is not a reset.
pub const TIMEOUT: Duration = Duration::from_millis(2_000);

pub struct LivenessWatchdog {
    rwdt: Rwdt,
    status_led: Output<'static>,
}

impl LivenessWatchdog {
    /// Arms the watchdog; from here on it must be fed within [`TIMEOUT`].
    pub fn start(rtc: RTC_TIMER<'static>, status_led: AnyPin<'static>) -> Self {
        let mut rwdt = Rtc::new(rtc).rwdt;
        rwdt.set_timeout(RwdtStage::Stage0, TIMEOUT);
        rwdt.set_stage_action(RwdtStage::Stage0, RwdtStageAction::ResetSystem);
        rwdt.enable();
        rwdt.feed();
        Self {
            rwdt,
            status_led: Output::new(status_led, Level::High, OutputConfig::default()),
        }
    }
}

impl Watchdog for LivenessWatchdog {
    fn feed(&mut self) {
        self.rwdt.feed();
        self.status_led.toggle();
    }
}
