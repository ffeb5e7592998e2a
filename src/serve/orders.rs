//! What the page asks for, checked against the vehicle's limits before anything is sent: an
//! excitation, a fit, a flight. Each refusal names the field and what is wrong.

use serde::Deserialize;
use std::fmt::Write as _;

/// The vehicle's limits: depth, distance and duration the owner sets on the page (kept in the
/// data folder's `limits.json`; `pinc serve`'s flags give them until then), and the data folder's
/// size (a flag).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Deepest depth (m) any reference, band or stop may ask for.
    pub max_depth: f64,
    /// Longest excitation or scripted flight (s); the hold and pilot assist run until STOP.
    pub max_duration: f64,
    /// The farthest a flight may go from where it starts (m).
    pub max_distance: f64,
    /// The most the data folder may hold (bytes).
    pub max_data_bytes: f64,
}

/// The limits a dive starts with until the owner sets their own: a BlueROV2's enclosures are
/// rated to 100 m (the standard) and its tether is commonly 100-300 m; half of the rating, a
/// third of the shortest tether, and half an hour for an excitation or a scripted flight.
pub const DIVE_LIMITS: DiveLimits = DiveLimits { max_depth: 50.0, max_distance: 100.0, max_duration: 1800.0 };

/// The limits the page shows and sets, as `limits.json` keeps them.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DiveLimits {
    /// Deepest (m): every run stops past it, and nothing may ask for more.
    pub max_depth: f64,
    /// Farthest from where a flight starts (m).
    pub max_distance: f64,
    /// Longest excitation or scripted flight (s).
    pub max_duration: f64,
}

/// What the page may set each limit to: up to a BlueROV2 Heavy's 300 m enclosures, a kilometre,
/// a day.
const LIMIT_RANGES: [(&str, f64, &str); 3] =
    [("max_depth", 300.0, "m"), ("max_distance", 1000.0, "m"), ("max_duration", 86400.0, "s")];

impl DiveLimits {
    /// # Errors
    /// A limit that is not a positive number within its range, named with the range.
    pub fn check(&self) -> Result<(), String> {
        let values = [self.max_depth, self.max_distance, self.max_duration];
        for ((field, most, unit), v) in LIMIT_RANGES.into_iter().zip(values) {
            if !(v.is_finite() && v > 0.0 && v <= most) {
                return Err(format!("{field} {v} {unit} must be above 0 and at most {most} {unit}"));
            }
        }
        Ok(())
    }

    /// These limits with the data folder's size limit.
    pub fn with_data_bytes(self, max_data_bytes: f64) -> Limits {
        Limits {
            max_depth: self.max_depth,
            max_duration: self.max_duration,
            max_distance: self.max_distance,
            max_data_bytes,
        }
    }
}

/// How long the hold and pilot assist run (s): until STOP, the deadman or the page closed, in
/// practice (a day).
pub const UNTIL_STOP_S: f64 = 86400.0;

/// What a run writes per second, at most (bytes): a flight's MCAP log is about 21 kB/s (the
/// firmware tests' 60 s flights: 1.29 MB), doubled for its plots and a margin.
pub const RUN_BYTES_PER_S: f64 = 40e3;
/// What any run writes besides (bytes): summaries, plots, a fit's report.
pub const RUN_BYTES_FIXED: f64 = 5e6;

/// The room a run of `duration` s needs, checked against what the data folder holds
/// (`used`, bytes), its limit and the disk's free space (`free`, bytes).
///
/// # Errors
/// Past the limit, or more than the disk has, in words with the figures.
pub fn room_for(duration: f64, used: u64, free: Option<u64>, limits: &Limits) -> Result<(), String> {
    let needed = RUN_BYTES_FIXED + RUN_BYTES_PER_S * duration;
    let mb = |b: f64| b / 1e6;
    if used as f64 + needed > limits.max_data_bytes {
        return Err(format!(
            "refused: the data folder holds {:.0} MB of its {:.0} MB (pinc serve --max-data-mb) and a {duration:.0} s \
             run needs about {:.0} MB more: delete old runs first",
            mb(used as f64),
            mb(limits.max_data_bytes),
            mb(needed)
        ));
    }
    if let Some(free) = free
        && (free as f64) < needed
    {
        return Err(format!(
            "refused: the data folder's disk has {:.0} MB free and a {duration:.0} s run needs about {:.0} MB",
            mb(free as f64),
            mb(needed)
        ));
    }
    Ok(())
}

