//! The simulator binary as a child process, for the end-to-end tests: the tests of
//! this package (`sim/tests/`) and of the ROS 2 node (`ros2/tests/`) start the real
//! `virtual-base-controller` with [`SimulatorProcess`], talk to it over its socketcand
//! server, its SLCAN port or its console, and read what it prints.
//!
//! Each simulator gets a scratch directory of its own in the system's temporary
//! directory for its flash file (`flash.bin`) and its serial port link (`slcan`);
//! the directory is removed when the [`SimulatorProcess`] is dropped, also when the
//! test panics. Dropping it also ends the simulator: `quit` on its console, and if it
//! has not ended within [`QUIT_TIMEOUT`], it is killed, so that a broken test never
//! hangs or leaves a simulator running.
//!
//! ```no_run
//! use std::time::Duration;
//! use virtual_robot::process::SimulatorProcess;
//!
//! // In this package's tests: env!("CARGO_BIN_EXE_virtual-base-controller").
//! let mut simulator = SimulatorProcess::start("target/debug/virtual-base-controller")?;
//! println!("socketcand on {}", simulator.socketcand());
//! simulator.console("estop on")?;
//! simulator.console("status")?;
//! let line = simulator.wait_for_line("mode", Duration::from_secs(2));
//! let status = simulator.quit()?;
//! assert!(status.success());
//! # Ok::<(), std::io::Error>(())
//! ```

