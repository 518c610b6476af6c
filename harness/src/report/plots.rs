//! Plots like the paper's Figures 2–5, drawn by the workspace's one plotter
//! ([`stepsim_figure::chart`]) as SVG with titles, axis labels and tick
//! values; the PNG is that same SVG rasterised with its text (resvg and a
//! bundled font: no system font is needed, CI installs nothing).

use crate::score::report::Report;
use stepsim_figure::chart::{BLUE, Chart, Figure, GREY, Item, LIGHT, RED};

/// The report's figures, by file stem: Fig. 2 (shear response per PSF),
/// Fig. 3 (⟨m⟩ against σ_c), Fig. 4 (m_selc against m_uncontaminated),
/// Fig. 5 (residual against magnitude).
pub fn report_figures(r: &Report) -> Vec<(&'static str, Figure)> {
    vec![
        ("fig2_shear_response", fig2(r)),
        ("fig3_m_sigma_c", fig3(&[r])),
        ("fig4_mselc_muncontaminated", fig4(r)),
        ("fig5_residual_magnitude", fig5(r)),
    ]
}

/// Fig. 2: γ1 − γ1_true against γ1_true per PSF, with the fit (dashed) and
/// the ideal zero line (grey).
pub fn fig2(r: &Report) -> Figure {
    let charts = r
        .psfs
        .iter()
        .map(|p| {
            let pts: Vec<(f64, f64, Option<f64>)> = r
                .datasets
                .iter()
                .filter(|d| d.psf == p.psf)
                .filter_map(|d| Some((d.g1_true, d.g1? - d.g1_true, d.g1_err)))
                .collect();
            let xmax = pts.iter().map(|p| p.0).fold(0.0, f64::max);
            let xmin = pts.iter().map(|p| p.0).fold(0.0, f64::min);
            let mut items = vec![Item::Line {
                pts: vec![(xmin, 0.0), (xmax, 0.0)],
                colour: GREY,
                dashed: false,
            }];
            if let (Some(m), Some(c)) = (p.m, p.c1) {
                let q = p.q.unwrap_or(0.0);
                let line = (0..=40)
                    .map(|k| {
                        let x = xmin + (xmax - xmin) * k as f64 / 40.0;
                        (x, q * x * x + m * x + c)
                    })
                    .collect();
                items.push(Item::Line {
                    pts: line,
                    colour: RED,
                    dashed: true,
                });
            }
            let measured = measured_label(&pts, "measured");
            items.push(Item::Points { pts, colour: BLUE });
            let fit = if p.linear || p.q.unwrap_or(0.0) == 0.0 {
                "fit m γ + c"
            } else {
                "fit q γ² + m γ + c"
            };
            Chart {
                title: format!("{}: {} (PSF {})", r.submission, "γ1 − γ1 true", p.psf),
                x_label: "γ1 true".into(),
                y_label: "γ1 − γ1 true".into(),
                items,
                legend: vec![(measured, BLUE), (fit.into(), RED)],
            }
        })
        .collect();
    Figure {
        cols: 3,
        panel_px: (420, 320),
        charts,
    }
}

/// The legend of measured points: "± 1σ" only when some point has an
/// error bar (a run of one base field has none).
fn measured_label(pts: &[(f64, f64, Option<f64>)], what: &str) -> String {
    if pts.iter().any(|p| p.2.is_some_and(f64::is_finite)) {
        format!("{what} ± 1σ")
    } else {
        format!("{what} (no error: one base field)")
    }
}

/// Fig. 3: ⟨m⟩ against σ_c for one or more reports, one point each (the
/// paper's Fig. 3: one point a method); the shaded band is |⟨m⟩| < 7 %
/// (the paper's "less than 7 % calibration bias"), shown whole.
pub fn fig3(reports: &[&Report]) -> Figure {
    let pts: Vec<(f64, f64, Option<f64>)> = reports
        .iter()
        .filter_map(|r| Some((r.summary.sigma_c?, r.summary.m_mean?, None)))
        .collect();
    let names: Vec<&str> = reports.iter().map(|r| r.submission.as_str()).collect();
    let title = match names[..] {
        [one] => format!("{one}: ⟨m⟩ against σc (shaded: |⟨m⟩| < 7 %)"),
        _ => "⟨m⟩ against σc, one point a submission (shaded: |⟨m⟩| < 7 %)".to_string(),
    };
    let xmax = pts.iter().map(|p| p.0).fold(1e-4, f64::max);
    let items = vec![
        Item::Band {
            rect: [0.0, f64::MAX, -0.07, 0.07],
            colour: LIGHT,
        },
        Item::Line {
            pts: vec![(0.0, 0.0), (xmax, 0.0)],
            colour: GREY,
            dashed: false,
        },
        Item::Points { pts, colour: BLUE },
    ];
    Figure {
        cols: 1,
        panel_px: (520, 400),
        charts: vec![Chart {
            title,
            x_label: "σc".into(),
            y_label: "⟨m⟩".into(),
            items,
            legend: vec![],
        }],
    }
}

