//! The sans-IO core of reading: one MCAP file's bytes in, its schemas, channels and messages
//! out, with every place the file is damaged and where reading went on after it.
//!
//! The records are framed here (opcode, length, body) rather than by the mcap crate's
//! linear reader, which stops at the first bad record: a chunk whose CRC, compression or
//! records are bad, or any record that does not parse, is skipped, and reading
//! **resynchronises** on the next record that proves itself (a chunk whose records match
//! its CRC, a schema or channel that parses, the data end or the footer; [`resync`]). So one
//! flipped bit in a chunk loses that chunk alone, and a length field gone wrong loses only
//! the bytes up to the next good record. A chunk is kept only whole, so a file cut
//! mid-chunk (a killed writer) gives every message of every complete chunk and none of the
//! partial one, which is what recovery promises.
//!
//! The data section's CRC (in the data end record) and the summary's (in the footer) are
//! checked too: a flipped bit in a place no chunk CRC covers (a chunk's time range, a
//! message index, the summary) is found and reported, though no message is lost to it.

use std::collections::BTreeMap;
use std::io::Read;

use mcap::records::Record;

use crate::records::{op, MAGIC};

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

/// Why a scan did not reach a clean end of file, and where: the first problem found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanStop {
    /// Byte offset of the record at fault (or of the end of the file when it was cut short).
    pub offset: u64,
    pub what: String,
    /// The file ended early (truncated), rather than holding bad bytes.
    pub truncated: bool,
}

/// Bad bytes found and skipped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Damage {
    /// Byte offset of the record at fault.
    pub offset: u64,
    /// What is wrong.
    pub what: String,
    /// Where reading went on: the next record that proved itself, `None` if nothing after
    /// the damage could be read (or nothing was skipped: `crc_only`).
    pub resumed_at: Option<u64>,
    /// Messages lost with it are not known in general (a damaged chunk's count is in bytes
    /// that cannot be trusted); the time range of a skipped chunk when its header parsed.
    pub log_times: Option<(u64, u64)>,
    /// A CRC over bytes no message is read from failed (the data section's, the summary's):
    /// nothing was skipped.
    pub crc_only: bool,
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
    /// Every damaged place, in file order.
    pub damage: Vec<Damage>,
    /// Where the file ends early (mid-record, or with no footer): a writer killed or still
    /// writing.
    pub truncated_at: Option<u64>,
    /// `None` when the file was read to its end magic with no damage; else the first problem.
    pub stop: Option<ScanStop>,
}

impl ScannedFile {
    fn damaged(&mut self, offset: usize, what: String, resumed_at: Option<usize>, log_times: Option<(u64, u64)>) {
        if self.stop.is_none() {
            self.stop = Some(ScanStop { offset: offset as u64, what: what.clone(), truncated: false });
        }
        self.damage.push(Damage { offset: offset as u64, what, resumed_at: resumed_at.map(|p| p as u64), log_times, crc_only: false });
    }

    fn crc_failed(&mut self, offset: usize, what: String) {
        self.damaged(offset, what, None, None);
        if let Some(d) = self.damage.last_mut() {
            d.crc_only = true;
            d.resumed_at = None;
        }
    }

    fn cut_short(&mut self, offset: usize, what: String) {
        self.truncated_at = Some(offset as u64);
        if self.stop.is_none() {
            self.stop = Some(ScanStop { offset: offset as u64, what, truncated: true });
        }
    }
}

/// Where the scanner is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Section {
    Data,
    Summary,
}

/// What a record did to the scan.
enum Step {
    Next,
    /// The footer and the closing magic: the end.
    End,
}

/// `u64` little-endian at `at` (the caller checked 8 bytes are there).
fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(b)
}

/// The end of the record starting at `at` (opcode, length, body), if it lies in the file.
fn record_end(bytes: &[u8], at: usize) -> Option<usize> {
    if bytes.len().saturating_sub(at) < 9 {
        return None;
    }
    let len = u64_at(bytes, at + 1);
    usize::try_from(len).ok().and_then(|l| l.checked_add(at + 9)).filter(|&e| e <= bytes.len())
}

