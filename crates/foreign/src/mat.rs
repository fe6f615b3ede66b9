//! MATLAB MAT-files of level 5 (`save -v6`, `-v7`, scipy.io.savemat), read by hand (ADR
//! 0030 says why no crate): an index of every numeric array, struct field and matrix
//! column made in one pass (compressed variables inflated once, their data discarded), then
//! each mapped channel streamed from its place a block at a time, through its own inflater
//! when the variable is compressed. Memory stays bounded whatever the file's size.
//!
//! Names: a variable `x`, a struct field `s.x` (nested: `s.a.x`), a field of element k of a
//! struct array `s(k).x` (k from 1, as MATLAB counts), an element of a cell array `c{k}`.
//! A MAT-file of version 7.3 is an HDF5 file; it is recognised and refused with the way
//! round it (ADR 0030).

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use flate2::bufread::ZlibDecoder;

use crate::error::{listed, shown, ForeignError, Result};

/// Structs and cells nested deeper than this are refused (each level is a recursion: a
/// damaged or hostile file must not exhaust the stack).
const MAX_DEPTH: usize = 32;

const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;

/// What an array is.
#[derive(Debug, Clone, PartialEq)]
pub enum Kind {
    /// Real numbers (any integer or floating class).
    Numeric,
    /// Something a channel cannot be: the words say what (`a char array`, `complex`, ...).
    Other(String),
}

/// Where an array's real values are.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Place {
    /// At this byte of the file.
    File(u64),
    /// In the zlib stream of the miCOMPRESSED element whose data starts at byte `start` of the
    /// file and is `len` bytes long, this many bytes into the inflated stream.
    Inflated { start: u64, len: u64, at: u64 },
}

#[derive(Debug, Clone, PartialEq)]
struct Data {
    storage: u32,
    bytes: u64,
    place: Place,
    /// The values when they sat in the tag (a small data element).
    small: Option<Vec<f64>>,
}

/// An array of the file, with its dotted name.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    pub name: String,
    pub dims: Vec<u64>,
    pub kind: Kind,
    data: Option<Data>,
}

impl Array {
    pub fn len(&self) -> u64 {
        self.dims.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn dims_text(&self) -> String {
        self.dims.iter().map(u64::to_string).collect::<Vec<_>>().join("x")
    }
}

/// The index of a MAT-file.
#[derive(Debug)]
pub struct MatFile {
    path: PathBuf,
    big: bool,
    arrays: Vec<Array>,
}

fn storage_size(t: u32) -> Option<u64> {
    Some(match t {
        1 | 2 => 1,
        3 | 4 => 2,
        5..=7 => 4,
        9 | 12 | 13 => 8,
        _ => return None,
    })
}

fn class_name(class: u8) -> &'static str {
    match class {
        1 => "a cell array",
        2 => "a struct",
        3 => "an object",
        4 => "a char array",
        5 => "a sparse array",
        6 => "double",
        7 => "single",
        8 => "int8",
        9 => "uint8",
        10 => "int16",
        11 => "uint16",
        12 => "int32",
        13 => "uint32",
        14 => "int64",
        15 => "uint64",
        16 => "a function handle",
        17 => "an opaque object (string, table, timetable ...)",
        _ => "an unknown class",
    }
}

/// A byte source that knows its position and can skip.
trait Source: Read + Send {
    fn pos(&self) -> u64;
    fn skip(&mut self, n: u64) -> std::io::Result<()>;
}

struct FileSource {
    r: BufReader<File>,
    pos: u64,
}

impl Read for FileSource {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.r.read(buf)?;
        self.pos += n as u64;
        Ok(n)
    }
}

impl Source for FileSource {
    fn pos(&self) -> u64 {
        self.pos
    }
    fn skip(&mut self, n: u64) -> std::io::Result<()> {
        self.pos += n;
        self.r.seek(SeekFrom::Start(self.pos)).map(|_| ())
    }
}

struct Inflated {
    r: ZlibDecoder<BufReader<std::io::Take<File>>>,
    pos: u64,
}

impl Read for Inflated {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.r.read(buf)?;
        self.pos += n as u64;
        Ok(n)
    }
}

impl Source for Inflated {
    fn pos(&self) -> u64 {
        self.pos
    }
    fn skip(&mut self, n: u64) -> std::io::Result<()> {
        let copied = std::io::copy(&mut self.by_ref().take(n), &mut std::io::sink())?;
        if copied < n {
            return Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "the compressed variable ends early"));
        }
        Ok(())
    }
}

