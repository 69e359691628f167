//! Charts for the bench reports, drawn with plotters into PNG and SVG, with
//! DejaVuSans embedded so no system font (fontconfig/freetype) is needed.
//!
//! Every figure is drawn by one generic function over plotters'
//! `DrawingBackend`, once for the bitmap and once for the SVG. Log axes are
//! drawn in log10 space with tick labels written back in linear values, so
//! linear and log charts share one coordinate type.

use plotters::coord::Shift;
use plotters::prelude::*;

static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// A chart rendered both ways.
#[derive(Debug)]
pub struct Chart {
    /// PNG file contents.
    pub png: Vec<u8>,
    /// SVG file contents.
    pub svg: String,
}

/// Why a chart could not be drawn.
#[derive(Debug, thiserror::Error)]
#[error("chart: {0}")]
pub struct ChartError(String);

fn err(e: impl std::fmt::Display) -> ChartError {
    ChartError(e.to_string())
}

fn font() -> Result<(), ChartError> {
    static ONCE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let ok = *ONCE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_ok()
    });
    ok.then_some(())
        .ok_or_else(|| ChartError("the embedded font could not be registered".into()))
}

const PANEL: (u32, u32) = (900, 560);
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// Something drawable on any plotters backend.
trait Figure {
    /// Pixel size of the whole figure.
    fn size(&self) -> (u32, u32);
    /// Draws onto `root`.
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), ChartError>;
}

fn render(fig: &impl Figure) -> Result<Chart, ChartError> {
    font()?;
    let size = fig.size();
    let mut rgb = vec![0u8; (size.0 * size.1 * 3) as usize];
    fig.draw(BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area())?;
    let png = crate::files::image::encode_png_rgb8(size.0 as usize, size.1 as usize, &rgb)
        .map_err(err)?;
    let mut svg = String::new();
    fig.draw(SVGBackend::with_string(&mut svg, size).into_drawing_area())?;
    Ok(Chart { png, svg })
}

/// Marker drawn at each point of a series.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Marker {
    /// No marker (a line only).
    None,
    /// Filled circle.
    Circle,
    /// Filled triangle.
    Triangle,
    /// Cross.
    Cross,
}

/// One named series of (x, y) points.
#[derive(Debug, Clone)]
pub(crate) struct Series {
    /// Legend label.
    pub name: String,
    /// Points; on a log axis, values that are not positive and finite are skipped.
    pub points: Vec<(f64, f64)>,
    /// Optional vertical spread per point (low, high), drawn as a bar.
    pub spread: Vec<(f64, f64)>,
    /// Palette index.
    pub color: usize,
    /// Marker shape.
    pub marker: Marker,
    /// Join the points with a line.
    pub line: bool,
    /// Thin (2 px) rather than 3 px line.
    pub thin: bool,
}

impl Series {
    /// A line with circle markers in palette colour `color`.
    pub fn line(name: impl Into<String>, color: usize, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: name.into(),
            points,
            spread: Vec::new(),
            color,
            marker: Marker::Circle,
            line: true,
            thin: false,
        }
    }
}

/// One panel: axes, labels and series.
#[derive(Debug, Clone)]
pub(crate) struct Plot {
    /// Caption.
    pub title: String,
    /// X axis label.
    pub x_label: String,
    /// Y axis label.
    pub y_label: String,
    /// Log10 x axis.
    pub x_log: bool,
    /// Log10 y axis.
    pub y_log: bool,
    /// X takes whole numbers only (a grid side): ticks only at integers.
    pub x_integer: bool,
    /// Series in legend order.
    pub series: Vec<Series>,
}

/// A tick label. On a log axis (`v` is log10 of the value) only values whose
/// mantissa is 1, 2 or 5 are labelled, so the labels read 1e-3, 2e-3, 5e-3;
/// `sci` says whether the whole axis is written in exponent form (any tick
/// outside 0.01 to 10^4) or in decimals, so one axis never mixes the two.
fn label(v: f64, log: bool, sci: bool) -> String {
    if !log {
        return format!("{}", (v * 1e6).round() / 1e6);
    }
    let x = 10f64.powf(v);
    let decade = 10f64.powf(v.floor());
    let m = x / decade;
    let Some(&nice) = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .find(|&&n| (m / n - 1.0).abs() < 0.015)
    else {
        return String::new();
    };
    if !sci {
        return format!("{}", (nice * decade * 1e4).round() / 1e4);
    }
    let (mant, e) = if nice == 10.0 {
        (1.0, v.floor() + 1.0)
    } else {
        (nice, v.floor())
    };
    if mant == 1.0 {
        format!("1e{}", e as i32)
    } else {
        format!("{mant}e{}", e as i32)
    }
}

