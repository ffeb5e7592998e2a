//! A reference signal over time: what the scenarios' depth and heading and a path's north and
//! east are made of.

use serde::Serialize;

/// A point of a track: `(time s, value)`.
type Point = (f64, f64);

/// A reference signal: linear between points, a step where two points share a time, held
/// before the first point and after the last.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Track {
    /// `(time s, value)`, times non-decreasing.
    points: Vec<(f64, f64)>,
}

impl Track {
    /// Steps: `value_i` from `t_i` on.
    pub(super) fn steps(steps: &[(f64, f64)]) -> Self {
        let mut points = vec![steps[0]];
        for w in steps.windows(2) {
            points.push((w[1].0, w[0].1));
            points.push(w[1]);
        }
        Self { points }
    }

    /// A value held for ever.
    pub fn constant(v: f64) -> Self {
        Self { points: vec![(0.0, v)] }
    }

    /// Points `(time s, value)`, times non-decreasing (the caller checked them).
    pub(super) fn from_points(points: Vec<(f64, f64)>) -> Self {
        Self { points }
    }

    /// The rate of change at `t` (0 where held or at a step).
    pub fn slope(&self, t: f64) -> f64 {
        match self.segment(t) {
            Ok(((t0, v0), (t1, v1))) if t1 > t0 => (v1 - v0) / (t1 - t0),
            _ => 0.0,
        }
    }

    /// The points either side of `t`, or the value held there (before the first point or
    /// after the last). The last point at or before `t` counts: the later of two at the same
    /// time, a step.
    fn segment(&self, t: f64) -> Result<(Point, Point), f64> {
        let i = self.points.partition_point(|p| p.0 <= t + 1e-9);
        match i {
            0 => Err(self.points[0].1),
            i if i == self.points.len() => Err(self.points[i - 1].1),
            i => Ok((self.points[i - 1], self.points[i])),
        }
    }

    /// The value at `t`.
    pub fn at(&self, t: f64) -> f64 {
        match self.segment(t) {
            Ok(((t0, v0), (t1, v1))) => v0 + (v1 - v0) * (t - t0) / (t1 - t0),
            Err(held) => held,
        }
    }

    /// The same track with every value moved by `by`.
    pub fn shifted(&self, by: f64) -> Self {
        Self { points: self.points.iter().map(|&(t, v)| (t, v + by)).collect() }
    }

    /// Time of the last point.
    pub fn end(&self) -> f64 {
        self.points.last().map_or(0.0, |p| p.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracks_are_linear_between_points_and_step_at_shared_times() {
        let t = Track::from_points(vec![(1.0, 0.0), (3.0, 2.0), (3.0, 5.0), (4.0, 5.0)]);
        assert_eq!(t.at(0.0), 0.0);
        assert!((t.at(2.0) - 1.0).abs() < 1e-12);
        assert!((t.at(2.999) - 1.999).abs() < 1e-9);
        assert_eq!(t.at(3.0), 5.0);
        assert_eq!(t.at(10.0), 5.0);
    }
}
