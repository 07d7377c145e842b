//! The simulator's serial port: a pseudo-terminal whose far end (`/dev/pts/N`) the PC
//! software opens as if it were a USB-CAN adapter. Two plain threads do the blocking
//! I/O: one cuts what the PC writes into SLCAN lines and hands them to the executor,
//! the other writes the adapter's output back.
//!
//! The simulator holds the far end open itself only while no program uses the port.
//! It lets go when a program's first bytes arrive, so it learns when the last program
//! closes the port (the near end then reads EIO), as an adapter learns it is
//! unplugged: the bridge closes the SLCAN channel. Nothing the last program left
//! unread reaches the next one: the simulator takes the far end back and flushes its
//! input, and writes nothing until the next program's first bytes. (A pseudo-terminal
//! keeps what was written to it while no program had it open, and flushing the near
//! end does not discard it. Opening the far end only while no program has it, and
//! closing it only while one does, keeps clear of the terminal's last-close handling,
//! which a concurrent open can race.)

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::AsFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::thread;
use std::time::Duration;

use nix::errno::Errno;
use nix::fcntl::{Flock, FlockArg};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::openpty;
use nix::sys::termios::{FlushArg, SetArg, cfmakeraw, tcflush, tcgetattr, tcsetattr};

use crate::runtime::{QueueReceiver, cross_thread_queue};
use ::slcan::LineAssembler;

/// Chunks of output that may wait for the PC to read them. When the PC reads nothing
/// the terminal's buffer and then this queue fill up, and further output is dropped,
/// as a USB adapter's buffer overflows.
const OUTPUT_QUEUE: usize = 256;

/// How long the writer waits for room before it looks whether the program is still
/// there, and how often the reader looks again if it could not take the far end.
const IDLE_POLL: Duration = Duration::from_millis(20);

/// What happens on the port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PortEvent {
    /// A command line from the PC, without its CR.
    Line(Vec<u8>),
    /// The last program that had the port open closed it (or died).
    Closed,
}

/// Which program output is for. The reader starts a new attachment when a program's
/// first bytes arrive and ends it when the last program has gone; the writer writes a
/// chunk only while the attachment it was queued in lasts. One lock orders the two:
/// no chunk is written after the flush that follows its program's leaving.
#[derive(Default)]
struct Attachment {
    /// Counts the programs that attached since the simulator started.
    number: u64,
    /// Whether a program has the port open.
    present: bool,
}

/// A pseudo-terminal serving as the adapter's serial port.
pub struct SerialPort {
    path: PathBuf,
    events: QueueReceiver<PortEvent>,
    output: SyncSender<(u64, Vec<u8>)>,
    attachment: Arc<Mutex<Attachment>>,
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
        // Held until the first program's first bytes arrive.
        let idle_holder = File::from(pty.slave);
        let near_end = File::from(pty.master);
        let reader = near_end.try_clone()?;
        let attachment = Arc::new(Mutex::new(Attachment::default()));
        let (event_sender, events) = cross_thread_queue();
        let far_end = path.clone();
        let reader_attachment = attachment.clone();
        thread::Builder::new()
            .name("slcan-reader".into())
            .spawn(move || {
                let mut reader = reader;
                let mut assembler = LineAssembler::default();
                let mut buffer = [0; 256];
                let mut idle_holder = Some(idle_holder);
                let mut in_use = false;
                // Ends on an error other than "no program has the far end open", which
                // the bridge learns when the queue ends.
                loop {
                    match reader.read(&mut buffer) {
                        Ok(count @ 1..) => {
                            if !in_use {
                                in_use = true;
                                lock(&reader_attachment).attach();
                                // The program holds the far end: this is not the last close.
                                drop(idle_holder.take());
                            }
                            for line in assembler.push(&buffer[..count]) {
                                event_sender.send(PortEvent::Line(line));
                            }
                        }
                        Err(error) if error.raw_os_error() == Some(Errno::EINTR as i32) => {}
                        Ok(0) => thread::sleep(IDLE_POLL),
                        Err(error) if error.raw_os_error() == Some(Errno::EIO as i32) => {
                            if in_use {
                                in_use = false;
                                assembler = LineAssembler::default();
                                // From here on the writer writes nothing.
                                lock(&reader_attachment).present = false;
                                event_sender.send(PortEvent::Closed);
                            }
                            idle_holder = hold_and_flush(&far_end);
                            if idle_holder.is_none() {
                                thread::sleep(IDLE_POLL);
                            }
                        }
                        Err(_) => return,
                    }
                }
            })?;
        let (output, output_queue) = sync_channel(OUTPUT_QUEUE);
        let writer_attachment = attachment.clone();
        thread::Builder::new()
            .name("slcan-writer".into())
            .spawn(move || write_output(near_end, output_queue, &writer_attachment))?;
        Ok(Self {
            path,
            events,
            output,
            attachment,
        })
    }

    /// The far end's path, e.g. `/dev/pts/3`: what the PC software opens.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The PC's command lines and the port's closing; `None` once the port failed.
    pub fn events(&self) -> &QueueReceiver<PortEvent> {
        &self.events
    }

    /// Queues bytes for the program attached now. False if they were dropped because
    /// it has not been reading.
    pub fn send(&self, bytes: &[u8]) -> bool {
        let number = lock(&self.attachment).number;
        match self.output.try_send((number, bytes.to_vec())) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => false,
        }
    }
}

