//! The drive link task: carries out the decisions of [`base_core::drives::link`] on the
//! RS-485 line. It sends each request the core asks for and feeds the reply back,
//! waits as long as the core says (or until the controller's next demand), and passes
//! what the core reports on to the controller. Every decision (holding the drives at
//! zero, the setup, the cycle, when a drive counts as lost) is made in the core and
//! tested there with tables; this task knows bytes and time.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_futures::select::{Either, select};
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};

use crate::control::core_now;
use crate::hw::Rs485;
use crate::liveness::{CriticalTask, Liveness};
use crate::sync::{InputSender, RawMutex};
use base_core::drives::DriveSettings;
use base_core::drives::link::{DriveLink, Event, Next};
use base_core::modbus::Frame;
use base_core::time::Timestamp;

pub use base_core::drives::DriveDemand;

pub mod master;

use master::Master;

/// The drive link's channel ends (see [`crate::channels::Channels`]).
pub struct DriveLinkEnds<'a> {
    pub drive_demand: &'a Signal<RawMutex, DriveDemand>,
    pub inputs: InputSender<'a>,
    pub drive_brakes: &'a DriveBrakes,
    pub liveness: &'a Liveness,
}

/// Drive link → controller: whether both drives confirmed they are de-excited
/// ([`DriveLink::brakes_confirmed`]). A state, read before every controller input, so
/// one flag suffices (load and store only: the ESP32-C3 has no atomic swap).
pub struct DriveBrakes(AtomicBool);

impl DriveBrakes {
    /// Unknown at boot: not confirmed.
    pub const fn new() -> Self {
        Self(AtomicBool::new(false))
    }

    pub fn confirmed(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    fn set(&self, confirmed: bool) {
        self.0.store(confirmed, Ordering::Relaxed);
    }
}

impl Default for DriveBrakes {
    fn default() -> Self {
        Self::new()
    }
}

/// Runs the drive link forever. Every step checks in with the watchdog: the longest
/// step is one transaction (the reply timeout) or one wait (the poll interval or a
/// control cycle, both far below the watchdog's timeout).
pub async fn run<P: Rs485>(port: P, settings: DriveSettings, channels: DriveLinkEnds<'_>) -> ! {
    let mut master = Master::new(port, &settings.line, settings.reply_timeout_ms);
    let mut reply = Frame::new();
    let (mut link, mut effects) = DriveLink::boot(core_now(), &settings);
    // Replaced by the boot's first request before it is ever used.
    let mut next = Next::WaitUntil(Timestamp::BOOT);
    loop {
        channels.liveness.check_in(CriticalTask::DriveLink);
        channels.drive_brakes.set(link.brakes_confirmed());
        for input in effects.reports {
            channels.inputs.send(input).await;
        }
        if let Some(decided) = effects.next {
            next = decided;
        }
        effects = match &next {
            Next::Send(request) => {
                let transfer = master
                    .transact(&request.frame, request.expected_len, &mut reply)
                    .await;
                // A demand that came while the request was out is kept first, so the
                // link's next request already serves it (an e-stop never waits for
                // the rest of the feedback read).
                if let Some(demand) = channels.drive_demand.try_take() {
                    let kept = link.step(core_now(), Event::Demand(demand), &settings);
                    debug_assert!(kept.next.is_none() && kept.reports.is_empty());
                }
                let event = Event::Reply(transfer.map(|()| &reply[..]));
                link.step(core_now(), event, &settings)
            }
            Next::WaitUntil(at) => {
                let at = Instant::from_millis(at.as_millis());
                match select(Timer::at(at), channels.drive_demand.wait()).await {
                    Either::First(()) => link.step(core_now(), Event::Timer, &settings),
                    Either::Second(demand) => {
                        link.step(core_now(), Event::Demand(demand), &settings)
                    }
                }
            }
        };
    }
}
