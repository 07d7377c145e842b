//! The Modbus-RTU master: one request out, one reply in, with the line's timing. It
//! knows bytes and time, not registers; [`base_core::modbus`] builds and checks frames.

use embassy_time::{Duration, Instant, Timer, with_timeout};

use crate::hw::Rs485;
use base_core::modbus::{Frame, MAX_FRAME, TransferError};

use base_core::drives::settings::LineSettings;

/// Extra silence after a failed transaction, so that a slave still answering late
/// has finished before the next query (Oriental's own master waits 5 ms).
const AFTER_FAILURE_US: u64 = 5_000;
/// Extra silence after a broadcast, which nobody answers: the drives' manual asks
/// for C3.5 + 5 ms before the next query, the time every drive needs to act on it.
const AFTER_BROADCAST_US: u64 = 5_000;

pub struct Master<P> {
    port: P,
    char_time: Duration,
    silent_interval: Duration,
    reply_timeout: Duration,
    /// The line is free for the next request from this moment.
    quiet_from: Instant,
}

impl<P: Rs485> Master<P> {
    pub fn new(port: P, line: &LineSettings, reply_timeout_ms: u32) -> Self {
        Self {
            port,
            char_time: Duration::from_micros(line.char_time_us()),
            silent_interval: Duration::from_micros(line.silent_interval_us()),
            reply_timeout: Duration::from_millis(u64::from(reply_timeout_ms)),
            quiet_from: Instant::from_ticks(0),
        }
    }

    /// Sends `request` and collects the reply into `reply`. An `expected_len` of 0 is a
    /// broadcast: nothing is awaited, and the line stays quiet a little longer.
    ///
    /// The reply ends when `expected_len` bytes arrived (and then up to two more, the
    /// optional trailer of an ID-share reply), when it is a complete exception reply,
    /// or when the line stayed quiet for the reply timeout. A short reply is returned
    /// as it is: the parser tells what is missing, and for an ID-share reply which
    /// members answered.
    pub async fn transact(
        &mut self,
        request: &[u8],
        expected_len: usize,
        reply: &mut Frame,
    ) -> Result<(), TransferError> {
        reply.clear();
        Timer::at(self.quiet_from).await;
        self.drain_stale_input().await;
        self.write(request).await?;
        if expected_len == 0 {
            self.quiet_from =
                Instant::now() + self.silent_interval + Duration::from_micros(AFTER_BROADCAST_US);
            return Ok(());
        }
        let received = self.receive(expected_len.min(MAX_FRAME), reply).await;
        let pause = match received {
            Ok(()) => self.silent_interval,
            Err(_) => self.silent_interval + Duration::from_micros(AFTER_FAILURE_US),
        };
        self.quiet_from = Instant::now() + pause;
        received
    }

    async fn write(&mut self, request: &[u8]) -> Result<(), TransferError> {
        self.port
            .write_all(request)
            .await
            .map_err(|_| TransferError::Port)?;
        self.port.flush().await.map_err(|_| TransferError::Port)
    }

    async fn receive(
        &mut self,
        expected_len: usize,
        reply: &mut Frame,
    ) -> Result<(), TransferError> {
        let mut chunk = [0u8; 64];
        loop {
            let complete = reply.len() >= expected_len || is_exception(reply);
            // After the expected bytes, only the trailer may follow, right away.
            let wait = if complete {
                self.char_time * 2 + self.silent_interval
            } else {
                self.reply_timeout
            };
            let room = (MAX_FRAME - reply.len()).min(chunk.len());
            if room == 0 {
                return Ok(());
            }
            match with_timeout(wait, self.port.read(&mut chunk[..room])).await {
                Ok(Ok(0)) | Err(_) => break,
                Ok(Ok(n)) => {
                    // `room` bounds n, so this never overflows.
                    let _ = reply.extend_from_slice(&chunk[..n]);
                    if complete && reply.len() >= expected_len + 2 {
                        break;
                    }
                }
                Ok(Err(_)) => return Err(TransferError::Port),
            }
        }
        if reply.is_empty() {
            Err(TransferError::NoReply)
        } else {
            Ok(())
        }
    }

    /// Drops bytes left from an earlier, late reply so they are not read as this one's.
    async fn drain_stale_input(&mut self) {
        let mut chunk = [0u8; 64];
        while let Ok(Ok(n)) =
            with_timeout(Duration::from_ticks(0), self.port.read(&mut chunk)).await
        {
            if n == 0 {
                break;
            }
        }
    }
}

/// A complete exception reply: address, function | 0x80, code, CRC.
fn is_exception(reply: &[u8]) -> bool {
    reply.len() >= 5 && reply[1] & 0x80 != 0
}
