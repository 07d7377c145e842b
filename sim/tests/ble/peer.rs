//! The Bumble gamepad peer (sim/ble-peer/bumble_gamepad.py) as a child process: its
//! commands, and the events it prints, with the wall-clock time they arrived.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use embassy_time::Timer;
use virtual_robot::ble::{self, HciSpec, HostController};

/// One line the peer printed.
#[derive(Debug, Clone)]
pub struct Line {
    pub at: Instant,
    pub words: Vec<String>,
}

#[derive(Default)]
struct Lines {
    events: Vec<Line>,
    replies: Vec<Line>,
}

pub struct Peer {
    child: Child,
    stdin: ChildStdin,
    lines: Arc<Mutex<Lines>>,
    replies_seen: usize,
    pub hci: HciSpec,
}

/// Whether the tests may run: Bumble must be importable. In CI it must be.
pub fn bumble_available() -> bool {
    let importable = Command::new("python3")
        .args(["-c", "import bumble.controller, bumble.device"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|status| status.success());
    if !importable {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true but Bumble cannot be imported: `python3 -m pip install bumble==0.0.236`"
        );
        // Straight to the process's stderr: the test harness would hide an eprintln!
        // of a passing test.
        static ONCE: std::sync::Once = std::sync::Once::new();
        ONCE.call_once(|| {
            let _ = std::io::stderr().write_all(
                b"SKIPPED: the BLE scenarios need Google's Bumble (python3 -m pip install bumble==0.0.236)\n",
            );
        });
    }
    importable
}

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("ble-peer/bumble_gamepad.py")
}

impl Peer {
    pub fn start() -> Peer {
        let mut command = Command::new("python3");
        command.arg(script());
        // BLE_PEER_LOG=DEBUG shows Bumble's own log (every HCI packet) on stderr.
        if let Some(level) = std::env::var_os("BLE_PEER_LOG") {
            command.arg("--log").arg(level);
        }
        let mut child = command
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("python3 starts the Bumble peer");
        let stdin = child.stdin.take().expect("piped stdin");
        let stdout = BufReader::new(child.stdout.take().expect("piped stdout"));
        let lines = Arc::new(Mutex::new(Lines::default()));
        let (hci_sender, hci_receiver) = std::sync::mpsc::channel();
        let sink = lines.clone();
        std::thread::spawn(move || {
            for line in stdout.lines() {
                let Ok(line) = line else { return };
                let mut words: Vec<String> = line.split_whitespace().map(String::from).collect();
                if std::env::var_os("BLE_PEER_TRACE").is_some() {
                    eprintln!("peer: {line}");
                }
                let at = Instant::now();
                let mut lines = sink.lock().unwrap_or_else(PoisonError::into_inner);
                match words.first().map(String::as_str) {
                    Some("event") => {
                        words.remove(0);
                        lines.events.push(Line { at, words });
                    }
                    Some("hci") => {
                        let _ = hci_sender.send(words.get(1).cloned().unwrap_or_default());
                    }
                    Some(_) => lines.replies.push(Line { at, words }),
                    None => {}
                }
            }
        });
        let hci = hci_receiver
            .recv_timeout(Duration::from_secs(20))
            .expect("the peer says where its HCI transport listens");
        Peer {
            child,
            stdin,
            lines,
            replies_seen: 0,
            hci: HciSpec::parse(&hci).expect("the peer's HCI address"),
        }
    }

    /// A fresh controller for a booting robot (every TCP client gets its own).
    pub fn controller(&self) -> HostController {
        ble::open(&self.hci).expect("the peer's HCI transport accepts")
    }

    /// Sends a command and waits for its answer; an `error` answer fails the test.
    pub async fn cmd(&mut self, command: &str) -> String {
        writeln!(self.stdin, "{command}").expect("the peer reads commands");
        self.stdin.flush().expect("the peer reads commands");
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            let reply = {
                let lines = self.lines.lock().unwrap_or_else(PoisonError::into_inner);
                lines.replies.get(self.replies_seen).cloned()
            };
            if let Some(reply) = reply {
                self.replies_seen += 1;
                assert_eq!(
                    reply.words[0], "ok",
                    "peer refused `{command}`: {:?}",
                    reply.words
                );
                return reply.words[2..].join(" ");
            }
            assert!(
                Instant::now() < deadline,
                "the peer did not answer `{command}`"
            );
            Timer::after_millis(2).await;
        }
    }

    /// Every event so far.
    pub fn events(&self) -> Vec<Line> {
        self.lines
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .events
            .clone()
    }

    /// How many events so far (a mark to wait for later ones).
    pub fn mark(&self) -> usize {
        self.lines
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .events
            .len()
    }

    /// The events after `mark` that start with `words`.
    pub fn events_since(&self, mark: usize, words: &[&str]) -> Vec<Line> {
        self.events()
            .into_iter()
            .skip(mark)
            .filter(|line| starts_with(line, words))
            .collect()
    }

    /// Waits (up to `timeout_ms`) for an event after `mark` that starts with `words`.
    pub async fn wait_for(&self, mark: usize, words: &[&str], timeout_ms: u64) -> Line {
        let deadline = Instant::now() + Duration::from_millis(timeout_ms);
        loop {
            if let Some(line) = self.events_since(mark, words).into_iter().next() {
                return line;
            }
            assert!(
                Instant::now() < deadline,
                "no event {words:?} within {timeout_ms} ms; events since: {:#?}",
                self.events()
                    .into_iter()
                    .skip(mark)
                    .map(|l| l.words.join(" "))
                    .collect::<Vec<_>>()
            );
            Timer::after_millis(5).await;
        }
    }
}

fn starts_with(line: &Line, words: &[&str]) -> bool {
    words.len() <= line.words.len() && words.iter().zip(&line.words).all(|(a, b)| *a == b)
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = writeln!(self.stdin, "quit");
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
