//! CDR (XCDR1, little endian) as rmw_fastrtps writes a ROS 2 message.
//!
//! * A 4-byte encapsulation header `00 01 00 00` (CDR_LE, no options).
//! * Alignment is counted from the end of that header: a primitive of size n starts at an
//!   offset that is a multiple of n (at most 8).
//! * `string`: `uint32` length **including** the terminating NUL, the UTF-8 bytes, the NUL.
//! * `T[]`: `uint32` element count, then the elements, each aligned as itself; an empty
//!   sequence is the count alone (no padding for elements that are not there).
//! * `T[N]`: the N elements, no count.
//! * `bool`: one byte, 0 or 1. Nested messages: their fields in order, nothing around them.
//!
//! Two things rclpy's `serialize_message` (rmw_fastrtps, Fast-CDR 2) does that a reader must
//! expect, found by the golden tests:
//! * it does not zero the padding it skips, so padding bytes may be any value;
//! * the buffer it returns has the length Fast-CDR's size calculator predicted, and the
//!   calculator aligns an *empty* sequence's absent elements (to 8 for `float64[]`), so the
//!   message can be followed by a few bytes the data does not use (up to 4 per empty
//!   `float64[]`), unwritten: any value, often the previous message's. The data itself has
//!   no such padding.
//!
//! The writer here writes zeros, no trailing bytes, and can report where its padding is and
//! the length Fast-CDR's calculator would give ([`encode_with_padding`]); [`decode`] ignores
//! trailing bytes, [`decode_exact`] refuses more than 3.

use std::ops::Range;

/// The encapsulation header of little-endian plain CDR.
pub const ENCAPSULATION_CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Why bytes could not be decoded. `field` is the dotted path of the field being read
/// (`header.stamp.sec`, `values[3]`), empty for the encapsulation header and trailing bytes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("CDR decode error at byte {offset} (field `{field}`): {what}")]
pub struct CdrError {
    pub field: String,
    /// Offset in the buffer (including the 4-byte encapsulation header).
    pub offset: usize,
    pub what: String,
}

impl CdrError {
    /// Prefix the field path with the enclosing field's name (for nested messages).
    pub fn within(mut self, outer: &str) -> Self {
        self.field = if self.field.is_empty() { outer.to_string() } else { format!("{outer}.{}", self.field) };
        self
    }
}

/// Appends CDR to a buffer that starts with the encapsulation header.
#[derive(Debug)]
pub struct CdrWriter {
    buf: Vec<u8>,
    padding: Option<Vec<Range<usize>>>,
    /// Body offset as Fast-CDR's size calculator counts it (it also aligns the elements of
    /// empty sequences).
    calculator: usize,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    pub fn new() -> Self {
        Self::with_capacity(64)
    }

    pub fn with_capacity(bytes: usize) -> Self {
        let mut buf = Vec::with_capacity(bytes.max(4));
        buf.extend_from_slice(&ENCAPSULATION_CDR_LE);
        Self { buf, padding: None, calculator: 0 }
    }

    /// Pad with zeros so that the next byte's offset (after the header) is a multiple of
    /// `n`.
    pub fn align(&mut self, n: usize) {
        self.calculator = self.calculator.next_multiple_of(n);
        let pos = self.buf.len() - 4;
        let pad = (n - pos % n) % n;
        if pad > 0 {
            let start = self.buf.len();
            self.buf.resize(start + pad, 0);
            if let Some(p) = self.padding.as_mut() {
                p.push(start..start + pad);
            }
        }
    }

    pub fn bytes(&mut self, b: &[u8]) {
        self.calculator += b.len();
        self.buf.extend_from_slice(b);
    }

    pub fn u8(&mut self, v: u8) {
        self.bytes(&[v]);
    }

