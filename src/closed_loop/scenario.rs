//! The tracking scenarios: references over time (built in, or from a CSV file) and the plant
//! each runs against.

use super::path_plan::{HorizontalPlan, PathHeading, PathLimits, PlannedPath, survey};
use super::track::Track;
use crate::mpc::{Horizontal, Reference};
use crate::types::{Input, SimState};
use crate::vehicle::{Rk4Vehicle, VehicleParams};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// A reference file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceFileError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The content is not a reference table.
    #[error("{path}: line {line}: {message}")]
    Malformed {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: u64,
        /// What is wrong.
        message: String,
    },
}

/// Depth reference steps of the built-in scenarios `(time s, depth m)`.
const DEPTH_STEPS: [(f64, f64); 4] = [(0.0, 0.0), (2.0, 1.0), (20.0, 2.0), (40.0, 0.5)];
/// Heading reference steps `(time s, heading deg)`.
const HEADING_STEPS: [(f64, f64); 4] = [(0.0, 0.0), (10.0, 45.0), (30.0, -30.0), (50.0, 0.0)];

/// A closed-loop scenario: depth and heading references over time and the plant they run
/// against (the vehicle given to [`Scenario::plant`], with this scenario's disturbance).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Scenario {
    /// The name used on the command line and in logs (a file's stem for a reference file).
    pub name: String,
    /// Depth reference (m, positive down).
    pub depth: Track,
    /// Heading reference (deg).
    pub heading: Track,
    /// Length of the run (s).
    pub duration: f64,
    /// Factor on every damping coefficient of the plant.
    pub damping_scale: f64,
    /// Water velocity in the world frame `(x, y)` (m/s).
    pub current: [f64; 2],
    /// The horizontal goal: a point held or a path (`None`: depth and heading only).
    pub horizontal: Option<HorizontalPlan>,
    /// Whether the depth and heading tracks are offsets from where the vehicle is when control
    /// starts (`hold`: where it is, held), rather than depths and headings of their own.
    pub from_start: bool,
}

/// How long `hold` lasts unless told (s): until STOP, in practice.
pub const HOLD_DURATION_S: f64 = 3600.0;

/// The current of the built-in four-axis scenarios: 0.3 m/s towards 30 deg east of north
/// (along no axis of the vehicle or the world).
pub const FOUR_AXIS_CURRENT: [f64; 2] = [0.259_807_621_135_331_6, 0.15];

impl Default for Scenario {
    /// `default`: 60 s from rest at the surface; depth 0 -> 1 m (2 s) -> 2 m (20 s) -> 0.5 m
    /// (40 s); heading 0 -> 45 deg (10 s) -> -30 deg (30 s) -> 0 (50 s); the nominal plant.
    fn default() -> Self {
        Self {
            name: "default".into(),
            depth: Track::steps(&DEPTH_STEPS),
            heading: Track::steps(&HEADING_STEPS),
            duration: 60.0,
            damping_scale: 1.0,
            current: [0.0, 0.0],
            horizontal: None,
            from_start: false,
        }
    }
}

impl Scenario {
    /// `disturbed`: the references of `default`; the plant's damping is 20 % higher and a
    /// 0.1 m/s current flows along the world x axis.
    pub fn disturbed() -> Self {
        Self { name: "disturbed".into(), damping_scale: 1.2, current: [0.1, 0.0], ..Self::default() }
    }

