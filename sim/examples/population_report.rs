//! Measures the default population and writes the numbers and plots of
//! `docs/population.md`:
//!
//! ```sh
//! cargo run -p stepsim-sim --example population_report -- docs
//! ```
//!
//! Draws base fields 0..4 of the STEP1 defaults (4096² pixels of 0.206″
//! plus 10″ margins, I ≤ 26: ≈ 830 arcmin²), prints a Markdown table of the
//! differential counts, median sizes and redshifts per 0.5-mag bin, and
//! writes `population-counts.svg` and `population-sizes.svg` into the
//! directory given (hand-written SVG, no dependencies).

use std::fmt::Write as _;
use std::path::Path;
use stepsim_sim::config::RawConfig;
use stepsim_sim::plan::Plan;
use stepsim_sim::population::base_field;
use stepsim_sim::truth::TruthRow;

const FIELDS: u32 = 4;

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

struct Bin {
    mag: f64,
    n_gal: f64,
    n_star: f64,
    disk_h: f64,
    bulge_re: f64,
    z: f64,
}

fn main() {
    let out = std::env::args().nth(1).unwrap_or_else(|| "docs".into());
    let raw = RawConfig::parse("{}", Path::new("defaults"), &["run.seed=20060101".into()]).unwrap();
    let plan = Plan::new(raw, Path::new("defaults")).unwrap();
    let area1 = plan.placement_area().area_arcmin2;
    let area = area1 * f64::from(FIELDS);
    let mut rows: Vec<TruthRow> = Vec::new();
    for f in 0..FIELDS {
        rows.extend(base_field(&plan, f).unwrap());
    }
    let gals: Vec<&TruthRow> = rows.iter().filter(|r| !r.is_star()).collect();
    let per_field = gals.len() as f64 / f64::from(FIELDS);
    let mut bins = Vec::new();
    let mut m = 17.0;
    while m < 26.0 - 1e-9 {
        let inb: Vec<&&TruthRow> = gals
            .iter()
            .filter(|r| r.mag >= m && r.mag < m + 0.5)
            .collect();
        let stars = rows
            .iter()
            .filter(|r| r.is_star() && r.mag >= m && r.mag < m + 0.5)
            .count();
        bins.push(Bin {
            mag: m + 0.25,
            n_gal: inb.len() as f64 / area / 0.5,
            n_star: stars as f64 / area / 0.5,
            disk_h: median(
                inb.iter()
                    .filter(|r| r.bt < 1.0)
                    .map(|r| r.disk_h_arcsec)
                    .collect(),
            ),
            bulge_re: median(
                inb.iter()
                    .filter(|r| r.bt > 0.0)
                    .map(|r| r.bulge_re_arcsec)
                    .collect(),
            ),
            z: median(inb.iter().map(|r| r.z).collect()),
        });
        m += 0.5;
    }
    let n_2355 = gals.iter().filter(|r| r.mag < 23.55).count() as f64 / area;
    let n_24 = gals.iter().filter(|r| r.mag < 24.0).count() as f64 / area;
    // Least-squares slope of log10 dN/dm over 20 < I < 24.
    let pts: Vec<(f64, f64)> = bins
        .iter()
        .filter(|b| b.mag > 20.0 && b.mag < 24.0)
        .map(|b| (b.mag, b.n_gal.log10()))
        .collect();
    let k = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / k,
        pts.iter().map(|p| p.1).sum::<f64>() / k,
    );
    let slope = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum::<f64>()
        / pts.iter().map(|p| (p.0 - mx).powi(2)).sum::<f64>();

    println!(
        "{} fields, {:.1} arcmin² in all; {:.0} galaxies and {:.0} stars per field (I ≤ 26)",
        FIELDS,
        area,
        per_field,
        (rows.len() - gals.len()) as f64 / f64::from(FIELDS)
    );
    println!("slope d log N/dm over 20 < I < 24: {slope:.3}");
    println!("galaxies per arcmin² with I < 23.55: {n_2355:.1}; with I < 24: {n_24:.1}");
    println!();
    println!(
        "| I (bin centre) | galaxies / arcmin² / mag | stars / arcmin² / mag | median disk h (″) | median bulge r_e (″) | median z |"
    );
    println!("|---|---|---|---|---|---|");
    for b in &bins {
        println!(
            "| {:.2} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2} |",
            b.mag, b.n_gal, b.n_star, b.disk_h, b.bulge_re, b.z
        );
    }
    let dir = Path::new(&out);
    std::fs::create_dir_all(dir).unwrap();
    let counts = svg_plot(
        "Differential counts, I (Vega)",
        "log10 N / arcmin² / mag",
        &[
            (
                "galaxies",
                "#1f77b4",
                bins.iter()
                    .filter(|b| b.n_gal > 0.0)
                    .map(|b| (b.mag, b.n_gal.log10()))
                    .collect(),
            ),
            (
                "stars",
                "#d62728",
                bins.iter()
                    .filter(|b| b.n_star > 0.0)
                    .map(|b| (b.mag, b.n_star.log10()))
                    .collect(),
            ),
            // Reference line of slope 0.34 through the model at I = 22.
            ("slope 0.34", "#7f7f7f", {
                let at22 = bins
                    .iter()
                    .find(|b| (b.mag - 22.25).abs() < 1e-9)
                    .map(|b| b.n_gal.log10())
                    .unwrap_or(0.0);
                vec![(17.0, at22 - 0.34 * 5.25), (26.0, at22 + 0.34 * 3.75)]
            }),
        ],
    );
    std::fs::write(dir.join("population-counts.svg"), counts).unwrap();
    let sizes = svg_plot(
        "Median sizes against I (Vega)",
        "log10 size / arcsec",
        &[
            (
                "disk h",
                "#1f77b4",
                bins.iter()
                    .filter(|b| b.disk_h > 0.0)
                    .map(|b| (b.mag, b.disk_h.log10()))
                    .collect(),
            ),
            (
                "bulge r_e",
                "#ff7f0e",
                bins.iter()
                    .filter(|b| b.bulge_re > 0.0)
                    .map(|b| (b.mag, b.bulge_re.log10()))
                    .collect(),
            ),
        ],
    );
    std::fs::write(dir.join("population-sizes.svg"), sizes).unwrap();
}

