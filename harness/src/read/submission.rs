//! Reading a submission (SPEC §6): one table, or a directory of per-image
//! tables, checked strictly against the run's images.
//!
//! Accepted forms, told apart by content (not by file name), each possibly
//! gzip-compressed (inflated here within the input limit):
//! * **FITS table** (the data start with `SIMPLE  =`): the first binary or
//!   ASCII table extension is read through [`crate::read::fits_table`] (column
//!   types from cfitsio's codes; extra columns of any type are ignored);
//!   column names are matched case-insensitively; `image` must be text.
//! * **Whitespace ASCII**: the first non-blank line is the header, `#`
//!   followed by the column names (`# image x y e1 e2 weight`); later lines
//!   starting with `#` are comments; fields are separated by blanks or tabs.
//! * **CSV** (read with the `csv` crate, one record per line): the first
//!   non-blank line is a comma-separated header (`image,x,y,e1,e2,weight`;
//!   a leading `#` is tolerated); blanks around fields are ignored; fields
//!   may be wrapped in double quotes, and a quoted field may hold commas
//!   (`"a,b"`) and doubled quotes (`""` for `"`), but not line breaks.
//!
//! Text is UTF-8 (a leading byte-order mark is skipped); lines end with LF,
//! CR LF or a lone CR.
//!
//! Required columns `image`, `x`, `y`, `e1`, `e2`; optional `weight`
//! (default 1, must be finite and ≥ 0). In a directory each file is named
//! `<image-id>.<ext>` and may omit `image` (when present it must equal the
//! file's id); optional `flags` (the pipeline's own bits, not used in
//! scoring: zero-weight rows are how an object is dropped). Other columns
//! are ignored and reported as warnings.
//!
//! Refused, naming file, line (FITS: row) and column: an unknown image id, a
//! missing required column, a repeated column, a header of more than
//! [`MAX_COLUMNS`] columns, a required FITS column of
//! the wrong type, a value that does not parse, NaN or infinity, x or y off
//! the image (the half-pixel border, 0.5 ≤ x ≤ width + 0.5, is on the
//! image), a negative weight, |e1| or |e2| above [`MAX_ABS_SHEAR`], weights
//! whose sums over an image overflow, a line with the wrong number of
//! fields, binary content (NUL or control bytes, UTF-16), a duplicate row
//! (same image, x and y as an earlier row), a file with no rows; and, before
//! reading, anything that is not a regular file, a symbolic link inside a
//! directory, and more bytes than the limit ([`crate::read::input`]). The
//! submission is only read.

use crate::error::show_number;
use crate::error::{HarnessError, show_text};
use crate::read::fits_table::{ColumnKind, Table};
use crate::read::input::{
    CappedReader, GzReader, InputError, MAX_SUBMISSION_BYTES, gunzip_bounded, input_error, is_gzip,
    kind_of, open_regular, read_entry_file, read_regular_file, show_bytes,
};
use crate::read::spill::{DEFAULT_BUFFER_ROWS, SpillWriter, SpilledRows};
use crate::read::truth_set::ImageIndex;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
use std::io::Read;
use std::path::{Path, PathBuf};

/// One submitted object.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubRow {
    /// FITS pixel x.
    pub x: f64,
    /// FITS pixel y.
    pub y: f64,
    /// Shear estimate γ̂1.
    pub e1: f64,
    /// Shear estimate γ̂2.
    pub e2: f64,
    /// Weight (≥ 0).
    pub weight: f64,
    /// 1-based line (text) or row (FITS) in its file.
    pub line: u64,
}

/// A whole submission, rows grouped by image: spilled to disk by the
/// streaming reader ([`read_submission_limited`], one image read back at a
/// time), or held in memory by its slow twin ([`read_submission_slow`]).
#[derive(Debug, Clone)]
pub struct Submission {
    /// The file or directory given.
    pub path: PathBuf,
    rows: Rows,
    /// Columns present but not used (sorted, unique).
    pub ignored_columns: Vec<String>,
}

#[derive(Debug, Clone)]
enum Rows {
    Memory(Vec<Vec<SubRow>>),
    Spilled(SpilledRows),
}

impl Submission {
    /// A submission held in memory: `per_image[i]` the rows of image `i` of
    /// the [`ImageIndex`].
    pub fn from_rows(path: PathBuf, per_image: Vec<Vec<SubRow>>, ignored: Vec<String>) -> Self {
        Self {
            path,
            rows: Rows::Memory(per_image),
            ignored_columns: ignored,
        }
    }

    /// Number of images of the index it was read against.
    pub fn n_images(&self) -> usize {
        match &self.rows {
            Rows::Memory(v) => v.len(),
            Rows::Spilled(s) => s.n_images(),
        }
    }

    /// Rows of image `i`.
    pub fn image_len(&self, i: usize) -> usize {
        match &self.rows {
            Rows::Memory(v) => v[i].len(),
            Rows::Spilled(s) => s.len(i),
        }
    }

    /// Total number of rows.
    pub fn n_rows(&self) -> usize {
        (0..self.n_images()).map(|i| self.image_len(i)).sum()
    }

    /// Indices of images with no rows.
    pub fn missing_images(&self) -> Vec<usize> {
        (0..self.n_images())
            .filter(|&i| self.image_len(i) == 0)
            .collect()
    }

    /// The rows of image `i` in file order (read back from the spill file).
    pub fn image_rows(&self, i: usize) -> Result<Vec<SubRow>, HarnessError> {
        match &self.rows {
            Rows::Memory(v) => Ok(v[i].clone()),
            Rows::Spilled(s) => s.read(i).map_err(|e| spill_error(&self.path, &e)),
        }
    }

    /// The images `which` (indices into this submission's images), in that
    /// order: image `k` of the result is image `which[k]` of this one.
    pub fn select(&self, which: &[usize]) -> Self {
        let rows = match &self.rows {
            Rows::Memory(v) => Rows::Memory(which.iter().map(|&i| v[i].clone()).collect()),
            Rows::Spilled(s) => Rows::Spilled(s.select(which)),
        };
        Self {
            path: self.path.clone(),
            rows,
            ignored_columns: self.ignored_columns.clone(),
        }
    }

    /// For a spilled submission, the most rows its reader held in memory at
    /// once (`None` for one held in memory).
    pub fn max_rows_held(&self) -> Option<usize> {
        match &self.rows {
            Rows::Memory(_) => None,
            Rows::Spilled(s) => Some(s.max_rows_held()),
        }
    }
}

