//! The figure of a run, after the paper's Fig. 4: the end-effector paths of every execution of a
//! way-point set in three projections (x-y, x-z, y-z), and the error at each conditioning point
//! converging over the executions.
//!
//! [`render`] is pure: it takes the data ([`plot_data`] fills it from a recording's messages) and
//! writes one image, PNG or SVG. Text is set in DejaVu Sans, shipped in `clients/record/assets/`
//! and embedded in the binary, so no system font library is needed.

use std::path::Path;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{Context, Result, anyhow, bail};
use plotters::coord::Shift;
use plotters::coord::types::{RangedCoordf64, RangedCoordi64};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use serde_json::Value;

use crate::record::{self, Message, stats_of};

/// One execution of a way-point set as the recording saw it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Execution {
    /// 1-based.
    pub number: u32,
    /// End-effector positions (m, base frame: x, y, z) during the execution, in time order.
    pub path: Vec<[f64; 3]>,
    /// Per conditioning point, where the end effector was at its time (None if not recorded).
    pub reached: Vec<Option<[f64; 3]>>,
    /// Per conditioning point, the error (m); may be empty if stats are missing.
    pub errors_m: Vec<f64>,
}

/// Everything one figure shows.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlotData {
    pub title: String,
    /// The set's desired positions (m).
    pub waypoints: Vec<[f64; 3]>,
    /// In order.
    pub executions: Vec<Execution>,
}

/// The pixel size used (width, height).
pub const SIZE: (u32, u32) = (1800, 1200);

/// The family every text is set in; the embedded font is registered under it.
const FAMILY: &str = "sans-serif";
static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

/// Height of the title strip at the top.
const TITLE_H: u32 = 64;
/// Height of the row of the three projections, below the title strip; the convergence plot
/// takes the rest.
const TOP_H: u32 = 560;

const TITLE_PX: u32 = 32;
const CAPTION_PX: u32 = 26;
const DESC_PX: u32 = 24;
const LABEL_PX: u32 = 20;
const LEGEND_PX: u32 = 21;
const NUMBER_PX: u32 = 24;
const NOTE_PX: u32 = 28;

/// The convergence legend names each conditioning point up to this many points; beyond, only
/// the mean is named.
const MAX_NAMED_POINTS: usize = 12;

/// The projections of the top row: indices of the horizontal and vertical axes.
const PROJECTIONS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];
const AXES: [&str; 3] = ["x", "y", "z"];

/// Lines of the conditioning points in the convergence plot (matplotlib's tab10).
const POINT_COLOURS: [RGBColor; 10] = [
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

/// Renders the paper's Fig. 4 view to `out`: PNG when the extension is `.png` or missing, SVG
/// when it is `.svg` (either in any case); any other extension is an error. The PNG is written
/// to a temporary file beside `out` and renamed over it, so a viewer never sees half a file.
///
/// Errors (bad extension, unwritable path, nothing to plot) name `out`.
pub fn render(data: &PlotData, out: &Path) -> Result<()> {
    check_output(out)?;
    let format = format_of(out)?;
    let scene = Scene::new(data);
    if scene.is_empty() {
        bail!(
            "nothing to plot to {}: {:?} has no finite way-point, path point, reached point or \
             error",
            out.display(),
            data.title
        );
    }
    match format {
        Format::Png => {
            let rgb = draw_rgb(&scene)
                .with_context(|| format!("drawing the plot for {}", out.display()))?;
            write_png(&rgb, out)
        }
        Format::Svg => {
            let svg = draw_svg(&scene)
                .with_context(|| format!("drawing the plot for {}", out.display()))?;
            softarm_runtime::file::write_atomic(out, svg.as_bytes(), None)
                .with_context(|| format!("writing the SVG plot to {}", out.display()))
        }
    }
}

/// Refuses, before any work, an output [`render`] could not write: an extension other than
/// `.png` or `.svg`, a directory, a folder that is not there.
pub fn check_output(out: &Path) -> Result<()> {
    format_of(out)?;
    crate::check_output_path(out, "the plot")
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Png,
    Svg,
}

fn format_of(out: &Path) -> Result<Format> {
    let Some(ext) = out.extension() else {
        return Ok(Format::Png);
    };
    match ext.to_str().map(str::to_ascii_lowercase).as_deref() {
        Some("png") => Ok(Format::Png),
        Some("svg") => Ok(Format::Svg),
        _ => bail!(
            "cannot write the plot to {}: unsupported extension {:?} (use .png, the default, or \
             .svg)",
            out.display(),
            ext
        ),
    }
}

/// Registers the embedded font under [`FAMILY`], once per process.
fn ensure_font() -> Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FAMILY, FontStyle::Normal, FONT_BYTES).is_ok()
    });
    if ok {
        Ok(())
    } else {
        bail!("the embedded font (clients/record/assets/DejaVuSans.ttf) is not a usable font")
    }
}

