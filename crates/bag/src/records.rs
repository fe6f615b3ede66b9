//! MCAP records as bytes, for the writer (sans-IO: each function appends one record to a
//! buffer). Layouts from the MCAP specification (mcap.dev/spec): a record is an opcode byte,
//! a `u64` length and its fields, little-endian; a string is a `u32` byte length and UTF-8;
//! a map or array is a `u32` byte length and its entries. The mcap crate reads what these
//! write in the round-trip tests (`tests/writer_records.rs`), CRCs and indexes checked.

use std::collections::BTreeMap;

/// The magic at both ends of an MCAP file.
pub(crate) const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

pub(crate) mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const ATTACHMENT: u8 = 0x09;
    pub const ATTACHMENT_INDEX: u8 = 0x0A;
    pub const STATISTICS: u8 = 0x0B;
    pub const METADATA: u8 = 0x0C;
    pub const METADATA_INDEX: u8 = 0x0D;
    pub const SUMMARY_OFFSET: u8 = 0x0E;
    pub const DATA_END: u8 = 0x0F;
}

fn u16le(b: &mut Vec<u8>, v: u16) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn u32le(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn u64le(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}

/// A length as the `u32` prefix of a string, map or array. Our strings and maps are topic
/// names, schema texts and QoS YAML, far below 4 GiB; a longer one is refused by the caller
/// ([`fits_u32`]) before it gets here, so the cast cannot truncate.
fn len32(b: &mut Vec<u8>, n: usize) {
    u32le(b, n as u32);
}

/// `true` when `n` bytes can be an MCAP string, map or schema data length.
pub(crate) fn fits_u32(n: usize) -> bool {
    u32::try_from(n).is_ok()
}

fn string(b: &mut Vec<u8>, s: &str) {
    len32(b, s.len());
    b.extend_from_slice(s.as_bytes());
}

/// A record: opcode, length, then what `body` appends.
fn record(b: &mut Vec<u8>, opcode: u8, body: impl FnOnce(&mut Vec<u8>)) {
    b.push(opcode);
    let len_at = b.len();
    u64le(b, 0);
    let start = b.len();
    body(b);
    let len = (b.len() - start) as u64;
    b[len_at..len_at + 8].copy_from_slice(&len.to_le_bytes());
}

/// A map or array: its byte length, then what `entries` appends.
fn prefixed(b: &mut Vec<u8>, entries: impl FnOnce(&mut Vec<u8>)) {
    let len_at = b.len();
    u32le(b, 0);
    let start = b.len();
    entries(b);
    let len = (b.len() - start) as u32;
    b[len_at..len_at + 4].copy_from_slice(&len.to_le_bytes());
}

pub(crate) fn header(b: &mut Vec<u8>, profile: &str, library: &str) {
    record(b, op::HEADER, |b| {
        string(b, profile);
        string(b, library);
    });
}

pub(crate) fn schema(b: &mut Vec<u8>, id: u16, name: &str, encoding: &str, data: &[u8]) {
    record(b, op::SCHEMA, |b| {
        u16le(b, id);
        string(b, name);
        string(b, encoding);
        len32(b, data.len());
        b.extend_from_slice(data);
    });
}

pub(crate) fn channel(b: &mut Vec<u8>, id: u16, schema_id: u16, topic: &str, message_encoding: &str, metadata: &BTreeMap<String, String>) {
    record(b, op::CHANNEL, |b| {
        u16le(b, id);
        u16le(b, schema_id);
        string(b, topic);
        string(b, message_encoding);
        prefixed(b, |b| {
            for (k, v) in metadata {
                string(b, k);
                string(b, v);
            }
        });
    });
}

/// Length of a message record's fields before its data.
const MESSAGE_FIELDS: usize = 2 + 4 + 8 + 8;

/// A message record (publish time = log time, as rosbag2 writes them).
pub(crate) fn message(b: &mut Vec<u8>, channel_id: u16, sequence: u32, log_time: u64, data: &[u8]) {
    b.reserve(9 + MESSAGE_FIELDS + data.len());
    b.push(op::MESSAGE);
    u64le(b, (MESSAGE_FIELDS + data.len()) as u64);
    u16le(b, channel_id);
    u32le(b, sequence);
    u64le(b, log_time);
    u64le(b, log_time);
    b.extend_from_slice(data);
}

/// What a chunk record's header says about its records.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ChunkHeader<'a> {
    pub start_ns: u64,
    pub end_ns: u64,
    pub uncompressed_size: u64,
    pub uncompressed_crc: u32,
    pub compression: &'a str,
    pub compressed_size: u64,
}

