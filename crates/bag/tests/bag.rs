//! Bags of a real (short) sim_rig run through our writer and reader: every topic's bytes
//! back equal, splitting, recovery of a file cut mid-chunk, and clear errors (no panics)
//! for foreign, truncated and corrupted files.

use crate::scratch;
use crate::sim_rig;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use oilfilm_bag::reader::messages_of_file;
use oilfilm_bag::{recover, Bag, BagError, Compression, OilfilmMessage, WriterOptions};
use sim_rig::Published;

/// One short run shared by the tests (the graph is deterministic).
fn published() -> &'static [Published] {
    static P: OnceLock<Vec<Published>> = OnceLock::new();
    P.get_or_init(|| sim_rig::published(&sim_rig::short_run(2.0)))
}

fn tmp(name: &str) -> scratch::Scratch {
    scratch::Scratch::new("oilfilm-bag-test", name)
}

/// The bag holds exactly the published messages: in log-time order, each topic's in the
/// order published. (Messages of different topics with equal log times come in file order,
/// and the writer puts each topic in chunks of its own: their order among such ties is the
/// chunks', not the publishing order.)
fn assert_same_messages(got: &[oilfilm_bag::BagMessage], want: &[Published]) {
    assert_eq!(got.len(), want.len(), "message count");
    assert!(got.windows(2).all(|w| w[0].log_time <= w[1].log_time), "log-time order");
    let mut topics: Vec<&str> = want.iter().map(|m| m.topic.as_str()).collect();
    topics.sort_unstable();
    topics.dedup();
    for topic in topics {
        let g: Vec<_> = got.iter().filter(|m| &*m.topic == topic).collect();
        let w: Vec<_> = want.iter().filter(|m| m.topic == topic).collect();
        assert_eq!(g.len(), w.len(), "messages on {topic}");
        for (i, (g, w)) in g.iter().zip(&w).enumerate() {
            assert_eq!(&*g.type_name, w.type_name, "message {i} on {topic}");
            assert_eq!(g.log_time, w.log_time, "message {i} on {topic}");
            assert!(g.data == w.data, "message {i} on {topic}: bytes differ");
        }
    }
}

#[test]
fn every_topic_round_trips_byte_for_byte_and_decodes() {
    let want = published();
    for t in ["exciter/command", "daq/frames", "rig/status", "conditioned", "estimates"] {
        assert!(want.iter().any(|m| m.topic.ends_with(t)), "the short run publishes on {t}");
    }
    let dir = tmp("roundtrip");
    sim_rig::write_bag(&dir, want, WriterOptions::default()).unwrap().close().unwrap();
    let bag = Bag::open(&dir).unwrap();
    let info = bag.info();
    assert_eq!(info.version, 9);
    assert_eq!(info.storage_identifier, "mcap");
    assert_eq!(info.compression_mode, "", "compression is inside the MCAP chunks");
    assert_eq!(info.relative_file_paths, vec!["roundtrip_0.mcap".to_string()]);
    assert_eq!(info.message_count, want.len() as u64);
    assert_eq!(info.starting_time.nanoseconds_since_epoch, want[0].log_time);
    assert_eq!(info.duration.nanoseconds, want.last().unwrap().log_time - want[0].log_time);
    for t in &info.topics_with_message_count {
        let n = want.iter().filter(|m| m.topic == t.topic_metadata.name).count() as u64;
        assert_eq!(t.message_count, n, "{}", t.topic_metadata.name);
        assert_eq!(t.topic_metadata.offered_qos_profiles.len(), 1);
        // The RIHS01 hash of each type (pinned against rosidl in oilfilm-msgs' tests), in
        // metadata.yaml and in the channel metadata where rosbag2's MCAP plugin keeps it.
        let hash = oilfilm_msgs::type_description_hash(&t.topic_metadata.type_name).unwrap();
        assert_eq!(t.topic_metadata.type_description_hash, hash, "{}", t.topic_metadata.name);
    }
    let scanned = oilfilm_bag::scan::scan(&std::fs::read(dir.join("roundtrip_0.mcap")).unwrap());
    assert_eq!(scanned.channels.len(), info.topics_with_message_count.len());
    for c in scanned.channels.values() {
        let ty = &scanned.schemas[&c.schema_id].name;
        assert_eq!(c.metadata.get("topic_type_hash"), Some(&oilfilm_msgs::type_description_hash(ty).unwrap()), "{}", c.topic);
    }
    let got = bag.messages().unwrap();
    assert_same_messages(&got, want);
    // Decoding gives the published values: re-encoding them gives the published bytes (equal
    // to the bag's, per topic, above).
    let mut frames = 0;
    for g in &got {
        let again = match g.decode_ours().unwrap() {
            OilfilmMessage::ExciterCommand(m) => oilfilm_msgs::encode(&m),
            OilfilmMessage::DaqFrame(m) => {
                frames += 1;
                // The simulated 16-bit card's frames carry its counts (ADR 0018).
                assert_eq!(m.units, oilfilm_msgs::DaqFrame::UNITS_COUNTS);
                assert!(m.values.is_empty() && !m.counts.is_empty());
                m.check_samples().unwrap();
                oilfilm_msgs::encode(&m)
            }
            OilfilmMessage::ConditionedFrame(m) => oilfilm_msgs::encode(&m),
            OilfilmMessage::CoefficientEstimate(m) => oilfilm_msgs::encode(&m),
            OilfilmMessage::RigStatus(m) => oilfilm_msgs::encode(&m),
            OilfilmMessage::ParameterEvent(m) => oilfilm_msgs::encode(&m),
        };
        assert!(again == g.data, "{} at {}", g.topic, g.log_time);
    }
    assert_eq!(frames, want.iter().filter(|m| m.type_name == "oilfilm_msgs/msg/DaqFrame").count());
    // Asking for the wrong type is an error naming both types, not garbage.
    let e = got[0].decode::<oilfilm_msgs::RigStatus>();
    if got[0].type_name.as_ref() != "oilfilm_msgs/msg/RigStatus" {
        let e = e.unwrap_err().to_string();
        assert!(e.contains("not a oilfilm_msgs/msg/RigStatus"), "{e}");
    }
}