/// The designed excitation's axes.
const AXES: [&str; 4] = ["surge", "sway", "heave", "yaw"];

/// `POST api/excite`.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct ExciteOrder {
    /// Depth band TOP,BOTTOM (m).
    pub depth_band: [f64; 2],
    pub axes: Vec<String>,
    /// Longest the excitation plays (s): the watch stops it earlier once the fit would pass.
    pub duration: f64,
    #[serde(default)]
    pub seed: u64,
    /// Play the whole file (no watch stop).
    #[serde(default)]
    pub keep_going: bool,
}

/// `POST api/fit`.
#[derive(Deserialize, Debug)]
#[serde(deny_unknown_fields)]
pub struct FitOrder {
    /// A recording's name in the data folder.
    pub recording: String,
    #[serde(default = "default_epochs")]
    pub epochs: usize,
}

fn default_epochs() -> usize {
    30
}

/// `POST api/fly`.
#[derive(Deserialize, Debug, Clone)]
#[serde(deny_unknown_fields)]
pub struct FlyOrder {
    /// A fitted model's name (its folder in `models`).
    pub model: String,
    pub references: References,
    /// Length (s).
    pub duration: f64,
}

/// What the flight tracks.
#[derive(Deserialize, Debug, Clone)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum References {
    /// Depth FROM then TO at AT (s); heading likewise (deg).
    Steps { depth: [f64; 2], depth_at: f64, heading: [f64; 2], heading_at: f64 },
    /// Hold the depth, heading and position (where one is known) the vehicle has when control
    /// starts, until STOP or "resume".
    Hold,
    /// A lawnmower from the start: width, length, spacing (m), speed (m/s), depth (m).
    Survey { width: f64, length: f64, spacing: f64, speed: f64, depth: f64 },
    /// The page's gamepad: what full sticks ask for, surge, sway, heave (m/s), yaw (deg/s)
    /// (none: the model's default share).
    Pilot {
        #[serde(default)]
        speeds: Option<[f64; 4]>,
    },
    /// The pilot's joystick in Cockpit (`pinc serve --joystick`): the same speeds as the gamepad's.
    Joystick {
        #[serde(default)]
        speeds: Option<[f64; 4]>,
    },
}

fn finite(field: &str, v: f64) -> Result<f64, String> {
    if v.is_finite() { Ok(v) } else { Err(format!("{field} must be a number, got {v}")) }
}

fn depth(field: &str, v: f64, limits: &Limits) -> Result<f64, String> {
    let v = finite(field, v)?;
    if (0.0..=limits.max_depth).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{field} {v} m is outside the vehicle's limits: 0 to {} m (the limits on the page)",
            limits.max_depth
        ))
    }
}

fn duration(field: &str, v: f64, limits: &Limits) -> Result<f64, String> {
    let v = finite(field, v)?;
    if v > 0.0 && v <= limits.max_duration {
        Ok(v)
    } else {
        Err(format!("{field} {v} s must be above 0 and at most {} s (the limits on the page)", limits.max_duration))
    }
}

fn positive(field: &str, v: f64) -> Result<f64, String> {
    let v = finite(field, v)?;
    if v > 0.0 { Ok(v) } else { Err(format!("{field} must be above 0, got {v}")) }
}

impl ExciteOrder {
    pub fn check(&self, limits: &Limits) -> Result<(), String> {
        let [top, bottom] = self.depth_band;
        depth("depth_band top", top, limits)?;
        depth("depth_band bottom", bottom, limits)?;
        if bottom - top < 0.5 {
            return Err(format!("depth_band {top},{bottom}: the bottom must be at least 0.5 m below the top"));
        }
        duration("duration", self.duration, limits)?;
        if self.axes.is_empty() {
            return Err("axes: choose at least one of surge, sway, heave, yaw".into());
        }
        if let Some(a) = self.axes.iter().find(|a| !AXES.contains(&a.as_str())) {
            return Err(format!("axes: unknown axis {a:?} (surge, sway, heave, yaw)"));
        }
        Ok(())
    }
}

impl FitOrder {
    pub fn check(&self) -> Result<(), String> {
        if (1..=2000).contains(&self.epochs) {
            Ok(())
        } else {
            Err(format!("epochs {} must be 1 to 2000", self.epochs))
        }
    }
}

