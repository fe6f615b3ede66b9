//! Closed chunks compressed on worker threads and written to the file in the order they
//! were closed (ADR 0015).
//!
//! The writing thread gathers each chunk's message records and hands the closed chunk over
//! ([`Pipeline::submit_chunk`]); a worker compresses it (zstd or lz4; CRC of the records,
//! message index records) and whichever thread finds the next chunk in file order ready
//! writes it, and every ready one after it, to the file and hands it to the OS at once. So a
//! chunk reaches the file as soon as it and the chunks closed before it are compressed: a
//! killed writer loses only the chunks still being gathered or compressed, and the ones in
//! flight are bounded ([`Pipeline::new`]: the writing thread waits, it never queues more).
//! Records that need no compression (header, schemas, channels) take their turn in the same
//! order ([`Pipeline::submit_raw`]). With no workers the writing thread compresses and
//! writes each chunk itself, as it is closed.

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;

use crate::error::{io, BagError, Result};
use crate::records::{self, ChunkHeader, ChunkIndex};
use crate::writer::Compression;

/// A closed chunk as gathered: its message records back to back, and where each message is.
#[derive(Debug, Default)]
pub(crate) struct Gathered {
    pub records: Vec<u8>,
    /// Channel, log time and offset in `records` of each message, in the order written.
    pub index: Vec<(u16, u64, u64)>,
    pub start_ns: u64,
    pub end_ns: u64,
}

/// A chunk ready for the file: its record header, (compressed) records and message indexes.
struct Compressed {
    head: Vec<u8>,
    body: Vec<u8>,
    /// The message index records that follow the chunk.
    tail: Vec<u8>,
    /// Offset in `tail` of each channel's message index record.
    tail_offsets: Vec<(u16, u64)>,
    start_ns: u64,
    end_ns: u64,
    uncompressed_size: u64,
    /// The chunk's compression: the file's, or none when compressing did not shrink it.
    compression: &'static str,
    /// The uncompressed records' buffer, for reuse (when `body` is not that buffer).
    spare: Option<Vec<u8>>,
}

enum Item {
    Raw(Vec<u8>),
    Chunk(Compressed),
    /// A chunk whose compression failed (the error is recorded); keeps the order's place.
    Failed,
}

/// Compresses chunks: one per thread (a zstd context is reused chunk after chunk).
pub(crate) struct Codec {
    compression: Compression,
    level: i32,
    zstd: Option<zstd::bulk::Compressor<'static>>,
}

impl Codec {
    pub fn new(compression: Compression, level: i32) -> std::io::Result<Self> {
        let zstd = match compression {
            Compression::Zstd => Some(zstd::bulk::Compressor::new(level)?),
            Compression::Lz4 | Compression::None => None,
        };
        Ok(Self { compression, level, zstd })
    }

    fn name(&self) -> &'static str {
        match self.compression {
            Compression::Zstd => "zstd",
            Compression::Lz4 => "lz4",
            Compression::None => "",
        }
    }

    /// The chunk record's bytes for `g`, compressed into `out` (a recycled buffer).
    fn compress(&mut self, g: Gathered, mut out: Vec<u8>) -> std::io::Result<Compressed> {
        let crc = crc32fast::hash(&g.records);
        let uncompressed_size = g.records.len() as u64;
        out.clear();
        let compressed = match (self.compression, self.zstd.as_mut()) {
            // The records are the body: `out` goes back unused.
            (Compression::None, _) => None,
            (Compression::Zstd, z) => {
                let z = match z {
                    Some(z) => z,
                    None => return Err(std::io::Error::other("no zstd context (Codec::new makes one for zstd)")),
                };
                out.reserve(zstd::zstd_safe::compress_bound(g.records.len()));
                z.compress_to_buffer(&g.records, &mut out)?;
                Some(out)
            }
            (Compression::Lz4, _) => {
                let mut e = lz4::EncoderBuilder::new()
                    .level(self.level.max(0) as u32)
                    // As the mcap crate writes lz4 chunks: the chunk's own CRC covers the
                    // records, and some MCAP tools do not check lz4 block checksums right.
                    .block_checksum(lz4::liblz4::BlockChecksum::NoBlockChecksum)
                    .build(out)?;
                e.write_all(&g.records)?;
                let (out, result) = e.finish();
                result?;
                Some(out)
            }
        };
        // A chunk that compression does not shrink (a lone small message) is stored as it
        // is: MCAP names the compression per chunk, and `pymcap-cli doctor` warns about a
        // compressed chunk that is not smaller than its records.
        let (body, spare, compression) = match compressed {
            Some(c) if c.len() < g.records.len() => (c, Some(g.records), self.name()),
            Some(c) => (g.records, Some(c), ""),
            None => (g.records, None, ""),
        };
        let mut head = Vec::with_capacity(64);
        records::chunk_head(
            &mut head,
            &ChunkHeader { start_ns: g.start_ns, end_ns: g.end_ns, uncompressed_size, uncompressed_crc: crc, compression, compressed_size: body.len() as u64 },
        );
        // Message indexes by channel (a chunk per topic has one), each in log-time order.
        let mut by_channel: BTreeMap<u16, Vec<(u64, u64)>> = BTreeMap::new();
        for &(ch, t, offset) in &g.index {
            by_channel.entry(ch).or_default().push((t, offset));
        }
        let mut tail = Vec::with_capacity(by_channel.values().map(|v| 16 + v.len() * 16).sum());
        let mut tail_offsets = Vec::with_capacity(by_channel.len());
        for (ch, mut entries) in by_channel {
            if !entries.is_sorted_by_key(|e| e.0) {
                entries.sort_by_key(|e| e.0);
            }
            tail_offsets.push((ch, tail.len() as u64));
            records::message_index(&mut tail, ch, &entries);
        }
        Ok(Compressed { head, body, tail, tail_offsets, start_ns: g.start_ns, end_ns: g.end_ns, uncompressed_size, compression, spare })
    }
}

