//! The sans-IO core of reading: one MCAP file's bytes in, its schemas, channels and messages
//! out, with where and why reading stopped if it did not reach a clean end.
//!
//! Chunks are taken whole (the MCAP linear reader with `emit_chunks`), decompressed and
//! CRC-checked here, and their records kept only if the whole chunk is good: a file cut
//! mid-chunk (a killed writer) gives every message of every complete chunk and none of
//! the partial one, which is what recovery promises.

use std::collections::BTreeMap;
use std::io::Read;

use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaRecord {
    pub name: String,
    pub encoding: String,
    pub data: Vec<u8>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelRecord {
    pub topic: String,
    pub schema_id: u16,
    pub message_encoding: String,
    pub metadata: BTreeMap<String, String>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawMessage {
    pub channel_id: u16,
    pub sequence: u32,
    pub log_time: u64,
    pub publish_time: u64,
    pub data: Vec<u8>,
}

/// Why a scan stopped before a clean end of file, and where.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanStop {
    /// Bytes of the file read when the problem was found (the end of the record or chunk at
    /// fault, or the end of the file when it was cut short).
    pub offset: u64,
    pub what: String,
    /// The file ended early (truncated), rather than holding bad bytes.
    pub truncated: bool,
}

/// What one MCAP file holds, as far as it could be read.
#[derive(Debug, Clone, Default)]
pub struct ScannedFile {
    /// The header's profile, `None` if no header was read.
    pub profile: Option<String>,
    pub library: Option<String>,
    pub schemas: BTreeMap<u16, SchemaRecord>,
    pub channels: BTreeMap<u16, ChannelRecord>,
    /// In file order.
    pub messages: Vec<RawMessage>,
    /// Chunks read whole and kept.
    pub chunks: usize,
    /// The footer was read (the writer closed the file).
    pub footer: bool,
    /// `None` when the file was read to its end magic.
    pub stop: Option<ScanStop>,
}

/// Reads everything it can from one MCAP file's bytes. Never panics on bad input.
pub fn scan(bytes: &[u8]) -> ScannedFile {
    let mut out = ScannedFile::default();
    // No record can be longer than the file: a corrupt length must not make the reader
    // wait for (or allocate) more.
    let options = LinearReaderOptions::default()
        .with_emit_chunks(true)
        .with_record_length_limit(bytes.len().max(64));
    let mut reader = LinearReader::new_with_options(options);
    let mut fed = 0usize;
    let mut in_data_section = true;
    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(e) => e,
            Err(e) => {
                let truncated = fed >= bytes.len();
                out.stop = Some(ScanStop { offset: fed as u64, what: e.to_string(), truncated });
                return out;
            }
        };
        match event {
            LinearReadEvent::ReadRequest(want) => {
                let n = want.min(bytes.len() - fed);
                reader.insert(n).copy_from_slice(&bytes[fed..fed + n]);
                reader.notify_read(n);
                fed += n;
            }
            LinearReadEvent::Record { opcode, data } => {
                let record = match mcap::parse_record(opcode, data) {
                    Ok(r) => r,
                    Err(e) => {
                        out.stop = Some(ScanStop { offset: fed as u64, what: e.to_string(), truncated: false });
                        return out;
                    }
                };
                let result = match record {
                    Record::Header(h) => {
                        out.profile = Some(h.profile);
                        out.library = Some(h.library);
                        Ok(())
                    }
                    Record::Chunk { header, data } => read_chunk(&header, &data).and_then(|records| {
                        let mut staged = Staged::default();
                        for r in records {
                            staged.take(&out, r)?;
                        }
                        staged.commit(&mut out);
                        out.chunks += 1;
                        Ok(())
                    }),
                    Record::DataEnd(_) => {
                        in_data_section = false;
                        Ok(())
                    }
                    Record::Footer(_) => {
                        out.footer = true;
                        Ok(())
                    }
                    other if in_data_section => {
                        let mut staged = Staged::default();
                        staged.take(&out, Owned::from(other)).map(|()| staged.commit(&mut out))
                    }
                    // The summary repeats schemas and channels. The data section's copies
                    // outside chunks have no CRC, so a copy that differs is damage to one of
                    // them (a flipped byte in a type name would otherwise read as another type).
                    other => summary_agrees(&out, Owned::from(other)),
                };
                if let Err(what) = result {
                    out.stop = Some(ScanStop { offset: fed as u64, what, truncated: false });
                    return out;
                }
            }
        }
    }
    out
}

