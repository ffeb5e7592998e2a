//! Stages 1 and 4, the estimate: each recording replayed through the state estimator on a
//! vehicle and a sensor model, and the smoothed estimate cut into windows and split in time.
//! Apart because every pass of the fit runs it, on the starting vehicle first and then on
//! the identified one.

use super::inputs::Content;
use super::sensor_model::Sensors;
use super::sensors::HorizontalNoise;
use super::{FitError, FitStart, Pipeline};
use crate::dataset::Dataset;
use crate::dataset::import::{ImportOptions, Recording, import};
use crate::estimation::NoiseSettings;
use crate::estimation::replay::{Replay, ReplaySettings, replay, replay_streams};
use crate::model::SensorModel;
use crate::types::{Input, SimState};
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use std::path::Path;

/// The fit's replays take the heave and yaw accelerations this many times less certain than
/// a live estimator does: the smoothed velocities then follow the readings more than the
/// starting file, whose motion the identification would otherwise find again (measured on
/// the firmware's recording: the effective heave mass came out 66 % over the simulator's at
/// 1, and moved toward it at 3; at 10 the readings no longer determined it).
const FIT_PROCESS_SCALE: f64 = 3.0;

/// The estimator's noise under a sensor model (and the horizontal readings' noise where it
/// was measured), for a fit's replays.
fn noise_of(s: &SensorModel, horizontal: Option<HorizontalNoise>, process_scale: f64) -> NoiseSettings {
    let d = NoiseSettings::default();
    let (position_std, velocity_ned_std) =
        horizontal.map_or((d.position_std, d.velocity_ned_std), |h| (h.position_std, h.velocity_std));
    let mut process_std = d.process_std;
    process_std[6] *= process_scale;
    process_std[7] *= process_scale;
    NoiseSettings {
        depth_std: s.depth_std,
        depth_delay: s.depth_delay,
        heading_std: s.heading_std,
        yaw_rate_std: s.yaw_rate_std,
        process_std,
        position_std,
        velocity_ned_std,
        ..d
    }
}

/// An estimate of a replay (its `smoothed` or `filtered` steps) as a recording: states and the
/// inputs held to the next.
fn recording_of(path: &Path, steps: &[crate::estimation::smoother::Smoothed]) -> Recording {
    let mut rec = Recording::empty(path);
    let mut last = Input::zeros();
    for s in steps {
        last = s.input.unwrap_or(last);
        rec.t.push(s.t);
        rec.states.push(SimState::from_fn(|i, _| s.state[i]));
        rec.inputs.push(last);
    }
    rec
}

