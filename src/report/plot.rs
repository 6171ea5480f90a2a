//! PNG figures for the report: density histograms (Fig. 5) and mean ± std curves (training
//! curves next to Table 2).
//!
//! plotters draws into an RGB buffer in memory and `png` encodes it into an [`AtomicFile`], so a
//! figure appears whole or not at all, like every other pgser output. Text uses the DejaVu Sans
//! font bundled in `assets/fonts` (registered once with plotters' ab_glyph backend): no system
//! font library is needed, and the pixels do not depend on the fonts a machine has installed.

use std::io::{BufWriter, Write};
use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result, anyhow};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use crate::output::AtomicFile;

/// DejaVu Sans (licence in `assets/fonts/LICENSE`): the only font the figures use.
static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
/// The family name plotters asks for with `("sans-serif", size)`.
const FAMILY: &str = "sans-serif";

/// matplotlib's tab10 colours: distinguishable, and familiar from the paper's figures.
pub const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn ensure_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is compiled in, so failing to parse it is a build defect, not a user error.
        if register_font(FAMILY, FontStyle::Normal, FONT).is_err() {
            panic!("the bundled font assets/fonts/DejaVuSans.ttf is not a valid TrueType font");
        }
    });
}

type Chart<'a, 'b> = ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// What both figures share: the title, labelled axes over `x` × `y`, a light grid.
fn frame<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, Shift>,
    title: &str,
    (x_label, y_label): (&str, &str),
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    margin_right: u32,
) -> Result<Chart<'a, 'b>> {
    frame_with(root, title, (x_label, y_label), x, y, margin_right, &|x| format!("{x:.0}"))
}

/// [`frame`] with the x axis's labels written by `x_fmt`.
fn frame_with<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, Shift>,
    title: &str,
    (x_label, y_label): (&str, &str),
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    margin_right: u32,
    x_fmt: &dyn Fn(&f64) -> String,
) -> Result<Chart<'a, 'b>> {
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FAMILY, 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .margin_right(margin_right)
        .build_cartesian_2d(x, y)
        .map_err(|e| anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_label_formatter(x_fmt)
        .x_desc(x_label)
        .y_desc(y_label)
        .label_style((FAMILY, 14))
        .axis_desc_style((FAMILY, 16))
        .bold_line_style(BLACK.mix(0.12))
        .light_line_style(TRANSPARENT)
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    Ok(chart)
}

/// A vertical span the figure draws ink over: at `x`, everything from `lo` to `hi` (a line
/// point has `lo == hi`, a ±std band or a histogram bar a range).
type Span = (f64, f64, f64);

/// The four corners a legend can take, in the order preferred when several hide as little.
const CORNERS: [SeriesLabelPosition; 4] = [
    SeriesLabelPosition::LowerRight,
    SeriesLabelPosition::UpperLeft,
    SeriesLabelPosition::UpperRight,
    SeriesLabelPosition::LowerLeft,
];

/// The index in [`CORNERS`] of the corner where a legend box of `box_px` pixels hides the fewest
/// `spans` of a plot of `plot_px` pixels over `x` × `y`. A fixed corner hid curves whenever a
/// task's results happened to lie there (FetchSlide's TD3+BC curves sat under the legend at
/// the lower right), and which corner is empty depends on the task, so it is chosen per figure.
fn quietest_corner(
    spans: &[Span],
    (x, y): (std::ops::Range<f64>, std::ops::Range<f64>),
    plot_px: (u32, u32),
    box_px: (f64, f64),
) -> usize {
    // plotters keeps the box ~10 px from the plot's edges.
    let w = ((box_px.0 + 10.0) / plot_px.0.max(1) as f64).min(1.0) * (x.end - x.start);
    let h = ((box_px.1 + 10.0) / plot_px.1.max(1) as f64).min(1.0) * (y.end - y.start);
    let boxes = [
        (x.end - w..x.end, y.start..y.start + h),
        (x.start..x.start + w, y.end - h..y.end),
        (x.end - w..x.end, y.end - h..y.end),
        (x.start..x.start + w, y.start..y.start + h),
    ];
    let hidden = |(bx, by): &(std::ops::Range<f64>, std::ops::Range<f64>)| {
        spans.iter().filter(|(sx, lo, hi)| bx.contains(sx) && *lo <= by.end && *hi >= by.start).count()
    };
    (0..boxes.len()).min_by_key(|&i| hidden(&boxes[i])).unwrap_or(0)
}

/// The spans a mean ± std curve covers, sampled along each segment between evaluations, so a
/// line crossing a corner between two points counts too.
fn curve_spans(c: &Curve) -> Vec<Span> {
    const STEPS: usize = 16;
    let points: Vec<(f64, f64, f64)> =
        c.x.iter().zip(c.mean.iter().zip(&c.std)).map(|(x, (m, s))| (*x, *m, *s)).collect();
    let mut spans: Vec<Span> = points.iter().map(|(x, m, s)| (*x, m - s, m + s)).collect();
    for pair in points.windows(2) {
        let ((x0, m0, s0), (x1, m1, s1)) = (pair[0], pair[1]);
        for k in 1..STEPS {
            let t = k as f64 / STEPS as f64;
            let (x, m, s) = (x0 + t * (x1 - x0), m0 + t * (m1 - m0), s0 + t * (s1 - s0));
            spans.push((x, m - s, m + s));
        }
    }
    spans
}

/// The legend box's size in pixels for these labels at the legend's 15 px font: a sample line or
/// swatch and a gap, then the text (DejaVu Sans averages ~8.5 px a character at 15 px), and
/// ~19 px a row.
fn legend_box_px<'s>(labels: impl Iterator<Item = &'s str>) -> (f64, f64) {
    let (rows, chars) = labels.fold((0usize, 0usize), |(n, w), l| (n + 1, w.max(l.chars().count())));
    (45.0 + 8.5 * chars as f64, 12.0 + 19.0 * rows as f64)
}

