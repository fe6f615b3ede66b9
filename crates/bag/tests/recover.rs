//! `recover` past damage: a flipped bit anywhere in one chunk record (its opcode, length,
//! header, compressed bytes or CRC) loses that chunk alone, the reading resynchronising on
//! the next chunk; a damaged chunk before a cut (a killed writer) loses that chunk and the
//! cut one; a bag whose writer is alive is refused, and a killed writer's lock is cleared.

use crate::scratch;
use crate::sim_rig;

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;

use oilfilm_bag::{recording_state, recover, Bag, Compression, Recording, WriterOptions, LOCK_FILE};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sim_rig::Published;

fn published() -> &'static [Published] {
    static P: OnceLock<Vec<Published>> = OnceLock::new();
    P.get_or_init(|| sim_rig::published(&sim_rig::short_run(2.0)))
}

/// (topic, log time, bytes): a message as both sides can name it.
type Key = (String, u64, Vec<u8>);

/// A multiset of messages.
fn counted(msgs: impl IntoIterator<Item = Key>) -> BTreeMap<Key, usize> {
    let mut out = BTreeMap::new();
    for m in msgs {
        *out.entry(m).or_default() += 1;
    }
    out
}

/// Each chunk's (start, length) in its file and the messages it holds.
type Chunks = Vec<((u64, u64), Vec<Key>)>;

/// Each chunk of `bytes` (start, length) and its messages, as the mcap crate reads them.
fn chunks_of(bytes: &[u8]) -> Chunks {
    let summary = mcap::Summary::read(bytes).unwrap().unwrap();
    summary
        .chunk_indexes
        .iter()
        .map(|c| {
            let msgs =
                summary.stream_chunk(bytes, c).unwrap().map(|m| m.unwrap()).map(|m| (m.channel.topic.clone(), m.log_time, m.data.into_owned())).collect();
            ((c.chunk_start_offset, c.chunk_length), msgs)
        })
        .collect()
}

fn read_back(dir: &Path) -> BTreeMap<Key, usize> {
    counted(Bag::open(dir).unwrap().messages().unwrap().into_iter().map(|m| (m.topic.to_string(), m.log_time, m.data)))
}

/// A bag of one file in many small chunks; its bytes and chunks.
fn sound(dir: &Path, compression: Compression) -> (Vec<u8>, Chunks) {
    let options = WriterOptions { compression, chunk_size: 24 << 10, ..WriterOptions::default() };
    sim_rig::write_bag(dir, published(), options).unwrap().close().unwrap();
    let file = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).find(|p| p.extension().is_some_and(|x| x == "mcap")).unwrap();
    let bytes = std::fs::read(file).unwrap();
    let chunks = chunks_of(&bytes);
    assert!(chunks.len() >= 8, "{} chunks", chunks.len());
    (bytes, chunks)
}

#[test]
fn one_flipped_bit_in_one_chunk_loses_that_chunk_alone() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x0002_5b17_f11b);
    let mut lost_a_chunk = 0;
    let mut cases = 0;
    for (compression, name) in [(Compression::Zstd, "zstd"), (Compression::Lz4, "lz4"), (Compression::None, "none")] {
        let src = scratch::Scratch::new("oilfilm-bag-recover", &format!("src-{name}"));
        let (bytes, chunks) = sound(&src, compression);
        let all = counted(chunks.iter().flat_map(|(_, m)| m.clone()));
        let file_name = format!("src-{name}_0.mcap");
        for case in 0..12 {
            let k = rng.random_range(0..chunks.len());
            let ((start, len), in_chunk) = &chunks[k];
            // The first bytes (opcode, length, header fields) are the hard part: half the
            // cases flip there, the others anywhere in the chunk.
            let span = if case % 2 == 0 { 60.min(*len) } else { *len };
            let at = (*start + rng.random_range(0..span)) as usize;
            let bit = rng.random_range(0..8);
            let mut bad = bytes.clone();
            bad[at] ^= 1 << bit;
            let dir = scratch::Scratch::new("oilfilm-bag-recover", &format!("{name}-{case}"));
            std::fs::create_dir_all(&*dir).unwrap();
            std::fs::write(dir.join(&file_name), &bad).unwrap();
            std::fs::copy(src.join("metadata.yaml"), dir.join("metadata.yaml")).unwrap();
            let what = format!("{name}: bit {bit} of byte {at} (chunk {k} of {}, at {start}, {len} bytes)", chunks.len());

            let r = recover(&dir).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert!(!r.files[0].damage.is_empty(), "{what}: the damage is found");
            let got = read_back(&dir);
            // Nothing but what was written, and everything outside the flipped chunk.
            let mut want = all.clone();
            for m in in_chunk {
                if let Some(n) = want.get_mut(m) {
                    *n -= 1;
                }
            }
            want.retain(|_, n| *n > 0);
            for (m, n) in &got {
                assert!(all.get(m).is_some_and(|a| a >= n), "{what}: a message that was never written ({} at {})", m.0, m.1);
            }
            for (m, n) in &want {
                assert!(got.get(m).is_some_and(|g| g >= n), "{what}: lost {} at {} from an intact chunk", m.0, m.1);
            }
            let lost: usize = all.values().sum::<usize>() - got.values().sum::<usize>();
            assert!(lost == 0 || lost == in_chunk.len(), "{what}: lost {lost} messages, the chunk held {}", in_chunk.len());
            lost_a_chunk += usize::from(lost > 0);
            cases += 1;
            // The rewritten bag is sound: reading it strictly finds no damage.
            assert_eq!(recover(&dir).unwrap().files[0].stop, None, "{what}: recovered twice");
        }
    }
    // A flip in a chunk's time range is covered by no CRC but the data section's: the
    // messages survive. Most flips hit the compressed records or the CRC.
    eprintln!("{cases} flips: {lost_a_chunk} lost their chunk, {} lost nothing", cases - lost_a_chunk);
    assert!(lost_a_chunk * 2 > cases, "most flips must cost their chunk: {lost_a_chunk} of {cases}");
}

