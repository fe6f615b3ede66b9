//! The player and the recorder binaries on real DDS: a bag played (as fast as possible, then
//! at 4x real time) is recorded again with every message's bytes equal and in order (up to
//! the wire's padding to 4 bytes, see [`as_received`]), the
//! 4x replay takes a quarter of the bag's time, and `/clock` (rosgraph_msgs/msg/Clock)
//! carries the bag's log time, never going backwards, up to the last message's.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use oilfilm_bag::{Bag, BagWriter, TopicSpec, WriterOptions};
use oilfilm_graph::params::NodeArgs;
use oilfilm_graph::ports::Receive;
use oilfilm_graph::recorder::bag_qos;
use oilfilm_graph::stamp::Stamp;
use oilfilm_graph::topics::{self, TopicQos};
use oilfilm_msgs::{Clock, DaqFrame, Header, RigStatus, RosMessage};
use oilfilm_nodes::dds::{qos_from, RosNode};

const T0: u64 = 1_700_000_000_000_000_000;
const FRAMES: u64 = 120;
const PERIOD_NS: u64 = 50_000_000;

/// A bag of `FRAMES` DAQ frames (20 Hz of log time) and a status after every fourth.
fn source_bag(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut w = BagWriter::create(dir, WriterOptions::default()).unwrap();
    let f = w.add_topic(TopicSpec::ours("/oilfilm/daq/frames", DaqFrame::TYPE_NAME, vec![bag_qos(&topics::DAQ_FRAMES.qos)]).unwrap()).unwrap();
    let s = w.add_topic(TopicSpec::ours("/oilfilm/rig/status", RigStatus::TYPE_NAME, vec![bag_qos(&topics::RIG_STATUS.qos)]).unwrap()).unwrap();
    let mut sent = Vec::new();
    for k in 0..FRAMES {
        let t = T0 + k * PERIOD_NS;
        let stamp = Stamp(t as i64 - 3_000_000).to_time();
        let frame = DaqFrame {
            header: Header { stamp: stamp.clone(), frame_id: "oilfilm_bearing".into() },
            sequence: k,
            first_scan: k * 250,
            sample_rate_hz: 5000.0,
            scan_count: 250,
            channel_names: (0..10).map(|c| format!("ch{c}")).collect(),
            values: (0..2500).map(|i| (i as f64 * 1e-3 + k as f64).sin()).collect(),
            ..Default::default()
        };
        let bytes = oilfilm_msgs::encode(&frame);
        w.write(f, t, &bytes).unwrap();
        sent.push(("/oilfilm/daq/frames".to_string(), bytes));
        if k % 4 == 3 {
            let st = RigStatus { header: Header { stamp, frame_id: String::new() }, speed_rad_s: 157.0, message: format!("k={k}"), ..Default::default() };
            let bytes = oilfilm_msgs::encode(&st);
            w.write(s, t + 1000, &bytes).unwrap();
            sent.push(("/oilfilm/rig/status".to_string(), bytes));
        }
    }
    w.close().unwrap();
    sent
}

fn bin(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_oilfilm-player")).parent().unwrap().join(name)
}