fn inflater(path: &Path, start: u64, len: u64) -> std::io::Result<Inflated> {
    let mut f = File::open(path)?;
    f.seek(SeekFrom::Start(start))?;
    Ok(Inflated { r: ZlibDecoder::new(BufReader::with_capacity(1 << 16, f.take(len))), pos: 0 })
}

/// The parser of one file's elements.
struct Parser<'a> {
    path: &'a Path,
    big: bool,
    arrays: Vec<Array>,
}

impl Parser<'_> {
    fn u32(&self, b: [u8; 4]) -> u32 {
        if self.big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        }
    }

    /// A data element's tag: (type, size, the data when it sat in the tag).
    fn tag(&self, r: &mut dyn Source) -> std::io::Result<(u32, u64, Option<[u8; 4]>)> {
        let mut t = [0u8; 8];
        r.read_exact(&mut t)?;
        let first = self.u32([t[0], t[1], t[2], t[3]]);
        if first >> 16 != 0 {
            // Small data element format: size in the upper half, data in the next 4 bytes.
            return Ok((first & 0xFFFF, u64::from(first >> 16), Some([t[4], t[5], t[6], t[7]])));
        }
        Ok((first, u64::from(self.u32([t[4], t[5], t[6], t[7]])), None))
    }

    /// A sub-element's bytes (it must be small: flags, dims, names).
    fn small_element(&self, r: &mut dyn Source, what: &str) -> std::result::Result<(u32, Vec<u8>), String> {
        let (t, size, inline) = self.tag(r).map_err(|e| format!("reading its {what}: {e}"))?;
        if let Some(b) = inline {
            return Ok((t, b[..size.min(4) as usize].to_vec()));
        }
        if size > 1 << 20 {
            return Err(format!("its {what} claims {size} bytes"));
        }
        let mut v = vec![0u8; size as usize];
        r.read_exact(&mut v).map_err(|e| format!("reading its {what}: {e}"))?;
        r.skip(size.next_multiple_of(8) - size).map_err(|e| format!("reading its {what}: {e}"))?;
        Ok((t, v))
    }

    /// Parses the miMATRIX element whose data (after its tag) starts at `r.pos()` and is
    /// `size` bytes; `name` is the name it is known by (a field's), `compressed` where the
    /// stream lives when inflated.
    /// `depth` counts the structs and cells it is inside.
    fn matrix(&mut self, r: &mut dyn Source, size: u64, name: Option<String>, compressed: Option<(u64, u64)>, depth: usize) -> std::result::Result<(), String> {
        let end = r.pos() + size;
        if size == 0 {
            // An empty array (an empty struct field).
            if let Some(name) = name {
                self.arrays.push(Array { name, dims: vec![0, 0], kind: Kind::Numeric, data: None });
            }
            return Ok(());
        }
        let (_, flags) = self.small_element(r, "array flags")?;
        let flags = self.u32(flags.get(..4).and_then(|s| s.try_into().ok()).ok_or("its array flags are short")?);
        let class = (flags & 0xFF) as u8;
        let (complex, logical) = (flags & 0x0800 != 0, flags & 0x0200 != 0);
        let (_, dims) = self.small_element(r, "dimensions")?;
        let dims: Vec<u64> = dims.chunks_exact(4).map(|c| u64::from(self.u32([c[0], c[1], c[2], c[3]]))).collect();
        let (_, own) = self.small_element(r, "name")?;
        // MATLAB's names have at most 63 characters: a longer one is shortened as messages
        // quote it (no map could name it whole anyway).
        let name = name.unwrap_or_else(|| shown(&String::from_utf8_lossy(&own)));
        let dims_text = || dims.iter().map(u64::to_string).collect::<Vec<_>>().join("x");
        // Checked here, so that `Array::len` cannot overflow later.
        let count = dims.iter().try_fold(1u64, |a, &d| a.checked_mul(d)).ok_or_else(|| format!("`{name}`: its dimensions {} overflow", dims_text()))?;
        if matches!(class, 1 | 2) && depth >= MAX_DEPTH {
            return Err(format!("`{name}`: structs and cells nested deeper than {MAX_DEPTH} levels"));
        }
        match class {
            6..=15 => {
                let (storage, bytes, inline) = self.tag(r).map_err(|e| format!("`{name}`: reading its values: {e}"))?;
                let place = match compressed {
                    None => Place::File(r.pos()),
                    Some((start, len)) => Place::Inflated { start, len, at: r.pos() },
                };
                let esize = storage_size(storage).ok_or_else(|| format!("`{name}`: its values are stored as type {storage}, not a number type"))?;
                let small = match inline {
                    Some(b) => Some(b[..bytes.min(4) as usize].chunks_exact(esize as usize).map(|c| decode(storage, c, self.big)).collect()),
                    None if bytes <= 512 => {
                        let mut v = vec![0u8; bytes as usize];
                        r.read_exact(&mut v).map_err(|e| format!("`{name}`: reading its values: {e}"))?;
                        Some(v.chunks_exact(esize as usize).map(|c| decode(storage, c, self.big)).collect())
                    }
                    None => None,
                };
                if count.checked_mul(esize) != Some(bytes) {
                    return Err(format!("`{name}`: {bytes} bytes of values for {count} elements of {esize} bytes"));
                }
                let kind = if complex {
                    Kind::Other("complex".into())
                } else if logical {
                    Kind::Other("logical (true/false)".into())
                } else {
                    Kind::Numeric
                };
                self.arrays.push(Array { name: name.clone(), dims, kind, data: Some(Data { storage, bytes, place, small }) });
            }
            2 => {
                let (_, len) = self.small_element(r, "field name length")?;
                let len = self.u32(len.get(..4).and_then(|s| s.try_into().ok()).ok_or("its field name length is short")?) as usize;
                let (_, names) = self.small_element(r, "field names")?;
                if len == 0 && !names.is_empty() {
                    return Err(format!("`{name}`: field names of length 0"));
                }
                let fields: Vec<String> =
                    if len == 0 { Vec::new() } else { names.chunks(len).map(|c| shown(String::from_utf8_lossy(c).trim_end_matches('\0'))).collect() };
                // Each field of each element is an element of at least its 8-byte tag: a count
                // the bytes cannot hold is refused before it is looped over.
                let elements = count.saturating_mul(fields.len() as u64);
                if elements.saturating_mul(8) > end.saturating_sub(r.pos()) {
                    return Err(format!(
                        "`{name}`: {} ({count} elements of {} fields) cannot fit in its {} bytes",
                        dims_text(),
                        fields.len(),
                        end.saturating_sub(r.pos())
                    ));
                }
                self.arrays.push(Array { name: name.clone(), dims: dims.clone(), kind: Kind::Other("a struct".into()), data: None });
                for k in 0..if fields.is_empty() { 0 } else { count } {
                    for f in &fields {
                        let (t, size, _) = self.tag(r).map_err(|e| format!("`{name}.{f}`: {e}"))?;
                        if t != MI_MATRIX {
                            return Err(format!("`{name}.{f}`: expected a matrix element, found type {t}"));
                        }
                        let full = if count == 1 { format!("{name}.{f}") } else { format!("{name}({}).{f}", k + 1) };
                        self.matrix(r, size, Some(full), compressed, depth + 1)?;
                    }
                }
            }
            1 => {
                if count.saturating_mul(8) > end.saturating_sub(r.pos()) {
                    return Err(format!("`{name}`: {} cells cannot fit in its {} bytes", dims_text(), end.saturating_sub(r.pos())));
                }
                self.arrays.push(Array { name: name.clone(), dims: dims.clone(), kind: Kind::Other("a cell array".into()), data: None });
                for k in 0..count {
                    let (t, size, _) = self.tag(r).map_err(|e| format!("`{name}{{{}}}`: {e}", k + 1))?;
                    if t != MI_MATRIX {
                        return Err(format!("`{name}{{{}}}`: expected a matrix element, found type {t}", k + 1));
                    }
                    self.matrix(r, size, Some(format!("{name}{{{}}}", k + 1)), compressed, depth + 1)?;
                }
            }
            other => self.arrays.push(Array { name: name.clone(), dims, kind: Kind::Other(class_name(other).into()), data: None }),
        }
        let here = r.pos();
        if here > end {
            return Err(format!("`{name}` runs {} bytes past its element", here - end));
        }
        r.skip(end - here).map_err(|e| format!("`{name}`: {e}"))?;
        Ok(())
    }
}