#[test]
fn a_damaged_chunk_before_the_cut_of_a_killed_writer_costs_that_chunk_and_the_cut_one() {
    let dir = scratch::Scratch::new("oilfilm-bag-recover", "killed");
    let (bytes, chunks) = sound(&dir, Compression::Zstd);
    let file = dir.join("killed_0.mcap");
    let (damaged, cut) = (2, chunks.len() / 2);
    let ((start, len), _) = chunks[damaged];
    let ((cut_start, cut_len), _) = chunks[cut];
    let mut bad = bytes[..(cut_start + cut_len / 2) as usize].to_vec();
    bad[(start + len / 2) as usize] ^= 0x10;
    std::fs::write(&file, &bad).unwrap();
    std::fs::remove_file(dir.join("metadata.yaml")).unwrap();

    let r = recover(&dir).unwrap();
    let f = &r.files[0];
    assert_eq!(f.chunks, cut - 1, "every chunk before the cut but the damaged one");
    assert_eq!(f.damage.len(), 1, "{:?}", f.damage);
    assert_eq!(f.damage[0].offset, start, "the damage names the chunk's offset");
    assert!(f.damage[0].what.contains("CRC") || f.damage[0].what.contains("zstd"), "{}", f.damage[0].what);
    assert!(f.stop.as_ref().is_some_and(|s| !s.truncated && s.offset == start), "{:?}", f.stop);
    let want = counted(chunks[..cut].iter().enumerate().filter(|(i, _)| *i != damaged).flat_map(|(_, (_, m))| m.clone()));
    assert_eq!(read_back(&dir), want);
    assert_eq!(r.metadata.rosbag2_bagfile_information.message_count, want.values().sum::<usize>() as u64);
}

#[test]
fn a_bag_being_recorded_is_refused_and_a_killed_writers_lock_is_cleared() {
    let dir = scratch::Scratch::new("oilfilm-bag-recover", "live");
    let msgs = published();
    let w = sim_rig::write_bag(&dir, &msgs[..msgs.len() / 2], WriterOptions { chunk_size: 16 << 10, ..WriterOptions::default() }).unwrap();
    let lock = dir.join(LOCK_FILE);
    let text = std::fs::read_to_string(&lock).unwrap();
    assert!(text.contains(&format!("pid {}", std::process::id())), "{text}");
    assert!(matches!(recording_state(&dir).unwrap(), Recording::Alive { .. }));
    let before: Vec<_> = std::fs::read_dir(&*dir).unwrap().map(|e| e.unwrap().path()).collect();
    let e = recover(&dir).unwrap_err().to_string();
    assert!(e.contains("still being recorded") && e.contains(&format!("pid {}", std::process::id())), "{e}");
    let after: Vec<_> = std::fs::read_dir(&*dir).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(before, after, "nothing moved under the writer");
    w.close().unwrap();
    assert!(!lock.exists(), "a closed bag has no lock file");
    assert_eq!(recording_state(&dir).unwrap(), Recording::None);

    // What a killed writer leaves: the lock file, held by nobody.
    std::fs::write(&lock, "pid 4000000\nhost elsewhere\n").unwrap();
    assert_eq!(recording_state(&dir).unwrap(), Recording::Stale);
    recover(&dir).unwrap();
    assert!(!lock.exists(), "recovery clears a stale lock");
}
