//! The simulator's serial port: a pseudo-terminal whose far end (`/dev/pts/N`) the PC
//! software opens as if it were a USB-CAN adapter. Two plain threads do the blocking
//! I/O: one cuts what the PC writes into SLCAN lines and hands them to the executor,
//! the other writes the adapter's output back.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::thread;

use nix::pty::openpty;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

use crate::runtime::{QueueReceiver, cross_thread_queue};
use ::slcan::LineAssembler;

/// Chunks of output that may wait for the PC to read them. When the PC reads nothing
/// (no program attached) the terminal's buffer and then this queue fill up, and
/// further output is dropped, as a USB adapter's buffer overflows.
const OUTPUT_QUEUE: usize = 256;

/// A pseudo-terminal serving as the adapter's serial port.
pub struct SerialPort {
    path: PathBuf,
    /// The far end, kept open so that the near end stays usable while no program has
    /// the port open (the near end reads an error once every far end is closed).
    _far_end: OwnedFd,
    lines: QueueReceiver<Vec<u8>>,
    output: SyncSender<Vec<u8>>,
}

impl SerialPort {
    /// Opens a pseudo-terminal in raw mode (no echo, no line editing, CR kept as CR)
    /// and starts its reader and writer threads.
    pub fn open() -> io::Result<Self> {
        let pty = openpty(None, None)?;
        let mut termios = tcgetattr(&pty.slave)?;
        cfmakeraw(&mut termios);
        tcsetattr(&pty.slave, SetArg::TCSANOW, &termios)?;
        let path = nix::unistd::ttyname(&pty.slave)?;
        let near_end = File::from(pty.master);
        let reader = near_end.try_clone()?;
        let (line_sender, lines) = cross_thread_queue();
        thread::Builder::new()
            .name("slcan-reader".into())
            .spawn(move || {
                let mut reader = reader;
                let mut assembler = LineAssembler::default();
                let mut buffer = [0; 256];
                // Ends on an error, which the bridge learns when the queue ends.
                while let Ok(count @ 1..) = reader.read(&mut buffer) {
                    for line in assembler.push(&buffer[..count]) {
                        line_sender.send(line);
                    }
                }
            })?;
        let (output, output_queue) = sync_channel(OUTPUT_QUEUE);
        thread::Builder::new()
            .name("slcan-writer".into())
            .spawn(move || write_all_output(near_end, output_queue))?;
        Ok(Self {
            path,
            _far_end: pty.slave,
            lines,
            output,
        })
    }

    /// The far end's path, e.g. `/dev/pts/3`: what the PC software opens.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The PC's command lines, without their CR; `None` once the port failed.
    pub fn lines(&self) -> &QueueReceiver<Vec<u8>> {
        &self.lines
    }

    /// Queues bytes for the PC. False if they were dropped because the PC has not
    /// been reading.
    pub fn send(&self, bytes: &[u8]) -> bool {
        match self.output.try_send(bytes.to_vec()) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => false,
        }
    }
}

fn write_all_output(mut near_end: File, output_queue: Receiver<Vec<u8>>) {
    for bytes in output_queue {
        if near_end.write_all(&bytes).is_err() {
            return;
        }
    }
}

/// A symbolic link at a fixed path to the port, so that scripts need not learn the
/// `/dev/pts/N` number. Removed when dropped, if it still points to this port.
pub struct StableLink {
    link: PathBuf,
    target: PathBuf,
}

impl StableLink {
    /// Points `link` at `target`, replacing an earlier link there (one a simulator
    /// killed with Ctrl-C left behind). Anything at `link` that is not a symbolic link
    /// is not touched: that is an error.
    pub fn create(link: &Path, target: &Path) -> io::Result<Self> {
        match std::fs::symlink_metadata(link) {
            Ok(metadata) if metadata.file_type().is_symlink() => std::fs::remove_file(link)?,
            Ok(_) => {
                return Err(io::Error::new(
                    io::ErrorKind::AlreadyExists,
                    format!("{} exists and is not a symbolic link", link.display()),
                ));
            }
            Err(error) if error.kind() == io::ErrorKind::NotFound => {}
            Err(error) => return Err(error),
        }
        std::os::unix::fs::symlink(target, link)?;
        Ok(Self {
            link: link.to_owned(),
            target: target.to_owned(),
        })
    }

    pub fn path(&self) -> &Path {
        &self.link
    }
}

impl Drop for StableLink {
    fn drop(&mut self) {
        // Another simulator may have taken the link over since.
        if std::fs::read_link(&self.link).is_ok_and(|target| target == self.target) {
            let _ = std::fs::remove_file(&self.link);
        }
    }
}