use std::collections::VecDeque;
use std::ffi::OsString;
use std::io::{self, BufRead, BufReader, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use tempfile::TempDir;

use crate::simulator::STARTED;

/// How long the simulator may take to start: from the spawn to its last start-up line.
pub const START_TIMEOUT: Duration = Duration::from_secs(10);

/// How long the simulator may take to end after `quit` before it is killed.
pub const QUIT_TIMEOUT: Duration = Duration::from_secs(10);

/// How many of the simulator's last stderr lines are kept for error messages.
const STDERR_LINES_KEPT: usize = 40;

/// How a simulator is to be started: see [`SimulatorProcess::launch`].
#[derive(Debug, Clone)]
pub struct Launch {
    binary: PathBuf,
    link: bool,
    socketcand: bool,
    directory: Option<PathBuf>,
    args: Vec<OsString>,
}

impl Launch {
    /// No serial port link (`--no-link`); the pseudo-terminal is still opened.
    pub fn no_link(mut self) -> Self {
        self.link = false;
        self
    }

    /// No socketcand server (`--no-socketcand`).
    pub fn no_socketcand(mut self) -> Self {
        self.socketcand = false;
        self
    }

    /// The flash file and the link in `directory` (created if missing), which the
    /// caller keeps: it is not removed on drop. For a simulator that is to find what
    /// an earlier one stored.
    pub fn in_directory(mut self, directory: impl Into<PathBuf>) -> Self {
        self.directory = Some(directory.into());
        self
    }

    /// One more argument, after the launcher's own (so it can override them).
    pub fn arg(mut self, arg: impl Into<OsString>) -> Self {
        self.args.push(arg.into());
        self
    }

    /// More arguments, after the launcher's own.
    pub fn args<I>(mut self, args: I) -> Self
    where
        I: IntoIterator,
        I::Item: Into<OsString>,
    {
        self.args.extend(args.into_iter().map(Into::into));
        self
    }

    /// Starts the simulator and waits until it has set everything up (at most
    /// [`START_TIMEOUT`]). Fails if it cannot be spawned, exits during its start (the
    /// error has its stderr, e.g. a refused option), says nothing in time, or does not
    /// name the socketcand address or create the link it was asked for.
    pub fn start(self) -> io::Result<SimulatorProcess> {
        let directory = match &self.directory {
            Some(path) => {
                std::fs::create_dir_all(path)?;
                Directory::Kept(path.clone())
            }
            None => Directory::Scratch(
                tempfile::Builder::new()
                    .prefix("virtual-base-controller-")
                    .tempdir()?,
            ),
        };
        let link = self.link.then(|| directory.path().join("slcan"));
        let mut command = Command::new(&self.binary);
        command
            .arg("--flash")
            .arg(directory.path().join("flash.bin"));
        match &link {
            Some(link) => command.arg("--link").arg(link),
            None => command.arg("--no-link"),
        };
        if self.socketcand {
            // A free port: tests run side by side.
            command.args(["--socketcand", "127.0.0.1:0"]);
        } else {
            command.arg("--no-socketcand");
        }
        let mut child = command
            .args(&self.args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|error| {
                io::Error::new(
                    error.kind(),
                    format!("{} does not start: {error}", self.binary.display()),
                )
            })?;
        let console = child.stdin.take().expect("stdin is piped");
        let lines = forward_lines(child.stdout.take().expect("stdout is piped"));
        let (stderr, stderr_reader) =
            keep_last_lines(child.stderr.take().expect("stderr is piped"));
        let mut simulator = SimulatorProcess {
            child,
            console,
            lines,
            stderr,
            stderr_reader,
            startup: Vec::new(),
            socketcand: None,
            link,
            directory,
        };
        match simulator.await_start(self.socketcand) {
            Ok(()) => Ok(simulator),
            Err(error) => {
                simulator.kill();
                // All it said before it ended (its reader ends with the pipe).
                let deadline = Instant::now() + Duration::from_secs(1);
                while !simulator.stderr_reader.is_finished() && Instant::now() < deadline {
                    thread::sleep(Duration::from_millis(10));
                }
                Err(io::Error::new(
                    error.kind(),
                    format!(
                        "the simulator did not start: {error}\nits stdout:\n{}\nits stderr:\n{}",
                        simulator.startup.join("\n"),
                        simulator.stderr_tail()
                    ),
                ))
            }
        }
    }
}

/// A running simulator binary: see the [module](self) documentation.
#[derive(Debug)]
pub struct SimulatorProcess {
    child: Child,
    console: ChildStdin,
    /// The stdout lines after the start-up ones, as they come.
    lines: Receiver<String>,
    stderr: Arc<Mutex<VecDeque<String>>>,
    stderr_reader: JoinHandle<()>,
    startup: Vec<String>,
    socketcand: Option<SocketAddr>,
    link: Option<PathBuf>,
    // Removed as the fields drop, after `drop` has ended the simulator.
    directory: Directory,
}

impl SimulatorProcess {
    /// How to start the simulator `binary`: by default with `--flash DIR/flash.bin`,
    /// `--link DIR/slcan` and `--socketcand 127.0.0.1:0` (a free port) in a fresh
    /// scratch directory DIR, each of which [`Launch`] can change.
    pub fn launch(binary: impl Into<PathBuf>) -> Launch {
        Launch {
            binary: binary.into(),
            link: true,
            socketcand: true,
            directory: None,
            args: Vec::new(),
        }
    }

    /// Starts the simulator `binary` with the defaults of [`launch`](Self::launch).
    pub fn start(binary: impl Into<PathBuf>) -> io::Result<Self> {
        Self::launch(binary).start()
    }

    /// Reads the start-up lines until [`STARTED`], noting the socketcand address.
    fn await_start(&mut self, socketcand: bool) -> io::Result<()> {
        let deadline = Instant::now() + START_TIMEOUT;
        loop {
            let line = match self
                .lines
                .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            {
                Ok(line) => line,
                Err(RecvTimeoutError::Timeout) => {
                    return Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        format!("not started within {START_TIMEOUT:?}"),
                    ));
                }
                Err(RecvTimeoutError::Disconnected) => {
                    let status = wait_until(&mut self.child, Duration::from_secs(1))?;
                    return Err(io::Error::other(match status {
                        Some(status) => format!("it ended ({status})"),
                        None => "it closed its stdout".to_owned(),
                    }));
                }
            };
            if let Some(address) = line.strip_prefix("socketcand:") {
                // "socketcand:        127.0.0.1:40123, bus can0"
                let address = address.trim().split(',').next().unwrap_or_default();
                self.socketcand = Some(address.parse().map_err(|_| {
                    io::Error::new(
                        io::ErrorKind::InvalidData,
                        format!("no socketcand address in {line:?}"),
                    )
                })?);
            }
            let started = line == STARTED;
            self.startup.push(line);
            if started {
                break;
            }
        }
        if socketcand && self.socketcand.is_none() {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "it did not name its socketcand address",
            ));
        }
        if let Some(link) = &self.link {
            std::fs::read_link(link).map_err(|error| {
                io::Error::new(
                    error.kind(),
                    format!("no serial port link at {}: {error}", link.display()),
                )
            })?;
        }
        Ok(())
    }

    /// Where the socketcand server listens (`127.0.0.1:PORT`); its `to_string()` is
    /// the channel basectl and python-can take.
    ///
    /// # Panics
    /// If the simulator was started with [`Launch::no_socketcand`].
    pub fn socketcand(&self) -> SocketAddr {
        self.socketcand
            .expect("the simulator was started without a socketcand server")
    }

    /// The symbolic link to the simulator's SLCAN serial port.
    ///
    /// # Panics
    /// If the simulator was started with [`Launch::no_link`].
    pub fn link(&self) -> &Path {
        self.link
            .as_deref()
            .expect("the simulator was started without a link")
    }

    /// The directory of the flash file and the link.
    pub fn directory(&self) -> &Path {
        self.directory.path()
    }

    /// The simulator's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// What the simulator printed while starting, up to [`STARTED`].
    pub fn startup_lines(&self) -> &[String] {
        &self.startup
    }

    /// Types `line` on the simulator's console (`help` there lists the commands).
    pub fn console(&mut self, line: &str) -> io::Result<()> {
        writeln!(self.console, "{line}")?;
        self.console.flush()
    }

    /// Waits for the next stdout line that contains `text`, skipping the others;
    /// `None` after `timeout` or if the simulator ended first.
    pub fn wait_for_line(&self, text: &str, timeout: Duration) -> Option<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let line = self
                .lines
                .recv_timeout(deadline.saturating_duration_since(Instant::now()))
                .ok()?;
            if line.contains(text) {
                return Some(line);
            }
        }
    }

    /// The last lines the simulator wrote to stderr (its status lines, and its
    /// errors), for failure messages.
    pub fn stderr_tail(&self) -> String {
        let lines = self
            .stderr
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        lines
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// Ends the simulator with `quit` on its console; its exit status. If it has not
    /// ended within [`QUIT_TIMEOUT`], it is killed and this is an error.
    pub fn quit(mut self) -> io::Result<ExitStatus> {
        if let Some(status) = self.child.try_wait()? {
            return Ok(status);
        }
        // A simulator that already closed its console still gets its time to end.
        let _ = self.console("quit");
        self.wait_for_exit(QUIT_TIMEOUT)
    }

    /// Waits for the simulator to end by itself or by what the test did to it (a
    /// signal, a console command); its exit status. If it has not ended within
    /// `timeout`, it is killed and this is an error.
    pub fn wait_for_exit(&mut self, timeout: Duration) -> io::Result<ExitStatus> {
        match wait_until(&mut self.child, timeout)? {
            Some(status) => Ok(status),
            None => {
                self.kill();
                Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "the simulator did not end within {timeout:?} and was killed; its \
                         last stderr lines:\n{}",
                        self.stderr_tail()
                    ),
                ))
            }
        }
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for SimulatorProcess {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(Some(_))) {
            return;
        }
        let _ = self.console("quit");
        if !matches!(wait_until(&mut self.child, QUIT_TIMEOUT), Ok(Some(_))) {
            self.kill();
        }
    }
}

