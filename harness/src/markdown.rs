//! `report.md`: the paper's Table 4 (per dataset) and Table 5 (summary) for
//! one submission, plus the per-PSF fits and the binned residuals.

use crate::report::{Binned, Report};
use std::fmt::Write as _;

/// Formats a number with `d` decimals when it is of a sane size
/// (|x| < 10⁶), in scientific notation (`d` significant decimals) otherwise,
/// so that no value, however absurd, prints as hundreds of digits; `—` when
/// not finite.
pub fn fixed(x: f64, d: usize) -> String {
    if !x.is_finite() {
        "—".into()
    } else if x.abs() < 1e6 {
        format!("{x:.d$}")
    } else {
        format!("{x:.d$e}")
    }
}

/// Formats an optional number with `d` decimals ([`fixed`]); `—` when
/// missing.
pub fn num(v: Option<f64>, d: usize) -> String {
    v.map_or_else(|| "—".into(), |x| fixed(x, d))
}

/// Formats a number shortly, as Rust does (`0.25`, `1e308`, `-3`) but in
/// scientific notation outside 10⁻⁴ ≤ |x| < 10¹⁵; `inf`, `-inf`, `NaN`
/// as such.
pub fn show_number(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// Escapes text for a Markdown table cell or heading: `|`, backslash, backticks,
/// `*`, `_`, `[`, `]`, `<`, `>` and `&` cannot change the layout or inject
/// HTML, and line breaks and other control characters become spaces.
pub fn escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '&' => o.push_str("&amp;"),
            '|' | '\\' | '`' | '*' | '_' | '[' | ']' | '#' => {
                o.push('\\');
                o.push(c);
            }
            c if c.is_control() => o.push(' '),
            c => o.push(c),
        }
    }
    o
}

/// Formats `value ± error`.
pub fn pm(v: Option<f64>, e: Option<f64>, d: usize) -> String {
    match e {
        Some(_) => format!("{} ± {}", num(v, d), num(e, d)),
        None => num(v, d),
    }
}

/// The Table 5 header (leaderboard and report share it).
pub const TABLE5_HEADER: &str =
    "| ⟨m⟩ | σ_c | ⟨q⟩ | ⟨m_uncontaminated⟩ | ⟨m_selc⟩ | σ_c selc | ⟨m_weight⟩ | Q_c |";

/// The Table 5 cells of one report (without the leading name cell).
pub fn table5_cells(r: &Report) -> String {
    let s = &r.summary;
    format!(
        "| {} | {} | {} | {} | {} | {} | {} | {} |",
        num(s.m_mean, 4),
        num(s.sigma_c, 5),
        num(s.q_mean, 3),
        num(s.m_uncontaminated_mean, 4),
        num(s.m_selc_mean, 4),
        num(s.sigma_c_selc, 5),
        num(s.m_weight_mean, 4),
        num(s.q_c, 1)
    )
}

fn binned(out: &mut String, title: &str, unit: &str, b: &Binned) {
    let _ = writeln!(out, "\n## {title}\n");
    let _ = writeln!(
        out,
        "| bin ({unit}) | galaxies | γ1 − γ1_true | γ2 − γ2_true |"
    );
    let _ = writeln!(out, "|---|---:|---:|---:|");
    for bin in b.bins.iter().chain(std::iter::once(&b.all)) {
        let label = match (bin.lo, bin.hi) {
            (None, None) => "all".to_owned(),
            (None, Some(h)) => format!("< {}", show_number(h)),
            (Some(l), None) => format!("≥ {}", show_number(l)),
            (Some(l), Some(h)) => format!("{} – {}", show_number(l), show_number(h)),
        };
        let _ = writeln!(
            out,
            "| {label} | {} | {} | {} |",
            bin.n_objects,
            pm(bin.g1_residual, bin.g1_residual_err, 5),
            pm(bin.g2_residual, bin.g2_residual_err, 5)
        );
    }
}

/// Below this many base fields the report warns that its bootstrap interval
/// is not to be trusted.
pub const FEW_BASE_FIELDS: usize = 10;