/// The open file: where its bytes go, their CRC, and the chunk indexes for its summary.
pub(crate) struct FileSink {
    path: PathBuf,
    out: BufWriter<File>,
    /// Bytes written so far.
    pos: u64,
    /// CRC of every byte so far: the data section's, until the data end record.
    crc: crc32fast::Hasher,
    pub chunk_indexes: Vec<ChunkIndex>,
}

impl FileSink {
    pub fn new(path: PathBuf, file: File) -> Self {
        Self { path, out: BufWriter::with_capacity(1 << 16, file), pos: 0, crc: crc32fast::Hasher::new(), chunk_indexes: Vec::new() }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn position(&self) -> u64 {
        self.pos
    }

    /// Writes `bytes` and adds them to the running CRC.
    pub fn put(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.out.write_all(bytes)?;
        self.crc.update(bytes);
        self.pos += bytes.len() as u64;
        Ok(())
    }

    /// The CRC of everything written so far; the running CRC starts again from here.
    pub fn take_crc(&mut self) -> u32 {
        std::mem::take(&mut self.crc).finalize()
    }

    fn write_chunk(&mut self, c: &Compressed) -> std::io::Result<()> {
        let chunk_start_offset = self.pos;
        self.put(&c.head)?;
        self.put(&c.body)?;
        let chunk_length = self.pos - chunk_start_offset;
        let index_start = self.pos;
        self.put(&c.tail)?;
        self.chunk_indexes.push(ChunkIndex {
            start_ns: c.start_ns,
            end_ns: c.end_ns,
            chunk_start_offset,
            chunk_length,
            message_index_offsets: c.tail_offsets.iter().map(|&(ch, o)| (ch, index_start + o)).collect(),
            message_index_length: c.tail.len() as u64,
            compression: c.compression,
            compressed_size: c.body.len() as u64,
            uncompressed_size: c.uncompressed_size,
        });
        Ok(())
    }

    /// Hands what is buffered to the OS.
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }

    /// Flushes and waits for the file's data to reach the disk.
    pub fn sync(mut self) -> std::io::Result<()> {
        self.out.flush()?;
        self.out.get_ref().sync_data()
    }
}

struct State {
    /// Closed chunks waiting for a worker, with their place in the order.
    queue: VecDeque<(u64, Gathered)>,
    /// Items ready for the file, by place.
    done: BTreeMap<u64, Item>,
    /// The place of the next item to write.
    next_write: u64,
    /// Items handed over and not yet written (queued, compressing, or ready).
    in_flight: usize,
    /// Uncompressed bytes of those items.
    in_flight_bytes: u64,
    /// The open file; `None` while a thread writes to it (`writing`) or when none is open.
    sink: Option<FileSink>,
    writing: bool,
    /// The open file's length when the writing thread took it: what [`Pipeline::file_len_bound`]
    /// counts while `sink` is away (the batch being written is still in `in_flight_bytes`).
    taken_len: u64,
    /// The open file's path, for errors.
    path: PathBuf,
    /// The first error, not yet reported to the writing thread.
    error: Option<BagError>,
    /// A write or compression failed: nothing more is written to this file.
    failed: bool,
    /// Buffers to reuse (gathering and compressing), at most `max_free`.
    free: Vec<Vec<u8>>,
    max_free: usize,
    stop: bool,
}