/// The series' labels in a framed box at the corner where they hide the fewest of `spans`.
fn legend<'a, 'b: 'a, 's>(
    chart: &mut Chart<'a, 'b>,
    spans: &[Span],
    labels: impl Iterator<Item = &'s str>,
) -> Result<()> {
    let (x, y) = (chart.x_range(), chart.y_range());
    let at =
        CORNERS[quietest_corner(spans, (x, y), chart.plotting_area().dim_in_pixel(), legend_box_px(labels))].clone();
    chart
        .configure_series_labels()
        .position(at)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FAMILY, 15))
        .draw()
        .map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// Draws a `width` × `height` figure with `draw` and writes it to `path` as an RGB PNG.
fn save_png(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<()> {
    ensure_font();
    let mut buf = vec![0u8; width as usize * height as usize * 3];
    let render = |buf: &mut [u8]| -> Result<()> {
        let root = BitMapBackend::with_buffer(buf, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
        draw(&root)?;
        root.present().map_err(|e| anyhow!("{e}"))
    };
    render(&mut buf).with_context(|| format!("{}: cannot draw the figure", path.display()))?;
    let file = AtomicFile::create(path)?;
    {
        let mut w = BufWriter::new(file.handle()?);
        let mut enc = png::Encoder::new(&mut w, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let encode = || -> std::result::Result<(), png::EncodingError> {
            let mut writer = enc.write_header()?;
            writer.write_image_data(&buf)?;
            writer.finish()
        };
        encode().with_context(|| format!("{}: cannot encode the PNG", path.display()))?;
        w.flush().with_context(|| format!("{}: write failed", path.display()))?;
    }
    file.commit()
}

/// One histogram of a density plot.
pub struct HistSeries<'a> {
    pub label: String,
    pub values: &'a [f64],
    pub color: RGBColor,
}

/// The axis a histogram of `series` is drawn over: their finite values' span, widened by 2 % on
/// each side so the extreme bins show, and not past `bound` where the data stop short of it. A
/// Q histogram drawn over Q's whole range [−1/(1−γ), 0] puts data that lie in [−4, 0] into two
/// thin bars at the right edge.
pub fn fitted_range(series: &[&[f64]], bound: (f64, f64)) -> (f64, f64) {
    let finite = series.iter().flat_map(|s| s.iter().copied()).filter(|v| v.is_finite());
    let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return bound;
    }
    let pad = if hi > lo { 0.02 * (hi - lo) } else { 0.5 };
    // Data beyond a bound (a critic can overshoot Q's range) stay on the axis.
    let lo = if lo >= bound.0 { (lo - pad).max(bound.0) } else { lo - pad };
    let hi = if hi <= bound.1 { (hi + pad).min(bound.1) } else { hi + pad };
    (lo, hi)
}

/// The densities of `values` in `bins` equal bins over `[lo, hi]`. Values outside the range
/// count in the end bins: Q is clipped to [−1/(1−γ), 0] only in the targets, so a critic may
/// overshoot a little, and dropping those rows would bias the picture.
pub fn densities(values: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<f64> {
    let width = (hi - lo) / bins as f64;
    let mut counts = vec![0usize; bins];
    for &v in values {
        let b = ((v - lo) / width).floor();
        let b = if b.is_nan() { 0 } else { (b.max(0.0) as usize).min(bins - 1) };
        counts[b] += 1;
    }
    let n = values.len().max(1) as f64;
    counts.into_iter().map(|c| c as f64 / (n * width)).collect()
}

/// One panel of overlaid density histograms, already binned over `range` (equal bins).
pub struct DensityPanel {
    pub title: String,
    pub range: (f64, f64),
    /// (label, density per bin, colour) of each histogram.
    pub series: Vec<(String, Vec<f64>, RGBColor)>,
}

/// Overlaid semi-transparent density histograms over `[lo, hi]` (Fig. 5).
#[allow(clippy::too_many_arguments)]
pub fn density_histograms(
    path: &Path,
    size: (u32, u32),
    title: &str,
    x_label: &str,
    y_label: &str,
    (lo, hi): (f64, f64),
    bins: usize,
    series: &[HistSeries<'_>],
) -> Result<()> {
    let panel = DensityPanel {
        title: title.to_string(),
        range: (lo, hi),
        series: series.iter().map(|s| (s.label.clone(), densities(s.values, lo, hi, bins), s.color)).collect(),
    };
    save_png(path, size, |root| draw_densities(root, (x_label, y_label), &panel))
}

/// Several density panels in one figure, `cols` to a row in the given order (Fig. 5 across
/// tasks, one panel per task as in the paper).
pub fn density_panels(
    path: &Path,
    size: (u32, u32),
    cols: usize,
    labels: (&str, &str),
    panels: &[DensityPanel],
) -> Result<()> {
    let rows = panels.len().div_ceil(cols.max(1)).max(1);
    save_png(path, size, |root| {
        for (area, panel) in root.split_evenly((rows, cols.max(1))).iter().zip(panels) {
            draw_densities(area, labels, panel)?;
        }
        Ok(())
    })
}

/// One panel's histograms as bars, with its title, axes and legend.
fn draw_densities(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    labels: (&str, &str),
    panel: &DensityPanel,
) -> Result<()> {
    let (lo, hi) = panel.range;
    let bins = panel.series.iter().map(|s| s.1.len()).max().unwrap_or(1).max(1);
    let top = panel.series.iter().flat_map(|s| s.1.iter()).copied().fold(0.0f64, f64::max);
    let top = if top > 0.0 { top * 1.1 } else { 1.0 };
    let width = (hi - lo) / bins as f64;
    let mut chart = frame(area, &panel.title, labels, lo..hi, 0.0..top, 25)?;
    let mut spans = Vec::new();
    for (label, d, color) in &panel.series {
        let style = color.mix(0.45).filled();
        let bars = d.iter().enumerate().filter(|(_, h)| **h > 0.0).map(|(i, h)| {
            let x0 = lo + i as f64 * width;
            // The bar's ink for the legend's choice of corner: its two edges and middle.
            spans.extend([0.0, 0.5, 1.0].map(|f| (x0 + f * width, 0.0, *h)));
            Rectangle::new([(x0, 0.0), (x0 + width, *h)], style)
        });
        chart
            .draw_series(bars)
            .map_err(|e| anyhow!("{e}"))?
            .label(label.clone())
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 16, y + 6)], style));
    }
    legend(&mut chart, &spans, panel.series.iter().map(|s| s.0.as_str()))
}

