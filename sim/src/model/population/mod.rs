//! The Stuff-style galaxy and star population of the base fields (SPEC §2)
//! and the per-dataset sheared views of it (SPEC §5 truth columns).
//!
//! * [`base_field`]: every star and galaxy of one base field, unsheared.
//! * [`sheared`]: the view of a dataset with reduced shear g (κ = 0).
//! * [`rotated`]: the 90°-rotated twin of a base field.
//!
//! The model (types, luminosity functions, cosmology, sizes, shapes, stars)
//! lives in one file per concept; `docs/population.md` lists every number
//! and its source.
//!
//! Conventions (SPEC §1): sizes along the major axis; the renderer draws a
//! component as the circular profile stretched to axis ratio `*_ba` along
//! `pa_deg`, then applies the shear matrix A(g1, g2) of [`stepsim_contract::shear`].

pub mod cosmology;
pub mod shapes;
pub mod sizes;
mod spec;
pub mod stars;
pub mod stuff;

pub(crate) use spec::list_of;
pub use spec::{
    Cosmology, Flattening, GalaxySpec, GalaxyType, InclinationLaw, ListObject, Placement,
    PopulationSpec, Sizes, StarSpec,
};

use crate::model::wcs::TanWcs;
use cosmology::Lcdm;
use num_complex::Complex64;
use rand::RngExt;
use rand_distr::{Distribution, Poisson, StandardNormal};
use shapes::ShapeLaw;
use std::sync::{Arc, Mutex, OnceLock};
use stepsim_contract::seed::{SeedKey, Stream};
use stepsim_contract::shear::{self, Moments};
use stepsim_contract::truth::{KIND_GALAXY, KIND_STAR, TruthRow};
use stuff::StuffModel;

/// Most objects one base field may hold (a guard against configs that
/// would exhaust memory, e.g. `mag_faint` = 40).
pub const MAX_OBJECTS_PER_FIELD: f64 = 2e6;

/// An error while making a base field.
#[derive(Debug, thiserror::Error)]
pub enum PopulationError {
    /// A base field beyond the plan's, asked of a SkyMaker-list source.
    #[error("no SkyMaker list for base field {field}: the plan has {n_fields} base fields")]
    NoList {
        /// The field asked for.
        field: u32,
        /// Base fields of the plan.
        n_fields: u32,
    },
    /// The config asks for more objects than a field may hold.
    #[error(
        "{what}: {expected:.0} objects expected in one field (limit {MAX_OBJECTS_PER_FIELD:e}); lower `{key}`"
    )]
    TooMany {
        /// Galaxies or stars.
        what: &'static str,
        /// Expected number.
        expected: f64,
        /// The key to change.
        key: &'static str,
    },
}

/// Where galaxies are placed: [`PopulationSpec::placement`], widened with
/// `lens_positions` so that after lensing by any shear of the run
/// the galaxies still cover the image and its margin (the source-plane
/// rectangle A·(image + margin), A the shear matrix, about the image
/// centre). Lensing keeps areas, so the density on the image is unchanged.
pub fn galaxy_placement_area(spec: &PopulationSpec) -> Placement {
    let whole = spec.placement;
    if !spec.lens_positions {
        return whole;
    }
    let (xr, yr) = (whole.x_px, whole.y_px);
    let (cx, cy) = spec.lensing_centre;
    let (mut hx, mut hy) = (xr.1 - cx, yr.1 - cy);
    let (hx0, hy0) = (hx, hy);
    for &(g1, g2) in &spec.shears {
        let a = stepsim_contract::shear::shear_matrix(g1, g2);
        hx = hx.max(a[0][0].abs() * hx0 + a[0][1].abs() * hy0);
        hy = hy.max(a[1][0].abs() * hx0 + a[1][1].abs() * hy0);
    }
    if spec.rotate_positions {
        // The twin turns this area by 90° about the centre: a square keeps
        // it covering the image for every shear of the run (the turned
        // area of shear g is that of −g, whose box is this one's transposed).
        hx = hx.max(hy);
        hy = hx;
    }
    let s = spec.pixel_scale_arcsec / 60.0;
    Placement {
        area_arcmin2: 4.0 * hx * hy * s * s,
        x_px: (cx - hx, cx + hx),
        y_px: (cy - hy, cy + hy),
    }
}

