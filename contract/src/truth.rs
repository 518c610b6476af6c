//! The truth table: one row per object of a base field or image (SPEC §5).
//!
//! The same row type describes a base field (before shear: `g1 = g2 = 0`,
//! sheared columns equal to the intrinsic ones) and an image of a dataset
//! (after shear). The renderer draws an object from its row alone.
//!
//! Conventions: `x`, `y` are FITS pixel coordinates (first pixel centre at
//! 1.0); angles in degrees; sizes in arcsec along the major axis; ellipticities
//! are of the reduced-shear type e = (1−β)/(1+β)(cos 2θ, sin 2θ) (paper eq. 1).
//! Stars have `kind = 0`, `hubble_type = -1` and zero in every galaxy column.

/// Object kind code of a star.
pub const KIND_STAR: i32 = 0;
/// Object kind code of a galaxy.
pub const KIND_GALAXY: i32 = 1;

macro_rules! truth_row {
    (
        ints { $($iname:ident : $idoc:literal),* $(,)? }
        floats { $($fname:ident : $fdoc:literal),* $(,)? }
    ) => {
        /// One object of the truth table; field order is column order.
        #[derive(Debug, Clone, Copy, Default, PartialEq)]
        pub struct TruthRow {
            /// Object id, unique within a base field and equal across datasets.
            pub id: i64,
            $( #[doc = $idoc] pub $iname: i32, )*
            $( #[doc = $fdoc] pub $fname: f64, )*
        }

        /// Names of the integer columns after `id` (FITS type J).
        pub const INT_COLUMNS: &[&str] = &[$(stringify!($iname)),*];
        /// Names of the floating-point columns (FITS type D), in order.
        pub const FLOAT_COLUMNS: &[&str] = &[$(stringify!($fname)),*];

        impl TruthRow {
            /// The integer columns after `id`, in [`INT_COLUMNS`] order.
            pub fn ints(&self) -> [i32; INT_COLUMNS.len()] {
                [$(self.$iname),*]
            }
            /// The float columns, in [`FLOAT_COLUMNS`] order.
            pub fn floats(&self) -> [f64; FLOAT_COLUMNS.len()] {
                [$(self.$fname),*]
            }
            /// Mutable access to the float columns, in [`FLOAT_COLUMNS`] order.
            pub fn floats_mut(&mut self) -> [&mut f64; FLOAT_COLUMNS.len()] {
                [$(&mut self.$fname),*]
            }
            /// Mutable access to the integer columns, in [`INT_COLUMNS`] order.
            pub fn ints_mut(&mut self) -> [&mut i32; INT_COLUMNS.len()] {
                [$(&mut self.$iname),*]
            }
        }
    };
}

truth_row! {
    ints {
        kind: "0 star, 1 galaxy.",
        hubble_type: "Hubble type code: 0 E, 1 S0, 2 Sab, 3 Sbc, 4 Scd, 5 Irr; −1 for stars.",
    }
    floats {
        x: "FITS pixel x (first pixel centre = 1.0).",
        y: "FITS pixel y.",
        ra_deg: "Right ascension (TAN WCS of the field).",
        dec_deg: "Declination.",
        mag: "Apparent I magnitude (Vega).",
        flux_e: "Total flux in electrons over the exposure.",
        z: "Redshift (0 for stars).",
        bt: "Bulge-to-total flux ratio.",
        bulge_re_arcsec: "Bulge effective (half-light) radius along the major axis.",
        bulge_flat_q: "Intrinsic bulge flattening q.",
        incl_deg: "Inclination i of the disk plane.",
        bulge_ba: "Apparent bulge axis ratio β = sqrt(q² sin² i + cos² i).",
        disk_h_arcsec: "Disk exponential scale length along the major axis.",
        disk_ba: "Apparent disk axis ratio β = cos i.",
        pa_deg: "Intrinsic (unsheared) position angle, CCW from +x, in [0, 180).",
        bulge_e1_int: "Intrinsic bulge ellipticity e1 (eq. 1).",
        bulge_e2_int: "Intrinsic bulge ellipticity e2.",
        disk_e1_int: "Intrinsic disk ellipticity e1.",
        disk_e2_int: "Intrinsic disk ellipticity e2.",
        bulge_e1: "Sheared bulge ellipticity e1 (eq. 8).",
        bulge_e2: "Sheared bulge ellipticity e2.",
        disk_e1: "Sheared disk ellipticity e1.",
        disk_e2: "Sheared disk ellipticity e2.",
        e1_int: "Intrinsic whole-galaxy ellipticity e1 from flux-weighted second moments.",
        e2_int: "Intrinsic whole-galaxy ellipticity e2.",
        e1: "Sheared whole-galaxy ellipticity e1 (obeys eq. 8 exactly).",
        e2: "Sheared whole-galaxy ellipticity e2.",
        g1: "Applied reduced shear g1.",
        g2: "Applied reduced shear g2.",
    }
}

/// The columns of a truth table in file order: exactly the order of SPEC §5.
pub const COLUMN_ORDER: &[&str] = &[
    "id",
    "kind",
    "x",
    "y",
    "ra_deg",
    "dec_deg",
    "mag",
    "flux_e",
    "z",
    "hubble_type",
    "bt",
    "bulge_re_arcsec",
    "bulge_flat_q",
    "incl_deg",
    "bulge_ba",
    "disk_h_arcsec",
    "disk_ba",
    "pa_deg",
    "bulge_e1_int",
    "bulge_e2_int",
    "disk_e1_int",
    "disk_e2_int",
    "bulge_e1",
    "bulge_e2",
    "disk_e1",
    "disk_e2",
    "e1_int",
    "e2_int",
    "e1",
    "e2",
    "g1",
    "g2",
];

/// One cell of a truth row, typed as in the file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Column {
    /// 64-bit integer (`id`).
    Long(i64),
    /// 32-bit integer (`kind`, `hubble_type`).
    Int(i32),
    /// Double.
    Float(f64),
}

impl TruthRow {
    /// True for a star.
    pub fn is_star(&self) -> bool {
        self.kind == KIND_STAR
    }

    /// All column names in file order ([`COLUMN_ORDER`]).
    pub fn column_names() -> Vec<&'static str> {
        COLUMN_ORDER.to_vec()
    }

    /// The value of column `name`, typed as in the file, or `None` for an
    /// unknown name.
    pub fn value(&self, name: &str) -> Option<Column> {
        if name == "id" {
            return Some(Column::Long(self.id));
        }
        if let Some(j) = INT_COLUMNS.iter().position(|c| *c == name) {
            return Some(Column::Int(self.ints()[j]));
        }
        FLOAT_COLUMNS
            .iter()
            .position(|c| *c == name)
            .map(|j| Column::Float(self.floats()[j]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_are_the_spec_columns_in_order() {
        // SPEC §5, in its order (not sorted: the order is part of the file).
        let spec = "id kind x y ra_deg dec_deg mag flux_e z hubble_type bt bulge_re_arcsec bulge_flat_q \
                    incl_deg bulge_ba disk_h_arcsec disk_ba pa_deg bulge_e1_int bulge_e2_int disk_e1_int \
                    disk_e2_int bulge_e1 bulge_e2 disk_e1 disk_e2 e1_int e2_int e1 e2 g1 g2";
        let want: Vec<&str> = spec.split_whitespace().collect();
        assert_eq!(TruthRow::column_names(), want);
        // Every column has exactly one typed accessor.
        assert_eq!(want.len(), 1 + INT_COLUMNS.len() + FLOAT_COLUMNS.len());
        let r = TruthRow::default();
        assert!(want.iter().all(|c| r.value(c).is_some()));
        assert_eq!(r.value("nope"), None);
    }

    #[test]
    fn accessors_follow_column_order() {
        let mut r = TruthRow::default();
        for (i, v) in r.floats_mut().into_iter().enumerate() {
            *v = i as f64;
        }
        assert_eq!(r.x, 0.0);
        assert_eq!(r.y, 1.0);
        assert_eq!(r.g2, (FLOAT_COLUMNS.len() - 1) as f64);
        assert_eq!(r.floats()[5], r.flux_e);
    }
}