fn lock(attachment: &Mutex<Attachment>) -> MutexGuard<'_, Attachment> {
    // The two threads only set plain fields under the lock: a panic cannot leave
    // them half-written.
    attachment.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Attachment {
    fn attach(&mut self) {
        self.number += 1;
        self.present = true;
    }
}

/// Opens the far end, which no program has open now, and discards what waits unread
/// in its input: it was meant for the program that left. Only the far end's own flush
/// does that. Held until the next program's first bytes arrive; `None` if it could
/// not be opened (the reader then looks again every [`IDLE_POLL`]).
fn hold_and_flush(far_end: &Path) -> Option<File> {
    let port = File::options()
        .read(true)
        .write(true)
        .custom_flags(nix::libc::O_NOCTTY)
        .open(far_end)
        .ok()?;
    let _ = tcflush(&port, FlushArg::TCIFLUSH);
    Some(port)
}

/// Writes each chunk while the program it was queued for is attached, and drops it
/// otherwise. It waits for room in short steps, so that a program that stopped
/// reading and then left does not hold a chunk until the next one arrives.
fn write_output(
    mut near_end: File,
    output_queue: Receiver<(u64, Vec<u8>)>,
    attachment: &Mutex<Attachment>,
) {
    let step = PollTimeout::from(IDLE_POLL.as_millis() as u16);
    for (number, bytes) in output_queue {
        loop {
            let mut room = [PollFd::new(near_end.as_fd(), PollFlags::POLLOUT)];
            let writable = poll(&mut room, step).is_ok_and(|ready| ready > 0)
                && room[0]
                    .revents()
                    .is_some_and(|events| events.contains(PollFlags::POLLOUT));
            let attachment = lock(attachment);
            if !attachment.present || attachment.number != number {
                break;
            }
            if writable {
                if near_end.write_all(&bytes).is_err() {
                    return;
                }
                break;
            }
        }
    }
}

/// A symbolic link at a fixed path to the port, so that scripts need not learn the
/// `/dev/pts/N` number, and a lock file beside it (`PATH.lock`, holding the pid) that
/// says a live simulator serves it. Both are removed when dropped.
pub struct StableLink {
    link: PathBuf,
    target: PathBuf,
    lock_path: PathBuf,
    _lock: Flock<File>,
}

/// The lock file of `link`: its path with `.lock` appended. basectl looks at it to
/// tell a live simulator's link from one a killed simulator left behind.
pub fn lock_path(link: &Path) -> PathBuf {
    let mut path = link.as_os_str().to_owned();
    path.push(".lock");
    PathBuf::from(path)
}

impl StableLink {
    /// Points `link` at `target`. Refused while another live simulator holds the
    /// link's lock; a link a dead simulator left behind is replaced. Anything at
    /// `link` that is not a symbolic link is not touched: that is an error.
    pub fn create(link: &Path, target: &Path) -> io::Result<Self> {
        let lock_path = lock_path(link);
        let lock_file = File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&lock_path)?;
        let lock = match Flock::lock(lock_file, FlockArg::LockExclusiveNonblock) {
            Ok(lock) => lock,
            Err((mut file, Errno::EWOULDBLOCK)) => {
                let mut pid = String::new();
                let _ = file.read_to_string(&mut pid);
                return Err(io::Error::new(
                    io::ErrorKind::AddrInUse,
                    format!(
                        "{} is served by another simulator (pid {}); stop it, or give this \
                         one another --link",
                        link.display(),
                        pid.trim()
                    ),
                ));
            }
            Err((_, errno)) => return Err(errno.into()),
        };
        lock.set_len(0)?;
        let mut file: &File = &lock;
        writeln!(file, "{}", std::process::id())?;
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
            lock_path,
            _lock: lock,
        })
    }

    pub fn path(&self) -> &Path {
        &self.link
    }
}

impl Drop for StableLink {
    fn drop(&mut self) {
        if std::fs::read_link(&self.link).is_ok_and(|target| target == self.target) {
            let _ = std::fs::remove_file(&self.link);
        }
        let _ = std::fs::remove_file(&self.lock_path);
    }
}
