//! Truth tables on disk: FITS binary table (the reference form) and a CSV
//! twin for people who want to look at one.

use super::fits::{Primary, create_fits, finish_fits, open_fits, write_fits_hashed};
use super::{IoError, write_atomically};
use crate::truth::{COLUMN_ORDER, Column, FLOAT_COLUMNS, INT_COLUMNS, TruthRow};
use fitsio::tables::{ColumnDataType, ColumnDescription};
use std::path::Path;

/// Extension name of the truth table HDU.
pub const TRUTH_EXTNAME: &str = "TRUTH";

/// Header keywords written into the truth table HDU (name, value, comment).
pub type Keyword = (String, f64, String);

/// Writes a truth table as a FITS binary table (HDU 1, EXTNAME `TRUTH`),
/// atomically, and returns the SHA-256 (hex) of the file's bytes.
/// `keywords` go into the table header.
///
/// The rows go to cfitsio as one block of big-endian row bytes
/// (`row_bytes`, one `fits_write_tblbytes` call) and the file is built in
/// memory and hashed as written ([`super::fits::write_fits_hashed`]); the
/// bytes are those of the column-by-column writer
/// [`write_truth_fits_slow`] (test
/// `block_writer_equals_the_column_writer_byte_for_byte`).
pub fn write_truth_fits(
    path: &Path,
    rows: &[TruthRow],
    keywords: &[Keyword],
) -> Result<String, IoError> {
    let block = row_bytes(rows);
    write_fits_hashed(path, Primary::default(), |f| {
        let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
        let hdu = f.create_table(TRUTH_EXTNAME, &columns(path)?).map_err(fe)?;
        if !block.is_empty() {
            let mut status = 0;
            // SAFETY: `f` is open with the new table current; `block` holds
            // exactly rows × row length bytes, which cfitsio copies.
            unsafe {
                fitsio::sys::ffptbb(
                    f.as_raw(),
                    1,
                    1,
                    block.len() as i64,
                    block.as_ptr() as *mut u8,
                    &mut status,
                )
            };
            if status != 0 {
                return Err(IoError::fits_status(path, status));
            }
        }
        for (k, v, c) in keywords {
            hdu.write_key(f, k, (*v, c.as_str())).map_err(fe)?;
        }
        Ok(())
    })
}

/// The table's columns in SPEC §5 order, with their FITS types.
fn columns(path: &Path) -> Result<Vec<fitsio::tables::ConcreteColumnDescription>, IoError> {
    let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
    COLUMN_ORDER
        .iter()
        .map(|name| {
            let typ = match TruthRow::default().value(name) {
                Some(Column::Long(_)) => ColumnDataType::LongLong,
                Some(Column::Int(_)) => ColumnDataType::Int,
                _ => ColumnDataType::Double,
            };
            ColumnDescription::new(*name)
                .with_type(typ)
                .create()
                .map_err(fe)
        })
        .collect()
}

/// Where a column's value comes from in a [`TruthRow`].
#[derive(Clone, Copy)]
enum Source {
    Id,
    Int(usize),
    Float(usize),
}

/// The rows as FITS stores them: each row its columns in [`COLUMN_ORDER`],
/// big-endian (K: 8 bytes, J: 4, D: 8), rows one after the other.
fn row_bytes(rows: &[TruthRow]) -> Vec<u8> {
    let sources: Vec<Source> = COLUMN_ORDER
        .iter()
        .map(|name| {
            if *name == "id" {
                Source::Id
            } else if let Some(j) = INT_COLUMNS.iter().position(|c| c == name) {
                Source::Int(j)
            } else {
                let j = FLOAT_COLUMNS.iter().position(|c| c == name);
                Source::Float(j.expect("every column is id, an int or a float"))
            }
        })
        .collect();
    let row_len: usize = sources
        .iter()
        .map(|s| if matches!(s, Source::Int(_)) { 4 } else { 8 })
        .sum();
    let mut out = Vec::with_capacity(rows.len() * row_len);
    for r in rows {
        let (ints, floats) = (r.ints(), r.floats());
        for s in &sources {
            match *s {
                Source::Id => out.extend_from_slice(&r.id.to_be_bytes()),
                Source::Int(j) => out.extend_from_slice(&ints[j].to_be_bytes()),
                Source::Float(j) => out.extend_from_slice(&floats[j].to_be_bytes()),
            }
        }
    }
    out
}