/// Draws the figure into an RGB buffer of [`SIZE`] (row-major, 3 bytes a pixel).
fn draw_rgb(scene: &Scene) -> Result<Vec<u8>> {
    ensure_font()?;
    let mut buf = vec![255u8; SIZE.0 as usize * SIZE.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        draw(&root, scene).map_err(|e| anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    Ok(buf)
}

fn draw_svg(scene: &Scene) -> Result<String> {
    ensure_font()?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        draw(&root, scene).map_err(|e| anyhow!("{e}"))?;
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    Ok(svg)
}

/// Encodes `rgb` as PNG to a temporary file beside `out`, then renames it over `out`.
fn write_png(rgb: &[u8], out: &Path) -> Result<()> {
    static SEQ: AtomicU64 = AtomicU64::new(0);
    let name = out
        .file_name()
        .ok_or_else(|| anyhow!("cannot write the plot to {}: no file name", out.display()))?;
    let tmp = out.with_file_name(format!(
        ".{}.{}-{}.tmp.png",
        name.to_string_lossy(),
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    ));
    let written = (|| -> Result<()> {
        let mut backend = BitMapBackend::new(&tmp, SIZE);
        backend
            .blit_bitmap((0, 0), SIZE, rgb)
            .map_err(|e| anyhow!("{e}"))?;
        backend.present().map_err(|e| anyhow!("{e}"))?;
        Ok(())
    })()
    .and_then(|()| std::fs::rename(&tmp, out).map_err(Into::into));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.with_context(|| format!("writing the PNG plot to {}", out.display()))
}

/// The data as drawn: in mm, non-finite values dropped.
struct Scene<'a> {
    title: &'a str,
    /// (1-based number, position).
    waypoints: Vec<(usize, [f64; 3])>,
    executions: Vec<ExecutionView>,
    /// The most conditioning points any execution has errors for.
    n_points: usize,
}

struct ExecutionView {
    number: u32,
    /// The path split where it has non-finite points.
    runs: Vec<Vec<[f64; 3]>>,
    reached: Vec<[f64; 3]>,
    /// Per conditioning point, the error (mm) if finite.
    errors: Vec<Option<f64>>,
}

impl<'a> Scene<'a> {
    fn new(data: &'a PlotData) -> Self {
        let waypoints = data
            .waypoints
            .iter()
            .enumerate()
            .filter_map(|(k, &p)| finite_mm(p).map(|p| (k + 1, p)))
            .collect();
        let executions: Vec<ExecutionView> = data
            .executions
            .iter()
            .map(|e| ExecutionView {
                number: e.number,
                runs: runs(e.path.iter().map(|&p| finite_mm(p))),
                reached: e
                    .reached
                    .iter()
                    .filter_map(|&p| p.and_then(finite_mm))
                    .collect(),
                errors: e
                    .errors_m
                    .iter()
                    .map(|&v| v.is_finite().then_some(v * 1e3))
                    .collect(),
            })
            .collect();
        let n_points = executions.iter().map(|e| e.errors.len()).max().unwrap_or(0);
        Self {
            title: &data.title,
            waypoints,
            executions,
            n_points,
        }
    }

    /// Every finite position drawn in the projections.
    fn positions(&self) -> impl Iterator<Item = [f64; 3]> + '_ {
        let waypoints = self.waypoints.iter().map(|&(_, p)| p);
        let executions = self
            .executions
            .iter()
            .flat_map(|e| e.runs.iter().flatten().chain(&e.reached).copied());
        waypoints.chain(executions)
    }

    fn has_errors(&self) -> bool {
        self.executions
            .iter()
            .any(|e| e.errors.iter().any(Option::is_some))
    }

    fn is_empty(&self) -> bool {
        self.positions().next().is_none() && !self.has_errors()
    }

    /// The mean error (mm) of execution `e` over its finite errors.
    fn mean_error(e: &ExecutionView) -> Option<f64> {
        let finite: Vec<f64> = e.errors.iter().flatten().copied().collect();
        (!finite.is_empty()).then(|| finite.iter().sum::<f64>() / finite.len() as f64)
    }
}

fn finite_mm(p: [f64; 3]) -> Option<[f64; 3]> {
    p.iter().all(|v| v.is_finite()).then(|| p.map(|v| v * 1e3))
}

/// Splits a sequence at its gaps (`None`s) into runs of present values.
fn runs<T>(items: impl IntoIterator<Item = Option<T>>) -> Vec<Vec<T>> {
    let mut runs = vec![];
    let mut current = vec![];
    for item in items {
        match item {
            Some(v) => current.push(v),
            None if !current.is_empty() => runs.push(std::mem::take(&mut current)),
            None => {}
        }
    }
    if !current.is_empty() {
        runs.push(current);
    }
    runs
}

