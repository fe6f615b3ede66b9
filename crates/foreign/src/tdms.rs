//! National Instruments TDMS files, read by hand (ADR 0030 says why no crate): an index of
//! every segment's metadata made in one pass over the lead-ins (the raw data is skipped),
//! then each channel streamed from its runs of values, a block at a time.
//!
//! What is read: segments with new or incremental object lists, raw data indices repeated
//! from the previous segment, several chunks per segment, contiguous and interleaved raw
//! data, little- and big-endian segments, every numeric type, and the properties of the
//! file, its groups and channels. What is refused with its reason: a segment the writer
//! never finished, a segment that runs past the end of the file (a truncated file), raw
//! data that is not a whole number of chunks, and DAQmx raw data (the card's codes with
//! scaler records: DAQmx logging's format).
//!
//! The format: NI's "TDMS File Format Internal Structure". A segment is a 28-byte lead-in
//! (`TDSm`, the table-of-contents mask, the version, the length of the rest of the segment
//! and of its metadata), the metadata (objects `/'group'/'channel'` with their raw data index
//! and properties) and the raw data.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use crate::error::{listed, shown, ForeignError, Result};

const TOC_META_DATA: u32 = 1 << 1;
const TOC_NEW_OBJ_LIST: u32 = 1 << 2;
const TOC_RAW_DATA: u32 = 1 << 3;
const TOC_INTERLEAVED: u32 = 1 << 5;
const TOC_BIG_ENDIAN: u32 = 1 << 6;
const TOC_DAQMX_RAW_DATA: u32 = 1 << 7;
const LEAD_IN: u64 = 28;
const NO_DATA: u32 = 0xFFFF_FFFF;
const SAME_AS_BEFORE: u32 = 0;
const DAQMX_FORMAT_CHANGING: u32 = 0x6912_0000;
const DAQMX_DIGITAL_LINE: u32 = 0x6913_0000;
const TYPE_STRING: u32 = 0x20;
const TYPE_DAQMX: u32 = 0xFFFF_FFFF;

/// A property value.
#[derive(Debug, Clone, PartialEq)]
pub enum Property {
    Int(i64),
    UInt(u64),
    Float(f64),
    Bool(bool),
    Text(String),
    /// Seconds since 1904-01-01 UTC and the fraction in 2^-64 s.
    Time {
        seconds: i64,
        fraction: u64,
    },
}

impl Property {
    /// The value as a number, if it is one.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Property::Int(v) => Some(v as f64),
            Property::UInt(v) => Some(v as f64),
            Property::Float(v) => Some(v),
            _ => None,
        }
    }
}

/// A run of one channel's values in the file: `count` values, the first at byte `offset`,
/// each `stride` bytes after the one before (the value's size for contiguous data, a row of
/// every channel for interleaved data).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Run {
    offset: u64,
    count: u64,
    stride: u64,
    big_endian: bool,
    segment: usize,
}

/// An object of the file: the root, a group, or a channel.
#[derive(Debug, Clone, Default)]
pub struct Object {
    /// The path as written (`/'Group'/'Channel'`).
    pub path: String,
    pub group: Option<String>,
    pub channel: Option<String>,
    pub properties: Vec<(String, Property)>,
    /// Data type code of its raw data, once it had some.
    data_type: Option<u32>,
    runs: Vec<Run>,
    len: u64,
}

impl Object {
    pub fn property(&self, name: &str) -> Option<&Property> {
        self.properties.iter().rev().find(|(n, _)| n == name).map(|(_, v)| v)
    }

