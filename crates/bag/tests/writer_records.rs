//! The writer frames MCAP itself (records.rs, chunks.rs); the mcap crate's reader is the
//! oracle: every file it writes, for every compression, number of compression workers and
//! chunk layout, is read with the data-section, summary and chunk CRCs checked, the summary
//! (statistics, schemas, channels, chunk indexes, summary offsets) against what the file
//! holds, and each chunk's message indexes against its messages.

use crate::scratch;
use crate::sim_rig;

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use oilfilm_bag::{Bag, BagWriter, Compression, WriterOptions};
use sim_rig::Published;

fn published() -> &'static [Published] {
    static P: OnceLock<Vec<Published>> = OnceLock::new();
    P.get_or_init(|| sim_rig::published(&sim_rig::short_run(2.0)))
}

fn tmp(name: &str) -> scratch::Scratch {
    scratch::Scratch::new("oilfilm-bag-records", name)
}

/// A message as the mcap crate reads it: topic, sequence, log time, publish time, bytes.
type Msg = (String, u32, u64, u64, Vec<u8>);

/// Every record of the file through the mcap crate's linear reader with every CRC checked
/// (chunks decompressed, their records yielded), and nothing after the end magic.
fn records_checked(bytes: &[u8]) -> Vec<(u8, Vec<u8>)> {
    let options = LinearReaderOptions::default()
        .with_validate_chunk_crcs(true)
        .with_validate_data_section_crc(true)
        .with_validate_summary_section_crc(true)
        .with_check_finishes_after_end_magic(true);
    let mut reader = LinearReader::new_with_options(options);
    let mut fed = 0;
    let mut out = Vec::new();
    while let Some(event) = reader.next_event() {
        match event.expect("the mcap crate reads the file, CRCs checked") {
            LinearReadEvent::ReadRequest(want) => {
                let n = want.min(bytes.len() - fed);
                reader.insert(n).copy_from_slice(&bytes[fed..fed + n]);
                reader.notify_read(n);
                fed += n;
            }
            LinearReadEvent::Record { opcode, data } => out.push((opcode, data.to_vec())),
        }
    }
    assert_eq!(fed, bytes.len(), "the reader read the whole file");
    out
}