/// The error of the spill file (the harness's own temporary file; no
/// participant data in the message).
fn spill_error(path: &Path, e: &std::io::Error) -> HarnessError {
    HarnessError::submission(
        path,
        None,
        None,
        format!(
            "cannot use the temporary file that holds the rows while scoring (in {}): {e}",
            std::env::temp_dir().display()
        ),
    )
}

/// Rows read from one file: (image index, row).
#[derive(Debug, Clone, Default)]
pub struct FileRows {
    /// The rows with their image index.
    pub rows: Vec<(usize, SubRow)>,
    /// Columns ignored.
    pub ignored_columns: Vec<String>,
    /// Bytes of the file after gzip decompression (as stored when not
    /// compressed).
    pub uncompressed_bytes: u64,
}

use stepsim_contract::MAX_ABS_SHEAR;

/// Reads a submission file or directory, within [`MAX_SUBMISSION_BYTES`]
/// (streamed: [`read_submission_limited`]).
pub fn read_submission(path: &Path, index: &ImageIndex) -> Result<Submission, HarnessError> {
    read_submission_limited(path, index, MAX_SUBMISSION_BYTES)
}

/// Reads a submission file or directory of at most `max_bytes` bytes (the
/// sum over its files, both as stored and after gzip decompression),
/// streamed: the rows are checked as they are read and spilled by image to
/// a temporary file (`read/spill.rs`), so that memory holds at most
/// [`DEFAULT_BUFFER_ROWS`] rows of a single table (and, for a directory,
/// the rows of the files being read, one image each), never the catalogue.
/// The checks and messages are those of [`read_submission_slow`], its
/// slow twin; a text line longer than [`MAX_LINE_BYTES`] is refused.
///
/// The top-level `path` may be a symbolic link (it is followed: the organiser
/// named it). In a directory, entries whose names start with `.` and
/// subdirectories are skipped; an entry that is a symbolic link, a FIFO, a
/// socket or a device is refused, so that nothing outside the directory is
/// ever read.
pub fn read_submission_limited(
    path: &Path,
    index: &ImageIndex,
    max_bytes: u64,
) -> Result<Submission, HarnessError> {
    read_submission_spilled(path, index, max_bytes, DEFAULT_BUFFER_ROWS)
}

/// The files of a submission: the file itself, or the entries of a
/// directory with their image (checked, sorted, sizes within `max_bytes`).
fn submission_files(
    path: &Path,
    index: &ImageIndex,
    max_bytes: u64,
) -> Result<Vec<(PathBuf, Option<usize>)>, HarnessError> {
    let at = |p: &Path, m: String| HarnessError::submission(p, None, None, m);
    let meta = std::fs::metadata(path).map_err(|e| at(path, format!("cannot read: {e}")))?;
    Ok(if meta.is_dir() {
        let mut entries = Vec::new();
        let rd = std::fs::read_dir(path).map_err(|e| at(path, format!("cannot list: {e}")))?;
        for entry in rd {
            let entry = entry.map_err(|e| at(path, format!("cannot list: {e}")))?;
            let p = entry.path();
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') {
                continue;
            }
            let ft = entry
                .file_type()
                .map_err(|e| at(&p, format!("cannot read: {e}")))?;
            if ft.is_dir() {
                continue;
            }
            if ft.is_symlink() {
                return Err(at(
                    &p,
                    "is a symbolic link; a submission directory must hold the files \
                     themselves (links are refused so that nothing outside it is read)"
                        .into(),
                ));
            }
            if !ft.is_file() {
                return Err(at(&p, InputError::NotRegular(kind_of(&ft)).to_string()));
            }
            let stem = name.split('.').next().unwrap_or_default().to_owned();
            let Some(&i) = index.by_id.get(&stem) else {
                return Err(at(
                    &p,
                    format!("unknown image id `{stem}` (files are named <image-id>.<ext>)"),
                ));
            };
            entries.push((p, Some(i)));
        }
        entries.sort();
        for w in entries.windows(2) {
            if w[0].1 == w[1].1 {
                return Err(at(
                    &w[1].0,
                    format!(
                        "a second file for image `{}`",
                        index.images[w[1].1.unwrap_or(0)].image
                    ),
                ));
            }
        }
        if entries.is_empty() {
            return Err(at(path, "empty directory".into()));
        }
        // The sizes as listed, before reading anything.
        let mut total = 0u64;
        for (p, _) in &entries {
            let len = std::fs::symlink_metadata(p)
                .map_err(|e| at(p, format!("cannot read: {e}")))?
                .len();
            total = total.saturating_add(len);
            if total > max_bytes {
                return Err(at(
                    p,
                    format!(
                        "the submission's files together are larger than the limit of {}",
                        show_bytes(max_bytes)
                    ),
                ));
            }
        }
        entries
    } else {
        vec![(path.to_path_buf(), None)]
    })
}

/// [`read_submission_limited`] with a buffer of `buffer_rows` rows before
/// each spill (at least 1).
pub fn read_submission_spilled(
    path: &Path,
    index: &ImageIndex,
    max_bytes: u64,
    buffer_rows: usize,
) -> Result<Submission, HarnessError> {
    let files = submission_files(path, index, max_bytes)?;
    let spill = |e: std::io::Error| spill_error(path, &e);
    let mut writer = SpillWriter::new(index.images.len(), buffer_rows).map_err(spill)?;
    let (ignored, table) = if let [(p, None)] = &files[..] {
        let st = stream_table(p, index, max_bytes, &mut writer)?;
        (st.ignored, Some(st.text))
    } else {
        (
            stream_directory(&files, index, max_bytes, &mut writer)?,
            None,
        )
    };
    let rows = writer.finish().map_err(spill)?;
    if let Some(text) = table {
        check_spilled(path, &rows, index, text)?;
    }
    Ok(Submission {
        path: path.to_path_buf(),
        rows: Rows::Spilled(rows),
        ignored_columns: ignored,
    })
}

/// Reads a submission whole, every row held in memory: the slow, obvious
/// twin of [`read_submission_limited`] (same checks, same messages, same
/// rows), kept to test it.
pub fn read_submission_slow(
    path: &Path,
    index: &ImageIndex,
    max_bytes: u64,
) -> Result<Submission, HarnessError> {
    let at = |p: &Path, m: String| HarnessError::submission(p, None, None, m);
    let files = submission_files(path, index, max_bytes)?;
    let follow = files.len() == 1 && files[0].1.is_none();
    let parsed: Vec<Result<FileRows, HarnessError>> = files
        .par_iter()
        .map(|(p, fixed)| {
            let bytes = read_file(p, max_bytes, follow).map_err(|e| at(p, e.to_string()))?;
            parse_file_limited(p, &bytes, index, *fixed, max_bytes)
        })
        .collect();
    let mut per_image = vec![Vec::new(); index.images.len()];
    let mut ignored = Vec::new();
    let mut total = 0u64;
    for ((p, _), r) in files.iter().zip(parsed) {
        let fr = r?;
        total = total.saturating_add(fr.uncompressed_bytes);
        if total > max_bytes {
            return Err(at(
                p,
                format!(
                    "the submission's files together are larger than the limit of {} \
                     after gzip decompression",
                    show_bytes(max_bytes)
                ),
            ));
        }
        for (i, row) in fr.rows {
            per_image[i].push(row);
        }
        ignored.extend(fr.ignored_columns);
    }
    ignored.sort();
    ignored.dedup();
    Ok(Submission::from_rows(
        path.to_path_buf(),
        per_image,
        ignored,
    ))
}