    /// Fast-CDR's size calculator aligns for the elements of an empty sequence.
    fn empty_sequence(&mut self, element_align: usize) {
        self.calculator = self.calculator.next_multiple_of(element_align);
    }
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.bytes(&v.to_le_bytes());
    }

    /// A sequence's element count (or a string's length) as `uint32`.
    pub fn len(&mut self, n: usize) {
        // A message larger than 4 GiB cannot be sent by any DDS; saturating keeps the writer
        // total (the length would then disagree with the data and the reader would refuse it).
        self.u32(u32::try_from(n).unwrap_or(u32::MAX));
    }

    pub fn string(&mut self, s: &str) {
        self.len(s.len() + 1);
        self.bytes(s.as_bytes());
        self.u8(0);
    }

    pub fn position(&self) -> usize {
        self.buf.len()
    }

    pub fn finish(self) -> Vec<u8> {
        self.buf
    }

    /// The serialized length Fast-CDR's size calculator gives (header included): what
    /// rclpy's `serialize_message` returns.
    pub fn fastcdr_length(&self) -> usize {
        4 + self.calculator.max(self.buf.len() - 4)
    }
}

/// Reads CDR from a buffer that starts with the encapsulation header.
#[derive(Debug)]
pub struct CdrReader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    /// Checks the encapsulation header (little-endian plain CDR only).
    pub fn new(buf: &'a [u8]) -> Result<Self, CdrError> {
        let err = |what: String| CdrError { field: String::new(), offset: 0, what };
        if buf.len() < 4 {
            return Err(err(format!("{} bytes: shorter than the 4-byte encapsulation header", buf.len())));
        }
        match [buf[0], buf[1]] {
            [0x00, 0x01] => Ok(Self { buf, pos: 4 }),
            [0x00, 0x00] => Err(err("big-endian CDR (encapsulation 00 00) is not supported".into())),
            [a, b] => Err(err(format!("encapsulation {a:02x} {b:02x} is not plain little-endian CDR (00 01)"))),
        }
    }

    pub fn error(&self, field: &str, what: impl Into<String>) -> CdrError {
        CdrError { field: field.to_string(), offset: self.pos, what: what.into() }
    }

    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    pub fn align(&mut self, n: usize, field: &str) -> Result<(), CdrError> {
        let pad = (n - (self.pos - 4) % n) % n;
        if pad > self.remaining() {
            return Err(self.error(field, "buffer ends inside alignment padding"));
        }
        self.pos += pad;
        Ok(())
    }

    pub fn take(&mut self, n: usize, field: &str) -> Result<&'a [u8], CdrError> {
        if n > self.remaining() {
            return Err(self.error(field, format!("needs {n} bytes, {} left", self.remaining())));
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// `N` bytes after aligning to `N` (a primitive of size `N`).
    pub fn primitive<const N: usize>(&mut self, field: &str) -> Result<[u8; N], CdrError> {
        self.align(N, field)?;
        let s = self.take(N, field)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// A sequence's element count, refused if the remaining bytes cannot hold that many
    /// elements of at least `min_element_bytes` each (so a corrupt count cannot allocate).
    /// The refusal's offset is the count's own.
    pub fn len(&mut self, field: &str, min_element_bytes: usize) -> Result<usize, CdrError> {
        let n = u32::from_le_bytes(self.primitive::<4>(field)?) as usize;
        if n.saturating_mul(min_element_bytes.max(1)) > self.remaining() {
            let what = format!("count {n} exceeds the {} bytes left", self.remaining());
            return Err(CdrError { field: field.to_string(), offset: self.pos - 4, what });
        }
        Ok(n)
    }

    pub fn string(&mut self, field: &str) -> Result<String, CdrError> {
        let start = self.pos;
        let n = self.len(field, 1)?;
        if n == 0 {
            return Err(CdrError { field: field.into(), offset: start, what: "string length 0 (it must count the NUL)".into() });
        }
        let b = self.take(n, field)?;
        let (text, nul) = b.split_at(n - 1);
        if nul != [0] {
            return Err(CdrError { field: field.into(), offset: start, what: "string is not NUL-terminated".into() });
        }
        match std::str::from_utf8(text) {
            Ok(s) => Ok(s.to_string()),
            Err(e) => Err(CdrError { field: field.into(), offset: start, what: format!("string is not UTF-8: {e}") }),
        }
    }

    pub fn position(&self) -> usize {
        self.pos
    }

    /// Accept the end of the message strictly: at most 3 trailing bytes (padding to a
    /// 4-byte boundary that some DDS writers add), nothing more.
    pub fn finish(self) -> Result<(), CdrError> {
        if self.remaining() > 3 {
            return Err(self.error("", format!("{} bytes left after the last field", self.remaining())));
        }
        Ok(())
    }
}

/// A value that has a ROS .msg type and a CDR form: primitives, strings, fixed arrays,
/// sequences and messages.
pub trait CdrField: Sized {
    /// The type as a .msg file spells it: `float64`, `string[]`, `float64[4]`,
    /// `std_msgs/Header`.
    fn ros_type() -> String;
    /// Smallest encoded size of one value, bytes (for checking sequence counts).
    const MIN_BYTES: usize;
    fn write(&self, w: &mut CdrWriter);
    /// `field` names the field being read, for errors.
    fn read(r: &mut CdrReader, field: &str) -> Result<Self, CdrError>;
}

macro_rules! primitive {
    ($t:ty, $name:literal, $n:literal) => {
        impl CdrField for $t {
            fn ros_type() -> String {
                $name.to_string()
            }
            const MIN_BYTES: usize = $n;
            fn write(&self, w: &mut CdrWriter) {
                w.align($n);
                w.bytes(&self.to_le_bytes());
            }
            fn read(r: &mut CdrReader, field: &str) -> Result<Self, CdrError> {
                Ok(<$t>::from_le_bytes(r.primitive::<$n>(field)?))
            }
        }
    };
}
primitive!(u8, "uint8", 1);
primitive!(i8, "int8", 1);
primitive!(u16, "uint16", 2);
primitive!(i16, "int16", 2);
primitive!(u32, "uint32", 4);
primitive!(i32, "int32", 4);
primitive!(u64, "uint64", 8);
primitive!(i64, "int64", 8);
primitive!(f32, "float32", 4);
primitive!(f64, "float64", 8);

impl CdrField for bool {
    fn ros_type() -> String {
        "bool".into()
    }
    const MIN_BYTES: usize = 1;
    fn write(&self, w: &mut CdrWriter) {
        w.u8(u8::from(*self));
    }
    fn read(r: &mut CdrReader, field: &str) -> Result<Self, CdrError> {
        match r.primitive::<1>(field)? {
            [0] => Ok(false),
            [1] => Ok(true),
            [b] => Err(r.error(field, format!("bool byte {b} is neither 0 nor 1"))),
        }
    }
}

impl CdrField for String {
    fn ros_type() -> String {
        "string".into()
    }
    const MIN_BYTES: usize = 5;
    fn write(&self, w: &mut CdrWriter) {
        w.string(self);
    }
    fn read(r: &mut CdrReader, field: &str) -> Result<Self, CdrError> {
        r.string(field)
    }
}

/// Element types of sequences and arrays (not themselves arrays: ROS has no nested arrays).
pub trait CdrElement: CdrField {
    /// Alignment of the element's first byte.
    const ALIGN: usize;

    /// Reads `n` elements (the count already read and checked). Element by element unless
    /// the type reads them in bulk.
    fn read_many(r: &mut CdrReader, n: usize, field: &str) -> Result<Vec<Self>, CdrError> {
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            out.push(Self::read(r, field).map_err(|e| element_error(e, field, i))?);
        }
        Ok(out)
    }
}
macro_rules! element {
    ($($t:ty: $a:literal),*) => { $( impl CdrElement for $t { const ALIGN: usize = $a; } )* };
}
element!(bool: 1, String: 4);