/// Checks one file against the mcap crate's reader; returns its messages in file order.
fn check_file(path: &Path, compression: Compression) -> Vec<Msg> {
    let bytes = std::fs::read(path).unwrap();
    let name = path.display();

    // The linear read: header first with profile ros2, then the data section.
    let records = records_checked(&bytes);
    match mcap::parse_record(records[0].0, &records[0].1).unwrap() {
        Record::Header(h) => assert_eq!(h.profile, "ros2", "{name}"),
        other => panic!("{name}: first record {other:?}"),
    }
    let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
    let mut linear = Vec::new();
    for (op, data) in &records {
        if let Record::Message { header, data } = mcap::parse_record(*op, data).unwrap() {
            let topic = summary.channels[&header.channel_id].topic.clone();
            linear.push((topic, header.sequence, header.log_time, header.publish_time, data.into_owned()));
        }
    }

    // Statistics against what is there.
    let stats = summary.stats.clone().expect("statistics");
    assert_eq!(stats.message_count, linear.len() as u64, "{name}");
    assert_eq!(stats.chunk_count as usize, summary.chunk_indexes.len(), "{name}");
    assert_eq!(stats.channel_count as usize, summary.channels.len(), "{name}");
    assert_eq!(stats.schema_count as usize, summary.schemas.len(), "{name}");
    if !linear.is_empty() {
        assert_eq!(stats.message_start_time, linear.iter().map(|m| m.2).min().unwrap(), "{name}");
        assert_eq!(stats.message_end_time, linear.iter().map(|m| m.2).max().unwrap(), "{name}");
    }
    let mut per_channel: BTreeMap<u16, u64> = BTreeMap::new();
    for m in &linear {
        let id = summary.channels.values().find(|c| c.topic == m.0).unwrap().id;
        *per_channel.entry(id).or_default() += 1;
    }
    assert_eq!(stats.channel_message_counts, per_channel, "{name}");
    for c in summary.channels.values() {
        assert_eq!(c.message_encoding, "cdr");
        let s = c.schema.as_ref().expect("a schema");
        assert_eq!(s.encoding, "ros2msg");
        assert!(c.metadata.contains_key("offered_qos_profiles"), "{name}: {}", c.topic);
    }

    // Chunk indexes, in file order; each chunk's messages and message indexes.
    let mut from_chunks = Vec::new();
    let mut last_end = 0;
    for ci in &summary.chunk_indexes {
        assert!(ci.chunk_start_offset >= last_end, "{name}: chunks in file order, not overlapping");
        last_end = ci.chunk_start_offset + ci.chunk_length + ci.message_index_length;
        let want = match compression {
            Compression::Zstd => "zstd",
            Compression::Lz4 => "lz4",
            Compression::None => "",
        };
        // A chunk compression did not shrink is stored uncompressed (doctor warns otherwise).
        let stored = ci.compression.is_empty() && ci.compressed_size == ci.uncompressed_size;
        assert!(ci.compression == want || stored, "{name}: chunk compression `{}`", ci.compression);
        assert!(ci.compression.is_empty() || ci.compressed_size < ci.uncompressed_size, "{name}: a compressed chunk is smaller");
        let msgs: Vec<_> = summary.stream_chunk(&bytes, ci).unwrap().map(|m| m.unwrap()).collect();
        assert!(!msgs.is_empty(), "{name}: no empty chunks");
        assert_eq!(ci.message_start_time, msgs.iter().map(|m| m.log_time).min().unwrap(), "{name}");
        assert_eq!(ci.message_end_time, msgs.iter().map(|m| m.log_time).max().unwrap(), "{name}");
        let indexes = summary.read_message_indexes(&bytes, ci).unwrap();
        assert_eq!(indexes.len(), ci.message_index_offsets.len(), "{name}");
        let indexed: usize = indexes.values().map(Vec::len).sum();
        assert_eq!(indexed, msgs.len(), "{name}: one index entry per message");
        for (channel, entries) in &indexes {
            assert!(entries.windows(2).all(|w| w[0].log_time <= w[1].log_time), "{name}: index in log-time order");
            // Every entry's offset points at a message of that channel and log time.
            for e in entries {
                let m = summary.seek_message(&bytes, ci, e).unwrap();
                assert_eq!(m.channel.id, channel.id, "{name}");
                assert_eq!(m.log_time, e.log_time, "{name}");
            }
        }
        for m in msgs {
            from_chunks.push((m.channel.topic.clone(), m.sequence, m.log_time, m.publish_time, m.data.into_owned()));
        }
    }
    assert_eq!(from_chunks, linear, "{name}: the chunk indexes reach every message, in file order");

    // Summary offsets: each names a group of records of its opcode, as the summary holds them.
    let footer = mcap::read::footer(&bytes).unwrap();
    assert!(footer.summary_start > 0 && footer.summary_offset_start > footer.summary_start, "{name}");
    let offsets = &bytes[footer.summary_offset_start as usize..bytes.len() - 8 - 29];
    let mut groups = Vec::new();
    for r in mcap::read::LinearReader::sans_magic(offsets) {
        match r.unwrap() {
            Record::SummaryOffset(o) => groups.push(o),
            other => panic!("{name}: {other:?} among the summary offsets"),
        }
    }
    let opcodes: Vec<u8> = groups.iter().map(|g| g.group_opcode).collect();
    let mut want_groups = vec![0x03, 0x04, 0x0B];
    if !summary.chunk_indexes.is_empty() {
        want_groups.push(0x08);
    }
    want_groups.push(0x0D);
    assert_eq!(opcodes, want_groups, "{name}: schemas, channels, statistics, chunk indexes, metadata indexes");
    // rosbag2's metadata record, as its MCAP plugin writes one: found through its index, its
    // `serialized_metadata` the bag's metadata.yaml fields (this file listed) and the distro.
    assert_eq!(stats.metadata_count, 1, "{name}");
    assert_eq!(summary.metadata_indexes.len(), 1, "{name}");
    let mi = &summary.metadata_indexes[0];
    assert_eq!(mi.name, "rosbag2", "{name}");
    let meta = mcap::read::metadata(&bytes, mi).unwrap();
    assert_eq!(meta.name, "rosbag2");
    let info: oilfilm_bag::metadata::BagInfo = serde_yaml_ng::from_str(&meta.metadata["serialized_metadata"]).unwrap();
    let file_name = path.file_name().unwrap().to_string_lossy().into_owned();
    assert_eq!(info.relative_file_paths.last(), Some(&file_name), "{name}: the bag so far, this file last");
    assert_eq!(info.files.last().map(|f| f.message_count), Some(linear.len() as u64), "{name}");
    assert_eq!(meta.metadata["ROS_DISTRO"], info.ros_distro, "{name}");
    for g in &groups {
        let slice = &bytes[g.group_start as usize..(g.group_start + g.group_length) as usize];
        let mut n = 0;
        for r in mcap::read::LinearReader::sans_magic(slice) {
            let kind = match r.unwrap() {
                Record::Schema { .. } => 0x03,
                Record::Channel(_) => 0x04,
                Record::Statistics(_) => 0x0B,
                Record::ChunkIndex(_) => 0x08,
                Record::MetadataIndex(_) => 0x0D,
                other => panic!("{name}: {other:?} in a summary group"),
            };
            assert_eq!(kind, g.group_opcode, "{name}: a record of another kind in group {:#04x}", g.group_opcode);
            n += 1;
        }
        let expected = match g.group_opcode {
            0x03 => summary.schemas.len(),
            0x04 => summary.channels.len(),
            0x0B | 0x0D => 1,
            _ => summary.chunk_indexes.len(),
        };
        assert_eq!(n, expected, "{name}: group {:#04x}", g.group_opcode);
    }
    linear
}