/// The range of `values` widened to at least `min_span`, plus a 6 % margin each side; `None`
/// without values.
fn padded(values: impl IntoIterator<Item = f64>, min_span: f64) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc: Option<(f64, f64)>, v| {
            Some(acc.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))))
        })?;
    if hi - lo < min_span {
        let centre = 0.5 * (lo + hi);
        lo = centre - 0.5 * min_span;
        hi = centre + 0.5 * min_span;
    }
    let margin = 0.06 * (hi - lo);
    Some((lo - margin, hi + margin))
}

/// Widens the narrower of two ranges about its centre so that a unit spans as many pixels on
/// both axes of a plotting area of `pixels` (width, height).
fn equal_aspect(x: (f64, f64), y: (f64, f64), pixels: (u32, u32)) -> ((f64, f64), (f64, f64)) {
    let (w, h) = (f64::from(pixels.0.max(1)), f64::from(pixels.1.max(1)));
    let per_pixel = ((x.1 - x.0) / w).max((y.1 - y.0) / h);
    let widen = |(lo, hi): (f64, f64), px: f64| {
        let centre = 0.5 * (lo + hi);
        let half = 0.5 * per_pixel * px;
        (centre - half, centre + half)
    };
    (widen(x, w), widen(y, h))
}

/// Decimals for tick labels over a span (mm).
fn decimals(span: f64) -> usize {
    if span >= 20.0 {
        0
    } else if span >= 2.0 {
        1
    } else {
        2
    }
}

fn font(px: u32) -> TextStyle<'static> {
    (FAMILY, px).into_font().color(&BLACK)
}

/// The colour of execution `i` of `n`: pale and translucent early, deep and opaque late.
fn execution_colour(i: usize, n: usize) -> RGBAColor {
    let t = if n <= 1 {
        1.0
    } else {
        i as f64 / (n - 1) as f64
    };
    ramp(t)
}

fn ramp(t: f64) -> RGBAColor {
    let (faint, strong) = ([165.0, 190.0, 230.0], [8.0, 44.0, 140.0]);
    let c = |k: usize| (faint[k] + (strong[k] - faint[k]) * t).round() as u8;
    RGBColor(c(0), c(1), c(2)).mix(0.4 + 0.6 * t)
}

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, scene: &Scene) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let (title, body) = root.split_vertically(TITLE_H);
    let (top, bottom) = body.split_vertically(TOP_H);
    draw_title(&title, scene)?;
    for (area, &(a, b)) in top.split_evenly((1, 3)).iter().zip(&PROJECTIONS) {
        draw_projection(area, scene, a, b)?;
    }
    draw_convergence(&bottom, scene)
}

/// The title at the left, a key to the markers and execution colours at the right.
fn draw_title<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, scene: &Scene) -> DrawResult<DB> {
    let (w, h) = area.dim_in_pixel();
    let y = h as i32 / 2;
    let key_font = font(LEGEND_PX).pos(Pos::new(HPos::Left, VPos::Center));
    let text_w = |s: &str| area.estimate_text_size(s, &key_font).map(|(w, _)| w as i32);

    // The key, laid out from the right edge leftwards.
    let bar_w = 180;
    let mut x = w as i32 - 24;
    if let (Some(first), Some(last)) = (scene.executions.first(), scene.executions.last()) {
        // The colour ramp from the first execution to the last; one execution: its path's line.
        let (bar_w, cells, label) = if scene.executions.len() > 1 {
            let last_label = last.number.to_string();
            x -= text_w(&last_label)?;
            area.draw_text(&last_label, &key_font, (x, y))?;
            x -= 8;
            (bar_w, 36, format!("execution {}", first.number))
        } else {
            (40, 1, format!("path of execution {}", first.number))
        };
        x -= bar_w;
        for j in 0..cells {
            let t = if cells > 1 {
                j as f64 / (cells - 1) as f64
            } else {
                1.0
            };
            let (x0, x1) = (x + bar_w * j / cells, x + bar_w * (j + 1) / cells);
            let (y0, y1) = if cells > 1 {
                (y - 9, y + 9)
            } else {
                (y - 1, y + 2)
            };
            area.draw(&Rectangle::new([(x0, y0), (x1, y1)], ramp(t).filled()))?;
        }
        x -= 8 + text_w(&label)?;
        area.draw_text(&label, &key_font, (x, y))?;
        x -= 36;
        x -= text_w("reached")?;
        area.draw_text("reached", &key_font, (x, y))?;
        x -= 16;
        area.draw(&Circle::new((x, y), 6, ramp(1.0).filled()))?;
        x -= 36;
    }
    x -= text_w("way-point")?;
    area.draw_text("way-point", &key_font, (x, y))?;
    x -= 22;
    area.draw(&Circle::new((x, y), 11, BLACK.stroke_width(3)))?;
    area.draw(&Cross::new((x, y), 7, BLACK.stroke_width(3)))?;

    // The title, shortened with an ellipsis if it would run into the key.
    let title_font = font(TITLE_PX).pos(Pos::new(HPos::Left, VPos::Center));
    let room = (x - 24 - 40).max(0) as u32;
    let mut title = scene.title.to_string();
    while !title.is_empty() && area.estimate_text_size(&title, &title_font)?.0 > room {
        title.pop();
        while title.ends_with(' ') {
            title.pop();
        }
        if title.is_empty() {
            break;
        }
        title.pop();
        title.push('…');
    }
    area.draw_text(&title, &title_font, (24, y))
}

