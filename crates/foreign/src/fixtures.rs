//! Minimal writers of the three formats: float64 channels as a TDMS file (several groups,
//! several segments, contiguous or interleaved, either byte order), as a MAT-file (level 5:
//! one variable per channel, a struct of channels or one matrix, compressed or not) and as
//! CSV. For this project's tests, benchmark and worked example only: the files labs bring are
//! made by their own tools, and the interop tests make them with npTDMS, scipy and pandas.

use std::io::Write;
use std::path::Path;

/// One float64 channel of a TDMS file.
pub struct TdmsChannel<'a> {
    pub group: &'a str,
    pub name: &'a str,
    pub values: &'a [f64],
    /// Float64 properties (e.g. `wf_increment`).
    pub properties: Vec<(&'a str, f64)>,
}

/// How a TDMS file is laid out.
#[derive(Debug, Clone, Copy)]
pub struct TdmsLayout {
    pub segments: usize,
    pub interleaved: bool,
    pub big_endian: bool,
}

struct Out {
    bytes: Vec<u8>,
    big: bool,
}

impl Out {
    fn u32(&mut self, v: u32) {
        self.bytes.extend(if self.big { v.to_be_bytes() } else { v.to_le_bytes() });
    }
    fn u64(&mut self, v: u64) {
        self.bytes.extend(if self.big { v.to_be_bytes() } else { v.to_le_bytes() });
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.bytes.extend(s.as_bytes());
    }
}

fn quoted(name: &str) -> String {
    format!("'{}'", name.replace('\'', "''"))
}

/// Writes `channels` (all of one length) as a TDMS file. The first segment lists every
/// object (a new object list); the middle ones hold raw data only, or repeat each raw data
/// index by reference (the second of three or more); a shorter last segment gives new
/// indices without a new object list: the incremental forms LabVIEW writes.
pub fn tdms(path: &Path, channels: &[TdmsChannel], layout: TdmsLayout) -> std::io::Result<()> {
    let n = channels.first().map_or(0, |c| c.values.len());
    let segments = layout.segments.max(1);
    let per = n.div_ceil(segments).max(1);
    let mut file = Vec::new();
    let mut groups: Vec<&str> = Vec::new();
    for c in channels {
        if !groups.contains(&c.group) {
            groups.push(c.group);
        }
    }
    let mut start = 0;
    let mut k = 0;
    while start < n || (n == 0 && k == 0) {
        let count = per.min(n - start);
        let mut meta = Out { bytes: Vec::new(), big: layout.big_endian };
        let mut toc = 1 << 3;
        if layout.interleaved {
            toc |= 1 << 5;
        }
        if layout.big_endian {
            toc |= 1 << 6;
        }
        let path_of = |c: &TdmsChannel| format!("/{}/{}", quoted(c.group), quoted(c.name));
        if k == 0 {
            toc |= (1 << 1) | (1 << 2);
            meta.u32((1 + groups.len() + channels.len()) as u32);
            meta.string("/");
            meta.u32(0xFFFF_FFFF);
            meta.u32(0);
            for g in &groups {
                meta.string(&format!("/{}", quoted(g)));
                meta.u32(0xFFFF_FFFF);
                meta.u32(0);
            }
            for c in channels {
                meta.string(&path_of(c));
                meta.u32(20);
                meta.u32(10);
                meta.u32(1);
                meta.u64(count as u64);
                meta.u32(c.properties.len() as u32);
                for (name, v) in &c.properties {
                    meta.string(name);
                    meta.u32(10);
                    meta.f64(*v);
                }
            }
        } else if count != per || (k == 1 && segments >= 3) {
            toc |= 1 << 1;
            meta.u32(channels.len() as u32);
            for c in channels {
                meta.string(&path_of(c));
                if count == per {
                    meta.u32(0);
                } else {
                    meta.u32(20);
                    meta.u32(10);
                    meta.u32(1);
                    meta.u64(count as u64);
                }
                meta.u32(0);
            }
        }
        let mut raw = Out { bytes: Vec::new(), big: layout.big_endian };
        if layout.interleaved {
            for i in start..start + count {
                for c in channels {
                    raw.f64(c.values[i]);
                }
            }
        } else {
            for c in channels {
                for v in &c.values[start..start + count] {
                    raw.f64(*v);
                }
            }
        }
        let mut lead = Out { bytes: b"TDSm".to_vec(), big: false };
        lead.u32(toc);
        lead.big = layout.big_endian;
        lead.u32(4713);
        lead.u64((meta.bytes.len() + raw.bytes.len()) as u64);
        lead.u64(meta.bytes.len() as u64);
        file.extend(lead.bytes);
        file.extend(meta.bytes);
        file.extend(raw.bytes);
        start += count;
        k += 1;
        if n == 0 {
            break;
        }
    }
    std::fs::write(path, file)
}