/// Whether a log axis from 10^lo to 10^hi needs exponent labels.
fn needs_sci(lo: f64, hi: f64) -> bool {
    lo < -2.0 || hi >= 4.0
}

/// A tick label on an axis of whole numbers: integers only.
fn integer_label(v: f64) -> String {
    if (v - v.round()).abs() < 1e-6 {
        format!("{}", v.round())
    } else {
        String::new()
    }
}

/// How many key points to ask plotters for: on a log axis enough that
/// short ranges get 0.1-decade steps (so 2 and 5 appear), else about 10.
fn label_count(lo: f64, hi: f64, log: bool) -> usize {
    if log {
        ((hi - lo) * 10.0).ceil().clamp(4.0, 24.0) as usize
    } else {
        10
    }
}

impl Plot {
    fn transformed(&self, p: (f64, f64)) -> Option<(f64, f64)> {
        let f = |v: f64, log: bool| {
            if log {
                (v > 0.0 && v.is_finite()).then(|| v.log10())
            } else {
                v.is_finite().then_some(v)
            }
        };
        Some((f(p.0, self.x_log)?, f(p.1, self.y_log)?))
    }

    fn axes(&self) -> Option<((f64, f64), (f64, f64))> {
        let mut b = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for s in &self.series {
            for p in &s.points {
                if let Some((x, y)) = self.transformed(*p) {
                    b = (b.0.min(x), b.1.max(x), b.2.min(y), b.3.max(y));
                }
            }
            for y in s.spread.iter().flat_map(|r| [r.0, r.1]) {
                if let Some((_, y)) = self.transformed((1.0, y)) {
                    b.2 = b.2.min(y);
                    b.3 = b.3.max(y);
                }
            }
        }
        if !b.0.is_finite() {
            return None;
        }
        let pad = |lo: f64, hi: f64, log: bool| {
            let w = if hi > lo {
                hi - lo
            } else if log {
                1.0
            } else {
                lo.abs().max(1.0)
            };
            (lo - 0.06 * w, hi + 0.06 * w)
        };
        let (y0, y1) = pad(b.2, b.3, self.y_log);
        // Room above the data for the legend (upper left).
        let legend = 0.06 * (self.series.len() as f64 + 1.0) * (y1 - y0);
        Some((pad(b.0, b.1, self.x_log), (y0, y1 + legend)))
    }

    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), ChartError> {
        let Some(((x0, x1), (y0, y1))) = self.axes() else {
            return Err(ChartError(format!(
                "{}: no finite value to plot",
                self.title
            )));
        };
        let mut chart = ChartBuilder::on(root)
            .caption(&self.title, ("sans-serif", 22))
            .margin(16)
            .x_label_area_size(48)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(err)?;
        let (xl, yl) = (self.x_log, self.y_log);
        let (xs, ys) = (xl && needs_sci(x0, x1), yl && needs_sci(y0, y1));
        let integer = self.x_integer && !xl;
        let x_labels = if integer {
            ((x1 - x0).ceil() as usize + 1).clamp(2, 24)
        } else {
            label_count(x0, x1, xl)
        };
        let x_format = |v: &f64| {
            if integer {
                integer_label(*v)
            } else {
                label(*v, xl, xs)
            }
        };
        chart
            .configure_mesh()
            .x_desc(&self.x_label)
            .y_desc(&self.y_label)
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 16))
            .max_light_lines(2)
            .x_labels(x_labels)
            .y_labels(label_count(y0, y1, yl))
            .x_label_formatter(&x_format)
            .y_label_formatter(&|v| label(*v, yl, ys))
            .draw()
            .map_err(err)?;
        for s in &self.series {
            let c = PALETTE[s.color % PALETTE.len()];
            let width = if s.thin { 2 } else { 3 };
            let data: Vec<(f64, f64)> = s
                .points
                .iter()
                .filter_map(|p| self.transformed(*p))
                .collect();
            for (p, (lo, hi)) in s.points.iter().zip(&s.spread) {
                if let (Some(a), Some(b)) =
                    (self.transformed((p.0, *lo)), self.transformed((p.0, *hi)))
                {
                    chart
                        .draw_series(std::iter::once(PathElement::new(
                            vec![a, b],
                            c.stroke_width(1),
                        )))
                        .map_err(err)?;
                }
            }
            let anno = if s.line {
                chart
                    .draw_series(LineSeries::new(data.clone(), c.stroke_width(width)))
                    .map_err(err)?
            } else {
                chart
                    .draw_series(std::iter::empty::<PathElement<(f64, f64)>>())
                    .map_err(err)?
            };
            let marker = s.marker;
            anno.label(s.name.clone()).legend(
                move |(x, y)| -> DynElement<'static, DB, (i32, i32)> {
                    match marker {
                        Marker::None | Marker::Circle => {
                            PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3))
                                .into_dyn()
                        }
                        Marker::Triangle => {
                            TriangleMarker::new((x + 10, y), 6, c.filled()).into_dyn()
                        }
                        Marker::Cross => Cross::new((x + 10, y), 5, c.stroke_width(2)).into_dyn(),
                    }
                },
            );
            match marker {
                Marker::None => {}
                Marker::Circle => {
                    chart
                        .draw_series(data.iter().map(|&p| Circle::new(p, 4, c.filled())))
                        .map_err(err)?;
                }
                Marker::Triangle => {
                    chart
                        .draw_series(data.iter().map(|&p| TriangleMarker::new(p, 6, c.filled())))
                        .map_err(err)?;
                }
                Marker::Cross => {
                    chart
                        .draw_series(data.iter().map(|&p| Cross::new(p, 5, c.stroke_width(2))))
                        .map_err(err)?;
                }
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(err)?;
        Ok(())
    }
}

