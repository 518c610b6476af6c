//! SkyMaker/Stuff object lists (SPEC §2), read and written.
//!
//! One object per line, whitespace-separated; blank lines and lines starting
//! with `#` are ignored.
//!
//! ```text
//! 100 x y mag                                                     star
//! 200 x y mag B/T bulge_re bulge_q bulge_pa disk_h disk_q disk_pa [z] [type]
//! ```
//!
//! * `x`, `y`: FITS pixel coordinates (first pixel centre 1.0).
//! * `mag`: apparent magnitude (our I, Vega).
//! * `bulge_re`: bulge effective radius, `disk_h`: disk scale length, both
//!   in arcsec **along the major axis** (SPEC §2).
//! * `bulge_q`, `disk_q`: the *apparent* axis ratios b/a of the components,
//!   i.e. our `bulge_ba` and `disk_ba` columns (not the intrinsic
//!   flattening q of the truth table). Stuff writes disk_q = cos i, so
//!   reading sets `incl_deg = acos(disk_q)` and recovers the intrinsic bulge
//!   flattening from β² = q² sin² i + cos² i where i > 0.
//! * `bulge_pa`, `disk_pa`: position angles in degrees, counter-clockwise
//!   from +x. Our galaxies are co-axial, so a line whose two angles differ
//!   (modulo 180°, for two components that both have light and are not
//!   round) is refused.
//! * `z`: redshift (optional, 0 when absent); `type`: de Vaucouleurs T
//!   (optional; Stuff writes −6 E, −2 S0, 2 Sab, 4 Sbc, 6 Scd, 10 Irr).
//!
//! Reading never panics: every error names the file, the 1-based line, the
//! field and the offending text.

use crate::model::population::ListObject;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use stepsim_contract::io::{IoError, write_bytes_atomically};
use stepsim_contract::truth::TruthRow;

/// An error in a SkyMaker list.
#[derive(Debug, thiserror::Error)]
pub enum ListError {
    /// The file could not be read or written.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A line is malformed.
    #[error("{path}: line {line}: field `{field}`: {message}")]
    Line {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The field (column name) at fault.
        field: &'static str,
        /// What is wrong, with the offending text.
        message: String,
    },
}

const GALAXY_FIELDS: [&str; 13] = [
    "code", "x", "y", "mag", "bt", "bulge_re", "bulge_q", "bulge_pa", "disk_h", "disk_q",
    "disk_pa", "z", "type",
];

