//! Which galaxies are blended? A galaxy is *isolated* when no other truth
//! object (galaxy or star, on or off the image) brighter than
//! [`ISOLATION_FLUX_FRACTION`] of its flux lies within
//! [`ISOLATION_RADIUS_ARCSEC`] of it, judged on the truth table (fluxes from
//! the true `mag`). The report's `*_isolated` figures use only rows matched
//! to isolated galaxies, so a method's bias can be told from the scene's
//! blending bias (docs/scoring.md, "Blends").
//!
//! Distances are taken in one of two [`Plane`]s. In an unlensed run (STEP1's
//! scene) the image plane is the only one. In a run whose galaxy positions
//! are lensed (`population.lens_positions`) two galaxies' separation is taken
//! in the *source* plane, A (x_i − x_j) with A the dataset's shear matrix
//! (SPEC §1), so that the class is the same set of galaxies in every
//! dataset: classed in the image plane, a pair stretched along the shear is
//! isolated more often at +g than at −g, which selects on the shear and
//! biases `m_isolated` by itself. Stars are not lensed, and a galaxy's
//! distance from a star is the image's in both planes.
//!
//! [`isolated`] sweeps the objects sorted by x; [`isolated_slow`] is its
//! slow, obvious reference.

use serde::{Deserialize, Serialize};
use stepsim_contract::truth::TruthRow;

/// Default radius within which a neighbour counts (arcsec).
pub const ISOLATION_RADIUS_ARCSEC: f64 = 3.0;
/// Default flux fraction above which a neighbour counts.
pub const ISOLATION_FLUX_FRACTION: f64 = 0.1;

/// Where two galaxies' separation is measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plane {
    /// As the image shows it (a run whose positions are not lensed).
    Image,
    /// Before the lensing of positions by the constant reduced shear
    /// (g1, g2): A (x_i − x_j), A = [`stepsim_contract::shear::shear_matrix`].
    Source {
        /// The dataset's g1.
        g1: f64,
        /// The dataset's g2.
        g2: f64,
    },
}

impl Plane {
    /// The position (x, y) of a galaxy in this plane, A (x, y) for
    /// [`Plane::Source`] (the lensing centre drops out of the differences,
    /// which are all that is used), its image position for [`Plane::Image`].
    fn galaxy_position(&self, x: f64, y: f64) -> (f64, f64) {
        match *self {
            Plane::Image => (x, y),
            Plane::Source { g1, g2 } => {
                let a = stepsim_contract::shear::shear_matrix(g1, g2);
                (a[0][0] * x + a[0][1] * y, a[1][0] * x + a[1][1] * y)
            }
        }
    }
}

/// Where a report's isolated galaxies were classed (`report.json`'s
/// `isolation_plane`): `"image"`, or `"source"` for a run whose galaxy
/// positions are lensed. A report written before the key reads as
/// `"image"`; any other value is refused when a report is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum IsolationPlane {
    /// Separations as the image shows them.
    #[default]
    Image,
    /// Two galaxies' separation with the dataset's shear undone.
    Source,
}

impl IsolationPlane {
    /// The plane of a run whose galaxy positions are lensed or not.
    pub fn of_run(lensed_positions: bool) -> Self {
        if lensed_positions {
            IsolationPlane::Source
        } else {
            IsolationPlane::Image
        }
    }

    /// Its name in `report.json`.
    pub fn name(self) -> &'static str {
        match self {
            IsolationPlane::Image => "image",
            IsolationPlane::Source => "source",
        }
    }
}

/// The parameters of the class: the radius (pixels), the flux fraction and
/// the plane of galaxies' separations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Isolation {
    /// Radius within which a neighbour counts (pixels).
    pub radius_px: f64,
    /// Flux fraction above which a neighbour counts.
    pub fraction: f64,
    /// Where two galaxies' separation is taken.
    pub plane: Plane,
}