/// The galaxies of `rows` with their positions lensed by (g1, g2) about
/// [`PopulationSpec::lensing_centre`] ([`stepsim_contract::shear::lens_offset`]), sky
/// coordinates recomputed from the images' WCS ([`PopulationSpec::wcs`], the
/// same for every base field: `_field` is unused); stars unchanged. Galaxies
/// that land beyond the image and its margin ([`PopulationSpec::placement`])
/// are left out, so every dataset has the density of an unlensed one.
pub fn lensed(
    spec: &PopulationSpec,
    _field: u32,
    rows: &[TruthRow],
    g1: f64,
    g2: f64,
) -> Vec<TruthRow> {
    let Placement {
        x_px: xr, y_px: yr, ..
    } = spec.placement;
    let (cx, cy) = spec.lensing_centre;
    let wcs = spec.wcs;
    rows.iter()
        .filter_map(|r| {
            if r.is_star() {
                return Some(*r);
            }
            let (dx, dy) = stepsim_contract::shear::lens_offset((r.x - cx, r.y - cy), g1, g2);
            let (x, y) = (cx + dx, cy + dy);
            if !(xr.0..=xr.1).contains(&x) || !(yr.0..=yr.1).contains(&y) {
                return None;
            }
            let mut r = *r;
            (r.x, r.y) = (x, y);
            (r.ra_deg, r.dec_deg) = wcs.pixel_to_sky(x, y);
            Some(r)
        })
        .collect()
}

/// The Stuff model of `spec` for its galaxy magnitude range. Tabulating it
/// (a Simpson integral per type and redshift cell) took about 0.1 CPU-s in
/// a profile, and a run asks for it several times (the memory and disk
/// estimates, the checks, each base field), so the process keeps the last
/// few models made, keyed by the galaxy model and the cosmology they were
/// made from: the same spec gives the same model, made once.
pub fn model(spec: &PopulationSpec) -> Arc<StuffModel> {
    tabulated(spec).model.clone()
}

/// A tabulated model and the kept fraction measured on it.
struct Tabulated {
    galaxies: GalaxySpec,
    cosmology: Cosmology,
    model: Arc<StuffModel>,
    kept: OnceLock<f64>,
}

/// How many tabulated models the process keeps (a run uses one; a server
/// may hold a few challenges).
const MODELS_KEPT: usize = 4;

fn tabulated(spec: &PopulationSpec) -> Arc<Tabulated> {
    static MODELS: Mutex<Vec<Arc<Tabulated>>> = Mutex::new(Vec::new());
    tabulated_in(&MODELS, spec)
}

/// [`tabulated`] with the store given (a test's own).
fn tabulated_in(store: &Mutex<Vec<Arc<Tabulated>>>, spec: &PopulationSpec) -> Arc<Tabulated> {
    let same = |t: &Tabulated| t.galaxies == spec.galaxies && t.cosmology == spec.cosmology;
    let found = |models: &mut Vec<Arc<Tabulated>>| {
        let i = models.iter().position(|t| same(t))?;
        let t = models.remove(i);
        models.push(t.clone());
        Some(t)
    };
    if let Some(t) = found(&mut store.lock().unwrap_or_else(|p| p.into_inner())) {
        return t;
    }
    // Tabulated outside the lock: two threads asking at once both make it
    // (the same values), and the first stored is kept.
    let g = &spec.galaxies;
    let made = Arc::new(Tabulated {
        galaxies: g.clone(),
        cosmology: spec.cosmology.clone(),
        model: Arc::new(StuffModel::new(
            g,
            Lcdm::new(&spec.cosmology),
            g.mag_bright,
            g.mag_faint,
        )),
        kept: OnceLock::new(),
    });
    let mut models = store.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(t) = found(&mut models) {
        return t;
    }
    if models.len() == MODELS_KEPT {
        models.remove(0);
    }
    models.push(made.clone());
    made
}

/// All stars and galaxies of base field `field`, unsheared (g1 = g2 = 0,
/// sheared columns equal to the intrinsic ones), with unique ids, sorted by
/// id. Randomness comes only from `SeedKey::base(seed, field, Galaxies)` and
/// `(…, Stars)`, so every dataset shares the field. With
/// SkyMaker lists the field's list ([`PopulationSpec::skymaker_list`],
/// read by the plan) is used instead.
pub fn base_field(spec: &PopulationSpec, field: u32) -> Result<Vec<TruthRow>, PopulationError> {
    if spec.reads_skymaker_lists() {
        let objects = spec.skymaker_list(field).ok_or(PopulationError::NoList {
            field,
            n_fields: spec.n_fields,
        })?;
        return Ok(from_list(spec, objects));
    }
    let mut rows = galaxies(spec, field)?;
    let first_star = rows.len() as i64 + 1;
    rows.extend(stars_of_field(spec, field, first_star)?);
    Ok(rows)
}