/// Panels on a grid, row by row, `.1` columns.
struct Panels<'a>(&'a [Plot], usize);

impl Panels<'_> {
    fn shape(&self) -> (usize, usize) {
        let cols = self.1.clamp(1, self.0.len().max(1));
        (self.0.len().div_ceil(cols).max(1), cols)
    }
}

impl Figure for Panels<'_> {
    fn size(&self) -> (u32, u32) {
        let (rows, cols) = self.shape();
        (PANEL.0 * cols as u32, PANEL.1 * rows as u32)
    }

    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), ChartError> {
        root.fill(&WHITE).map_err(err)?;
        let areas = root.split_evenly(self.shape());
        for (plot, area) in self.0.iter().zip(&areas) {
            plot.draw_on(area)?;
        }
        root.present().map_err(err)
    }
}

/// One or more line/scatter panels side by side, e.g. kappa against
/// roughness (log-log) or PSNR against wall time (log x).
pub(crate) fn panels(plots: &[Plot]) -> Result<Chart, ChartError> {
    render(&Panels(plots, plots.len()))
}

/// Panels on a grid of `cols` columns, filled row by row.
pub(crate) fn panel_grid(plots: &[Plot], cols: usize) -> Result<Chart, ChartError> {
    render(&Panels(plots, cols))
}

/// A log-log line chart with one circle-marked line per series.
pub(crate) fn log_lines(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: Vec<Series>,
) -> Result<Chart, ChartError> {
    panels(&[Plot {
        title: title.into(),
        x_label: x_label.into(),
        y_label: y_label.into(),
        x_log: true,
        y_log: true,
        x_integer: false,
        series,
    }])
}

/// Grouped bars on a log axis.
struct Bars<'a> {
    title: &'a str,
    y_label: &'a str,
    series: &'a [&'a str],
    groups: &'a [(String, Vec<f64>)],
}

impl Figure for Bars<'_> {
    fn size(&self) -> (u32, u32) {
        PANEL
    }

    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), ChartError> {
        root.fill(&WHITE).map_err(err)?;
        let width = (self.series.len() + 1) as f64;
        let finite = |v: f64| v.is_finite() && v > 0.0;
        let top = self
            .groups
            .iter()
            .flat_map(|g| g.1.iter().copied())
            .filter(|v| finite(*v))
            .fold(1.0, f64::max);
        let mut chart = ChartBuilder::on(&root)
            .caption(self.title, ("sans-serif", 24))
            .margin(16)
            .x_label_area_size(20)
            .y_label_area_size(80)
            .build_cartesian_2d(
                -1.0..width * self.groups.len() as f64 - 1.0,
                (1.0..top * 30.0).log_scale(),
            )
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_desc(self.y_label)
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 16))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(err)?;
        for (k, name) in self.series.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let rects: Vec<Rectangle<(f64, f64)>> = self
                .groups
                .iter()
                .enumerate()
                .filter_map(|(g, (_, vals))| {
                    let v = *vals.get(k)?;
                    let x = g as f64 * width + k as f64;
                    finite(v).then(|| Rectangle::new([(x - 0.4, 1.0), (x + 0.4, v)], c.filled()))
                })
                .collect();
            chart
                .draw_series(rects)
                .map_err(err)?
                .label(name.to_string())
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], c.filled()));
        }
        for (g, (label, _)) in self.groups.iter().enumerate() {
            let x = g as f64 * width - 0.4;
            chart
                .draw_series(std::iter::once(Text::new(
                    label.clone(),
                    (x, top * 8.0),
                    ("sans-serif", 15),
                )))
                .map_err(err)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .position(SeriesLabelPosition::MiddleRight)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)
    }
}

