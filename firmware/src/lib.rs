//! The base controller on the chip: esp-hal implementations of the library's hardware
//! traits ([`base_runtime::hw`]) and the boards that say which pin does what. No
//! decisions are made here; `main.rs` wires these to [`base_runtime::run`].
#![no_std]

pub mod battery;
pub mod board;
pub mod can;
pub mod flash;
pub mod rs485;
pub mod watchdog;