/// [`read_regular_file`], or [`read_entry_file`] (links refused) unless
/// `follow`.
fn read_file(path: &Path, cap: u64, follow: bool) -> Result<Vec<u8>, InputError> {
    if follow {
        read_regular_file(path, cap)
    } else {
        read_entry_file(path, cap)
    }
}

/// Longest line of a text table the streaming reader takes (16 MiB; a row
/// is tens of bytes, and a header of [`MAX_COLUMNS`] names of up to 16 KiB
/// each fits).
pub const MAX_LINE_BYTES: usize = 16 << 20;

/// Rows of a FITS table read at a time by the streaming reader.
const FITS_CHUNK_ROWS: usize = 1 << 16;

/// What the streaming reader learnt of one file.
struct Streamed {
    ignored: Vec<String>,
    uncompressed_bytes: u64,
    n_rows: u64,
    text: bool,
}

/// A reader that counts the bytes read through it.
struct Counting<R> {
    inner: R,
    n: u64,
}

impl<R: Read> Read for Counting<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.n += n as u64;
        Ok(n)
    }
}

/// The first `n` bytes of `r` (fewer at its end).
fn peek<R: Read>(r: &mut R, n: usize) -> std::io::Result<Vec<u8>> {
    let mut head = Vec::with_capacity(n);
    r.take(n as u64).read_to_end(&mut head)?;
    Ok(head)
}

/// Reads one file (any accepted form) as a stream, handing each row to
/// `sink` in file order; the checks of [`parse_file_limited`] that need
/// only the row itself. A gzip FITS file is inflated to a temporary file
/// (removed when read) for cfitsio.
fn stream_file(
    path: &Path,
    index: &ImageIndex,
    fixed: Option<usize>,
    max_bytes: u64,
    follow: bool,
    sink: &mut dyn FnMut(usize, SubRow) -> Result<(), HarnessError>,
) -> Result<Streamed, HarnessError> {
    let at = |e: InputError| HarnessError::submission(path, None, None, e.to_string());
    let io = |e: std::io::Error| at(input_error(e));
    let (file, len) = open_regular(path, max_bytes, follow).map_err(at)?;
    let mut raw = CappedReader::new(file, max_bytes, "the file");
    let magic = peek(&mut raw, 2).map_err(io)?;
    let gz = is_gzip(&magic);
    let raw = std::io::Cursor::new(magic).chain(raw);
    let decoded: Box<dyn Read> = if gz {
        Box::new(GzReader::new(raw, max_bytes))
    } else {
        Box::new(raw)
    };
    let mut data = Counting {
        inner: decoded,
        n: 0,
    };
    let head = peek(&mut data, 9).map_err(io)?;
    if head.starts_with(b"SIMPLE  =") {
        let mut n_rows = 0u64;
        let ignored = if gz {
            let mut tmp = tempfile::NamedTempFile::new().map_err(|e| spill_error(path, &e))?;
            let mut all = std::io::Cursor::new(head).chain(&mut data);
            std::io::copy(&mut all, tmp.as_file_mut()).map_err(io)?;
            stream_fits(path, tmp.path(), data.n, index, fixed, &mut |i, r| {
                n_rows += 1;
                sink(i, r)
            })?
        } else {
            stream_fits(path, path, len, index, fixed, &mut |i, r| {
                n_rows += 1;
                sink(i, r)
            })?
        };
        let uncompressed_bytes = if gz { data.n } else { len };
        return Ok(Streamed {
            ignored,
            uncompressed_bytes,
            n_rows,
            text: false,
        });
    }
    let mut all = std::io::Cursor::new(head).chain(&mut data);
    let mut parser = TextParser::new(path, index, fixed);
    let mut n_rows = 0u64;
    let read = stream_lines(path, &mut all, &mut |line_no, raw| {
        if let Some((i, r)) = parser.line(line_no, raw)? {
            n_rows += 1;
            sink(i, r)?;
        }
        Ok(())
    });
    if let Err(e) = read {
        // A corrupt gzip file is told as such (as the whole-file reader,
        // which inflates first, tells it), not by the garbled line it gave:
        // the rest is inflated (within the cap) to check it.
        if gz {
            std::io::copy(&mut all, &mut std::io::sink()).map_err(io)?;
        }
        return Err(e);
    }
    let ignored = parser.finish()?;
    Ok(Streamed {
        ignored,
        uncompressed_bytes: data.n,
        n_rows,
        text: true,
    })
}

/// What [`stream_lines`] hands each line to: its number and its bytes.
type LineSink<'a> = dyn FnMut(u64, &[u8]) -> Result<(), HarnessError> + 'a;

/// Splits a text stream into lines exactly as [`parse_file`] does (LF, CR
/// LF or a lone CR; a UTF-16 start refused, a UTF-8 byte-order mark
/// skipped), handing each to `f` with its 1-based number. Holds at most
/// [`MAX_LINE_BYTES`] of a line and 64 KiB more.
fn stream_lines(path: &Path, r: &mut dyn Read, f: &mut LineSink<'_>) -> Result<(), HarnessError> {
    let io =
        |e: std::io::Error| HarnessError::submission(path, None, None, input_error(e).to_string());
    let mut buf = vec![0u8; MAX_LINE_BYTES + (1 << 16)];
    let (mut start, mut len, mut eof, mut first) = (0usize, 0usize, false, true);
    let mut line_no = 0u64;
    loop {
        if !eof {
            buf.copy_within(start..len, 0);
            len -= start;
            start = 0;
            if len > MAX_LINE_BYTES {
                return Err(HarnessError::submission(
                    path,
                    Some(line_no + 1),
                    None,
                    format!(
                        "the line is longer than {} (not a table of rows?)",
                        show_bytes(MAX_LINE_BYTES as u64)
                    ),
                ));
            }
            let n = loop {
                match r.read(&mut buf[len..]) {
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    other => break other.map_err(io)?,
                }
            };
            if n == 0 {
                eof = true;
            }
            len += n;
        }
        if first {
            if len < 3 && !eof {
                continue;
            }
            first = false;
            let rest = text_start(path, &buf[..len])?;
            start = len - rest.len();
        }
        loop {
            let rest = &buf[start..len];
            match rest.iter().position(|&c| c == b'\n' || c == b'\r') {
                Some(rel) => {
                    let e = start + rel;
                    if buf[e] == b'\r' && e + 1 == len && !eof {
                        break;
                    }
                    line_no += 1;
                    f(line_no, &buf[start..e])?;
                    start = e + if buf[e] == b'\r' && buf.get(e + 1) == Some(&b'\n') && e + 1 < len
                    {
                        2
                    } else {
                        1
                    };
                }
                None => {
                    if eof {
                        if start < len {
                            line_no += 1;
                            f(line_no, &buf[start..len])?;
                        }
                        return Ok(());
                    }
                    break;
                }
            }
        }
    }
}