/// Parses list text; `path` is used in messages only.
pub fn parse_list(text: &str, path: &Path) -> Result<Vec<ListObject>, ListError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let err = |field: &'static str, message: String| ListError::Line {
            path: path.into(),
            line,
            field,
            message,
        };
        // The first 13 fields (the most a line may have) are kept; all are
        // checked, and counted.
        let (mut words, mut vals, mut count) = ([""; 13], [0.0f64; 13], 0);
        for (j, w) in content.split_ascii_whitespace().enumerate() {
            let field = GALAXY_FIELDS.get(j).copied().unwrap_or("extra");
            let v: f64 = w
                .parse()
                .map_err(|_| err(field, format!("`{w}` is not a number")))?;
            if !v.is_finite() {
                return Err(err(field, format!("`{w}` is not finite")));
            }
            if j < vals.len() {
                (words[j], vals[j]) = (w, v);
            }
            count = j + 1;
        }
        let code = vals[0];
        if code == 100.0 {
            if count != 4 {
                return Err(err(
                    "code",
                    format!("a star line has 4 fields (100 x y mag), found {count}"),
                ));
            }
            out.push(ListObject::Star {
                x: vals[1],
                y: vals[2],
                mag: vals[3],
            });
        } else if code == 200.0 {
            if !(11..=13).contains(&count) {
                return Err(err(
                    "code",
                    format!(
                        "a galaxy line has 11 to 13 fields (200 x y mag B/T bulge_re \
                             bulge_q bulge_pa disk_h disk_q disk_pa [z] [type]), found {count}"
                    ),
                ));
            }
            let check = |j: usize, lo: f64, hi: f64, lo_open: bool| {
                let v = vals[j];
                let ok = if lo_open { v > lo } else { v >= lo } && v <= hi;
                if ok {
                    Ok(v)
                } else {
                    let open = if lo_open { "(" } else { "[" };
                    Err(err(
                        GALAXY_FIELDS[j],
                        format!("{} is outside {open}{lo}, {hi}]", words[j]),
                    ))
                }
            };
            let bt = check(4, 0.0, 1.0, false)?;
            let bulge_re = check(5, 0.0, 3600.0, false)?;
            let bulge_q = check(6, 0.0, 1.0, true)?;
            let disk_h = check(8, 0.0, 3600.0, false)?;
            let disk_q = check(9, 0.0, 1.0, true)?;
            let z = if count > 11 {
                Some(check(11, 0.0, 100.0, false)?)
            } else {
                None
            };
            if bt > 0.0 && bulge_re == 0.0 {
                return Err(err("bulge_re", "B/T > 0 needs bulge_re > 0".into()));
            }
            if bt < 1.0 && disk_h == 0.0 {
                return Err(err("disk_h", "B/T < 1 needs disk_h > 0".into()));
            }
            let (bpa, dpa) = (vals[7], vals[10]);
            let diff = (bpa - dpa).rem_euclid(180.0);
            let diff = diff.min(180.0 - diff);
            if bt > 0.0 && bt < 1.0 && bulge_q < 1.0 && disk_q < 1.0 && diff > 1e-3 {
                return Err(err(
                    "disk_pa",
                    format!(
                        "bulge_pa {bpa} and disk_pa {dpa} differ: stepsim galaxies are co-axial"
                    ),
                ));
            }
            out.push(ListObject::Galaxy {
                x: vals[1],
                y: vals[2],
                mag: vals[3],
                bt,
                bulge_re_arcsec: bulge_re,
                bulge_ba: bulge_q,
                bulge_pa_deg: bpa,
                disk_h_arcsec: disk_h,
                disk_ba: disk_q,
                disk_pa_deg: dpa,
                z,
                t_type: (count > 12).then_some(vals[12]),
            });
        } else {
            return Err(err(
                "code",
                format!(
                    "`{}` is not an object code (100 star, 200 galaxy)",
                    words[0]
                ),
            ));
        }
    }
    Ok(out)
}

/// Reads a list file.
pub fn read_list(path: &Path) -> Result<Vec<ListObject>, ListError> {
    Ok(read_list_and_bytes(path)?.0)
}

/// [`read_list`], also handing back the file's bytes (what a run keeps a
/// copy of): one read, so the objects are those of the bytes.
pub fn read_list_and_bytes(path: &Path) -> Result<(Vec<ListObject>, Vec<u8>), ListError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::os(path, e))?;
    let text = std::str::from_utf8(&bytes).map_err(|e| {
        IoError::os(
            path,
            std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("not UTF-8 text (byte {})", e.valid_up_to()),
            ),
        )
    })?;
    let objects = parse_list(text, path)?;
    Ok((objects, bytes))
}

/// Formats truth rows as a list. Galaxies get `t_types[hubble_type]` in
/// the type column (or the code itself when out of range). Numbers are
/// written in the shortest form that reads back exactly.
pub fn format_list(rows: &[TruthRow], t_types: &[f64]) -> String {
    let mut s = String::from(
        "# stepsim base field (SkyMaker/Stuff list): 100 x y mag | 200 x y mag B/T \
         bulge_re bulge_q bulge_pa disk_h disk_q disk_pa z type\n",
    );
    for r in rows {
        if r.is_star() {
            let _ = writeln!(s, "100 {} {} {}", r.x, r.y, r.mag);
        } else {
            let t = usize::try_from(r.hubble_type)
                .ok()
                .and_then(|i| t_types.get(i).copied())
                .unwrap_or(f64::from(r.hubble_type));
            let _ = writeln!(
                s,
                "200 {} {} {} {} {} {} {} {} {} {} {} {}",
                r.x,
                r.y,
                r.mag,
                r.bt,
                r.bulge_re_arcsec,
                r.bulge_ba,
                r.pa_deg,
                r.disk_h_arcsec,
                r.disk_ba,
                r.pa_deg,
                r.z,
                t
            );
        }
    }
    s
}