/// Checks, without drawing anything, that [`base_field`] will succeed for
/// every field of `spec`: the expected object counts are within
/// [`MAX_OBJECTS_PER_FIELD`] (a SkyMaker source's lists were read and
/// checked by the plan). Commands call this before writing anything.
pub fn preflight(spec: &PopulationSpec) -> Result<(), PopulationError> {
    if spec.reads_skymaker_lists() {
        return Ok(());
    }
    let area = galaxy_placement_area(spec).area_arcmin2;
    let expected = model(spec).density_per_arcmin2() * area;
    if expected > MAX_OBJECTS_PER_FIELD {
        return Err(PopulationError::TooMany {
            what: "galaxies",
            expected,
            key: "population.galaxies.mag_faint",
        });
    }
    let expected = spec.stars.density_per_arcmin2 * area;
    if expected > MAX_OBJECTS_PER_FIELD {
        return Err(PopulationError::TooMany {
            what: "stars",
            expected,
            key: "population.stars.density_per_arcmin2",
        });
    }
    Ok(())
}

/// Draws [`kept_fraction`] makes.
pub const KEPT_FRACTION_DRAWS: usize = 8192;

/// The fraction of the galaxies drawn by [`base_field`] that it keeps: those
/// whose observed magnitude (after the type's inclination dimming and
/// K-correction) lies in [`population.galaxies.mag_bright`,
/// `mag_faint`]. Estimated from [`KEPT_FRACTION_DRAWS`] draws of a fixed
/// stream (the same for every seed; binomial error at most 0.006); 1 for a
/// SkyMaker list, whose objects are all kept.
pub fn kept_fraction(spec: &PopulationSpec) -> f64 {
    if spec.reads_skymaker_lists() {
        return 1.0;
    }
    let g = &spec.galaxies;
    let tabulated = tabulated(spec);
    let model = &tabulated.model;
    *tabulated.kept.get_or_init(|| {
        let law = ShapeLaw::new(&g.flattening, g.inclination, g.max_inclination_deg);
        let mut rng = SeedKey::base(0, 0, Stream::Galaxies).rng();
        let kept = (0..KEPT_FRACTION_DRAWS)
            .filter(|_| {
                let lum = model.draw(&mut rng);
                let shape = law.draw(&mut rng);
                let t = &model.types[lum.code as usize];
                let (mag, _) = t.observe(lum.mag, shape.incl, lum.z);
                (g.mag_bright..=g.mag_faint).contains(&mag)
            })
            .count();
        kept as f64 / KEPT_FRACTION_DRAWS as f64
    })
}

/// de Vaucouleurs T of each Hubble type code (for SkyMaker lists).
pub fn t_types(spec: &PopulationSpec) -> Vec<f64> {
    spec.galaxies.types.iter().map(|t| t.t_type).collect()
}

