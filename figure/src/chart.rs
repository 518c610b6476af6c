//! Charts as SVG, and as PNG drawn from that very SVG: axes with round
//! ticks and tick values, a title, axis labels, a legend, points with
//! vertical error bars, lines and shaded bands, in a grid of panels. The one
//! plotter of the workspace: the score figures (`harness/src/report/plots.rs`) and
//! the population plots (`sim/examples/population_report.rs`) use it.

use crate::picture::xml_escape;
use std::fmt::Write as _;

/// Palette: white, black, light grey, blue, red, green, orange, mid grey.
pub const PALETTE: [[u8; 3]; 8] = [
    [255, 255, 255],
    [0, 0, 0],
    [225, 225, 225],
    [31, 119, 180],
    [214, 39, 40],
    [44, 160, 44],
    [255, 127, 14],
    [150, 150, 150],
];

/// Palette index of a colour.
pub type Colour = u8;
/// Black.
pub const BLACK: Colour = 1;
/// Light grey (bands).
pub const LIGHT: Colour = 2;
/// Blue.
pub const BLUE: Colour = 3;
/// Red.
pub const RED: Colour = 4;
/// Green.
pub const GREEN: Colour = 5;
/// Orange.
pub const ORANGE: Colour = 6;
/// Grey (reference lines).
pub const GREY: Colour = 7;

/// One thing drawn in a chart, in data coordinates.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    /// Markers with optional vertical error bars.
    Points {
        /// (x, y, σ_y).
        pts: Vec<(f64, f64, Option<f64>)>,
        /// Colour.
        colour: Colour,
    },
    /// A polyline.
    Line {
        /// Vertices.
        pts: Vec<(f64, f64)>,
        /// Colour.
        colour: Colour,
        /// Dashed?
        dashed: bool,
    },
    /// A filled rectangle (x0, x1, y0, y1), clipped to the axes.
    Band {
        /// Corners.
        rect: [f64; 4],
        /// Colour.
        colour: Colour,
    },
}

/// One panel with axes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Chart {
    /// Title, above the panel.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// What is drawn, in order.
    pub items: Vec<Item>,
    /// Legend entries (text, colour), each after a short line of its
    /// colour, in the corner of the panel that covers the fewest data
    /// (top-left first); none: no legend.
    pub legend: Vec<(String, Colour)>,
}

/// A grid of charts.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Panel columns.
    pub cols: usize,
    /// Panel size in pixels.
    pub panel_px: (usize, usize),
    /// The panels.
    pub charts: Vec<Chart>,
}

const MARGIN: (f64, f64, f64, f64) = (82.0, 15.0, 28.0, 45.0); // left, right, top, bottom

/// "Nice" tick values covering [lo, hi] (about five).
pub fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return vec![lo];
    }
    let raw = (hi - lo) / 7.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|f| f * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

impl Chart {
    /// Data range over every item, padded by 8 % (never empty, and at least
    /// 0.1 % of the largest value wide, so that tick labels stay short). A
    /// band's edges count on each axis where they are finite and below
    /// 1e300 (a band open to one side, `f64::MAX`, does not stretch that
    /// axis), so that a band is shown whole.
    pub fn range(&self) -> ([f64; 2], [f64; 2]) {
        let (mut x, mut y) = ([f64::MAX, f64::MIN], [f64::MAX, f64::MIN]);
        // Bands first: each finite edge on its own axis (an open edge,
        // `f64::MAX`, leaves its axis to the data).
        let edge = |v: f64| v.is_finite() && v.abs() < 1e300;
        for it in &self.items {
            if let Item::Band { rect, .. } = it {
                for &v in rect[..2].iter().filter(|v| edge(**v)) {
                    x = [x[0].min(v), x[1].max(v)];
                }
                for &v in rect[2..].iter().filter(|v| edge(**v)) {
                    y = [y[0].min(v), y[1].max(v)];
                }
            }
        }
        let mut add = |px: f64, py: f64| {
            if px.is_finite() && py.is_finite() {
                x = [x[0].min(px), x[1].max(px)];
                y = [y[0].min(py), y[1].max(py)];
            }
        };
        for it in &self.items {
            match it {
                Item::Points { pts, .. } => {
                    for &(px, py, e) in pts {
                        let e = e.unwrap_or(0.0);
                        add(px, py - e);
                        add(px, py + e);
                    }
                }
                Item::Line { pts, .. } => pts.iter().for_each(|&(px, py)| add(px, py)),
                Item::Band { .. } => {}
            }
        }
        let pad = |r: [f64; 2]| {
            if r[0] > r[1] {
                [-1.0, 1.0]
            } else {
                let w = (r[1] - r[0])
                    .max(1e-3 * r[0].abs().max(r[1].abs()))
                    .max(1e-9);
                [r[0] - 0.08 * w, r[1] + 0.08 * w]
            }
        };
        (pad(x), pad(y))
    }
}