impl Pipeline<'_> {
    /// Each recording replayed through the estimator on `vehicle` and `sensors`; `live`: the
    /// estimator as a live session runs it (its process noise unscaled).
    pub(super) fn replay_as(
        &self,
        vehicle: &VehicleParams,
        sensors: &Sensors,
        live: bool,
    ) -> Result<Vec<Replay>, FitError> {
        let settings = self.settings;
        let replay_settings = ReplaySettings {
            dt: settings.dt,
            surface_pressure: settings.surface_pressure,
            water_density: settings.water_density,
            noise: noise_of(&sensors.model, sensors.horizontal, if live { 1.0 } else { FIT_PROCESS_SCALE }),
            ignore_position: false,
        };
        self.logs
            .iter()
            .map(|log| {
                let model = Rk4Vehicle { params: *vehicle, ..Rk4Vehicle::with_dt(settings.dt) };
                match &log.content {
                    Content::Mavlink(messages) => {
                        replay(messages, model, Some(self.thrusters.clone()), &replay_settings)
                    }
                    Content::Streams(streams) => replay_streams(streams, model, &replay_settings),
                }
                .map_err(|e| FitError::Input { path: log.path.clone(), message: e.to_string() })
            })
            .collect()
    }

    pub(super) fn replay_all(&self, vehicle: &VehicleParams, sensors: &Sensors) -> Result<Vec<Replay>, FitError> {
        self.replay_as(vehicle, sensors, false)
    }

    /// The smoothed estimates as a dataset: windows, split in time; with
    /// [`FitStart::Estimated`], each point's start is the filter's estimate there.
    pub(super) fn dataset_of(&self, runs: &[Replay]) -> Result<Dataset, FitError> {
        let smoothed: Vec<Recording> =
            self.logs.iter().zip(runs).map(|(l, r)| recording_of(&l.path, &r.smoothed)).collect();
        let mut data = self.windows_of(&smoothed)?;
        if self.settings.start == FitStart::Estimated {
            let filtered: Vec<Recording> =
                self.logs.iter().zip(runs).map(|(l, r)| recording_of(&l.path, &r.filtered)).collect();
            let starts = self.windows_of(&filtered)?;
            for (set, from) in data.sets.iter_mut().zip(&starts.sets) {
                // The filter and the smoother step at the same times: the same windows.
                if (from.name.as_str(), from.count, from.points) != (set.name.as_str(), set.count, set.points) {
                    return Err(FitError::Data(format!(
                        "the filtered estimate cut into other windows than the smoothed one ({} {}x{} against {}x{})",
                        set.name, from.count, from.points, set.count, set.points
                    )));
                }
                set.starts = from.states.clone();
            }
        }
        Ok(data)
    }

    /// `recordings` cut into windows and split in time.
    fn windows_of(&self, recordings: &[Recording]) -> Result<Dataset, FitError> {
        let settings = self.settings;
        let hashes: Vec<String> = self.logs.iter().map(|l| l.sha256.clone()).collect();
        let options = ImportOptions {
            format: "mavlink".into(),
            dt: settings.dt,
            window: settings.window,
            split: settings.split,
            seed: settings.seed,
            collocation_points: 1,
            topics: None,
            gap_tolerance: None,
            dt_from_log: false,
        };
        import(recordings, &hashes, &options).map_err(|e| FitError::Data(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::FitSettings;
    use crate::fit::inputs::{Log, read_recording, starting_vehicle};
    use std::path::PathBuf;

    /// `FitStart::Estimated`: each point's start is the filter's estimate there, which the
    /// samples after the point never touched (the same with the recording cut short), while the
    /// targets stay the smoothed estimate (which the cut changes).
    #[test]
    fn estimated_starts_are_the_filters_own_and_see_nothing_after_their_point() {
        let dir = env!("CARGO_MANIFEST_DIR");
        let rec = PathBuf::from(format!("{dir}/tests/fixtures/ardusub/gps_designed_90s.mcap"));
        let vehicle = PathBuf::from(format!("{dir}/tests/fixtures/ardusub/sitl_vectored.toml"));
        let mut settings = FitSettings::new(vec![rec.clone()], vehicle);
        settings.start = FitStart::Estimated;
        settings.split = [1.0, 0.0, 0.0];
        let (base, thrusters, _) = starting_vehicle(&settings).unwrap();
        let Ok((Content::Mavlink(messages), _)) = read_recording(&rec, &thrusters, settings.water_density) else {
            panic!("the fixture reads as MAVLink");
        };
        let windows = |messages: Vec<_>| {
            let log = Log { path: rec.clone(), sha256: "0".repeat(64), content: Content::Mavlink(messages), cut: None };
            let pipeline = Pipeline { settings: &settings, base, thrusters: thrusters.clone(), logs: vec![log] };
            let runs = pipeline.replay_all(&base, &Sensors::default()).unwrap();
            pipeline.dataset_of(&runs).unwrap().set("train").unwrap().clone()
        };
        let whole = windows(messages.clone());
        let cut = windows(messages[..messages.len() * 2 / 3].to_vec());
        assert!(cut.count >= 10 && cut.count < whole.count, "{} {}", cut.count, whole.count);
        let n = cut.count * cut.points;
        assert_eq!(whole.starts.len(), whole.states.len());
        // Causal: every start the cut recording has is the whole one's, bit for bit.
        assert!(whole.starts[..n] == cut.starts[..n]);
        // The smoothed targets near the cut saw what came after it.
        let last = (cut.count - 1) * cut.points..n;
        assert!(whole.states[last.clone()] != cut.states[last]);
        // The starts are the filter's, not the targets: their velocities differ by what the
        // smoother added (measured 4.6, 6.8 and 1.0 cm/s RMS on u, v, w: the recording's first
        // 41 s have no position yet).
        let rms = |c: usize| {
            let sq: f64 = whole.starts.iter().zip(&whole.states).map(|(a, b)| (a[c] - b[c]).powi(2)).sum();
            (sq / whole.states.len() as f64).sqrt()
        };
        for c in 5..8 {
            assert!(rms(c) > 0.005 && rms(c) < 0.1, "component {c}: {}", rms(c));
        }
    }
}