fn galaxies(spec: &PopulationSpec, field: u32) -> Result<Vec<TruthRow>, PopulationError> {
    let g = &spec.galaxies;
    let model = model(spec);
    let Placement {
        area_arcmin2: area,
        x_px: xr,
        y_px: yr,
    } = galaxy_placement_area(spec);
    let expected = model.density_per_arcmin2() * area;
    if expected > MAX_OBJECTS_PER_FIELD {
        return Err(PopulationError::TooMany {
            what: "galaxies",
            expected,
            key: "population.galaxies.mag_faint",
        });
    }
    let mut rng = SeedKey::base(spec.seed, field, Stream::Galaxies).rng();
    let n = poisson(&mut rng, expected);
    let law = ShapeLaw::new(&g.flattening, g.inclination, g.max_inclination_deg);
    let wcs = spec.wcs;
    let ins = &spec.instrument;
    let sz = &g.sizes;
    let h = model.cosmo.h();
    let mut rows = Vec::with_capacity(n);
    for _ in 0..n {
        let x = xr.0 + (xr.1 - xr.0) * rng.random::<f64>();
        let y = yr.0 + (yr.1 - yr.0) * rng.random::<f64>();
        let lum = model.draw(&mut rng);
        let shape = law.draw(&mut rng);
        let n_disk: f64 = rng.sample(StandardNormal);
        let t = &model.types[lum.code as usize];
        let (mag, bt) = t.observe(lum.mag, shape.incl, lum.z);
        if !(g.mag_bright..=g.mag_faint).contains(&mag) {
            continue;
        }
        let dm = t.dm_star(lum.z);
        let zf = 1.0 + lum.z;
        let bulge_re = if t.bt > 0.0 {
            let m_b = lum.m_abs - 2.5 * t.bt.log10();
            let kpc = sizes::bulge_re_kpc(
                m_b - dm,
                sz.bulge_m_knee + 5.0 * h.log10(),
                sz.bulge_re_knee_kpc_h / h,
            ) * zf.powf(sz.bulge_evol);
            sizes::kpc_to_arcsec(kpc, lum.d_a_mpc)
        } else {
            0.0
        };
        let disk_h = if t.bt < 1.0 {
            let m_d = lum.m_abs - 2.5 * (1.0 - t.bt).log10();
            let kpc = sizes::disk_h_kpc(
                m_d - (t.m_star + dm),
                sz.disk_re_star_kpc_h / h,
                sz.disk_beta,
                sz.disk_sigma_ln,
                n_disk,
            ) * zf.powf(sz.disk_evol);
            sizes::kpc_to_arcsec(kpc, lum.d_a_mpc)
        } else {
            0.0
        };
        let (ra, dec) = wcs.pixel_to_sky(x, y);
        let mut r = TruthRow {
            id: rows.len() as i64 + 1,
            kind: KIND_GALAXY,
            hubble_type: lum.code,
            x,
            y,
            ra_deg: ra,
            dec_deg: dec,
            mag,
            flux_e: ins.mag_to_electrons(mag),
            z: lum.z,
            bt,
            bulge_re_arcsec: bulge_re,
            bulge_flat_q: shape.q,
            incl_deg: shape.incl.to_degrees(),
            bulge_ba: shape.bulge_ba,
            disk_h_arcsec: disk_h,
            disk_ba: shape.disk_ba,
            pa_deg: shape.theta.to_degrees(),
            ..TruthRow::default()
        };
        fill_ellipticities(&mut r);
        rows.push(r);
    }
    Ok(rows)
}

fn stars_of_field(
    spec: &PopulationSpec,
    field: u32,
    first_id: i64,
) -> Result<Vec<TruthRow>, PopulationError> {
    let s = &spec.stars;
    let Placement {
        area_arcmin2: area,
        x_px: xr,
        y_px: yr,
    } = spec.placement;
    let expected = s.density_per_arcmin2 * area;
    if expected > MAX_OBJECTS_PER_FIELD {
        return Err(PopulationError::TooMany {
            what: "stars",
            expected,
            key: "population.stars.density_per_arcmin2",
        });
    }
    let mut rng = SeedKey::base(spec.seed, field, Stream::Stars).rng();
    let n = poisson(&mut rng, expected);
    let wcs = spec.wcs;
    let ins = &spec.instrument;
    Ok((0..n)
        .map(|k| {
            let x = xr.0 + (xr.1 - xr.0) * rng.random::<f64>();
            let y = yr.0 + (yr.1 - yr.0) * rng.random::<f64>();
            let mag = stars::draw_mag(s, &mut rng);
            star_row(first_id + k as i64, x, y, mag, &wcs, ins)
        })
        .collect())
}

fn star_row(
    id: i64,
    x: f64,
    y: f64,
    mag: f64,
    wcs: &TanWcs,
    ins: &crate::model::noise::Instrument,
) -> TruthRow {
    let (ra, dec) = wcs.pixel_to_sky(x, y);
    TruthRow {
        id,
        kind: KIND_STAR,
        hubble_type: -1,
        x,
        y,
        ra_deg: ra,
        dec_deg: dec,
        mag,
        flux_e: ins.mag_to_electrons(mag),
        ..TruthRow::default()
    }
}

fn poisson(rng: &mut stepsim_contract::seed::SimRng, mean: f64) -> usize {
    if mean <= 0.0 {
        return 0;
    }
    match Poisson::new(mean) {
        Ok(p) => {
            let v: f64 = p.sample(rng);
            v as usize
        }
        Err(_) => mean.round() as usize,
    }
}

