//! An ASCII record as a command reads it: plain or gzip-compressed (`.gz`, recognised by its
//! magic bytes, not its name), and the rig it was measured on. The rig is `--rig FILE` when
//! given; otherwise the one the record's header names (`# rig: rig.toml`, resolved beside the
//! record), or the built-in rig when the header names that; a header naming neither is warned
//! about and the built-in rig is used.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use oilfilm_identification::ascii::{self, Record};
use oilfilm_physics::config::RigConfig;

/// The record in a file, plain or gzip (recognised by its magic bytes), read as a stream: the
/// text is never held whole, only the record's columns.
pub fn read_record(path: &Path) -> Result<Record> {
    use std::io::BufRead;
    let name = path.display().to_string();
    let file = std::fs::File::open(path).with_context(|| format!("cannot read {name}"))?;
    let mut stream = std::io::BufReader::with_capacity(1 << 16, file);
    let gzip = stream.fill_buf().with_context(|| format!("cannot read {name}"))?.starts_with(&[0x1f, 0x8b]);
    let record = if gzip {
        ascii::read_stream(std::io::BufReader::with_capacity(1 << 16, flate2::bufread::MultiGzDecoder::new(stream)), &name)
    } else {
        ascii::read_stream(stream, &name)
    };
    Ok(record?)
}

/// A parsed record and the rig it is analysed with.
pub struct AsciiInput {
    pub record: Record,
    pub rig: RigConfig,
    /// Where the rig came from, for the output.
    pub rig_source: String,
}

/// Reads `path` and resolves its rig (`explicit` is `--rig`).
pub fn load(path: &Path, explicit: Option<&Path>) -> Result<AsciiInput> {
    let record = read_record(path)?;
    let (rig, rig_source) = rig_of(path, &record.header, explicit)?;
    Ok(AsciiInput { record, rig, rig_source })
}

/// The header of the record in `path` (plain or gzip), reading no further than its column
/// line: the error of a header that cannot be interpreted names its line and column.
pub fn read_header(path: &Path) -> Result<ascii::Header> {
    let name = path.display().to_string();
    let stream = oilfilm_graph::lines::open_ascii(&name)?;
    let mut reader = ascii::LineReader::new(&name);
    let done = std::cell::Cell::new(false);
    let (mut header, mut failed, mut last) = (None, None, 0);
    oilfilm_graph::lines::read_lines(stream, &|| done.get(), &mut |number, line, _cut| {
        last = number;
        match reader.feed(number, line) {
            Ok(ascii::Fed::Header(h)) => header = Some(h),
            Ok(_) => return Ok(()),
            // Every later line would give the same error.
            Err(e) => failed = Some(e),
        }
        done.set(true);
        Ok(())
    })?;
    match (header, failed) {
        (Some(h), _) => Ok(h),
        (None, Some(e)) => Err(e.into()),
        (None, None) => Err(reader.finish(last.max(1)).err().map_or_else(|| anyhow::anyhow!("{name}: the file ends in its header"), Into::into)),
    }
}

/// The rig `header` names for the record in `path`, or `explicit` (`--rig`), and where it
/// came from.
pub fn rig_of(path: &Path, header: &ascii::Header, explicit: Option<&Path>) -> Result<(RigConfig, String)> {
    let name = path.display().to_string();
    let named = header.rig.trim().to_string();
    let beside = |n: &str| -> Option<PathBuf> {
        let p = Path::new(n);
        let candidate = if p.is_absolute() { p.to_path_buf() } else { path.parent().unwrap_or(Path::new(".")).join(p) };
        candidate.is_file().then_some(candidate)
    };
    let read_rig = |p: &Path| -> Result<RigConfig> { Ok(oilfilm_graph::node::read_rig_file(p)?) };
    let (rig, rig_source) = match explicit {
        Some(p) => {
            if let Some(h) = beside(&named).filter(|h| h.canonicalize().ok() != p.canonicalize().ok()) {
                eprintln!("note: {name} names rig file {}, --rig {} was given and is used", h.display(), p.display());
            }
            (read_rig(p)?, format!("{} (--rig)", p.display()))
        }
        None => {
            let builtin = RigConfig::zhou2004()?;
            match beside(&named) {
                Some(h) => (read_rig(&h).with_context(|| format!("{name} names its rig `{named}`"))?, format!("{} (named by the record)", h.display())),
                None if named.is_empty() || named == builtin.name => (builtin, "built-in zhou2004".into()),
                None => {
                    eprintln!(
                        "warning: {name} names rig `{named}`, which is neither a file beside it nor the built-in rig `{}`; the built-in rig is used (give --rig FILE)",
                        builtin.name
                    );
                    (builtin, format!("built-in zhou2004 (the record names `{named}`, not found)"))
                }
            }
        }
    };
    Ok((rig, rig_source))
}