/// One curve: mean over seeds at each x, with a ±std band.
pub struct Curve {
    pub label: String,
    pub x: Vec<f64>,
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
}

/// Mean curves with ±std bands (training curves). The y range fits the bands, not a fixed
/// [0, T], so small differences between variants stay visible.
pub fn mean_std_curves(
    path: &Path,
    size: (u32, u32),
    title: &str,
    x_label: &str,
    y_label: &str,
    curves: &[Curve],
) -> Result<()> {
    let xs = curves.iter().flat_map(|c| c.x.iter().copied());
    let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    let ys = curves.iter().flat_map(|c| c.mean.iter().zip(&c.std).flat_map(|(m, s)| [m - s, m + s]));
    let (y0, y1) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y), b.max(y)));
    let (x0, x1) = if x0.is_finite() && x1 > x0 { (x0, x1) } else { (x0.min(0.0), x0.max(0.0) + 1.0) };
    let pad = if y1 > y0 { 0.05 * (y1 - y0) } else { 1.0 };
    let (y0, y1) = if y0.is_finite() { (y0 - pad, y1 + pad) } else { (0.0, 1.0) };
    save_png(path, size, |root| {
        let mut chart = frame(root, title, (x_label, y_label), x0..x1, y0..y1, 40)?;
        for (i, c) in curves.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            let upper = c.x.iter().zip(c.mean.iter().zip(&c.std)).map(|(x, (m, s))| (*x, m + s));
            let lower = c.x.iter().zip(c.mean.iter().zip(&c.std)).map(|(x, (m, s))| (*x, m - s)).rev();
            let band: Vec<(f64, f64)> = upper.chain(lower).collect();
            chart
                .draw_series(std::iter::once(Polygon::new(band, color.mix(0.2).filled())))
                .map_err(|e| anyhow!("{e}"))?;
            let points: Vec<(f64, f64)> = c.x.iter().copied().zip(c.mean.iter().copied()).collect();
            chart
                .draw_series(LineSeries::new(points, color.stroke_width(2)))
                .map_err(|e| anyhow!("{e}"))?
                .label(c.label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
        }
        let spans: Vec<Span> = curves.iter().flat_map(curve_spans).collect();
        legend(&mut chart, &spans, curves.iter().map(|c| c.label.as_str()))
    })
}

