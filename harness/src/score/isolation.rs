//! Which galaxies are blended? A galaxy is *isolated* when no other truth
//! object (galaxy or star, on or off the image) brighter than
//! [`ISOLATION_FLUX_FRACTION`] of its flux lies within
//! [`ISOLATION_RADIUS_ARCSEC`] of it, judged on the truth table (image
//! positions, fluxes from the true `mag`). The report's `*_isolated`
//! figures use only rows matched to isolated galaxies, so a method's bias
//! can be told from the scene's blending bias (docs/scoring.md, "Blends").
//!
//! [`isolated`] sweeps the objects sorted by x; [`isolated_slow`] is its
//! slow, obvious reference.

use stepsim_contract::truth::TruthRow;

/// Default radius within which a neighbour counts (arcsec).
pub const ISOLATION_RADIUS_ARCSEC: f64 = 3.0;
/// Default flux fraction above which a neighbour counts.
pub const ISOLATION_FLUX_FRACTION: f64 = 0.1;

/// Relative flux of a magnitude (any zero point).
fn flux(mag: f64) -> f64 {
    10f64.powf(-0.4 * mag)
}

fn blends(g: &TruthRow, n: &TruthRow, r2: f64, fraction: f64) -> bool {
    (n.x - g.x).powi(2) + (n.y - g.y).powi(2) <= r2 && flux(n.mag) >= fraction * flux(g.mag)
}

/// Reference: for each row, true when it is a galaxy with no other row
/// within `radius_px` whose flux is at least `fraction` of its own. O(n²).
pub fn isolated_slow(truth: &[TruthRow], radius_px: f64, fraction: f64) -> Vec<bool> {
    let r2 = radius_px * radius_px;
    truth
        .iter()
        .enumerate()
        .map(|(i, g)| {
            !g.is_star()
                && !truth
                    .iter()
                    .enumerate()
                    .any(|(j, n)| j != i && blends(g, n, r2, fraction))
        })
        .collect()
}

/// The same as [`isolated_slow`], by a sweep over the rows sorted by x
/// (only rows with |Δx| ≤ radius are compared).
pub fn isolated(truth: &[TruthRow], radius_px: f64, fraction: f64) -> Vec<bool> {
    let r2 = radius_px * radius_px;
    let mut order: Vec<usize> = (0..truth.len()).collect();
    order.sort_by(|&a, &b| truth[a].x.total_cmp(&truth[b].x));
    let xs: Vec<f64> = order.iter().map(|&k| truth[k].x).collect();
    let mut out = vec![false; truth.len()];
    for (pos, &i) in order.iter().enumerate() {
        let g = &truth[i];
        if g.is_star() {
            continue;
        }
        let lo = xs.partition_point(|&x| x < g.x - radius_px);
        let hi = xs.partition_point(|&x| x <= g.x + radius_px);
        out[i] = !(lo..hi).any(|p| p != pos && blends(g, &truth[order[p]], r2, fraction));
    }
    out
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
        assert_eq!(isolated(&t, 14.6, 0.1), vec![false, false, false, true]);
        // With a 13-px radius the star is too far: the first is isolated;
        // the second never is (the first is 100× brighter).
        assert_eq!(isolated(&t, 13.0, 0.1), vec![true, false, false, true]);
        assert_eq!(isolated(&t, 13.0, 0.1), isolated_slow(&t, 13.0, 0.1));
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
                assert_eq!(isolated(&t, r, 0.1), isolated_slow(&t, r, 0.1));
            }
        }
    }
}