/// Whether a schema or channel repeated in the summary is the one the data section declared.
fn summary_agrees(file: &ScannedFile, r: Owned) -> Result<(), String> {
    match r {
        Owned::Schema(id, s) => match file.schemas.get(&id) {
            Some(old) if *old != s => Err(format!("schema {id} differs between the data section (`{}`) and the summary (`{}`): the file is damaged", old.name, s.name)),
            _ => Ok(()),
        },
        Owned::Channel(id, c) => match file.channels.get(&id) {
            Some(old) if *old != c => Err(format!("channel {id} differs between the data section (`{}`) and the summary (`{}`): the file is damaged", old.topic, c.topic)),
            _ => Ok(()),
        },
        _ => Ok(()),
    }
}

/// A record from inside a chunk, owned (its bytes were decompressed here).
enum Owned {
    Schema(u16, SchemaRecord),
    Channel(u16, ChannelRecord),
    Message(RawMessage),
    Other,
}

impl From<Record<'_>> for Owned {
    fn from(r: Record<'_>) -> Self {
        match r {
            Record::Schema { header, data } => Owned::Schema(
                header.id,
                SchemaRecord { name: header.name, encoding: header.encoding, data: data.into_owned() },
            ),
            Record::Channel(c) => Owned::Channel(
                c.id,
                ChannelRecord { topic: c.topic, schema_id: c.schema_id, message_encoding: c.message_encoding, metadata: c.metadata },
            ),
            Record::Message { header, data } => Owned::Message(RawMessage {
                channel_id: header.channel_id,
                sequence: header.sequence,
                log_time: header.log_time,
                publish_time: header.publish_time,
                data: data.into_owned(),
            }),
            _ => Owned::Other,
        }
    }
}

/// Records of one chunk, checked against what the file declared so far and kept only if
/// the whole chunk is good.
#[derive(Default)]
struct Staged {
    schemas: BTreeMap<u16, SchemaRecord>,
    channels: BTreeMap<u16, ChannelRecord>,
    messages: Vec<RawMessage>,
}

impl Staged {
    fn take(&mut self, file: &ScannedFile, r: Owned) -> Result<(), String> {
        match r {
            Owned::Schema(id, s) => {
                if id == 0 {
                    return Err(format!("schema `{}` has id 0, which MCAP reserves for no schema", s.name));
                }
                if let Some(old) = file.schemas.get(&id).or(self.schemas.get(&id)) {
                    if *old != s {
                        return Err(format!("schema id {id} is declared twice, differently (`{}`, `{}`)", old.name, s.name));
                    }
                }
                self.schemas.insert(id, s);
            }
            Owned::Channel(id, c) => {
                if c.schema_id != 0 && !file.schemas.contains_key(&c.schema_id) && !self.schemas.contains_key(&c.schema_id) {
                    return Err(format!("channel {id} (`{}`) names schema {}, which is not declared before it", c.topic, c.schema_id));
                }
                if let Some(old) = file.channels.get(&id).or(self.channels.get(&id)) {
                    if *old != c {
                        return Err(format!("channel id {id} is declared twice, differently (`{}`, `{}`)", old.topic, c.topic));
                    }
                }
                self.channels.insert(id, c);
            }
            Owned::Message(m) => {
                if !file.channels.contains_key(&m.channel_id) && !self.channels.contains_key(&m.channel_id) {
                    return Err(format!("a message (log time {} ns) is on channel {}, which is not declared before it", m.log_time, m.channel_id));
                }
                self.messages.push(m);
            }
            Owned::Other => {}
        }
        Ok(())
    }

    fn commit(self, file: &mut ScannedFile) {
        file.schemas.extend(self.schemas);
        file.channels.extend(self.channels);
        file.messages.extend(self.messages);
    }
}

/// Decompresses a chunk, checks its CRC and splits it into records.
fn read_chunk(header: &mcap::records::ChunkHeader, data: &[u8]) -> Result<Vec<Owned>, String> {
    let records = decompress_chunk(header, data)?;
    let mut out = Vec::new();
    let mut at = 0usize;
    while at < records.len() {
        let rest = &records[at..];
        if rest.len() < 9 {
            return Err(format!("a record header in the chunk is cut short at its byte {at}"));
        }
        let opcode = rest[0];
        let mut len_bytes = [0u8; 8];
        len_bytes.copy_from_slice(&rest[1..9]);
        let len = u64::from_le_bytes(len_bytes);
        let body_end = usize::try_from(len).ok().and_then(|l| l.checked_add(9)).filter(|&e| e <= rest.len());
        let Some(body_end) = body_end else {
            return Err(format!("a record in the chunk at its byte {at} claims {len} bytes, more than the chunk holds"));
        };
        let record = mcap::parse_record(opcode, &rest[9..body_end]).map_err(|e| format!("record in the chunk at its byte {at}: {e}"))?;
        out.push(Owned::from(record));
        at += body_end;
    }
    Ok(out)
}

