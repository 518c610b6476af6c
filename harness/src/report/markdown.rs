//! `report.md`: the paper's Table 4 (per dataset) and Table 5 (summary) for
//! one submission, plus the per-PSF fits and the binned residuals.

use crate::error::show_number;
use crate::score::report::{Binned, Report};
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

/// Appends a Markdown table to `out`: the header row, the alignment row
/// (one letter per column: `l` left, `r` right, `c` centred) and one line per
/// row. Cells are written as given: escape participant text first
/// ([`escape`]). Every table of the report and the leaderboard is written by
/// this one function.
pub fn table<R: AsRef<[String]>>(
    out: &mut String,
    header: &[&str],
    align: &str,
    rows: impl IntoIterator<Item = R>,
) {
    debug_assert_eq!(
        header.len(),
        align.chars().count(),
        "one alignment per column"
    );
    let line = |out: &mut String, cells: &mut dyn Iterator<Item = &str>| {
        out.push('|');
        for c in cells {
            out.push(' ');
            out.push_str(c);
            out.push_str(" |");
        }
        out.push('\n');
    };
    line(out, &mut header.iter().copied());
    out.push('|');
    for a in align.chars() {
        out.push_str(match a {
            'r' => "---:|",
            'c' => ":-:|",
            _ => "---|",
        });
    }
    out.push('\n');
    for r in rows {
        line(out, &mut r.as_ref().iter().map(String::as_str));
    }
}

/// The Table 5 columns (leaderboard and report share them).
pub const TABLE5_COLUMNS: [&str; 8] = [
    "⟨m⟩",
    "σ_c",
    "⟨q⟩",
    "⟨m_uncontaminated⟩",
    "⟨m_selc⟩",
    "σ_c selc",
    "⟨m_weight⟩",
    "Q_c",
];

/// The Table 5 cells of one report (without the leading name cell).
pub fn table5_cells(r: &Report) -> Vec<String> {
    let s = &r.summary;
    vec![
        num(s.m_mean, 4),
        num(s.sigma_c, 5),
        num(s.q_mean, 3),
        num(s.m_uncontaminated_mean, 4),
        num(s.m_selc_mean, 4),
        num(s.sigma_c_selc, 5),
        num(s.m_weight_mean, 4),
        num(s.q_c, 1),
    ]
}

