//! Matching submitted positions to truth objects (SPEC §7): each submitted
//! object goes to the nearest truth object (galaxy or star) within the match
//! radius. Several submitted objects may match the same truth object (the
//! paper's rule; each counts). Ties in distance go to the lower truth index,
//! so the result is unique.
//!
//! [`match_nearest`] is the fast matcher (a uniform grid of cells no
//! smaller than the radius, so only the 3 × 3 neighbouring cells are
//! searched; about one truth object per cell);
//! [`match_nearest_slow`] is its slow, obvious reference.

/// Index of the matched truth object for each query, or `None`.
pub type Matches = Vec<Option<usize>>;

/// Is candidate (d2, j) better than the current best?
fn better(d2: f64, j: usize, best: Option<(f64, usize)>) -> bool {
    match best {
        None => true,
        Some((bd, bj)) => d2 < bd || (d2 == bd && j < bj),
    }
}

/// Reference matcher: compares every query with every truth object.
/// O(n·m); kept as the reference that tests [`match_nearest`].
pub fn match_nearest_slow(truth: &[(f64, f64)], queries: &[(f64, f64)], radius: f64) -> Matches {
    let r2 = radius * radius;
    queries
        .iter()
        .map(|&(qx, qy)| {
            let mut best = None;
            for (j, &(tx, ty)) in truth.iter().enumerate() {
                let d2 = (tx - qx).powi(2) + (ty - qy).powi(2);
                if d2 <= r2 && better(d2, j, best) {
                    best = Some((d2, j));
                }
            }
            best.map(|b| b.1)
        })
        .collect()
}

/// Fast matcher: bins the truth objects into square cells of side `radius`
/// and searches the 3 × 3 cells around each query. Same result as
/// [`match_nearest_slow`] (same distance formula, same tie rule).
pub fn match_nearest(truth: &[(f64, f64)], queries: &[(f64, f64)], radius: f64) -> Matches {
    if truth.is_empty() || radius.is_nan() || radius <= 0.0 {
        return match_nearest_slow(truth, queries, radius.max(0.0));
    }
    let r2 = radius * radius;
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for &(x, y) in truth {
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    // Cells of about one object each, never smaller than the radius (so the
    // 3 × 3 neighbourhood suffices) and never more cells than objects.
    let area = ((x1 - x0) * (y1 - y0)).max(0.0);
    let cell = radius
        .max((area / truth.len() as f64).sqrt())
        .max((x1 - x0).max(y1 - y0) / 4096.0);
    let nx = ((x1 - x0) / cell).floor() as usize + 1;
    let ny = ((y1 - y0) / cell).floor() as usize + 1;
    // Counting sort of truth indices by cell (CSR layout).
    let cell_of = |x: f64, y: f64| -> usize {
        let cx = (((x - x0) / cell).floor() as usize).min(nx - 1);
        let cy = (((y - y0) / cell).floor() as usize).min(ny - 1);
        cy * nx + cx
    };
    let mut start = vec![0usize; nx * ny + 1];
    for &(x, y) in truth {
        start[cell_of(x, y) + 1] += 1;
    }
    for c in 0..nx * ny {
        start[c + 1] += start[c];
    }
    let mut fill = start.clone();
    let mut order = vec![0usize; truth.len()];
    for (j, &(x, y)) in truth.iter().enumerate() {
        let c = cell_of(x, y);
        order[fill[c]] = j;
        fill[c] += 1;
    }
    queries
        .iter()
        .map(|&(qx, qy)| {
            // Cells that can hold a point within `radius` of the query.
            let fx = ((qx - x0) / cell).floor();
            let fy = ((qy - y0) / cell).floor();
            if fx < -1.0 || fy < -1.0 || fx > nx as f64 || fy > ny as f64 {
                return None;
            }
            let (fx, fy) = (fx as i64, fy as i64);
            let mut best = None;
            for cy in (fy - 1).max(0)..=(fy + 1).min(ny as i64 - 1) {
                for cx in (fx - 1).max(0)..=(fx + 1).min(nx as i64 - 1) {
                    let c = cy as usize * nx + cx as usize;
                    for &j in &order[start[c]..start[c + 1]] {
                        let (tx, ty) = truth[j];
                        let d2 = (tx - qx).powi(2) + (ty - qy).powi(2);
                        if d2 <= r2 && better(d2, j, best) {
                            best = Some((d2, j));
                        }
                    }
                }
            }
            best.map(|b| b.1)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use stepsim_contract::seed::SimRng;

    #[test]
    fn grid_matcher_equals_brute_force_on_random_fields() {
        let mut rng = SimRng::seed_from_u64(7);
        for case in 0..60 {
            let n = rng.random_range(0..400usize);
            let m = rng.random_range(0..300usize);
            let size = rng.random_range(10.0..500.0);
            let radius = rng.random_range(0.2..20.0);
            let pt =
                |rng: &mut SimRng| (rng.random_range(-5.0..size), rng.random_range(-5.0..size));
            let mut truth: Vec<(f64, f64)> = (0..n).map(|_| pt(&mut rng)).collect();
            // Some exact ties and duplicates.
            if n > 3 {
                truth[1] = truth[0];
                truth[2] = (truth[0].0 + 1.0, truth[0].1);
            }
            let mut queries: Vec<(f64, f64)> = (0..m).map(|_| pt(&mut rng)).collect();
            if n > 3 {
                queries.push((truth[0].0 + 0.5, truth[0].1)); // equidistant from 0/1 and 2
                queries.push(truth[2]);
            }
            let fast = match_nearest(&truth, &queries, radius);
            let slow = match_nearest_slow(&truth, &queries, radius);
            assert_eq!(fast, slow, "case {case}");
            if n > 3 {
                assert_eq!(fast[m], Some(0), "tie goes to the lower index");
                assert_eq!(fast[m + 1], Some(2));
            }
        }
    }

    #[test]
    fn radius_is_inclusive_and_far_queries_do_not_match() {
        let truth = [(10.0, 10.0), (20.0, 10.0)];
        let q = [(13.0, 14.0), (13.0, 14.1), (1e6, -1e6), (16.0, 10.0)];
        assert_eq!(
            match_nearest(&truth, &q, 5.0),
            vec![Some(0), None, None, Some(1)]
        );
    }
}