    /// Values of raw data in the file.
    pub fn len(&self) -> u64 {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// `Group/Channel`, as a map names it.
    pub fn name(&self) -> String {
        match (&self.group, &self.channel) {
            (Some(g), Some(c)) => format!("{g}/{c}"),
            (Some(g), None) => g.clone(),
            _ => "/".into(),
        }
    }
}

/// The index of a TDMS file: its objects with their properties and where their values are.
#[derive(Debug)]
pub struct TdmsFile {
    path: PathBuf,
    objects: Vec<Object>,
    segments: usize,
}

/// The raw data index of an object in the segment being read.
#[derive(Debug, Clone, Copy, PartialEq)]
struct RawIndex {
    data_type: u32,
    count: u64,
    /// Bytes of this object's values in one chunk.
    bytes: u64,
}

fn type_size(code: u32) -> Option<u64> {
    Some(match code {
        1 | 5 | 0x21 => 1,
        2 | 6 => 2,
        3 | 7 | 9 | 0x19 => 4,
        4 | 8 | 10 | 0x1A | 0x08_000C => 8,
        0x44 | 0x10_000D => 16,
        _ => return None,
    })
}

fn type_name(code: u32) -> String {
    match code {
        1 => "I8".into(),
        2 => "I16".into(),
        3 => "I32".into(),
        4 => "I64".into(),
        5 => "U8".into(),
        6 => "U16".into(),
        7 => "U32".into(),
        8 => "U64".into(),
        9 | 0x19 => "SGL".into(),
        10 | 0x1A => "DBL".into(),
        11 | 0x1B => "EXT".into(),
        0x20 => "string".into(),
        0x21 => "boolean".into(),
        0x44 => "timestamp".into(),
        0x08_000C => "complex SGL".into(),
        0x10_000D => "complex DBL".into(),
        TYPE_DAQMX => "DAQmx raw data".into(),
        other => format!("type 0x{other:x}"),
    }
}

/// Little/big-endian reads from a byte slice, with the position for messages.
struct Bytes<'a> {
    data: &'a [u8],
    at: usize,
    big: bool,
}

impl<'a> Bytes<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.at.checked_add(n)?;
        let s = self.data.get(self.at..end)?;
        self.at = end;
        Some(s)
    }
    fn u32(&mut self) -> Option<u32> {
        let b: [u8; 4] = self.take(4)?.try_into().ok()?;
        Some(if self.big { u32::from_be_bytes(b) } else { u32::from_le_bytes(b) })
    }
    fn u64(&mut self) -> Option<u64> {
        let b: [u8; 8] = self.take(8)?.try_into().ok()?;
        Some(if self.big { u64::from_be_bytes(b) } else { u64::from_le_bytes(b) })
    }
    fn string(&mut self) -> Option<std::result::Result<String, ()>> {
        let n = self.u32()? as usize;
        let s = self.take(n)?;
        Some(String::from_utf8(s.to_vec()).map_err(|_| ()))
    }
    fn value(&mut self, code: u32) -> Option<std::result::Result<Property, String>> {
        let big = self.big;
        let mut num = |size: usize| -> Option<u64> { self.take(size).map(|b| unsigned(b, big)) };
        Some(Ok(match code {
            1 => Property::Int(i64::from(num(1)? as u8 as i8)),
            2 => Property::Int(i64::from(num(2)? as u16 as i16)),
            3 => Property::Int(i64::from(num(4)? as u32 as i32)),
            4 => Property::Int(num(8)? as i64),
            5 => Property::UInt(num(1)?),
            6 => Property::UInt(num(2)?),
            7 => Property::UInt(num(4)?),
            8 => Property::UInt(num(8)?),
            9 | 0x19 => Property::Float(f64::from(f32::from_bits(num(4)? as u32))),
            10 | 0x1A => Property::Float(f64::from_bits(num(8)?)),
            0x21 => Property::Bool(num(1)? != 0),
            0x44 => {
                // Little-endian: fraction then seconds; big-endian: seconds then fraction.
                let (a, b) = (num(8)?, num(8)?);
                let (seconds, fraction) = if big { (a as i64, b) } else { (b as i64, a) };
                Property::Time { seconds, fraction }
            }
            0x20 => match self.string()? {
                Ok(s) => Property::Text(s),
                Err(()) => return Some(Err("a string property is not UTF-8".into())),
            },
            other => return Some(Err(format!("a property of {} cannot be read", type_name(other)))),
        }))
    }
}