impl FlyOrder {
    pub fn check(&self, limits: &Limits) -> Result<(), String> {
        if !self.until_stop() {
            duration("duration", self.duration, limits)?;
        }
        match &self.references {
            References::Steps { depth: [a, b], depth_at, heading: [h0, h1], heading_at } => {
                depth("depth from", *a, limits)?;
                depth("depth to", *b, limits)?;
                for (field, v) in [("heading from", h0), ("heading to", h1)] {
                    finite(field, *v)?;
                }
                for (field, at) in [("depth_at", depth_at), ("heading_at", heading_at)] {
                    if !(finite(field, *at)? >= 0.0 && *at <= self.duration) {
                        return Err(format!("{field} {at} s must be within the flight (0 to {} s)", self.duration));
                    }
                }
            }
            References::Hold => {}
            References::Pilot { speeds: Some(speeds) } | References::Joystick { speeds: Some(speeds) } => {
                for (field, v) in ["surge", "sway", "heave", "yaw"].into_iter().zip(speeds) {
                    positive(&format!("speeds {field}"), *v)?;
                }
            }
            References::Pilot { speeds: None } | References::Joystick { speeds: None } => {}
            References::Survey { width, length, spacing, speed, depth: d } => {
                for (field, v) in [("width", width), ("length", length), ("spacing", spacing), ("speed", speed)] {
                    positive(field, *v)?;
                }
                depth("depth", *d, limits)?;
                let reach = width.hypot(*length);
                if reach > limits.max_distance {
                    return Err(format!(
                        "the survey reaches {reach:.1} m from the start, past the vehicle's limit of {} m \
                         (the limits on the page)",
                        limits.max_distance
                    ));
                }
            }
        }
        Ok(())
    }

    /// Whether the flight runs until STOP (the hold, pilot assist): the duration limit is for
    /// excitations and scripted flights.
    pub fn until_stop(&self) -> bool {
        matches!(self.references, References::Hold | References::Pilot { .. } | References::Joystick { .. })
    }

    /// The order as flown: a flight until STOP lasts [`UNTIL_STOP_S`], whatever it asked.
    pub fn flown(mut self) -> Self {
        if self.until_stop() {
            self.duration = UNTIL_STOP_S;
        }
        self
    }

