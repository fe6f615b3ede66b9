//! Reading checks what a bag says it holds against what is read: a file metadata.yaml does
//! not list, a damaged summary (chunk index) or chunk, and counts that differ are errors
//! naming the file and the difference; with `allow_partial` the read goes on and returns
//! each difference. Both readers (`read_topics`, the summary-driven one, and `messages`,
//! the record-by-record one) read the same messages and find the same differences.

use crate::scratch;
use crate::sim_rig;

use std::path::Path;
use std::sync::OnceLock;

use oilfilm_bag::{Bag, BagError, MessageRef, MetadataFile, ReadOptions, Shortfall, ShortfallKind, WriterOptions};
use sim_rig::Published;

fn published() -> &'static [Published] {
    static P: OnceLock<Vec<Published>> = OnceLock::new();
    P.get_or_init(|| sim_rig::published(&sim_rig::short_run(2.0)))
}

const FRAMES: &str = "/oilfilm/daq/frames";

fn inputs(_: &str, ty: &str) -> bool {
    ty == "oilfilm_msgs/msg/DaqFrame" || ty == "oilfilm_msgs/msg/RigStatus"
}

type Key = (String, u64, Vec<u8>);

/// What `read_topics_with` hands out for the inputs, and its shortfalls.
fn read(dir: &Path, options: ReadOptions) -> oilfilm_bag::Result<(Vec<Key>, Vec<Shortfall>)> {
    read_of(dir, options, &inputs)
}

fn read_of(dir: &Path, options: ReadOptions, wanted: &dyn Fn(&str, &str) -> bool) -> oilfilm_bag::Result<(Vec<Key>, Vec<Shortfall>)> {
    let bag = Bag::open(dir)?;
    let decode = |m: &MessageRef| Ok((m.topic.to_string(), m.log_time, m.data.to_vec()));
    bag.read_topics_with(options, wanted, &decode, 2, |it| it.collect())
}

/// What `messages_with` gives for the inputs, and its shortfalls.
fn read_whole(dir: &Path, options: ReadOptions) -> oilfilm_bag::Result<(Vec<Key>, Vec<Shortfall>)> {
    let (m, s) = Bag::open(dir)?.messages_with(options)?;
    Ok((m.into_iter().filter(|m| inputs(&m.topic, &m.type_name)).map(|m| (m.topic.to_string(), m.log_time, m.data)).collect(), s))
}

fn bag(name: &str, split: bool) -> scratch::Scratch {
    let dir = scratch::Scratch::new("oilfilm-bag-integrity", name);
    let options = WriterOptions { chunk_size: 24 << 10, split_duration_ns: split.then_some(700_000_000), ..WriterOptions::default() };
    sim_rig::write_bag(&dir, published(), options).unwrap().close().unwrap();
    dir
}

fn incomplete(e: BagError) -> String {
    assert!(matches!(e, BagError::Incomplete { .. }), "{e}");
    e.to_string()
}

#[test]
fn a_file_metadata_yaml_does_not_list_is_an_error_naming_it_or_left_out_and_said() {
    let dir = bag("unlisted", true);
    let every = |_: &str, _: &str| true;
    let (all, none) = read_of(&dir, ReadOptions::STRICT, &every).unwrap();
    assert!(none.is_empty());
    // metadata.yaml as the recorder left it at its last split before being killed: the
    // last file not listed, the counts those of the files before it.
    let meta_path = dir.join("metadata.yaml");
    let mut meta = MetadataFile::parse(&std::fs::read_to_string(&meta_path).unwrap()).unwrap();
    let info = &mut meta.rosbag2_bagfile_information;
    assert!(info.relative_file_paths.len() >= 3);
    let last = info.relative_file_paths.pop().unwrap();
    info.files.pop();
    let kept = Bag::open(&dir).unwrap().files()[..info.relative_file_paths.len()].to_vec();
    for t in &mut info.topics_with_message_count {
        t.message_count = kept
            .iter()
            .map(|f| {
                oilfilm_bag::reader::messages_of_file(f, &std::fs::read(f).unwrap()).unwrap().iter().filter(|m| *m.topic == t.topic_metadata.name).count()
                    as u64
            })
            .sum();
    }
    std::fs::write(&meta_path, meta.to_yaml()).unwrap();

    for e in [read(&dir, ReadOptions::STRICT).unwrap_err(), read_whole(&dir, ReadOptions::STRICT).unwrap_err()] {
        let e = incomplete(e);
        assert!(e.contains(&last) && e.contains("does not list") && e.contains("bag recover"), "{e}");
    }
    let (got, short) = read_of(&dir, ReadOptions::PARTIAL, &every).unwrap();
    assert_eq!(short.len(), 1, "{short:?}");
    assert_eq!((short[0].kind, short[0].path.file_name().unwrap().to_string_lossy().into_owned()), (ShortfallKind::UnlistedFile, last.clone()));
    assert!(
        got.len() < all.len() && all.starts_with(&got),
        "the listed files' messages, in order: {} of {}, first difference at {:?}",
        got.len(),
        all.len(),
        got.iter().zip(&all).position(|(a, b)| a != b)
    );
    let (whole, short_whole) = Bag::open(&dir).unwrap().messages_with(ReadOptions::PARTIAL).unwrap();
    assert_eq!(short_whole, short);
    assert_eq!(whole.into_iter().map(|m| (m.topic.to_string(), m.log_time, m.data)).collect::<Vec<_>>(), got);
}