/// Maps data to pixel coordinates of one panel.
struct Frame {
    ox: f64,
    oy: f64,
    w: f64,
    h: f64,
    xr: [f64; 2],
    yr: [f64; 2],
}

impl Frame {
    fn px(&self, x: f64, y: f64) -> (f64, f64) {
        (
            self.ox + (x - self.xr[0]) / (self.xr[1] - self.xr[0]) * self.w,
            self.oy + self.h - (y - self.yr[0]) / (self.yr[1] - self.yr[0]) * self.h,
        )
    }
    fn clip(&self, x: f64, y: f64) -> (f64, f64) {
        (
            x.clamp(self.xr[0], self.xr[1]),
            y.clamp(self.yr[0], self.yr[1]),
        )
    }
}

impl Frame {
    /// Where the legend's first swatch starts: the corner (top-left,
    /// top-right, bottom-left, bottom-right) whose legend box covers the
    /// fewest drawn points and line samples, the first of equals.
    fn legend_origin(&self, c: &Chart) -> (f64, f64) {
        let (bw, bh) = legend_box(c);
        let mut marks: Vec<(f64, f64)> = Vec::new();
        for it in &c.items {
            match it {
                Item::Points { pts, .. } => {
                    for &(x, y, e) in pts {
                        marks.push(self.px(x, y));
                        // The error bar's length counts too.
                        if let Some(e) = e.filter(|e| e.is_finite()) {
                            marks.extend((-4..=4).map(|k| self.px(x, y + e * f64::from(k) / 4.0)));
                        }
                    }
                }
                Item::Line { pts, .. } => {
                    for w in pts.windows(2) {
                        let (a, b) = (self.px(w[0].0, w[0].1), self.px(w[1].0, w[1].1));
                        marks.extend((0..=20).map(|k| {
                            let t = f64::from(k) / 20.0;
                            (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
                        }));
                    }
                }
                Item::Band { .. } => {}
            }
        }
        let corners = [
            (self.ox, self.oy),
            (self.ox + self.w - bw, self.oy),
            (self.ox, self.oy + self.h - bh),
            (self.ox + self.w - bw, self.oy + self.h - bh),
        ];
        let covered = |(x0, y0): (f64, f64)| {
            marks
                .iter()
                .filter(|&&(x, y)| x >= x0 && x <= x0 + bw && y >= y0 && y <= y0 + bh)
                .count()
        };
        let mut best = corners[0];
        for &c in &corners[1..] {
            if covered(c) < covered(best) {
                best = c;
            }
        }
        (best.0 + 8.0, best.1 + 16.0)
    }
}

/// Width and height (pixels) of the legend's box: the swatches, the
/// longest text (11-px DejaVu Sans, about 0.6 em a character) and room
/// below the last line, so that a legend in a lower corner stays clear of
/// the tick marks.
fn legend_box(c: &Chart) -> (f64, f64) {
    let chars = c
        .legend
        .iter()
        .map(|(t, _)| t.chars().count())
        .max()
        .unwrap_or(0);
    (
        33.0 + 6.6 * chars as f64,
        14.0 + 15.0 * c.legend.len() as f64,
    )
}

impl Figure {
    /// Image size in pixels.
    pub fn size(&self) -> (usize, usize) {
        let cols = self.columns();
        let rows = self.charts.len().div_ceil(cols).max(1);
        (cols * self.panel_px.0, rows * self.panel_px.1)
    }

    /// Columns used: at most `cols`, and no more than there are charts (an
    /// empty column left a blank third of Fig. 2 for two PSFs).
    fn columns(&self) -> usize {
        self.cols.clamp(1, self.charts.len().max(1))
    }