/// Points of one series: (x, mean, std), joined in x order.
pub struct PointSeries {
    pub label: String,
    pub points: Vec<(f64, f64, f64)>,
}

/// A study's figure: each series as points with ±std error bars joined by a line, and each
/// reference `(label, mean, std)` as a band across the whole x range (a result that does not
/// depend on x: the baseline, `-swap`). `log_x` labels the axis 10^x (x given as log10).
pub fn points_and_bands(
    path: &Path,
    size: (u32, u32),
    title: &str,
    (x_label, log_x): (&str, bool),
    y_label: &str,
    series: &[PointSeries],
    bands: &[(String, f64, f64)],
) -> Result<()> {
    let xs = series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
    let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    let (x0, x1) = if x0.is_finite() { (x0, x1) } else { (0.0, 1.0) };
    let pad = if x1 > x0 { 0.08 * (x1 - x0) } else { 0.5 };
    let (x0, x1) = (x0 - pad, x1 + pad);
    let ys = series.iter().flat_map(|s| s.points.iter().flat_map(|(_, m, d)| [m - d.max(0.0), m + d.max(0.0)]));
    let ys = ys.chain(bands.iter().flat_map(|(_, m, d)| [m - d.max(0.0), m + d.max(0.0)]));
    let (y0, y1) =
        ys.filter(|y| y.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y), b.max(y)));
    let ypad = if y1 > y0 { 0.08 * (y1 - y0) } else { 1.0 };
    let (y0, y1) = if y0.is_finite() { (y0 - ypad, y1 + ypad) } else { (0.0, 1.0) };
    let fmt = move |x: &f64| {
        if !log_x {
            return format!("{x}");
        }
        let v = 10f64.powf(*x);
        match v {
            v if v >= 1e6 => format!("{}M", (v / 1e6 * 10.0).round() / 10.0),
            v if v >= 1e3 => format!("{}k", (v / 1e3).round()),
            v => format!("{v:.0}"),
        }
    };
    save_png(path, size, |root| {
        let mut chart = frame_with(root, title, (x_label, y_label), x0..x1, y0..y1, 40, &fmt)?;
        let mut spans: Vec<Span> = Vec::new();
        for (i, (label, m, d)) in bands.iter().enumerate() {
            let color = PALETTE[(series.len() + i) % PALETTE.len()];
            let d = if d.is_finite() { *d } else { 0.0 };
            chart
                .draw_series(std::iter::once(Rectangle::new([(x0, m - d), (x1, m + d)], color.mix(0.15).filled())))
                .map_err(|e| anyhow!("{e}"))?;
            chart
                .draw_series(LineSeries::new([(x0, *m), (x1, *m)], color.stroke_width(2)))
                .map_err(|e| anyhow!("{e}"))?
                .label(label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
            let steps = 16;
            spans.extend((0..=steps).map(|k| (x0 + (x1 - x0) * k as f64 / steps as f64, m - d, m + d)));
        }
        for (i, s) in series.iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            let mut points = s.points.clone();
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            let dx = 0.01 * (x1 - x0);
            for &(x, m, d) in &points {
                let d = if d.is_finite() { d } else { 0.0 };
                let bar = [
                    vec![(x, m - d), (x, m + d)],
                    vec![(x - dx, m - d), (x + dx, m - d)],
                    vec![(x - dx, m + d), (x + dx, m + d)],
                ];
                chart
                    .draw_series(bar.into_iter().map(|p| PathElement::new(p, color.stroke_width(2))))
                    .map_err(|e| anyhow!("{e}"))?;
                spans.push((x, m - d, m + d));
            }
            chart
                .draw_series(points.iter().map(|&(x, m, _)| Circle::new((x, m), 5, color.filled())))
                .map_err(|e| anyhow!("{e}"))?;
            chart
                .draw_series(LineSeries::new(points.iter().map(|&(x, m, _)| (x, m)), color.stroke_width(2)))
                .map_err(|e| anyhow!("{e}"))?
                .label(s.label.clone())
                .legend(move |(x, y)| Circle::new((x + 9, y), 5, color.filled()));
        }
        let labels: Vec<&str> =
            bands.iter().map(|b| b.0.as_str()).chain(series.iter().map(|s| s.label.as_str())).collect();
        legend(&mut chart, &spans, labels.into_iter())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(label: &str, y: f64) -> Curve {
        Curve { label: label.into(), x: vec![0.0, 10.0], mean: vec![y, y], std: vec![0.0, 0.0] }
    }

    /// The legend goes where no curve is: with curves along the bottom it leaves the preferred
    /// lower right for the upper left; with one along the top it keeps the lower right.
    #[test]
    fn the_legend_takes_an_empty_corner() {
        let range = (0.0..10.0, 0.0..10.0);
        let bottom: Vec<Span> = [flat("a", 0.5), flat("b", 1.0)].iter().flat_map(curve_spans).collect();
        assert_eq!(quietest_corner(&bottom, range.clone(), (800, 500), (150.0, 60.0)), 1);
        let top: Vec<Span> = curve_spans(&flat("a", 9.5));
        assert_eq!(quietest_corner(&top, range.clone(), (800, 500), (150.0, 60.0)), 0);
        // A rising curve with a wide band fills the lower left and upper right: one of the others.
        let rising = Curve { label: "r".into(), x: vec![0.0, 10.0], mean: vec![0.0, 10.0], std: vec![1.0, 1.0] };
        let corner = quietest_corner(&curve_spans(&rising), range.clone(), (800, 500), (150.0, 60.0));
        assert!(corner == 0 || corner == 1, "corner {corner}");
        // A line that crosses a corner between its two points hides it too: (0, 8) → (3, 10)
        // passes through the upper-left box although neither end is in it, so with curves along
        // the bottom the upper right is left.
        let crossing = Curve { label: "c".into(), x: vec![0.0, 3.0], mean: vec![8.0, 10.0], std: vec![0.0, 0.0] };
        assert!(curve_spans(&crossing).iter().any(|(x, y, _)| *x > 0.0 && *x < 2.0 && *y > 8.6));
        let mut both = bottom.clone();
        both.extend(curve_spans(&crossing));
        assert_eq!(quietest_corner(&both, range, (800, 500), (150.0, 60.0)), 2);
    }

    #[test]
    fn a_histogram_axis_fits_its_data_inside_the_bound() {
        // Data in [−4, −0.5] of Q's range [−50, 0]: 2 % of the span beyond each end.
        let (a, b) = ([-4.0, -1.0, f64::NAN], [-0.5, -2.0]);
        let (lo, hi) = fitted_range(&[&a, &b], (-50.0, 0.0));
        assert!((lo + 4.07).abs() < 1e-12 && (hi + 0.43).abs() < 1e-12, "{lo} {hi}");
        // Not past the bound where the data reach it; past it where the data do.
        assert_eq!(fitted_range(&[&[-50.0, 0.0]], (-50.0, 0.0)), (-50.0, 0.0));
        let (lo, hi) = fitted_range(&[&[-60.0, 1.0]], (-50.0, 0.0));
        assert!(lo < -60.0 && hi > 1.0);
        // One value, and none.
        assert_eq!(fitted_range(&[&[-3.0]], (-50.0, 0.0)), (-3.5, -2.5));
        assert_eq!(fitted_range(&[&[]], (-50.0, 0.0)), (-50.0, 0.0));
        // Every value lands inside: the first and last bins hold the extremes.
        let d = densities(&[-4.0, -1.0, -0.5, -2.0], -4.07, -0.43, 50);
        assert!(d[0] > 0.0 && d[49] > 0.0);
    }

    #[test]
    fn the_legend_box_grows_with_its_labels() {
        let (w1, h1) = legend_box_px(["TD3"].into_iter());
        let (w2, h2) = legend_box_px(["TD3", "TD3+BC baseline"].into_iter());
        assert!(w2 > w1 && h2 > h1);
        assert_eq!(h2 - h1, 19.0);
    }
}