/// Reads everything it can from one MCAP file's bytes. Never panics on bad input, and
/// never allocates more than the file's size plus what its chunks decompress to (each
/// checked against its header's size and CRC).
pub fn scan(bytes: &[u8]) -> ScannedFile {
    let mut out = ScannedFile::default();
    if bytes.len() < MAGIC.len() || bytes[..MAGIC.len()] != *MAGIC {
        if MAGIC.starts_with(bytes) {
            out.cut_short(bytes.len(), "the file ends inside the MCAP magic".into());
        } else {
            out.damaged(0, "not an MCAP file (no MCAP magic at its start)".into(), None, None);
        }
        return out;
    }
    let mut pos = MAGIC.len();
    let mut section = Section::Data;
    let mut summary_start = None;
    loop {
        if pos == bytes.len() {
            out.cut_short(pos, format!("the file ends after {} complete chunks without a footer", out.chunks));
            break;
        }
        let Some(end) = record_end(bytes, pos) else {
            // Cut short by a killed writer, or a length field gone wrong.
            let what = if bytes.len() - pos < 9 {
                format!("the file ends inside a record header at byte {pos}")
            } else {
                format!("a record (opcode {:#04x}) at byte {pos} claims {} bytes, more than the file holds", bytes[pos], u64_at(bytes, pos + 1))
            };
            match resync(bytes, pos + 1, &out) {
                Some(next) => {
                    out.damaged(pos, what, Some(next), None);
                    pos = next;
                    continue;
                }
                None => {
                    out.cut_short(pos, what);
                    break;
                }
            }
        };
        match record(bytes, pos, end, &mut section, &mut summary_start, &mut out) {
            Ok(Step::Next) => pos = end,
            Ok(Step::End) => break,
            Err((what, log_times)) => match resync(bytes, pos + 1, &out) {
                Some(next) => {
                    out.damaged(pos, what, Some(next), log_times);
                    pos = next;
                }
                None => {
                    out.damaged(pos, what, None, log_times);
                    if !out.footer {
                        out.truncated_at.get_or_insert(bytes.len() as u64);
                    }
                    break;
                }
            },
        }
    }
    out
}

/// One record (the bytes `at..end`): taken into `out`, or an error and, for a chunk whose
/// header parsed, its time range.
fn record(
    bytes: &[u8],
    at: usize,
    end: usize,
    section: &mut Section,
    summary_start: &mut Option<usize>,
    out: &mut ScannedFile,
) -> Result<Step, (String, Option<(u64, u64)>)> {
    let opcode = bytes[at];
    let body = &bytes[at + 9..end];
    let plain = |what: String| (what, None);
    if at == MAGIC.len() {
        if opcode != op::HEADER {
            return Err(plain("the first record is not an MCAP header".into()));
        }
        return match mcap::parse_record(opcode, body) {
            Ok(Record::Header(h)) => {
                out.profile = Some(h.profile);
                out.library = Some(h.library);
                Ok(Step::Next)
            }
            Ok(_) | Err(_) => Err(plain("the MCAP header record does not parse".into())),
        };
    }
    match (opcode, *section) {
        (op::HEADER, _) => Err(plain("a second header record".into())),
        (op::FOOTER, _) => {
            if body.len() != 20 || end + MAGIC.len() != bytes.len() || bytes[end..] != *MAGIC {
                return Err(plain("a footer record that is not followed by the closing magic at the end of the file".into()));
            }
            let start = summary_start.unwrap_or(at);
            let saved = u32::from_le_bytes([body[16], body[17], body[18], body[19]]);
            if saved != 0 {
                let calculated = crc32fast::hash(&bytes[start..at + 9 + 16]);
                if calculated != saved {
                    out.crc_failed(start, summary_crc_text(calculated, saved));
                }
            }
            out.footer = true;
            Ok(Step::End)
        }
        (op::DATA_END, Section::Data) => {
            if body.len() != 4 {
                return Err(plain(format!("a data end record of {} bytes (4 expected)", body.len())));
            }
            let saved = u32::from_le_bytes([body[0], body[1], body[2], body[3]]);
            if saved != 0 {
                let calculated = crc32fast::hash(&bytes[..at]);
                if calculated != saved {
                    out.crc_failed(at, format!("data section CRC {calculated:#010x} differs from the data end record's {saved:#010x}: bytes no chunk CRC covers changed (a chunk's time range, a message index)"));
                }
            }
            *section = Section::Summary;
            *summary_start = Some(end);
            Ok(Step::Next)
        }
        (op::CHUNK, Section::Data) => {
            let (header, data) = match mcap::parse_record(op::CHUNK, body) {
                Ok(Record::Chunk { header, data }) => (header, data),
                _ => return Err(plain("a chunk record whose header does not parse".into())),
            };
            let times = Some((header.message_start_time, header.message_end_time));
            let records = read_chunk(&header, &data).map_err(|e| (format!("chunk: {e}"), times))?;
            let mut staged = Staged::default();
            for r in records {
                staged.take(out, r).map_err(|e| (format!("chunk: {e}"), times))?;
            }
            staged.commit(out);
            out.chunks += 1;
            Ok(Step::Next)
        }
        (op::SCHEMA | op::CHANNEL | op::MESSAGE, Section::Data) => {
            let r = mcap::parse_record(opcode, body).map_err(|e| plain(format!("record does not parse: {e}")))?;
            let mut staged = Staged::default();
            staged.take(out, Owned::from(r)).map_err(plain)?;
            staged.commit(out);
            Ok(Step::Next)
        }
        // The summary repeats schemas and channels. The data section's copies outside chunks
        // have no CRC, so a copy that differs is damage to one of them (a flipped byte in a
        // type name would otherwise read as another type).
        (op::SCHEMA | op::CHANNEL, Section::Summary) => {
            let r = mcap::parse_record(opcode, body).map_err(|e| plain(format!("record (opcode {opcode:#04x}) does not parse: {e}")))?;
            summary_agrees(out, Owned::from(r)).map_err(plain)?;
            Ok(Step::Next)
        }
        // Indexes and records no reader here uses: they must parse, nothing more.
        (op::MESSAGE_INDEX | op::ATTACHMENT | op::METADATA, Section::Data)
        | (op::CHUNK_INDEX | op::ATTACHMENT_INDEX | op::METADATA_INDEX | op::STATISTICS | op::SUMMARY_OFFSET, Section::Summary) => {
            mcap::parse_record(opcode, body).map_err(|e| plain(format!("record (opcode {opcode:#04x}) does not parse: {e}")))?;
            Ok(Step::Next)
        }
        (_, Section::Data) => Err(plain(format!("a record with opcode {opcode:#04x}, which does not belong in the data section"))),
        (_, Section::Summary) => Err(plain(format!("a record with opcode {opcode:#04x}, which does not belong in the summary section"))),
    }
}