/// Everything of a chunk record up to its (compressed) records, which follow it in the file:
/// the record's length counts them.
pub(crate) fn chunk_head(b: &mut Vec<u8>, h: &ChunkHeader) {
    let fields = 8 + 8 + 8 + 4 + 4 + h.compression.len() as u64 + 8;
    b.push(op::CHUNK);
    u64le(b, fields + h.compressed_size);
    u64le(b, h.start_ns);
    u64le(b, h.end_ns);
    u64le(b, h.uncompressed_size);
    u32le(b, h.uncompressed_crc);
    string(b, h.compression);
    u64le(b, h.compressed_size);
}

/// A message index record: each message's log time and offset in the chunk's records.
pub(crate) fn message_index(b: &mut Vec<u8>, channel_id: u16, entries: &[(u64, u64)]) {
    record(b, op::MESSAGE_INDEX, |b| {
        u16le(b, channel_id);
        len32(b, entries.len() * 16);
        for &(t, offset) in entries {
            u64le(b, t);
            u64le(b, offset);
        }
    });
}

/// A chunk index record of the summary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct ChunkIndex {
    pub start_ns: u64,
    pub end_ns: u64,
    pub chunk_start_offset: u64,
    pub chunk_length: u64,
    /// File offset of each channel's message index record.
    pub message_index_offsets: Vec<(u16, u64)>,
    pub message_index_length: u64,
    pub compression: &'static str,
    pub compressed_size: u64,
    pub uncompressed_size: u64,
}

pub(crate) fn chunk_index(b: &mut Vec<u8>, c: &ChunkIndex) {
    record(b, op::CHUNK_INDEX, |b| {
        u64le(b, c.start_ns);
        u64le(b, c.end_ns);
        u64le(b, c.chunk_start_offset);
        u64le(b, c.chunk_length);
        prefixed(b, |b| {
            for &(id, offset) in &c.message_index_offsets {
                u16le(b, id);
                u64le(b, offset);
            }
        });
        u64le(b, c.message_index_length);
        string(b, c.compression);
        u64le(b, c.compressed_size);
        u64le(b, c.uncompressed_size);
    });
}

#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct Statistics {
    pub message_count: u64,
    pub schema_count: u16,
    pub channel_count: u32,
    pub chunk_count: u32,
    pub start_ns: u64,
    pub end_ns: u64,
    pub metadata_count: u32,
    /// Messages of each channel that has any, by channel id.
    pub channel_message_counts: BTreeMap<u16, u64>,
}

pub(crate) fn statistics(b: &mut Vec<u8>, s: &Statistics) {
    record(b, op::STATISTICS, |b| {
        u64le(b, s.message_count);
        u16le(b, s.schema_count);
        u32le(b, s.channel_count);
        u32le(b, 0); // attachments
        u32le(b, s.metadata_count);
        u32le(b, s.chunk_count);
        u64le(b, s.start_ns);
        u64le(b, s.end_ns);
        prefixed(b, |b| {
            for (&id, &n) in &s.channel_message_counts {
                u16le(b, id);
                u64le(b, n);
            }
        });
    });
}

/// A metadata record: a name and a map of strings.
pub(crate) fn metadata(b: &mut Vec<u8>, name: &str, entries: &BTreeMap<String, String>) {
    record(b, op::METADATA, |b| {
        string(b, name);
        prefixed(b, |b| {
            for (k, v) in entries {
                string(b, k);
                string(b, v);
            }
        });
    });
}

/// A metadata index record of the summary: where a metadata record is and its name.
pub(crate) fn metadata_index(b: &mut Vec<u8>, offset: u64, length: u64, name: &str) {
    record(b, op::METADATA_INDEX, |b| {
        u64le(b, offset);
        u64le(b, length);
        string(b, name);
    });
}

pub(crate) fn data_end(b: &mut Vec<u8>, data_section_crc: u32) {
    record(b, op::DATA_END, |b| u32le(b, data_section_crc));
}

pub(crate) fn summary_offset(b: &mut Vec<u8>, group_opcode: u8, group_start: u64, group_length: u64) {
    record(b, op::SUMMARY_OFFSET, |b| {
        b.push(group_opcode);
        u64le(b, group_start);
        u64le(b, group_length);
    });
}

/// The footer up to (not including) its summary CRC, which covers the summary section and
/// these bytes; [`footer_end`] appends the CRC and the closing magic.
pub(crate) fn footer_start(b: &mut Vec<u8>, summary_start: u64, summary_offset_start: u64) {
    b.push(op::FOOTER);
    u64le(b, 8 + 8 + 4);
    u64le(b, summary_start);
    u64le(b, summary_offset_start);
}

pub(crate) fn footer_end(b: &mut Vec<u8>, summary_crc: u32) {
    u32le(b, summary_crc);
    b.extend_from_slice(MAGIC);
}