fn start_recorder(out: &Path) -> Child {
    Command::new(bin("oilfilm-recorder"))
        .args(["--ros-args", "-r", "__node:=recorder", "-p", "topics:=[daq/frames, rig/status]", "-p", "status_period_s:=0"])
        .arg("-p")
        .arg(format!("output:={}", out.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start oilfilm-recorder")
}

fn stop(mut child: Child) {
    let pid = child.id().to_string();
    let _ = Command::new("kill").args(["-INT", &pid]).status();
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline {
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "the recorder closes cleanly on SIGINT: {status}");
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    panic!("the recorder did not stop on SIGINT");
}

/// Plays `bag` with `params` while collecting /clock; returns the clock values (ns) and
/// the player's wall time.
fn play(bag: &Path, params: &[&str], clock: &mut dyn Receive<Clock>) -> (Vec<i64>, Duration) {
    let mut cmd = Command::new(bin("oilfilm-player"));
    cmd.args(["--ros-args", "-r", "__node:=player", "-p", &format!("bag:={}", bag.display()), "-p", "wait_s:=20"]);
    for p in params {
        cmd.args(["-p", p]);
    }
    let started = Instant::now();
    let mut child = cmd.stdout(Stdio::null()).stderr(Stdio::null()).spawn().expect("start oilfilm-player");
    let mut clocks = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        while let Some(c) = clock.receive().unwrap() {
            clocks.push(Stamp::from_time(&c.clock).0);
        }
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(Instant::now() < deadline, "the player did not finish in 60 s");
        std::thread::sleep(Duration::from_millis(2));
    };
    let elapsed = started.elapsed();
    assert!(status.success(), "the player ends at the end of the bag: {status}");
    while let Some(c) = clock.receive().unwrap() {
        clocks.push(Stamp::from_time(&c.clock).0);
    }
    (clocks, elapsed)
}

/// Whether `got` is what a DDS reader receives for `sent`: the same bytes, or (for a
/// message small enough to go in one DATA submessage) the same bytes padded with zeros to a
/// multiple of 4. That padding is not signalled (rustdds, like RTPS 2.3, sends
/// representation options 0), so a message ending off a 4-byte boundary (a string at the
/// end) arrives with up to 3 more bytes; CDR readers ignore them, and rosbag2 records them
/// too.
fn as_received(got: &[u8], sent: &[u8]) -> bool {
    got == sent
        || (got.len() > sent.len()
            && got.len() - sent.len() <= 3
            && (got.len() - 4).is_multiple_of(4)
            && got.starts_with(sent)
            && got[sent.len()..].iter().all(|&b| b == 0))
}

fn check_recorded(dir: &Path, sent: &[(String, Vec<u8>)]) -> Vec<u64> {
    let got = Bag::open(dir).unwrap().messages().unwrap();
    for topic in ["/oilfilm/daq/frames", "/oilfilm/rig/status"] {
        let want: Vec<&Vec<u8>> = sent.iter().filter(|(t, _)| t == topic).map(|(_, b)| b).collect();
        let have: Vec<&Vec<u8>> = got.iter().filter(|m| &*m.topic == topic).map(|m| &m.data).collect();
        assert_eq!(have.len(), want.len(), "{topic}: every message played is recorded");
        for (i, (h, w)) in have.iter().zip(&want).enumerate() {
            assert!(as_received(h, w), "{topic}[{i}]: recorded {} bytes are not the {} played (in order)", h.len(), w.len());
        }
    }
    got.iter().filter(|m| &*m.topic == "/oilfilm/daq/frames").map(|m| m.log_time).collect()
}

fn check_clock(clocks: &[i64]) {
    assert!(!clocks.is_empty(), "/clock published");
    assert!(clocks.windows(2).all(|w| w[1] >= w[0]), "/clock never goes backwards");
    assert!(clocks.iter().all(|&c| c >= T0 as i64 && c <= (T0 + (FRAMES - 1) * PERIOD_NS + 1000) as i64), "/clock is the bag's log time");
    assert_eq!(*clocks.last().unwrap(), (T0 + (FRAMES - 1) * PERIOD_NS + 1000) as i64, "/clock ends at the last message's log time");
}

#[test]
fn a_bag_played_on_dds_is_recorded_again_byte_for_byte_with_clock() {
    std::env::set_var("ROS_DOMAIN_ID", (50 + std::process::id() % 50).to_string());
    let dir = std::env::temp_dir().join(format!("oilfilm-player-dds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let source = dir.join("source");
    let sent = source_bag(&source);

    let me = NodeArgs { name: "clock_probe".into(), namespace: topics::NAMESPACE.into(), ..Default::default() };
    let mut ros = RosNode::new(&me).unwrap();
    let qos = qos_from(TopicQos { reliable: true, depth: 1000, transient_local: false });
    let mut clock = ros.subscription_named::<Clock>("/clock", Clock::TYPE_NAME, qos).unwrap();

    // As fast as possible: nothing dropped.
    let fast = dir.join("fast");
    let recorder = start_recorder(&fast);
    let (clocks, elapsed) = play(&source, &["fast:=true"], &mut clock);
    stop(recorder);
    check_recorded(&fast, &sent);
    check_clock(&clocks);
    println!("fast: {} messages in {:.2} s (with discovery), {} /clock", sent.len(), elapsed.as_secs_f64(), clocks.len());

    // 4x real time: the frames arrive spread over a quarter of the bag's 5.95 s.
    let rate = dir.join("rate4");
    let recorder = start_recorder(&rate);
    let (clocks, _) = play(&source, &["rate:=4.0"], &mut clock);
    stop(recorder);
    let log_times = check_recorded(&rate, &sent);
    check_clock(&clocks);
    let span_s = (log_times[log_times.len() - 1] - log_times[0]) as f64 * 1e-9;
    let want_s = (FRAMES - 1) as f64 * PERIOD_NS as f64 * 1e-9 / 4.0;
    println!("rate 4: frames over {span_s:.3} s (bag / 4 = {want_s:.3} s), {} /clock", clocks.len());
    assert!((span_s - want_s).abs() < 0.25, "paced at 4x: {span_s:.3} s vs {want_s:.3} s");
    assert!(clocks.len() as f64 > want_s * 50.0, "/clock ticks between messages ({} in {want_s:.2} s)", clocks.len());

    drop(clock);
    ros.shutdown();
    let _ = std::fs::remove_dir_all(&dir);
}