/// Truth rows from a SkyMaker list (ids = 1-based object order in the file).
pub fn from_list(spec: &PopulationSpec, objects: &[ListObject]) -> Vec<TruthRow> {
    let wcs = spec.wcs;
    let ins = &spec.instrument;
    let types = &spec.galaxies.types;
    objects
        .iter()
        .enumerate()
        .map(|(k, o)| {
            let id = k as i64 + 1;
            match *o {
                ListObject::Star { x, y, mag } => star_row(id, x, y, mag, &wcs, ins),
                ListObject::Galaxy {
                    x,
                    y,
                    mag,
                    bt,
                    bulge_re_arcsec,
                    bulge_ba,
                    bulge_pa_deg,
                    disk_h_arcsec,
                    disk_ba,
                    disk_pa_deg,
                    z,
                    t_type,
                } => {
                    let code = match t_type {
                        Some(t) => nearest(types.iter().map(|ty| ty.t_type), t),
                        None => nearest(types.iter().map(|ty| ty.bt), bt),
                    };
                    let incl = disk_ba.clamp(0.0, 1.0).acos();
                    let q = shapes::flattening_from_axis_ratio(bulge_ba, incl).unwrap_or(1.0);
                    // The angle of the component that defines the shape.
                    let pa = if bt >= 1.0 || disk_ba >= 1.0 {
                        bulge_pa_deg
                    } else {
                        disk_pa_deg
                    };
                    let (ra, dec) = wcs.pixel_to_sky(x, y);
                    let mut r = TruthRow {
                        id,
                        kind: KIND_GALAXY,
                        hubble_type: code,
                        x,
                        y,
                        ra_deg: ra,
                        dec_deg: dec,
                        mag,
                        flux_e: ins.mag_to_electrons(mag),
                        z: z.unwrap_or(0.0),
                        bt,
                        bulge_re_arcsec,
                        bulge_flat_q: q,
                        incl_deg: incl.to_degrees(),
                        bulge_ba,
                        disk_h_arcsec,
                        disk_ba,
                        pa_deg: pa.rem_euclid(180.0),
                        ..TruthRow::default()
                    };
                    fill_ellipticities(&mut r);
                    r
                }
            }
        })
        .collect()
}

fn nearest(values: impl Iterator<Item = f64>, target: f64) -> i32 {
    let mut best = (0, f64::INFINITY);
    for (i, v) in values.enumerate() {
        if (v - target).abs() < best.1 {
            best = (i as i32, (v - target).abs());
        }
    }
    best.0
}

/// Major-axis second moments (arcsec²) of the bulge and the disk of a row:
/// σ² = ⟨r²⟩/2 of the untruncated circular profile of the component's
/// major-axis size (de Vaucouleurs: ⟨r²⟩ = 21.6793 r_e²; exponential:
/// ⟨r²⟩ = 6 h²; see [`sizes`]).
pub fn component_sigma2(row: &TruthRow) -> (f64, f64) {
    (
        0.5 * crate::model::profile::sersic::devaucouleurs_r2_over_re2()
            * row.bulge_re_arcsec.powi(2),
        0.5 * crate::model::profile::Exponential::MEAN_R2 * row.disk_h_arcsec.powi(2),
    )
}

/// The intrinsic (unsheared) second-moment tensor of a galaxy: the
/// flux-weighted sum B/T·Q_bulge + (1 − B/T)·Q_disk of its components'
/// unweighted moments (arcsec²).
pub fn galaxy_moments(row: &TruthRow) -> Moments {
    let (sb, sd) = component_sigma2(row);
    let theta = row.pa_deg.to_radians();
    Moments::default()
        .add_weighted(row.bt, &Moments::of_ellipse(sb, row.bulge_ba, theta))
        .add_weighted(1.0 - row.bt, &Moments::of_ellipse(sd, row.disk_ba, theta))
}