struct Shared {
    state: Mutex<State>,
    changed: Condvar,
}

/// The state lock. A thread that panicked while holding it (none of ours can: nothing under
/// the lock panics) would leave consistent data behind, so a poisoned lock is taken as is.
fn lock(shared: &Shared) -> MutexGuard<'_, State> {
    shared.state.lock().unwrap_or_else(|e| e.into_inner())
}

fn wait<'a>(shared: &'a Shared, st: MutexGuard<'a, State>) -> MutexGuard<'a, State> {
    shared.changed.wait(st).unwrap_or_else(|e| e.into_inner())
}

/// Writes the ready items that are next in file order, if no other thread is writing;
/// returns once none is (the thread writing picks up what becomes ready meanwhile).
fn drain<'a>(shared: &'a Shared, mut st: MutexGuard<'a, State>) -> MutexGuard<'a, State> {
    loop {
        if st.writing {
            return st;
        }
        let mut batch = Vec::new();
        loop {
            let next = st.next_write;
            let Some(item) = st.done.remove(&next) else { break };
            batch.push(item);
            st.next_write += 1;
        }
        if batch.is_empty() {
            return st;
        }
        let mut sink = st.sink.take();
        st.taken_len = sink.as_ref().map_or(0, FileSink::position);
        st.writing = true;
        let skip = st.failed;
        drop(st);
        let mut result = Ok(());
        let mut spare = Vec::new();
        let mut bytes = 0;
        let n = batch.len();
        for item in batch {
            match item {
                Item::Raw(b) => {
                    if !skip && result.is_ok() {
                        result = sink.as_mut().map_or(Ok(()), |s| s.put(&b));
                    }
                }
                Item::Chunk(c) => {
                    if !skip && result.is_ok() {
                        result = sink.as_mut().map_or(Ok(()), |s| s.write_chunk(&c));
                    }
                    bytes += c.uncompressed_size;
                    spare.push(c.body);
                    spare.extend(c.spare);
                }
                Item::Failed => {}
            }
        }
        if !skip && result.is_ok() {
            // To the OS now: a chunk handed over is on its way to the disk, not in a buffer.
            result = sink.as_mut().map_or(Ok(()), |s| s.flush());
        }
        st = lock(shared);
        st.sink = sink;
        st.writing = false;
        st.in_flight -= n;
        st.in_flight_bytes = st.in_flight_bytes.saturating_sub(bytes);
        if let Err(e) = result {
            let path = st.path.clone();
            fail(&mut st, io(path)(e));
        }
        for b in spare {
            if st.free.len() < st.max_free && b.capacity() > 0 {
                st.free.push(b);
            }
        }
        shared.changed.notify_all();
    }
}

/// [`Pipeline::file_len_bound`].
fn len_bound(shared: &Shared) -> u64 {
    let st = lock(shared);
    let written = match &st.sink {
        Some(sink) => sink.position(),
        None if st.writing => st.taken_len,
        None => 0,
    };
    written + st.in_flight_bytes
}

fn fail(st: &mut State, e: BagError) {
    if !st.failed {
        st.error = Some(e);
        st.failed = true;
    }
}

fn worker(shared: Arc<Shared>, mut codec: Codec) {
    let mut st = lock(&shared);
    loop {
        while st.queue.is_empty() && !st.stop {
            st = wait(&shared, st);
        }
        let Some((place, job)) = st.queue.pop_front() else { return };
        let out = st.free.pop().unwrap_or_default();
        drop(st);
        let result = codec.compress(job, out);
        st = lock(&shared);
        let item = match result {
            Ok(c) => Item::Chunk(c),
            Err(e) => {
                let path = st.path.clone();
                fail(&mut st, io(path)(e));
                Item::Failed
            }
        };
        st.done.insert(place, item);
        st = drain(&shared, st);
    }
}

/// The chunks between the writing thread and the file (see the module docs).
pub(crate) struct Pipeline {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
    /// Compresses on the writing thread when there are no workers.
    inline: Option<Codec>,
    max_in_flight: usize,
    /// The place of the next item handed over.
    next_place: u64,
}

