//! Figures drawn with plotters, each written as PNG (bitmap backend) and SVG: ROC curves of one
//! cell (one line per method, the paper's fig:roc / fig:roc2), F1 against attack amplitude, a
//! detector statistic over time with the attack intervals shaded and the threshold drawn (the
//! CUSUM post-attack false-alarm plot, the paper's fig:CUSUM_3_plots), and a top view of a flight
//! (reference, truth and estimate in the world ENU x–y plane, metres, attacked stretch marked).
//!
//! Inputs are plain slices, so this module knows no detector, dataset or runner type. Text is
//! set in DejaVu Sans, embedded from the `dejavu` crate and registered with plotters' ab_glyph
//! renderer, so no system font is needed (docs/decisions/062-plot-font.md). Every file is
//! written to a temporary file in the target directory and renamed into place.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::io::{IoError, write_path_atomic, write_text_atomic};
use crate::metrics::{MeanStd, RocCurve};

/// Pixel size of every figure.
const SIZE: (u32, u32) = (900, 640);

/// Font family name under which the embedded font is registered.
const FONT: &str = "sans-serif";

/// Line colours (the "tab10" palette), cycled per series.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// A figure could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// The embedded font could not be registered.
    #[error("cannot register the embedded plot font")]
    Font,
    /// The input cannot be plotted.
    #[error("{figure}: {msg}")]
    Data {
        /// Which figure.
        figure: &'static str,
        /// What is wrong with the input.
        msg: String,
    },
    /// plotters failed while drawing or encoding.
    #[error("{}: drawing failed: {msg}", path.display())]
    Draw {
        /// The output file.
        path: PathBuf,
        /// The backend's message.
        msg: String,
    },
    /// Writing the file failed.
    #[error(transparent)]
    Io(#[from] IoError),
}

/// Result alias of this module.
pub type Result<T, E = PlotError> = std::result::Result<T, E>;

/// Registers the embedded DejaVu Sans once per process.
fn ensure_font() -> Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
            && plotters::style::register_font(FONT, FontStyle::Bold, dejavu::sans::bold()).is_ok()
    });
    if ok { Ok(()) } else { Err(PlotError::Font) }
}

/// Something that can draw itself on any plotters backend.
trait Figure {
    /// Figure name used in error messages.
    const NAME: &'static str;
    /// Draws on `root` (already filled white).
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> std::result::Result<(), String>;
}

/// Writes `fig` to `<out_stem>.png` and `<out_stem>.svg`, each atomically; returns both paths.
fn write_figure<F: Figure>(out_stem: &Path, fig: &F) -> Result<Vec<PathBuf>> {
    ensure_font()?;
    let png = out_stem.with_extension("png");
    let svg = out_stem.with_extension("svg");
    // PNG: the bitmap backend picks the encoder from the extension, so the temporary file
    // keeps `.png`; it is renamed over the final name only after a successful encode.
    write_path_atomic(&png, ".png", |tmp| -> Result<()> {
        let draw_err = |msg: String| PlotError::Draw { path: png.clone(), msg };
        let root = BitMapBackend::new(tmp, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_err(e.to_string()))?;
        fig.draw(&root).map_err(draw_err)?;
        root.present().map_err(|e| draw_err(e.to_string()))
    })?;

    let mut text = String::new();
    {
        let draw_err = |msg: String| PlotError::Draw { path: svg.clone(), msg };
        let root = SVGBackend::with_string(&mut text, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_err(e.to_string()))?;
        fig.draw(&root).map_err(draw_err)?;
        root.present().map_err(|e| draw_err(e.to_string()))?;
    }
    write_text_atomic(&svg, &text)?;
    Ok(vec![png, svg])
}

fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// `lo..hi` padded by `frac` of its width (or ±0.5 when degenerate).
fn padded(lo: f64, hi: f64, frac: f64) -> Range<f64> {
    let w = hi - lo;
    if w > 0.0 { (lo - frac * w)..(hi + frac * w) } else { (lo - 0.5)..(hi + 0.5) }
}