/// An unsigned integer of 1 to 8 bytes in the given byte order.
fn unsigned(b: &[u8], big: bool) -> u64 {
    let mut a = [0u8; 8];
    if big {
        a[8 - b.len()..].copy_from_slice(b);
        u64::from_be_bytes(a)
    } else {
        a[..b.len()].copy_from_slice(b);
        u64::from_le_bytes(a)
    }
}

/// Splits `/'Group'/'Channel'` into its names (`''` inside a name is one quote).
fn split_path(path: &str) -> Option<Vec<String>> {
    if path == "/" {
        return Some(Vec::new());
    }
    let mut names = Vec::new();
    let mut rest = path;
    while !rest.is_empty() {
        rest = rest.strip_prefix("/'")?;
        let mut name = String::new();
        let mut chars = rest.char_indices().peekable();
        let end = loop {
            let (i, c) = chars.next()?;
            if c == '\'' {
                if matches!(chars.peek(), Some((_, '\''))) {
                    chars.next();
                    name.push('\'');
                } else {
                    break i + 1;
                }
            } else {
                name.push(c);
            }
        };
        names.push(name);
        rest = &rest[end..];
    }
    Some(names)
}

impl TdmsFile {
    /// Indexes `path`: every segment's lead-in and metadata, the raw data skipped.
    pub fn open(path: &Path) -> Result<Self> {
        let file = File::open(path).map_err(|e| ForeignError::io(format!("cannot open {}", path.display()), e))?;
        let file_len = file.metadata().map_err(|e| ForeignError::io(format!("cannot read {}", path.display()), e))?.len();
        let mut reader = BufReader::new(file);
        let bad = |segment: usize, at: u64, message: String| ForeignError::record(path, None, Some(format!("segment {segment} at byte {at}")), message);

        let mut objects: Vec<Object> = vec![Object { path: "/".into(), ..Default::default() }];
        let mut by_path: HashMap<String, usize> = HashMap::from([("/".to_string(), 0)]);
        // The objects with raw data, in order, and their last raw data index.
        let mut active: Vec<(usize, RawIndex)> = Vec::new();
        let mut last_index: HashMap<usize, RawIndex> = HashMap::new();
        let mut pos = 0u64;
        let mut segment = 0usize;
        while pos < file_len {
            if file_len - pos < LEAD_IN {
                return Err(bad(segment, pos, format!("the file ends {} bytes into the segment's 28-byte lead-in: it is truncated", file_len - pos)));
            }
            reader.seek(SeekFrom::Start(pos)).map_err(|e| ForeignError::io(format!("cannot read {}", path.display()), e))?;
            let mut lead = [0u8; LEAD_IN as usize];
            reader.read_exact(&mut lead).map_err(|e| ForeignError::io(format!("cannot read {}", path.display()), e))?;
            if &lead[..4] != b"TDSm" {
                let what = if &lead[..4] == b"TDSh" {
                    "`TDSh`: this is a .tdms_index file; give the .tdms file beside it".to_string()
                } else {
                    format!("{:?}", String::from_utf8_lossy(&lead[..4]))
                };
                return Err(bad(
                    segment,
                    pos,
                    format!("expected a segment's tag `TDSm`, found {what}{}", if segment == 0 { " (not a TDMS file)" } else { ": the file is damaged" }),
                ));
            }
            let toc = u32::from_le_bytes([lead[4], lead[5], lead[6], lead[7]]);
            let big = toc & TOC_BIG_ENDIAN != 0;
            let mut b = Bytes { data: &lead[8..], at: 0, big };
            // Twenty bytes are there: the three fields read.
            let (_version, next, raw_offset) = (b.u32().unwrap_or(0), b.u64().unwrap_or(0), b.u64().unwrap_or(0));
            if next == u64::MAX {
                return Err(bad(segment, pos, "the segment was never finished by its writer (its length is 0xFFFFFFFFFFFFFFFF): the acquisition stopped while writing, and the file is truncated".into()));
            }
            let end = pos.checked_add(LEAD_IN).and_then(|p| p.checked_add(next)).filter(|&e| e <= file_len).ok_or_else(|| {
                bad(
                    segment,
                    pos,
                    format!(
                        "the segment says {next} bytes follow its lead-in, but the file ends {} bytes after it: the file is truncated",
                        file_len - pos - LEAD_IN
                    ),
                )
            })?;
            if raw_offset > next {
                return Err(bad(segment, pos, format!("its metadata ({raw_offset} bytes) is longer than the segment ({next} bytes)")));
            }
            let raw_start = pos + LEAD_IN + raw_offset;

            if toc & TOC_META_DATA != 0 {
                let mut meta = vec![0u8; raw_offset as usize];
                reader.read_exact(&mut meta).map_err(|e| ForeignError::io(format!("cannot read {}", path.display()), e))?;
                let mut m = Bytes { data: &meta, at: 0, big };
                let short = |m: &Bytes| bad(segment, pos, format!("its metadata ends early (byte {} of {})", m.at, meta.len()));
                let count = m.u32().ok_or_else(|| short(&m))?;
                if toc & TOC_NEW_OBJ_LIST != 0 {
                    active.clear();
                }
                for _ in 0..count {
                    let object_path = m.string().ok_or_else(|| short(&m))?.map_err(|()| bad(segment, pos, "an object's path is not UTF-8".into()))?;
                    // As messages quote it (a damaged file's path can be long).
                    let quoted = shown(&object_path);
                    let id = match by_path.get(&object_path) {
                        Some(&id) => id,
                        None => {
                            let names = split_path(&object_path)
                                .ok_or_else(|| bad(segment, pos, format!("object path `{quoted}` is not of the form /'group'/'channel'")))?;
                            if names.len() > 2 {
                                return Err(bad(segment, pos, format!("object path `{quoted}` is deeper than group/channel")));
                            }
                            let id = objects.len();
                            objects.push(Object {
                                path: object_path.clone(),
                                group: names.first().cloned(),
                                channel: names.get(1).cloned(),
                                ..Default::default()
                            });
                            by_path.insert(object_path.clone(), id);
                            id
                        }
                    };
                    let index_len = m.u32().ok_or_else(|| short(&m))?;
                    let index = match index_len {
                        NO_DATA => None,
                        SAME_AS_BEFORE => {
                            Some(*last_index.get(&id).ok_or_else(|| bad(segment, pos, format!("`{quoted}` repeats a raw data index it never had")))?)
                        }
                        DAQMX_FORMAT_CHANGING | DAQMX_DIGITAL_LINE => {
                            let (data_type, _dim, n) =
                                (m.u32().ok_or_else(|| short(&m))?, m.u32().ok_or_else(|| short(&m))?, m.u64().ok_or_else(|| short(&m))?);
                            let scalers = m.u32().ok_or_else(|| short(&m))? as usize;
                            m.take(scalers.checked_mul(if index_len == DAQMX_FORMAT_CHANGING { 20 } else { 17 }).ok_or_else(|| short(&m))?)
                                .ok_or_else(|| short(&m))?;
                            let widths = m.u32().ok_or_else(|| short(&m))? as usize;
                            let mut width = 0u64;
                            for k in 0..widths {
                                let w = u64::from(m.u32().ok_or_else(|| short(&m))?);
                                if k == 0 {
                                    width = w;
                                }
                            }
                            let _ = data_type;
                            Some(RawIndex { data_type: TYPE_DAQMX, count: n, bytes: n.saturating_mul(width) })
                        }
                        _ => {
                            let data_type = m.u32().ok_or_else(|| short(&m))?;
                            let dim = m.u32().ok_or_else(|| short(&m))?;
                            let n = m.u64().ok_or_else(|| short(&m))?;
                            if dim != 1 {
                                return Err(bad(segment, pos, format!("`{quoted}` has raw data of dimension {dim} (TDMS writes 1)")));
                            }
                            let bytes = if data_type == TYPE_STRING {
                                m.u64().ok_or_else(|| short(&m))?
                            } else {
                                let size = type_size(data_type).ok_or_else(|| {
                                    bad(segment, pos, format!("`{quoted}` holds {}, which has no fixed size this reader knows", type_name(data_type)))
                                })?;
                                n.checked_mul(size).ok_or_else(|| bad(segment, pos, format!("`{quoted}`: {n} values overflow")))?
                            };
                            Some(RawIndex { data_type, count: n, bytes })
                        }
                    };
                    match index {
                        Some(ix) => {
                            last_index.insert(id, ix);
                            if let Some(slot) = active.iter_mut().find(|(a, _)| *a == id) {
                                slot.1 = ix;
                            } else {
                                active.push((id, ix));
                            }
                        }
                        None => active.retain(|(a, _)| *a != id),
                    }
                    let properties = m.u32().ok_or_else(|| short(&m))?;
                    for _ in 0..properties {
                        let name =
                            m.string().ok_or_else(|| short(&m))?.map_err(|()| bad(segment, pos, format!("a property name of `{quoted}` is not UTF-8")))?;
                        let code = m.u32().ok_or_else(|| short(&m))?;
                        let value = m
                            .value(code)
                            .ok_or_else(|| short(&m))?
                            .map_err(|why| bad(segment, pos, format!("`{quoted}` property `{}`: {why}", shown(&name))))?;
                        let props = &mut objects[id].properties;
                        props.retain(|(n, _)| *n != name);
                        props.push((name, value));
                    }
                }
            }

            if active.iter().any(|(_, ix)| ix.data_type == TYPE_DAQMX) {
                // DAQmx raw data is one buffer of the card's codes shared by its channels, laid
                // out by scaler records; it is not read (`stream` says so), only marked.
                for (id, ix) in &active {
                    let o = &mut objects[*id];
                    o.data_type = Some(TYPE_DAQMX);
                    o.len = o
                        .len
                        .checked_add(ix.count)
                        .ok_or_else(|| bad(segment, pos, format!("`{}` claims more values than a file can hold", shown(&o.path))))?;
                }
            } else if toc & (TOC_RAW_DATA | TOC_DAQMX_RAW_DATA) != 0 && end > raw_start {
                let raw = end - raw_start;
                // The sizes are the file's own words (a string's byte count is not checked
                // against its value count): summed checked.
                let overflow = || bad(segment, pos, "its objects' raw data sizes overflow: the metadata is damaged".into());
                let chunk = active.iter().try_fold(0u64, |a, (_, ix)| a.checked_add(ix.bytes)).ok_or_else(overflow)?;
                if chunk == 0 {
                    return Err(bad(segment, pos, format!("{raw} bytes of raw data but no object with data in the segment")));
                }
                if !raw.is_multiple_of(chunk) {
                    return Err(bad(
                        segment,
                        pos,
                        format!("its {raw} bytes of raw data are not a whole number of {chunk}-byte chunks: the segment is damaged or truncated"),
                    ));
                }
                let interleaved = toc & TOC_INTERLEAVED != 0;
                if interleaved {
                    let n = active.first().map_or(0, |(_, ix)| ix.count);
                    if let Some((id, ix)) = active.iter().find(|(_, ix)| ix.count != n || ix.data_type == TYPE_STRING) {
                        return Err(bad(
                            segment,
                            pos,
                            format!(
                                "interleaved data with `{}` holding {} {} values against {n}",
                                shown(&objects[*id].path),
                                ix.count,
                                type_name(ix.data_type)
                            ),
                        ));
                    }
                }
                let row = active.iter().try_fold(0u64, |a, (_, ix)| a.checked_add(ix.bytes / ix.count.max(1))).ok_or_else(overflow)?;
                for c in 0..raw / chunk {
                    let base = raw_start + c * chunk;
                    let mut at = base;
                    for (id, ix) in &active {
                        let o = &mut objects[*id];
                        if o.data_type.is_some_and(|t| t != ix.data_type) && ix.count > 0 {
                            return Err(bad(
                                segment,
                                pos,
                                format!(
                                    "`{}` changes its data type from {} to {}",
                                    shown(&o.path),
                                    type_name(o.data_type.unwrap_or(0)),
                                    type_name(ix.data_type)
                                ),
                            ));
                        }
                        if ix.count > 0 {
                            o.data_type = Some(ix.data_type);
                        }
                        let size = ix.bytes / ix.count.max(1);
                        let run = if interleaved {
                            Run { offset: at, count: ix.count, stride: row, big_endian: big, segment }
                        } else {
                            Run { offset: at, count: ix.count, stride: size, big_endian: big, segment }
                        };
                        at += if interleaved { size } else { ix.bytes };
                        if run.count == 0 {
                            continue;
                        }
                        o.len = o
                            .len
                            .checked_add(run.count)
                            .ok_or_else(|| bad(segment, pos, format!("`{}` claims more values than a file can hold", shown(&o.path))))?;
                        match o.runs.last_mut() {
                            // A contiguous continuation (the next chunk of a channel alone in
                            // its segments) extends the run before it.
                            Some(last)
                                if last.stride == size
                                    && run.stride == size
                                    && last.big_endian == big
                                    && last.count.checked_mul(size).and_then(|b| last.offset.checked_add(b)) == Some(run.offset) =>
                            {
                                // Both counts are within `o.len`, which did not overflow.
                                last.count += run.count
                            }
                            _ => o.runs.push(run),
                        }
                    }
                }
            }
            pos = end;
            segment += 1;
        }
        Ok(TdmsFile { path: path.to_path_buf(), objects, segments: segment })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn segments(&self) -> usize {
        self.segments
    }

    /// Every object: the root first, then groups and channels in the order they appear.
    pub fn objects(&self) -> &[Object] {
        &self.objects
    }

    pub fn root(&self) -> &Object {
        &self.objects[0]
    }

    pub fn group(&self, name: &str) -> Option<&Object> {
        self.objects.iter().find(|o| o.channel.is_none() && o.group.as_deref() == Some(name))
    }

    /// The channels of a group, in the order they first appear.
    pub fn channels_of<'a>(&'a self, group: &'a str) -> impl Iterator<Item = &'a Object> + 'a {
        self.objects.iter().filter(move |o| o.channel.is_some() && o.group.as_deref() == Some(group))
    }

