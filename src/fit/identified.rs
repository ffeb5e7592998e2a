//! Stages 1-5 composed: estimate on the starting vehicle, identify, fit the sensors, estimate
//! and identify again until the coefficients settle, fit the heave on the depth readings, take
//! in the heave gain; and what they found ([`Identified`]). Apart because both [`super::fit`]
//! and [`super::determinacy`] (the recording's watch) run exactly these stages.

use super::heave_gain::{HEAVE_GAIN_TOLERANCE, MAX_HEAVE_GAIN_STEPS, mean_heave_gain, with_heave_gain};
use super::heave_on_depth::{HeaveOnDepth, heave_on_depth};
use super::identification::coefficient;
use super::open_loop_depth::{self, OpenLoopDepth};
use super::sensor_model::{LagMethod, Sensors};
use super::sensors::{self, HorizontalNoise};
use super::{FitError, Pipeline, Stage, report};
use crate::dataset::Dataset;
use crate::estimation::NoiseSettings;
use crate::estimation::replay::Replay;
use crate::identify::Identification;
use crate::model::SensorModel;
use crate::vehicle::VehicleParams;

/// Most estimate-and-identify passes after the first.
const MAX_PASSES: usize = 8;
/// The passes stop once no heave or yaw coefficient moved more than this fraction.
const PASS_TOLERANCE: f64 = 0.01;

/// What the estimate-and-identify stages (1-5) found.
pub struct Identified {
    /// The identified vehicle.
    pub identification: Identification,
    /// The sensor model.
    pub sensors: SensorModel,
    /// The position source's noise as measured from its readings (`None`: no position source,
    /// or too few readings; the estimator's defaults were used).
    pub horizontal_noise: Option<HorizontalNoise>,
    /// Depth lags tried and the residual sum of squares at each.
    pub lag_scan: Vec<(f64, f64)>,
    /// What the depth lag was measured against.
    pub lag_method: LagMethod,
    /// Readings too few to measure their noise.
    pub sensors_defaulted: Vec<&'static str>,
    /// Whether a position or velocity source was fused.
    pub horizontal: bool,
    /// Estimate-and-identify passes on the fitted sensors.
    pub passes: usize,
    /// The heave fitted on the depth readings after the passes (`None`: too few whole
    /// segments, the identification's heave kept).
    pub heave_on_depth: Option<HeaveOnDepth>,
    /// The filter's mean heave gain after the passes and after each time it was taken in.
    pub heave_gains: Vec<f64>,
    pub(super) runs: Vec<Replay>,
    /// The replays' step (s).
    pub(super) dt: f64,
    /// The identified vehicle's depth open loop against the readings, computed once for the
    /// warnings and the report.
    pub open_loop_depth: OpenLoopDepth,
    /// The dataset the final identification and the training used.
    pub dataset: Dataset,
}

impl Identified {
    /// The report's warnings for the axes whose identified physics misses the held-out
    /// velocities ([`report::held_out_axes`]; none without held-out windows), and for a heave
    /// whose open-loop depth misses the readings ([`open_loop_depth`]).
    pub(super) fn bias_warnings(&self) -> Vec<String> {
        let mut warnings = match self.dataset.set("test").filter(|s| s.count > 0) {
            Some(test) => {
                report::bias_warnings(&report::held_out_axes(&self.identification.vehicle, test, self.horizontal))
            }
            None => Vec::new(),
        };
        warnings.extend(open_loop_depth::warning(&self.open_loop_depth));
        warnings
    }

    /// `vehicle`'s depth rolled out open loop from the recorded thrust against the depth
    /// readings of these recordings ([`open_loop_depth::open_loop_depth`]).
    pub fn open_loop_depth_of(&self, vehicle: &VehicleParams) -> OpenLoopDepth {
        open_loop_depth::open_loop_depth(vehicle, &self.runs, self.dt, self.sensors.depth_delay)
    }
}