/// A centred note in an otherwise empty panel.
fn draw_note<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, note: &str) -> DrawResult<DB> {
    let (w, h) = area.dim_in_pixel();
    let style = font(NOTE_PX)
        .color(&RGBColor(110, 110, 110))
        .pos(Pos::new(HPos::Center, VPos::Center));
    area.draw_text(note, &style, (w as i32 / 2, h as i32 / 2))
}

fn projection_chart<'a, 'b, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
) -> ChartBuilder<'a, 'b, DB> {
    let mut builder = ChartBuilder::on(area);
    builder
        .margin_top(8)
        .margin_bottom(8)
        .margin_left(8)
        .margin_right(28)
        .x_label_area_size(64)
        .y_label_area_size(92);
    builder
}

/// One panel of the top row: the paths, reached points and way-points projected on axes `a`
/// (horizontal) and `b` (vertical), in mm, with equal scales.
fn draw_projection<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    scene: &Scene,
    a: usize,
    b: usize,
) -> DrawResult<DB> {
    let caption = format!("{}–{} projection", AXES[a], AXES[b]);
    let area = area.titled(&caption, font(CAPTION_PX))?;
    let (Some(xr), Some(yr)) = (
        padded(scene.positions().map(|p| p[a]), 10.0),
        padded(scene.positions().map(|p| p[b]), 10.0),
    ) else {
        return draw_note(&area, "no positions");
    };
    // Build once on a dummy range to learn the plotting area's size (nothing is drawn yet).
    let pixels = projection_chart(&area)
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)?
        .plotting_area()
        .dim_in_pixel();
    let (xr, yr) = equal_aspect(xr, yr, pixels);
    let mut chart = projection_chart(&area).build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    let (x_decimals, y_decimals) = (decimals(xr.1 - xr.0), decimals(yr.1 - yr.0));
    let x_fmt = move |v: &f64| format!("{v:.x_decimals$}");
    let y_fmt = move |v: &f64| format!("{v:.y_decimals$}");
    chart
        .configure_mesh()
        .x_desc(format!("{} (mm)", AXES[a]))
        .y_desc(format!("{} (mm)", AXES[b]))
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style(font(LABEL_PX))
        .axis_desc_style(font(DESC_PX))
        .max_light_lines(4)
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(242, 242, 242))
        .draw()?;

    let project = |p: &[f64; 3]| (p[a], p[b]);
    let n = scene.executions.len();
    for (i, e) in scene.executions.iter().enumerate() {
        let colour = execution_colour(i, n);
        let width = if i + 1 == n { 3 } else { 2 };
        for run in &e.runs {
            if let [only] = run.as_slice() {
                chart.draw_series(std::iter::once(Circle::new(
                    project(only),
                    2,
                    colour.filled(),
                )))?;
            } else {
                chart.draw_series(LineSeries::new(
                    run.iter().map(project),
                    colour.stroke_width(width),
                ))?;
            }
        }
    }
    for (i, e) in scene.executions.iter().enumerate() {
        let colour = execution_colour(i, n);
        chart.draw_series(
            e.reached
                .iter()
                .map(|p| Circle::new(project(p), 5, colour.filled())),
        )?;
    }
    chart.draw_series(scene.waypoints.iter().map(|(k, p)| {
        EmptyElement::at(project(p))
            + Circle::new((0, 0), 13, BLACK.stroke_width(3))
            + Cross::new((0, 0), 8, BLACK.stroke_width(3))
            + Text::new(
                k.to_string(),
                (14, -34),
                font(NUMBER_PX).pos(Pos::new(HPos::Left, VPos::Top)),
            )
    }))?;
    Ok(())
}

