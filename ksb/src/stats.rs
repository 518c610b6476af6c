//! The median, until the workspace's numerics crate (`stepsim-numerics`,
//! made from `stepsim_sim::stats` in parallel) is merged: ksb then takes it
//! from there and this file goes. It is `crate::stats::median`
//! verbatim, so that ksb does not link the simulator for one function.

/// Median of a sample, reordering it (sorted); the mean of the two middle
/// values for an even count; `None` when empty. NaNs sort after +∞
/// ([`f64::total_cmp`]).
pub(crate) fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}
