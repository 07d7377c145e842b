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

/// Arms the watchdog straight after `esp_hal::init` (which stops the bootloader's):
/// a hang anywhere in the start, the image's arming write first of all, resets the
/// chip within [`TIMEOUT`]. The RTC block is borrowed only for this; the watchdog
/// keeps running until [`LivenessWatchdog::start`] takes it over.
pub fn guard_start(rtc: RTC_TIMER<'_>) {
    arm(&mut Rtc::new(rtc).rwdt);
}

fn arm(rwdt: &mut Rwdt) {
    rwdt.set_timeout(RwdtStage::Stage0, TIMEOUT);
    rwdt.set_stage_action(RwdtStage::Stage0, RwdtStageAction::ResetSystem);
    rwdt.enable();
    rwdt.feed();
}

impl LivenessWatchdog {
    /// Takes the watchdog over (arming it again, fed); from here on it must be fed
    /// within [`TIMEOUT`].
    pub fn start(rtc: RTC_TIMER<'static>, status_led: AnyPin<'static>) -> Self {
        let mut rwdt = Rtc::new(rtc).rwdt;
        arm(&mut rwdt);
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