/// Numeric sequences in bulk: the elements of a sequence are contiguous after one alignment
/// (each is as long as its alignment, so every later one is aligned too), so one bounds check
/// and a `from_le_bytes` per chunk replace a checked read per element. The DAQ frames'
/// `int16` counts and float64 values and the conditioned frames' float64 columns are nearly
/// all of our bytes.
macro_rules! bulk_element {
    ($($t:ty),*) => { $(
        impl CdrElement for $t {
            const ALIGN: usize = std::mem::size_of::<$t>();
            fn read_many(r: &mut CdrReader, n: usize, field: &str) -> Result<Vec<Self>, CdrError> {
                const N: usize = std::mem::size_of::<$t>();
                if n == 0 {
                    return Ok(Vec::new());
                }
                r.align(N, field)?;
                let bytes = r.take(n.checked_mul(N).ok_or_else(|| r.error(field, format!("count {n} overflows")))?, field)?;
                Ok(bytes
                    .chunks_exact(N)
                    .map(|b| {
                        let mut a = [0u8; N];
                        a.copy_from_slice(b);
                        <$t>::from_le_bytes(a)
                    })
                    .collect())
            }
        }
    )* };
}
bulk_element!(u8, i8, u16, i16, u32, i32, u64, i64, f32, f64);

