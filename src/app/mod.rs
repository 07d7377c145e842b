//! The running controller: async tasks that own the hardware (through [`crate::hw`])
//! and move values between it and the [`crate::controller::Controller`].

pub mod channels;
