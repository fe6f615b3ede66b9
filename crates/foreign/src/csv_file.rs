//! CSV records through the `csv` crate: a header row naming the columns, optionally a units
//! row, then one row per scan, read row by row. Numbers use a decimal point; a comma as the
//! decimal separator is refused with the way round it (a comma-decimal file is ambiguous
//! with a comma delimiter, and silently reading `1,5` as two fields or as 15 loses data).

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use crate::error::{listed, shown, ForeignError, Result};
use crate::map::CsvOptions;

/// A CSV file opened at its first data row.
pub struct CsvRows {
    path: PathBuf,
    reader: csv::Reader<BufReader<File>>,
    header: Vec<String>,
    units: Option<Vec<String>>,
    record: csv::ByteRecord,
    /// Rows read ahead (to find the rate from a time column) and not yet handed out.
    ahead: std::collections::VecDeque<(u64, csv::ByteRecord)>,
    /// 1-based data row of the next row handed out.
    row: u64,
}

/// `1,5` or `-0,25e-3`: a number with a comma where the point goes.
fn comma_decimal(field: &str) -> bool {
    let f = field.trim().trim_start_matches(['+', '-']);
    let Some((a, b)) = f.split_once(',') else { return false };
    let b = b.split(['e', 'E']).next().unwrap_or("");
    !a.is_empty() && !b.is_empty() && a.bytes().all(|c| c.is_ascii_digit()) && b.bytes().all(|c| c.is_ascii_digit())
}

impl CsvRows {
    pub fn open(path: &Path, options: &CsvOptions) -> Result<Self> {
        let file = File::open(path).map_err(|e| ForeignError::io(format!("cannot open {}", path.display()), e))?;
        let mut reader =
            csv::ReaderBuilder::new().delimiter(options.delimiter).has_headers(false).flexible(true).from_reader(BufReader::with_capacity(1 << 16, file));
        let mut record = csv::ByteRecord::new();
        let bad = |line: Option<u64>, m: String| ForeignError::record(path, None, line.map(|l| format!("line {l}")), m);
        let read = |reader: &mut csv::Reader<BufReader<File>>, record: &mut csv::ByteRecord| -> Result<bool> {
            reader.read_byte_record(record).map_err(|e| bad(e.position().map(|p| p.line()), format!("not readable as CSV: {e}")))
        };
        if !read(&mut reader, &mut record)? {
            return Err(bad(None, "the file is empty: a header row naming the columns is needed".into()));
        }
        let text =
            |r: &csv::ByteRecord| -> Vec<String> { r.iter().map(|f| String::from_utf8_lossy(f).trim().trim_start_matches('\u{feff}').to_string()).collect() };
        let header = text(&record);
        if header.iter().all(|h| h.parse::<f64>().is_ok()) {
            return Err(bad(
                Some(1),
                "the first row is numbers: a header row naming the columns is needed (the map's `from` names them; `index` counts them from 0)".into(),
            ));
        }
        let units = if options.units_row {
            if !read(&mut reader, &mut record)? {
                return Err(bad(Some(2), "the file ends before its units row".into()));
            }
            Some(text(&record))
        } else {
            None
        };
        let rows = CsvRows { path: path.to_path_buf(), reader, header, units, record, ahead: Default::default(), row: 1 };
        if let Some(u) = &rows.units {
            if u.len() != rows.header.len() {
                return Err(bad(Some(2), format!("the units row has {} fields, the header {}", u.len(), rows.header.len())));
            }
        }
        Ok(rows)
    }

    pub fn header(&self) -> &[String] {
        &self.header
    }

