//! Reading a submission (SPEC §6): one table, or a directory of per-image
//! tables, checked strictly against the run's images.
//!
//! Accepted forms, told apart by content (not by file name):
//! * **FITS binary table** (the file starts with `SIMPLE  =`, or is
//!   gzip-compressed, which cfitsio reads): the first
//!   binary or ASCII table extension is read; column names are matched
//!   case-insensitively; `image` must be a string column.
//! * **Whitespace ASCII**: the first non-blank line is the header, `#`
//!   followed by the column names (`# image x y e1 e2 weight`); later lines
//!   starting with `#` are comments; fields are separated by blanks or tabs.
//! * **CSV**: the first non-blank line is a comma-separated header
//!   (`image,x,y,e1,e2,weight`; a leading `#` is tolerated); fields may be
//!   wrapped in double quotes; no embedded commas.
//!
//! Required columns `image`, `x`, `y`, `e1`, `e2`; optional `weight`
//! (default 1, must be finite and ≥ 0). In a directory each file is named
//! `<image-id>.<ext>` and may omit `image` (when present it must equal the
//! file's id). Other columns are ignored and reported as warnings.
//!
//! Refused, naming file, line (FITS: row) and column: an unknown image id, a
//! missing required column, a repeated column, a value that does not parse,
//! NaN or infinity, x or y off the image (the half-pixel border,
//! 0.5 ≤ x ≤ width + 0.5, is on the image), a negative weight, a line with
//! the wrong number of fields, a duplicate row (same image, x and y as an
//! earlier row), a file with no rows. The submission is only read.

use crate::error::HarnessError;
use crate::truth_set::ImageIndex;
use rayon::prelude::*;
use std::collections::HashMap;
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
}

/// Reads a submission file or directory.
pub fn read_submission(path: &Path, index: &ImageIndex) -> Result<Submission, HarnessError> {
    let meta = std::fs::metadata(path)
        .map_err(|e| HarnessError::submission(path, None, None, format!("cannot read: {e}")))?;
    let files: Vec<(PathBuf, Option<usize>)> = if meta.is_dir() {
        let mut entries = Vec::new();
        let rd = std::fs::read_dir(path)
            .map_err(|e| HarnessError::submission(path, None, None, format!("cannot list: {e}")))?;
        for entry in rd {
            let entry = entry.map_err(|e| {
                HarnessError::submission(path, None, None, format!("cannot list: {e}"))
            })?;
            let p = entry.path();
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') || p.is_dir() {
                continue;
            }
            let stem = name.split('.').next().unwrap_or_default().to_owned();
            let Some(&i) = index.by_id.get(&stem) else {
                return Err(HarnessError::submission(
                    &p,
                    None,
                    None,
                    format!("unknown image id `{stem}` (files are named <image-id>.<ext>)"),
                ));
            };
            entries.push((p, Some(i)));
        }
        entries.sort();
        for w in entries.windows(2) {
            if w[0].1 == w[1].1 {
                return Err(HarnessError::submission(
                    &w[1].0,
                    None,
                    None,
                    format!(
                        "a second file for image `{}`",
                        index.images[w[1].1.unwrap_or(0)].image
                    ),
                ));
            }
        }
        if entries.is_empty() {
            return Err(HarnessError::submission(
                path,
                None,
                None,
                "empty directory",
            ));
        }
        entries
    } else {
        vec![(path.to_path_buf(), None)]
    };
    let parsed: Vec<Result<FileRows, HarnessError>> = files
        .par_iter()
        .map(|(p, fixed)| {
            let bytes = std::fs::read(p).map_err(|e| {
                HarnessError::submission(p, None, None, format!("cannot read: {e}"))
            })?;
            parse_file(p, &bytes, index, *fixed)
        })
        .collect();
    let mut per_image = vec![Vec::new(); index.images.len()];
    let mut ignored = Vec::new();
    for r in parsed {
        let fr = r?;
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

/// Parses the bytes of one submission file (any accepted form). `fixed`
/// is the image of a per-image file. Pure apart from FITS, which cfitsio
/// reads from `path`.
pub fn parse_file(
    path: &Path,
    bytes: &[u8],
    index: &ImageIndex,
    fixed: Option<usize>,
) -> Result<FileRows, HarnessError> {
    let is_fits = bytes.starts_with(b"SIMPLE  =") || bytes.starts_with(&[0x1f, 0x8b]);
    let fr = if is_fits {
        parse_fits(path, index, fixed)?
    } else {
        parse_text(path, bytes, index, fixed)?
    };
    if fr.rows.is_empty() {
        return Err(HarnessError::submission(
            path,
            None,
            None,
            "no rows (empty table)",
        ));
    }
    check_duplicates(path, &fr.rows, index, !is_fits)?;
    Ok(fr)
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

fn layout(
    path: &Path,
    header_line: Option<u64>,
    names: &[String],
    fixed: Option<usize>,
) -> Result<Layout, HarnessError> {
    let lower: Vec<String> = names.iter().map(|n| n.to_ascii_lowercase()).collect();
    for (i, n) in lower.iter().enumerate() {
        if n.is_empty() {
            return Err(HarnessError::submission(
                path,
                header_line,
                None,
                format!("column {} of the header has no name", i + 1),
            ));
        }
        if lower[..i].contains(n) {
            return Err(HarnessError::submission(
                path,
                header_line,
                Some(n),
                "column named twice in the header",
            ));
        }
    }
    let find = |n: &str| lower.iter().position(|c| c == n);
    let mut req = [0usize; 4];
    for (k, name) in REQUIRED.iter().enumerate() {
        req[k] = find(name).ok_or_else(|| {
            HarnessError::submission(
                path,
                header_line,
                Some(name),
                format!("required column missing (header has: {})", lower.join(" ")),
            )
        })?;
    }
    let image = find("image");
    if image.is_none() && fixed.is_none() {
        return Err(HarnessError::submission(
            path,
            header_line,
            Some("image"),
            format!("required column missing (header has: {})", lower.join(" ")),
        ));
    }
    let known = ["image", "x", "y", "e1", "e2", "weight"];
    let ignored = lower
        .iter()
        .filter(|n| !known.contains(&n.as_str()))
        .cloned()
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
            return Err(err(n, format!("value `{v}` is not finite")));
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
        return Err(err("weight", format!("weight {weight} is negative")));
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
                        "image `{id}` in the file of image `{}`",
                        index.images[f].image
                    ),
                ))
            }
        }
        (Some(id), None) => index
            .by_id
            .get(id)
            .copied()
            .ok_or_else(|| err("image", format!("unknown image id `{id}`"))),
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
    let mut fields: Vec<&str> = Vec::new();
    for (k, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let line_no = k as u64 + 1;
        let text = std::str::from_utf8(raw).map_err(|_| {
            HarnessError::submission(path, Some(line_no), None, "not text (invalid UTF-8)")
        })?;
        let text = text.strip_suffix('\r').unwrap_or(text).trim();
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
            let names: Vec<String> = if csv {
                body.split(',')
                    .map(|s| unquote(s.trim()).to_owned())
                    .collect()
            } else {
                body.split_whitespace().map(str::to_owned).collect()
            };
            let lay = layout(path, Some(line_no), &names, fixed)?;
            header = Some((lay, names.len(), csv));
            continue;
        };
        if !*csv && text.starts_with('#') {
            continue;
        }
        fields.clear();
        if *csv {
            fields.extend(text.split(',').map(|s| unquote(s.trim())));
        } else {
            fields.extend(text.split_whitespace());
        }
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
            fields[col]
                .parse::<f64>()
                .map_err(|_| err(name, format!("cannot read `{}` as a number", fields[col])))
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
    })
}