    /// References from a CSV file with header `t,depth_m,heading_deg`: linear between rows
    /// (heading in the numbers given: write 190, not -170, to turn on through 180), a step
    /// where two rows share a time, held after the last row. The run lasts until the last
    /// row's time unless `duration` says otherwise. The plant is the nominal one.
    ///
    /// # Errors
    /// The file cannot be read, its header differs, a field is not a finite number, a time
    /// goes backwards, there are no rows, or the run would last no time.
    pub fn from_file(path: &Path, duration: Option<f64>) -> Result<Self, ReferenceFileError> {
        let bad = |line: u64, message: String| ReferenceFileError::Malformed { path: path.into(), line, message };
        let file = std::fs::File::open(path).map_err(|source| ReferenceFileError::Io { path: path.into(), source })?;
        let mut reader = csv::ReaderBuilder::new().trim(csv::Trim::All).from_reader(file);
        let header = reader.headers().map_err(|e| bad(1, e.to_string()))?.clone();
        if header.iter().ne(["t", "depth_m", "heading_deg"]) {
            let found: Vec<&str> = header.iter().collect();
            return Err(bad(1, format!("header must be t,depth_m,heading_deg, found {}", found.join(","))));
        }
        let (mut depth, mut heading) = (Vec::new(), Vec::new());
        for record in reader.records() {
            let record = record.map_err(|e| bad(e.position().map_or(0, |p| p.line()), e.to_string()))?;
            let line = record.position().map_or(0, |p| p.line());
            let mut v = [0.0; 3];
            for (j, name) in ["t", "depth_m", "heading_deg"].iter().enumerate() {
                let text = record.get(j).unwrap_or("");
                v[j] = text
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| bad(line, format!("{name}: {text:?} is not a finite number")))?;
            }
            if let Some(&(t_prev, _)) = depth.last()
                && v[0] < t_prev
            {
                return Err(bad(line, format!("t = {} comes before the previous row's {t_prev}", v[0])));
            }
            depth.push((v[0], v[1]));
            heading.push((v[0], v[2]));
        }
        if depth.is_empty() {
            return Err(bad(1, "no rows after the header".into()));
        }
        let depth = Track::from_points(depth);
        let duration = duration.unwrap_or(depth.end());
        if !(duration.is_finite() && duration > 0.0) {
            return Err(bad(1, format!("the run would last {duration} s; give --duration or rows up to a later time")));
        }
        let name = path.file_stem().map_or_else(|| "reference".into(), |s| s.to_string_lossy().into_owned());
        Ok(Self {
            name,
            depth,
            heading: Track::from_points(heading),
            duration,
            damping_scale: 1.0,
            current: [0.0, 0.0],
            horizontal: None,
            from_start: false,
        })
    }

    /// `station`: 60 s holding the point where control starts in [`FOUR_AXIS_CURRENT`],
    /// diving to 1 m, stepping to 2 m at 30 s, turning from 0 to 45 deg at 20 s.
    pub fn station() -> Self {
        Self {
            name: "station".into(),
            depth: Track::steps(&[(0.0, 1.0), (30.0, 2.0)]),
            heading: Track::steps(&[(0.0, 0.0), (20.0, 45.0)]),
            duration: 60.0,
            damping_scale: 1.0,
            current: FOUR_AXIS_CURRENT,
            horizontal: Some(HorizontalPlan::station()),
            from_start: false,
        }
    }

    /// `hold`: holding the point, the depth and the heading the vehicle has when control starts
    /// (a live vehicle's estimate at its first cycle; the simulated one starts at rest at the
    /// surface), for an hour unless told, in [`FOUR_AXIS_CURRENT`]. What "hold here" flies.
    pub fn hold() -> Self {
        Self {
            name: "hold".into(),
            depth: Track::steps(&[(0.0, 0.0)]),
            heading: Track::steps(&[(0.0, 0.0)]),
            duration: HOLD_DURATION_S,
            damping_scale: 1.0,
            current: FOUR_AXIS_CURRENT,
            horizontal: Some(HorizontalPlan::station()),
            from_start: true,
        }
    }

    /// This scenario as flown from a start at `depth` (m) and `heading` (rad): a scenario
    /// [`from_start`](Self::from_start) has its depth and heading tracks moved there (the
    /// heading track in degrees, continued from the start's heading); any other is itself.
    pub fn started_at(&self, depth: f64, heading: f64) -> Self {
        if !self.from_start {
            return self.clone();
        }
        let heading = heading.to_degrees();
        Self {
            depth: self.depth.shifted(depth),
            heading: self.heading.shifted(heading),
            from_start: false,
            ..self.clone()
        }
    }

    /// A scenario flying `path` (named `name`) in `current`, lasting until 5 s after its last
    /// waypoint unless `duration` says otherwise.
    pub fn along(name: &str, path: PlannedPath, current: [f64; 2], duration: Option<f64>) -> Self {
        let duration = duration.unwrap_or(path.horizontal.end() + 5.0);
        Self {
            name: name.into(),
            depth: path.depth,
            heading: path.heading,
            duration,
            damping_scale: 1.0,
            current,
            horizontal: Some(path.horizontal),
            from_start: false,
        }
    }

    /// `survey`: 4 legs of 10 m northwards and back, 2 m apart, at 0.3 m/s and 2 m deep, facing
    /// north, in [`FOUR_AXIS_CURRENT`], after
    /// [`PATH_LEAD_S`](super::path_plan::PATH_LEAD_S) holding the start.
    pub fn survey() -> Self {
        let limits = PathLimits { max_speed: f64::INFINITY, max_distance: None };
        let path =
            survey((4, 10.0, 2.0), 0.3, 2.0, PathHeading::Fixed(0.0), &limits).expect("the built-in survey is valid");
        Self::along("survey", path, FOUR_AXIS_CURRENT, None)
    }

    /// The name used on the command line and in logs.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Length of the run (s).
    pub fn duration(&self) -> f64 {
        self.duration
    }

    /// The reference at time `t`, its horizontal goal (if any) in the plan's own frame.
    pub fn reference(&self, t: f64) -> Reference {
        self.reference_from(t, [0.0, 0.0])
    }

    /// The reference at time `t` with the horizontal goal moved by `offset` (north, east):
    /// where the vehicle started, for a plan measured from the start.
    pub fn reference_from(&self, t: f64, offset: [f64; 2]) -> Reference {
        let horizontal = self.horizontal.as_ref().map(|h| {
            let ([n, e], velocity) = h.at(t);
            Horizontal { north: n + offset[0], east: e + offset[1], velocity }
        });
        Reference { depth: self.depth.at(t), heading: self.heading.at(t).to_radians(), horizontal }
    }

    /// The plant of this scenario for `vehicle`, sampled at `dt`.
    pub fn plant(&self, dt: f64, vehicle: &VehicleParams) -> Plant {
        let mut vehicle = Rk4Vehicle { params: *vehicle, ..Rk4Vehicle::with_dt(dt) };
        if self.damping_scale != 1.0 {
            vehicle.params = vehicle.params.with_damping_scaled(self.damping_scale);
        }
        Plant { vehicle, current: self.current }
    }
}