/// One plotted line: name, colour, points.
type Series<'a> = (&'a str, &'a str, Vec<(f64, f64)>);

/// A minimal line plot as SVG text.
fn svg_plot(title: &str, ylabel: &str, series: &[Series]) -> String {
    let (w, h, l, r, t, b) = (640.0, 420.0, 70.0, 20.0, 40.0, 50.0);
    let ys: Vec<f64> = series
        .iter()
        .flat_map(|s| s.2.iter().map(|p| p.1))
        .collect();
    let (x0, x1) = (17.0, 26.0);
    let y0 = (ys.iter().copied().fold(f64::INFINITY, f64::min) * 2.0).floor() / 2.0;
    let y1 = (ys.iter().copied().fold(f64::NEG_INFINITY, f64::max) * 2.0).ceil() / 2.0;
    let px = |x: f64| l + (x - x0) / (x1 - x0) * (w - l - r);
    let py = |y: f64| h - b - (y - y0) / (y1 - y0) * (h - t - b);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="{}" y="22" text-anchor="middle" font-size="15">{title}</text>"#,
        w / 2.0
    );
    let _ = writeln!(
        s,
        r#"<rect x="{l}" y="{t}" width="{}" height="{}" fill="none" stroke="black"/>"#,
        w - l - r,
        h - t - b
    );
    let mut x = x0;
    while x <= x1 + 1e-9 {
        let _ = writeln!(
            s,
            r#"<line x1="{0}" y1="{1}" x2="{0}" y2="{2}" stroke="black"/><text x="{0}" y="{3}" text-anchor="middle">{4}</text>"#,
            px(x),
            h - b,
            h - b + 5.0,
            h - b + 18.0,
            x
        );
        x += 1.0;
    }
    let mut y = y0;
    while y <= y1 + 1e-9 {
        let _ = writeln!(
            s,
            r#"<line x1="{0}" y1="{1}" x2="{2}" y2="{1}" stroke="lightgray"/><text x="{3}" y="{4}" text-anchor="end">{5:.1}</text>"#,
            l,
            py(y),
            w - r,
            l - 6.0,
            py(y) + 4.0,
            y
        );
        y += 0.5;
    }
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">I (Vega)</text>"#,
        (l + w - r) / 2.0,
        h - 12.0
    );
    let _ = writeln!(
        s,
        r#"<text x="16" y="{0}" text-anchor="middle" transform="rotate(-90 16 {0})">{ylabel}</text>"#,
        (t + h - b) / 2.0
    );
    for (i, (name, colour, pts)) in series.iter().enumerate() {
        let path: Vec<String> = pts
            .iter()
            .map(|p| format!("{:.1},{:.1}", px(p.0), py(p.1)))
            .collect();
        let _ = writeln!(
            s,
            r#"<polyline fill="none" stroke="{colour}" stroke-width="2" points="{}"/>"#,
            path.join(" ")
        );
        for p in pts {
            let _ = writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="2.5" fill="{colour}"/>"#,
                px(p.0),
                py(p.1)
            );
        }
        let ly = t + 18.0 + 16.0 * i as f64;
        let _ = writeln!(
            s,
            r#"<line x1="{}" y1="{ly}" x2="{}" y2="{ly}" stroke="{colour}" stroke-width="2"/><text x="{}" y="{}">{name}</text>"#,
            l + 12.0,
            l + 36.0,
            l + 42.0,
            ly + 4.0
        );
    }
    s.push_str("</svg>\n");
    s
}