    /// A channel by `Group/Channel` (or the file's own path `/'Group'/'Channel'`), or by its
    /// position in a group.
    pub fn find<'a>(&'a self, from: &'a str, index: Option<usize>) -> Option<&'a Object> {
        match index {
            Some(i) => self.channels_of(from).nth(i),
            None => self.objects.iter().find(|o| o.channel.is_some() && (o.path == from || o.name() == from)),
        }
    }

    /// The channel names of the file, for a message.
    pub fn channel_names(&self) -> String {
        let names: Vec<String> = self.objects.iter().filter(|o| o.channel.is_some()).map(|o| format!("`{}`", shown(&o.name()))).collect();
        if names.is_empty() {
            "none".into()
        } else {
            listed(names)
        }
    }

    /// A reader of a channel's values, from the first.
    pub fn stream(&self, object: &Object, label: &str) -> Result<ChannelStream> {
        let bad = |m: String| ForeignError::record(&self.path, Some(label.to_string()), None, m);
        let data_type = object.data_type.ok_or_else(|| bad("the channel holds no values".into()))?;
        if data_type == TYPE_DAQMX {
            return Err(bad("the channel holds DAQmx raw data (the card's codes with NI's scaler records, as DAQmx logging writes them): not read; log scaled data, or save the channel as scaled values (e.g. npTDMS or LabVIEW's TDMS conversion) and map those".into()));
        }
        let size = match data_type {
            1..=10 | 0x19 | 0x1A => type_size(data_type).unwrap_or(8),
            other => return Err(bad(format!("the channel holds {} values, not numbers", type_name(other)))),
        };
        let file = File::open(&self.path).map_err(|e| ForeignError::io(format!("cannot open {}", self.path.display()), e))?;
        Ok(ChannelStream {
            path: self.path.clone(),
            label: label.to_string(),
            file,
            runs: object.runs.clone(),
            run: 0,
            done_in_run: 0,
            data_type,
            size,
            buf: Vec::new(),
        })
    }
}