/// Whether a schema or channel repeated in the summary is the one the data section declared.
fn summary_agrees(file: &ScannedFile, r: Owned) -> Result<(), String> {
    match r {
        Owned::Schema(id, s) => match file.schemas.get(&id) {
            Some(old) if *old != s => {
                Err(format!("schema {id} differs between the data section (`{}`) and the summary (`{}`): the file is damaged", old.name, s.name))
            }
            _ => Ok(()),
        },
        Owned::Channel(id, c) => match file.channels.get(&id) {
            Some(old) if *old != c => {
                Err(format!("channel {id} differs between the data section (`{}`) and the summary (`{}`): the file is damaged", old.topic, c.topic))
            }
            _ => Ok(()),
        },
        _ => Ok(()),
    }
}

/// What a summary CRC mismatch is called, by every reader.
pub(crate) fn summary_crc_text(calculated: u32, saved: u32) -> String {
    format!("summary CRC {calculated:#010x} differs from the footer's {saved:#010x}: the summary (the chunk index) is damaged")
}

/// The first offset from `from` on where a record starts that proves itself: a chunk whose
/// records decompress to its CRC, a schema or channel that parses (and fits what `file`
/// declared), a data end record followed by a summary record, or the footer at the end of
/// the file. A chunk with a zero CRC (none given) must parse record by record instead.
/// Message, message index and other records are not trusted as landing places: a damaged
/// chunk's bytes can look like them, and the next chunk is what matters.
pub(crate) fn resync(bytes: &[u8], from: usize, file: &ScannedFile) -> Option<usize> {
    let n = bytes.len();
    (from..n.saturating_sub(8)).find(|&p| {
        let opcode = bytes[p];
        if !matches!(opcode, op::CHUNK | op::SCHEMA | op::CHANNEL | op::DATA_END | op::FOOTER) {
            return false;
        }
        let Some(end) = record_end(bytes, p) else { return false };
        let body = &bytes[p + 9..end];
        match opcode {
            op::FOOTER => body.len() == 20 && end + MAGIC.len() == n && bytes[end..] == *MAGIC,
            op::DATA_END => {
                body.len() == 4
                    && record_end(bytes, end).is_some_and(|_| {
                        matches!(
                            bytes[end],
                            op::SCHEMA
                                | op::CHANNEL
                                | op::STATISTICS
                                | op::CHUNK_INDEX
                                | op::METADATA_INDEX
                                | op::ATTACHMENT_INDEX
                                | op::SUMMARY_OFFSET
                                | op::FOOTER
                        )
                    })
            }
            op::CHUNK => match mcap::parse_record(op::CHUNK, body) {
                // The CRC proves the records; without one they must parse.
                Ok(Record::Chunk { header, data }) if header.uncompressed_crc != 0 => decompress_chunk(&header, &data).is_ok(),
                Ok(Record::Chunk { header, data }) => read_chunk(&header, &data).is_ok_and(|r| !r.is_empty()),
                _ => false,
            },
            _ => match mcap::parse_record(opcode, body) {
                Ok(Record::Schema { header, .. }) => header.id != 0 && !header.name.is_empty() && !header.encoding.is_empty(),
                Ok(Record::Channel(c)) => {
                    !c.topic.is_empty() && !c.message_encoding.is_empty() && (c.schema_id == 0 || file.schemas.contains_key(&c.schema_id))
                }
                _ => false,
            },
        }
    })
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
            Record::Schema { header, data } => Owned::Schema(header.id, SchemaRecord { name: header.name, encoding: header.encoding, data: data.into_owned() }),
            Record::Channel(c) => {
                Owned::Channel(c.id, ChannelRecord { topic: c.topic, schema_id: c.schema_id, message_encoding: c.message_encoding, metadata: c.metadata })
            }
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
fn decompress_into(
    header: &mcap::records::ChunkHeader,
    data: &[u8],
    out: &mut Vec<u8>,
    zstd: &mut Option<zstd::bulk::Decompressor<'static>>,
) -> Result<(), String> {
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