/// Grouped bars on a log axis: one colour per series (e.g. polarizer
/// configuration), one group per setting (e.g. grid and occluder), the group
/// name written above it. Non-finite values (an infinite kappa) draw no bar.
pub(crate) fn log_bars(
    title: &str,
    y_label: &str,
    series: &[&str],
    groups: &[(String, Vec<f64>)],
) -> Result<Chart, ChartError> {
    render(&Bars {
        title,
        y_label,
        series,
        groups,
    })
}

/// Indices of the points on the Pareto front of "less time, more quality":
/// a point is kept when no other point is at least as fast and strictly
/// better, or strictly faster and at least as good. Sorted by time.
pub(crate) fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len())
        .filter(|&k| points[k].0.is_finite() && points[k].1.is_finite())
        .collect();
    idx.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[b].1.total_cmp(&points[a].1))
    });
    let mut best = f64::NEG_INFINITY;
    idx.into_iter()
        .filter(|&k| {
            let keep = points[k].1 > best;
            if keep {
                best = points[k].1;
            }
            keep
        })
        .collect()
}

/// An axis label numbering the categories a chart's integer x stands for:
/// `case: 1 nopol, 2 rotating`.
pub(crate) fn numbered<'a>(what: &str, names: impl Iterator<Item = &'a str>) -> String {
    let names: Vec<String> = names
        .enumerate()
        .map(|(k, n)| format!("{} {n}", k + 1))
        .collect();
    format!("{what}: {}", names.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let p = [
            (1.0, 10.0),
            (2.0, 9.0),
            (3.0, 12.0),
            (0.5, 5.0),
            (3.0, 11.0),
        ];
        assert_eq!(pareto_front(&p), vec![3, 0, 2]);
    }

    #[test]
    fn log_labels_only_at_one_two_five() {
        assert_eq!(label(-2.0, true, false), "0.01");
        assert_eq!(label(2f64.log10() - 4.0, true, true), "2e-4");
        assert_eq!(label(5f64.log10(), true, false), "5");
        assert_eq!(label(-3.4, true, true), "");
        assert_eq!(label(2.5, false, false), "2.5");
        assert_eq!(label(6.0, true, true), "1e6");
        assert_eq!(label(0.5, true, false), "");
        // One axis, one format: 5000 and 10000 on an axis that reaches 1e5
        // read 5e3 and 1e4, not 5000 next to 1e4.
        assert!(needs_sci(3.0, 5.0) && !needs_sci(-2.0, 3.9));
        assert_eq!(label(5000f64.log10(), true, true), "5e3");
        assert_eq!(label(4.0 - 1e-9, true, true), "1e4");
        assert_eq!(label(5000f64.log10(), true, false), "5000");
    }

    #[test]
    fn an_integer_axis_labels_whole_numbers_only() {
        assert_eq!(integer_label(3.0), "3");
        assert_eq!(integer_label(2.5), "");
        assert_eq!(integer_label(4.0000001), "4");
    }

    #[test]
    fn a_chart_renders_as_png_and_svg() {
        let c = panels(&[Plot {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            x_log: true,
            y_log: false,
            x_integer: false,
            series: vec![Series::line(
                "a",
                0,
                vec![(0.1, 1.0), (1.0, 2.0), (-1.0, 3.0)],
            )],
        }])
        .unwrap();
        assert_eq!(&c.png[1..4], b"PNG");
        assert!(c.svg.contains("<svg"));
        let none = Plot {
            title: "empty".into(),
            x_label: String::new(),
            y_label: String::new(),
            x_log: true,
            y_log: true,
            x_integer: false,
            series: vec![Series::line("a", 0, vec![(0.0, -1.0)])],
        };
        assert!(panels(&[none])
            .unwrap_err()
            .to_string()
            .contains("no finite value"));
    }
}