    pub fn units(&self) -> Option<&[String]> {
        self.units.as_deref()
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The column a map names: by header name, or by position from 0.
    pub fn column(&self, from: Option<&str>, index: Option<usize>, label: &str) -> Result<usize> {
        let bad = |m: String| ForeignError::record(&self.path, Some(label.to_string()), Some("line 1".into()), m);
        match (from, index) {
            (Some(name), _) => {
                let hits: Vec<usize> = self.header.iter().enumerate().filter(|(_, h)| *h == name).map(|(i, _)| i).collect();
                match hits.as_slice() {
                    [one] => Ok(*one),
                    [] => Err(bad(format!("no column `{name}` in the header ({})", listed(self.header.iter().map(|h| format!("`{}`", shown(h))))))),
                    many => Err(bad(format!("the header names `{name}` {} times (columns {})", many.len(), listed(many.iter().map(usize::to_string))))),
                }
            }
            (None, Some(i)) if i < self.header.len() => Ok(i),
            (None, Some(i)) => Err(bad(format!("no column {i}: the header has {} (counted from 0)", self.header.len()))),
            (None, None) => Err(bad("names no column".into())),
        }
    }

    /// Reads rows ahead until `n` are buffered (or the file ends).
    pub fn look_ahead(&mut self, n: usize) -> Result<()> {
        while self.ahead.len() < n {
            let line = self.reader.position().line();
            let more = self
                .reader
                .read_byte_record(&mut self.record)
                .map_err(|e| ForeignError::record(&self.path, None, e.position().map(|p| format!("line {}", p.line())), format!("not readable as CSV: {e}")))?;
            if !more {
                break;
            }
            let line = self.record.position().map_or(line, |p| p.line());
            self.ahead.push_back((line, self.record.clone()));
        }
        Ok(())
    }

    /// The `k`-th buffered row's value of `column`, parsed (for the time column).
    pub fn ahead_value(&self, k: usize, column: usize, label: &str) -> Option<Result<f64>> {
        let (line, r) = self.ahead.get(k)?;
        Some(self.parse(r, *line, column, label))
    }

    fn parse(&self, r: &csv::ByteRecord, line: u64, column: usize, label: &str) -> Result<f64> {
        let at = || Some(format!("line {line}, column {column}"));
        let field = r.get(column).ok_or_else(|| ForeignError::record(&self.path, Some(label.to_string()), at(), "missing".to_string()))?;
        let whole = std::str::from_utf8(field).map_err(|_| ForeignError::record(&self.path, Some(label.to_string()), at(), "not UTF-8 text"))?.trim();
        // As messages quote it.
        let text = shown(whole);
        match whole.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            Ok(v) => Err(ForeignError::record(&self.path, Some(label.to_string()), at(), format!("`{text}` is {v}: a value must be finite"))),
            Err(_) if comma_decimal(whole) => Err(ForeignError::record(
                &self.path,
                Some(label.to_string()),
                at(),
                format!("`{text}` has a comma as its decimal separator: write numbers with a decimal point (pandas: to_csv(..., decimal='.'); a spreadsheet: a locale with '.' decimals)"),
            )),
            Err(_) if line == 2 && self.units.is_none() => Err(ForeignError::record(&self.path, Some(label.to_string()), at(), format!("`{text}` is not a number: if the second row names the units, set [csv] units_row = true in the map"))),
            Err(_) => Err(ForeignError::record(&self.path, Some(label.to_string()), at(), format!("`{text}` is not a number"))),
        }
    }

    /// The next row's values of `columns` (labelled for messages) appended to `out`; false at
    /// the end of the file.
    pub fn next_row(&mut self, columns: &[(usize, String)], out: &mut Vec<f64>) -> Result<bool> {
        self.look_ahead(1)?;
        let Some((line, r)) = self.ahead.pop_front() else { return Ok(false) };
        if r.len() != self.header.len() {
            let hint = if self.reader_delimiter_is_comma(&r) { " (a comma decimal separator splits numbers in two: write decimal points)" } else { "" };
            return Err(ForeignError::record(
                &self.path,
                None,
                Some(format!("line {line} (data row {})", self.row)),
                format!("{} fields, the header has {}: the rows are ragged{hint}", r.len(), self.header.len()),
            ));
        }
        for (c, label) in columns {
            out.push(self.parse(&r, line, *c, label)?);
        }
        self.row += 1;
        Ok(true)
    }

    fn reader_delimiter_is_comma(&self, r: &csv::ByteRecord) -> bool {
        r.len() > self.header.len() && r.iter().all(|f| f.iter().all(|b| b.is_ascii_digit() || matches!(b, b'-' | b'+' | b'e' | b'E' | b' ')))
    }
}

#[cfg(test)]
mod tests {
    use super::comma_decimal;

    #[test]
    fn comma_decimals_are_recognised_and_plain_numbers_are_not() {
        assert!(comma_decimal("1,5"));
        assert!(comma_decimal("-0,25e-3"));
        assert!(!comma_decimal("1.5"));
        assert!(!comma_decimal("1,"));
        assert!(!comma_decimal("abc,def"));
    }
}
