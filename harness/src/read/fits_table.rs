//! The first table of a participant's FITS file, read with cfitsio's own
//! calls (through `fitsio::sys`), and cfitsio errors told as sentences.
//!
//! The `fitsio` crate's HDU description panics on column types it does not
//! know (variable-length `P`/`Q`, complex `C`/`M`, an empty `TFORM`) and on
//! some image types, so a submission is never described through it: after
//! the file is opened, this module moves between HDUs, describes columns
//! ([`ColumnKind`], from cfitsio's equivalent type code) and reads them with
//! the raw calls. Before anything is read, the table's extent (NAXIS1 ×
//! NAXIS2 plus the heap) must lie inside the file, so that a header claiming
//! 10¹² rows cannot make the harness allocate for them.

use crate::error::HarnessError;
use fitsio::sys;
use std::ffi::{CStr, CString};
use std::os::raw::{c_char, c_int};
use std::path::Path;

/// HDUs examined before giving up on finding a table.
pub const MAX_HDUS: c_int = 1000;

/// What a column holds, as far as a submission is concerned.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ColumnKind {
    /// One real or integer number per row.
    Number,
    /// Text (one string per row).
    Text,
    /// Anything else, described in words (`a vector of 3 numbers per row`,
    /// `a variable-length array`, `complex numbers`, `logical values`).
    Other(String),
}

/// One column of the table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Column {
    /// `TTYPEn` (empty when absent).
    pub name: String,
    /// `TFORMn` as written.
    pub tform: String,
    /// What it holds.
    pub kind: ColumnKind,
    /// 1-based column number.
    number: c_int,
    /// Bytes of one string (text columns).
    string_len: usize,
}

/// The first table extension of a FITS file, opened.
pub struct Table<'a> {
    file: fitsio::FitsFile,
    path: &'a Path,
    /// Columns in order.
    pub columns: Vec<Column>,
    /// Rows.
    pub n_rows: usize,
}

/// What cfitsio's status code means, as a lower-case sentence.
pub fn status_sentence(status: c_int) -> String {
    let s = match status {
        104 => "the file cannot be opened",
        106 => "the file cannot be written (is the disk full?)",
        107 => "the file ends before its header or data do (truncated?)",
        108 | 116 => "the file cannot be read",
        113 => "not enough memory to read the file",
        202 => "a required header keyword is missing",
        204 | 205 | 209 | 403..=412 => "a header keyword has an unreadable value",
        207 | 252 | 254 => "the header has a malformed card (not a FITS header?)",
        208 => "the header's required keywords are out of order",
        210 => "the header has no END card",
        211..=216 | 220 | 221 | 225 | 251 => {
            "the header's structure keywords (SIMPLE, XTENSION, BITPIX, NAXIS, PCOUNT, GCOUNT) are invalid"
        }
        217 | 218 | 234 | 236 | 241 | 261 | 311 | 312 => "the table's column formats are invalid",
        255 => "the data's fill area is not blank",
        301 => "the file has fewer extensions than its structure implies",
        322 => "a column has a zero scale factor (TSCALn = 0)",
        _ => "",
    };
    if !s.is_empty() {
        return s.to_owned();
    }
    let mut buf = [0 as c_char; 31];
    // SAFETY: ffgerr writes at most 30 characters and a NUL into `buf`.
    unsafe { sys::ffgerr(status, buf.as_mut_ptr()) };
    // SAFETY: `buf` is NUL-terminated (zeroed, at most 30 characters written).
    let text = unsafe { CStr::from_ptr(buf.as_ptr()) }.to_string_lossy();
    if text.trim().is_empty() {
        format!("cfitsio failed with status {status}")
    } else {
        format!("cfitsio: {}", text.trim())
    }
}

/// A `fitsio` error as a sentence (no `FitsError { .. }` structs).
pub fn fitsio_sentence(e: &fitsio::errors::Error) -> String {
    use fitsio::errors::Error;
    match e {
        Error::Fits(f) => status_sentence(f.status),
        Error::Io(e) => e.to_string(),
        Error::Null(_) => "the file name contains a NUL byte".into(),
        Error::Utf8(_) | Error::IntoString(_) => "a FITS text value is not UTF-8".into(),
        Error::Message(m) => m.trim_start_matches("Error: ").to_owned(),
        other => other.to_string(),
    }
}

