//! The horizontal navigation of a live run against the simulator's truth, drawn: how far the
//! vehicle truly was from where control started, where pinc's estimate and the autopilot's
//! position put it, and each one's error, over the run (a DVL gap shows as the autopilot's
//! position stopping while pinc's dead reckoning follows the truth).

use crate::plot::{Panel, PlotError, Series, figure};
use std::path::Path;

/// Samples further apart than this (s) are drawn apart.
const GAP_S: f64 = 1.0;

/// A live run's navigation against the truth, per sample (scenario time s, metres).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NavigationTrack {
    /// Distance from where control started: the truth's, pinc's estimate's, the autopilot's
    /// position's (each from its own value then).
    pub truth: Vec<(f64, f64)>,
    /// pinc's estimate's distance from the point.
    pub pinc: Vec<(f64, f64)>,
    /// The autopilot's position's distance from the point, while it measured one.
    pub autopilot: Vec<(f64, f64)>,
    /// pinc's estimate's distance from the truth.
    pub pinc_error: Vec<(f64, f64)>,
    /// The autopilot's position's distance from the truth.
    pub autopilot_error: Vec<(f64, f64)>,
    /// Each change of pinc's navigation: scenario time, `measured` / `dead_reckoning` / `lost`.
    pub changes: Vec<(f64, &'static str)>,
}

impl NavigationTrack {
    /// Draws it to `path` (PNG): the distances from the point above, the errors below, the
    /// navigation's changes in the title.
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn plot(&self, path: &Path, title: &str) -> Result<(), PlotError> {
        let changes: Vec<String> = self.changes.iter().map(|(t, mode)| format!("{mode} at {t:.1} s")).collect();
        let top = format!("{title}: distance from where control started ({})", changes.join(", "));
        // A line broken where its samples stop for longer than a second (the autopilot's
        // position while it measures none), each piece labelled once.
        let line = |label: &'static str, points: &[(f64, f64)], color, dashed| -> Vec<Series<'static>> {
            points
                .chunk_by(|a, b| b.0 - a.0 <= GAP_S)
                .enumerate()
                .map(|(i, piece)| Series {
                    label: if i == 0 { label } else { "" },
                    points: piece.to_vec(),
                    color,
                    dashed,
                })
                .collect()
        };
        let panel = |title, y_label, series: Vec<Vec<Series<'static>>>| Panel {
            title,
            x_label: "time (s)",
            y_label,
            log_y: false,
            series: series.into_iter().flatten().collect(),
        };
        let panels = [
            panel(
                &top,
                "distance (m)",
                vec![
                    line("truth", &self.truth, 0, false),
                    line("pinc's estimate", &self.pinc, 1, false),
                    line("the autopilot's position", &self.autopilot, 2, true),
                ],
            ),
            panel(
                "distance from the truth",
                "error (m)",
                vec![
                    line("pinc's estimate", &self.pinc_error, 1, false),
                    line("the autopilot's position", &self.autopilot_error, 2, true),
                ],
            ),
        ];
        figure(path, 1200, 900, 1, &panels)
    }
}