fn finite_range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values.into_iter().filter(|v| v.is_finite()).fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// Shades the attack intervals `[a, b)` across the plot's height `y`, with one legend entry.
fn shade_attacks<DB: DrawingBackend>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    attacks: &[(f64, f64)],
    y: &Range<f64>,
) -> std::result::Result<(), String> {
    let red = RGBColor(214, 39, 40);
    for (i, &(a, b)) in attacks.iter().enumerate() {
        let series = chart
            .draw_series(std::iter::once(Rectangle::new([(a, y.start), (b, y.end)], red.mix(0.15).filled())))
            .map_err(|e| e.to_string())?;
        if i == 0 {
            series
                .label("attack interval")
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], red.mix(0.3).filled()));
        }
    }
    Ok(())
}

fn legend_line(c: RGBColor) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
}

// ---------------------------------------------------------------------------------------------
// ROC curves.

/// ROC curves of one cell, one line per method, with AUC in the legend.
struct RocFigure<'a> {
    title: &'a str,
    curves: &'a [(&'a str, &'a RocCurve)],
}

/// Thins a curve to points at least `eps` apart in either coordinate (first and last kept),
/// so that SVG files stay small for curves with thousands of distinct scores.
fn thin(points: impl Iterator<Item = (f64, f64)>, eps: f64) -> Vec<(f64, f64)> {
    let all: Vec<(f64, f64)> = points.collect();
    let mut out: Vec<(f64, f64)> = Vec::new();
    for (i, &p) in all.iter().enumerate() {
        let keep = match out.last() {
            None => true,
            Some(&(x, y)) => i + 1 == all.len() || (p.0 - x).abs() >= eps || (p.1 - y).abs() >= eps,
        };
        if keep {
            out.push(p);
        }
    }
    out
}

impl Figure for RocFigure<'_> {
    const NAME: &'static str = "ROC plot";

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> std::result::Result<(), String> {
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(0f64..1f64, 0f64..1.0f64)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("False-positive rate")
            .y_desc("True-positive rate")
            .label_style((FONT, 15))
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(LineSeries::new([(0.0, 0.0), (1.0, 1.0)], BLACK.mix(0.3)))
            .map_err(|e| e.to_string())?
            .label("chance (AUC 0.5)")
            .legend(legend_line(RGBColor(180, 180, 180)));
        for (i, (label, roc)) in self.curves.iter().enumerate() {
            let c = colour(i);
            let pts = thin(roc.points().iter().map(|p| (p.fpr, p.tpr)), 1e-3);
            chart
                .draw_series(LineSeries::new(pts, c.stroke_width(2)))
                .map_err(|e| e.to_string())?
                .label(format!("{label} (AUC {:.3})", roc.auc()))
                .legend(legend_line(c));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FONT, 15))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())
    }
}

/// ROC curves of one cell, one line per `(method, curve)`, to `<out_stem>.png` and `.svg`.
///
/// # Errors
/// [`PlotError::Data`] when `curves` is empty; [`PlotError::Draw`] or [`PlotError::Io`] when
/// drawing or writing fails.
pub fn roc_plot(out_stem: &Path, title: &str, curves: &[(&str, &RocCurve)]) -> Result<Vec<PathBuf>> {
    if curves.is_empty() {
        return Err(PlotError::Data { figure: RocFigure::NAME, msg: "no ROC curve to draw".into() });
    }
    write_figure(out_stem, &RocFigure { title, curves })
}

// ---------------------------------------------------------------------------------------------
// F1 against amplitude.

/// One method's F1 (mean ± std over seeds) at each attack amplitude.
#[derive(Debug, Clone, Copy)]
pub struct SweepSeries<'a> {
    /// Method name.
    pub label: &'a str,
    /// `(amplitude, F1)` points in increasing amplitude.
    pub points: &'a [(f64, MeanStd)],
}

struct SweepFigure<'a> {
    title: &'a str,
    x_desc: &'a str,
    series: &'a [SweepSeries<'a>],
    x: Range<f64>,
}