/// The bottom row: the error (mm) at each conditioning point over the executions, and their
/// mean.
fn draw_convergence<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    scene: &Scene,
) -> DrawResult<DB> {
    let area = area.titled(
        "Error at each conditioning point over the executions",
        font(CAPTION_PX),
    )?;
    if !scene.has_errors() {
        return draw_note(&area, "no statistics");
    }
    let numbers = || scene.executions.iter().map(|e| i64::from(e.number));
    let (first, last) = (numbers().min().unwrap_or(1), numbers().max().unwrap_or(1));
    let top = scene
        .executions
        .iter()
        .flat_map(|e| e.errors.iter().flatten())
        .fold(0.0f64, |m, &v| m.max(v));
    let bottom = scene
        .executions
        .iter()
        .flat_map(|e| e.errors.iter().flatten())
        .fold(0.0f64, |m, &v| m.min(v));
    let span = if top - bottom > 0.0 {
        top - bottom
    } else {
        1.0
    };

    let mut chart = ChartBuilder::on(&area)
        .margin_top(8)
        .margin_bottom(8)
        .margin_left(8)
        .margin_right(36)
        .x_label_area_size(64)
        .y_label_area_size(92)
        .build_cartesian_2d(
            (first - 1)..(last + 1),
            (bottom - 0.02 * span)..(bottom + 1.12 * span),
        )?;
    let y_decimals = decimals(span);
    let y_fmt = move |v: &f64| format!("{v:.y_decimals$}");
    chart
        .configure_mesh()
        .x_desc("execution")
        .y_desc("error (mm)")
        .x_labels(16)
        .y_labels(8)
        .y_label_formatter(&y_fmt)
        .label_style(font(LABEL_PX))
        .axis_desc_style(font(DESC_PX))
        .max_light_lines(4)
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(242, 242, 242))
        .draw()?;

    // The mean first, as a thick backdrop the points' lines stay visible on.
    let means = scene
        .executions
        .iter()
        .map(|e| Scene::mean_error(e).map(|v| (i64::from(e.number), v)));
    draw_error_series(
        &mut chart,
        runs(means),
        BLACK.to_rgba(),
        5,
        7,
        Some("mean".to_string()),
    )?;

    let named = scene.n_points <= MAX_NAMED_POINTS;
    for k in 0..scene.n_points {
        let colour = POINT_COLOURS[k % POINT_COLOURS.len()];
        let points = scene.executions.iter().map(|e| {
            e.errors
                .get(k)
                .copied()
                .flatten()
                .map(|v| (i64::from(e.number), v))
        });
        let label = named.then(|| format!("point {}", k + 1));
        draw_error_series(&mut chart, runs(points), colour.to_rgba(), 2, 5, label)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .margin(16)
        .legend_area_size(40)
        .background_style(WHITE.mix(0.9))
        .border_style(RGBColor(160, 160, 160))
        .label_font(font(LEGEND_PX))
        .draw()
}

/// One line of the convergence plot, broken at gaps, with a marker at each value; named in the
/// legend when `label` is given.
fn draw_error_series<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordi64, RangedCoordf64>>,
    runs: Vec<Vec<(i64, f64)>>,
    colour: RGBAColor,
    width: u32,
    marker: u32,
    label: Option<String>,
) -> DrawResult<DB> {
    let mut label = label;
    for run in runs {
        let line = chart.draw_series(LineSeries::new(
            run.iter().copied(),
            colour.stroke_width(width),
        ))?;
        if let Some(label) = label.take() {
            line.label(label).legend(move |(x, y)| {
                EmptyElement::at((x, y))
                    + PathElement::new(vec![(-4, 0), (28, 0)], colour.stroke_width(width))
                    + Circle::new((12, 0), marker, colour.filled())
            });
        }
        chart.draw_series(run.iter().map(|&p| Circle::new(p, marker, colour.filled())))?;
    }
    Ok(())
}