/// The error of element `i` of sequence or array `field`: `field[i]`, followed by the path
/// inside the element when it is a message (`new_parameters[1].value.string_value`).
fn element_error(e: CdrError, field: &str, i: usize) -> CdrError {
    let inner = e.field.strip_prefix(field).unwrap_or("");
    CdrError { field: format!("{field}[{i}]{inner}"), ..e }
}

impl<T: CdrElement> CdrField for Vec<T> {
    fn ros_type() -> String {
        format!("{}[]", T::ros_type())
    }
    const MIN_BYTES: usize = 4;
    fn write(&self, w: &mut CdrWriter) {
        w.len(self.len());
        if self.is_empty() {
            w.empty_sequence(T::ALIGN);
        }
        for v in self {
            v.write(w);
        }
    }
    fn read(r: &mut CdrReader, field: &str) -> Result<Self, CdrError> {
        let n = r.len(field, T::MIN_BYTES)?;
        T::read_many(r, n, field)
    }
}

impl<T: CdrElement + Copy + Default, const N: usize> CdrField for [T; N] {
    fn ros_type() -> String {
        format!("{}[{N}]", T::ros_type())
    }
    const MIN_BYTES: usize = N * T::MIN_BYTES;
    fn write(&self, w: &mut CdrWriter) {
        for v in self {
            v.write(w);
        }
    }
    fn read(r: &mut CdrReader, field: &str) -> Result<Self, CdrError> {
        let mut out = [T::default(); N];
        for (i, slot) in out.iter_mut().enumerate() {
            *slot = T::read(r, field).map_err(|e| element_error(e, field, i))?;
        }
        Ok(out)
    }
}

/// A whole ROS message: its fields in .msg order, its full type name and its definition.
pub trait RosMessage: CdrField {
    /// `pkg/msg/Type`.
    const TYPE_NAME: &'static str;
    /// The .msg text (for our own types: the file in `msgs/msg/`, embedded).
    const DEFINITION: &'static str;
    /// `(name, .msg type)` of every field, in order.
    fn fields() -> Vec<(&'static str, String)>;
    /// `(name, .msg type, value as written)` of every constant.
    const CONSTANTS: &'static [(&'static str, &'static str, &'static str)];
}

/// Serialise a message: encapsulation header and CDR body, as `serialize_message` does.
pub fn encode<M: RosMessage>(msg: &M) -> Vec<u8> {
    let mut w = CdrWriter::new();
    msg.write(&mut w);
    w.finish()
}

/// A serialised message with where its padding is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Layout {
    pub bytes: Vec<u8>,
    /// Byte ranges of `bytes` that are alignment padding (zeros here, anything from ROS).
    pub padding: Vec<Range<usize>>,
    /// The length rclpy's `serialize_message` gives the same message (Fast-CDR's size
    /// calculator): `bytes.len()` plus the unused bytes it leaves after the data.
    pub fastcdr_length: usize,
}

/// Serialise and report where the writer put alignment padding.
pub fn encode_with_padding<M: RosMessage>(msg: &M) -> Layout {
    let mut w = CdrWriter::new();
    w.padding = Some(Vec::new());
    msg.write(&mut w);
    let padding = w.padding.take().unwrap_or_default();
    let fastcdr_length = w.fastcdr_length();
    Layout { bytes: w.finish(), padding, fastcdr_length }
}

/// Deserialise a message, ignoring bytes after its last field (rclpy's buffers can carry a
/// few; see the module documentation).
pub fn decode<M: RosMessage>(bytes: &[u8]) -> Result<M, CdrError> {
    let mut r = CdrReader::new(bytes)?;
    M::read(&mut r, "")
}

/// Deserialise a message; at most 3 bytes may follow its last field.
pub fn decode_exact<M: RosMessage>(bytes: &[u8]) -> Result<M, CdrError> {
    let mut r = CdrReader::new(bytes)?;
    let m = M::read(&mut r, "")?;
    r.finish()?;
    Ok(m)
}