    fn frames(&self) -> Vec<Frame> {
        let cols = self.columns();
        self.charts
            .iter()
            .enumerate()
            .map(|(i, c)| {
                let (xr, yr) = c.range();
                let (pw, ph) = (self.panel_px.0 as f64, self.panel_px.1 as f64);
                Frame {
                    ox: (i % cols) as f64 * pw + MARGIN.0,
                    oy: (i / cols) as f64 * ph + MARGIN.2,
                    w: pw - MARGIN.0 - MARGIN.1,
                    h: ph - MARGIN.2 - MARGIN.3,
                    xr,
                    yr,
                }
            })
            .collect()
    }

    /// The figure as SVG text.
    pub fn to_svg(&self) -> String {
        let (w, h) = self.size();
        let col = |c: Colour| {
            let [r, g, b] = PALETTE[usize::from(c) % PALETTE.len()];
            format!("#{r:02x}{g:02x}{b:02x}")
        };
        let mut s = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" \
             viewBox=\"0 0 {w} {h}\" font-family=\"sans-serif\" font-size=\"11\">\n\
             <rect width=\"{w}\" height=\"{h}\" fill=\"#ffffff\"/>\n"
        );
        for (c, f) in self.charts.iter().zip(self.frames()) {
            for it in &c.items {
                match it {
                    Item::Band { rect, colour } => {
                        let (x0, y0) = f.px(f.clip(rect[0], rect[3]).0, f.clip(rect[0], rect[3]).1);
                        let (x1, y1) = f.px(f.clip(rect[1], rect[2]).0, f.clip(rect[1], rect[2]).1);
                        let _ = writeln!(
                            s,
                            "<rect x=\"{x0:.1}\" y=\"{y0:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{}\"/>",
                            (x1 - x0).max(0.0),
                            (y1 - y0).max(0.0),
                            col(*colour)
                        );
                    }
                    Item::Line {
                        pts,
                        colour,
                        dashed,
                    } => {
                        let p: Vec<String> = pts
                            .iter()
                            .map(|&(x, y)| {
                                let (a, b) = f.px(x, y);
                                format!("{a:.1},{b:.1}")
                            })
                            .collect();
                        let dash = if *dashed {
                            " stroke-dasharray=\"6,4\""
                        } else {
                            ""
                        };
                        let _ = writeln!(
                            s,
                            "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1.5\"{dash}/>",
                            p.join(" "),
                            col(*colour)
                        );
                    }
                    Item::Points { pts, colour } => {
                        for &(x, y, e) in pts {
                            let (a, b) = f.px(x, y);
                            if let Some(e) = e {
                                let (_, b0) = f.px(x, y - e);
                                let (_, b1) = f.px(x, y + e);
                                let _ = writeln!(
                                    s,
                                    "<line x1=\"{a:.1}\" y1=\"{b0:.1}\" x2=\"{a:.1}\" y2=\"{b1:.1}\" stroke=\"{}\"/>",
                                    col(*colour)
                                );
                            }
                            let _ = writeln!(
                                s,
                                "<circle cx=\"{a:.1}\" cy=\"{b:.1}\" r=\"3.5\" fill=\"{}\"/>",
                                col(*colour)
                            );
                        }
                    }
                }
            }
            // Axes box, ticks and labels.
            let _ = writeln!(
                s,
                "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#000000\"/>",
                f.ox, f.oy, f.w, f.h
            );
            let ts = ticks(f.xr[0], f.xr[1]);
            for (&t, label) in ts.iter().zip(tick_labels(&ts)) {
                let (a, _) = f.px(t, f.yr[0]);
                let b = f.oy + f.h;
                let _ = writeln!(
                    s,
                    "<line x1=\"{a:.1}\" y1=\"{b:.1}\" x2=\"{a:.1}\" y2=\"{:.1}\" stroke=\"#000000\"/>\
                     <text x=\"{a:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
                    b - 5.0,
                    b + 14.0,
                    label
                );
            }
            let ts = ticks(f.yr[0], f.yr[1]);
            for (&t, label) in ts.iter().zip(tick_labels(&ts)) {
                let (_, b) = f.px(f.xr[0], t);
                let _ = writeln!(
                    s,
                    "<line x1=\"{:.1}\" y1=\"{b:.1}\" x2=\"{:.1}\" y2=\"{b:.1}\" stroke=\"#000000\"/>\
                     <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
                    f.ox,
                    f.ox + 5.0,
                    f.ox - 4.0,
                    b + 4.0,
                    label
                );
            }
            let (lx, ly) = f.legend_origin(c);
            if !c.legend.is_empty() {
                // A pale ground, so that no line runs through the text.
                let (bw, _) = legend_box(c);
                let _ = writeln!(
                    s,
                    "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"#ffffff\" fill-opacity=\"0.85\"/>",
                    lx - 4.0,
                    ly - 10.0,
                    bw - 8.0,
                    15.0 * c.legend.len() as f64 + 4.0
                );
            }
            for (k, (text, colour)) in c.legend.iter().enumerate() {
                let (x, y) = (lx, ly + 15.0 * k as f64);
                let _ = writeln!(
                    s,
                    "<line x1=\"{x:.1}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"{}\" stroke-width=\"2.5\"/>\
                     <text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
                    x + 20.0,
                    col(*colour),
                    x + 25.0,
                    y + 4.0,
                    xml_escape(text)
                );
            }
            let _ = writeln!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" font-size=\"13\">{}</text>\n\
                 <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>\n\
                 <text transform=\"translate({:.1},{:.1}) rotate(-90)\" text-anchor=\"middle\">{}</text>",
                f.ox + f.w / 2.0,
                f.oy - 9.0,
                xml_escape(&c.title),
                f.ox + f.w / 2.0,
                f.oy + f.h + 32.0,
                xml_escape(&c.x_label),
                f.ox - 66.0,
                f.oy + f.h / 2.0,
                xml_escape(&c.y_label)
            );
        }
        s.push_str("</svg>\n");
        s
    }

    /// The figure as PNG: the very SVG of [`Figure::to_svg`] rasterised,
    /// titles, labels and tick values included (resvg with the bundled
    /// DejaVu Sans; see [`crate::png`]).
    pub fn to_png(&self) -> Result<Vec<u8>, crate::png::SvgError> {
        crate::png::svg_to_png(&self.to_svg())
    }
}