fn check(path: &Path, status: c_int, what: &str) -> Result<(), HarnessError> {
    if status == 0 {
        Ok(())
    } else {
        Err(HarnessError::submission(
            path,
            None,
            None,
            format!("{what}: {}", status_sentence(status)),
        ))
    }
}

/// Numeric equivalent type codes of cfitsio (TBYTE … TDOUBLE).
const NUMBER_TYPES: [c_int; 12] = [11, 12, 20, 21, 30, 31, 40, 41, 42, 80, 81, 82];

fn kind_of(typecode: c_int, repeat: i64, width: i64, ascii: bool) -> (ColumnKind, usize) {
    if typecode < 0 {
        return (
            ColumnKind::Other("a variable-length array (TFORM P or Q)".into()),
            0,
        );
    }
    match typecode {
        16 => {
            // Binary `rA`: one string of r bytes; `rAw` with w < r is an
            // array of strings. ASCII tables: repeat 1, width w.
            if ascii || repeat == width {
                (
                    ColumnKind::Text,
                    usize::try_from(width.max(repeat)).unwrap_or(0),
                )
            } else {
                (
                    ColumnKind::Other(format!(
                        "an array of {} strings per row",
                        repeat / width.max(1)
                    )),
                    0,
                )
            }
        }
        t if NUMBER_TYPES.contains(&t) => {
            if repeat == 1 {
                (ColumnKind::Number, 0)
            } else {
                (
                    ColumnKind::Other(format!("a vector of {repeat} numbers per row")),
                    0,
                )
            }
        }
        83 | 163 => (ColumnKind::Other("complex numbers".into()), 0),
        14 => (ColumnKind::Other("logical values".into()), 0),
        1 => (ColumnKind::Other("bits".into()), 0),
        _ => (
            ColumnKind::Other(format!("values of type code {typecode}")),
            0,
        ),
    }
}