/// The rows of the first table of a FITS file, [`FITS_CHUNK_ROWS`] at a
/// time (the checks of [`parse_file`]); returns the ignored columns.
fn stream_fits(
    path: &Path,
    open_path: &Path,
    len: u64,
    index: &ImageIndex,
    fixed: Option<usize>,
    sink: &mut dyn FnMut(usize, SubRow) -> Result<(), HarnessError>,
) -> Result<Vec<String>, HarnessError> {
    let (mut t, lay, cols) = open_table(path, open_path, len, fixed)?;
    let mut first = 0usize;
    while first < t.n_rows {
        let n = FITS_CHUNK_ROWS.min(t.n_rows - first);
        let xs = t.numbers_range(&cols[lay.x], first, n)?;
        let ys = t.numbers_range(&cols[lay.y], first, n)?;
        let e1s = t.numbers_range(&cols[lay.e1], first, n)?;
        let e2s = t.numbers_range(&cols[lay.e2], first, n)?;
        let ws = match lay.weight {
            Some(c) => Some(t.numbers_range(&cols[c], first, n)?),
            None => None,
        };
        let ids = match lay.image {
            Some(c) => Some(t.strings_range(&cols[c], first, n)?),
            None => None,
        };
        for k in 0..n {
            let row_no = (first + k) as u64 + 1;
            let err = |c: &str, m: String| HarnessError::submission_row(path, row_no, Some(c), m);
            let id = ids.as_ref().map(|v| v[k].as_str());
            let image = resolve_image(index, fixed, id, &err)?;
            let vals = [
                xs[k],
                ys[k],
                e1s[k],
                e2s[k],
                ws.as_ref().map_or(1.0, |w| w[k]),
            ];
            let (i, row) = make_row(index, image, vals, row_no, &err)?;
            sink(i, row)?;
        }
        first += n;
    }
    Ok(lay.ignored)
}

/// The single table of a submission, streamed into `writer`; returns the
/// ignored columns and whether it is text.
fn stream_table(
    path: &Path,
    index: &ImageIndex,
    max_bytes: u64,
    writer: &mut SpillWriter,
) -> Result<Streamed, HarnessError> {
    let st = stream_file(path, index, None, max_bytes, true, &mut |i, r| {
        writer.push(i, r).map_err(|e| spill_error(path, &e))
    })?;
    if st.n_rows == 0 {
        return Err(HarnessError::submission(
            path,
            None,
            None,
            "no rows (empty table)",
        ));
    }
    Ok(st)
}

/// The per-image files of a directory, read in parallel (each file's rows,
/// one image's, held while it is checked) and spilled one image each;
/// errors and sizes in file order as [`read_submission_slow`] reports
/// them. Returns the ignored columns.
fn stream_directory(
    files: &[(PathBuf, Option<usize>)],
    index: &ImageIndex,
    max_bytes: u64,
    writer: &mut SpillWriter,
) -> Result<Vec<String>, HarnessError> {
    let writer = std::sync::Mutex::new(writer);
    let results: Vec<Result<Streamed, HarnessError>> = files
        .par_iter()
        .map(|(p, fixed)| {
            let mut rows = Vec::new();
            let st = stream_file(p, index, *fixed, max_bytes, false, &mut |i, r| {
                rows.push((i, r));
                Ok(())
            })?;
            if rows.is_empty() {
                return Err(HarnessError::submission(
                    p,
                    None,
                    None,
                    "no rows (empty table)",
                ));
            }
            check_duplicates(p, &rows, index, st.text)?;
            check_sums(p, &rows, index, st.text)?;
            let image = rows[0].0;
            let only: Vec<SubRow> = rows.into_iter().map(|(_, r)| r).collect();
            writer
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .push_image(image, &only)
                .map_err(|e| spill_error(p, &e))?;
            Ok(st)
        })
        .collect();
    let mut ignored = Vec::new();
    let mut total = 0u64;
    for ((p, _), r) in files.iter().zip(results) {
        let st = r?;
        total = total.saturating_add(st.uncompressed_bytes);
        if total > max_bytes {
            return Err(HarnessError::submission(
                p,
                None,
                None,
                format!(
                    "the submission's files together are larger than the limit of {} \
                     after gzip decompression",
                    show_bytes(max_bytes)
                ),
            ));
        }
        ignored.extend(st.ignored);
    }
    ignored.sort();
    ignored.dedup();
    Ok(ignored)
}

/// The checks of a whole table that need all of an image's rows, run on the
/// spilled rows one image at a time: the row reported is the one the whole
/// table's check ([`parse_file`]) reports, the first in file order, and a
/// duplicate comes before an overflow.
fn check_spilled(
    path: &Path,
    rows: &SpilledRows,
    index: &ImageIndex,
    text: bool,
) -> Result<(), HarnessError> {
    type Found = (Option<(u64, HarnessError)>, Option<(u64, HarnessError)>);
    let found: Vec<Result<Found, HarnessError>> = (0..rows.n_images())
        .into_par_iter()
        .map(|i| {
            if rows.len(i) == 0 {
                return Ok((None, None));
            }
            let v = rows.read(i).map_err(|e| spill_error(path, &e))?;
            Ok((
                first_duplicate(path, i, &v, index, text),
                first_overflow(path, i, &v, index, text),
            ))
        })
        .collect();
    let mut dup: Option<(u64, HarnessError)> = None;
    let mut over: Option<(u64, HarnessError)> = None;
    for r in found {
        let (d, o) = r?;
        for (best, new) in [(&mut dup, d), (&mut over, o)] {
            if let Some((line, e)) = new
                && best.as_ref().is_none_or(|(l, _)| line < *l)
            {
                *best = Some((line, e));
            }
        }
    }
    match dup.or(over) {
        Some((_, e)) => Err(e),
        None => Ok(()),
    }
}