impl Isolation {
    /// The harness's class ([`ISOLATION_RADIUS_ARCSEC`],
    /// [`ISOLATION_FLUX_FRACTION`]) on images of `pixel_scale_arcsec`.
    pub fn standard(pixel_scale_arcsec: f64, plane: Plane) -> Self {
        Isolation {
            radius_px: ISOLATION_RADIUS_ARCSEC / pixel_scale_arcsec,
            fraction: ISOLATION_FLUX_FRACTION,
            plane,
        }
    }
}

/// Relative flux of a magnitude (any zero point).
fn flux(mag: f64) -> f64 {
    10f64.powf(-0.4 * mag)
}

/// Squared distance of `g` and `n` as the class measures it: between two
/// galaxies, of their positions in the class's plane (each position
/// mapped, then subtracted, as [`isolated`]'s sweep does, so that the two
/// agree to the bit at the radius), else of their image positions.
fn distance2(g: &TruthRow, n: &TruthRow, plane: Plane) -> f64 {
    let ((gx, gy), (nx, ny)) = if g.is_star() || n.is_star() {
        ((g.x, g.y), (n.x, n.y))
    } else {
        (
            plane.galaxy_position(g.x, g.y),
            plane.galaxy_position(n.x, n.y),
        )
    };
    (nx - gx).powi(2) + (ny - gy).powi(2)
}

/// Reference: for each row, true when it is a galaxy with no other row
/// within the radius (measured as [`Plane`] says) whose flux is at least
/// the fraction of its own. O(n²).
pub fn isolated_slow(truth: &[TruthRow], class: Isolation) -> Vec<bool> {
    let r2 = class.radius_px * class.radius_px;
    truth
        .iter()
        .enumerate()
        .map(|(i, g)| {
            !g.is_star()
                && !truth.iter().enumerate().any(|(j, n)| {
                    j != i
                        && distance2(g, n, class.plane) <= r2
                        && flux(n.mag) >= class.fraction * flux(g.mag)
                })
        })
        .collect()
}

/// Marks each galaxy that has a neighbour among the rows `pos` holds
/// (`pos[k]` = (row, x, y) in the plane of the sweep): within `radius_px`
/// there and at least `fraction` of its flux. A sweep over the rows sorted
/// by x (only rows with |Δx| ≤ radius are compared).
fn mark_blended(
    truth: &[TruthRow],
    mut pos: Vec<(usize, f64, f64)>,
    radius_px: f64,
    fraction: f64,
    neighbour: impl Fn(&TruthRow) -> bool,
    blended: &mut [bool],
) {
    let r2 = radius_px * radius_px;
    pos.sort_by(|a, b| a.1.total_cmp(&b.1));
    let xs: Vec<f64> = pos.iter().map(|p| p.1).collect();
    for &(i, x, y) in &pos {
        let g = &truth[i];
        if g.is_star() || blended[i] {
            continue;
        }
        let lo = xs.partition_point(|&v| v < x - radius_px);
        let hi = xs.partition_point(|&v| v <= x + radius_px);
        blended[i] = pos[lo..hi].iter().any(|&(j, nx, ny)| {
            let n = &truth[j];
            j != i
                && neighbour(n)
                && (nx - x).powi(2) + (ny - y).powi(2) <= r2
                && flux(n.mag) >= fraction * flux(g.mag)
        });
    }
}

