//! Figures as SVG files (plotters' SVG backend, text as SVG text so that no font file is needed):
//! panels of line curves against a step axis, and bar charts.

use std::path::Path;

use plotters::prelude::*;

use crate::error::EvalError;

/// One line of a panel: `(x, y)` points in drawing order.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// One chart of a figure.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// A logarithmic y axis (losses); non-positive values are left out.
    pub log_y: bool,
    pub curves: Vec<Curve>,
}

const COLORS: [RGBColor; 4] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
];

/// Panel size in pixels.
const PANEL: (u32, u32) = (560, 360);

/// Writes `panels` side by side in rows of two as one SVG at `path` (atomically). Panels without any
/// point are drawn empty with "no data".
pub fn write_panels(path: &Path, panels: &[Panel]) -> Result<(), EvalError> {
    let svg = draw_panels(panels).map_err(plot_error(path))?;
    Ok(anerf_data::atomic::write_bytes(path, svg.as_bytes())?)
}

/// The SVG text of [`write_panels`], for figures drawn on request (the viewer's live curves).
pub fn panels_svg(panels: &[Panel]) -> Result<String, EvalError> {
    draw_panels(panels).map_err(|e| EvalError::Draw(e.to_string()))
}

fn draw_panels(panels: &[Panel]) -> Result<String, DrawingAreaErrorKind<std::io::Error>> {
    let rows = panels.len().div_ceil(2).max(1) as u32;
    let cols = panels.len().clamp(1, 2) as u32;
    let mut svg = String::new();
    {
        let root =
            SVGBackend::with_string(&mut svg, (PANEL.0 * cols, PANEL.1 * rows)).into_drawing_area();
        root.fill(&WHITE)?;
        let areas = root.split_evenly((rows as usize, cols as usize));
        for (panel, area) in panels.iter().zip(&areas) {
            draw_panel(panel, area)?;
        }
        root.present()?;
    }
    Ok(svg)
}

type Area<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;
type DrawResult = Result<(), DrawingAreaErrorKind<std::io::Error>>;

/// Largest magnitude of a value drawn: a log's values beyond it (a diverged loss, a corrupt line) are left
/// out, as non-finite ones are, so that every axis has a finite, resolvable range.
pub const AXIS_LIMIT: f64 = 1e12;

fn draw_panel(panel: &Panel, area: &Area) -> DrawResult {
    let drawable = |v: f64| v.is_finite() && v.abs() <= AXIS_LIMIT;
    let keep = |&(x, y): &(f64, f64)| {
        drawable(x) && drawable(y) && (!panel.log_y || y >= 1.0 / AXIS_LIMIT)
    };
    let all: Vec<(f64, f64)> = panel
        .curves
        .iter()
        .flat_map(|c| c.points.iter().copied().filter(keep))
        .collect();
    let (x0, x1, y0, y1) = bounds(&all);
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(&panel.title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(64);
    // The two axis kinds are different coordinate types; one generic body draws on either.
    if panel.log_y {
        let mut chart = builder.build_cartesian_2d(x0..x1, (y0..y1).log_scale())?;
        draw_curves(&mut chart, panel, keep)?;
    } else {
        let mut chart = builder.build_cartesian_2d(x0..x1, y0..y1)?;
        draw_curves(&mut chart, panel, keep)?;
    }
    if all.is_empty() {
        area.draw_text(
            "no data",
            &("sans-serif", 16).into(),
            (PANEL.0 as i32 / 2 - 30, PANEL.1 as i32 / 2),
        )?;
    }
    Ok(())
}

/// The grid, axis labels, every curve of `panel` (the points `keep` accepts) and the legend.
fn draw_curves<'a, X, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, Y>>,
    panel: &Panel,
    keep: impl Fn(&(f64, f64)) -> bool + Copy,
) -> DrawResult
where
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>
        + plotters::coord::ranged1d::ValueFormatter<f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>
        + plotters::coord::ranged1d::ValueFormatter<f64>,
{
    chart
        .configure_mesh()
        .x_desc(&panel.x_label)
        .y_desc(&panel.y_label)
        .draw()?;
    for (i, c) in panel.curves.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        chart
            .draw_series(LineSeries::new(
                c.points.iter().copied().filter(keep),
                color,
            ))?
            .label(&c.name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color));
    }
    legend(chart, panel)
}

/// The legend, when a panel has more than one curve.
fn legend<'a, X, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, Cartesian2d<X, Y>>,
    panel: &Panel,
) -> DrawResult
where
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
{
    if panel.curves.len() > 1 {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
    }
    Ok(())
}

