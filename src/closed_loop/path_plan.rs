//! Horizontal references: a point to hold, a path of waypoints from a file, or a lawnmower
//! survey, each turned into north and east tracks over time (with the path's velocity as
//! feed-forward) and, where the heading follows the track, a heading track. A path is checked
//! whole before anything moves: a bad number, a time going back, a leg faster than the
//! vehicle can go or a point past the distance limit names its line.

use super::track::Track;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Where a path's coordinates are measured from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum PathFrame {
    /// Metres north and east of where the vehicle is when control starts.
    #[default]
    Start,
    /// Metres north and east of the autopilot's EKF origin (`LOCAL_POSITION_NED`'s frame).
    Origin,
}

/// Which way the vehicle faces along a path.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub enum PathHeading {
    /// Along each leg (turning at the waypoints).
    Track,
    /// A fixed heading (deg).
    Fixed(f64),
}

/// A horizontal reference over time: north and east tracks (m) in `frame`, from which the
/// position and the path's velocity at any time follow.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HorizontalPlan {
    /// North (m) over time.
    pub north: Track,
    /// East (m) over time.
    pub east: Track,
    /// What the coordinates are measured from.
    pub frame: PathFrame,
    /// Whether this is a point held (station keeping) rather than a path: errors are judged
    /// from the point, not across the track.
    pub station: bool,
    /// The waypoints `(t, north, east)` the tracks pass through, for cross-track errors.
    pub waypoints: Vec<(f64, f64, f64)>,
}

impl HorizontalPlan {
    /// Hold the point where control starts.
    pub fn station() -> Self {
        Self {
            north: Track::constant(0.0),
            east: Track::constant(0.0),
            frame: PathFrame::Start,
            station: true,
            waypoints: vec![(0.0, 0.0, 0.0)],
        }
    }

    /// The goal `(north, east)` and the path's velocity at `t`.
    pub fn at(&self, t: f64) -> ([f64; 2], [f64; 2]) {
        ([self.north.at(t), self.east.at(t)], [self.north.slope(t), self.east.slope(t)])
    }

    /// Time of the last waypoint.
    pub fn end(&self) -> f64 {
        self.waypoints.last().map_or(0.0, |w| w.0)
    }