fn binned(out: &mut String, title: &str, unit: &str, b: &Binned) {
    let _ = writeln!(out, "\n## {title}\n");
    let unit = format!("bin ({unit})");
    let rows = b.bins.iter().chain(std::iter::once(&b.all)).map(|bin| {
        let label = match (bin.lo, bin.hi) {
            (None, None) => "all".to_owned(),
            (None, Some(h)) => format!("< {}", show_number(h)),
            (Some(l), None) => format!("≥ {}", show_number(l)),
            (Some(l), Some(h)) => format!("{} – {}", show_number(l), show_number(h)),
        };
        vec![
            label,
            bin.n_objects.to_string(),
            pm(bin.g1_residual, bin.g1_residual_err, 5),
            pm(bin.g2_residual, bin.g2_residual_err, 5),
        ]
    });
    table(
        out,
        &[&unit, "galaxies", "γ1 − γ1_true", "γ2 − γ2_true"],
        "lrrr",
        rows,
    );
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

/// The model of every fitted family of every PSF, its q and why (one row
/// each; families without a recorded model, as in reports written before
/// it was, are left out).
fn fit_models(o: &mut String, r: &Report) {
    use crate::score::report::FitKind;
    let mut rows = Vec::new();
    for p in &r.psfs {
        let families = [
            ("γ1 (m, c1)", &p.fit, p.q, p.q_err),
            ("γ2 (m2, c2)", &p.fit2, p.q2, p.q2_err),
            (
                "uncontaminated",
                &p.fit_uncontaminated,
                p.q_uncontaminated,
                p.q_uncontaminated_err,
            ),
            ("isolated", &p.fit_isolated, p.q_isolated, p.q_isolated_err),
            ("selection (selc)", &p.fit_selc, p.q_selc, p.q_selc_err),
            ("weight", &p.fit_weight, p.q_weight, p.q_weight_err),
        ];
        for (family, choice, q, qe) in families {
            if let Some(c) = choice {
                rows.push(vec![
                    escape(&p.psf),
                    family.to_owned(),
                    match c.model {
                        FitKind::Linear => "linear".to_owned(),
                        FitKind::Quadratic => "quadratic".to_owned(),
                    },
                    pm(q, qe, 3),
                    escape(&c.reason),
                ]);
            }
        }
    }
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(
        o,
        "\n## Fit model of every family\n\nOne rule for all: the quadratic q γ_true² + m γ_true + c is fitted only with at least 4 distinct shears (so that the data can test it) and kept when |q| ≥ 2σ_q; otherwise the fit is linear and q = 0.\n"
    );
    table(o, &["PSF", "fit", "model", "q", "why"], "lllrl", rows);
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
    let mut rows = vec![
        std::iter::once(escape(&r.submission))
            .chain(table5_cells(r))
            .collect::<Vec<_>>(),
    ];
    if let Some(b) = &r.summary.bootstrap {
        let ci = |v: Option<[f64; 2]>, d: usize| match v {
            Some([a, b]) => format!("[{}, {}]", fixed(a, d), fixed(b, d)),
            None => "—".into(),
        };
        let widened = match (b.base_fields, b.widening) {
            (Some(f), Some(k)) => format!(
                " of {f} base field{}, widened ×{} for Student's t with {} degree{} of freedom",
                if f == 1 { "" } else { "s" },
                fixed(k, 3),
                f - 1,
                if f == 2 { "" } else { "s" }
            ),
            _ => " of base fields".to_owned(),
        };
        rows.push(vec![
            format!(
                "{:.0} % interval ({} resamples{widened})",
                100.0 * b.confidence,
                b.n_resamples
            ),
            ci(b.m_mean, 4),
            ci(b.sigma_c, 5),
            ci(b.q_mean, 3),
            ci(b.m_uncontaminated_mean, 4),
            ci(b.m_selc_mean, 4),
            ci(b.sigma_c_selc, 5),
            ci(b.m_weight_mean, 4),
            ci(b.q_c, 1),
        ]);
    }
    let header: Vec<&str> = std::iter::once("submission")
        .chain(TABLE5_COLUMNS)
        .collect();
    table(&mut o, &header, "lrrrrrrrr", &rows);
    if let Some(b) = &r.summary.bootstrap {
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
    table(
        &mut o,
        &[
            "PSF",
            "m",
            "q",
            "c1",
            "c2",
            "linear",
            "m_uncontaminated",
            "m_selc",
            "c1_selc",
            "c2_selc",
            "m_weight",
            "c1_weight",
        ],
        "lrrrrcrrrrrr",
        r.psfs.iter().map(|p| {
            vec![
                escape(&p.psf),
                pm(p.m, p.m_err, 4),
                pm(p.q, p.q_err, 3),
                pm(p.c1, p.c1_err, 5),
                pm(p.c2, p.c2_err, 5),
                (if p.linear { "yes" } else { "no" }).into(),
                pm(p.m_uncontaminated, p.m_uncontaminated_err, 4),
                pm(p.m_selc, p.m_selc_err, 4),
                pm(p.c1_selc, p.c1_selc_err, 5),
                pm(p.c2_selc, p.c2_selc_err, 5),
                pm(p.m_weight, p.m_weight_err, 4),
                pm(p.c1_weight, p.c1_weight_err, 5),
            ]
        }),
    );
    fit_models(&mut o, r);
    let _ = writeln!(
        o,
        "\n## Isolated galaxies (no neighbour above 10 % of the flux within 3″)\n"
    );
    if r.isolation_plane == crate::score::isolation::IsolationPlane::Source {
        let _ = writeln!(
            o,
            "The run lensed its galaxies' positions: two galaxies' separation is taken in the \
             source plane (each dataset's shear undone), so the class holds the same galaxies in \
             every dataset; a galaxy's distance from a star is the image's.\n"
        );
    }
    table(
        &mut o,
        &["PSF", "m_isolated", "c1_isolated", "c2_isolated"],
        "lrrr",
        r.psfs.iter().map(|p| {
            vec![
                escape(&p.psf),
                pm(p.m_isolated, p.m_isolated_err, 4),
                pm(p.c1_isolated, p.c1_isolated_err, 5),
                pm(p.c2_isolated, p.c2_isolated_err, 5),
            ]
        }),
    );
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
    table(
        &mut o,
        &[
            "dataset",
            "PSF",
            "γ1_true",
            "γ2_true",
            "images",
            "objects",
            "Ngals /arcmin²",
            "% stars",
            "% false",
            "% chance",
            "% stars′",
            "% false′",
            "γ1",
            "γ2",
            "SNR",
            "S/N_s",
            "S/N_s′",
        ],
        "llrrrrrrrrrrrrrrr",
        r.datasets.iter().map(|d| {
            vec![
                escape(&d.dataset),
                escape(&d.psf),
                show_number(d.g1_true),
                show_number(d.g2_true),
                d.n_images.to_string(),
                d.n_objects.to_string(),
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
                num(d.sn_shot_weighted, 1),
            ]
        }),
    );
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
    use crate::score::isolation::IsolationPlane;

    #[test]
    fn a_table_has_a_header_an_alignment_row_and_one_line_per_row() {
        let mut o = String::new();
        table(
            &mut o,
            &["name", "value", "ok"],
            "lrc",
            [
                vec!["a".to_owned(), "1".into(), "yes".into()],
                vec![escape("b|c"), "2".into(), "no".into()],
            ],
        );
        assert_eq!(
            o,
            "| name | value | ok |\n|---|---:|:-:|\n| a | 1 | yes |\n| b\\|c | 2 | no |\n"
        );
    }

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
            serde_json::from_str(include_str!("../../tests/data/report_minimal.json")).unwrap();
        r.summary.bootstrap = Some(crate::score::report::BootstrapCi {
            n_resamples: 200,
            seed: 1,
            confidence: 0.95,
            base_fields: None,
            widening: None,
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
    fn every_family_says_its_fit_model_and_why() {
        use crate::score::report::{FitChoice, FitKind};
        let mut r: Report =
            serde_json::from_str(include_str!("../../tests/data/report_minimal.json")).unwrap();
        // A report written before the models were recorded: no table.
        assert!(!report_markdown(&r).contains("Fit model of every family"));
        let p = &mut r.psfs[0];
        p.fit = Some(FitChoice {
            model: FitKind::Linear,
            reason: "linear: 3 distinct shears, …".into(),
        });
        p.fit_isolated = Some(FitChoice {
            model: FitKind::Quadratic,
            reason: "quadratic: |q| = 2.6 σ_q ≥ 2 σ_q".into(),
        });
        (p.q_isolated, p.q_isolated_err) = (Some(-1.25), Some(0.48));
        let psf = escape(&p.psf);
        let md = report_markdown(&r);
        assert!(md.contains("## Fit model of every family"), "{md}");
        assert!(
            md.contains(&format!(
                "| {psf} | γ1 (m, c1) | linear | 0.000 | linear: 3 distinct shears, … |"
            )),
            "{md}"
        );
        assert!(
            md.contains(&format!(
                "| {psf} | isolated | quadratic | -1.250 ± 0.480 | quadratic: \\|q\\| = 2.6 σ\\_q ≥ 2 σ\\_q |"
            )),
            "{md}"
        );
        // Families without a model recorded are left out.
        assert!(!md.contains("| weight |"), "{md}");
    }

    #[test]
    fn isolated_galaxy_figures_carry_their_bootstrap_intervals() {
        let mut r: Report =
            serde_json::from_str(include_str!("../../tests/data/report_minimal.json")).unwrap();
        r.summary.m_isolated_mean = Some(-0.0123);
        r.summary.sigma_c_isolated = Some(0.00234);
        let without = report_markdown(&r);
        assert!(
            without.contains("⟨m_isolated⟩ = -0.0123; σ_c of the isolated galaxies = 0.00234."),
            "{without}"
        );
        // A report written before `isolation_plane` reads as the image's,
        // and says nothing of planes; a lensed run's says where it classed.
        assert_eq!(r.isolation_plane, IsolationPlane::Image);
        assert!(!without.contains("source plane"), "{without}");
        let mut lensed = r.clone();
        lensed.isolation_plane = IsolationPlane::Source;
        assert!(
            report_markdown(&lensed).contains("separation is taken in the source plane"),
            "{}",
            report_markdown(&lensed)
        );
        r.summary.bootstrap = Some(crate::score::report::BootstrapCi {
            n_resamples: 200,
            seed: 1,
            confidence: 0.95,
            base_fields: None,
            widening: None,
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
            serde_json::from_str(include_str!("../../tests/data/report_minimal.json")).unwrap();
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