impl Pipeline {
    /// `workers` threads compressing (0: the writing thread compresses). At most
    /// `2 * workers` chunks (1 without workers) are in flight; handing over another waits.
    pub fn new(compression: Compression, level: i32, workers: usize, dir: &Path) -> Result<Self> {
        let max_in_flight = (2 * workers).max(1);
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                queue: VecDeque::new(),
                done: BTreeMap::new(),
                next_write: 0,
                in_flight: 0,
                in_flight_bytes: 0,
                sink: None,
                writing: false,
                taken_len: 0,
                path: dir.to_path_buf(),
                error: None,
                failed: false,
                free: Vec::new(),
                max_free: 2 * max_in_flight + 2,
                stop: false,
            }),
            changed: Condvar::new(),
        });
        let mut p = Self { shared, workers: Vec::new(), inline: None, max_in_flight, next_place: 0 };
        if workers == 0 {
            p.inline = Some(Codec::new(compression, level).map_err(io(dir))?);
        }
        for i in 0..workers {
            let codec = Codec::new(compression, level).map_err(io(dir))?;
            let shared = Arc::clone(&p.shared);
            let handle = std::thread::Builder::new().name(format!("bag-compress-{i}")).spawn(move || worker(shared, codec)).map_err(io(dir))?;
            p.workers.push(handle);
        }
        Ok(p)
    }

    /// Makes `sink` the file the items go to. The previous file must be finished.
    pub fn start_file(&mut self, sink: FileSink) {
        let mut st = lock(&self.shared);
        st.path = sink.path().to_path_buf();
        st.sink = Some(sink);
        st.failed = false;
        st.error = None;
    }

    /// The first error not reported yet, or that the file failed earlier.
    fn check(st: &mut State) -> Result<()> {
        if let Some(e) = st.error.take() {
            return Err(e);
        }
        if st.failed {
            return Err(BagError::Usage { path: st.path.clone(), what: "an earlier write to this file failed (reported then); it takes no more".into() });
        }
        Ok(())
    }

    /// Waits until another item may be in flight; returns its place.
    fn reserve(&mut self, bytes: u64) -> Result<(MutexGuard<'_, State>, u64)> {
        let mut st = lock(&self.shared);
        while st.in_flight >= self.max_in_flight && !st.failed {
            st = wait(&self.shared, st);
        }
        Self::check(&mut st)?;
        st.in_flight += 1;
        st.in_flight_bytes += bytes;
        let place = self.next_place;
        self.next_place += 1;
        Ok((st, place))
    }

    /// Writes `bytes` (whole records) after everything handed over before.
    pub fn submit_raw(&mut self, bytes: Vec<u8>) -> Result<()> {
        let shared = Arc::clone(&self.shared);
        let (mut st, place) = self.reserve(0)?;
        st.done.insert(place, Item::Raw(bytes));
        let mut st = drain(&shared, st);
        Self::check(&mut st)
    }

    /// Hands a closed chunk over: compressed here (no workers) or on a worker, written
    /// after everything handed over before.
    pub fn submit_chunk(&mut self, chunk: Gathered) -> Result<()> {
        let shared = Arc::clone(&self.shared);
        let size = chunk.records.len() as u64;
        if self.inline.is_some() {
            let (st, place) = self.reserve(size)?;
            let out = {
                let mut st = st;
                st.free.pop().unwrap_or_default()
            };
            let result = self.inline.as_mut().map(|c| c.compress(chunk, out));
            let mut st = lock(&shared);
            let item = match result {
                Some(Ok(c)) => Item::Chunk(c),
                Some(Err(e)) => {
                    let path = st.path.clone();
                    fail(&mut st, io(path)(e));
                    Item::Failed
                }
                None => Item::Failed,
            };
            st.done.insert(place, item);
            let mut st = drain(&shared, st);
            return Self::check(&mut st);
        }
        let (mut st, place) = self.reserve(size)?;
        st.queue.push_back((place, chunk));
        shared.changed.notify_all();
        Ok(())
    }

    /// A buffer for gathering the next chunk (one that came back from an earlier chunk,
    /// so its pages are mapped already).
    pub fn take_buffer(&self) -> Vec<u8> {
        let mut b = lock(&self.shared).free.pop().unwrap_or_default();
        b.clear();
        b
    }

    /// Bytes written to the open file, plus the uncompressed size of the chunks on their
    /// way to it (an upper bound of what they will add). While a thread is writing, the
    /// file's length when it took the file (counting nothing then let a file grow past its
    /// split size by whatever was written meanwhile).
    pub fn file_len_bound(&self) -> u64 {
        len_bound(&self.shared)
    }

    /// Waits until everything handed over is written and returns the file (for its
    /// summary), or the first error.
    pub fn finish_file(&mut self) -> Result<FileSink> {
        let mut st = lock(&self.shared);
        while st.in_flight > 0 || st.writing {
            st = wait(&self.shared, st);
        }
        let sink = st.sink.take();
        Self::check(&mut st)?;
        sink.ok_or_else(|| BagError::Usage { path: st.path.clone(), what: "no file is open".into() })
    }
}

