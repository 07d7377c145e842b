//! What the ROS 2 tests share: the simulator binary and base-ros2 as a child process.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

use virtual_robot::process::SimulatorProcess;

/// The simulator binary, built next to this test (`cargo test --workspace` builds it;
/// alone, `cargo test -p base-ros2` builds it here).
pub fn simulator_binary() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    let profile_dir = exe.parent().unwrap().parent().unwrap();
    let binary = profile_dir.join("virtual-base-controller");
    let status = Command::new(env!("CARGO"))
        // The profile `cargo test` builds everything with: in a workspace run the
        // simulator is already built and this is a no-op.
        .args([
            "build",
            "-q",
            "--profile",
            "test",
            "-p",
            "virtual-robot",
            "--bin",
            "virtual-base-controller",
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .status()
        .expect("cargo builds the simulator");
    assert!(status.success(), "the simulator did not build");
    assert!(binary.exists(), "no simulator at {}", binary.display());
    binary
}

/// The simulator (without an SLCAN link: the node uses socketcand), once the
/// controller has reached standby.
pub fn start_simulator() -> SimulatorProcess {
    let simulator = SimulatorProcess::launch(simulator_binary())
        .no_link()
        .start()
        .expect("the simulator starts");
    // The drives boot within the first second; let the controller reach standby.
    thread::sleep(Duration::from_millis(1500));
    simulator
}

/// The bridge as a child process; its stderr is collected for failure messages.
pub struct Bridge {
    child: Child,
    log: Arc<Mutex<String>>,
}

impl Bridge {
    pub fn with_args(socketcand: &str, domain: &str, args: &[&str]) -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_base-ros2"))
            .args(["--interface", "socketcand", "--channel", socketcand])
            .args(args)
            .env("ROS_DOMAIN_ID", domain)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("base-ros2 starts");
        let log = Arc::new(Mutex::new(String::new()));
        let lines = BufReader::new(child.stderr.take().unwrap()).lines();
        let sink = Arc::clone(&log);
        thread::spawn(move || {
            for line in lines.map_while(Result::ok) {
                let mut log = sink.lock().unwrap();
                log.push_str(&line);
                log.push('\n');
            }
        });
        Bridge { child, log }
    }

    pub fn log(&self) -> String {
        self.log.lock().unwrap().clone()
    }

    /// SIGTERM, as systemd or ros2 launch end it; the exit status.
    pub fn terminate(mut self) -> std::process::ExitStatus {
        let _ = Command::new("kill")
            .arg(self.child.id().to_string())
            .status();
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            assert!(Instant::now() < deadline, "base-ros2 ignored SIGTERM");
            thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