#[test]
fn split_by_duration_and_by_size_keep_every_message_and_rewrite_metadata() {
    let want = published();
    // By duration: 0.5 s files of a 2.4 s run.
    let dir = tmp("split_time");
    let options = WriterOptions { split_duration_ns: Some(500_000_000), ..WriterOptions::default() };
    let mut w = sim_rig::write_bag(&dir, &want[..want.len() / 2], options).unwrap();
    // metadata.yaml is written at each split, listing the files closed so far.
    let closed = w.files().len();
    assert!(closed >= 1, "half the run spans more than 0.5 s");
    let meta = Bag::open(&dir).unwrap();
    assert_eq!(meta.info().relative_file_paths.len(), closed);
    w.split().unwrap();
    drop(w); // dropping closes too
    let bag = Bag::open(&dir).unwrap();
    assert_eq!(bag.info().relative_file_paths.len(), closed + 2, "the forced split leaves an empty last file");
    assert_same_messages(&bag.messages().unwrap(), &want[..want.len() / 2]);

    let dir = tmp("split_time_all");
    let options = WriterOptions { split_duration_ns: Some(500_000_000), ..WriterOptions::default() };
    sim_rig::write_bag(&dir, want, options).unwrap().close().unwrap();
    let bag = Bag::open(&dir).unwrap();
    let files = &bag.info().files;
    assert!(files.len() >= 5, "{} files", files.len());
    for f in files {
        assert!(f.duration.nanoseconds < 500_000_000, "{}: {} ns", f.path, f.duration.nanoseconds);
    }
    assert_eq!(files.iter().map(|f| f.message_count).sum::<u64>(), want.len() as u64);
    assert_same_messages(&bag.messages().unwrap(), want);

    // By size: uncompressed, 64 KiB chunks, 300 kB files.
    let dir = tmp("split_size");
    let options = WriterOptions { compression: Compression::None, chunk_size: 64 << 10, split_size_bytes: Some(300_000), ..WriterOptions::default() };
    sim_rig::write_bag(&dir, want, options).unwrap().close().unwrap();
    let bag = Bag::open(&dir).unwrap();
    let total: u64 = want.iter().map(|m| m.data.len() as u64).sum();
    assert!(bag.files().len() as u64 >= total / 400_000, "{} files for {total} bytes", bag.files().len());
    for f in bag.files() {
        let len = std::fs::metadata(&f).unwrap().len();
        // A file is closed at the first message after it reached the limit: at most one
        // chunk (and the largest message) over.
        assert!(len < 300_000 + (64 << 10) + 200_000, "{}: {len} bytes", f.display());
    }
    assert_same_messages(&bag.messages().unwrap(), want);
}

/// Writes a bag, then makes it look like its writer was killed in the middle of chunk `k`:
/// no metadata.yaml, the file cut half-way through that chunk. Returns the bag directory,
/// the file and the messages of the complete chunks 0..k as the mcap crate's own reader
/// sees them in the intact file.
fn killed_mid_chunk(name: &str) -> (scratch::Scratch, PathBuf, Vec<(u64, Vec<u8>)>, usize) {
    let dir = tmp(name);
    let options = WriterOptions { chunk_size: 32 << 10, ..WriterOptions::default() };
    sim_rig::write_bag(&dir, published(), options).unwrap().close().unwrap();
    let file = dir.join(format!("{name}_0.mcap"));
    let bytes = std::fs::read(&file).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let chunks = &summary.chunk_indexes;
    assert!(chunks.len() >= 6, "{} chunks", chunks.len());
    let k = chunks.len() / 2;
    let mut kept = Vec::new();
    for c in &chunks[..k] {
        for m in summary.stream_chunk(&bytes, c).unwrap() {
            let m = m.unwrap();
            kept.push((m.log_time, m.data.into_owned()));
        }
    }
    let cut = chunks[k].chunk_start_offset + chunks[k].chunk_length / 2;
    std::fs::write(&file, &bytes[..cut as usize]).unwrap();
    std::fs::remove_file(dir.join("metadata.yaml")).unwrap();
    (dir, file, kept, k)
}

