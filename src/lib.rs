//! The base controller: a hardware-free core that decides (pure `no_std` code with
//! time passed in), and the async tasks that run it, written against the hardware
//! traits of [`hw`]. The chip shell implements those traits with esp-hal; the virtual
//! robot in `sim/` implements them in memory for the whole-system tests.
#![cfg_attr(not(test), no_std)]

// First, so that every module below can log.
#[macro_use]
mod fmt;

pub mod app;
pub mod battery;
pub mod calibration;
pub mod can;
pub mod controller;
pub mod debounce;
pub mod drives;
pub mod feedback;
pub mod gamepad;
pub mod hid;
pub mod hw;
pub mod hx711;
pub mod kinematics;
pub mod modbus;
pub mod odometry;
pub mod power;
pub mod registers;
pub mod remote;
pub mod scale;
pub mod store;
pub mod supervisor;
pub mod time;
