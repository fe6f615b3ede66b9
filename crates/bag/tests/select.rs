//! `Bag::read_topics` (the summary-driven, multi-threaded reader behind `oilfilm identify
//! BAG`) gives exactly what `Bag::messages` gives for the same topics, in the same order, on
//! every kind of bag: one chunk series or a chunk per topic, zstd, lz4 or none, split files,
//! and files it cannot use the summary of (a recovered-then-cut file falls back to the full
//! reader's error).

use crate::sim_rig;

use std::path::PathBuf;
use std::sync::OnceLock;

use oilfilm_bag::{Bag, BagMessage, Compression, MessageRef, WriterOptions};
use sim_rig::Published;

fn published() -> &'static [Published] {
    static P: OnceLock<Vec<Published>> = OnceLock::new();
    P.get_or_init(|| sim_rig::published(&sim_rig::short_run(3.0)))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("oilfilm-bag-select-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d.join(name)
}

/// (topic, log time, bytes) of what `read_topics` hands out for `wanted`.
fn selected(bag: &Bag, wanted: &(dyn Fn(&str, &str) -> bool + Sync), threads: usize) -> oilfilm_bag::Result<Vec<(String, u64, Vec<u8>)>> {
    let decode = |m: &MessageRef| Ok((m.topic.to_string(), m.log_time, m.data.to_vec()));
    bag.read_topics(wanted, &decode, threads, |it| it.collect())
}

fn expected(all: &[BagMessage], wanted: &dyn Fn(&str, &str) -> bool) -> Vec<(String, u64, Vec<u8>)> {
    all.iter().filter(|m| wanted(&m.topic, &m.type_name)).map(|m| (m.topic.to_string(), m.log_time, m.data.clone())).collect()
}

#[test]
fn read_topics_equals_messages_filtered_on_every_kind_of_bag() {
    let want = published();
    let inputs = |_: &str, ty: &str| ty == "oilfilm_msgs/msg/DaqFrame" || ty == "oilfilm_msgs/msg/RigStatus";
    let status_only = |t: &str, _: &str| t.ends_with("rig/status");
    let everything = |_: &str, _: &str| true;
    let nothing = |_: &str, _: &str| false;
    let mut cases = Vec::new();
    for per_topic in [true, false] {
        for compression in [Compression::Zstd, Compression::Lz4, Compression::None] {
            cases.push((per_topic, compression, None, 1 << 20));
        }
        // Small chunks (many per topic) and files split every second.
        cases.push((per_topic, Compression::Zstd, Some(1_000_000_000), 48 << 10));
    }
    for (k, (per_topic, compression, split, chunk_size)) in cases.into_iter().enumerate() {
        let dir = tmp(&format!("case{k}"));
        let options = WriterOptions { compression, chunk_per_topic: per_topic, split_duration_ns: split, chunk_size, ..WriterOptions::default() };
        sim_rig::write_bag(&dir, want, options).unwrap().close().unwrap();
        let bag = Bag::open(&dir).unwrap();
        if split.is_some() {
            assert!(bag.files().len() >= 3, "case {k}: split into {} files", bag.files().len());
        }
        let all = bag.messages().unwrap();
        assert_eq!(all.len(), want.len());
        for (name, wanted) in [("inputs", &inputs as &(dyn Fn(&str, &str) -> bool + Sync)), ("status", &status_only), ("all", &everything), ("none", &nothing)]
        {
            let exp = expected(&all, wanted);
            for threads in [1, 2, 4] {
                let got = selected(&bag, wanted, threads).unwrap();
                assert_eq!(got.len(), exp.len(), "case {k} ({per_topic}, {compression:?}, split {split:?}) {name}, {threads} threads: count");
                assert!(got == exp, "case {k} ({per_topic}, {compression:?}, split {split:?}) {name}, {threads} threads: order or bytes differ");
            }
        }
        let _ = std::fs::remove_dir_all(dir.parent().unwrap());
    }
}

#[test]
fn a_chunk_per_topic_lets_the_reader_skip_the_others() {
    // The DAQ frames alone are a fraction of the bag: reading them must not decompress the
    // conditioned frames' chunks. Damage every chunk of the conditioned topic's channel:
    // the full reader refuses the file, read_topics for the inputs does not notice.
    let dir = tmp("skip");
    sim_rig::write_bag(&dir, published(), WriterOptions::default()).unwrap().close().unwrap();
    let bag = Bag::open(&dir).unwrap();
    let before = selected(&bag, &|_: &str, ty: &str| ty == "oilfilm_msgs/msg/DaqFrame", 2).unwrap();
    let file = bag.files()[0].clone();
    let bytes = std::fs::read(&file).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let conditioned = summary.channels.values().find(|c| c.topic.ends_with("conditioned")).unwrap().id;
    let mut damaged = bytes.clone();
    let mut hit = 0;
    for ci in &summary.chunk_indexes {
        if ci.message_index_offsets.keys().eq([conditioned].iter()) {
            // A byte in the middle of the compressed data.
            let at = (ci.chunk_start_offset + ci.chunk_length - ci.compressed_size / 2) as usize;
            damaged[at] ^= 0x55;
            hit += 1;
        }
    }
    assert!(hit >= 3, "{hit} chunks of the conditioned frames alone");
    std::fs::write(&file, &damaged).unwrap();
    assert!(bag.messages().is_err(), "the full reader checks every chunk");
    let after = selected(&bag, &|_: &str, ty: &str| ty == "oilfilm_msgs/msg/DaqFrame", 2).unwrap();
    assert!(after == before);
    let e = selected(&bag, &|t: &str, _: &str| t.ends_with("conditioned"), 2).unwrap_err().to_string();
    assert!(e.contains(&file.display().to_string()) && (e.contains("zstd") || e.contains("CRC")), "{e}");
    let _ = std::fs::remove_dir_all(dir.parent().unwrap());
}

#[test]
fn a_file_cut_short_gives_the_full_readers_error() {
    let dir = tmp("cut");
    sim_rig::write_bag(&dir, published(), WriterOptions::default()).unwrap().close().unwrap();
    let bag = Bag::open(&dir).unwrap();
    let file = bag.files()[0].clone();
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
    let e = selected(&bag, &|_: &str, _: &str| true, 2).unwrap_err().to_string();
    assert!(e.contains("oilfilm bag recover"), "{e}");
    let _ = std::fs::remove_dir_all(dir.parent().unwrap());
}
