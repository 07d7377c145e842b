//! The base controller's core: everything that decides, as pure `no_std` code with no
//! async, no hardware and no clock. Time is an argument (`now`), hardware is values in
//! and out. The runtime crate (`base-runtime`) runs it on a chip or on the virtual
//! robot; the PC tools use its CAN codec and register table.
//!
//! # One shape for every state machine
//!
//! The supervisor, the front button and PC power ([`power`]), the gamepad mapping
//! ([`remote`]), the drive link ([`drives::link`], whose `Params` are the drives'
//! settings) and the calibrations are written the same way:
//!
//! - The state is an `enum` whose variants carry the data that only they need (a
//!   timer that runs only while excited lives in `Active`, not beside the enum); what
//!   the inputs last reported is kept apart from it, as observations.
//! - One method moves it: `machine.step(now, event, &params) -> Effects`, in that
//!   argument order. Inside, `match (state, event)` (or `match state`) is exhaustive,
//!   so a new state or event does not compile until every case is decided.
//! - The vocabulary is the module's own: `supervisor::Event`, `power::Effects`,
//!   `remote::Params`. `Event` is what happened, `Effects` what must happen now
//!   (`None` or `false` fields mean "nothing"), `Params` the register values it reads,
//!   passed on every step, so a register write applies from the next event on.
//! - A transition diagram in ASCII heads each machine's documentation, and its tests
//!   are tables of (time, event) → effects.
//! - The calibrations take no time: `step(command)` answers `Ok` with what to store or
//!   `Err` with the stable rejection code.
//!
//! [`controller::Controller`] composes them: `handle(now, Input) -> Output` is the one
//! seam to the runtime, whose tasks turn hardware into `Input`s and `Output`s into
//! hardware.
#![cfg_attr(not(test), no_std)]

// First, so that every module below can log.
#[macro_use]
mod fmt;

pub mod battery;
pub mod calibration;
pub mod can;
pub mod controller;
pub mod debounce;
pub mod drives;
pub mod feedback;
pub mod gamepad;
pub mod hid;
pub mod kinematics;
pub mod modbus;
pub mod odometry;
pub mod panic_loop;
pub mod plausibility;
pub mod power;
pub mod registers;
pub mod remote;
pub mod scale;
pub mod supervisor;
pub mod time;
pub mod update;
