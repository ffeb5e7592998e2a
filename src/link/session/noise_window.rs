//! The white noise of a sensor's two-axis readings (a USBL's fixes, a DVL's velocities),
//! measured as they come over a bounded window: what the sensor is, not what a setting guesses.

use crate::estimation::white_noise_std;
use std::collections::VecDeque;

/// The noise is measured again every this many readings, from the last [`WINDOW`] of them.
const EVERY: u64 = 16;
const WINDOW: usize = 240;

/// A sensor's newest readings `(t, a, b)`, their count and the noise measured on them.
#[derive(Debug, Default)]
pub(super) struct NoiseWindow {
    readings: VecDeque<(f64, f64, f64)>,
    count: u64,
    noise: Option<f64>,
}

impl NoiseWindow {
    /// Takes one reading; the noise when it was measured again with it.
    pub(super) fn push(&mut self, t: f64, a: f64, b: f64) -> Option<f64> {
        if self.readings.len() == WINDOW {
            self.readings.pop_front();
        }
        self.readings.push_back((t, a, b));
        self.count += 1;
        if !self.count.is_multiple_of(EVERY) {
            return None;
        }
        self.noise = white_noise_2d(self.readings.make_contiguous());
        self.noise
    }

    /// Readings taken.
    pub(super) fn count(&self) -> u64 {
        self.count
    }

    /// The newest reading's time.
    pub(super) fn newest(&self) -> Option<f64> {
        self.readings.back().map(|r| r.0)
    }

    /// The noise last measured (each axis's white noise, their mean).
    pub(super) fn noise(&self) -> Option<f64> {
        self.noise
    }
}

/// The white noise of two-axis readings: each axis's spread about the line through its
/// neighbours ([`white_noise_std`]), the two axes' mean; `None` for too few.
fn white_noise_2d(readings: &[(f64, f64, f64)]) -> Option<f64> {
    let a: Vec<(f64, f64)> = readings.iter().map(|&(t, a, _)| (t, a)).collect();
    let b: Vec<(f64, f64)> = readings.iter().map(|&(t, _, b)| (t, b)).collect();
    Some(0.5 * (white_noise_std(&a, false)? + white_noise_std(&b, false)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reading moving steadily on both axes with alternating errors of +-0.1: its white noise
    /// is the errors' (the steady motion is no noise), measured every 16 readings, from at most
    /// the newest 240.
    #[test]
    fn the_noise_is_measured_on_the_readings_and_not_their_motion() {
        let mut w = NoiseWindow::default();
        let mut measured = Vec::new();
        for k in 0..400 {
            let e = if k % 2 == 0 { 0.1 } else { -0.1 };
            let t = 0.25 * f64::from(k);
            measured.extend(w.push(t, 0.3 * t + e, -0.2 * t - e));
        }
        assert_eq!((w.count(), measured.len(), w.newest()), (400, 25, Some(99.75)));
        // Against the line through its neighbours a +-0.1 alternation is off by 0.2, over a
        // sqrt(1.5) spread of the three readings' noise, as a robust spread (1.4826 times the
        // median): 0.242.
        let want = 1.4826 * 0.2 / 1.5_f64.sqrt();
        assert!(measured.iter().all(|n| (n - want).abs() < 1e-9), "{measured:?}");
        assert_eq!(w.readings.len(), 240);
    }
}
