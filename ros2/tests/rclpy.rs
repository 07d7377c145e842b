//! base-ros2 against ROS 2 itself: rclpy (Jazzy) on Fast DDS, ROS 2's default
//! middleware, from the PyPI wheels `.ci/install-ros2` installs into a Python 3.11
//! virtual environment. The scenarios are `tests/python/rclpy_scenarios.py`: graph and
//! types, QoS, `/odom` rate and stamps, reset by the service (also while driving, and
//! by a one-shot publisher on the topic), forward, counter-clockwise, the stale-command
//! stop, a zero twist at the goal, a 50 Hz stream of changing speeds, `/rosout`, the
//! parameters, the e-stop in `/diagnostics`, SIGTERM leaving the graph, and the two
//! latency figures docs/ros2.md quotes.
//!
//! Fast DDS discovers by multicast, which the loopback interface does not carry
//! unless told to: the test runs itself again in a network namespace of its own
//! (`unshare --net`, root), where loopback has multicast and nothing else is on the
//! network. It writes `target/ros2-scenarios.txt` (`ros2 scenarios: N passed, M
//! failed`) for CI's summary. With CI=true a missing venv fails the test instead of
//! skipping it.

mod support;

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc::channel;
use std::thread;
use std::time::{Duration, Instant};

use support::{Bridge, start_simulator};

/// Set in the child that runs inside the network namespace.
const IN_NAMESPACE: &str = "BASE_ROS2_TEST_IN_NETNS";
const TEST_NAME: &str = "rclpy_on_fast_dds_drives_resets_and_reads_the_simulated_base";

/// The venv's python, where `.ci/install-ros2` puts it.
fn venv_python() -> PathBuf {
    match std::env::var_os("BASE_ROS2_VENV") {
        Some(venv) => PathBuf::from(venv).join("bin/python"),
        None => PathBuf::from(std::env::var_os("HOME").unwrap_or_default())
            .join(".cache/base-ros2/jazzy-venv/bin/python"),
    }
}

/// `true` if rclpy can run; otherwise a skip, or a failure under CI=true.
fn rclpy_available() -> bool {
    let found = Command::new(venv_python())
        .args(["-c", "import rclpy, can, std_srvs"])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|status| status.success());
    if !found {
        let message = "rclpy (ROS 2 Jazzy) is needed in the venv .ci/install-ros2 makes; run it";
        assert!(std::env::var("CI").as_deref() != Ok("true"), "{message}");
        eprintln!("SKIPPED: {message}");
    }
    found
}

fn summary_file() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/ros2-scenarios.txt")
}

#[test]
fn rclpy_on_fast_dds_drives_resets_and_reads_the_simulated_base() {
    if std::env::var_os(IN_NAMESPACE).is_some() {
        scenarios_in_this_namespace();
        return;
    }
    let _ = std::fs::remove_file(summary_file());
    if !rclpy_available() {
        return;
    }
    let setup = "ip link set lo up && ip link set lo multicast on && \
                 ip route add 224.0.0.0/4 dev lo && exec \"$0\" \"$@\"";
    let output = Command::new("unshare")
        .args(["--net", "sh", "-c", setup])
        .arg(std::env::current_exe().unwrap())
        .args(["--exact", TEST_NAME, "--nocapture", "--test-threads=1"])
        .env(IN_NAMESPACE, "1")
        .stdin(Stdio::null())
        .output()
        .expect("unshare runs (util-linux, as root)");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    let counts = stdout.lines().find_map(|line| {
        let rest = line.strip_prefix("SCENARIOS passed=")?;
        let (passed, failed) = rest.split_once(" failed=")?;
        Some((passed.parse::<u32>().ok()?, failed.parse::<u32>().ok()?))
    });
    if let Some((passed, failed)) = counts {
        std::fs::write(
            summary_file(),
            format!("ros2 scenarios: {passed} passed, {failed} failed\n"),
        )
        .unwrap();
    }
    let lines: Vec<&str> = stdout
        .lines()
        .filter(|line| {
            ["PASS ", "FAIL ", "FIGURE ", "SCENARIOS "]
                .iter()
                .any(|prefix| line.starts_with(prefix))
        })
        .collect();
    // The scenario lines show with --nocapture, and in full when anything failed.
    println!("{}", lines.join("\n"));
    assert!(
        output.status.success() && matches!(counts, Some((passed, 0)) if passed > 0),
        "{}\n--- the namespace's whole output:\n{stdout}\n{stderr}",
        lines.join("\n")
    );
}

/// Inside the namespace: the simulator, base-ros2 with ROS arguments as `ros2 run`
/// passes them, and the rclpy peer.
fn scenarios_in_this_namespace() {
    let mut simulator = start_simulator();
    let socketcand = simulator.socketcand();
    let directory = simulator.directory().to_owned();
    let params = directory.join("params.yaml");
    std::fs::write(
        &params,
        "base_ros2:\n  ros__parameters:\n    odom_frame: odom\n    publish_tf: true\n",
    )
    .unwrap();
    let bridge = Bridge::with_args(
        &socketcand.to_string(),
        "0",
        &[
            "--ros-args",
            "-p",
            "cmd_vel_timeout:=0.5",
            "-p",
            "hardware_id:=sim_base",
            "--params-file",
            params.to_str().unwrap(),
        ],
    );
    let python_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python");
    let mut peer = Command::new(venv_python())
        .arg(python_dir.join("rclpy_scenarios.py"))
        .args([socketcand.ip().to_string(), socketcand.port().to_string()])
        .current_dir(&python_dir)
        .env("ROS_DOMAIN_ID", "0")
        .env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the venv's python runs the scenarios");
    let (sender, lines) = channel();
    let stdout = BufReader::new(peer.stdout.take().unwrap()).lines();
    thread::spawn(move || {
        for line in stdout.map_while(Result::ok) {
            let _ = sender.send(line);
        }
    });
    let mut bridge = Some(bridge);
    let mut bridge_log = String::new();
    let deadline = Instant::now() + Duration::from_secs(240);
    while let Ok(line) = lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        println!("{line}");
        let mut answer = || writeln!(peer.stdin.as_mut().unwrap()).unwrap();
        match line.as_str() {
            "ESTOP?" => {
                simulator.console("estop on").unwrap();
                answer();
            }
            "SIGTERM?" => {
                if let Some(bridge) = bridge.take() {
                    bridge_log = bridge.log();
                    let status = bridge.terminate();
                    println!("base-ros2 ended on SIGTERM: {status}");
                }
                answer();
            }
            _ if line.starts_with("SCENARIOS ") => break,
            _ => {}
        }
    }
    let _ = peer.kill();
    let output = peer.wait_with_output().unwrap();
    if let Some(bridge) = &bridge {
        bridge_log = bridge.log();
    }
    println!(
        "--- peer stderr:\n{}\n--- base-ros2 said:\n{bridge_log}",
        String::from_utf8_lossy(&output.stderr)
    );
}