/// How a MAT-file holds its channels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MatLayout<'a> {
    /// One column vector per channel, named as the channel.
    Variables,
    /// One 1x1 struct of that name, a field per channel (and per scalar).
    Struct(&'a str),
    /// One N x C matrix of that name, a column per channel in order (scalars as variables).
    Matrix(&'a str),
}

fn element(out: &mut Vec<u8>, kind: u32, data: &[u8]) {
    out.extend(kind.to_le_bytes());
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
    out.resize(out.len().next_multiple_of(8), 0);
}

/// A double matrix element (tag included) of `rows` x `cols` values, column-major.
fn double_matrix(name: &str, rows: usize, cols: usize, values: impl Iterator<Item = f64>) -> Vec<u8> {
    let mut body = Vec::new();
    element(&mut body, 6, &[6, 0, 0, 0, 0, 0, 0, 0]);
    element(&mut body, 5, &[(rows as u32).to_le_bytes(), (cols as u32).to_le_bytes()].concat());
    element(&mut body, 1, name.as_bytes());
    let data: Vec<u8> = values.flat_map(f64::to_le_bytes).collect();
    element(&mut body, 9, &data);
    let mut out = Vec::new();
    element(&mut out, 14, &body);
    out
}

/// Writes `columns` (all of one length) and `scalars` as a level-5 MAT-file.
pub fn mat(path: &Path, columns: &[(&str, &[f64])], scalars: &[(&str, f64)], layout: MatLayout, compress: bool) -> std::io::Result<()> {
    let mut header = b"MATLAB 5.0 MAT-file, written by oilfilm's test fixtures".to_vec();
    header.resize(116, b' ');
    header.extend([0u8; 8]);
    header.extend([0x00, 0x01, b'I', b'M']);
    let n = columns.first().map_or(0, |c| c.1.len());
    let mut variables: Vec<Vec<u8>> = Vec::new();
    match layout {
        MatLayout::Variables => {
            variables.extend(columns.iter().map(|(name, v)| double_matrix(name, v.len(), 1, v.iter().copied())));
            variables.extend(scalars.iter().map(|(name, v)| double_matrix(name, 1, 1, std::iter::once(*v))));
        }
        MatLayout::Matrix(name) => {
            variables.push(double_matrix(name, n, columns.len(), columns.iter().flat_map(|(_, v)| v.iter().copied())));
            variables.extend(scalars.iter().map(|(name, v)| double_matrix(name, 1, 1, std::iter::once(*v))));
        }
        MatLayout::Struct(name) => {
            let fields: Vec<(&str, Vec<u8>)> = columns
                .iter()
                .map(|(f, v)| (*f, double_matrix("", v.len(), 1, v.iter().copied())))
                .chain(scalars.iter().map(|(f, v)| (*f, double_matrix("", 1, 1, std::iter::once(*v)))))
                .collect();
            let mut body = Vec::new();
            element(&mut body, 6, &[2, 0, 0, 0, 0, 0, 0, 0]);
            element(&mut body, 5, &[1u32.to_le_bytes(), 1u32.to_le_bytes()].concat());
            element(&mut body, 1, name.as_bytes());
            // Field name length as a small data element.
            body.extend(((4u32 << 16) | 5).to_le_bytes());
            body.extend(32u32.to_le_bytes());
            let names: Vec<u8> = fields
                .iter()
                .flat_map(|(f, _)| {
                    let mut b = f.as_bytes().to_vec();
                    b.resize(32, 0);
                    b
                })
                .collect();
            element(&mut body, 1, &names);
            for (_, m) in &fields {
                body.extend(m);
            }
            let mut out = Vec::new();
            element(&mut out, 14, &body);
            variables.push(out);
        }
    }
    let mut file = header;
    for v in variables {
        if compress {
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            z.write_all(&v)?;
            let data = z.finish()?;
            file.extend(15u32.to_le_bytes());
            file.extend((data.len() as u32).to_le_bytes());
            file.extend(data);
        } else {
            file.extend(v);
        }
    }
    std::fs::write(path, file)
}

/// Writes a CSV file: `header`, an optional units row, then the rows of `columns` (values
/// in Rust's shortest round-trip form, so they read back bit for bit).
pub fn csv(path: &Path, columns: &[(&str, &[f64])], units: Option<&[&str]>) -> std::io::Result<()> {
    let mut text = String::new();
    text.push_str(&columns.iter().map(|c| c.0).collect::<Vec<_>>().join(","));
    text.push('\n');
    if let Some(u) = units {
        text.push_str(&u.join(","));
        text.push('\n');
    }
    let n = columns.first().map_or(0, |c| c.1.len());
    for i in 0..n {
        let row: Vec<String> = columns.iter().map(|c| format!("{:?}", c.1[i])).collect();
        text.push_str(&row.join(","));
        text.push('\n');
    }
    std::fs::write(path, text)
}