/// Distinct bootstrap resamples of `n` items (multisets of size `n`:
/// C(2n − 1, n)), saturating.
pub fn distinct_resamples(n: usize) -> u64 {
    let mut c: u64 = 1;
    for i in 1..=n as u64 {
        // C(n − 1 + i, i) = C(n − 1 + i − 1, i − 1) · (n − 1 + i) / i
        c = match c.checked_mul(n as u64 - 1 + i) {
            Some(v) => v / i,
            None => return u64::MAX,
        };
    }
    c
}

/// The Markdown report.
pub fn report_markdown(r: &Report) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "# Score of {}\n", escape(&r.submission));
    let _ = writeln!(
        o,
        "Matched within {} arcsec. Definitions: `docs/scoring.md` (paper section 4).\n",
        show_number(r.match_radius_arcsec)
    );
    for w in &r.warnings {
        let _ = writeln!(o, "- **warning:** {}", escape(w));
    }
    let _ = writeln!(
        o,
        "\n## Table 5: calibration, PSF residuals, non-linearity\n"
    );
    let _ = writeln!(o, "| submission {TABLE5_HEADER}");
    let _ = writeln!(o, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    let _ = writeln!(o, "| {} {}", escape(&r.submission), table5_cells(r));
    if let Some(b) = &r.summary.bootstrap {
        let ci = |v: Option<[f64; 2]>, d: usize| match v {
            Some([a, b]) => format!("[{}, {}]", fixed(a, d), fixed(b, d)),
            None => "—".into(),
        };
        let _ = writeln!(
            o,
            "| {:.0} % interval ({} resamples of base fields) | {} | {} | {} | {} | {} | {} | {} | {} |",
            100.0 * b.confidence,
            b.n_resamples,
            ci(b.m_mean, 4),
            ci(b.sigma_c, 5),
            ci(b.q_mean, 3),
            ci(b.m_uncontaminated_mean, 4),
            ci(b.m_selc_mean, 4),
            ci(b.sigma_c_selc, 5),
            ci(b.m_weight_mean, 4),
            ci(b.q_c, 1)
        );
        let fields = r.datasets.iter().map(|d| d.n_images).max().unwrap_or(0);
        if fields < FEW_BASE_FIELDS {
            let _ = writeln!(
                o,
                "\n**Caveat:** the interval resamples only {fields} base field{} (images per dataset), so it can take at most {} distinct values and is no reliable {:.0} % interval; trust it from about {FEW_BASE_FIELDS} base fields on.",
                if fields == 1 { "" } else { "s" },
                distinct_resamples(fields),
                100.0 * b.confidence
            );
        }
    }
    let _ = writeln!(o, "\n## Fits per PSF\n");
    let _ = writeln!(
        o,
        "| PSF | m | q | c1 | c2 | linear | m_uncontaminated | m_selc | c1_selc | c2_selc | m_weight | c1_weight |"
    );
    let _ = writeln!(
        o,
        "|---|---:|---:|---:|---:|:-:|---:|---:|---:|---:|---:|---:|"
    );
    for p in &r.psfs {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            escape(&p.psf),
            pm(p.m, p.m_err, 4),
            pm(p.q, p.q_err, 3),
            pm(p.c1, p.c1_err, 5),
            pm(p.c2, p.c2_err, 5),
            if p.linear { "yes" } else { "no" },
            pm(p.m_uncontaminated, p.m_uncontaminated_err, 4),
            pm(p.m_selc, p.m_selc_err, 4),
            pm(p.c1_selc, p.c1_selc_err, 5),
            pm(p.c2_selc, p.c2_selc_err, 5),
            pm(p.m_weight, p.m_weight_err, 4),
            pm(p.c1_weight, p.c1_weight_err, 5)
        );
    }
    let _ = writeln!(
        o,
        "\n## Isolated galaxies (no neighbour above 10 % of the flux within 3″)\n"
    );
    let _ = writeln!(o, "| PSF | m_isolated | c1_isolated | c2_isolated |");
    let _ = writeln!(o, "|---|---:|---:|---:|");
    for p in &r.psfs {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} |",
            escape(&p.psf),
            pm(p.m_isolated, p.m_isolated_err, 4),
            pm(p.c1_isolated, p.c1_isolated_err, 5),
            pm(p.c2_isolated, p.c2_isolated_err, 5)
        );
    }
    let iso_ci = |v: Option<[f64; 2]>, d: usize| match (&r.summary.bootstrap, v) {
        (Some(b), Some([lo, hi])) => format!(
            " ({:.0} % interval [{}, {}])",
            100.0 * b.confidence,
            fixed(lo, d),
            fixed(hi, d)
        ),
        _ => String::new(),
    };
    let b = r.summary.bootstrap.as_ref();
    let _ = writeln!(
        o,
        "\n⟨m_isolated⟩ = {}{}; σ_c of the isolated galaxies = {}{}.",
        num(r.summary.m_isolated_mean, 4),
        iso_ci(b.and_then(|b| b.m_isolated_mean), 4),
        num(r.summary.sigma_c_isolated, 5),
        iso_ci(b.and_then(|b| b.sigma_c_isolated), 5)
    );
    let _ = writeln!(
        o,
        "\n## Table 4: number density, contamination, signal-to-noise\n"
    );
    let _ = writeln!(
        o,
        "| dataset | PSF | γ1_true | γ2_true | images | objects | Ngals /arcmin² | % stars | % false | % chance | % stars′ | % false′ | γ1 | γ2 | SNR | S/N_s | S/N_s′ |"
    );
    let _ = writeln!(
        o,
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for d in &r.datasets {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            escape(&d.dataset),
            escape(&d.psf),
            show_number(d.g1_true),
            show_number(d.g2_true),
            d.n_images,
            d.n_objects,
            fixed(d.ngal_per_arcmin2, 1),
            fixed(d.pct_stars, 2),
            fixed(d.pct_false, 2),
            num(d.pct_chance_match, 2),
            num(d.pct_stars_weighted, 2),
            num(d.pct_false_weighted, 2),
            pm(d.g1, d.g1_err, 5),
            pm(d.g2, d.g2_err, 5),
            num(d.snr, 1),
            num(d.sn_shot, 1),
            num(d.sn_shot_weighted, 1)
        );
    }
    binned(
        &mut o,
        "Residual by true magnitude",
        "I mag",
        &r.by_magnitude,
    );
    binned(
        &mut o,
        "Residual by true disk scale length",
        "arcsec",
        &r.by_disk_size,
    );
    let _ = writeln!(
        o,
        "\nA bin's error (±) is the scatter over a dataset's images of their mean residual, divided by √N and combined over datasets; it is left out when, in some dataset, fewer than two images have weighted galaxies in the bin (no scatter to measure)."
    );
    let _ = writeln!(
        o,
        "\nPlots: `fig2_shear_response`, `fig3_m_sigma_c`, `fig4_mselc_muncontaminated`, \
         `fig5_residual_magnitude` (each as `.svg` and `.png`)."
    );
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distinct_resamples_are_multisets() {
        // 1 field: {a}; 2: {aa, ab, bb}; 3: C(5, 3) = 10; 10: C(19, 10).
        assert_eq!(distinct_resamples(1), 1);
        assert_eq!(distinct_resamples(2), 3);
        assert_eq!(distinct_resamples(3), 10);
        assert_eq!(distinct_resamples(10), 92378);
        assert_eq!(distinct_resamples(0), 1);
    }

    #[test]
    fn numbers_print_short_whatever_their_size() {
        assert_eq!(fixed(0.012345, 4), "0.0123");
        assert_eq!(fixed(-999_999.0, 1), "-999999.0");
        assert_eq!(fixed(1e308, 4), "1.0000e308");
        assert_eq!(fixed(-2.5e7, 1), "-2.5e7");
        assert_eq!(fixed(f64::INFINITY, 2), "—");
        assert_eq!(num(None, 2), "—");
        assert_eq!(show_number(1e308), "1e308");
        assert_eq!(show_number(0.25), "0.25");
        assert_eq!(show_number(-3.0), "-3");
        assert_eq!(show_number(1e-300), "1e-300");
        assert_eq!(show_number(f64::NAN), "NaN");
    }

    #[test]
    fn escaped_text_cannot_break_a_table_or_inject_html() {
        assert_eq!(
            escape("a|b`c`<script>&\n*_[x]#\\"),
            "a\\|b\\`c\\`&lt;script&gt;&amp; \\*\\_\\[x\\]\\#\\\\"
        );
    }

    #[test]
    fn an_interval_from_few_base_fields_carries_a_caveat_and_bins_say_why_no_errors() {
        let mut r: Report =
            serde_json::from_str(include_str!("../tests/data/report_minimal.json")).unwrap();
        r.summary.bootstrap = Some(crate::report::BootstrapCi {
            n_resamples: 200,
            seed: 1,
            confidence: 0.95,
            m_mean: Some([-0.1, 0.1]),
            q_mean: None,
            sigma_c: None,
            m_uncontaminated_mean: None,
            m_selc_mean: None,
            sigma_c_selc: None,
            m_weight_mean: None,
            q_c: None,
            m_isolated_mean: None,
            sigma_c_isolated: None,
        });
        for d in &mut r.datasets {
            d.n_images = 2;
        }
        let md = report_markdown(&r);
        assert!(
            md.contains("**Caveat:** the interval resamples only 2 base fields (images per dataset), so it can take at most 3 distinct values and is no reliable 95 % interval"),
            "{md}"
        );
        assert!(
            md.contains("it is left out when, in some dataset, fewer than two images"),
            "{md}"
        );
        for d in &mut r.datasets {
            d.n_images = FEW_BASE_FIELDS;
        }
        assert!(!report_markdown(&r).contains("Caveat"));
    }

    #[test]
    fn isolated_galaxy_figures_carry_their_bootstrap_intervals() {
        let mut r: Report =
            serde_json::from_str(include_str!("../tests/data/report_minimal.json")).unwrap();
        r.summary.m_isolated_mean = Some(-0.0123);
        r.summary.sigma_c_isolated = Some(0.00234);
        let without = report_markdown(&r);
        assert!(
            without.contains("⟨m_isolated⟩ = -0.0123; σ_c of the isolated galaxies = 0.00234."),
            "{without}"
        );
        r.summary.bootstrap = Some(crate::report::BootstrapCi {
            n_resamples: 200,
            seed: 1,
            confidence: 0.95,
            m_mean: None,
            q_mean: None,
            sigma_c: None,
            m_uncontaminated_mean: None,
            m_selc_mean: None,
            sigma_c_selc: None,
            m_weight_mean: None,
            q_c: None,
            m_isolated_mean: Some([-0.05, 0.02]),
            sigma_c_isolated: Some([0.001, 0.004]),
        });
        let md = report_markdown(&r);
        assert!(
            md.contains(
                "⟨m_isolated⟩ = -0.0123 (95 % interval [-0.0500, 0.0200]); \
                 σ_c of the isolated galaxies = 0.00234 (95 % interval [0.00100, 0.00400])."
            ),
            "{md}"
        );
    }

    #[test]
    fn report_md_of_absurd_values_stays_readable() {
        let mut r: Report =
            serde_json::from_str(include_str!("../tests/data/report_minimal.json")).unwrap();
        r.submission = "evil|name\n# heading".into();
        r.match_radius_arcsec = 1e300;
        r.datasets[0].g1 = Some(1e308);
        r.datasets[0].g1_true = -1e300;
        r.datasets[0].ngal_per_arcmin2 = 1e300;
        r.psfs[0].m = Some(-1e308);
        r.summary.m_mean = Some(1e308);
        r.warnings.push("columns ignored: <b>|</b>".into());
        let md = report_markdown(&r);
        let longest = md.lines().map(|l| l.chars().count()).max().unwrap();
        assert!(longest < 400, "a line of {longest} characters");
        assert!(
            md.starts_with("# Score of evil\\|name \\# heading\n"),
            "{md}"
        );
        assert!(md.contains("Matched within 1e300 arcsec"));
        assert!(md.contains("| 1.00000e308 ± 0.00100 |"), "{md}");
        assert!(md.contains("columns ignored: &lt;b&gt;\\|&lt;/b&gt;"));
        assert!(!md.contains("<b>"));
    }
}
