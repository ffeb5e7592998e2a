//! A plot of rollouts against the ground truth: the planar path, depth, heading and position
//! error of a set's shortest, median and longest VPT (`pinc eval`'s figure).

use super::{VPT_THRESHOLD_M, full_rollouts, position_errors, vpt_of_rollouts};
use crate::dataset::TrajectorySet;
use crate::plot::{Panel, Series, figure};
use crate::runtime::Predictor;
use std::path::Path;

/// Unwraps the angles (deg) of a series in place: a heading crossing +-180 deg goes on past it
/// instead of jumping by 360.
fn unwrap_degrees(points: &mut [(f64, f64)]) {
    for k in 1..points.len() {
        points[k].1 = points[k - 1].1 + (points[k].1 - points[k - 1].1 + 180.0).rem_euclid(360.0) - 180.0;
    }
}

/// xy, z, psi and position error of three dev rollouts (shortest, median and longest VPT)
/// against the ground truth.
pub fn plot_rollouts(path: &Path, model: &crate::model::PincModel, set: &TrajectorySet) -> Result<(), String> {
    let p = Predictor::<f32>::new(model);
    let out = full_rollouts(&p, set).map_err(|e| e.to_string())?;
    let v = vpt_of_rollouts(&out, set);
    let mut idx: Vec<usize> = (0..set.count).collect();
    idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let picks = [idx[0], idx[idx.len() / 2], idx[idx.len() - 1]];
    let n = set.points;
    let t = |k: usize| k as f64 * set.dt;
    let labels: Vec<String> = picks.iter().map(|&i| format!("#{i} (VPT {:.2} s)", v[i])).collect();
    let truth_labels: Vec<String> = picks.iter().map(|&i| format!("#{i} truth (dashed)")).collect();
    let mut panels = Vec::new();
    let mut line = |title, y_label, log_y, f: &dyn Fn(&crate::State) -> (f64, f64), use_t: bool, unwrap_deg: bool| {
        let mut series = Vec::new();
        for (c, &i) in picks.iter().enumerate() {
            let pred = &out[i * n..(i + 1) * n];
            let truth = set.trajectory(i).0;
            let pts = |tr: &[crate::State]| -> Vec<(f64, f64)> {
                let mut p: Vec<(f64, f64)> =
                    tr.iter().enumerate().map(|(k, s)| if use_t { (t(k), f(s).1) } else { f(s) }).collect();
                if unwrap_deg {
                    unwrap_degrees(&mut p);
                }
                p
            };
            series.push(Series { label: &truth_labels[c], points: pts(truth), color: c, dashed: true });
            series.push(Series { label: &labels[c], points: pts(pred), color: c, dashed: false });
        }
        panels.push(Panel { title, x_label: if use_t { "t (s)" } else { "x (m)" }, y_label, log_y, series });
    };
    line("planar path", "y (m)", false, &|s| (s[0], s[1]), false, false);
    line("depth", "z (m, down)", false, &|s| (0.0, s[2]), true, false);
    line("heading", "psi (deg)", false, &|s| (0.0, s[4].atan2(s[3]).to_degrees()), true, true);
    let mut err_series: Vec<Series> = picks
        .iter()
        .enumerate()
        .map(|(c, &i)| Series {
            label: &labels[c],
            points: position_errors(&out[i * n..(i + 1) * n], set.trajectory(i).0)
                .into_iter()
                .enumerate()
                .map(|(k, e)| (t(k), e.max(1e-6)))
                .collect(),
            color: c,
            dashed: false,
        })
        .collect();
    err_series.push(Series {
        label: "0.05 m",
        points: vec![(0.0, VPT_THRESHOLD_M), (t(n - 1), VPT_THRESHOLD_M)],
        color: 6,
        dashed: true,
    });
    panels.push(Panel { title: "position error", x_label: "t (s)", y_label: "m", log_y: true, series: err_series });
    figure(path, 1400, 1000, 2, &panels)
}

#[cfg(test)]
mod tests {
    use super::unwrap_degrees;

    #[test]
    fn a_heading_across_180_deg_is_drawn_on_not_as_a_jump() {
        let mut p = vec![(0.0, 178.0), (0.08, -179.0), (0.16, -175.0), (0.24, 179.0)];
        unwrap_degrees(&mut p);
        let y: Vec<f64> = p.iter().map(|q| q.1).collect();
        assert_eq!(y, [178.0, 181.0, 185.0, 179.0]);
    }
}