/// The first row of image `i` (rows in file order) with the x and y of an
/// earlier one: its line and error.
fn first_duplicate(
    path: &Path,
    i: usize,
    rows: &[SubRow],
    index: &ImageIndex,
    text: bool,
) -> Option<(u64, HarnessError)> {
    let mut seen: HashMap<(u64, u64), u64> = HashMap::with_capacity(rows.len());
    for r in rows {
        let key = ((r.x + 0.0).to_bits(), (r.y + 0.0).to_bits());
        if let Some(first) = seen.insert(key, r.line) {
            return Some((r.line, duplicate_error(path, i, r, first, index, text)));
        }
    }
    None
}

/// The first row of image `i` at which its weighted sums overflow.
fn first_overflow(
    path: &Path,
    i: usize,
    rows: &[SubRow],
    index: &ImageIndex,
    text: bool,
) -> Option<(u64, HarnessError)> {
    let mut s = [0.0f64; 3];
    for r in rows {
        s[0] += r.weight;
        s[1] += r.weight * r.e1.abs();
        s[2] += r.weight * r.e2.abs();
        if s.iter().any(|v| !v.is_finite()) {
            return Some((r.line, overflow_error(path, i, r, index, text)));
        }
    }
    None
}

/// Parses the bytes of one submission file (any accepted form), within
/// [`MAX_SUBMISSION_BYTES`]. `fixed` is the image of a per-image file.
/// Pure apart from FITS, which cfitsio reads from `path`.
pub fn parse_file(
    path: &Path,
    bytes: &[u8],
    index: &ImageIndex,
    fixed: Option<usize>,
) -> Result<FileRows, HarnessError> {
    parse_file_limited(path, bytes, index, fixed, MAX_SUBMISSION_BYTES)
}

/// [`parse_file`] with the cap on the decompressed size of a gzip file.
pub fn parse_file_limited(
    path: &Path,
    bytes: &[u8],
    index: &ImageIndex,
    fixed: Option<usize>,
    max_bytes: u64,
) -> Result<FileRows, HarnessError> {
    let inflated;
    let data = if is_gzip(bytes) {
        inflated = gunzip_bounded(bytes, max_bytes)
            .map_err(|e| HarnessError::submission(path, None, None, e.to_string()))?;
        &inflated[..]
    } else {
        bytes
    };
    let is_fits = data.starts_with(b"SIMPLE  =");
    let mut fr = if is_fits {
        parse_fits(path, data, index, fixed)?
    } else {
        parse_text(path, data, index, fixed)?
    };
    fr.uncompressed_bytes = data.len() as u64;
    if fr.rows.is_empty() {
        return Err(HarnessError::submission(
            path,
            None,
            None,
            "no rows (empty table)",
        ));
    }
    check_duplicates(path, &fr.rows, index, !is_fits)?;
    check_sums(path, &fr.rows, index, !is_fits)?;
    Ok(fr)
}

/// Refuses weights whose sums over an image overflow: Σw, Σw|e1| and
/// Σw|e2| must stay finite (every image's rows are in one file). Names the
/// row at which a sum first becomes infinite.
fn check_sums(
    path: &Path,
    rows: &[(usize, SubRow)],
    index: &ImageIndex,
    text: bool,
) -> Result<(), HarnessError> {
    let mut sums = vec![[0.0f64; 3]; index.images.len()];
    for (i, r) in rows {
        let s = &mut sums[*i];
        s[0] += r.weight;
        s[1] += r.weight * r.e1.abs();
        s[2] += r.weight * r.e2.abs();
        if s.iter().any(|v| !v.is_finite()) {
            return Err(overflow_error(path, *i, r, index, text));
        }
    }
    Ok(())
}

/// The column layout of a table.
struct Layout {
    image: Option<usize>,
    x: usize,
    y: usize,
    e1: usize,
    e2: usize,
    weight: Option<usize>,
    ignored: Vec<String>,
}

const REQUIRED: [&str; 4] = ["x", "y", "e1", "e2"];

/// Columns a table may have: more names on the header line of a text
/// table (or a FITS table with more `TFIELDS`, which the FITS standard caps
/// at 999) are refused, naming the file, the line and the count, before any
/// name is looked at. A submission needs seven at most (`image`, `x`, `y`,
/// `e1`, `e2`, `weight`, `flags`); 1024 leaves room for a pipeline's own.
pub const MAX_COLUMNS: usize = 1024;

/// Names of a header quoted in a message about it.
const HEADER_NAMES_SHOWN: usize = 16;

/// The refusal of a header of `n` > [`MAX_COLUMNS`] columns.
fn too_many_columns(path: &Path, header_line: Option<u64>, n: usize) -> HarnessError {
    let what = if header_line.is_some() {
        "the header names"
    } else {
        "the table has"
    };
    HarnessError::submission(
        path,
        header_line,
        None,
        format!("{what} {n} columns, more than the {MAX_COLUMNS} a submission may have"),
    )
}

/// The (lower-case) names of a header as a message quotes them: the first
/// [`HEADER_NAMES_SHOWN`], each cut by [`show_text`], then the count.
fn show_header(lower: &[String]) -> String {
    let mut s = lower
        .iter()
        .take(HEADER_NAMES_SHOWN)
        .map(|n| show_text(n))
        .collect::<Vec<_>>()
        .join(" ");
    if lower.len() > HEADER_NAMES_SHOWN {
        s.push_str(&format!(" … ({} columns)", lower.len()));
    }
    s
}

/// Refuses the first column, from the left, that has no name or repeats
/// an earlier one (one pass with a hash set: linear in the header's size).
fn check_names(
    path: &Path,
    header_line: Option<u64>,
    lower: &[String],
) -> Result<(), HarnessError> {
    let mut seen: HashSet<&str> = HashSet::with_capacity(lower.len());
    for (i, n) in lower.iter().enumerate() {
        if n.is_empty() {
            return Err(unnamed_column(path, header_line, i));
        }
        if !seen.insert(n.as_str()) {
            return Err(repeated_column(path, header_line, n));
        }
    }
    Ok(())
}

/// The obvious twin of [`check_names`] (quadratic: each name against all
/// before it), compared with it in the tests.
#[cfg(test)]
fn check_names_slow(
    path: &Path,
    header_line: Option<u64>,
    lower: &[String],
) -> Result<(), HarnessError> {
    for (i, n) in lower.iter().enumerate() {
        if n.is_empty() {
            return Err(unnamed_column(path, header_line, i));
        }
        if lower[..i].contains(n) {
            return Err(repeated_column(path, header_line, n));
        }
    }
    Ok(())
}

