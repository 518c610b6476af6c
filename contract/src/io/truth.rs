//! Truth tables on disk: FITS binary table (the reference form) and a CSV
//! twin for people who want to look at one.

use super::fits::{Primary, create_fits, finish_fits, open_fits};
use super::{IoError, write_atomically};
use crate::truth::{COLUMN_ORDER, Column, FLOAT_COLUMNS, INT_COLUMNS, TruthRow};
use fitsio::tables::{ColumnDataType, ColumnDescription};
use std::path::Path;

/// Extension name of the truth table HDU.
pub const TRUTH_EXTNAME: &str = "TRUTH";

/// Header keywords written into the truth table HDU (name, value, comment).
pub type Keyword = (String, f64, String);

/// Writes a truth table as a FITS binary table (HDU 1, EXTNAME `TRUTH`),
/// atomically. `keywords` go into the table header.
pub fn write_truth_fits(
    path: &Path,
    rows: &[TruthRow],
    keywords: &[Keyword],
) -> Result<(), IoError> {
    write_atomically(path, |tmp| {
        let fe = |e: fitsio::errors::Error| IoError::fits(path, e);
        let mut f = create_fits(tmp, Primary::default())?;
        // Columns in SPEC §5 order; values are written by name below.
        let mut cols = Vec::with_capacity(COLUMN_ORDER.len());
        for name in COLUMN_ORDER {
            let typ = match TruthRow::default().value(name) {
                Some(Column::Long(_)) => ColumnDataType::LongLong,
                Some(Column::Int(_)) => ColumnDataType::Int,
                _ => ColumnDataType::Double,
            };
            cols.push(
                ColumnDescription::new(*name)
                    .with_type(typ)
                    .create()
                    .map_err(fe)?,
            );
        }
        let hdu = f.create_table(TRUTH_EXTNAME, &cols).map_err(fe)?;
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