/// The figure of a recording: the last way-point set it saw executed, with the end effector's
/// path per execution (tracker samples between the execution's first and last setpoint), the
/// reached points (`cp_sample`) and the errors (`stats`).
pub fn plot_data(messages: &[Message], title: &str) -> anyhow::Result<PlotData> {
    let samples: Vec<&Message> = messages.iter().filter(|m| m.topic == "cp_sample").collect();
    let Some(set) = samples.last().and_then(|m| m.value["set_id"].as_u64()) else {
        bail!(
            "the recording has no conditioning samples: no way-point set was executed while it ran"
        );
    };
    let of_set: Vec<&&Message> = samples
        .iter()
        .filter(|m| m.value["set_id"].as_u64() == Some(set))
        .collect();
    let position = |v: &Value| -> Option<[f64; 3]> {
        let a = v.as_array()?;
        Some([
            a.first()?.as_f64()?,
            a.get(1)?.as_f64()?,
            a.get(2)?.as_f64()?,
        ])
    };
    let points = of_set
        .iter()
        .filter_map(|m| m.value["points"].as_u64())
        .max()
        .unwrap_or(0) as usize;
    let mut waypoints = vec![[f64::NAN; 3]; points];
    let request = messages
        .iter()
        .rev()
        .find(|m| m.topic == "estimate_request" && m.value["set_id"].as_u64() == Some(set));
    if let Some(req) = request {
        for (i, p) in req.value["desired"]
            .as_array()
            .into_iter()
            .flatten()
            .take(points)
            .enumerate()
        {
            waypoints[i] = position(p).unwrap_or([f64::NAN; 3]);
        }
    }
    for m in &of_set {
        let i = m.value["point"].as_u64().unwrap_or(u64::MAX) as usize;
        if i < points && waypoints[i][0].is_nan() {
            waypoints[i] = position(&m.value["desired"]).unwrap_or([f64::NAN; 3]);
        }
    }
    // The set's span: from its acceptance (the controller asks the learner for its estimates
    // then) to its last conditioning sample's execution's end.
    let set_start = request.map_or(0, |m| m.publish_time);
    let mut numbers: Vec<u32> = of_set
        .iter()
        .filter_map(|m| m.value["execution"].as_u64().map(|e| e as u32))
        .collect();
    numbers.sort_unstable();
    numbers.dedup();
    let stats: Vec<softarm_ipc::ExecutionStats> = stats_of(messages)
        .into_iter()
        .filter(|s| s.set_id == set)
        .collect();
    let execute = softarm_ipc::ControllerState::Execute as u64;
    let mut executions = Vec::new();
    for &n in &numbers {
        // The setpoints of this execution: EXECUTE, this number, since the set's start.
        let span = messages
            .iter()
            .filter(|m| {
                m.topic == "setpoint"
                    && m.value["state"].as_u64() == Some(execute)
                    && m.value["execution"].as_u64() == Some(u64::from(n))
            })
            .map(|m| m.publish_time)
            .filter(|&t| t >= set_start)
            .fold(None, |acc: Option<(u64, u64)>, t| {
                Some(acc.map_or((t, t), |(a, b)| (a.min(t), b.max(t))))
            });
        let path = span.map_or_else(Vec::new, |(a, b)| {
            messages
                .iter()
                .filter(|m| m.topic == "tracker" && (a..=b).contains(&m.publish_time))
                .filter_map(|m| position(&m.value["position"]))
                .collect()
        });
        let mut reached = vec![None; points];
        for m in of_set
            .iter()
            .filter(|m| m.value["execution"].as_u64() == Some(u64::from(n)))
        {
            let i = m.value["point"].as_u64().unwrap_or(u64::MAX) as usize;
            if i < points {
                reached[i] = position(&m.value["reached"]);
            }
        }
        let errors_m = stats
            .iter()
            .find(|s| s.execution == n)
            .map_or_else(Vec::new, |s| s.errors().to_vec());
        executions.push(Execution {
            number: n,
            path,
            reached,
            errors_m,
        });
    }
    Ok(PlotData {
        title: format!("{title}: set {set}, {} executions", executions.len()),
        waypoints,
        executions,
    })
}