fn unnamed_column(path: &Path, header_line: Option<u64>, i: usize) -> HarnessError {
    HarnessError::submission(
        path,
        header_line,
        None,
        format!("column {} of the header has no name", i + 1),
    )
}

fn repeated_column(path: &Path, header_line: Option<u64>, name: &str) -> HarnessError {
    HarnessError::submission(
        path,
        header_line,
        Some(name),
        "column named twice in the header",
    )
}

/// Maps the header's names to the columns used. Linear in the size of
/// the header; refuses more than [`MAX_COLUMNS`] names.
fn layout(
    path: &Path,
    header_line: Option<u64>,
    names: &[String],
    fixed: Option<usize>,
) -> Result<Layout, HarnessError> {
    if names.len() > MAX_COLUMNS {
        return Err(too_many_columns(path, header_line, names.len()));
    }
    let lower: Vec<String> = names.iter().map(|n| n.to_ascii_lowercase()).collect();
    check_names(path, header_line, &lower)?;
    let find = |n: &str| lower.iter().position(|c| c == n);
    let missing = |name: &str| {
        HarnessError::submission(
            path,
            header_line,
            Some(name),
            format!(
                "required column missing (header has: {})",
                show_header(&lower)
            ),
        )
    };
    let mut req = [0usize; 4];
    for (k, name) in REQUIRED.iter().enumerate() {
        req[k] = find(name).ok_or_else(|| missing(name))?;
    }
    let image = find("image");
    if image.is_none() && fixed.is_none() {
        return Err(missing("image"));
    }
    // `flags` is documented (the pipeline's own bits, e.g. `stepsim
    // measure`'s): accepted and not used, so not reported as ignored.
    // Ignored names are kept as a message quotes them.
    let known = ["image", "x", "y", "e1", "e2", "weight", "flags"];
    let ignored = lower
        .iter()
        .filter(|n| !known.contains(&n.as_str()))
        .map(|n| show_text(n))
        .collect();
    Ok(Layout {
        image,
        x: req[0],
        y: req[1],
        e1: req[2],
        e2: req[3],
        weight: find("weight"),
        ignored,
    })
}

/// Checks one row's values and builds it. `at` builds the error location.
#[allow(clippy::too_many_arguments)]
fn make_row(
    index: &ImageIndex,
    image: usize,
    vals: [f64; 5],
    line: u64,
    err: &dyn Fn(&str, String) -> HarnessError,
) -> Result<(usize, SubRow), HarnessError> {
    let names = ["x", "y", "e1", "e2", "weight"];
    for (v, n) in vals.iter().zip(names) {
        if !v.is_finite() {
            return Err(err(n, format!("value `{}` is not finite", show_number(*v))));
        }
    }
    let [x, y, e1, e2, weight] = vals;
    if !(0.5..=f64::from(index.width_px) + 0.5).contains(&x) {
        return Err(err(
            "x",
            format!(
                "x = {x} is off the image (0.5 to {} allowed)",
                f64::from(index.width_px) + 0.5
            ),
        ));
    }
    if !(0.5..=f64::from(index.height_px) + 0.5).contains(&y) {
        return Err(err(
            "y",
            format!(
                "y = {y} is off the image (0.5 to {} allowed)",
                f64::from(index.height_px) + 0.5
            ),
        ));
    }
    if weight < 0.0 {
        return Err(err(
            "weight",
            format!("weight {} is negative", show_number(weight)),
        ));
    }
    for (v, n) in [(e1, "e1"), (e2, "e2")] {
        if v.abs() > MAX_ABS_SHEAR {
            return Err(err(
                n,
                format!(
                    "{n} = {} is beyond the accepted range (|{n}| ≤ {MAX_ABS_SHEAR:e}); \
                     cut failed measurements",
                    show_number(v)
                ),
            ));
        }
    }
    Ok((
        image,
        SubRow {
            x,
            y,
            e1,
            e2,
            weight,
            line,
        },
    ))
}

fn resolve_image(
    index: &ImageIndex,
    fixed: Option<usize>,
    id: Option<&str>,
    err: &dyn Fn(&str, String) -> HarnessError,
) -> Result<usize, HarnessError> {
    match (id, fixed) {
        (Some(id), Some(f)) => {
            if index.images[f].image == id {
                Ok(f)
            } else {
                Err(err(
                    "image",
                    format!(
                        "image `{}` in the file of image `{}`",
                        show_text(id),
                        index.images[f].image
                    ),
                ))
            }
        }
        (Some(id), None) => index
            .by_id
            .get(id)
            .copied()
            .ok_or_else(|| err("image", format!("unknown image id `{}`", show_text(id)))),
        (None, Some(f)) => Ok(f),
        (None, None) => Err(err("image", "no image id".into())),
    }
}

fn parse_text(
    path: &Path,
    bytes: &[u8],
    index: &ImageIndex,
    fixed: Option<usize>,
) -> Result<FileRows, HarnessError> {
    let bytes = text_start(path, bytes)?;
    let mut parser = TextParser::new(path, index, fixed);
    let mut rows = Vec::new();
    for (k, raw) in Lines(bytes).enumerate() {
        if let Some(row) = parser.line(k as u64 + 1, raw)? {
            rows.push(row);
        }
    }
    Ok(FileRows {
        rows,
        ignored_columns: parser.finish()?,
        uncompressed_bytes: 0,
    })
}

/// Refuses UTF-16 text and skips a UTF-8 byte-order mark: the start of the
/// text (at least its first 3 bytes, or all of it) in, the text to split
/// into lines out.
fn text_start<'a>(path: &Path, bytes: &'a [u8]) -> Result<&'a [u8], HarnessError> {
    if bytes.starts_with(&[0xff, 0xfe]) || bytes.starts_with(&[0xfe, 0xff]) {
        return Err(HarnessError::submission(
            path,
            Some(1),
            None,
            "the file is UTF-16 text; save it as UTF-8",
        ));
    }
    Ok(bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes))
}

/// The rows of a text table, one line at a time (the whole file read by
/// [`parse_file`] and the stream read by [`read_submission_limited`] share
/// it): the header, then a row or nothing for each line.
struct TextParser<'a> {
    path: &'a Path,
    index: &'a ImageIndex,
    fixed: Option<usize>,
    /// Layout, number of columns, CSV?
    header: Option<(Layout, usize, bool)>,
    record: csv::StringRecord,
    csv_reader: csv::ReaderBuilder,
}

