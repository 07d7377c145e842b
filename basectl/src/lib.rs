//! basectl, the base controller's commissioning CLI: the bus ([`bus`]), the controller
//! behind it ([`base`]) and one module per command. `main.rs` only parses the
//! command line; the end-to-end tests (`sim/tests/basectl.rs`) call these functions
//! against the simulator.

pub mod base;
pub mod bus;
pub mod calibrate;
pub mod cli;
pub mod commission;
pub mod config;
pub mod drive;
pub mod firmware;
pub mod heartbeat;
pub mod info;
pub mod log;
pub mod monitor;
pub mod registers;
pub mod rejection;
pub mod rules;
pub mod signing;