    /// Distance from `(north, east)` to the path: to the point held, or to the nearest leg.
    pub fn cross_track(&self, north: f64, east: f64) -> f64 {
        let w = &self.waypoints;
        if w.len() == 1 {
            return (north - w[0].1).hypot(east - w[0].2);
        }
        w.windows(2)
            .map(|l| {
                let (a, b) = ((l[0].1, l[0].2), (l[1].1, l[1].2));
                let (dx, dy) = (b.0 - a.0, b.1 - a.1);
                let len2 = dx * dx + dy * dy;
                let f =
                    if len2 > 0.0 { (((north - a.0) * dx + (east - a.1) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
                (north - a.0 - f * dx).hypot(east - a.1 - f * dy)
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// The farthest a waypoint lies from the frame's zero (m).
    pub fn reach(&self) -> f64 {
        self.waypoints.iter().map(|w| w.1.hypot(w.2)).fold(0.0, f64::max)
    }
}

/// A path and the heading and depth tracks that go with it.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPath {
    /// North and east over time.
    pub horizontal: HorizontalPlan,
    /// Depth (m) over time.
    pub depth: Track,
    /// Heading (deg) over time, unwrapped so that it turns the short way.
    pub heading: Track,
}

/// A path that cannot be flown, naming where.
#[derive(Debug, thiserror::Error)]
pub enum PathError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A row or setting that is wrong.
    #[error("{place}: {message}")]
    Bad {
        /// The file and line (`FILE: line N`), or the setting.
        place: String,
        /// What is wrong.
        message: String,
    },
}

/// The limits a path is checked against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathLimits {
    /// The fastest the vehicle can go horizontally (m/s): its steady speed at full thrust.
    pub max_speed: f64,
    /// The farthest a waypoint may lie from the start (m), `--max-distance`.
    pub max_distance: Option<f64>,
}

/// Time spent holding the first waypoint before the path starts (s): the dive to depth.
pub const PATH_LEAD_S: f64 = 10.0;

/// One waypoint as read.
#[derive(Debug, Clone, Copy)]
struct Waypoint {
    line: u64,
    north: f64,
    east: f64,
    depth: f64,
    /// Arrival time (s after the path starts), or the leg's speed (m/s) to get there.
    when: When,
    heading: Option<f64>,
}

#[derive(Debug, Clone, Copy)]
enum When {
    At(f64),
    Speed(f64),
}

/// Reads a path file: a CSV with columns `north_m,east_m,depth_m` and either `t` (s, the time
/// to be at the point) or `speed_m_s` (the speed of the leg that ends there; the first row's is
/// not used), and optionally `heading_deg` (a number, or empty to face along the leg). The
/// first row is where the path starts; it is held for [`PATH_LEAD_S`] first.
///
/// # Errors
/// The file cannot be read; a missing column; a field not a finite number; a time going back;
/// a leg faster than `limits.max_speed`; a point past `limits.max_distance`.
pub fn read_path_file(path: &Path, frame: PathFrame, limits: &PathLimits) -> Result<PlannedPath, PathError> {
    let place = |line: u64| format!("{}: line {line}", path.display());
    let bad = |line: u64, message: String| PathError::Bad { place: place(line), message };
    let file = std::fs::File::open(path).map_err(|source| PathError::Io { path: path.into(), source })?;
    let mut reader = csv::ReaderBuilder::new().trim(csv::Trim::All).from_reader(file);
    let header = reader.headers().map_err(|e| bad(1, e.to_string()))?.clone();
    let column = |name: &str| header.iter().position(|h| h == name);
    let found = || header.iter().collect::<Vec<_>>().join(",");
    let (Some(cn), Some(ce), Some(cd)) = (column("north_m"), column("east_m"), column("depth_m")) else {
        return Err(bad(1, format!("the header needs north_m,east_m,depth_m; found {}", found())));
    };
    let (ct, cs, ch) = (column("t"), column("speed_m_s"), column("heading_deg"));
    if ct.is_some() == cs.is_some() {
        return Err(bad(1, format!("the header needs one of t or speed_m_s; found {}", found())));
    }
    let mut points = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| bad(e.position().map_or(0, |p| p.line()), e.to_string()))?;
        let line = record.position().map_or(0, |p| p.line());
        let number = |c: usize, name: &str| -> Result<f64, PathError> {
            let text = record.get(c).unwrap_or("");
            text.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(line, format!("{name}: {text:?} is not a finite number")))
        };
        let when = match (ct, cs) {
            (Some(c), _) => When::At(number(c, "t")?),
            (_, Some(c)) => When::Speed(number(c, "speed_m_s")?),
            _ => unreachable!("one of the two columns, checked above"),
        };
        let heading = match ch.and_then(|c| record.get(c)) {
            None | Some("") => None,
            Some(_) => Some(number(ch.expect("present"), "heading_deg")?),
        };
        points.push(Waypoint {
            line,
            north: number(cn, "north_m")?,
            east: number(ce, "east_m")?,
            depth: number(cd, "depth_m")?,
            when,
            heading,
        });
    }
    if points.is_empty() {
        return Err(bad(1, "no waypoints after the header".into()));
    }
    plan(&points, frame, limits, &place)
}

/// A lawnmower survey from the start: `legs` legs of `length` m northwards and back, `spacing`
/// m apart eastwards, at `speed` m/s and `depth` m, facing `heading`.
///
/// # Errors
/// A non-positive or non-finite size, fewer than one leg, a speed past the vehicle's, or a
/// survey reaching past `--max-distance`.
pub fn survey(
    (legs, length, spacing): (usize, f64, f64),
    speed: f64,
    depth: f64,
    heading: PathHeading,
    limits: &PathLimits,
) -> Result<PlannedPath, PathError> {
    let place = |_: u64| "--survey".to_string();
    let positive = [("length", length), ("spacing", spacing), ("speed", speed)];
    if let Some((name, v)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        return Err(PathError::Bad { place: place(0), message: format!("{name} {v} (a positive number)") });
    }
    if !(depth.is_finite() && depth >= 0.0) || legs == 0 {
        return Err(PathError::Bad { place: place(0), message: format!("{legs} legs at depth {depth} m") });
    }
    let h = match heading {
        PathHeading::Track => None,
        PathHeading::Fixed(d) => Some(d),
    };
    let mut points = vec![Waypoint { line: 0, north: 0.0, east: 0.0, depth, when: When::Speed(speed), heading: h }];
    for leg in 0..legs {
        let east = leg as f64 * spacing;
        let (from, to) = if leg % 2 == 0 { (0.0, length) } else { (length, 0.0) };
        if leg > 0 {
            points.push(Waypoint { line: 0, north: from, east, depth, when: When::Speed(speed), heading: h });
        }
        points.push(Waypoint { line: 0, north: to, east, depth, when: When::Speed(speed), heading: h });
    }
    plan(&points, PathFrame::Start, limits, &place)
}