impl<'a> TextParser<'a> {
    fn new(path: &'a Path, index: &'a ImageIndex, fixed: Option<usize>) -> Self {
        Self {
            path,
            index,
            fixed,
            header: None,
            record: csv::StringRecord::new(),
            csv_reader: csv_line_reader(),
        }
    }

    /// Reads line `line_no` (1-based, without its end).
    fn line(&mut self, line_no: u64, raw: &[u8]) -> Result<Option<(usize, SubRow)>, HarnessError> {
        let path = self.path;
        if let Some(c) = raw.iter().find(|&&c| c < 0x20 && c != b'\t' || c == 0x7f) {
            let what = if *c == 0 {
                "a NUL byte".to_owned()
            } else {
                format!("the control character 0x{c:02x}")
            };
            return Err(HarnessError::submission(
                path,
                Some(line_no),
                None,
                format!("contains {what}: this is binary data, not a text table"),
            ));
        }
        let text = std::str::from_utf8(raw).map_err(|_| {
            HarnessError::submission(path, Some(line_no), None, "not text (invalid UTF-8)")
        })?;
        let text = text.trim();
        if text.is_empty() {
            return Ok(None);
        }
        let Some((lay, ncol, csv)) = &self.header else {
            let (body, hash) = match text.strip_prefix('#') {
                Some(rest) => (rest, true),
                None => (text, false),
            };
            let csv = body.contains(',');
            if !hash && !csv {
                return Err(HarnessError::submission(
                    path,
                    Some(line_no),
                    None,
                    "the first line must be a header: `# image x y e1 e2 weight` \
                     (whitespace) or `image,x,y,e1,e2,weight` (CSV)",
                ));
            }
            // The count is checked before a name is copied or compared.
            let names: Vec<String> = if csv {
                csv_fields(&self.csv_reader, body, &mut self.record);
                if self.record.len() > MAX_COLUMNS {
                    return Err(too_many_columns(path, Some(line_no), self.record.len()));
                }
                self.record.iter().map(|s| unquote(s).to_owned()).collect()
            } else {
                let words: Vec<&str> = body.split_whitespace().collect();
                if words.len() > MAX_COLUMNS {
                    return Err(too_many_columns(path, Some(line_no), words.len()));
                }
                words.into_iter().map(str::to_owned).collect()
            };
            let lay = layout(path, Some(line_no), &names, self.fixed)?;
            self.header = Some((lay, names.len(), csv));
            return Ok(None);
        };
        if !*csv && text.starts_with('#') {
            return Ok(None);
        }
        let fields: Vec<&str> = if *csv {
            csv_fields(&self.csv_reader, text, &mut self.record);
            self.record.iter().map(unquote).collect()
        } else {
            text.split_whitespace().collect()
        };
        if fields.len() != *ncol {
            return Err(HarnessError::submission(
                path,
                Some(line_no),
                None,
                format!("expected {ncol} fields, found {}", fields.len()),
            ));
        }
        let err = |c: &str, m: String| HarnessError::submission(path, Some(line_no), Some(c), m);
        let num = |col: usize, name: &str| -> Result<f64, HarnessError> {
            fields[col].parse::<f64>().map_err(|_| {
                err(
                    name,
                    format!("cannot read `{}` as a number", show_text(fields[col])),
                )
            })
        };
        let image = resolve_image(self.index, self.fixed, lay.image.map(|c| fields[c]), &err)?;
        let vals = [
            num(lay.x, "x")?,
            num(lay.y, "y")?,
            num(lay.e1, "e1")?,
            num(lay.e2, "e2")?,
            match lay.weight {
                Some(c) => num(c, "weight")?,
                None => 1.0,
            },
        ];
        make_row(self.index, image, vals, line_no, &err).map(Some)
    }

    /// The ignored columns; refuses a text without a header.
    fn finish(self) -> Result<Vec<String>, HarnessError> {
        match self.header {
            Some((lay, _, _)) => Ok(lay.ignored),
            None => Err(HarnessError::submission(
                self.path,
                None,
                None,
                "empty file (no header, no rows)",
            )),
        }
    }
}

/// The lines of a text, ended by LF, CR LF or a lone CR (without the ends).
struct Lines<'a>(&'a [u8]);

impl<'a> Iterator for Lines<'a> {
    type Item = &'a [u8];
    fn next(&mut self) -> Option<&'a [u8]> {
        if self.0.is_empty() {
            return None;
        }
        let end = self
            .0
            .iter()
            .position(|&c| c == b'\n' || c == b'\r')
            .unwrap_or(self.0.len());
        let line = &self.0[..end];
        let skip = match self.0.get(end..end + 2) {
            Some(b"\r\n") => 2,
            Some(_) => 1,
            None => usize::from(end < self.0.len()),
        };
        self.0 = &self.0[end + skip..];
        Some(line)
    }
}

/// The `csv` crate's reader for one line of a CSV submission: no header,
/// any number of fields (counted by the caller, who names the line), each
/// trimmed of blanks; a field in double quotes may hold commas, and `""`
/// inside it stands for one quote.
fn csv_line_reader() -> csv::ReaderBuilder {
    let mut b = csv::ReaderBuilder::new();
    b.has_headers(false)
        .flexible(true)
        .trim(csv::Trim::All)
        .buffer_capacity(256);
    b
}

/// Reads the fields of one CSV line into `record` (none when the line
/// holds no record).
fn csv_fields(reader: &csv::ReaderBuilder, line: &str, record: &mut csv::StringRecord) {
    let mut rd = reader.from_reader(line.as_bytes());
    if !matches!(rd.read_record(record), Ok(true)) {
        record.clear();
    }
}

/// A field still wrapped in double quotes after the CSV reader (quotes
/// after leading blanks are not CSV quotes) loses them, as it always has.
fn unquote(s: &str) -> &str {
    s.strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .unwrap_or(s)
}

