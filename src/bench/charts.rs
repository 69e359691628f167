//! Charts for the bench reports, drawn with plotters into PNG and SVG, with
//! DejaVuSans embedded so no system font (fontconfig/freetype) is needed.

use plotters::coord::Shift;
use plotters::prelude::*;

static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// A chart rendered both ways.
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

const SIZE: (u32, u32) = (900, 560);
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// One named series of (x, y) points.
pub struct Series {
    /// Legend label.
    pub name: String,
    /// Points; y must be positive for the log axis (others are skipped).
    pub points: Vec<(f64, f64)>,
}

fn render(
    draw: impl Fn(DrawingArea<BitMapBackend<'_>, Shift>) -> Result<(), ChartError>,
    draw_svg: impl Fn(DrawingArea<SVGBackend<'_>, Shift>) -> Result<(), ChartError>,
) -> Result<Chart, ChartError> {
    font()?;
    let mut rgb = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, SIZE).into_drawing_area();
        draw(root)?;
    }
    let img = image::RgbImage::from_raw(SIZE.0, SIZE.1, rgb)
        .ok_or_else(|| ChartError("buffer size".into()))?;
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .map_err(err)?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        draw_svg(root)?;
    }
    Ok(Chart {
        png: png.into_inner(),
        svg,
    })
}

macro_rules! log_lines {
    ($root:expr, $title:expr, $xlabel:expr, $ylabel:expr, $series:expr, $xlog:expr) => {{
        let root = $root;
        root.fill(&WHITE).map_err(err)?;
        let pts = $series
            .iter()
            .flat_map(|s: &Series| s.points.iter().copied())
            .filter(|p| p.1 > 0.0 && p.1.is_finite());
        let (mut x0, mut x1, mut y0, mut y1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for (x, y) in pts {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
        if !x0.is_finite() {
            return Err(ChartError("no finite positive value to plot".into()));
        }
        let mut chart = ChartBuilder::on(&root)
            .caption($title, ("sans-serif", 24))
            .margin(16)
            .x_label_area_size(48)
            .y_label_area_size(80)
            .build_cartesian_2d(
                (x0 * 0.9..x1 * 1.1).log_scale(),
                (y0 / 2.0..y1 * 2.0).log_scale(),
            )
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc($xlabel)
            .y_desc($ylabel)
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 16))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .x_label_formatter(&|v| format!("{v:.2}"))
            .x_labels(8)
            .draw()
            .map_err(err)?;
        for (k, s) in $series.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let style = if s.name.contains("occluder") {
                c.stroke_width(2)
            } else {
                c.stroke_width(3)
            };
            let data: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(|p| p.1 > 0.0 && p.1.is_finite())
                .collect();
            chart
                .draw_series(LineSeries::new(data.clone(), style))
                .map_err(err)?
                .label(s.name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(3))
                });
            chart
                .draw_series(data.iter().map(|&p| Circle::new(p, 4, c.filled())))
                .map_err(err)?;
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .position(SeriesLabelPosition::UpperLeft)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
        let _ = $xlog;
        Ok(())
    }};
}

/// A log-log line chart (e.g. kappa against roughness).
pub fn log_lines(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<Chart, ChartError> {
    render(
        |root| log_lines!(root, title, x_label, y_label, series, true),
        |root| log_lines!(root, title, x_label, y_label, series, true),
    )
}

macro_rules! bars {
    ($root:expr, $title:expr, $ylabel:expr, $series:expr, $groups:expr) => {{
        let root = $root;
        root.fill(&WHITE).map_err(err)?;
        let k_series = $series.len();
        let width = (k_series + 1) as f64;
        let finite = |v: f64| v.is_finite() && v > 0.0;
        let top = $groups
            .iter()
            .flat_map(|g: &(String, Vec<f64>)| g.1.iter().copied())
            .filter(|v| finite(*v))
            .fold(1.0, f64::max);
        let mut chart = ChartBuilder::on(&root)
            .caption($title, ("sans-serif", 24))
            .margin(16)
            .x_label_area_size(20)
            .y_label_area_size(80)
            .build_cartesian_2d(
                -1.0..width * $groups.len() as f64 - 1.0,
                (1.0..top * 30.0).log_scale(),
            )
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_desc($ylabel)
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 16))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(err)?;
        for (k, name) in $series.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let rects: Vec<Rectangle<(f64, f64)>> = $groups
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
        for (g, (label, _)) in $groups.iter().enumerate() {
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
        root.present().map_err(err)?;
        Ok(())
    }};
}

/// Grouped bars on a log axis: one colour per series (e.g. polarizer
/// configuration), one group per setting (e.g. grid and occluder), the group
/// name written above it. Non-finite values (an infinite kappa) draw no bar.
pub fn log_bars(
    title: &str,
    y_label: &str,
    series: &[&str],
    groups: &[(String, Vec<f64>)],
) -> Result<Chart, ChartError> {
    render(
        |root| bars!(root, title, y_label, series, groups),
        |root| bars!(root, title, y_label, series, groups),
    )
}