/// One channel's values, read in order, a block at a time.
pub struct ChannelStream {
    path: PathBuf,
    label: String,
    file: File,
    runs: Vec<Run>,
    run: usize,
    done_in_run: u64,
    data_type: u32,
    size: u64,
    buf: Vec<u8>,
}

/// Bytes read at once from a run.
const READ_BYTES: u64 = 1 << 16;

impl ChannelStream {
    /// Appends up to `max` next values to `out`; returns how many (0 at the end).
    pub fn read(&mut self, out: &mut Vec<f64>, max: usize) -> Result<usize> {
        let mut got = 0usize;
        while got < max {
            let Some(run) = self.runs.get(self.run).copied() else { break };
            let left = run.count - self.done_in_run;
            if left == 0 {
                self.run += 1;
                self.done_in_run = 0;
                continue;
            }
            let rows = left.min((max - got) as u64).min((READ_BYTES / run.stride.max(1)).max(1));
            let start = run.offset + self.done_in_run * run.stride;
            let bytes = (rows - 1) * run.stride + self.size;
            self.buf.resize(bytes as usize, 0);
            let io = |e| {
                ForeignError::record(
                    &self.path,
                    Some(self.label.clone()),
                    Some(format!("segment {} at byte {start}", run.segment)),
                    format!("cannot read the values: {e}"),
                )
            };
            self.file.seek(SeekFrom::Start(start)).map_err(io)?;
            self.file.read_exact(&mut self.buf).map_err(io)?;
            for r in 0..rows as usize {
                let at = r * run.stride as usize;
                out.push(decode(self.data_type, &self.buf[at..at + self.size as usize], run.big_endian));
            }
            self.done_in_run += rows;
            got += rows as usize;
        }
        Ok(got)
    }
}