fn decode(storage: u32, b: &[u8], big: bool) -> f64 {
    let mut a = [0u8; 8];
    if big {
        a[8 - b.len()..].copy_from_slice(b);
    } else {
        a[..b.len()].copy_from_slice(b);
    }
    let u = if big { u64::from_be_bytes(a) } else { u64::from_le_bytes(a) };
    match storage {
        1 => f64::from(u as u8 as i8),
        2 => f64::from(u as u8),
        3 => f64::from(u as u16 as i16),
        4 => f64::from(u as u16),
        5 => f64::from(u as u32 as i32),
        6 => f64::from(u as u32),
        7 => f64::from(f32::from_bits(u as u32)),
        12 => u as i64 as f64,
        13 => u as f64,
        _ => f64::from_bits(u),
    }
}

impl MatFile {
    /// Indexes `path`.
    pub fn open(path: &Path) -> Result<Self> {
        let io = |e| ForeignError::io(format!("cannot read {}", path.display()), e);
        let file = File::open(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        let mut header = [0u8; 128];
        let mut r = FileSource { r: BufReader::with_capacity(1 << 16, file), pos: 0 };
        let bad = |at: Option<u64>, m: String| ForeignError::record(path, None, at.map(|a| format!("byte {a}")), m);
        if file_len < 128 || r.read_exact(&mut header).is_err() {
            return Err(bad(Some(file_len), format!("the file ends here, {file_len} bytes in: shorter than a MAT-file's 128-byte header")));
        }
        let text = String::from_utf8_lossy(&header[..116]);
        if text.starts_with("MATLAB 7.3 MAT-file") || header[..8] == *b"\x89HDF\r\n\x1a\n" {
            return Err(bad(
                None,
                "a MATLAB 7.3 MAT-file (HDF5) is not read (ADR 0030): in MATLAB `save(file, '-v7')` (variables under 2 GB), or export the channels as CSV"
                    .into(),
            ));
        }
        if !text.starts_with("MATLAB 5.0 MAT-file") {
            return Err(bad(Some(0), format!("not a MAT-file: its header begins {:?}", text.chars().take(20).collect::<String>())));
        }
        let big = match &header[126..128] {
            b"IM" => false,
            b"MI" => true,
            other => return Err(bad(Some(126), format!("endian indicator {other:?} is neither IM nor MI"))),
        };
        let mut p = Parser { path, big, arrays: Vec::new() };
        while r.pos() < file_len {
            let at = r.pos();
            if file_len - at < 8 {
                return Err(bad(Some(at), format!("{} stray bytes after the last variable: the file is truncated", file_len - at)));
            }
            let (t, size, _) = p.tag(&mut r).map_err(io)?;
            let data_at = r.pos();
            if data_at + size > file_len {
                return Err(bad(Some(at), format!("a variable of {size} bytes, but the file ends {} bytes later: the file is truncated", file_len - data_at)));
            }
            match t {
                MI_MATRIX => p.matrix(&mut r, size, None, None, 0).map_err(|m| bad(Some(at), m))?,
                MI_COMPRESSED => {
                    let mut z = inflater(path, data_at, size).map_err(io)?;
                    let (inner, inner_size, _) = p.tag(&mut z).map_err(|e| bad(Some(at), format!("a compressed variable cannot be inflated: {e}")))?;
                    if inner != MI_MATRIX {
                        return Err(bad(Some(at), format!("a compressed element holds type {inner}, not a variable")));
                    }
                    p.matrix(&mut z, inner_size, None, Some((data_at, size)), 0).map_err(|m| bad(Some(at), format!("{m} (in a compressed variable)")))?;
                    r.skip(size).map_err(io)?;
                }
                other => return Err(bad(Some(at), format!("a top-level element of type {other}, not a variable"))),
            }
            // Top-level elements are padded to 8 bytes in uncompressed files.
            let pad = r.pos().next_multiple_of(8) - r.pos();
            if t == MI_MATRIX && pad > 0 {
                r.skip(pad.min(file_len - r.pos())).map_err(io)?;
            }
        }
        let _ = p.path;
        Ok(MatFile { path: path.to_path_buf(), big, arrays: p.arrays })
    }

    pub fn arrays(&self) -> &[Array] {
        &self.arrays
    }

    pub fn find(&self, name: &str) -> Option<&Array> {
        self.arrays.iter().find(|a| a.name == name)
    }

    /// The names of the numeric arrays, for a message.
    pub fn names(&self) -> String {
        let v: Vec<String> = self
            .arrays
            .iter()
            .map(|a| {
                format!(
                    "`{}` ({} {})",
                    a.name,
                    a.dims_text(),
                    match &a.kind {
                        Kind::Numeric => "numbers",
                        Kind::Other(w) => w,
                    }
                )
            })
            .collect();
        if v.is_empty() {
            "none".into()
        } else {
            listed(v)
        }
    }

    /// The one value of a scalar array.
    pub fn scalar(&self, name: &str) -> Result<f64> {
        let bad = |m: String| ForeignError::record(&self.path, Some(format!("`{name}`")), None, m);
        let a = self.find(name).ok_or_else(|| bad(format!("no such variable or field; the file has {}", self.names())))?;
        if a.kind != Kind::Numeric || a.len() != 1 {
            return Err(bad(format!(
                "is {} {}, not one number",
                a.dims_text(),
                match &a.kind {
                    Kind::Numeric => "numbers",
                    Kind::Other(w) => w,
                }
            )));
        }
        let mut s = self.stream(name, None, name)?;
        let mut v = Vec::new();
        s.read(&mut v, 1)?;
        v.first().copied().ok_or_else(|| bad("holds no value".into()))
    }

    /// A reader of a vector's values, or of column `column` (from 0) of a matrix.
    pub fn stream(&self, name: &str, column: Option<usize>, label: &str) -> Result<ChannelStream> {
        let bad = |m: String| ForeignError::record(&self.path, Some(label.to_string()), None, m);
        let a = self.find(name).ok_or_else(|| bad(format!("no variable or struct field `{name}`; the file has {}", self.names())))?;
        if let Kind::Other(what) = &a.kind {
            return Err(bad(format!("`{name}` is {what} ({}), not real numbers", a.dims_text())));
        }
        let Some(data) = &a.data else { return Err(bad(format!("`{name}` is empty"))) };
        let rows = a.dims.first().copied().unwrap_or(0);
        let cols: u64 = a.dims.iter().skip(1).product();
        let esize = storage_size(data.storage).unwrap_or(8);
        let (skip, count) = match column {
            None if a.dims.iter().filter(|&&d| d != 1).count() <= 1 => (0, a.len()),
            None => return Err(bad(format!("`{name}` is a {} matrix: give index = the column (from 0) that holds this channel", a.dims_text()))),
            Some(c) if a.dims.len() == 2 && (c as u64) < cols => (c as u64 * rows * esize, rows),
            Some(c) => return Err(bad(format!("`{name}` is {}: it has no column {c} (columns count from 0)", a.dims_text()))),
        };
        let source: Box<dyn Source> = match data.place {
            Place::File(at) => {
                let f = File::open(&self.path).map_err(|e| ForeignError::io(format!("cannot open {}", self.path.display()), e))?;
                let mut s = FileSource { r: BufReader::with_capacity(1 << 16, f), pos: 0 };
                s.skip(at + skip).map_err(|e| ForeignError::io(format!("cannot read {}", self.path.display()), e))?;
                Box::new(s)
            }
            Place::Inflated { start, len, at } => {
                let mut z = inflater(&self.path, start, len).map_err(|e| ForeignError::io(format!("cannot read {}", self.path.display()), e))?;
                z.skip(at + skip).map_err(|e| bad(format!("its compressed variable cannot be inflated: {e}")))?;
                Box::new(z)
            }
        };
        Ok(ChannelStream {
            path: self.path.clone(),
            label: label.to_string(),
            source,
            storage: data.storage,
            esize,
            big: self.big,
            left: count,
            small: data.small.clone().map(|v| v.into_iter().skip((skip / esize) as usize).take(count as usize).collect()),
            buf: Vec::new(),
        })
    }
}

/// One channel's values, read in order, a block at a time.
pub struct ChannelStream {
    path: PathBuf,
    label: String,
    source: Box<dyn Source>,
    storage: u32,
    esize: u64,
    big: bool,
    left: u64,
    small: Option<Vec<f64>>,
    buf: Vec<u8>,
}

impl ChannelStream {
    /// Values this stream still holds.
    pub fn remaining(&self) -> u64 {
        self.left
    }

    /// Appends up to `max` next values to `out`; returns how many (0 at the end).
    pub fn read(&mut self, out: &mut Vec<f64>, max: usize) -> Result<usize> {
        let n = (max as u64).min(self.left) as usize;
        if n == 0 {
            return Ok(0);
        }
        if let Some(small) = &mut self.small {
            out.extend(small.drain(..n.min(small.len())));
            self.left -= n as u64;
            return Ok(n);
        }
        self.buf.resize(n * self.esize as usize, 0);
        let at = self.source.pos();
        self.source.read_exact(&mut self.buf).map_err(|e| {
            ForeignError::record(
                &self.path,
                Some(self.label.clone()),
                Some(format!("byte {at} of the variable's values")),
                format!("cannot read the values: {e}"),
            )
        })?;
        out.extend(self.buf.chunks_exact(self.esize as usize).map(|c| decode(self.storage, c, self.big)));
        self.left -= n as u64;
        Ok(n)
    }
}