/// The simulated vehicle: body velocities are relative to the water, which moves with a
/// constant world-frame `current`; with no position dependence in the dynamics that adds
/// exactly `current * dt` to the position each sample.
#[derive(Debug, Clone)]
pub struct Plant {
    /// The vehicle and its integrator.
    pub vehicle: Rk4Vehicle,
    /// Water velocity in the world frame `(x, y)` (m/s).
    pub current: [f64; 2],
}

impl Plant {
    /// One sample period under the held input `u`.
    pub fn step(&self, s: &SimState, u: &Input) -> SimState {
        let mut next = self.vehicle.step_sim(s, u);
        next[0] += self.current[0] * self.vehicle.dt;
        next[1] += self.current[1] * self.vehicle.dt;
        next
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn references_follow_the_scenario_schedule() {
        let s = Scenario::default();
        assert_eq!(s.reference(1.99).depth, 0.0);
        assert_eq!(s.reference(2.0).depth, 1.0);
        assert_eq!(s.reference(45.0).depth, 0.5);
        assert!((s.reference(10.0).heading - 45f64.to_radians()).abs() < 1e-12);
        assert!((s.reference(35.0).heading + 30f64.to_radians()).abs() < 1e-12);
        assert_eq!(s.reference(59.0).heading, 0.0);
        assert_eq!(s.reference(100.0).depth, 0.5);
    }

    #[test]
    fn the_current_moves_the_disturbed_plant_exactly_by_current_times_dt() {
        let (nominal, disturbed) = {
            let v = VehicleParams::default();
            (Scenario::default().plant(0.08, &v), Scenario::disturbed().plant(0.08, &v))
        };
        let s = SimState::from([0.0, 0.0, 1.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        let u = Input::zeros();
        let a = nominal.step(&s, &u);
        let b = disturbed.step(&s, &u);
        // At rest the damping does not act, so only the drift differs.
        assert!((b[0] - a[0] - 0.008).abs() < 1e-12 && (b[1] - a[1]).abs() < 1e-12);
    }
}
