//! The base controller's core: everything that decides, as pure `no_std` code with no
//! async, no hardware and no clock. Time is an argument (`now`), hardware is values in
//! and out. The runtime crate (`base-runtime`) runs it on a chip or on the virtual
//! robot; the PC tools use its CAN codec and register table.
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
pub mod power;
pub mod registers;
pub mod remote;
pub mod scale;
pub mod supervisor;
pub mod time;