    /// A steps order as `mpc_track --reference`'s CSV (a step is two rows at one time).
    pub fn reference_csv(&self) -> Option<String> {
        let References::Steps { depth, depth_at, heading, heading_at } = &self.references else { return None };
        let at = |t: f64, d_at: f64, h_at: f64, after: bool| {
            let pick = |v: &[f64; 2], when: f64| if t > when || (after && t == when) { v[1] } else { v[0] };
            (pick(depth, d_at), pick(heading, h_at))
        };
        let mut times = vec![*depth_at, *heading_at];
        times.sort_by(f64::total_cmp);
        times.dedup();
        let mut csv = String::from("t,depth_m,heading_deg\n");
        let (d, h) = at(0.0, *depth_at, *heading_at, false);
        let _ = writeln!(csv, "0,{d},{h}");
        for t in times {
            for after in [false, true] {
                let (d, h) = at(t, *depth_at, *heading_at, after);
                let _ = writeln!(csv, "{t},{d},{h}");
            }
        }
        let (d, h) = at(self.duration, *depth_at, *heading_at, true);
        let _ = writeln!(csv, "{},{d},{h}", self.duration);
        Some(csv)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: Limits = Limits { max_depth: 3.0, max_duration: 600.0, max_distance: 20.0, max_data_bytes: 1e9 };

    fn fly(json: &str) -> Result<(), String> {
        serde_json::from_str::<FlyOrder>(json).map_err(|e| e.to_string())?.check(&LIMITS)
    }

    #[test]
    fn numbers_past_the_vehicles_limits_are_refused_naming_the_field() {
        let e = fly(r#"{"model":"m","duration":30,"references":{"kind":"steps","depth":[1,5],"depth_at":10,"heading":[0,90],"heading_at":20}}"#).unwrap_err();
        assert!(e.contains("depth to 5 m is outside the vehicle's limits: 0 to 3 m"), "{e}");
        let e = fly(r#"{"model":"m","duration":3000,"references":{"kind":"survey","width":4,"length":10,"spacing":2,"speed":0.3,"depth":2}}"#).unwrap_err();
        assert!(e.starts_with("duration 3000 s"), "{e}");
        // The hold and pilot assist run until STOP: their duration is not the limit's.
        fly(r#"{"model":"m","duration":3000,"references":{"kind":"hold"}}"#).unwrap();
        fly(r#"{"model":"m","duration":90000,"references":{"kind":"joystick"}}"#).unwrap();
        let e = fly(r#"{"model":"m","duration":60,"references":{"kind":"survey","width":40,"length":10,"spacing":2,"speed":0.3,"depth":2}}"#).unwrap_err();
        assert!(e.contains("reaches 41.2 m from the start, past the vehicle's limit of 20 m"), "{e}");
        let e = fly(r#"{"model":"m","duration":30,"references":{"kind":"steps","depth":[1,2],"depth_at":40,"heading":[0,90],"heading_at":20}}"#).unwrap_err();
        assert!(e.contains("depth_at 40 s must be within the flight"), "{e}");
        let e =
            fly(r#"{"model":"m","duration":30,"references":{"kind":"pilot","speeds":[0.5,0,0.3,20]}}"#).unwrap_err();
        assert_eq!(e, "speeds sway must be above 0, got 0");
        fly(r#"{"model":"m","duration":600,"references":{"kind":"pilot"}}"#).unwrap();
        assert_eq!(
            DiveLimits { max_depth: 0.0, ..DIVE_LIMITS }.check().unwrap_err(),
            "max_depth 0 m must be above 0 and at most 300 m"
        );
        assert!(DiveLimits { max_duration: f64::NAN, ..DIVE_LIMITS }.check().is_err());
        DIVE_LIMITS.check().unwrap();
        let e = fly(r#"{"model":"m","duration":30,"references":{"kind":"orbit"}}"#).unwrap_err();
        assert!(e.contains("unknown variant `orbit`"), "{e}");
        let band = |b: &str| {
            serde_json::from_str::<ExciteOrder>(&format!(
                r#"{{"depth_band":{b},"axes":["heave","yaw"],"duration":90}}"#
            ))
            .unwrap()
            .check(&LIMITS)
        };
        assert!(band("[0.5,2.5]").is_ok());
        assert!(band("[0.5,3.5]").unwrap_err().contains("depth_band bottom 3.5 m is outside"));
        assert!(band("[2,2.2]").unwrap_err().contains("at least 0.5 m below"));
        let axes =
            serde_json::from_str::<ExciteOrder>(r#"{"depth_band":[0.5,2],"axes":["roll"],"duration":90}"#).unwrap();
        assert!(axes.check(&LIMITS).unwrap_err().contains("unknown axis \"roll\""));
    }

    #[test]
    fn steps_become_a_reference_file_with_steps_as_two_rows_at_one_time() {
        let o: FlyOrder = serde_json::from_str(
            r#"{"model":"m","duration":30,"references":{"kind":"steps","depth":[1,2],"depth_at":10,"heading":[0,90],"heading_at":20}}"#,
        )
        .unwrap();
        assert_eq!(
            o.reference_csv().unwrap(),
            "t,depth_m,heading_deg\n0,1,0\n10,1,0\n10,2,0\n20,2,0\n20,2,90\n30,2,90\n"
        );
    }

    #[test]
    fn a_run_past_the_data_folders_limit_or_its_disk_is_refused_with_the_figures() {
        let limits = Limits { max_data_bytes: 100e6, ..LIMITS };
        // 600 s: 5 MB + 24 MB.
        room_for(600.0, 70_000_000, Some(1_000_000_000), &limits).unwrap();
        let e = room_for(600.0, 80_000_000, Some(1_000_000_000), &limits).unwrap_err();
        assert_eq!(
            e,
            "refused: the data folder holds 80 MB of its 100 MB (pinc serve --max-data-mb) and a 600 s run needs \
             about 29 MB more: delete old runs first"
        );
        let e = room_for(600.0, 0, Some(20_000_000), &limits).unwrap_err();
        assert_eq!(e, "refused: the data folder's disk has 20 MB free and a 600 s run needs about 29 MB");
        room_for(600.0, 0, None, &limits).unwrap();
    }
}