impl Pipeline<'_> {
    /// Stages 1-5: estimate on the starting vehicle, identify, fit the sensors, estimate and
    /// identify again until the heave and yaw coefficients settle, fit the heave on the depth
    /// readings, take in the heave gain.
    pub(super) fn identified(&self, on_stage: &mut impl FnMut(Stage)) -> Result<Identified, FitError> {
        // Pass 1: the starting vehicle and the estimator's default sensors.
        on_stage(Stage::Estimate);
        let first = self.replay_all(&self.base, &Sensors::default())?;
        let horizontal = first.iter().any(|r| r.horizontal);
        on_stage(Stage::Identify);
        let rough = self.identify_on(&self.dataset_of(&first)?, horizontal)?;
        let (model, sensors_defaulted, lag_scan, lag_method) = self.sensors(&first, on_stage);
        // The position source's own noise, from its readings: at the live default (0.3 m, for
        // a position that may be an acoustic fix) the filter's surge and sway followed the
        // vehicle file it ran on, and the identification found that file again (on the
        // firmware's GPS, the simulator's sway drag 62 came out 84-94; measured 0.01 m here).
        let measurements: Vec<_> = first.iter().flat_map(|r| r.measurements.iter().copied()).collect();
        let horizontal_noise = match sensors::horizontal_noise(&measurements) {
            [Some(position_std), velocity] => Some(HorizontalNoise {
                position_std,
                velocity_std: velocity.unwrap_or(NoiseSettings::default().velocity_ned_std),
            }),
            _ => None,
        };
        let sensors = Sensors { model, horizontal: horizontal_noise };

        // Pass 2: the identified vehicle and the fitted sensors.
        on_stage(Stage::Refine);
        let mut vehicle = rough.vehicle;
        let mut passes = 0;
        let (runs, dataset, mut identification) = loop {
            let runs = self.replay_all(&vehicle, &sensors)?;
            let data = self.dataset_of(&runs)?;
            let id = self.identify_on(&data, horizontal)?;
            passes += 1;
            let surge_sway: &[&str] = if horizontal { &["x_ud", "x_u", "x_uu", "y_vd", "y_v", "y_vv"] } else { &[] };
            let moved = ["volume", "z_wd", "z_w", "z_ww", "n_rd", "n_r", "n_rr"].iter().chain(surge_sway).any(|k| {
                let (a, b) = (coefficient(&vehicle, k), coefficient(&id.vehicle, k));
                (a - b).abs() > PASS_TOLERANCE * a.abs().max(b.abs()).max(1e-9)
            });
            vehicle = id.vehicle;
            if !moved || passes == MAX_PASSES {
                break (runs, data, id);
            }
        };

        // The heave on the depth readings themselves: from the smoothed heave rate the
        // identification takes the depth sensor's noise for drag (docs/MODEL.md section 10.1).
        let segments = open_loop_depth::depth_segments(&runs, self.settings.dt, sensors.model.depth_delay);
        let heave_on_depth = heave_on_depth(&identification, &self.base, &segments, self.settings.dt);
        if let Some(h) = &heave_on_depth {
            h.apply_to(&mut identification);
        }

        // The heave force the identified vehicle still misses: the heave gain (docs/MODEL.md
        // section 12) that the estimator, run as a live session runs it, estimates from the
        // depth itself, where the identification from smoothed velocities leaves part of it
        // (measured on the firmware's recording: a gain of about 0.3 in flight after the
        // passes). The heave equation takes the gain in until the estimator finds none.
        let mut heave_gains = Vec::new();
        loop {
            let gain = mean_heave_gain(&self.replay_as(&identification.vehicle, &sensors, true)?);
            heave_gains.push(gain);
            if gain.abs() < HEAVE_GAIN_TOLERANCE || heave_gains.len() > MAX_HEAVE_GAIN_STEPS {
                break;
            }
            identification.vehicle = with_heave_gain(identification.vehicle, gain);
        }
        let (runs, dataset) = if heave_gains.len() > 1 || heave_on_depth.is_some() {
            let runs = self.replay_all(&identification.vehicle, &sensors)?;
            let data = self.dataset_of(&runs)?;
            (runs, data)
        } else {
            (runs, dataset)
        };
        let open_loop_depth = open_loop_depth::open_loop_depth(
            &identification.vehicle,
            &runs,
            self.settings.dt,
            sensors.model.depth_delay,
        );
        Ok(Identified {
            identification,
            sensors: sensors.model,
            horizontal_noise: sensors.horizontal,
            lag_scan,
            lag_method,
            sensors_defaulted,
            horizontal,
            passes,
            heave_on_depth,
            heave_gains,
            runs,
            dt: self.settings.dt,
            open_loop_depth,
            dataset,
        })
    }
}