fn unquote(s: &str) -> &str {
    s.strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .unwrap_or(s)
}

fn parse_fits(
    path: &Path,
    index: &ImageIndex,
    fixed: Option<usize>,
) -> Result<FileRows, HarnessError> {
    use fitsio::hdu::HduInfo;
    let mut f = stepsim_sim::io::fits::open_fits(path)?;
    let mut found = None;
    let mut last_error = String::from("none");
    // Walk the extensions by index (fitsio's HDU iterator panics on a
    // corrupt header; `hdu(i)` returns an error instead).
    for i in 1..=999 {
        let hdu = match f.hdu(i) {
            Ok(h) => h,
            Err(e) => {
                last_error = e.to_string();
                break;
            }
        };
        if let HduInfo::TableInfo {
            column_descriptions,
            num_rows,
        } = &hdu.info
        {
            let (cols, n) = (column_descriptions.clone(), *num_rows);
            found = Some((hdu, cols, n));
            break;
        }
    }
    let Some((hdu, cols, nrows)) = found else {
        return Err(HarnessError::submission(
            path,
            None,
            None,
            format!("no readable table extension in this FITS file (cfitsio: {last_error})"),
        ));
    };
    let names: Vec<String> = cols.iter().map(|c| c.name.clone()).collect();
    let lay = layout(path, None, &names, fixed)?;
    for (i, c) in cols.iter().enumerate() {
        let used = [
            Some(lay.x),
            Some(lay.y),
            Some(lay.e1),
            Some(lay.e2),
            lay.weight,
        ];
        if used.contains(&Some(i)) && c.data_type.repeat != 1 {
            return Err(HarnessError::submission(
                path,
                None,
                Some(&names[i].to_ascii_lowercase()),
                format!(
                    "a vector column (repeat {}) where one number per row is needed",
                    c.data_type.repeat
                ),
            ));
        }
    }
    let read = |f: &mut fitsio::FitsFile, col: usize| -> Result<Vec<f64>, HarnessError> {
        hdu.read_col::<f64>(f, names[col].as_str()).map_err(|e| {
            HarnessError::submission(
                path,
                None,
                Some(&names[col].to_ascii_lowercase()),
                format!("cannot read as numbers: {e}"),
            )
        })
    };
    let xs = read(&mut f, lay.x)?;
    let ys = read(&mut f, lay.y)?;
    let e1s = read(&mut f, lay.e1)?;
    let e2s = read(&mut f, lay.e2)?;
    let ws = match lay.weight {
        Some(c) => Some(read(&mut f, c)?),
        None => None,
    };
    let ids: Option<Vec<String>> = match lay.image {
        Some(c) => Some(
            hdu.read_col::<String>(&mut f, names[c].as_str())
                .map_err(|e| {
                    HarnessError::submission(
                        path,
                        None,
                        Some("image"),
                        format!("cannot read as text: {e}"),
                    )
                })?,
        ),
        None => None,
    };
    let mut rows = Vec::with_capacity(nrows);
    for r in 0..nrows.min(xs.len()) {
        let row_no = r as u64 + 1;
        let err = |c: &str, m: String| HarnessError::submission_row(path, row_no, Some(c), m);
        let id = ids
            .as_ref()
            .map(|v| v.get(r).map(|s| s.trim()).unwrap_or(""));
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