/// The tracks of checked waypoints: times from the speeds, the heading along each leg where
/// none is given, the first point held for [`PATH_LEAD_S`].
fn plan(
    points: &[Waypoint],
    frame: PathFrame,
    limits: &PathLimits,
    place: &dyn Fn(u64) -> String,
) -> Result<PlannedPath, PathError> {
    let bad = |line: u64, message: String| PathError::Bad { place: place(line), message };
    let times = arrival_times(points, limits.max_speed, &bad)?;
    check_reach(points, limits.max_distance, &bad)?;
    Ok(tracks(points, &times, frame))
}

/// When the path reaches each waypoint (s after it starts): given, or from the leg's speed;
/// a time going back or a leg faster than `max_speed` is refused.
fn arrival_times(
    points: &[Waypoint],
    max_speed: f64,
    bad: &dyn Fn(u64, String) -> PathError,
) -> Result<Vec<f64>, PathError> {
    let mut times = vec![0.0];
    for w in points.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        let dist = (b.north - a.north).hypot(b.east - a.east);
        let prev = *times.last().expect("one time per point");
        let t = match b.when {
            When::At(t) => {
                let t0 = match a.when {
                    When::At(t0) => t0,
                    When::Speed(_) => unreachable!("a file has one kind of column"),
                };
                if t < t0 {
                    return Err(bad(b.line, format!("t = {t} comes before the previous row's {t0}")));
                }
                prev + (t - t0)
            }
            When::Speed(v) if v > 0.0 => prev + dist / v,
            When::Speed(v) if dist == 0.0 && v == 0.0 => prev,
            When::Speed(v) => return Err(bad(b.line, format!("speed {v} m/s (positive)"))),
        };
        let speed = if t > prev {
            dist / (t - prev)
        } else if dist > 0.0 {
            f64::INFINITY
        } else {
            0.0
        };
        if speed > max_speed {
            return Err(bad(
                b.line,
                format!(
                    "the leg to ({}, {}) asks {speed:.2} m/s, faster than the vehicle's {max_speed:.2} m/s",
                    b.north, b.east
                ),
            ));
        }
        times.push(t);
    }
    Ok(times)
}

/// Refuses the first waypoint farther than `max_distance` from the start.
fn check_reach(
    points: &[Waypoint],
    max_distance: Option<f64>,
    bad: &dyn Fn(u64, String) -> PathError,
) -> Result<(), PathError> {
    let Some(limit) = max_distance else { return Ok(()) };
    match points.iter().find(|w| w.north.hypot(w.east) > limit) {
        Some(w) => Err(bad(
            w.line,
            format!(
                "({}, {}) lies {:.2} m from the start, past --max-distance {limit} m",
                w.north,
                w.east,
                w.north.hypot(w.east)
            ),
        )),
        None => Ok(()),
    }
}

