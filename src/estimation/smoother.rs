//! The Rauch-Tung-Striebel smoother: a filter's pass forward, run backward, so that each
//! estimate of a recorded log uses the measurements after it too. For logs, not for control.

use super::ekf::{FilterCovariance, FilterState};
use crate::types::{Input, NS};
use nalgebra::SMatrix;

/// One step of a filter's forward pass: the estimate after the step's measurements, and the
/// prediction to the next step with its transition matrix.
#[derive(Debug, Clone)]
pub struct ForwardStep {
    /// Time (s).
    pub t: f64,
    /// Estimate after this step's measurements.
    pub filtered: FilterState,
    /// Its covariance.
    pub filtered_p: FilterCovariance,
    /// The next step's prediction from this one (`None` at the last step of a run).
    pub next: Option<Prediction>,
}

/// A prediction one step on.
#[derive(Debug, Clone)]
pub struct Prediction {
    /// The predicted state.
    pub state: FilterState,
    /// Its covariance.
    pub p: FilterCovariance,
    /// The transition matrix used.
    pub f: FilterCovariance,
    /// The input applied over the step (without the estimated disturbance).
    pub input: Input,
}

/// A smoothed estimate.
#[derive(Debug, Clone, Copy)]
pub struct Smoothed {
    /// Time (s).
    pub t: f64,
    /// The state.
    pub state: FilterState,
    /// One standard deviation of each simulator-state part.
    pub std: [f64; NS],
    /// The input applied from this step to the next (`None` at the end of a run).
    pub input: Option<Input>,
}

/// One standard deviation of each simulator-state part of a covariance.
pub fn std_of(p: &FilterCovariance) -> [f64; NS] {
    std::array::from_fn(|i| p[(i, i)].max(0.0).sqrt())
}

/// Smooths one unbroken run of steps (each `next` but the last's set).
pub fn rts(steps: &[ForwardStep]) -> Vec<Smoothed> {
    let n = steps.len();
    let mut out = vec![None; n];
    let Some(last) = steps.last() else { return Vec::new() };
    let (mut x, mut p) = (last.filtered, last.filtered_p);
    out[n - 1] = Some(Smoothed { t: last.t, state: x, std: std_of(&p), input: None });
    for k in (0..n - 1).rev() {
        let s = &steps[k];
        let Some(pred) = &s.next else { break };
        // C = P_k|k F' P_{k+1|k}^-1, by a solve (P_{k+1|k} is symmetric positive definite).
        let gain: SMatrix<f64, { super::NE }, { super::NE }> = match pred.p.cholesky() {
            Some(ch) => ch.solve(&(pred.f * s.filtered_p)).transpose(),
            None => FilterCovariance::zeros(),
        };
        x = s.filtered + gain * (x - pred.state);
        p = s.filtered_p + gain * (p - pred.p) * gain.transpose();
        p = (p + p.transpose()) * 0.5;
        out[k] = Some(Smoothed { t: s.t, state: x, std: std_of(&p), input: Some(pred.input) });
    }
    out.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimation::{Ekf, Measurement, NoiseSettings};
    use crate::traits::DiscreteModel;
    use crate::types::{Input, SimState};
    use crate::vehicle::{Rk4Vehicle, to_network, to_simulator};

    /// On a simulated dive and turn measured by depth, heading and yaw rate only, the smoother's
    /// heave and yaw rate are closer to the truth than the filter's.
    #[test]
    fn smoothing_beats_filtering_on_a_known_motion() {
        let model = Rk4Vehicle::with_dt(0.08);
        // The simulated depth sensor below does not lag.
        let mut e = Ekf::new(model, NoiseSettings { depth_delay: 0.0, ..NoiseSettings::default() });
        let x0 = SimState::from([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        e.reset(0.0, &x0, &[10.0, 10.0, 0.1, 0.02, 0.3, 0.3, 0.3, 0.05]);
        let mut truth = x0;
        let mut seed = 7u64;
        let mut noise = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        let mut steps: Vec<ForwardStep> = Vec::new();
        let mut truths = Vec::new();
        for k in 0..400 {
            let t = k as f64 * 0.08;
            let u = Input::new(0.0, 0.0, 25.0 * (0.4 * t).sin(), 1.5 * (0.3 * t).sin());
            if k > 0 {
                let prior = (e.state().to_owned(), e.covariance().to_owned());
                e.predict(&u).unwrap();
                let last = steps.last_mut().unwrap();
                debug_assert_eq!(last.filtered, prior.0);
                last.next =
                    Some(Prediction { state: *e.state(), p: *e.covariance(), f: *e.last_transition(), input: u });
                let mut next = crate::types::State::zeros();
                model.step(&mut (), &to_network(&truth), &u, &mut next).unwrap();
                truth = to_simulator(&next);
            }
            // A noisy depth sensor (0.1 m, uniform), heading and yaw rate.
            e.update(&Measurement::Depth { t, z: truth[2] + 0.17 * noise() });
            e.update(&Measurement::Heading { t, psi: truth[3] + 0.02 * noise() });
            e.update(&Measurement::YawRate { t, r: truth[7] + 0.005 * noise() });
            steps.push(ForwardStep { t, filtered: *e.state(), filtered_p: *e.covariance(), next: None });
            truths.push(truth);
        }
        let smoothed = rts(&steps);
        assert_eq!(smoothed.len(), steps.len());
        let rms = |f: &dyn Fn(usize) -> f64| ((50..350).map(|k| f(k).powi(2)).sum::<f64>() / 300.0).sqrt();
        let (fw, sw) = (rms(&|k| steps[k].filtered[6] - truths[k][6]), rms(&|k| smoothed[k].state[6] - truths[k][6]));
        let (fz, sz) = (rms(&|k| steps[k].filtered[2] - truths[k][2]), rms(&|k| smoothed[k].state[2] - truths[k][2]));
        assert!(sw < fw && sz < fz, "w filtered {fw} smoothed {sw}; z filtered {fz} smoothed {sz}");
        assert!(smoothed[100].std[2] < steps[100].filtered_p[(2, 2)].sqrt());
    }
}
