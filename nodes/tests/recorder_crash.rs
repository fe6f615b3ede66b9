//! The recorder killed for real: the sim_rig's exciter and DAQ publish on DDS, the
//! `oilfilm-recorder` binary records them with its default chunking (1 MiB or 1 s of log
//! time), and once a few chunks are on disk it gets SIGKILL. Recovery (the code of
//! `oilfilm bag recover`) must then give a bag our reader opens that holds every message of
//! every complete chunk (as the mcap crate's own streaming reader finds them in the killed
//! file), and the loss must be at most the chunk that was open: about 1 s.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use oilfilm_bag::{Bag, BagMessage};
use oilfilm_graph::launch::NodeLaunch;
use oilfilm_graph::stamp::Stamp;
use oilfilm_msgs::DaqFrame;
use oilfilm_nodes::supervisor::Supervisor;

fn bin_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_oilfilm-recorder")).parent().unwrap().to_path_buf()
}

fn node(name: &str, params: &[&str]) -> NodeLaunch {
    let params_file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../launch_configs/params/sim_rig.yaml");
    let mut args: Vec<String> = ["--ros-args", "-r", &format!("__node:={name}"), "-r", "__ns:=/oilfilm", "--params-file", &params_file.display().to_string()]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for p in params {
        args.extend(["-p".to_string(), p.to_string()]);
    }
    NodeLaunch { exec: format!("oilfilm-{name}"), name: name.into(), namespace: "/oilfilm".into(), args }
}

/// (topic, log time, bytes) of every message the mcap crate's streaming reader returns
/// before the killed file's first error: the messages of its complete chunks.
fn complete_chunk_messages(bytes: &[u8]) -> (Vec<(String, u64, Vec<u8>)>, bool) {
    let mut out = Vec::new();
    let mut ended_in_error = false;
    match mcap::MessageStream::new(bytes) {
        Ok(stream) => {
            for m in stream {
                match m {
                    Ok(m) => out.push((m.channel.topic.clone(), m.log_time, m.data.into_owned())),
                    Err(_) => {
                        ended_in_error = true;
                        break;
                    }
                }
            }
        }
        Err(_) => ended_in_error = true,
    }
    (out, ended_in_error)
}

#[test]
fn sigkill_mid_chunk_loses_at_most_the_open_chunk() {
    std::env::set_var("ROS_DOMAIN_ID", (100 + std::process::id() % 50).to_string());
    let dir = std::env::temp_dir().join(format!("oilfilm-recorder-crash-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let bag_dir = dir.join("killed");
    std::fs::create_dir_all(&dir).unwrap();
    let file = bag_dir.join("killed_0.mcap");

    // The recorder first, so the DAQ (which waits for a reader of its frames) starts at once.
    let mut recorder = Command::new(env!("CARGO_BIN_EXE_oilfilm-recorder"))
        .args(["--ros-args", "-r", "__node:=recorder", "-r", "__ns:=/oilfilm", "-p"])
        .arg(format!("output:={}", bag_dir.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start oilfilm-recorder");
    let mut graph = Supervisor::start(&[node("exciter", &[]), node("daq", &["rate_factor:=1.0"])], &bin_dir()).unwrap();

    // Wait for three complete chunks of DAQ frames (about 3 s of recording at the default
    // 1 s chunks; each topic has chunks of its own, so count the frames they hold).
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut chunks = 0;
    while Instant::now() < deadline {
        if let Ok(bytes) = std::fs::read(&file) {
            let scanned = oilfilm_bag::scan::scan(&bytes);
            let daq = scanned.channels.iter().find(|(_, c)| c.topic == "/oilfilm/daq/frames").map(|(&id, _)| id);
            let frames = scanned.messages.iter().filter(|m| Some(m.channel_id) == daq).count();
            chunks = scanned.chunks;
            if frames >= 25 {
                break;
            }
        }
        if let Some((name, status)) = graph.exited() {
            panic!("{name} exited while recording: {status}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(chunks >= 3, "only {chunks} chunk(s), fewer than 25 frames, written in 60 s");
    // Let the next chunk fill for a part of a second, so the kill lands mid-chunk.
    std::thread::sleep(Duration::from_millis(600));
    let killed_at = Stamp::now();
    recorder.kill().expect("SIGKILL the recorder"); // Child::kill is SIGKILL on Unix
    let status = recorder.wait().unwrap();
    graph.stop(Duration::from_secs(5));
    assert!(!status.success(), "the recorder was killed: {status}");
    assert!(!bag_dir.join("metadata.yaml").exists(), "a killed recorder wrote no metadata.yaml");
    let killed_bytes = std::fs::read(&file).unwrap();
    let e = Bag::open(&bag_dir).unwrap_err().to_string();
    assert!(e.contains("metadata.yaml") && e.contains("recover"), "{e}");

    let (want, ended_in_error) = complete_chunk_messages(&killed_bytes);
    assert!(ended_in_error, "the killed file has no footer: the streaming reader must stop at an error");
    let recovery = oilfilm_bag::recover(&bag_dir).unwrap();
    assert_eq!(recovery.files.len(), 1);
    assert!(recovery.files[0].original.is_some(), "the damaged file was rewritten and kept aside");
    assert!(recovery.files[0].chunks >= 3, "{} complete chunks kept", recovery.files[0].chunks);

    let bag = Bag::open(&bag_dir).unwrap();
    let got: Vec<BagMessage> = bag.messages().unwrap();
    let mut got_tuples: Vec<(String, u64, Vec<u8>)> = got.iter().map(|m| (m.topic.to_string(), m.log_time, m.data.clone())).collect();
    let mut want_sorted = want.clone();
    got_tuples.sort();
    want_sorted.sort();
    assert_eq!(got_tuples.len(), want_sorted.len(), "every message of every complete chunk");
    assert!(got_tuples == want_sorted, "the recovered messages are the complete chunks' messages, byte for byte");
    assert_eq!(bag.info().message_count, got.len() as u64);

    // The frames recorded are the DAQ's, in order, none missing in between.
    let frames: Vec<DaqFrame> = got.iter().filter(|m| &*m.topic == "/oilfilm/daq/frames").map(|m| m.decode().unwrap()).collect();
    assert!(frames.len() >= 20, "{} frames in three 1 s chunks of 0.1 s frames", frames.len());
    for w in frames.windows(2) {
        assert_eq!(w[1].sequence, w[0].sequence + 1, "a frame is missing between complete chunks");
    }
    let per_topic = got.iter().fold(BTreeMap::<String, usize>::new(), |mut m, x| {
        *m.entry(x.topic.to_string()).or_default() += 1;
        m
    });

    // The loss: from the last recovered message to the kill. The open chunk began at most
    // 1 s + one frame period (0.1 s) of log time before its last message; allow another
    // frame period for the last frame in flight and 0.3 s for a loaded machine.
    let last = got.iter().map(|m| m.log_time).max().unwrap();
    let lost_s = killed_at.seconds_since(Stamp(last as i64));
    println!("crash: {} chunks kept, {} messages {per_topic:?}, {lost_s:.3} s lost before the kill", recovery.files[0].chunks, got.len());
    assert!(lost_s <= 1.0 + 0.1 + 0.1 + 0.3, "{lost_s:.3} s of recording lost: more than one chunk");
    assert!(lost_s > 0.0);
    let _ = std::fs::remove_dir_all(&dir);
}