impl<'a> Table<'a> {
    /// Finds the first table extension (binary or ASCII) of an opened file
    /// whose uncompressed size is `file_len` bytes, and describes its
    /// columns. Refuses, naming the file: no table in the first
    /// [`MAX_HDUS`] HDUs, a table whose rows or heap reach past the end of
    /// the file, and any cfitsio error (as a sentence).
    pub fn first_table(
        mut file: fitsio::FitsFile,
        path: &'a Path,
        file_len: u64,
    ) -> Result<Self, HarnessError> {
        // SAFETY: `file` owns a valid fitsfile for the whole function.
        let fptr = unsafe { file.as_raw() };
        let mut status = 0;
        let mut hdu_type = 0;
        let mut found = false;
        // Where the previous HDU ends: moving past the last HDU of a complete
        // file is "no table", anything else is damage.
        let mut prev_end = 0i64;
        for i in 1..=MAX_HDUS {
            // SAFETY: valid fptr, out-pointers to locals.
            unsafe { sys::ffmahd(fptr, i, &mut hdu_type, &mut status) };
            if status != 0 {
                if i > 1 && i128::from(prev_end) >= i128::from(file_len) {
                    return Err(HarnessError::submission(
                        path,
                        None,
                        None,
                        "no table extension in this FITS file (a binary or ASCII table \
                         extension with the columns is needed)",
                    ));
                }
                check(path, status, &format!("HDU {i}"))?;
            }
            if hdu_type == 1 || hdu_type == 2 {
                found = true;
                break;
            }
            let (mut h, mut d) = (0i64, 0i64);
            // SAFETY: valid fptr, out-pointers to locals.
            unsafe { sys::ffghadll(fptr, &mut h, &mut d, &mut prev_end, &mut status) };
            check(path, status, &format!("HDU {i}"))?;
        }
        if !found {
            return Err(HarnessError::submission(
                path,
                None,
                None,
                format!("no table extension in the first {MAX_HDUS} HDUs"),
            ));
        }
        let ascii = hdu_type == 1;
        let (mut n_rows, mut n_cols) = (0i64, 0 as c_int);
        let (mut head, mut data, mut end) = (0i64, 0i64, 0i64);
        let mut naxis1 = 0i64;
        // SAFETY: valid fptr, out-pointers to locals, NUL-terminated names.
        unsafe {
            sys::ffgnrwll(fptr, &mut n_rows, &mut status);
            sys::ffgncl(fptr, &mut n_cols, &mut status);
            sys::ffghadll(fptr, &mut head, &mut data, &mut end, &mut status);
            sys::ffgkyjj(
                fptr,
                c"NAXIS1".as_ptr(),
                &mut naxis1,
                std::ptr::null_mut(),
                &mut status,
            );
        }
        check(path, status, "table header")?;
        let rows_bytes = i128::from(naxis1) * i128::from(n_rows);
        if n_rows < 0 || naxis1 < 0 || i128::from(data) + rows_bytes > i128::from(file_len) {
            return Err(HarnessError::submission(
                path,
                None,
                None,
                format!(
                    "the table header announces {n_rows} rows of {naxis1} bytes, more than \
                     the file holds ({file_len} bytes)"
                ),
            ));
        }
        if i128::from(end) > i128::from(file_len) + 2880 {
            return Err(HarnessError::submission(
                path,
                None,
                None,
                format!(
                    "the table's data (with its heap) end at byte {end}, past the end of \
                     the file ({file_len} bytes)"
                ),
            ));
        }
        let mut columns = Vec::with_capacity(usize::try_from(n_cols).unwrap_or(0));
        for c in 1..=n_cols {
            let name = key_string(fptr, &format!("TTYPE{c}"));
            let tform = key_string(fptr, &format!("TFORM{c}"));
            let (mut typecode, mut repeat, mut width) = (0 as c_int, 0i64, 0i64);
            // SAFETY: valid fptr, column number in 1..=n_cols.
            unsafe {
                sys::ffeqtyll(fptr, c, &mut typecode, &mut repeat, &mut width, &mut status);
            }
            check(path, status, &format!("column {c} (`{name}`)"))?;
            let (mut kind, string_len) = kind_of(typecode, repeat, width, ascii);
            // A field cannot be wider than the row (cfitsio does not check
            // this for ASCII tables, and the string buffers are sized by it).
            let field_bytes = if ascii { width } else { string_len as i64 };
            if field_bytes > naxis1 {
                kind = ColumnKind::Other(format!(
                    "fields of {field_bytes} bytes in rows of {naxis1} bytes"
                ));
            }
            columns.push(Column {
                name,
                tform,
                kind,
                number: c,
                string_len,
            });
        }
        Ok(Self {
            file,
            path,
            columns,
            n_rows: usize::try_from(n_rows).unwrap_or(0),
        })
    }

    fn col_error(&self, col: &Column, status: c_int) -> HarnessError {
        HarnessError::submission(
            self.path,
            None,
            Some(&col.name.to_ascii_lowercase()),
            status_sentence(status),
        )
    }

    /// Reads a [`ColumnKind::Number`] column (scaled by TSCALn/TZEROn);
    /// undefined values (TNULLn) become NaN.
    pub fn numbers(&mut self, col: &Column) -> Result<Vec<f64>, HarnessError> {
        self.numbers_range(col, 0, self.n_rows)
    }

    /// Rows `first .. first + n` (0-based) of a [`ColumnKind::Number`]
    /// column, as [`Table::numbers`] reads them; `n` is cut at the last row.
    pub fn numbers_range(
        &mut self,
        col: &Column,
        first: usize,
        n: usize,
    ) -> Result<Vec<f64>, HarnessError> {
        debug_assert_eq!(col.kind, ColumnKind::Number);
        let n = n.min(self.n_rows.saturating_sub(first));
        let mut out = vec![0.0f64; n];
        if n == 0 {
            return Ok(out);
        }
        let (mut anynul, mut status) = (0, 0);
        // SAFETY: `out` holds n values, one per row of a scalar column.
        unsafe {
            sys::ffgcvd(
                self.file.as_raw(),
                col.number,
                first as i64 + 1,
                1,
                n as i64,
                f64::NAN,
                out.as_mut_ptr(),
                &mut anynul,
                &mut status,
            );
        }
        if status != 0 {
            return Err(self.col_error(col, status));
        }
        Ok(out)
    }

