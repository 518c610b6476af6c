//! Reading a submission (SPEC §6): one table, or a directory of per-image
//! tables, checked strictly against the run's images.
//!
//! Accepted forms, told apart by content (not by file name), each possibly
//! gzip-compressed (inflated here within the input limit):
//! * **FITS table** (the data start with `SIMPLE  =`): the first binary or
//!   ASCII table extension is read through [`crate::fits_table`] (column
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
//! directory, and more bytes than the limit ([`crate::input`]). The
//! submission is only read.

use crate::error::{HarnessError, show_text};
use crate::fits_table::{ColumnKind, Table};
use crate::input::{
    InputError, MAX_SUBMISSION_BYTES, gunzip_bounded, is_gzip, kind_of, read_entry_file,
    read_regular_file, show_bytes,
};
use crate::markdown::show_number;
use crate::truth_set::ImageIndex;
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};
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

/// A whole submission, rows grouped by image.
#[derive(Debug, Clone)]
pub struct Submission {
    /// The file or directory given.
    pub path: PathBuf,
    /// Rows of image `i` of the [`ImageIndex`] (empty when not submitted).
    pub per_image: Vec<Vec<SubRow>>,
    /// Columns present but not used (sorted, unique).
    pub ignored_columns: Vec<String>,
}

impl Submission {
    /// Total number of rows.
    pub fn n_rows(&self) -> usize {
        self.per_image.iter().map(Vec::len).sum()
    }

    /// Indices of images with no rows.
    pub fn missing_images(&self) -> Vec<usize> {
        (0..self.per_image.len())
            .filter(|&i| self.per_image[i].is_empty())
            .collect()
    }
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

pub use stepsim_contract::MAX_ABS_SHEAR;

/// Reads a submission file or directory, within [`MAX_SUBMISSION_BYTES`].
pub fn read_submission(path: &Path, index: &ImageIndex) -> Result<Submission, HarnessError> {
    read_submission_limited(path, index, MAX_SUBMISSION_BYTES)
}

/// Reads a submission file or directory of at most `max_bytes` bytes (the
/// sum over its files, both as stored and after gzip decompression).
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
    let at = |p: &Path, m: String| HarnessError::submission(p, None, None, m);
    let meta = std::fs::metadata(path).map_err(|e| at(path, format!("cannot read: {e}")))?;
    let files: Vec<(PathBuf, Option<usize>)> = if meta.is_dir() {
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
    };
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
    Ok(Submission {
        path: path.to_path_buf(),
        per_image,
        ignored_columns: ignored,
    })
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
            let msg = format!(
                "weight {} makes the weighted sums of image `{}` overflow (larger than \
                 {:e}); scale the weights down",
                show_number(r.weight),
                index.images[*i].image,
                f64::MAX
            );
            return Err(if text {
                HarnessError::submission(path, Some(r.line), Some("weight"), msg)
            } else {
                HarnessError::submission_row(path, r.line, Some("weight"), msg)
            });
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
    let mut header: Option<(Layout, usize, bool)> = None; // layout, n columns, csv?
    let mut rows = Vec::new();
    let mut record = csv::StringRecord::new();
    let csv_reader = csv_line_reader();
    if bytes.starts_with(&[0xff, 0xfe]) || bytes.starts_with(&[0xfe, 0xff]) {
        return Err(HarnessError::submission(
            path,
            Some(1),
            None,
            "the file is UTF-16 text; save it as UTF-8",
        ));
    }
    let bytes = bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes);
    for (k, raw) in Lines(bytes).enumerate() {
        let line_no = k as u64 + 1;
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
            continue;
        }
        let Some((lay, ncol, csv)) = &header else {
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
                csv_fields(&csv_reader, body, &mut record);
                if record.len() > MAX_COLUMNS {
                    return Err(too_many_columns(path, Some(line_no), record.len()));
                }
                record.iter().map(|s| unquote(s).to_owned()).collect()
            } else {
                let words: Vec<&str> = body.split_whitespace().collect();
                if words.len() > MAX_COLUMNS {
                    return Err(too_many_columns(path, Some(line_no), words.len()));
                }
                words.into_iter().map(str::to_owned).collect()
            };
            let lay = layout(path, Some(line_no), &names, fixed)?;
            header = Some((lay, names.len(), csv));
            continue;
        };
        if !*csv && text.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = if *csv {
            csv_fields(&csv_reader, text, &mut record);
            record.iter().map(unquote).collect()
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
        let image = resolve_image(index, fixed, lay.image.map(|c| fields[c]), &err)?;
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
        rows.push(make_row(index, image, vals, line_no, &err)?);
    }
    let Some((lay, _, _)) = header else {
        return Err(HarnessError::submission(
            path,
            None,
            None,
            "empty file (no header, no rows)",
        ));
    };
    Ok(FileRows {
        rows,
        ignored_columns: lay.ignored,
        uncompressed_bytes: 0,
    })
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

fn parse_fits(
    path: &Path,
    data: &[u8],
    index: &ImageIndex,
    fixed: Option<usize>,
) -> Result<FileRows, HarnessError> {
    if path.to_str().is_none() {
        // fitsio panics converting such a name for cfitsio.
        return Err(HarnessError::submission(
            path,
            None,
            None,
            "the file name is not valid UTF-8, which cfitsio cannot open; rename the file",
        ));
    }
    let f = stepsim_contract::io::fits::open_fits(path)?;
    let mut t = Table::first_table(f, path, data.len() as u64)?;
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
            let what = if text { "line" } else { "row" };
            let msg = format!(
                "duplicate row: image `{}` x = {} y = {} already given at {what} {first}",
                index.images[*i].image, r.x, r.y
            );
            return Err(if text {
                HarnessError::submission(path, Some(r.line), Some("x"), msg)
            } else {
                HarnessError::submission_row(path, r.line, Some("x"), msg)
            });
        }
    }
    Ok(())
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