/// The same as [`isolated_slow`], by sweeps: in the image plane every pair,
/// or, for [`Plane::Source`], galaxy–star pairs in the image plane and
/// galaxy–galaxy pairs in the source plane.
pub fn isolated(truth: &[TruthRow], class: Isolation) -> Vec<bool> {
    let mut blended = vec![false; truth.len()];
    let image = || {
        truth
            .iter()
            .enumerate()
            .map(|(i, t)| (i, t.x, t.y))
            .collect()
    };
    let (r, f) = (class.radius_px, class.fraction);
    match class.plane {
        Plane::Image => mark_blended(truth, image(), r, f, |_| true, &mut blended),
        Plane::Source { .. } => {
            mark_blended(truth, image(), r, f, TruthRow::is_star, &mut blended);
            let source = truth
                .iter()
                .enumerate()
                .filter(|(_, t)| !t.is_star())
                .map(|(i, t)| {
                    let (x, y) = class.plane.galaxy_position(t.x, t.y);
                    (i, x, y)
                })
                .collect();
            mark_blended(truth, source, r, f, |n| !n.is_star(), &mut blended);
        }
    }
    truth
        .iter()
        .zip(blended)
        .map(|(t, b)| !t.is_star() && !b)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use stepsim_contract::seed::SimRng;
    use stepsim_contract::truth::{KIND_GALAXY, KIND_STAR};

    fn row(x: f64, y: f64, mag: f64, kind: i32) -> TruthRow {
        TruthRow {
            x,
            y,
            mag,
            kind,
            ..TruthRow::default()
        }
    }

    fn image(radius_px: f64) -> Isolation {
        Isolation {
            radius_px,
            fraction: 0.1,
            plane: Plane::Image,
        }
    }

    #[test]
    fn neighbours_count_by_distance_and_flux() {
        let t = [
            row(10.0, 10.0, 22.0, KIND_GALAXY),
            // 2.5 mag fainter (1 %) at 5 px: does not blend the first.
            row(15.0, 10.0, 24.5, KIND_GALAXY),
            // A star 2 mag fainter (16 %) at 14 px from the first.
            row(10.0, 24.0, 24.0, KIND_STAR),
            row(100.0, 100.0, 23.0, KIND_GALAXY),
        ];
        assert_eq!(isolated(&t, image(14.6)), vec![false, false, false, true]);
        // With a 13-px radius the star is too far: the first is isolated;
        // the second never is (the first is 100× brighter).
        assert_eq!(isolated(&t, image(13.0)), vec![true, false, false, true]);
        assert_eq!(isolated(&t, image(13.0)), isolated_slow(&t, image(13.0)));
    }

    #[test]
    fn sweep_matches_brute_force() {
        let mut rng = SimRng::seed_from_u64(7);
        for _ in 0..30 {
            let n = rng.random_range(0..400);
            let t: Vec<TruthRow> = (0..n)
                .map(|_| {
                    let kind = if rng.random::<f64>() < 0.1 {
                        KIND_STAR
                    } else {
                        KIND_GALAXY
                    };
                    // Integer positions make ties at exactly the radius.
                    let x = f64::from(rng.random_range(0..200));
                    row(
                        x,
                        f64::from(rng.random_range(0..200)),
                        rng.random_range(18.0..26.0),
                        kind,
                    )
                })
                .collect();
            for r in [5.0, 14.6] {
                for plane in [
                    Plane::Image,
                    Plane::Source { g1: 0.0, g2: 0.0 },
                    Plane::Source {
                        g1: 0.07,
                        g2: -0.05,
                    },
                    Plane::Source { g1: -0.3, g2: 0.2 },
                ] {
                    let class = Isolation {
                        radius_px: r,
                        fraction: 0.1,
                        plane,
                    };
                    assert_eq!(isolated(&t, class), isolated_slow(&t, class), "{class:?}");
                }
            }
        }
    }

    #[test]
    fn two_galaxies_are_apart_by_their_source_separation_and_a_star_by_the_image_s() {
        // g1 = 0.2 stretches x by (1 − |g|²)^(1/2)/(1 − g1) = 1.2247: two
        // galaxies 15 px apart along x in the image are 12.25 px apart in
        // the source plane, and two 11 px apart along y in the image come
        // from 13.47 px.
        let (g1, g2) = (0.2, 0.0);
        let source = |radius_px| Isolation {
            radius_px,
            fraction: 0.1,
            plane: Plane::Source { g1, g2 },
        };
        let t = [
            row(100.0, 100.0, 22.0, KIND_GALAXY),
            row(115.0, 100.0, 22.0, KIND_GALAXY),
            row(300.0, 100.0, 22.0, KIND_GALAXY),
            row(300.0, 111.0, 22.0, KIND_GALAXY),
            // A star 13 px along x from a galaxy: the image's distance.
            row(500.0, 100.0, 22.0, KIND_GALAXY),
            row(513.0, 100.0, 22.0, KIND_STAR),
        ];
        assert_eq!(
            isolated(&t, image(13.0)),
            vec![true, true, false, false, false, false]
        );
        assert_eq!(
            isolated(&t, source(13.0)),
            vec![false, false, true, true, false, false]
        );
        // 12.2 px: the source pair at 12.247 is apart, the star (13 px) too.
        assert_eq!(
            isolated(&t, source(12.2)),
            vec![true, true, true, true, true, false]
        );
        for r in [12.2, 13.0] {
            assert_eq!(isolated(&t, source(r)), isolated_slow(&t, source(r)));
        }
    }

    #[test]
    fn a_neighbour_exactly_at_the_radius_counts_in_the_source_plane() {
        // Ties: the radius set to a pair's distance as the class measures
        // it (where the square root squares back exactly); the sweep and
        // the reference agree that the neighbour blends.
        let mut rng = SimRng::seed_from_u64(5);
        let mut ties = 0;
        for _ in 0..2000 {
            let (x, y) = (rng.random_range(0.0..4096.0), rng.random_range(0.0..4096.0));
            let t = [
                row(x, y, 22.0, KIND_GALAXY),
                row(
                    x + rng.random_range(-9.0..9.0),
                    y + rng.random_range(-9.0..9.0),
                    22.5,
                    KIND_GALAXY,
                ),
            ];
            let plane = Plane::Source {
                g1: rng.random_range(-0.2..0.2),
                g2: rng.random_range(-0.2..0.2),
            };
            let d2 = distance2(&t[0], &t[1], plane);
            let class = Isolation {
                radius_px: d2.sqrt(),
                fraction: 0.1,
                plane,
            };
            if class.radius_px * class.radius_px != d2 {
                continue;
            }
            ties += 1;
            assert_eq!(isolated(&t, class), vec![false, false], "{t:?} {class:?}");
            assert_eq!(isolated_slow(&t, class), vec![false, false]);
        }
        assert!(ties > 500, "{ties}");
    }

    #[test]
    fn the_source_plane_class_is_the_same_galaxies_at_plus_and_minus_g() {
        // Galaxies lensed as `population.lens_positions` lenses them
        // (x = A⁻¹ x_s about a centre) at +g and −g: classed in the source
        // plane the isolated galaxies are those of the unlensed scene in
        // both datasets; classed in the image plane they are not. (Stars,
        // which stay in place, are the first test's.)
        let mut rng = SimRng::seed_from_u64(11);
        let (cx, cy) = (1024.5, 1024.5);
        let sources: Vec<TruthRow> = (0..3000)
            .map(|_| {
                row(
                    rng.random_range(1.0..2048.0),
                    rng.random_range(1.0..2048.0),
                    rng.random_range(20.0..25.0),
                    KIND_GALAXY,
                )
            })
            .collect();
        let lensed = |g1: f64, g2: f64| -> Vec<TruthRow> {
            sources
                .iter()
                .map(|s| {
                    let (dx, dy) =
                        stepsim_contract::shear::lens_offset((s.x - cx, s.y - cy), g1, g2);
                    row(cx + dx, cy + dy, s.mag, KIND_GALAXY)
                })
                .collect()
        };
        let unlensed = image(14.6);
        let at = |g1, g2| Isolation {
            plane: Plane::Source { g1, g2 },
            ..unlensed
        };
        let (plus, minus) = (lensed(0.05, -0.03), lensed(-0.05, 0.03));
        let truth = isolated(&sources, unlensed);
        assert_eq!(isolated(&plus, at(0.05, -0.03)), truth);
        assert_eq!(isolated(&minus, at(-0.05, 0.03)), truth);
        assert_eq!(isolated_slow(&plus, at(0.05, -0.03)), truth);
        let differ = |a: &[bool], b: &[bool]| a.iter().zip(b).filter(|(x, y)| x != y).count();
        let n_iso = truth.iter().filter(|&&i| i).count();
        let image_differ = differ(&isolated(&plus, unlensed), &isolated(&minus, unlensed));
        assert!((1500..2900).contains(&n_iso), "{n_iso}");
        assert!(image_differ >= 20, "{image_differ} of {n_iso}");
    }
}