impl Figure for SweepFigure<'_> {
    const NAME: &'static str = "F1-versus-amplitude plot";

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> std::result::Result<(), String> {
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(self.x.clone(), 0f64..1.05f64)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc(self.x_desc)
            .y_desc("Per-step F1")
            .label_style((FONT, 15))
            .draw()
            .map_err(|e| e.to_string())?;
        for (i, s) in self.series.iter().enumerate() {
            let c = colour(i);
            chart
                .draw_series(LineSeries::new(s.points.iter().map(|(a, m)| (*a, m.mean)), c.stroke_width(2)))
                .map_err(|e| e.to_string())?
                .label(s.label)
                .legend(legend_line(c));
            chart
                .draw_series(s.points.iter().map(|(a, m)| Circle::new((*a, m.mean), 4, c.filled())))
                .map_err(|e| e.to_string())?;
            // Error bars: mean ± sample std over seeds.
            chart
                .draw_series(s.points.iter().filter_map(|(a, m)| {
                    m.std.map(|sd| PathElement::new(vec![(*a, m.mean - sd), (*a, m.mean + sd)], c.stroke_width(1)))
                }))
                .map_err(|e| e.to_string())?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FONT, 15))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())
    }
}

/// F1 against attack amplitude, one line per method with ± std error bars, to
/// `<out_stem>.png` and `.svg`. `x_desc` names the amplitude axis and its unit, e.g.
/// "Attack amplitude (GPS σ)".
///
/// # Errors
/// [`PlotError::Data`] when there is no finite point; [`PlotError::Draw`] or
/// [`PlotError::Io`] when drawing or writing fails.
pub fn f1_amplitude_plot(
    out_stem: &Path,
    title: &str,
    x_desc: &str,
    series: &[SweepSeries<'_>],
) -> Result<Vec<PathBuf>> {
    let Some((lo, hi)) = finite_range(series.iter().flat_map(|s| s.points.iter().map(|p| p.0))) else {
        return Err(PlotError::Data { figure: SweepFigure::NAME, msg: "no finite amplitude to draw".into() });
    };
    write_figure(out_stem, &SweepFigure { title, x_desc, series, x: padded(lo, hi, 0.03) })
}

// ---------------------------------------------------------------------------------------------
// Detector statistic over time.

/// A detector statistic over one flight, e.g. the CUSUM sum `g_k`.
#[derive(Debug, Clone, Copy)]
pub struct StatisticTrace<'a> {
    /// Time stamps in seconds.
    pub t: &'a [f64],
    /// The statistic at each time stamp.
    pub statistic: &'a [f64],
    /// The alarm threshold (drawn as a horizontal line).
    pub threshold: f64,
    /// Attack intervals `[start_s, end_s)` to shade.
    pub attacks: &'a [(f64, f64)],
    /// Per-step alarms, if any; alarmed steps are marked (false alarms after an attack show).
    pub alarms: Option<&'a [bool]>,
}

struct StatisticFigure<'a> {
    title: &'a str,
    y_desc: &'a str,
    trace: StatisticTrace<'a>,
    x: Range<f64>,
    y: Range<f64>,
}