/// `softarm plot FILE -o OUT`: the recording's last set drawn into `output` (PNG or SVG).
pub fn run(recording: &Path, output: &Path) -> anyhow::Result<()> {
    // Before the recording is read: a plot that cannot be written is refused first.
    check_output(output)?;
    let messages = record::read(recording)?;
    let data = plot_data(&messages, &recording.display().to_string())?;
    render(&data, output)?;
    println!("wrote {}", output.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    const WAYPOINTS: [[f64; 3]; 3] = [[0.05, -0.02, 0.20], [0.0, 0.06, 0.15], [-0.05, 0.01, 0.22]];

    /// Three way-points and `n` executions whose paths approach them, errors (different for each
    /// point) shrinking by 30 % an execution.
    fn synthetic(n: u32) -> PlotData {
        let home = [0.0, 0.0, 0.25];
        let executions = (0..n)
            .map(|i| {
                let scale = 0.03 * 0.7f64.powi(i as i32);
                let offsets: Vec<[f64; 3]> = (0..WAYPOINTS.len())
                    .map(|k| {
                        let phase = (k as u32 + i) as f64;
                        let scale = scale * [0.5, 0.8, 1.6][k];
                        [scale * phase.cos(), scale * phase.sin(), 0.5 * scale]
                    })
                    .collect();
                let reached: Vec<[f64; 3]> = WAYPOINTS
                    .iter()
                    .zip(&offsets)
                    .map(|(w, o)| [w[0] + o[0], w[1] + o[1], w[2] + o[2]])
                    .collect();
                let mut corners = vec![home];
                corners.extend(&reached);
                corners.push(home);
                let path = corners
                    .windows(2)
                    .flat_map(|seg| {
                        let (p, q) = (seg[0], seg[1]);
                        (0..50).map(move |s| {
                            let t = s as f64 / 50.0;
                            [0, 1, 2].map(|d| p[d] + (q[d] - p[d]) * t)
                        })
                    })
                    .collect();
                Execution {
                    number: i + 1,
                    path,
                    reached: reached.into_iter().map(Some).collect(),
                    errors_m: offsets
                        .iter()
                        .map(|o| (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]).sqrt())
                        .collect(),
                }
            })
            .collect();
        PlotData {
            title: "Way-point set A <&> run 7".to_string(),
            waypoints: WAYPOINTS.to_vec(),
            executions,
        }
    }

    /// A fresh directory for one test.
    fn temp_dir(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("softarm-plot-{}-{test}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// (x0, y0, x1, y1) of the three projections and the convergence plot.
    fn panels() -> [(u32, u32, u32, u32); 4] {
        let (w, h) = SIZE;
        let (top, mid) = (TITLE_H, TITLE_H + TOP_H);
        [
            (0, top, w / 3, mid),
            (w / 3, top, 2 * w / 3, mid),
            (2 * w / 3, top, w, mid),
            (0, mid, w, h),
        ]
    }

    /// Fractions of the region's pixels that are not white, and that are coloured (not grey).
    fn ink(rgb: &[u8], (x0, y0, x1, y1): (u32, u32, u32, u32)) -> (f64, f64) {
        let (mut inked, mut coloured) = (0usize, 0usize);
        for y in y0..y1 {
            for x in x0..x1 {
                let i = 3 * (y as usize * SIZE.0 as usize + x as usize);
                let [r, g, b] = [rgb[i], rgb[i + 1], rgb[i + 2]];
                if (r, g, b) != (255, 255, 255) {
                    inked += 1;
                }
                if r.max(g).max(b) - r.min(g).min(b) > 40 {
                    coloured += 1;
                }
            }
        }
        let area = ((x1 - x0) * (y1 - y0)) as f64;
        (inked as f64 / area, coloured as f64 / area)
    }

    fn rgb_of(data: &PlotData) -> Vec<u8> {
        let rgb = draw_rgb(&Scene::new(data)).unwrap();
        assert_eq!(rgb.len(), SIZE.0 as usize * SIZE.1 as usize * 3);
        rgb
    }

    #[test]
    fn plot_panels_all_show_data() {
        let rgb = rgb_of(&synthetic(10));
        for (i, panel) in panels().into_iter().enumerate() {
            let (inked, coloured) = ink(&rgb, panel);
            assert!(inked > 0.01, "panel {i} {panel:?}: only {inked:.4} inked");
            assert!(
                coloured > 0.002,
                "panel {i} {panel:?}: only {coloured:.4} coloured"
            );
        }
        let (title_ink, _) = ink(&rgb, (0, 0, SIZE.0, TITLE_H));
        assert!(title_ink > 0.01, "title strip: only {title_ink:.4} inked");
    }

    #[test]
    fn plot_png_file_has_size() {
        let dir = temp_dir("png");
        let out = dir.join("fig.png");
        render(&synthetic(10), &out).unwrap();
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!(&bytes[12..16], b"IHDR");
        let be = |at: usize| u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap());
        assert_eq!((be(16), be(20)), SIZE);
        assert!(
            bytes.len() > 20_000,
            "suspiciously small PNG: {} bytes",
            bytes.len()
        );
        // The temporary file is gone; only the figure is left.
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["fig.png"]);
        // No extension: PNG too; upper-case extension accepted.
        for name in ["fig", "FIG.PNG"] {
            let out = dir.join(name);
            render(&synthetic(3), &out).unwrap();
            assert_eq!(&std::fs::read(&out).unwrap()[..8], b"\x89PNG\r\n\x1a\n");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn plot_svg_has_title() {
        let dir = temp_dir("svg");
        let out = dir.join("fig.svg");
        let data = synthetic(10);
        render(&data, &out).unwrap();
        let svg = std::fs::read_to_string(&out).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..svg.len().min(200)]);
        assert!(svg.contains(r#"width="1800""#) && svg.contains(r#"height="1200""#));
        assert!(svg.contains("Way-point set A &lt;&amp;&gt; run 7"));
        assert!(!svg.contains("no statistics"));
        assert!(
            svg.len() > 50_000,
            "suspiciously small SVG: {} bytes",
            svg.len()
        );
        assert!(svg.trim_end().ends_with("</svg>"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn plot_errors_name_the_path() {
        let dir = temp_dir("errors");
        let data = synthetic(2);
        for name in ["fig.jpg", "fig.pdf"] {
            let out = dir.join(name);
            let err = format!("{:#}", render(&data, &out).unwrap_err());
            assert!(err.contains(&out.display().to_string()), "{err}");
            assert!(err.contains("extension"), "{err}");
            assert!(!out.exists());
        }
        let missing = dir.join("no/such/dir/fig.png");
        let err = format!("{:#}", render(&data, &missing).unwrap_err());
        assert!(err.contains(&missing.display().to_string()), "{err}");
        let missing_svg = dir.join("no/such/dir/fig.svg");
        let err = format!("{:#}", render(&data, &missing_svg).unwrap_err());
        assert!(err.contains(&missing_svg.display().to_string()), "{err}");
        let err = format!("{:#}", render(&data, &dir).unwrap_err());
        assert!(err.contains("directory"), "{err}");
        let empty = PlotData {
            title: "empty".into(),
            waypoints: vec![[f64::NAN; 3]],
            executions: vec![Execution {
                number: 1,
                errors_m: vec![f64::NAN],
                ..Execution::default()
            }],
        };
        let out = dir.join("empty.png");
        let err = format!("{:#}", render(&empty, &out).unwrap_err());
        assert!(err.contains("nothing to plot") && err.contains(&out.display().to_string()));
        assert!(!out.exists());
        // Nothing half-written was left behind.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn plot_edge_cases_render() {
        // One execution, with a path broken by NaN, a missing and a NaN reached point.
        let mut one = synthetic(1);
        let e = &mut one.executions[0];
        e.path[10] = [f64::NAN, 0.0, 0.0];
        e.path[11][2] = f64::INFINITY;
        e.reached[1] = None;
        e.reached[2] = Some([0.0, f64::NAN, 0.0]);
        e.errors_m[0] = f64::NAN;
        let rgb = rgb_of(&one);
        for panel in panels() {
            assert!(ink(&rgb, panel).0 > 0.01, "{panel:?}");
        }

        // Zero-length paths and no statistics: the bottom panel says so.
        let mut bare = synthetic(4);
        for e in &mut bare.executions {
            e.path.clear();
            e.errors_m.clear();
        }
        let rgb = rgb_of(&bare);
        let bottom = panels()[3];
        let (inked, coloured) = ink(&rgb, bottom);
        assert!(inked > 0.0005 && coloured == 0.0, "{inked} {coloured}");

        // Everything at one spot (degenerate ranges), and one execution with one error.
        let spot = PlotData {
            title: "one spot".into(),
            waypoints: vec![[0.1, 0.1, 0.1]],
            executions: vec![Execution {
                number: 5,
                path: vec![[0.1, 0.1, 0.1]; 3],
                reached: vec![Some([0.1, 0.1, 0.1])],
                errors_m: vec![0.0],
            }],
        };
        let rgb = rgb_of(&spot);
        for panel in panels() {
            assert!(ink(&rgb, panel).0 > 0.01, "{panel:?}");
        }

        // Only way-points, no executions at all; an over-long title.
        let only = PlotData {
            title: "a very long title ".repeat(20),
            waypoints: WAYPOINTS.to_vec(),
            executions: vec![],
        };
        rgb_of(&only);

        // Many conditioning points (more than the legend names).
        let mut many = synthetic(3);
        for e in &mut many.executions {
            e.errors_m = (0..20).map(|k| 0.001 * k as f64).collect();
        }
        rgb_of(&many);
    }

    #[test]
    fn plot_ranges() {
        assert_eq!(padded([], 10.0), None);
        assert_eq!(padded([f64::NAN], 10.0), None);
        let (lo, hi) = padded([3.0, 3.0], 10.0).unwrap();
        assert!(lo < -2.0 && hi > 8.0 && (lo + hi - 6.0).abs() < 1e-9);
        let (lo, hi) = padded([0.0, 100.0], 10.0).unwrap();
        assert!((lo + 6.0).abs() < 1e-9 && (hi - 106.0).abs() < 1e-9);
        let (x, y) = equal_aspect((0.0, 100.0), (0.0, 10.0), (200, 100));
        assert_eq!(x, (0.0, 100.0));
        assert!(((y.1 - y.0) - 50.0).abs() < 1e-9 && ((y.0 + y.1) - 10.0).abs() < 1e-9);
        assert_eq!(
            runs([Some(1), None, None, Some(2), Some(3), None]),
            [vec![1], vec![2, 3]]
        );
    }

    /// Writes /tmp/plot-sample.png for a look by eye: `cargo test -p softarm-record --lib
    /// plot_sample -- --ignored`.
    #[test]
    #[ignore]
    fn plot_sample() {
        render(&synthetic(10), Path::new("/tmp/plot-sample.png")).unwrap();
        render(&synthetic(10), Path::new("/tmp/plot-sample.svg")).unwrap();
        let mut bare = synthetic(1);
        bare.executions[0].errors_m.clear();
        bare.executions[0].path.truncate(60);
        bare.executions[0].path[20][0] = f64::NAN;
        render(&bare, Path::new("/tmp/plot-sample-edge.png")).unwrap();
    }
}