/// The slow obvious twin of [`write_truth_fits`]: a file on disk, one
/// cfitsio column write per column (how tables were written before).
pub fn write_truth_fits_slow(
    path: &Path,
    rows: &[TruthRow],
    keywords: &[Keyword],
) -> Result<(), IoError> {
    write_atomically(path, |tmp| {
        let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
        let mut f = create_fits(tmp, Primary::default())?;
        let hdu = f.create_table(TRUTH_EXTNAME, &columns(path)?).map_err(fe)?;
        let ids: Vec<i64> = rows.iter().map(|r| r.id).collect();
        hdu.write_col(&mut f, "id", &ids).map_err(fe)?;
        for (j, name) in INT_COLUMNS.iter().enumerate() {
            let v: Vec<i32> = rows.iter().map(|r| r.ints()[j]).collect();
            hdu.write_col(&mut f, *name, &v).map_err(fe)?;
        }
        for (j, name) in FLOAT_COLUMNS.iter().enumerate() {
            let v: Vec<f64> = rows.iter().map(|r| r.floats()[j]).collect();
            hdu.write_col(&mut f, *name, &v).map_err(fe)?;
        }
        for (k, v, c) in keywords {
            hdu.write_key(&mut f, k, (*v, c.as_str())).map_err(fe)?;
        }
        finish_fits(f, path)
    })
}

/// Reads a truth table written by [`write_truth_fits`]. A missing column is
/// an error naming the file and the column.
pub fn read_truth_fits(path: &Path) -> Result<Vec<TruthRow>, IoError> {
    let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
    let mut f = open_fits(path)?;
    let hdu = f.hdu(TRUTH_EXTNAME).map_err(fe)?;
    let col_err = |name: &str, e: fitsio::errors::Error| {
        IoError::format(path, format!("column `{name}`: {e}"))
    };
    let ids: Vec<i64> = hdu.read_col(&mut f, "id").map_err(|e| col_err("id", e))?;
    let mut rows = vec![TruthRow::default(); ids.len()];
    for (r, id) in rows.iter_mut().zip(&ids) {
        r.id = *id;
    }
    for (j, name) in INT_COLUMNS.iter().enumerate() {
        let v: Vec<i32> = hdu.read_col(&mut f, name).map_err(|e| col_err(name, e))?;
        for (r, x) in rows.iter_mut().zip(v) {
            *r.ints_mut()[j] = x;
        }
    }
    for (j, name) in FLOAT_COLUMNS.iter().enumerate() {
        let v: Vec<f64> = hdu.read_col(&mut f, name).map_err(|e| col_err(name, e))?;
        for (r, x) in rows.iter_mut().zip(v) {
            *r.floats_mut()[j] = x;
        }
    }
    Ok(rows)
}