/// The axis ranges of `points`, padded, with a unit range where there is no spread.
fn bounds(points: &[(f64, f64)]) -> (f64, f64, f64, f64) {
    if points.is_empty() {
        return (0.0, 1.0, 0.1, 1.0);
    }
    let fold = |f: fn(&(f64, f64)) -> f64| {
        points
            .iter()
            .map(f)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            })
    };
    let (x0, x1) = fold(|p| p.0);
    let (y0, y1) = fold(|p| p.1);
    let (x0, x1) = if x1 > x0 {
        (x0, x1)
    } else {
        (x0 - 0.5, x0 + 0.5)
    };
    let pad = if y1 > y0 {
        (y1 - y0) * 0.05
    } else {
        y0.abs().max(1e-3) * 0.1
    };
    let y_lo = if y0 > 0.0 && y0 - pad <= 0.0 {
        y0 * 0.9
    } else {
        y0 - pad
    };
    (x0, x1, y_lo, y1 + pad)
}

/// Writes a bar chart of `bars` (label, value) at `path` (atomically): one bar per entry, its value
/// printed above it.
pub fn write_bar_chart(
    path: &Path,
    title: &str,
    y_label: &str,
    bars: &[(String, f64)],
) -> Result<(), EvalError> {
    let mut svg = String::new();
    {
        let width = (120 + 70 * bars.len() as u32).max(PANEL.0);
        let root = SVGBackend::with_string(&mut svg, (width, PANEL.1)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error(path))?;
        let top = bars
            .iter()
            .map(|b| b.1)
            .filter(|v| v.is_finite())
            .fold(0.0f64, f64::max);
        let top = if top > 0.0 { top * 1.15 } else { 1.0 };
        let n = bars.len().max(1);
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d((0..n).into_segmented(), 0.0..top)
            .map_err(plot_error(path))?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .y_desc(y_label)
            .x_labels(n)
            .x_label_formatter(&|v| match v {
                SegmentValue::CenterOf(i) => bars.get(*i).map_or(String::new(), |b| b.0.clone()),
                _ => String::new(),
            })
            .draw()
            .map_err(plot_error(path))?;
        chart
            .draw_series(bars.iter().enumerate().map(|(i, (_, v))| {
                let v = if v.is_finite() { *v } else { 0.0 };
                Rectangle::new(
                    [
                        (SegmentValue::Exact(i), 0.0),
                        (SegmentValue::Exact(i + 1), v),
                    ],
                    COLORS[0].mix(0.8).filled(),
                )
            }))
            .map_err(plot_error(path))?;
        chart
            .draw_series(bars.iter().enumerate().map(|(i, (_, v))| {
                Text::new(
                    format!("{v:.2}"),
                    (SegmentValue::CenterOf(i), *v),
                    ("sans-serif", 13),
                )
            }))
            .map_err(plot_error(path))?;
        root.present().map_err(plot_error(path))?;
    }
    Ok(anerf_data::atomic::write_bytes(path, svg.as_bytes())?)
}

fn plot_error<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> EvalError + '_ {
    move |e| EvalError::Format {
        path: path.to_path_buf(),
        detail: format!("drawing the figure: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A log whose values reach the limits of f64 (and NaN, infinities, zeros on a log axis) is drawn:
    /// the drawing finishes and shows the ordinary points. It used to loop forever building the axes.
    #[test]
    fn a_log_with_extreme_values_is_drawn() {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let extreme = vec![
                (1.0, 0.5),
                (2.0, f64::MAX),
                (3.0, -f64::MAX),
                (f64::MAX, 0.25),
                (4.0, f64::NAN),
                (5.0, f64::INFINITY),
                (6.0, f64::MIN_POSITIVE),
                (7.0, 0.0),
                (8.0, 1e300),
                (9.0, 0.125),
            ];
            let panels: Vec<Panel> = [false, true]
                .into_iter()
                .map(|log_y| Panel {
                    title: "loss".into(),
                    x_label: "step".into(),
                    y_label: "loss".into(),
                    log_y,
                    curves: vec![Curve {
                        name: "extreme".into(),
                        points: extreme.clone(),
                    }],
                })
                .collect();
            tx.send(panels_svg(&panels).map_err(|e| e.to_string()))
                .unwrap();
        });
        // Generous: the drawing takes milliseconds; a hang is what this guards against.
        let svg = rx
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("drawing finished")
            .unwrap();
        assert!(
            svg.starts_with("<svg") && svg.contains("polyline"),
            "{}",
            &svg[..200.min(svg.len())]
        );
        assert!(
            !svg.contains("NaN") && !svg.contains("inf"),
            "no non-finite coordinate"
        );
    }
}