/// Opens the first table of the FITS file `open_path` (`path` itself, or
/// the inflated copy of a gzip `path`; `len` its bytes) and checks its
/// columns; errors name `path`.
fn open_table<'p>(
    path: &'p Path,
    open_path: &Path,
    len: u64,
    fixed: Option<usize>,
) -> Result<(Table<'p>, Layout, Vec<crate::read::fits_table::Column>), HarnessError> {
    if path.to_str().is_none() {
        // fitsio panics converting such a name for cfitsio.
        return Err(HarnessError::submission(
            path,
            None,
            None,
            "the file name is not valid UTF-8, which cfitsio cannot open; rename the file",
        ));
    }
    let f = stepsim_contract::io::fits::open_fits(open_path).map_err(|e| {
        // The message of an inflated copy names the copy: name the file.
        let e = HarnessError::from(e);
        if open_path == path {
            e
        } else {
            let m = e.to_string();
            let m = m.replace(
                &open_path.display().to_string(),
                &path.display().to_string(),
            );
            let m = m
                .strip_prefix(&format!("{}: ", path.display()))
                .unwrap_or(&m);
            HarnessError::submission(path, None, None, m.to_owned())
        }
    })?;
    let t = Table::first_table(f, path, len)?;
    let names: Vec<String> = t.columns.iter().map(|c| c.name.clone()).collect();
    let lay = layout(path, None, &names, fixed)?;
    let used = [
        Some(lay.x),
        Some(lay.y),
        Some(lay.e1),
        Some(lay.e2),
        lay.weight,
    ];
    for (i, c) in t.columns.iter().enumerate() {
        let wrong = |what: &str, need: &str| {
            HarnessError::submission(
                path,
                None,
                Some(&names[i].to_ascii_lowercase()),
                format!(
                    "the column holds {what} (TFORM `{}`) where {need} is needed",
                    c.tform
                ),
            )
        };
        match &c.kind {
            ColumnKind::Number if Some(i) == lay.image => {
                return Err(wrong("numbers", "text (the image id)"));
            }
            ColumnKind::Text if used.contains(&Some(i)) => {
                return Err(wrong("text", "one number per row"));
            }
            ColumnKind::Other(what) if used.contains(&Some(i)) => {
                return Err(wrong(what, "one number per row"));
            }
            ColumnKind::Other(what) if Some(i) == lay.image => {
                return Err(wrong(what, "text (the image id)"));
            }
            _ => {}
        }
    }
    let cols = t.columns.clone();
    Ok((t, lay, cols))
}

fn parse_fits(
    path: &Path,
    data: &[u8],
    index: &ImageIndex,
    fixed: Option<usize>,
) -> Result<FileRows, HarnessError> {
    let (mut t, lay, cols) = open_table(path, path, data.len() as u64, fixed)?;
    let xs = t.numbers(&cols[lay.x])?;
    let ys = t.numbers(&cols[lay.y])?;
    let e1s = t.numbers(&cols[lay.e1])?;
    let e2s = t.numbers(&cols[lay.e2])?;
    let ws = match lay.weight {
        Some(c) => Some(t.numbers(&cols[c])?),
        None => None,
    };
    let ids = match lay.image {
        Some(c) => Some(t.strings(&cols[c])?),
        None => None,
    };
    let mut rows = Vec::with_capacity(t.n_rows);
    for r in 0..t.n_rows {
        let row_no = r as u64 + 1;
        let err = |c: &str, m: String| HarnessError::submission_row(path, row_no, Some(c), m);
        let id = ids.as_ref().map(|v| v[r].as_str());
        let image = resolve_image(index, fixed, id, &err)?;
        let vals = [
            xs[r],
            ys[r],
            e1s[r],
            e2s[r],
            ws.as_ref().map_or(1.0, |w| w[r]),
        ];
        rows.push(make_row(index, image, vals, row_no, &err)?);
    }
    Ok(FileRows {
        rows,
        ignored_columns: lay.ignored,
        uncompressed_bytes: 0,
    })
}

/// Refuses a row with the same image, x and y as an earlier row.
fn check_duplicates(
    path: &Path,
    rows: &[(usize, SubRow)],
    index: &ImageIndex,
    text: bool,
) -> Result<(), HarnessError> {
    let mut seen: HashMap<(usize, u64, u64), u64> = HashMap::with_capacity(rows.len());
    for (i, r) in rows {
        // +0.0 and -0.0 are the same position.
        let key = (*i, (r.x + 0.0).to_bits(), (r.y + 0.0).to_bits());
        if let Some(first) = seen.insert(key, r.line) {
            return Err(duplicate_error(path, *i, r, first, index, text));
        }
    }
    Ok(())
}

/// The error for row `r` of image `i`, a duplicate of the row at `first`.
fn duplicate_error(
    path: &Path,
    i: usize,
    r: &SubRow,
    first: u64,
    index: &ImageIndex,
    text: bool,
) -> HarnessError {
    let what = if text { "line" } else { "row" };
    let msg = format!(
        "duplicate row: image `{}` x = {} y = {} already given at {what} {first}",
        index.images[i].image, r.x, r.y
    );
    if text {
        HarnessError::submission(path, Some(r.line), Some("x"), msg)
    } else {
        HarnessError::submission_row(path, r.line, Some("x"), msg)
    }
}

/// The error for row `r` of image `i`, at which the weighted sums overflow.
fn overflow_error(
    path: &Path,
    i: usize,
    r: &SubRow,
    index: &ImageIndex,
    text: bool,
) -> HarnessError {
    let msg = format!(
        "weight {} makes the weighted sums of image `{}` overflow (larger than \
         {:e}); scale the weights down",
        show_number(r.weight),
        index.images[i].image,
        f64::MAX
    );
    if text {
        HarnessError::submission(path, Some(r.line), Some("weight"), msg)
    } else {
        HarnessError::submission_row(path, r.line, Some("weight"), msg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn the_name_check_agrees_with_its_quadratic_twin() {
        let mut rng = stepsim_contract::seed::SimRng::seed_from_u64(23);
        let alphabet = ["", "x", "y", "e1", "E1", "image", "a", "b", "weight", "ab"];
        let path = Path::new("h.txt");
        let mut refused = 0;
        for _ in 0..2000 {
            let n = rng.random_range(0..12);
            let names: Vec<String> = (0..n)
                .map(|_| {
                    if rng.random_bool(0.7) {
                        format!("c{}", rng.random_range(0..40))
                    } else {
                        alphabet[rng.random_range(0..alphabet.len())].to_owned()
                    }
                })
                .collect();
            let fast = check_names(path, Some(3), &names).map_err(|e| e.to_string());
            let slow = check_names_slow(path, Some(3), &names).map_err(|e| e.to_string());
            assert_eq!(fast, slow, "{names:?}");
            refused += usize::from(fast.is_err());
        }
        assert!(refused > 200 && refused < 1800, "{refused}");
    }

    #[test]
    fn headers_quote_at_most_sixteen_names() {
        let names: Vec<String> = (0..40).map(|i| format!("c{i}")).collect();
        let s = show_header(&names);
        assert!(
            s.starts_with("c0 c1 ") && s.ends_with("c15 … (40 columns)"),
            "{s}"
        );
        assert_eq!(show_header(&names[..2]), "c0 c1");
    }
}
