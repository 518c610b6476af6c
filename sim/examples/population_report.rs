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
//! writes `population-counts` and `population-sizes` as SVG and PNG into
//! the directory given (drawn by `stepsim_figure::chart`).

use std::path::Path;
use stepsim_contract::truth::TruthRow;
use stepsim_figure::chart::{BLUE, Chart, Colour, Figure, GREY, Item, ORANGE, RED};
use stepsim_sim::Plan;
use stepsim_sim::model::population::base_field;

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
    let plan = Plan::from_json("{}", Path::new("defaults"), &["run.seed=20060101"]).unwrap();
    let area1 = plan.placement_area().area_arcmin2;
    let area = area1 * f64::from(FIELDS);
    let mut rows: Vec<TruthRow> = Vec::new();
    for f in 0..FIELDS {
        rows.extend(base_field(&plan.population(), f).unwrap());
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
    let counts = plot(
        "Differential counts, I (Vega)",
        "log10 N / arcmin² / mag",
        &[
            (
                "galaxies",
                BLUE,
                bins.iter()
                    .filter(|b| b.n_gal > 0.0)
                    .map(|b| (b.mag, b.n_gal.log10()))
                    .collect(),
            ),
            (
                "stars",
                RED,
                bins.iter()
                    .filter(|b| b.n_star > 0.0)
                    .map(|b| (b.mag, b.n_star.log10()))
                    .collect(),
            ),
            // Reference line of slope 0.34 through the model at I = 22.
            ("slope 0.34", GREY, {
                let at22 = bins
                    .iter()
                    .find(|b| (b.mag - 22.25).abs() < 1e-9)
                    .map(|b| b.n_gal.log10())
                    .unwrap_or(0.0);
                vec![(17.0, at22 - 0.34 * 5.25), (26.0, at22 + 0.34 * 3.75)]
            }),
        ],
    );
    write_figure(dir, "population-counts", &counts);
    let sizes = plot(
        "Median sizes against I (Vega)",
        "log10 size / arcsec",
        &[
            (
                "disk h",
                BLUE,
                bins.iter()
                    .filter(|b| b.disk_h > 0.0)
                    .map(|b| (b.mag, b.disk_h.log10()))
                    .collect(),
            ),
            (
                "bulge r_e",
                ORANGE,
                bins.iter()
                    .filter(|b| b.bulge_re > 0.0)
                    .map(|b| (b.mag, b.bulge_re.log10()))
                    .collect(),
            ),
        ],
    );
    write_figure(dir, "population-sizes", &sizes);
}

/// One plotted line: name, colour, points.
type Series<'a> = (&'a str, Colour, Vec<(f64, f64)>);

/// Lines with markers against I magnitude, one legend entry each, by the
/// workspace's plotter.
fn plot(title: &str, y_label: &str, series: &[Series]) -> Figure {
    let mut items = Vec::new();
    for (_, colour, pts) in series {
        items.push(Item::Line {
            pts: pts.clone(),
            colour: *colour,
            dashed: false,
        });
        items.push(Item::Points {
            pts: pts.iter().map(|&(x, y)| (x, y, None)).collect(),
            colour: *colour,
        });
    }
    Figure {
        cols: 1,
        panel_px: (640, 420),
        charts: vec![Chart {
            title: title.into(),
            x_label: "I magnitude (Vega)".into(),
            y_label: y_label.into(),
            items,
            legend: series
                .iter()
                .map(|(name, colour, _)| ((*name).to_owned(), *colour))
                .collect(),
        }],
    }
}

/// Writes `stem.svg` and `stem.png` (the PNG drawn from the very SVG).
fn write_figure(dir: &Path, stem: &str, fig: &Figure) {
    std::fs::write(dir.join(format!("{stem}.svg")), fig.to_svg()).unwrap();
    std::fs::write(dir.join(format!("{stem}.png")), fig.to_png().unwrap()).unwrap();
}
