//! The virtual robot: the base controller's hardware in memory, for whole-system tests
//! on the host (and the simulator). Every part implements a trait of
//! `base_runtime::hw`, so the firmware's own task code runs against it unchanged.
//!
//! Time is virtual: [`runtime::block_on`] runs the tasks and jumps the clock to the next
//! timer whenever every task waits, so a test of minutes of driving runs in
//! milliseconds and always the same way.

pub mod air;
pub mod app_flash;
pub mod ble;
pub mod can;
pub mod drives;
pub mod fake_hci;
pub mod file_flash;
pub mod flash;
pub mod io;
pub mod latency;
pub mod process;
pub mod robot;
pub mod runtime;
pub mod simulator;
pub mod slcan;