/// Labels of equally spaced ticks, with just the digits that tell them
/// apart: decimals from the spacing, scientific notation for very large or
/// very small values.
pub fn tick_labels(ts: &[f64]) -> Vec<String> {
    let step = if ts.len() > 1 { ts[1] - ts[0] } else { 0.0 };
    let big = ts.iter().fold(0.0f64, |m, t| m.max(t.abs()));
    let step_exp = if step > 0.0 && step.is_finite() {
        step.log10().floor() as i32
    } else if big > 0.0 && big.is_finite() {
        big.log10().floor() as i32
    } else {
        0
    };
    let scientific = big >= 1e5 || (big < 1e-3 && big > 0.0);
    ts.iter()
        .map(|&t| {
            if t == 0.0 {
                return "0".to_owned();
            }
            let s = if scientific {
                let digits = (big.log10().floor() as i32 - step_exp).clamp(0, 12) as usize;
                format!("{t:.digits$e}")
            } else {
                let decimals = (-step_exp).clamp(0, 15) as usize;
                format!("{t:.decimals$}")
            };
            if s.trim_start_matches('-')
                .chars()
                .all(|c| c == '0' || c == '.')
            {
                "0".to_owned()
            } else {
                s
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::png::decode;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(
            ticks(0.0, 1.0),
            vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
        );
        let t = ticks(-0.013, 0.021);
        assert!(t.len() >= 3 && t[0] >= -0.013 && *t.last().unwrap() <= 0.021);
    }

    #[test]
    fn tick_labels_tell_every_tick_apart() {
        let cases: [(f64, f64); 6] = [
            (0.0, 1.0),
            (-0.013, 0.021),
            (0.001659_9, 0.001660_1),
            (19.0, 26.0),
            (2e-5, 9e-5),
            (1e5, 9e5),
        ];
        for (lo, hi) in cases {
            let ts = ticks(lo, hi);
            let labels = tick_labels(&ts);
            let mut unique = labels.clone();
            unique.dedup();
            assert_eq!(unique.len(), ts.len(), "{lo}..{hi}: {labels:?}");
            for (t, l) in ts.iter().zip(&labels) {
                let back: f64 = l.parse().unwrap();
                let step = ts[1] - ts[0];
                assert!((back - t).abs() < 0.01 * step, "{l} for {t}");
            }
        }
        assert_eq!(
            tick_labels(&ticks(0.0, 1.0)),
            ["0", "0.2", "0.4", "0.6", "0.8", "1.0"]
        );
    }

    #[test]
    fn a_figure_has_no_empty_columns() {
        let chart = |t: &str| Chart {
            title: t.into(),
            x_label: "x".into(),
            y_label: "y".into(),
            items: vec![],
            legend: vec![],
        };
        let fig = |n: usize| Figure {
            cols: 3,
            panel_px: (420, 320),
            charts: (0..n).map(|i| chart(&i.to_string())).collect(),
        };
        // Two PSFs: two panels wide, not three with a blank one.
        assert_eq!(fig(2).size(), (840, 320));
        assert_eq!(fig(3).size(), (1260, 320));
        assert_eq!(fig(4).size(), (1260, 640));
        assert_eq!(fig(0).size(), (420, 320));
    }

    #[test]
    fn a_chart_draws_points_where_the_data_are() {
        let fig = Figure {
            cols: 1,
            panel_px: (200, 200),
            charts: vec![Chart {
                title: "t<1>".into(),
                x_label: "x".into(),
                y_label: "y".into(),
                items: vec![Item::Points {
                    pts: vec![(0.0, 0.0, None), (1.0, 1.0, Some(0.1))],
                    colour: RED,
                }],
                legend: vec![],
            }],
        };
        let svg = fig.to_svg();
        assert_eq!(svg.matches("<circle").count(), 2);
        assert!(svg.contains("t&lt;1&gt;"));
        let png = decode(&fig.to_png().unwrap()).unwrap();
        assert_eq!((png.width, png.height), (200, 200));
        // The first point sits at the lower-left of the padded range.
        let f = &fig.frames()[0];
        let (px, py) = f.px(0.0, 0.0);
        let [r, g, b] = PALETTE[usize::from(RED)];
        assert_eq!(png.pixel(px as usize, py as usize), [r, g, b, 255]);
        assert_eq!(
            png.pixel(5, 5),
            [255, 255, 255, 255],
            "background stays white"
        );
    }

    #[test]
    fn the_png_carries_the_titles_labels_and_tick_values_of_the_svg() {
        let fig = Figure {
            cols: 1,
            panel_px: (300, 240),
            charts: vec![Chart {
                title: "coma: shear response".into(),
                x_label: "g1 true".into(),
                y_label: "g1 measured".into(),
                items: vec![Item::Points {
                    pts: vec![(0.0, 0.0, None), (0.1, 0.1, None)],
                    colour: BLUE,
                }],
                legend: vec![],
            }],
        };
        let svg = fig.to_svg();
        // The same drawing without any text element.
        let mut bare = String::new();
        let mut rest = svg.as_str();
        while let Some(a) = rest.find("<text") {
            bare.push_str(&rest[..a]);
            let b = rest[a..].find("</text>").unwrap() + a + "</text>".len();
            rest = &rest[b..];
        }
        bare.push_str(rest);
        assert!(svg.matches("<text").count() >= 8, "title, labels, ticks");
        let with = decode(&fig.to_png().unwrap()).unwrap();
        let without = decode(&crate::png::svg_to_png(&bare).unwrap()).unwrap();
        let dark = |d: &crate::png::Decoded, y0: usize, y1: usize| {
            (y0..y1)
                .flat_map(|y| (0..d.width).map(move |x| (x, y)))
                .filter(|&(x, y)| d.pixel(x, y)[0] < 100)
                .count()
        };
        let f = &fig.frames()[0];
        let top = f.oy as usize;
        // Above the frame only the title is drawn; below it tick values and
        // the x label.
        assert_eq!(dark(&without, 0, top - 2), 0);
        assert!(dark(&with, 0, top - 2) > 100, "title drawn");
        let bottom = (f.oy + f.h) as usize + 2;
        assert!(
            dark(&with, bottom, with.height) > dark(&without, bottom, with.height) + 100,
            "tick values and x label drawn"
        );
    }

    #[test]
    fn a_legend_names_each_entry_after_a_line_of_its_colour() {
        let mut chart = Chart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            items: vec![Item::Points {
                pts: vec![(0.0, 0.0, None), (1.0, 1.0, None)],
                colour: BLUE,
            }],
            legend: vec![("galaxies".into(), BLUE), ("stars <faint>".into(), RED)],
        };
        let fig = |c: &Chart| Figure {
            cols: 1,
            panel_px: (300, 240),
            charts: vec![c.clone()],
        };
        let svg = fig(&chart).to_svg();
        assert!(svg.contains(">galaxies</text>") && svg.contains(">stars &lt;faint&gt;</text>"));
        // The second entry's swatch, 15 px below the first, in red.
        let f = &fig(&chart).frames()[0];
        let (x, y) = ((f.ox + 18.0) as usize, (f.oy + 31.0) as usize);
        let png = decode(&fig(&chart).to_png().unwrap()).unwrap();
        let [r, g, b] = PALETTE[usize::from(RED)];
        assert_eq!(png.pixel(x, y), [r, g, b, 255]);
        chart.legend.clear();
        let png = decode(&fig(&chart).to_png().unwrap()).unwrap();
        assert_eq!(
            png.pixel(x, y),
            [255, 255, 255, 255],
            "no legend, no swatch"
        );
    }

    #[test]
    fn a_band_is_shown_whole_and_an_open_edge_does_not_stretch_the_axis() {
        let chart = Chart {
            items: vec![
                Item::Band {
                    rect: [0.0, f64::MAX, -0.07, 0.07],
                    colour: LIGHT,
                },
                Item::Points {
                    pts: vec![(3e-4, -0.13, None)],
                    colour: BLUE,
                },
            ],
            ..Chart::default()
        };
        let (x, y) = chart.range();
        assert!(y[1] > 0.07 && y[0] < -0.13, "{y:?}");
        assert!(x[0] < 0.0 && x[1] > 3e-4 && x[1] < 1e-3, "{x:?}");
    }

    #[test]
    fn a_legend_in_a_lower_corner_stays_clear_of_the_tick_marks() {
        // Points along the top: the legend goes to a lower corner, and its
        // last line's text ends above the 5-px tick marks.
        let chart = Chart {
            items: vec![Item::Points {
                pts: (0..=10)
                    .map(|k| (f64::from(k), 1.0, None))
                    .chain([(5.0, 0.0, None)])
                    .collect(),
                colour: BLUE,
            }],
            legend: vec![("measured ± 1σ".into(), BLUE), ("fit m γ + c".into(), RED)],
            ..Chart::default()
        };
        let fig = Figure {
            cols: 1,
            panel_px: (420, 320),
            charts: vec![chart.clone()],
        };
        let f = &fig.frames()[0];
        let (_, y) = f.legend_origin(&chart);
        assert!(y > f.oy + f.h / 2.0, "a lower corner: {y}");
        let last_baseline = y + 15.0 * (chart.legend.len() - 1) as f64 + 4.0;
        // DejaVu's descent at 11 px is under 3 px.
        assert!(last_baseline + 3.0 < f.oy + f.h - 5.0, "{last_baseline}");
    }

    #[test]
    fn the_legend_goes_to_the_corner_with_the_fewest_data() {
        // A line falling from the top-left corner to the bottom-right: the
        // top-left and bottom-right corners are taken, the top-right is free.
        let chart = Chart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            items: vec![Item::Line {
                pts: vec![(0.0, 1.0), (1.0, 0.0)],
                colour: BLUE,
                dashed: false,
            }],
            legend: vec![("disk h".into(), BLUE), ("bulge r_e".into(), RED)],
        };
        let fig = Figure {
            cols: 1,
            panel_px: (400, 300),
            charts: vec![chart.clone()],
        };
        let f = &fig.frames()[0];
        let (x, y) = f.legend_origin(&chart);
        assert!(x > f.ox + f.w / 2.0 && y < f.oy + f.h / 2.0, "({x}, {y})");
        // Nothing drawn: top-left.
        let empty = Chart {
            items: vec![],
            ..chart
        };
        assert_eq!(f.legend_origin(&empty), (f.ox + 8.0, f.oy + 16.0));
    }
}