/// North, east, depth and heading tracks through the waypoints at their `times`, after the
/// lead; the heading of each leg (along it, or as given) unwrapped against the last, turning at
/// the waypoint.
fn tracks(points: &[Waypoint], times: &[f64], frame: PathFrame) -> PlannedPath {
    let mut north = vec![(0.0, points[0].north)];
    let mut east = vec![(0.0, points[0].east)];
    let mut depth = vec![(0.0, points[0].depth)];
    let mut heading: Vec<(f64, f64)> = Vec::new();
    let mut waypoints = Vec::new();
    let mut last_heading = points[0].heading.unwrap_or(0.0);
    for (i, (w, &t)) in points.iter().zip(times).enumerate() {
        let at = PATH_LEAD_S + t;
        north.push((at, w.north));
        east.push((at, w.east));
        depth.push((at, w.depth));
        waypoints.push((at, w.north, w.east));
        let next = points.get(i + 1).filter(|n| (n.north - w.north).hypot(n.east - w.east) > 1e-9);
        let wanted = match (w.heading, next) {
            (Some(h), _) => h,
            (None, Some(n)) => (n.east - w.east).atan2(n.north - w.north).to_degrees(),
            (None, None) => last_heading,
        };
        let unwrapped = last_heading + crate::vehicle::wrap_angle((wanted - last_heading).to_radians()).to_degrees();
        heading.push((if i == 0 { 0.0 } else { at }, if i == 0 { unwrapped } else { last_heading }));
        heading.push((at, unwrapped));
        last_heading = unwrapped;
    }
    PlannedPath {
        horizontal: HorizontalPlan {
            north: Track::from_points(north),
            east: Track::from_points(east),
            frame,
            station: false,
            waypoints,
        },
        depth: Track::from_points(depth),
        heading: Track::from_points(heading),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: PathLimits = PathLimits { max_speed: 1.0, max_distance: Some(30.0) };

    fn write(text: &str) -> tempfile::NamedTempFile {
        let f = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(f.path(), text).unwrap();
        f
    }

    #[test]
    fn a_survey_runs_its_legs_at_its_speed_and_its_cross_track_is_the_distance_to_the_legs() {
        let p = survey((4, 10.0, 2.0), 0.3, 2.0, PathHeading::Fixed(0.0), &LIMITS).unwrap();
        let h = &p.horizontal;
        // 4 legs of 10 m and 3 transits of 2 m at 0.3 m/s after the lead.
        assert!((h.end() - (PATH_LEAD_S + 46.0 / 0.3)).abs() < 1e-9, "{}", h.end());
        let (pos, vel) = h.at(PATH_LEAD_S + 5.0 / 0.3);
        assert!((pos[0] - 5.0).abs() < 1e-9 && pos[1].abs() < 1e-12);
        assert!((vel[0] - 0.3).abs() < 1e-9 && vel[1].abs() < 1e-12);
        // Second leg runs south at east = 2.
        let (pos, vel) = h.at(PATH_LEAD_S + (10.0 + 2.0 + 3.0) / 0.3);
        assert!((pos[0] - 7.0).abs() < 1e-9 && (pos[1] - 2.0).abs() < 1e-9 && (vel[0] + 0.3).abs() < 1e-9);
        assert!((h.cross_track(5.0, 0.5) - 0.5).abs() < 1e-12);
        assert!((h.cross_track(11.0, 1.0) - 1.0).abs() < 1e-12);
        assert_eq!(p.depth.at(0.0), 2.0);
        assert_eq!(p.heading.at(100.0), 0.0);
    }

    #[test]
    fn along_the_track_the_heading_turns_the_short_way_at_each_waypoint() {
        let p = survey((2, 10.0, 2.0), 0.5, 1.0, PathHeading::Track, &LIMITS).unwrap();
        let t1 = PATH_LEAD_S + 20.0; // the first corner
        assert_eq!(p.heading.at(t1 - 0.01), 0.0);
        assert_eq!(p.heading.at(t1 + 0.01), 90.0);
        // Then south: 180, reached from 90 by +90 (not -270).
        assert_eq!(p.heading.at(t1 + 4.0 + 0.01), 180.0);
    }

    #[test]
    fn a_bad_path_is_refused_naming_its_line() {
        let cases = [
            ("north_m,east_m,depth_m,speed_m_s\n0,0,1,0.3\n5,nan,1,0.3\n", "line 3", "east_m"),
            ("north_m,east_m,depth_m,t\n0,0,1,0\n5,0,1,20\n6,0,1,10\n", "line 4", "comes before"),
            ("north_m,east_m,depth_m,t\n0,0,1,0\n5,0,1,2\n", "line 3", "faster than the vehicle's 1.00 m/s"),
            ("north_m,east_m,depth_m,speed_m_s\n0,0,1,0.3\n40,0,1,0.3\n", "line 3", "past --max-distance 30 m"),
            ("north,east,depth_m,t\n0,0,1,0\n", "line 1", "north_m,east_m,depth_m"),
            ("north_m,east_m,depth_m\n0,0,1\n", "line 1", "one of t or speed_m_s"),
        ];
        for (text, line, what) in cases {
            let f = write(text);
            let e = read_path_file(f.path(), PathFrame::Start, &LIMITS).unwrap_err().to_string();
            assert!(e.contains(line) && e.contains(what), "{e}");
        }
    }

    #[test]
    fn a_path_file_with_times_and_fixed_headings_reads_as_written() {
        let f = write("north_m,east_m,depth_m,t,heading_deg\n0,0,1,0,30\n3,4,2,10,\n3,4,2,15,90\n");
        let p = read_path_file(f.path(), PathFrame::Origin, &LIMITS).unwrap();
        let (pos, vel) = p.horizontal.at(PATH_LEAD_S + 5.0);
        assert!((pos[0] - 1.5).abs() < 1e-12 && (pos[1] - 2.0).abs() < 1e-12);
        assert!((vel[0] - 0.3).abs() < 1e-12 && (vel[1] - 0.4).abs() < 1e-12);
        assert_eq!(p.heading.at(1.0), 30.0);
        assert_eq!(p.horizontal.frame, PathFrame::Origin);
        assert!((p.horizontal.reach() - 5.0).abs() < 1e-12);
        assert!((p.depth.at(PATH_LEAD_S + 5.0) - 1.5).abs() < 1e-12);
    }
}
