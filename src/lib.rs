//! The hardware-free core of the base controller: everything that decides, as pure
//! `no_std` code with time passed in. The chip shell only moves bytes between the
//! peripherals and this crate.
#![cfg_attr(not(test), no_std)]

pub mod battery;
pub mod calibration;
pub mod can;
pub mod controller;
pub mod debounce;
pub mod feedback;
pub mod kinematics;
pub mod odometry;
pub mod power;
pub mod registers;
pub mod scale;
pub mod supervisor;
pub mod time;