/// One numeric value of TDMS type `code` from its bytes.
fn decode(code: u32, b: &[u8], big: bool) -> f64 {
    let u = unsigned(b, big);
    match code {
        1 => f64::from(u as u8 as i8),
        2 => f64::from(u as u16 as i16),
        3 => f64::from(u as u32 as i32),
        4 => u as i64 as f64,
        5 => f64::from(u as u8),
        6 => f64::from(u as u16),
        7 => f64::from(u as u32),
        8 => u as f64,
        9 | 0x19 => f64::from(f32::from_bits(u as u32)),
        _ => f64::from_bits(u),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_split_with_quotes_and_slashes() {
        assert_eq!(split_path("/").unwrap(), Vec::<String>::new());
        assert_eq!(split_path("/'Probes'").unwrap(), ["Probes"]);
        assert_eq!(split_path("/'Pro/bes'/'A ''x'''").unwrap(), ["Pro/bes", "A 'x'"]);
        assert!(split_path("Probes/A").is_none());
        assert!(split_path("/'open").is_none());
    }

    #[test]
    fn values_of_every_numeric_type_both_byte_orders() {
        assert_eq!(decode(2, &(-3i16).to_le_bytes(), false), -3.0);
        assert_eq!(decode(2, &(-3i16).to_be_bytes(), true), -3.0);
        assert_eq!(decode(7, &4_000_000_000u32.to_le_bytes(), false), 4e9);
        assert_eq!(decode(9, &1.5f32.to_be_bytes(), true), 1.5);
        assert_eq!(decode(10, &0.1f64.to_le_bytes(), false), 0.1);
        assert_eq!(decode(1, &[0xFF], false), -1.0);
    }
}