impl Figure for StatisticFigure<'_> {
    const NAME: &'static str = "statistic plot";

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> std::result::Result<(), String> {
        let tr = &self.trace;
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(65)
            .build_cartesian_2d(self.x.clone(), self.y.clone())
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("Time (s)")
            .y_desc(self.y_desc)
            .label_style((FONT, 15))
            .draw()
            .map_err(|e| e.to_string())?;
        shade_attacks(&mut chart, tr.attacks, &self.y)?;
        let c = colour(0);
        chart
            .draw_series(LineSeries::new(tr.t.iter().copied().zip(tr.statistic.iter().copied()), c.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label("statistic")
            .legend(legend_line(c));
        let th = RGBColor(0, 0, 0);
        chart
            .draw_series(DashedLineSeries::new(
                [(self.x.start, tr.threshold), (self.x.end, tr.threshold)],
                10,
                6,
                th.stroke_width(1),
            ))
            .map_err(|e| e.to_string())?
            .label(format!("threshold {:.3}", tr.threshold))
            .legend(legend_line(th));
        if let Some(alarms) = tr.alarms {
            let red = RGBColor(214, 39, 40);
            let marks = tr.t.iter().zip(tr.statistic).zip(alarms).filter(|(_, a)| **a).map(|((t, s), _)| (*t, *s));
            chart
                .draw_series(marks.map(|p| Circle::new(p, 2, red.filled())))
                .map_err(|e| e.to_string())?
                .label("alarm")
                .legend(move |(x, y)| Circle::new((x + 10, y), 3, red.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font((FONT, 15))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())
    }
}

/// A detector statistic over time with attack intervals shaded, the threshold dashed and
/// alarms marked (the paper's CUSUM post-attack plot), to `<out_stem>.png` and `.svg`.
///
/// # Errors
/// [`PlotError::Data`] when `t` and `statistic` (or `alarms`) differ in length or hold no
/// finite point; [`PlotError::Draw`] or [`PlotError::Io`] when drawing or writing fails.
pub fn statistic_plot(out_stem: &Path, title: &str, y_desc: &str, trace: StatisticTrace<'_>) -> Result<Vec<PathBuf>> {
    let data = |msg: String| PlotError::Data { figure: StatisticFigure::NAME, msg };
    if trace.t.len() != trace.statistic.len() {
        return Err(data(format!("{} time stamps but {} statistic values", trace.t.len(), trace.statistic.len())));
    }
    if let Some(a) = trace.alarms
        && a.len() != trace.t.len()
    {
        return Err(data(format!("{} time stamps but {} alarms", trace.t.len(), a.len())));
    }
    let (Some((t0, t1)), Some((s0, s1))) =
        (finite_range(trace.t.iter().copied()), finite_range(trace.statistic.iter().copied()))
    else {
        return Err(data("no finite point to draw".into()));
    };
    let th = if trace.threshold.is_finite() { trace.threshold } else { s1 };
    let y = padded(s0.min(th).min(0.0), s1.max(th), 0.05);
    write_figure(out_stem, &StatisticFigure { title, y_desc, trace, x: t0..t1, y })
}

// ---------------------------------------------------------------------------------------------
// Position error over time, one line per detector.

/// One detector's position error over one flight.
#[derive(Debug, Clone, Copy)]
pub struct ErrorSeries<'a> {
    /// Detector name.
    pub label: &'a str,
    /// `(time s, error m)` points in time order.
    pub points: &'a [(f64, f64)],
}

struct ErrorFigure<'a> {
    title: &'a str,
    series: &'a [ErrorSeries<'a>],
    attacks: &'a [(f64, f64)],
    x: Range<f64>,
    y: Range<f64>,
}

impl Figure for ErrorFigure<'_> {
    const NAME: &'static str = "position-error plot";

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> std::result::Result<(), String> {
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(65)
            .build_cartesian_2d(self.x.clone(), self.y.clone())
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("Time (s)")
            .y_desc("Position error |p_hat - p| (m)")
            .label_style((FONT, 15))
            .draw()
            .map_err(|e| e.to_string())?;
        shade_attacks(&mut chart, self.attacks, &self.y)?;
        for (i, s) in self.series.iter().enumerate() {
            let c = colour(i);
            let clipped = s.points.iter().map(|&(t, e)| (t, e.min(self.y.end)));
            chart
                .draw_series(LineSeries::new(clipped, c.stroke_width(2)))
                .map_err(|e| e.to_string())?
                .label(s.label)
                .legend(legend_line(c));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font((FONT, 15))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())
    }
}

/// Position error over time, one line per detector, attack intervals shaded, to
/// `<out_stem>.png` and `.svg`. Errors above `y_max_m` are drawn at `y_max_m`, so one runaway
/// estimate does not flatten the others.
///
/// # Errors
/// [`PlotError::Data`] when there is no finite point; [`PlotError::Draw`] or
/// [`PlotError::Io`] when drawing or writing fails.
pub fn error_time_plot(
    out_stem: &Path,
    title: &str,
    series: &[ErrorSeries<'_>],
    attacks: &[(f64, f64)],
    y_max_m: f64,
) -> Result<Vec<PathBuf>> {
    let pts = || series.iter().flat_map(|s| s.points.iter());
    let (Some((t0, t1)), Some((_, e1))) = (finite_range(pts().map(|p| p.0)), finite_range(pts().map(|p| p.1))) else {
        return Err(PlotError::Data { figure: ErrorFigure::NAME, msg: "no finite point to draw".into() });
    };
    let top = if y_max_m.is_finite() && y_max_m > 0.0 { e1.min(y_max_m) } else { e1 };
    write_figure(out_stem, &ErrorFigure { title, series, attacks, x: t0..t1, y: 0.0..(top * 1.05).max(0.1) })
}

// ---------------------------------------------------------------------------------------------
// Flight top view.

/// Horizontal tracks of one flight in the world ENU frame, metres.
#[derive(Debug, Clone, Copy)]
pub struct TopView<'a> {
    /// Reference trajectory `(x_east, y_north)`.
    pub reference: &'a [(f64, f64)],
    /// True positions.
    pub truth: &'a [(f64, f64)],
    /// Estimated positions.
    pub estimate: &'a [(f64, f64)],
    /// Per estimate point: `true` while an attack is active (drawn thick red).
    pub attacked: &'a [bool],
}