/// Fig. 4: m_selc against m_uncontaminated per PSF (blue) and their means
/// (red), with the 1:1 line.
pub fn fig4(r: &Report) -> Figure {
    let pts: Vec<(f64, f64, Option<f64>)> = r
        .psfs
        .iter()
        .filter_map(|p| Some((p.m_uncontaminated?, p.m_selc?, p.m_selc_err)))
        .collect();
    let mean: Vec<(f64, f64, Option<f64>)> =
        [(r.summary.m_uncontaminated_mean, r.summary.m_selc_mean)]
            .iter()
            .filter_map(|&(a, b)| Some((a?, b?, None)))
            .collect();
    let per_psf = measured_label(&pts, "per PSF");
    let lo = pts.iter().flat_map(|p| [p.0, p.1]).fold(-0.01, f64::min);
    let hi = pts.iter().flat_map(|p| [p.0, p.1]).fold(0.01, f64::max);
    Figure {
        cols: 1,
        panel_px: (520, 400),
        charts: vec![Chart {
            title: format!("{}: selection bias against uncontaminated m", r.submission),
            x_label: "m uncontaminated".into(),
            y_label: "m selc".into(),
            items: vec![
                Item::Line {
                    pts: vec![(lo, lo), (hi, hi)],
                    colour: GREY,
                    dashed: false,
                },
                Item::Points { pts, colour: BLUE },
                Item::Points {
                    pts: mean,
                    colour: RED,
                },
            ],
            legend: vec![
                (per_psf, BLUE),
                ("mean over PSFs".into(), RED),
                ("1:1".into(), GREY),
            ],
        }],
    }
}

/// Fig. 5: γ1 − γ1_true against true magnitude (bin centres; open bins
/// drawn half a bin beyond their edge), with the all-galaxy mean dashed.
pub fn fig5(r: &Report) -> Figure {
    let b = &r.by_magnitude;
    let pts: Vec<(f64, f64, Option<f64>)> = b
        .bins
        .iter()
        .filter_map(|bin| {
            let x = match (bin.lo, bin.hi) {
                (Some(l), Some(h)) => 0.5 * (l + h),
                (None, Some(h)) => h - 0.5,
                (Some(l), None) => l + 0.5,
                (None, None) => 0.0,
            };
            Some((x, bin.g1_residual?, bin.g1_residual_err))
        })
        .collect();
    let (x0, x1) = (
        pts.iter().map(|p| p.0).fold(f64::MAX, f64::min),
        pts.iter().map(|p| p.0).fold(f64::MIN, f64::max),
    );
    let mut items = Vec::new();
    if let (Some(all), true) = (b.all.g1_residual, x0 <= x1) {
        items.push(Item::Line {
            pts: vec![(x0, all), (x1, all)],
            colour: RED,
            dashed: true,
        });
    }
    let bins = measured_label(&pts, "magnitude bin");
    items.push(Item::Points { pts, colour: BLUE });
    Figure {
        cols: 1,
        panel_px: (520, 400),
        charts: vec![Chart {
            title: format!("{}: shear residual against magnitude", r.submission),
            x_label: "I magnitude (true)".into(),
            y_label: "γ1 − γ1 true".into(),
            items,
            legend: vec![(bins, BLUE), ("all galaxies".into(), RED)],
        }],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The full preset's report (docs/full-preset): six PSFs, linear fits.
    fn preset() -> Report {
        serde_json::from_str(include_str!("../../../docs/full-preset/report.json")).unwrap()
    }

    #[test]
    fn fig3_names_its_submission_and_shows_the_7_percent_band_whole() {
        let r = preset();
        let f = fig3(&[&r]);
        let c = &f.charts[0];
        assert!(
            c.title
                .starts_with("KSB+ (stepsim measure): ⟨m⟩ against σc"),
            "{}",
            c.title
        );
        let (_, y) = c.range();
        assert!(
            y[0] < r.summary.m_mean.unwrap() && y[0] < -0.07 && y[1] > 0.07,
            "{y:?}"
        );
        let two = fig3(&[&r, &r]);
        assert!(two.charts[0].title.contains("one point a submission"));
    }

    #[test]
    fn fig2_names_the_fit_it_draws_and_error_bars_only_when_there_are_some() {
        let mut r = preset();
        let legend = |r: &Report| fig2(r).charts[0].legend.clone();
        assert_eq!(legend(&r)[0].0, "measured ± 1σ");
        assert_eq!(legend(&r)[1].0, "fit m γ + c");
        r.psfs[0].linear = false;
        r.psfs[0].q = Some(0.3);
        assert_eq!(legend(&r)[1].0, "fit q γ² + m γ + c");
        for d in &mut r.datasets {
            d.g1_err = None;
        }
        assert_eq!(legend(&r)[0].0, "measured (no error: one base field)");
    }
}