#[test]
fn a_damaged_chunk_index_fails_the_summary_crc_and_the_partial_read_loses_nothing() {
    let dir = bag("index", false);
    let file = dir.join("index_0.mcap");
    let bytes = std::fs::read(&file).unwrap();
    let (all, _) = read(&dir, ReadOptions::STRICT).unwrap();
    // Two bytes of a chunk index changed: the chunk's offset now points elsewhere (the
    // change that made identify read 49 of 60 frames).
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let footer = mcap::read::footer(&bytes).unwrap();
    let chunk_indexes_at = (footer.summary_start as usize..bytes.len()).find(|&p| bytes[p] == 0x08).unwrap();
    let mut bad = bytes.clone();
    bad[chunk_indexes_at + 9 + 16] ^= 0x40;
    bad[chunk_indexes_at + 9 + 17] ^= 0x01;
    std::fs::write(&file, &bad).unwrap();
    assert!(!summary.chunk_indexes.is_empty());

    for e in [read(&dir, ReadOptions::STRICT).unwrap_err(), read_whole(&dir, ReadOptions::STRICT).unwrap_err()] {
        let e = e.to_string();
        assert!(e.contains("index_0.mcap") && e.contains("summary CRC"), "{e}");
    }
    let (got, short) = read(&dir, ReadOptions::PARTIAL).unwrap();
    assert_eq!(got, all, "read record by record, nothing is lost");
    assert_eq!(short.iter().map(|s| s.kind).collect::<Vec<_>>(), [ShortfallKind::SummaryCrc], "{short:?}");
    let (whole, short_whole) = read_whole(&dir, ReadOptions::PARTIAL).unwrap();
    assert_eq!(whole, all);
    assert_eq!(short_whole.len(), 1, "{short_whole:?}");
    assert!(short_whole[0].what.contains("summary CRC"), "{short_whole:?}");
}

#[test]
fn a_damaged_chunk_is_an_error_naming_its_offset_or_skipped_with_the_counts_said() {
    let dir = bag("chunk", false);
    let file = dir.join("chunk_0.mcap");
    let bytes = std::fs::read(&file).unwrap();
    let (all, _) = read(&dir, ReadOptions::STRICT).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let frames_id = summary.channels.values().find(|c| c.topic == FRAMES).unwrap().id;
    let ci = summary.chunk_indexes.iter().find(|c| c.message_index_offsets.contains_key(&frames_id)).unwrap().clone();
    let in_chunk: Vec<Key> =
        summary.stream_chunk(&bytes, &ci).unwrap().map(|m| m.unwrap()).map(|m| (m.channel.topic.clone(), m.log_time, m.data.into_owned())).collect();
    let mut bad = bytes.clone();
    bad[(ci.chunk_start_offset + ci.chunk_length - 20) as usize] ^= 0x04;
    std::fs::write(&file, &bad).unwrap();

    let e = read(&dir, ReadOptions::STRICT).unwrap_err().to_string();
    assert!(e.contains("chunk_0.mcap") && e.contains(&format!("at byte {}", ci.chunk_start_offset)), "{e}");
    let e = read_whole(&dir, ReadOptions::STRICT).unwrap_err().to_string();
    assert!(e.contains("chunk_0.mcap") && e.contains(&ci.chunk_start_offset.to_string()), "{e}");

    let (got, short) = read(&dir, ReadOptions::PARTIAL).unwrap();
    let want: Vec<Key> = all.iter().filter(|m| !in_chunk.contains(m)).cloned().collect();
    assert_eq!(got, want, "every message but the damaged chunk's");
    let kinds: Vec<ShortfallKind> = short.iter().map(|s| s.kind).collect();
    assert!(kinds.contains(&ShortfallKind::DamagedChunk), "{short:?}");
    let count = short.iter().find(|s| s.kind == ShortfallKind::Count && s.path.ends_with("metadata.yaml")).unwrap_or_else(|| panic!("{short:?}"));
    assert!(count.what.contains(FRAMES) && count.what.contains(&format!("{} missing", in_chunk.len())), "{count}");
    // The other reader reads the same messages.
    let (whole, short_whole) = read_whole(&dir, ReadOptions::PARTIAL).unwrap();
    assert_eq!(whole, got);
    assert!(short_whole.iter().any(|s| s.kind == ShortfallKind::DamagedChunk && s.what.contains(&ci.chunk_start_offset.to_string())), "{short_whole:?}");
}

#[test]
fn counts_that_differ_from_metadata_yaml_are_an_error_naming_the_topic() {
    let dir = bag("counts", false);
    let meta_path = dir.join("metadata.yaml");
    let text = std::fs::read_to_string(&meta_path).unwrap();
    let mut meta = MetadataFile::parse(&text).unwrap();
    let t = meta.rosbag2_bagfile_information.topics_with_message_count.iter_mut().find(|t| t.topic_metadata.name == FRAMES).unwrap();
    t.message_count += 1;
    std::fs::write(&meta_path, meta.to_yaml()).unwrap();
    for e in [read(&dir, ReadOptions::STRICT).unwrap_err(), read_whole(&dir, ReadOptions::STRICT).unwrap_err()] {
        let e = incomplete(e);
        assert!(e.contains("metadata.yaml") && e.contains(FRAMES) && e.contains("1 missing"), "{e}");
    }
    let (_, short) = read(&dir, ReadOptions::PARTIAL).unwrap();
    assert_eq!(short.len(), 1, "{short:?}");
    // A consumer that stops early is not told about counts it did not read.
    let bag = Bag::open(&dir).unwrap();
    let first = bag.read_topics(&inputs, &|m| Ok(m.log_time), 1, |it| it.next()).unwrap();
    assert!(first.is_some());
}