/// The scratch directory, or one the caller keeps.
#[derive(Debug)]
enum Directory {
    Scratch(TempDir),
    Kept(PathBuf),
}

impl Directory {
    fn path(&self) -> &Path {
        match self {
            Directory::Scratch(directory) => directory.path(),
            Directory::Kept(path) => path,
        }
    }
}

/// The child's exit status, or `None` if it is still running after `timeout`.
fn wait_until(child: &mut Child, timeout: Duration) -> io::Result<Option<ExitStatus>> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(status) = child.try_wait()? {
            return Ok(Some(status));
        }
        if Instant::now() >= deadline {
            return Ok(None);
        }
        thread::sleep(Duration::from_millis(10));
    }
}

/// Reads `output` line by line on a thread of its own, so that the simulator never
/// blocks on a full pipe, and hands the lines over. The thread ends with the pipe.
fn forward_lines(output: impl io::Read + Send + 'static) -> Receiver<String> {
    let (sender, receiver) = mpsc::channel();
    thread::spawn(move || {
        // Once nobody listens, the lines are still read, so the simulator can write.
        for_each_line(output, |line| {
            let _ = sender.send(line);
        });
    });
    receiver
}

/// Reads `output` on a thread of its own and keeps its last [`STDERR_LINES_KEPT`]
/// lines.
fn keep_last_lines(
    output: impl io::Read + Send + 'static,
) -> (Arc<Mutex<VecDeque<String>>>, JoinHandle<()>) {
    let kept = Arc::new(Mutex::new(VecDeque::new()));
    let sink = Arc::clone(&kept);
    let reader = thread::spawn(move || {
        for_each_line(output, |line| {
            let mut lines = sink.lock().unwrap_or_else(|poison| poison.into_inner());
            if lines.len() == STDERR_LINES_KEPT {
                lines.pop_front();
            }
            lines.push_back(line);
        });
    });
    (kept, reader)
}

/// Calls `each` with every line of `output` (without its line end; bytes that are not
/// UTF-8 replaced) until the pipe closes.
fn for_each_line(output: impl io::Read, mut each: impl FnMut(String)) {
    let mut output = BufReader::new(output);
    let mut line = Vec::new();
    while matches!(output.read_until(b'\n', &mut line), Ok(1..)) {
        let text = String::from_utf8_lossy(&line);
        each(text.trim_end_matches(['\n', '\r']).to_owned());
        line.clear();
    }
}