/// Writes a list atomically.
pub fn write_list(path: &Path, rows: &[TruthRow], t_types: &[f64]) -> Result<(), IoError> {
    write_bytes_atomically(path, format_list(rows, t_types).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_stars_galaxies_comments_and_optional_columns() {
        let text = "# header\n\n100 10.5 20.25 18.3\n\
                    200 1 2 22.5 0.3 0.4 0.8 30 0.5 0.6 30\n\
                    200 1 2 22.5 0.3 0.4 0.8 30 0.5 0.6 210 1.2 4\n";
        let v = parse_list(text, Path::new("a.list")).unwrap();
        assert_eq!(v.len(), 3);
        assert_eq!(
            v[0],
            ListObject::Star {
                x: 10.5,
                y: 20.25,
                mag: 18.3
            }
        );
        match v[2] {
            ListObject::Galaxy {
                z,
                t_type,
                disk_pa_deg,
                ..
            } => {
                assert_eq!((z, t_type, disk_pa_deg), (Some(1.2), Some(4.0), 210.0));
            }
            _ => panic!("expected a galaxy"),
        }
        assert!(matches!(v[1], ListObject::Galaxy { z: None, .. }));
    }

    #[test]
    fn malformed_lines_name_file_line_and_field() {
        let good = "200 1 2 22.5 0.3 0.4 0.8 30 0.5 0.6 30";
        let cases = [
            ("100 1 2", "line 2", "code"),
            ("100 1 2 x", "line 2", "mag"),
            ("300 1 2 3", "line 2", "code"),
            ("200 1 2 22 1.5 0.4 0.8 30 0.5 0.6 30", "line 2", "`bt`"),
            (
                "200 1 2 22 0.5 -0.4 0.8 30 0.5 0.6 30",
                "line 2",
                "bulge_re",
            ),
            ("200 1 2 22 0.5 0.4 0 30 0.5 0.6 30", "line 2", "bulge_q"),
            ("200 1 2 22 0.5 0.4 0.8 30 0.5 1.2 30", "line 2", "disk_q"),
            ("200 1 2 22 0.5 0.4 0.8 30 0.5 0.6 70", "line 2", "disk_pa"),
            ("200 1 2 22 0.5 0.4 0.8 30 0.5 0.6 30 -1", "line 2", "`z`"),
            (
                "200 1 2 22 0.5 0.4 0.8 30 0.5 0.6 30 1 4 9",
                "line 2",
                "code",
            ),
            ("200 1 2 22 0.5 0.4 0.8 30 0.5", "line 2", "code"),
            ("200 1 2 nan 0.5 0.4 0.8 30 0.5 0.6 30", "line 2", "mag"),
            ("200 1 2 22 0.5 0 0.8 30 0.5 0.6 30", "line 2", "bulge_re"),
            ("100 1 2 3e999", "line 2", "mag"),
            // A Unicode space does not separate fields.
            ("100 1 2\u{a0}3", "line 2", "`y`"),
            // Past the 13 fields a line may have: still counted and checked.
            ("100 1 2 3 4", "line 2", "found 5"),
            (
                "200 1 2 22 0.5 0.4 0.8 30 0.5 0.6 30 1 4 9 9 9",
                "line 2",
                "found 16",
            ),
            (
                "200 1 2 22 0.5 0.4 0.8 30 0.5 0.6 30 1 4 9 9 x",
                "line 2",
                "`extra`",
            ),
        ];
        for (bad, line, field) in cases {
            let text = format!("{good}\n{bad}\n{good}\n");
            let err = parse_list(&text, Path::new("f.list"))
                .unwrap_err()
                .to_string();
            assert!(err.contains("f.list"), "{bad}: {err}");
            assert!(err.contains(line), "{bad}: {err}");
            assert!(err.contains(field), "{bad}: expected {field} in {err}");
        }
        // Round components or pure bulges may carry any disk angle.
        let ok = "200 1 2 22 1 0.4 0.8 30 0.5 0.6 70\n200 1 2 22 0.5 0.4 1 30 0.5 0.6 70\n\
                  200 1 2 22 0.5 0.4 0.8 10 0.5 0.6 190\n";
        assert_eq!(parse_list(ok, Path::new("f.list")).unwrap().len(), 3);
    }

    #[test]
    fn missing_file_names_the_path() {
        let err = read_list(Path::new("/nonexistent/f.list"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/f.list"), "{err}");
    }
}