/// Recomputes every ellipticity column of a galaxy row from its axis
/// ratios, position angle, sizes, B/T and its `g1`, `g2`: the components by
/// eq. 1 and eq. 8, the whole galaxy from the (sheared) moment tensor.
/// Stars are left alone.
pub fn fill_ellipticities(r: &mut TruthRow) {
    if r.is_star() {
        return;
    }
    let theta = r.pa_deg.to_radians();
    let g = Complex64::new(r.g1, r.g2);
    let eb = shear::ellipticity(r.bulge_ba, theta);
    let ed = shear::ellipticity(r.disk_ba, theta);
    let (ebs, eds) = (shear::apply_shear(eb, g), shear::apply_shear(ed, g));
    let q = galaxy_moments(r);
    let e_int = q.ellipticity();
    let e = q.sheared(r.g1, r.g2).ellipticity();
    (r.bulge_e1_int, r.bulge_e2_int) = (eb.re, eb.im);
    (r.disk_e1_int, r.disk_e2_int) = (ed.re, ed.im);
    (r.bulge_e1, r.bulge_e2) = (ebs.re, ebs.im);
    (r.disk_e1, r.disk_e2) = (eds.re, eds.im);
    (r.e1_int, r.e2_int) = (e_int.re, e_int.im);
    (r.e1, r.e2) = (e.re, e.im);
}

/// The view of a dataset with reduced shear (g1, g2): sheared ellipticities
/// of each component by eq. 8 and of the whole galaxy from its sheared
/// moment tensor; `g1`, `g2` set. Positions, fluxes, sizes and `pa_deg`
/// (intrinsic) are unchanged (κ = 0); stars change only in g1, g2.
///
/// Whole galaxy: Q = B/T·Q_b + (1 − B/T)·Q_d with Q_c = R(θ) diag(σ_c²,
/// β_c² σ_c²) R(θ)ᵀ and the exact moments of the untruncated profiles along
/// the major axis: de Vaucouleurs σ_b² = ⟨r²⟩/2 = Γ(16)/(2 Γ(8) b₄⁸) r_e²
/// = 10.840 r_e² (b₄ = 7.669249, the root of γ(8, b) = Γ(8)/2), exponential
/// σ_d² = Γ(4)/(2 Γ(2)) h² = 3 h² (Sérsic moments, Graham & Driver 2005,
/// PASA 22, 118). The sheared tensor is Q' = A⁻¹ Q A⁻ᵀ; e1, e2 are the
/// eq.-1 ellipticity of Q' and obey eq. 8 exactly.
pub fn sheared(rows: &[TruthRow], g1: f64, g2: f64) -> Vec<TruthRow> {
    rows.iter()
        .map(|r| {
            let mut r = *r;
            r.g1 = g1;
            r.g2 = g2;
            fill_ellipticities(&mut r);
            r
        })
        .collect()
}

/// The rotated twin of a base field as `spec` asks for it: [`rotated`],
/// and with `rotate_positions` every object's position turned by 90° about
/// [`PopulationSpec::lensing_centre`] as well ([`turned_positions`]).
pub fn twin(spec: &PopulationSpec, rows: &[TruthRow]) -> Vec<TruthRow> {
    let twin = rotated(rows);
    if spec.rotate_positions {
        turned_positions(spec, &twin)
    } else {
        twin
    }
}

/// Every object of `rows` (galaxies and stars) moved by a 90° turn about
/// [`PopulationSpec::lensing_centre`] (c), in the sense of the position
/// angles (from +x towards +y): (x, y) → (c_x − (y − c_y), c_y + (x − c_x)),
/// sky coordinates recomputed from the images' WCS. On a square image
/// c_x = c_y and pixel centres go to pixel centres exactly.
pub fn turned_positions(spec: &PopulationSpec, rows: &[TruthRow]) -> Vec<TruthRow> {
    let (cx, cy) = spec.lensing_centre;
    rows.iter()
        .map(|r| {
            let mut r = *r;
            (r.x, r.y) = (cx - (r.y - cy), cy + (r.x - cx));
            (r.ra_deg, r.dec_deg) = spec.wcs.pixel_to_sky(r.x, r.y);
            r
        })
        .collect()
}

/// The 90°-rotated twin: every galaxy's position angle turned by 90°
/// (intrinsic ellipticities change sign), same positions and everything
/// else; ellipticities recomputed with the rows' own g1, g2.
pub fn rotated(rows: &[TruthRow]) -> Vec<TruthRow> {
    rows.iter()
        .map(|r| {
            let mut r = *r;
            if !r.is_star() {
                r.pa_deg = (r.pa_deg + 90.0).rem_euclid(180.0);
                fill_ellipticities(&mut r);
            }
            r
        })
        .collect()
}

#[cfg(test)]
mod tests;
