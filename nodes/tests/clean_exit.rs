//! A node binary stopped with SIGINT (as `oilfilm launch` and `ros2 launch` stop it) exits 0
//! and logs no error on its way out.
//!
//! ros2-client's spinner declares its context before the parameter servers, so a spinner that
//! outlived every other holder of the context dropped the DDS participant first; removing each
//! of the node's twelve parameter-service endpoints then failed with a RustDDS ERROR line
//! ("Cannot remove Reader ... Disconnected"), 39 of them at the end of every `oilfilm launch`.
//! Dropping a `RosNode` (which `RosNode::shutdown` does) now joins the spinner while it still
//! holds the context, on every path out of a node.
//!
//! A stop signal delivered to one of RustDDS's threads interrupts its `poll`, and its event
//! loop then stops for good ("dp_event_loop poll failed: Interrupted system call"): nothing the
//! node writes afterwards leaves the process, the exciter's ramp to zero included. So every
//! RustDDS thread blocks SIGINT and SIGTERM, and the node's main thread takes them; the test
//! reads each thread's signal mask from `/proc`.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

#[test]
fn a_node_stopped_with_sigint_exits_0_without_an_error_line() {
    // A domain of its own (the other DDS tests use 1-219).
    let domain = 220 + std::process::id() % 12;
    let mut child = Command::new(env!("CARGO_BIN_EXE_oilfilm-estimator"))
        .args(["--ros-args", "-r", "__node:=clean_exit", "-r", "__ns:=/oilfilm_test"])
        .env("ROS_DOMAIN_ID", domain.to_string())
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting oilfilm-estimator");
    let stderr = child.stderr.take().expect("stderr is piped");
    let (tx, rx) = mpsc::channel::<String>();
    let reader = std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    // Up once it says so: its parameter services and ports exist from then on.
    let mut log = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !log.iter().any(|l: &String| l.contains("ready:")) {
        let left = deadline.saturating_duration_since(Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) => log.push(line),
            Err(_) => {
                let _ = child.kill();
                panic!("the estimator did not start within 30 s:\n{}", log.join("\n"));
            }
        }
    }
    // Let discovery and the announcer run a moment, as in any real run.
    std::thread::sleep(Duration::from_millis(1500));
    let threads = threads(child.id());
    let dds: Vec<&(String, u64)> = threads.iter().filter(|(name, _)| name.starts_with("RustDDS")).collect();
    assert!(dds.len() >= 2, "RustDDS's threads not found: {threads:?}");
    for (name, blocked) in &dds {
        assert!(blocked & STOP_SIGNALS == STOP_SIGNALS, "thread `{name}` does not block SIGINT and SIGTERM (mask {blocked:#x}): {threads:?}");
    }
    let main = threads.iter().find(|(name, _)| name.starts_with("oilfilm-estim")).expect("the main thread is named after the binary");
    assert!(main.1 & STOP_SIGNALS == 0, "the main thread blocks the stop signals (mask {:#x}): none could stop the node", main.1);
    let sent = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("running kill");
    assert!(sent.success(), "kill -INT failed");
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(s) = child.try_wait().expect("waiting for the estimator") {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("the estimator did not exit within 20 s of SIGINT");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    reader.join().expect("the stderr reader");
    log.extend(rx.try_iter());
    let errors: Vec<&String> = log.iter().filter(|l| l.contains("ERROR")).collect();
    assert!(status.success(), "exit status {status}:\n{}", log.join("\n"));
    assert!(errors.is_empty(), "{} error line(s) on the way out:\n{}", errors.len(), log.join("\n"));
    // The log was read to the end: the node said it was starting and gave its parameters.
    assert!(log.iter().any(|l| l.contains("starting")), "{}", log.join("\n"));
}

/// SIGINT (2) and SIGTERM (15) in a `/proc` signal mask (bit `n - 1` for signal `n`).
const STOP_SIGNALS: u64 = (1 << 1) | (1 << 14);

/// Each thread of process `pid`: its name and the signals it blocks (`SigBlk` of
/// `/proc/<pid>/task/<tid>/status`).
fn threads(pid: u32) -> Vec<(String, u64)> {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).expect("the node's threads in /proc");
    tasks
        .map(|task| {
            let dir = task.expect("a thread's entry").path();
            let name = std::fs::read_to_string(dir.join("comm")).unwrap_or_default().trim().to_string();
            let status = std::fs::read_to_string(dir.join("status")).unwrap_or_default();
            let blocked = status.lines().find_map(|l| l.strip_prefix("SigBlk:")).and_then(|hex| u64::from_str_radix(hex.trim(), 16).ok());
            (name, blocked.expect("SigBlk in a thread's status"))
        })
        .collect()
}