#[test]
fn recovery_of_a_file_cut_mid_chunk_keeps_every_complete_chunk() {
    let (dir, file, kept, k) = killed_mid_chunk("killed");
    // Before recovery: errors that say what is wrong and what to do.
    let e = Bag::open(&dir).unwrap_err();
    assert!(matches!(e, BagError::Metadata { .. }), "{e}");
    assert!(e.to_string().contains("recover"), "{e}");
    let e = messages_of_file(&file, &std::fs::read(&file).unwrap()).unwrap_err().to_string();
    assert!(e.contains("killed_0.mcap") && e.contains("ends early") && e.contains(&format!("after {k} complete chunks")), "{e}");

    let r = recover(&dir).unwrap();
    assert_eq!(r.files.len(), 1);
    assert_eq!(r.files[0].chunks, k);
    assert!(r.files[0].stop.as_ref().is_some_and(|s| s.truncated));
    assert_eq!(r.messages(), kept.len() as u64);
    let original = r.files[0].original.clone().unwrap();
    assert!(original.ends_with("killed_0.mcap.damaged") && original.exists(), "the original is kept");

    let bag = Bag::open(&dir).unwrap();
    let got = bag.messages().unwrap();
    assert_eq!(got.len(), kept.len());
    let mut want = kept.clone();
    want.sort_by_key(|m| m.0);
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g.log_time, w.0);
        assert!(g.data == w.1);
        g.decode_ours().unwrap();
    }
    // The recovered file is a complete MCAP file to the mcap crate too, with a summary.
    let bytes = std::fs::read(&file).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    assert_eq!(summary.stats.unwrap().message_count, kept.len() as u64);
    // Its metadata.yaml counts what is there, per topic, with the channels' QoS and hashes.
    let info = bag.info();
    assert_eq!(info.message_count, kept.len() as u64);
    for t in &info.topics_with_message_count {
        assert_eq!(t.topic_metadata.offered_qos_profiles.len(), 1, "{}", t.topic_metadata.name);
        assert_eq!(t.topic_metadata.type_description_hash, oilfilm_msgs::type_description_hash(&t.topic_metadata.type_name).unwrap());
        assert_eq!(t.message_count, got.iter().filter(|m| *m.topic == t.topic_metadata.name).count() as u64);
    }
    // Recovering a sound bag again changes nothing.
    let again = recover(&dir).unwrap();
    assert!(again.files[0].original.is_none() && again.files[0].stop.is_none());
    assert_eq!(again.metadata, r.metadata);
}

#[test]
fn foreign_corrupted_and_truncated_files_give_errors_naming_the_file_not_panics() {
    let dir = tmp("errors");
    sim_rig::write_bag(&dir, &published()[..20], WriterOptions { chunk_size: 16 << 10, ..WriterOptions::default() }).unwrap().close().unwrap();
    let file = dir.join("errors_0.mcap");
    let bytes = std::fs::read(&file).unwrap();

    // Not the ros2 profile.
    let mut w = mcap::WriteOptions::new().profile("").create(std::io::Cursor::new(Vec::new())).unwrap();
    w.finish().unwrap();
    let foreign = w.into_inner().into_inner();
    let e = messages_of_file(Path::new("x/foreign.mcap"), &foreign).unwrap_err().to_string();
    assert!(e.contains("x/foreign.mcap") && e.contains("not `ros2`"), "{e}");

    // Not MCAP at all.
    let e = messages_of_file(Path::new("notes.txt"), b"hello, world").unwrap_err().to_string();
    assert!(e.starts_with("notes.txt"), "{e}");

    // Every prefix length class and many single-byte corruptions: an error or a clean
    // read, never a panic; a corrupted chunk is refused by its CRC, not decoded wrongly.
    let mut wrong_ok = 0;
    for i in (0..bytes.len()).step_by((bytes.len() / 400).max(1)) {
        let _ = messages_of_file(&file, &bytes[..i]).unwrap_err();
        let mut bad = bytes.clone();
        bad[i] ^= 0x5a;
        if let Ok(msgs) = messages_of_file(&file, &bad) {
            // A flip in an index, the summary or padding may be harmless; the data must
            // still be what was written.
            let good = messages_of_file(&file, &bytes).unwrap();
            if msgs != good {
                wrong_ok += 1;
            }
        }
    }
    assert_eq!(wrong_ok, 0, "corruptions read as different messages without an error");

    // A bag with a newer metadata version is refused by name.
    let meta = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    std::fs::write(dir.join("metadata.yaml"), meta.replace("version: 9", "version: 10")).unwrap();
    let e = Bag::open(&dir).unwrap_err().to_string();
    assert!(e.contains("metadata.yaml") && e.contains("version 10"), "{e}");

    // Writing into an existing non-empty directory is refused.
    let e = oilfilm_bag::BagWriter::create(&dir, WriterOptions::default()).err().unwrap().to_string();
    assert!(e.contains("not empty"), "{e}");
}
