//! PNG plots (plotters, bitmap backend) with a bundled DejaVu Sans font, so text renders
//! on machines without system fonts.

use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

static FONT: Once = Once::new();

/// Registers the bundled font as plotters' "sans-serif" (once per process).
fn ensure_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        // The bundled file is a valid TrueType font; failure would leave plots without text.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, bytes);
    });
}

/// A plotting failure (file system or drawing backend), as text.
pub type PlotError = String;

fn err(e: impl std::fmt::Display) -> PlotError {
    e.to_string()
}

/// One named line of a panel.
pub struct Series<'a> {
    /// Legend label.
    pub label: &'a str,
    /// Points `(x, y)`.
    pub points: Vec<(f64, f64)>,
    /// Colour index into a fixed palette.
    pub color: usize,
    /// Dashed (reference, bound) rather than solid.
    pub dashed: bool,
}

/// One panel of a figure.
pub struct Panel<'a> {
    /// Title above the panel.
    pub title: &'a str,
    /// X-axis label.
    pub x_label: &'a str,
    /// Y-axis label.
    pub y_label: &'a str,
    /// Logarithmic y axis.
    pub log_y: bool,
    /// Lines.
    pub series: Vec<Series<'a>>,
}

/// The palette (colour-blind-safe Okabe–Ito).
pub fn color(i: usize) -> RGBColor {
    const C: [RGBColor; 8] = [
        RGBColor(0, 114, 178),
        RGBColor(213, 94, 0),
        RGBColor(0, 158, 115),
        RGBColor(204, 121, 167),
        RGBColor(230, 159, 0),
        RGBColor(86, 180, 233),
        RGBColor(0, 0, 0),
        RGBColor(240, 228, 66),
    ];
    C[i % C.len()]
}

fn bounds(panel: &Panel) -> ((f64, f64), (f64, f64)) {
    let pts = panel
        .series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|(x, y)| x.is_finite() && y.is_finite() && (!panel.log_y || *y > 0.0));
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, y) in pts {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if !x0.is_finite() {
        return ((0.0, 1.0), if panel.log_y { (1e-6, 1.0) } else { (0.0, 1.0) });
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    if panel.log_y {
        (y0, y1) = (y0 * 0.8, y1 * 1.25);
    } else {
        let pad = ((y1 - y0) * 0.05).max(1e-6);
        (y0, y1) = (y0 - pad, y1 + pad);
    }
    ((x0, x1), (y0, y1))
}

/// A linear-axis tick: as few digits as the value needs (`50`, `0.25`, `-1.5e-3`).
fn tick(v: f64) -> String {
    if v.abs() < 1e-12 {
        return "0".into(); // float noise on a tick that is meant to be zero
    }
    if !(1e-3..1e5).contains(&v.abs()) {
        return format!("{v:.1e}");
    }
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    panel: &Panel,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let ((x0, x1), (y0, y1)) = bounds(panel);
    let mut builder = ChartBuilder::on(area);
    builder.caption(panel.title, ("sans-serif", 18)).margin(8).x_label_area_size(36).y_label_area_size(64);
    macro_rules! finish {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(panel.x_label)
                .y_desc(panel.y_label)
                .x_label_formatter(&|x| tick(*x))
                .y_label_formatter(&|y| if panel.log_y { format!("{y:.0e}") } else { tick(*y) })
                .label_style(("sans-serif", 13))
                .draw()
                .map_err(err)?;
            for s in &panel.series {
                let c = color(s.color);
                let pts: Vec<(f64, f64)> =
                    s.points.iter().copied().filter(|(x, y)| x.is_finite() && y.is_finite()).collect();
                let anno = if s.dashed {
                    chart.draw_series(DashedLineSeries::new(pts, 6, 4, c.stroke_width(2))).map_err(err)?
                } else {
                    // Segment by segment: plotters joins a thick polyline with unlimited
                    // mitres, so a series that reverses sharply (a chattering input) would
                    // draw spikes far outside the panel.
                    let segments = pts.windows(2).map(|w| PathElement::new(vec![w[0], w[1]], c.stroke_width(2)));
                    chart.draw_series(segments).map_err(err)?
                };
                if !s.label.is_empty() {
                    anno.label(s.label)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
                }
            }
            if panel.series.iter().any(|s| !s.label.is_empty()) {
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .label_font(("sans-serif", 13))
                    .draw()
                    .map_err(err)?;
            }
        }};
    }
    if panel.log_y {
        finish!(builder.build_cartesian_2d(x0..x1, (y0..y1).log_scale()).map_err(err)?);
    } else {
        finish!(builder.build_cartesian_2d(x0..x1, y0..y1).map_err(err)?);
    }
    Ok(())
}

/// Draws `panels` in a grid of `cols` columns into a PNG of `width x height` pixels.
///
/// # Errors
/// The file cannot be written or a panel cannot be drawn.
pub fn figure(path: &Path, width: u32, height: u32, cols: usize, panels: &[Panel]) -> Result<(), PlotError> {
    ensure_font();
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let rows = panels.len().div_ceil(cols.max(1));
    let areas = root.split_evenly((rows, cols.max(1)));
    for (area, panel) in areas.iter().zip(panels) {
        draw_panel(area, panel)?;
    }
    root.present().map_err(|e| format!("{}: {e}", path.display()))
}
