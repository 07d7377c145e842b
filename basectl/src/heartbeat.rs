//! `pc-heartbeat`: tells the base controller the PC is alive (`006#01` every second),
//! e.g. while the robot PC's own software is stopped.

use std::io::Write;
use std::time::{Duration, Instant};

use base_core::can::Command;

use crate::base::{Base, Error};

/// Twice as often as the protocol's minimum (every 2 s).
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);

pub fn pc_heartbeat(
    base: &mut Base,
    seconds: Option<u64>,
    out: &mut dyn Write,
) -> Result<(), Error> {
    let deadline = seconds.map(|seconds| Instant::now() + Duration::from_secs(seconds));
    let mut sent: u64 = 0;
    while deadline.is_none_or(|deadline| Instant::now() < deadline) {
        base.send(Command::Heartbeat)?;
        sent += 1;
        write!(out, "\rheartbeats sent: {sent}")?;
        out.flush()?;
        // Reading meanwhile keeps the adapter's output from piling up.
        let next = Instant::now() + HEARTBEAT_PERIOD;
        while base
            .next_report(next.saturating_duration_since(Instant::now()))?
            .is_some()
        {}
    }
    writeln!(out)?;
    Ok(())
}
