//! The controller task: the only caller of [`Controller::handle`]. It turns the input
//! queue and a 10 ms tick into calls, and hands each output to whoever acts on it.

use embassy_futures::select::{Either, select};
use embassy_futures::yield_now;
use embassy_time::{Duration, Instant, Timer};

use embassy_sync::signal::Signal;

use base_core::controller::{Controller, Input, Output};
use base_core::hid::light_bar::BaseLight;
use base_core::power::SwitchLevel;
use base_core::registers::Reg;
use base_core::time;

use crate::ble::RemoteRequest;
use crate::can::FrameQueue;
use crate::drive_link::{DriveBrakes, DriveDemand};
use crate::hw::OutputPin;
use crate::liveness::{CriticalTask, Liveness};
use crate::store::PendingWrites;
use crate::sync::{InputReceiver, RawMutex};
use crate::update::UpdateLink;

/// Timeouts and periodic frames are checked this often (the controller's contract).
pub const TICK: Duration = Duration::from_millis(10);

/// The core's time: milliseconds since boot.
pub fn core_now() -> time::Timestamp {
    time::Timestamp::from_millis(Instant::now().as_millis())
}

/// The controller task's channel ends (see [`crate::channels::Channels`]).
pub struct ControlEnds<'a> {
    pub inputs: InputReceiver<'a>,
    pub can_tx: &'a FrameQueue,
    pub drive_demand: &'a Signal<RawMutex, DriveDemand>,
    pub pending_writes: &'a PendingWrites,
    pub drive_brakes: &'a DriveBrakes,
    pub remote_requests: &'a Signal<RawMutex, RemoteRequest>,
    pub base_light: &'a Signal<RawMutex, BaseLight>,
    pub liveness: &'a Liveness,
    pub update: &'a UpdateLink,
}

pub async fn run<S: OutputPin>(
    mut controller: Controller,
    channels: ControlEnds<'_>,
    mut pc_switch: S,
) -> ! {
    let registers = controller.registers();
    let demand = DriveDemand::at_rest(
        registers.get(Reg::LoopEndDelay),
        u32::from(registers.get(Reg::EstopDecel)),
    );
    // The drive link starts from the defaults; this gives it the stored cycle time.
    channels.drive_demand.signal(demand);
    let mut state = Dispatched {
        demand,
        remote: RemoteRequest::default(),
        light: None,
    };
    // What the controller last heard of the update task's motion lock.
    let mut update_lock = false;
    let mut next_tick = Instant::now() + TICK;
    // One input or one tick per iteration, and a due tick before any queued input: a
    // sustained input backlog can neither starve the timeouts (enable, brakes, the
    // e-stop's S-OFF) nor the other tasks, and every iteration checks in.
    loop {
        channels.liveness.check_in(CriticalTask::Controller);
        let input = if Instant::now() >= next_tick {
            None
        } else {
            match select(channels.inputs.receive(), Timer::at(next_tick)).await {
                Either::First(input) => Some(input),
                Either::Second(()) => None,
            }
        };
        let input = input.unwrap_or_else(|| {
            next_tick = (next_tick + TICK).max(Instant::now());
            Input::Tick
        });
        controller.set_persist_pending(channels.pending_writes.persist_pending());
        controller.set_drive_brakes_confirmed(channels.drive_brakes.confirmed());
        // The drops so far, for `can_tx_dropped`: a read of it answers the count
        // up to the input before it.
        controller.set_can_tx_dropped(channels.can_tx.dropped());
        let now = core_now();
        // A change of the update task's lock is an input of its own, handled first, so
        // that no input after the change meets the old lock.
        let locked = channels.update.locked();
        if locked != update_lock {
            update_lock = locked;
            let out = controller.handle(now, Input::UpdateLock(locked));
            dispatch(&controller, out, &channels, &mut state, &mut pc_switch);
        }
        let out = controller.handle(now, input);
        channels.update.set_gate(controller.update_gate(now));
        dispatch(&controller, out, &channels, &mut state, &mut pc_switch);
        // The other tasks run between two inputs even when the queue never empties.
        yield_now().await;
    }
}

/// What the controller last asked of the drive link and of the remote task, and the
/// light it last published.
struct Dispatched {
    demand: DriveDemand,
    remote: RemoteRequest,
    light: Option<BaseLight>,
}

fn dispatch<S: OutputPin>(
    controller: &Controller,
    out: Output,
    channels: &ControlEnds<'_>,
    state: &mut Dispatched,
    pc_switch: &mut S,
) {
    let demand = &mut state.demand;
    for frame in out.frames {
        channels.can_tx.send(frame);
    }
    if !out.bulk_replies.is_empty() {
        channels.can_tx.send_batch(&out.bulk_replies);
    }
    let mut next = *demand;
    if let Some(wheels) = out.wheels {
        next.wheels = wheels;
    }
    if let Some(excite) = out.excite {
        next.excite = excite;
    }
    if out.setup_drives {
        next.setup_requests = next.setup_requests.wrapping_add(1);
        // The setup leaves the drives de-excited; only a new request excites them.
        next.excite = false;
    }
    next.cycle_ms = controller.registers().get(Reg::LoopEndDelay);
    next.stop_decel = u32::from(controller.registers().get(Reg::EstopDecel));
    next.feedback_due_at = Some(controller.position_due_at());
    // A new command always goes out, even one equal to the last (the e-stop edge).
    if next != *demand || out.wheels.is_some() {
        *demand = next;
        channels.drive_demand.signal(next);
    }
    if let Some(level) = out.pc_switch {
        // A GPIO write cannot fail on our boards; the error type is kept generic.
        let _ = match level {
            SwitchLevel::Closed => pc_switch.set_high(),
            SwitchLevel::Open => pc_switch.set_low(),
        };
    }
    // Flash waits for the brakes, confirmed by both drives: an erase must never stall
    // the loop while a wheel may turn.
    channels
        .pending_writes
        .set_at_rest(controller.brakes_applied());
    channels.pending_writes.record(&out.persist);

    let mut remote = state.remote;
    if let Some(open) = out.pairing_window {
        remote.pairing_open = open;
    }
    if let Some(pad) = out.disconnect_remote {
        remote.disconnect(pad);
    }
    if out.bluetooth_on {
        remote.turn_ons = remote.turn_ons.wrapping_add(1);
    }
    if remote != state.remote {
        state.remote = remote;
        channels.remote_requests.signal(remote);
    }
    let light = BaseLight::from_supervisor(controller.supervisor());
    if state.light != Some(light) {
        state.light = Some(light);
        channels.base_light.signal(light);
    }
}