/// Checks every file of a bag; the messages, per topic, must be the published ones.
fn check_bag(dir: &Path, compression: Compression, want: &[Published]) -> Vec<Vec<u8>> {
    let bag = Bag::open(dir).unwrap();
    let mut got: Vec<Msg> = Vec::new();
    let mut files = Vec::new();
    for f in &bag.info().relative_file_paths {
        let path = dir.join(f);
        let msgs = check_file(&path, compression);
        // Each file numbers each topic's messages from 0, as rosbag2 does.
        let mut next: BTreeMap<&str, u32> = BTreeMap::new();
        for m in &msgs {
            let n = next.entry(&m.0).or_default();
            assert_eq!(m.1, *n, "{f}: sequence on {}", m.0);
            *n += 1;
        }
        got.extend(msgs);
        files.push(std::fs::read(&path).unwrap());
    }
    let mut topics: Vec<&str> = want.iter().map(|m| m.topic.as_str()).collect();
    topics.sort_unstable();
    topics.dedup();
    for topic in topics {
        let g: Vec<_> = got.iter().filter(|m| m.0 == topic).collect();
        let w: Vec<_> = want.iter().filter(|m| m.topic == topic).collect();
        assert_eq!(g.len(), w.len(), "{}: messages on {topic}", dir.display());
        for (i, (g, w)) in g.iter().zip(&w).enumerate() {
            assert_eq!((g.2, g.3), (w.log_time, w.log_time), "times of message {i} on {topic}");
            assert!(g.4 == w.data, "message {i} on {topic}: bytes differ");
        }
    }
    // Our own reader agrees.
    assert_eq!(bag.messages().unwrap().len(), want.len());
    files
}

#[test]
fn every_file_reads_in_the_mcap_crate_with_crcs_summary_and_indexes_checked() {
    let want = published();
    for compression in [Compression::Zstd, Compression::Lz4, Compression::None] {
        for per_topic in [true, false] {
            let mut written: Vec<(u32, Vec<Vec<u8>>)> = Vec::new();
            for workers in [0u32, 1, 3] {
                let name = format!("{compression:?}-{per_topic}-{workers}");
                // One bag name for all, so the file names (in rosbag2's metadata record too)
                // agree.
                let dir = tmp(&name).join("bag");
                let options = WriterOptions {
                    compression,
                    chunk_per_topic: per_topic,
                    compression_threads: workers,
                    chunk_size: 24 << 10,
                    split_duration_ns: Some(700_000_000),
                    ..WriterOptions::default()
                };
                sim_rig::write_bag(&dir, want, options).unwrap().close().unwrap();
                let files = check_bag(&dir, compression, want);
                assert!(files.len() >= 3, "{name}: split into {} files", files.len());
                written.push((workers, files));
            }
            // Chunks go to the file in the order they were closed, whoever compressed them:
            // the same bytes with any number of workers.
            for (workers, files) in &written[1..] {
                assert!(*files == written[0].1, "{compression:?}, per topic {per_topic}: {workers} workers wrote other bytes than 0");
            }
        }
    }
}