/// A firmware fixture (tests/fixtures/ardusub) by name.
#[cfg(test)]
pub(super) fn fixture(name: &str) -> std::path::PathBuf {
    std::path::PathBuf::from(format!("{}/tests/fixtures/ardusub/{name}", env!("CARGO_MANIFEST_DIR")))
}

/// Stages 1-5 on one of the firmware's recordings, from the simulator's thrusters and a
/// BlueROV2's hull (`sitl_vectored.toml`), as `pinc fit` runs them.
#[cfg(test)]
pub(super) fn identified_on_fixture(recording: &str) -> Identified {
    use super::FitSettings;
    use super::inputs::{Log, read_recording, starting_vehicle};
    let rec = fixture(recording);
    let settings = FitSettings::new(vec![rec.clone()], fixture("sitl_vectored.toml"));
    let (base, thrusters, _) = starting_vehicle(&settings).unwrap();
    let (content, _) = read_recording(&rec, &thrusters, settings.water_density).unwrap();
    let log = Log { path: rec, sha256: "0".repeat(64), content, cut: None };
    let pipeline = Pipeline { settings: &settings, base, thrusters, logs: vec![log] };
    pipeline.identified(&mut |_| {}).unwrap()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On the firmware's GPS recording the fit measures the position source's noise (at its
    /// floor: the autopilot's position is smooth) and identifies surge and sway near the
    /// simulator's drag; the held-out check passes the simulator's own file and flags one with
    /// the drag of a biased fit, on surge and sway only.
    #[test]
    fn a_biased_surge_and_sway_show_in_the_held_out_velocities() {
        let found = identified_on_fixture("gps_designed_90s.mcap");
        let noise = found.horizontal_noise.unwrap();
        assert_eq!((noise.position_std, noise.velocity_std), (0.01, 0.01));
        // Quadratic drag against the simulator's 48.3 and 62.1 (measured 50.3 and 56.3 with
        // linear terms of 0.3 and 4.1; 51.5 and 71.7 at the estimator's 0.3 m default).
        let v = &found.identification.vehicle;
        for (drag, truth) in [(v.x_uu, -48.3), (v.y_vv, -62.1)] {
            assert!((drag / truth - 1.0).abs() < 0.15, "{drag} against {truth}");
        }
        let truth = VehicleParams::load(fixture("sitl_truth.toml")).unwrap();
        let test = found.dataset.set("test").unwrap();
        let axes = report::held_out_axes(&truth, test, true);
        assert!(axes.iter().all(|a| a.judged && !a.biased), "{axes:?}");
        let biased = VehicleParams { x_u: -20.4, x_uu: -26.8, y_vv: -98.8, ..truth };
        let axes = report::held_out_axes(&biased, test, true);
        let flagged: Vec<&str> = axes.iter().filter(|a| a.biased).map(|a| a.axis).collect();
        assert_eq!(flagged, ["surge", "sway"], "{axes:?}");
        assert_eq!(report::bias_warnings(&axes).len(), 2);
        assert!(found.bias_warnings().is_empty());
    }
}