impl Drop for Pipeline {
    fn drop(&mut self) {
        lock(&self.shared).stop = true;
        self.shared.changed.notify_all();
        for w in self.workers.drain(..) {
            // A worker that panicked has nothing left to clean up; its panic was printed.
            let _ = w.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Handing over waits rather than queueing: with a slow compression (zstd level 19) and
    /// one worker, no more than 2 chunks are ever between being closed and being in the file,
    /// and the file gets every chunk, in the order handed over.
    #[test]
    fn at_most_twice_the_workers_chunks_are_in_flight_and_they_land_in_order() {
        let dir = std::env::temp_dir().join(format!("oilfilm-bag-chunks-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bounded.mcap");
        let mut p = Pipeline::new(Compression::Zstd, 19, 1, &dir).unwrap();
        p.start_file(FileSink::new(path.clone(), File::create(&path).unwrap()));
        let mut most = 0;
        for i in 0..10u64 {
            let records: Vec<u8> = (0..100_000u32).flat_map(|k| (k.wrapping_mul(2_654_435_761) >> 9).to_le_bytes()).collect();
            p.submit_chunk(Gathered { records, index: vec![(1, i, 0)], start_ns: i, end_ns: i }).unwrap();
            most = most.max(lock(&p.shared).in_flight);
        }
        let sink = p.finish_file().unwrap();
        assert!((1..=2).contains(&most), "{most} chunks in flight at most");
        let starts: Vec<u64> = sink.chunk_indexes.iter().map(|c| c.start_ns).collect();
        assert_eq!(starts, (0..10).collect::<Vec<_>>());
        assert!(sink.chunk_indexes.windows(2).all(|w| w[0].chunk_start_offset < w[1].chunk_start_offset));
        assert_eq!(std::fs::metadata(&path).unwrap().len(), sink.position());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The writer splits a file by [`Pipeline::file_len_bound`], so it must never fall below
    /// what is already in the file, also while a thread is writing (the file is out of the
    /// shared state then). Uncompressed chunks, so that a worker is writing most of the time,
    /// and a thread watching: the file's length on disk first, then the bound.
    #[test]
    fn the_file_length_bound_covers_the_file_while_chunks_are_written() {
        let dir = std::env::temp_dir().join(format!("oilfilm-bag-chunks-bound-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bound.mcap");
        let mut p = Pipeline::new(Compression::None, 0, 1, &dir).unwrap();
        p.start_file(FileSink::new(path.clone(), File::create(&path).unwrap()));
        let shared = Arc::clone(&p.shared);
        let done = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let watcher = {
            let (path, done) = (path.clone(), Arc::clone(&done));
            std::thread::spawn(move || {
                // (bound, length on disk just before) where the bound was short; observations.
                let (mut short, mut seen) = (None, 0u64);
                while !done.load(std::sync::atomic::Ordering::Relaxed) {
                    let on_disk = std::fs::metadata(&path).map_or(0, |m| m.len());
                    let bound = len_bound(&shared);
                    seen += 1;
                    // A chunk record is its records plus a header and message indexes of a
                    // few dozen bytes: the bound counts the records only.
                    if bound + 512 < on_disk && short.is_none() {
                        short = Some((bound, on_disk));
                    }
                }
                (short, seen)
            })
        };
        for i in 0..200u64 {
            let records = vec![i as u8; 256 << 10];
            p.submit_chunk(Gathered { records, index: vec![(1, i, 0)], start_ns: i, end_ns: i }).unwrap();
        }
        // Stopped before the file is taken back (it has no length in the state after that).
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        let (short, seen) = watcher.join().unwrap();
        let sink = p.finish_file().unwrap();
        assert!(seen > 100, "the watcher looked {seen} times");
        assert_eq!(short, None, "bound below the file's length (bound, length) over {seen} looks");
        assert_eq!(sink.chunk_indexes.len(), 200);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