/// Writes the CSV twin of a truth table (header line of column names; floats
/// with 17 significant digits so that they read back exactly).
pub fn write_truth_csv(path: &Path, rows: &[TruthRow]) -> Result<(), IoError> {
    let fail = |e: csv::Error| IoError::format(path, format!("cannot format the CSV: {e}"));
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(Vec::new());
    w.write_record(TruthRow::column_names()).map_err(fail)?;
    for r in rows {
        let fields = COLUMN_ORDER.iter().map(|name| {
            match r.value(name).expect("every column has a value") {
                Column::Long(v) => v.to_string(),
                Column::Int(v) => v.to_string(),
                Column::Float(v) => format!("{v:?}"),
            }
        });
        w.write_record(fields).map_err(fail)?;
    }
    let bytes = w
        .into_inner()
        .map_err(|e| IoError::format(path, format!("cannot format the CSV: {e}")))?;
    super::write_bytes_atomically(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(n: usize) -> Vec<TruthRow> {
        (0..n)
            .map(|i| {
                let mut r = TruthRow {
                    id: i as i64 * 7 + 1,
                    kind: (i % 2) as i32,
                    hubble_type: i as i32 - 1,
                    ..Default::default()
                };
                for (j, v) in r.floats_mut().into_iter().enumerate() {
                    *v = (i * 31 + j) as f64 * 0.123_456_789_012_345 - 3.0;
                }
                r
            })
            .collect()
    }

    #[test]
    fn fits_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.fits");
        let rows = sample(50);
        write_truth_fits(&path, &rows, &[("PIXSCALE".into(), 0.206, "arcsec".into())]).unwrap();
        assert_eq!(read_truth_fits(&path).unwrap(), rows);
        // The file's columns are in SPEC §5 order.
        let mut f = open_fits(&path).unwrap();
        let hdu = f.hdu(TRUTH_EXTNAME).unwrap();
        let names: Vec<String> = match &hdu.info {
            fitsio::hdu::HduInfo::TableInfo {
                column_descriptions,
                ..
            } => column_descriptions.iter().map(|c| c.name.clone()).collect(),
            _ => panic!("not a table"),
        };
        assert_eq!(names, TruthRow::column_names());
        // Empty tables are fine too.
        write_truth_fits(&dir.path().join("e.fits"), &[], &[]).unwrap();
        assert!(
            read_truth_fits(&dir.path().join("e.fits"))
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn block_writer_equals_the_column_writer_byte_for_byte() {
        let dir = tempfile::tempdir().unwrap();
        let kw = [
            ("PIXSCALE".to_string(), 0.206, "arcsec".to_string()),
            ("G1".to_string(), -0.05, "shear".to_string()),
        ];
        for n in [0, 1, 7, 3000] {
            let rows = sample(n);
            let (a, b) = (dir.path().join("a.fits"), dir.path().join("b.fits"));
            let sha = write_truth_fits(&a, &rows, &kw).unwrap();
            write_truth_fits_slow(&b, &rows, &kw).unwrap();
            let (ba, bb) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
            assert_eq!(ba.len() % 2880, 0, "{n} rows");
            assert!(ba == bb, "{n} rows: the block writer's bytes differ");
            // The returned hash is the file's.
            assert_eq!(sha, crate::digest::sha256_hex(&bb), "{n} rows");
            assert_eq!(read_truth_fits(&a).unwrap(), rows);
        }
    }

    #[test]
    fn row_bytes_are_big_endian_in_column_order() {
        let rows = sample(2);
        let b = row_bytes(&rows);
        let row_len = 8 + 4 * INT_COLUMNS.len() + 8 * FLOAT_COLUMNS.len();
        assert_eq!(b.len(), 2 * row_len);
        // Row 1 starts with its id (8 bytes), then `kind` (4 bytes), then x.
        let r = &b[row_len..];
        assert_eq!(i64::from_be_bytes(r[..8].try_into().unwrap()), rows[1].id);
        assert_eq!(
            i32::from_be_bytes(r[8..12].try_into().unwrap()),
            rows[1].kind
        );
        assert_eq!(f64::from_be_bytes(r[12..20].try_into().unwrap()), rows[1].x);
    }

    #[test]
    fn csv_twin_has_a_header_and_one_line_per_row() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.csv");
        let rows = sample(3);
        write_truth_csv(&path, &rows).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4);
        assert_eq!(lines[0], TruthRow::column_names().join(","));
        assert!(lines[0].starts_with("id,kind,x,y,ra_deg,dec_deg,mag,flux_e,z,hubble_type,bt,"));
        let fields: Vec<&str> = lines[2].split(',').collect();
        assert_eq!(fields.len(), TruthRow::column_names().len());
        assert_eq!(fields[2].parse::<f64>().unwrap(), rows[1].x);
        assert_eq!(fields[9].parse::<i32>().unwrap(), rows[1].hubble_type);
        // Read back with the csv crate: every value exactly.
        let mut rd = csv::Reader::from_path(&path).unwrap();
        let back: Vec<csv::StringRecord> = rd.records().map(|r| r.unwrap()).collect();
        assert_eq!(back.len(), 3);
        for (rec, row) in back.iter().zip(&rows) {
            assert_eq!(rec[0].parse::<i64>().unwrap(), row.id);
            assert_eq!(rec[2].parse::<f64>().unwrap(), row.x);
            assert_eq!(rec[3].parse::<f64>().unwrap(), row.y);
        }
    }

    #[test]
    fn missing_file_names_the_path() {
        let err = read_truth_fits(Path::new("/nonexistent/x.fits"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/x.fits"), "{err}");
    }
}