/// The crash bound with workers: a chunk handed to a worker reaches the file without the
/// writer being called again (a recorder killed then loses only the chunks being gathered).
#[test]
fn a_closed_chunk_reaches_the_file_while_the_writer_waits() {
    let frames: Vec<&Published> = published().iter().filter(|m| m.topic.ends_with("daq/frames")).take(6).collect();
    assert_eq!(frames.len(), 6);
    let dir = tmp("prompt");
    // A frame (40 kB) fills a chunk: each write closes one.
    let options = WriterOptions { compression_threads: 1, chunk_size: 8 << 10, ..WriterOptions::default() };
    let mut w = BagWriter::create(&dir, options).unwrap();
    let topic = w.add_topic(sim_rig::topic_spec(&oilfilm_graph::topics::DAQ_FRAMES)).unwrap();
    for m in &frames {
        w.write(topic, m.log_time, &m.data).unwrap();
    }
    let file = dir.join("prompt_0.mcap");
    let deadline = Instant::now() + Duration::from_secs(60);
    let scanned = loop {
        let s = oilfilm_bag::scan::scan(&std::fs::read(&file).unwrap());
        if s.messages.len() == frames.len() || Instant::now() > deadline {
            break s;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(scanned.chunks, frames.len(), "every closed chunk is in the file");
    assert_eq!(scanned.messages.len(), frames.len());
    for (m, want) in scanned.messages.iter().zip(&frames) {
        assert!(m.data == want.data && m.log_time == want.log_time);
    }
    assert!(!scanned.footer, "the file is still open");
    w.close().unwrap();
}

/// A chunk that compression does not shrink (bytes with no redundancy) is stored as it is,
/// named uncompressed in its header and index; compressible ones beside it stay compressed.
#[test]
fn a_chunk_compression_does_not_shrink_is_stored_uncompressed() {
    let frames: Vec<&Published> = published().iter().filter(|m| m.topic.ends_with("daq/frames")).take(2).collect();
    for (compression, name) in [(Compression::Zstd, "zstd"), (Compression::Lz4, "lz4")] {
        let dir = tmp(&format!("incompressible-{name}"));
        let mut w = BagWriter::create(&dir, WriterOptions { compression, ..WriterOptions::default() }).unwrap();
        let noise_topic = w.add_topic(sim_rig::topic_spec(&oilfilm_graph::topics::ESTIMATES)).unwrap();
        let frame_topic = w.add_topic(sim_rig::topic_spec(&oilfilm_graph::topics::DAQ_FRAMES)).unwrap();
        // xorshift bytes: incompressible for zstd and lz4.
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let noise: Vec<u8> = (0..300)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        w.write(noise_topic, frames[0].log_time, &noise).unwrap();
        for m in &frames {
            w.write(frame_topic, m.log_time, &m.data).unwrap();
        }
        w.close().unwrap();
        let file = dir.join(format!("incompressible-{name}_0.mcap"));
        let msgs = check_file(&file, compression);
        assert_eq!(msgs.len(), 3);
        let bytes = std::fs::read(&file).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let kinds: Vec<(String, &str)> = summary
            .chunk_indexes
            .iter()
            .map(|c| (summary.stream_chunk(&bytes, c).unwrap().next().unwrap().unwrap().channel.topic.clone(), c.compression.as_str()))
            .collect();
        assert_eq!(kinds.len(), 2, "{name}: {kinds:?}");
        for (topic, c) in &kinds {
            let want = if topic.ends_with("estimates") { "" } else { name };
            assert_eq!(*c, want, "{name}: the chunk of {topic}");
        }
    }
}
