//! Numbers, times and sizes as the pages write them.

/// `v` with `dp` decimals, a true minus sign, `—` when missing.
pub(crate) fn fixed(v: Option<f64>, dp: usize) -> String {
    match v.filter(|v| v.is_finite()) {
        Some(v) => {
            let s = format!("{v:.dp$}");
            match s.strip_prefix('-') {
                // -0.000 reads as 0.000.
                Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
                Some(rest) => format!("−{rest}"),
                None => s,
            }
        }
        None => "—".into(),
    }
}

/// As [`fixed`], with a `+` on positive values (columns of signed numbers).
pub(crate) fn signed(v: Option<f64>, dp: usize) -> String {
    let s = fixed(v, dp);
    match v {
        Some(x) if x > 0.0 && !s.chars().all(|c| c == '0' || c == '.') => format!("+{s}"),
        _ => s,
    }
}

/// The ends of a 95 % interval as shown with `dp` decimals by `show`
/// ([`fixed`] or [`signed`]); `None` when they read the same: an interval
/// of no width at the precision shown (the bootstrap found no spread: one
/// base field, or resamples that all agree) says nothing of the
/// uncertainty, and is shown as "—" (the leaderboard and the report page).
pub(crate) fn interval_ends(
    ci: [f64; 2],
    dp: usize,
    show: fn(Option<f64>, usize) -> String,
) -> Option<(String, String)> {
    let (lo, hi) = (show(Some(ci[0]), dp), show(Some(ci[1]), dp));
    (lo != hi).then_some((lo, hi))
}

/// A time as `YYYY-MM-DD HH:MM UTC`.
pub(super) fn when(t_s: i64) -> String {
    let t = crate::utc_text(t_s);
    format!("{} {} UTC", &t[..10], &t[11..16])
}

/// A byte count for people (`12.3 kB`).
pub(super) fn size_text(bytes: i64) -> String {
    let b = bytes as f64;
    if b < 1e3 {
        format!("{bytes} B")
    } else if b < 1e6 {
        format!("{:.1} kB", b / 1e3)
    } else if b < 1e9 {
        format!("{:.1} MB", b / 1e6)
    } else {
        format!("{:.2} GB", b / 1e9)
    }
}

/// A size cap for people: whole MiB or KiB when it is one (`256 MiB`).
pub(super) fn cap_text(bytes: u64) -> String {
    if bytes >= 1 << 20 && bytes % (1 << 20) == 0 {
        format!("{} MiB", bytes >> 20)
    } else if bytes >= 1 << 10 && bytes % (1 << 10) == 0 {
        format!("{} KiB", bytes >> 10)
    } else {
        format!("{bytes} bytes")
    }
}