struct TopViewFigure<'a> {
    title: &'a str,
    view: TopView<'a>,
    x: Range<f64>,
    y: Range<f64>,
}

impl Figure for TopViewFigure<'_> {
    const NAME: &'static str = "top-view plot";

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> std::result::Result<(), String> {
        let v = &self.view;
        let mut chart = ChartBuilder::on(root)
            .caption(self.title, (FONT, 24))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(self.x.clone(), self.y.clone())
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("East x (m)")
            .y_desc("North y (m)")
            .label_style((FONT, 15))
            .draw()
            .map_err(|e| e.to_string())?;
        let grey = RGBColor(127, 127, 127);
        chart
            .draw_series(DashedLineSeries::new(v.reference.iter().copied(), 8, 5, grey.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label("reference")
            .legend(legend_line(grey));
        chart
            .draw_series(LineSeries::new(v.truth.iter().copied(), BLACK.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label("truth")
            .legend(legend_line(BLACK));
        let blue = colour(0);
        chart
            .draw_series(LineSeries::new(v.estimate.iter().copied(), blue.stroke_width(1)))
            .map_err(|e| e.to_string())?
            .label("estimate")
            .legend(legend_line(blue));
        let red = RGBColor(214, 39, 40);
        let mut labelled = false;
        let mut k = 0;
        while k < v.estimate.len() {
            if !v.attacked[k] {
                k += 1;
                continue;
            }
            let start = k;
            while k < v.estimate.len() && v.attacked[k] {
                k += 1;
            }
            let series = chart
                .draw_series(LineSeries::new(v.estimate[start..k].iter().copied(), red.stroke_width(4)))
                .map_err(|e| e.to_string())?;
            if !labelled {
                series
                    .label("estimate under attack")
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], red.stroke_width(4)));
                labelled = true;
            }
        }
        if let Some(&p0) = v.truth.first() {
            chart
                .draw_series(std::iter::once(TriangleMarker::new(p0, 7, BLACK.filled())))
                .map_err(|e| e.to_string())?
                .label("start")
                .legend(|(x, y)| TriangleMarker::new((x + 10, y), 5, BLACK.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font((FONT, 15))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())
    }
}

/// Top view of one flight (reference dashed, truth, estimate, attacked stretch of the
/// estimate thick red), to `<out_stem>.png` and `.svg`. Each axis spans its data padded by 5%;
/// equal scaling of the two axes is not enforced.
///
/// # Errors
/// [`PlotError::Data`] when `attacked` and `estimate` differ in length or no point is finite;
/// [`PlotError::Draw`] or [`PlotError::Io`] when drawing or writing fails.
pub fn top_view_plot(out_stem: &Path, title: &str, view: TopView<'_>) -> Result<Vec<PathBuf>> {
    let data = |msg: String| PlotError::Data { figure: TopViewFigure::NAME, msg };
    if view.attacked.len() != view.estimate.len() {
        return Err(data(format!("{} estimate points but {} attack flags", view.estimate.len(), view.attacked.len())));
    }
    let all = || view.reference.iter().chain(view.truth).chain(view.estimate);
    let (Some((x0, x1)), Some((y0, y1))) = (finite_range(all().map(|p| p.0)), finite_range(all().map(|p| p.1))) else {
        return Err(data("no finite point to draw".into()));
    };
    write_figure(out_stem, &TopViewFigure { title, view, x: padded(x0, x1, 0.05), y: padded(y0, y1, 0.05) })
}