/// A chunk's records: decompressed (zstd, lz4 or none), their size and CRC checked against
/// the chunk header.
pub(crate) fn decompress_chunk<'a>(header: &mcap::records::ChunkHeader, data: &'a [u8]) -> Result<std::borrow::Cow<'a, [u8]>, String> {
    use std::borrow::Cow;
    if header.compression.is_empty() {
        check_chunk(header, data)?;
        return Ok(Cow::Borrowed(data));
    }
    let mut out = Vec::new();
    decompress_into(header, data, &mut out, &mut None)?;
    Ok(Cow::Owned(out))
}

/// What one reader thread reuses from chunk to chunk: the buffer for a chunk's record as
/// read from the file, the buffer for its decompressed records and a zstd context. Without
/// them every chunk of a bag allocated two buffers of up to half a megabyte, which the
/// kernel handed out page by page (a page fault and a zeroed page each), and a context.
#[derive(Default)]
pub(crate) struct ChunkBuffers {
    pub(crate) record: Vec<u8>,
    pub(crate) records: Vec<u8>,
    pub(crate) zstd: Option<zstd::bulk::Decompressor<'static>>,
}

/// [`decompress_chunk`] into `out` (its contents replaced), with the zstd context kept in
/// `zstd` for the next chunk: the same checks, the same bytes.
pub(crate) fn decompress_chunk_reusing<'a>(
    header: &mcap::records::ChunkHeader,
    data: &'a [u8],
    out: &'a mut Vec<u8>,
    zstd: &mut Option<zstd::bulk::Decompressor<'static>>,
) -> Result<&'a [u8], String> {
    if header.compression.is_empty() {
        check_chunk(header, data)?;
        return Ok(data);
    }
    decompress_into(header, data, out, zstd)?;
    Ok(out)
}

/// A compressed chunk's records into `out`, checked.
fn decompress_into(header: &mcap::records::ChunkHeader, data: &[u8], out: &mut Vec<u8>, zstd: &mut Option<zstd::bulk::Decompressor<'static>>) -> Result<(), String> {
    /// Up to this size a zstd chunk is decompressed in one call into a buffer of at least the
    /// header's size (not touched beyond what the frame fills); a larger claim streams into
    /// a growing buffer instead of being trusted for an allocation.
    const BULK_MAX: u64 = 1 << 30;
    let size = header.uncompressed_size;
    out.clear();
    match header.compression.as_str() {
        "zstd" if size <= BULK_MAX => {
            let context = match zstd {
                Some(c) => c,
                None => zstd.insert(zstd::bulk::Decompressor::new().map_err(|e| format!("zstd chunk: {e}"))?),
            };
            // A frame longer than the buffer is an error; one longer than the header's size
            // but within a buffer left larger by an earlier chunk fails the size check below.
            out.reserve(size as usize);
            context.decompress_to_buffer(data, out).map_err(|e| format!("zstd chunk: {e}"))?;
        }
        "zstd" => {
            let d = zstd::stream::read::Decoder::new(data).map_err(|e| format!("zstd chunk: {e}"))?;
            read_limited(d, size, out).map_err(|e| format!("zstd chunk: {e}"))?;
        }
        "lz4" => {
            let d = lz4::Decoder::new(data).map_err(|e| format!("lz4 chunk: {e}"))?;
            read_limited(d, size, out).map_err(|e| format!("lz4 chunk: {e}"))?;
        }
        other => return Err(format!("chunk compression `{other}` is not zstd, lz4 or none")),
    }
    check_chunk(header, out)
}

/// A chunk's records against its header: their size, and their CRC when it is given.
fn check_chunk(header: &mcap::records::ChunkHeader, records: &[u8]) -> Result<(), String> {
    let size = header.uncompressed_size;
    if records.len() as u64 != size {
        return Err(format!("chunk holds {} bytes uncompressed, its header says {size}", records.len()));
    }
    if header.uncompressed_crc != 0 {
        let crc = crc32fast::hash(records);
        if crc != header.uncompressed_crc {
            return Err(format!("chunk CRC {crc:#010x} differs from its header's {:#010x}", header.uncompressed_crc));
        }
    }
    Ok(())
}

/// Reads at most `size` bytes (and one more, to notice a longer stream), growing the buffer
/// as data arrives rather than trusting the header's size for an allocation.
fn read_limited(r: impl Read, size: u64, out: &mut Vec<u8>) -> std::io::Result<()> {
    // Room for the claimed size up to 64 MiB (more than any chunk of ours) saves the copies
    // of growing the buffer; beyond that it grows as data arrives.
    out.reserve(size.min(64 << 20) as usize + 1);
    r.take(size.saturating_add(1)).read_to_end(out)?;
    Ok(())
}