    /// Reads a [`ColumnKind::Text`] column, each value trimmed of blanks.
    pub fn strings(&mut self, col: &Column) -> Result<Vec<String>, HarnessError> {
        self.strings_range(col, 0, self.n_rows)
    }

    /// Rows `first .. first + n` (0-based) of a [`ColumnKind::Text`]
    /// column, as [`Table::strings`] reads them; `n` is cut at the last row.
    pub fn strings_range(
        &mut self,
        col: &Column,
        first: usize,
        n: usize,
    ) -> Result<Vec<String>, HarnessError> {
        debug_assert_eq!(col.kind, ColumnKind::Text);
        let end = first.saturating_add(n).min(self.n_rows);
        let len = col.string_len + 1;
        let mut out = Vec::with_capacity(end.saturating_sub(first));
        // In blocks, so that the buffer stays small whatever the row count.
        let block = (1usize << 20) / len.max(1) + 1;
        let mut buf = vec![0 as c_char; block.min(end.saturating_sub(first)).max(1) * len];
        let mut first = first;
        while first < end {
            let n = block.min(end - first);
            buf.iter_mut().for_each(|b| *b = 0);
            let mut ptrs: Vec<*mut c_char> = (0..n).map(|k| buf[k * len..].as_mut_ptr()).collect();
            let (mut anynul, mut status) = (0, 0);
            let mut nul = [0 as c_char; 1];
            // SAFETY: each of the n pointers has room for string_len bytes
            // and a NUL, which is what cfitsio writes per row.
            unsafe {
                sys::ffgcvs(
                    self.file.as_raw(),
                    col.number,
                    first as i64 + 1,
                    1,
                    n as i64,
                    nul.as_mut_ptr(),
                    ptrs.as_mut_ptr(),
                    &mut anynul,
                    &mut status,
                );
            }
            if status != 0 {
                return Err(self.col_error(col, status));
            }
            for k in 0..n {
                let raw = &buf[k * len..(k + 1) * len];
                let bytes: Vec<u8> = raw
                    .iter()
                    .take_while(|&&c| c != 0)
                    .map(|&c| c as u8)
                    .collect();
                out.push(String::from_utf8_lossy(&bytes).trim().to_owned());
            }
            first += n;
        }
        Ok(out)
    }
}

/// A header keyword's string value, empty when absent or unreadable.
fn key_string(fptr: *mut sys::fitsfile, key: &str) -> String {
    let Ok(k) = CString::new(key) else {
        return String::new();
    };
    let mut value = [0 as c_char; 72];
    let mut status = 0;
    // SAFETY: FLEN_VALUE is 71 bytes with the NUL; `value` has 72.
    unsafe {
        sys::ffgkys(
            fptr,
            k.as_ptr(),
            value.as_mut_ptr(),
            std::ptr::null_mut(),
            &mut status,
        )
    };
    if status != 0 {
        return String::new();
    }
    // SAFETY: NUL-terminated by cfitsio (buffer zeroed, at most 71 bytes).
    unsafe { CStr::from_ptr(value.as_ptr()) }
        .to_string_lossy()
        .trim()
        .to_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statuses_read_as_sentences() {
        assert_eq!(
            status_sentence(106),
            "the file cannot be written (is the disk full?)"
        );
        assert_eq!(
            status_sentence(107),
            "the file ends before its header or data do (truncated?)"
        );
        // Unknown to our table: cfitsio's own short text, never a struct.
        let s = status_sentence(317);
        assert!(s.starts_with("cfitsio: ") && s.len() > 12, "{s}");
        let e = fitsio::errors::Error::Fits(fitsio::errors::FitsError {
            status: 106,
            message: "error writing to FITS file".into(),
        });
        assert_eq!(
            fitsio_sentence(&e),
            "the file cannot be written (is the disk full?)"
        );
    }
}
