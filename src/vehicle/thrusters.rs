//! The thrusters of a vehicle file (docs/THRUSTERS.md): where each one sits and pushes, the
//! autopilot output it is wired to, and its curve of thrust against command. Forward, the
//! commands a log recorded become the body input `[X, Y, Z, Mz]`; backward, a body input
//! becomes per-thruster commands (least-norm allocation, saturation that keeps the input's
//! direction, each curve inverted through its deadband).

use super::VehicleFileError;
use crate::types::{Input, NU};
use nalgebra::{DMatrix, DVector, Vector3};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What a curve's commands are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CommandUnit {
    /// Servo pulse width (µs), neutral 1500.
    Pwm,
    /// A normalised output in [-1, 1], neutral 0.
    Normalised,
}

impl CommandUnit {
    /// The command that means "stop" (a reversed thruster mirrors its commands about it).
    pub fn neutral(self) -> f64 {
        match self {
            CommandUnit::Pwm => 1500.0,
            CommandUnit::Normalised => 0.0,
        }
    }

    /// The range a command of this unit can take at all: a table outside it was written for
    /// another unit.
    fn plausible(self) -> (f64, f64) {
        match self {
            CommandUnit::Pwm => (800.0, 2200.0),
            CommandUnit::Normalised => (-1.0, 1.0),
        }
    }
}

/// Thrust (N) against command, linear between the table's points, zero inside the deadband.
#[derive(Debug, Clone, PartialEq)]
pub struct ThrusterCurve {
    /// The curve's name in the file.
    pub name: String,
    /// What the commands are.
    pub unit: CommandUnit,
    /// Commands, strictly increasing.
    pub command: Vec<f64>,
    /// Thrust at each command (N), non-decreasing.
    pub thrust: Vec<f64>,
    /// Commands in this closed interval give no thrust.
    pub deadband: (f64, f64),
    /// Supply voltage the table was measured at (V), if stated.
    pub voltage: Option<f64>,
    /// Where the numbers come from.
    pub source: String,
}

impl ThrusterCurve {
    /// Thrust at `command`: zero inside the deadband, clamped to the table's ends.
    pub fn thrust(&self, command: f64) -> f64 {
        if command >= self.deadband.0 && command <= self.deadband.1 {
            return 0.0;
        }
        interpolate(&self.command, &self.thrust, command)
    }

    /// The largest forward and reverse thrust (N): `(min, max)` of the table.
    pub fn thrust_range(&self) -> (f64, f64) {
        (self.thrust[0], self.thrust[self.thrust.len() - 1])
    }

    /// The command giving `thrust`: the deadband's centre for zero, otherwise the command
    /// outside the deadband on the matching side where the table reaches it; a thrust past
    /// the table's end gives the end.
    pub fn command_for(&self, thrust: f64) -> f64 {
        let (lo, hi) = self.deadband;
        if thrust == 0.0 || !thrust.is_finite() {
            return if thrust == 0.0 { 0.5 * (lo + hi) } else { f64::NAN };
        }
        // The branch of the table on the thrust's side of the deadband, from the deadband
        // edge outwards: thrust grows monotonically away from zero there.
        let n = self.command.len();
        let side: Vec<usize> = if thrust > 0.0 {
            (0..n).filter(|&i| self.command[i] >= hi).collect()
        } else {
            (0..n).rev().filter(|&i| self.command[i] <= lo).collect()
        };
        let (mut prev_c, mut prev_f) = (if thrust > 0.0 { hi } else { lo }, 0.0);
        for &i in &side {
            let (c, f) = (self.command[i], self.thrust[i]);
            if (thrust > 0.0 && f >= thrust) || (thrust < 0.0 && f <= thrust) {
                if f == prev_f {
                    return c;
                }
                return prev_c + (thrust - prev_f) * (c - prev_c) / (f - prev_f);
            }
            (prev_c, prev_f) = (c, f);
        }
        prev_c
    }
}

/// Linear interpolation in a table with increasing `x`, clamped to its ends.
fn interpolate(x: &[f64], y: &[f64], at: f64) -> f64 {
    let n = x.len();
    if at <= x[0] {
        return y[0];
    }
    if at >= x[n - 1] {
        return y[n - 1];
    }
    let i = x.partition_point(|&v| v <= at).min(n - 1);
    let (x0, x1, y0, y1) = (x[i - 1], x[i], y[i - 1], y[i]);
    y0 + (at - x0) * (y1 - y0) / (x1 - x0)
}

/// One thruster.
#[derive(Debug, Clone, PartialEq)]
pub struct Thruster {
    /// Its name in the file.
    pub name: String,
    /// The autopilot's output (servo) channel it is wired to, 1-based.
    pub channel: u8,
    /// Where it sits (m, body forward-right-down, from the origin of the body frame).
    pub position: [f64; 3],
    /// Unit vector of the force a positive thrust exerts (body forward-right-down).
    pub direction: [f64; 3],
    /// Thrust against command.
    pub curve: ThrusterCurve,
    /// The motor turns the other way: the curve applies to the command mirrored about the
    /// neutral one (ArduSub's `MOT_n_DIRECTION = -1`).
    pub reversed: bool,
    /// ArduSub's mixing factors `[roll, pitch, yaw, throttle, forward, lateral]` of this
    /// output, for a bridge that commands the pilot axes.
    pub mix: Option<[f64; 6]>,
}

impl Thruster {
    /// Thrust along `direction` at `command`. A PWM of 0 is no pulse at all (an output
    /// that is off, as autopilots log disarmed channels): no thrust.
    pub fn thrust(&self, command: f64) -> f64 {
        if self.curve.unit == CommandUnit::Pwm && command == 0.0 {
            return 0.0;
        }
        self.curve.thrust(self.oriented(command))
    }

    /// The command that gives `thrust` along `direction`.
    pub fn command_for(&self, thrust: f64) -> f64 {
        self.oriented(self.curve.command_for(thrust))
    }

    /// The thrust range `(min, max)` along `direction`.
    pub fn thrust_range(&self) -> (f64, f64) {
        self.curve.thrust_range()
    }

    /// A command as the curve sees it (mirrored for a reversed motor; the mirror is its own
    /// inverse).
    fn oriented(&self, command: f64) -> f64 {
        if self.reversed { 2.0 * self.curve.unit.neutral() - command } else { command }
    }

    /// Force and moment of a unit thrust: `[d; p x d]`.
    fn wrench_column(&self) -> [f64; 6] {
        let d = Vector3::from(self.direction);
        let m = Vector3::from(self.position).cross(&d);
        [d[0], d[1], d[2], m[0], m[1], m[2]]
    }
}

/// Rows of the 6-DOF wrench `[X, Y, Z, K, M, N]` the 4-DOF model's input takes.
const INPUT_ROWS: [usize; NU] = [0, 1, 2, 5];

/// Every thruster of a vehicle and the matrices that map thrusts to the body wrench and back.
#[derive(Debug, Clone)]
pub struct Thrusters {
    /// The thrusters, in file order.
    pub list: Vec<Thruster>,
    /// The 6 x n matrix from per-thruster thrust (N) to `[X, Y, Z, K, M, N]`.
    matrix: DMatrix<f64>,
    /// The n x 4 least-norm inverse of its `X, Y, Z, N` rows.
    pseudo_inverse: DMatrix<f64>,
}

/// The result of [`Thrusters::allocate`].
#[derive(Debug, Clone, PartialEq)]
pub struct Allocation {
    /// Thrust of each thruster (N), in thruster order.
    pub thrusts: Vec<f64>,
    /// The command of each thruster, in thruster order.
    pub commands: Vec<f64>,
    /// 1 when the input was reachable; below 1 the factor it was scaled down by, along its
    /// own direction, so that no thruster exceeds its curve.
    pub scale: f64,
    /// The full wrench `[X, Y, Z, K, M, N]` the thrusts give (roll and pitch moments are not
    /// controlled by the 4-DOF model, only reported).
    pub wrench: [f64; 6],
}

/// A thruster as written in a vehicle file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ThrusterSpec {
    name: String,
    channel: i64,
    position: [f64; 3],
    direction: [f64; 3],
    curve: String,
    #[serde(default)]
    reversed: bool,
    mix: Option<[f64; 6]>,
}

/// A curve as written in a vehicle file: inline points, or a table in Blue Robotics'
/// published CSV layout (columns `PWM (µs)` and `Force (Kg f)`) beside the file.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CurveSpec {
    unit: CommandUnit,
    points: Option<Vec<[f64; 2]>>,
    table: Option<PathBuf>,
    deadband: Option<[f64; 2]>,
    voltage: Option<f64>,
    source: String,
}

/// Standard gravity: Blue Robotics' tables give force in kgf.
const KGF: f64 = 9.80665;

impl Thrusters {
    /// Reads a vehicle file's thrusters.
    ///
    /// # Errors
    /// The file cannot be read, is not TOML, has no `[[thruster]]`, or a thruster or curve
    /// is invalid (see [`Thrusters::from_toml`]).
    pub fn load(path: impl AsRef<Path>) -> Result<Self, VehicleFileError> {
        let path = path.as_ref();
        let text =
            std::fs::read_to_string(path).map_err(|source| VehicleFileError::Io { path: path.into(), source })?;
        Self::from_toml(&text, path)?.ok_or_else(|| VehicleFileError::Thruster {
            path: path.into(),
            thruster: String::new(),
            message: "the file has no [[thruster]] table".into(),
        })
    }

    /// The thrusters of a vehicle file's text, `None` if it has none; `path` names the file
    /// in errors and is where curve tables are looked up from.
    ///
    /// # Errors
    /// Not TOML; a thruster or curve with an unknown or missing key; a curve whose commands
    /// do not increase, whose thrust is not monotonic, whose unit its commands contradict,
    /// or whose deadband lies outside it; a direction that is not a unit vector; a channel
    /// outside 1-32 or used twice; a thruster naming a curve the file lacks.
    pub fn from_toml(text: &str, path: &Path) -> Result<Option<Self>, VehicleFileError> {
        let table: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| VehicleFileError::Syntax { path: path.into(), message: e.to_string() })?;
        let Some(list) = table.get("thruster") else { return Ok(None) };
        let err = |thruster: &str, message: String| VehicleFileError::Thruster {
            path: path.into(),
            thruster: thruster.to_string(),
            message,
        };
        let Some(list) = list.as_array() else {
            return Err(err("", "`thruster` must be an array of tables ([[thruster]])".into()));
        };
        let mut curves = BTreeMap::new();
        if let Some(c) = table.get("curve") {
            let Some(c) = c.as_table() else {
                return Err(err("", "`curve` must be a table of named curves ([curve.NAME])".into()));
            };
            for (name, spec) in c {
                let spec: CurveSpec =
                    spec.clone().try_into().map_err(|e| err("", format!("curve {name}: {}", one_line(&e))))?;
                let curve = build_curve(name, spec, path).map_err(|m| err("", format!("curve {name}: {m}")))?;
                curves.insert(name.clone(), curve);
            }
        }
        let mut thrusters: Vec<Thruster> = Vec::with_capacity(list.len());
        for (i, value) in list.iter().enumerate() {
            let label = value.get("name").and_then(|n| n.as_str()).map_or(format!("#{}", i + 1), str::to_string);
            let spec: ThrusterSpec = value.clone().try_into().map_err(|e| err(&label, one_line(&e)))?;
            let channel = u8::try_from(spec.channel)
                .ok()
                .filter(|c| (1..=32).contains(c))
                .ok_or_else(|| err(&label, format!("channel = {} is not an output channel 1-32", spec.channel)))?;
            if let Some(other) = thrusters.iter().find(|t| t.channel == channel) {
                return Err(err(&label, format!("channel {channel} is already {}'s", other.name)));
            }
            let norm = Vector3::from(spec.direction).norm();
            // A NaN length is refused too (no ordering).
            if (norm - 1.0).abs().partial_cmp(&1e-3).is_none_or(|o| o.is_gt()) {
                return Err(err(&label, format!("direction {:?} has length {norm}, not 1", spec.direction)));
            }
            if spec.position.iter().any(|v| !v.is_finite()) {
                return Err(err(&label, format!("position {:?} is not finite", spec.position)));
            }
            let curve = curves.get(&spec.curve).cloned().ok_or_else(|| {
                let have: Vec<&str> = curves.keys().map(String::as_str).collect();
                err(&label, format!("curve {:?} is not in the file (it has: {})", spec.curve, have.join(", ")))
            })?;
            let direction = (Vector3::from(spec.direction) / norm).into();
            thrusters.push(Thruster {
                name: spec.name,
                channel,
                position: spec.position,
                direction,
                curve,
                reversed: spec.reversed,
                mix: spec.mix,
            });
        }
        if thrusters.is_empty() {
            return Err(err("", "`thruster` is an empty list".into()));
        }
        Ok(Some(Self::new(thrusters)))
    }

    /// The allocation of a list of thrusters. A layout that cannot produce every one of
    /// `X`, `Y`, `Z`, `Mz` (no sway thrusters, say) still maps commands to inputs exactly;
    /// its allocation gives the nearest input it can produce (least squares, then least
    /// norm) and its reachable box is zero along what it cannot.
    pub fn new(list: Vec<Thruster>) -> Self {
        let n = list.len();
        let mut matrix = DMatrix::zeros(6, n);
        for (j, t) in list.iter().enumerate() {
            for (i, v) in t.wrench_column().into_iter().enumerate() {
                matrix[(i, j)] = v;
            }
        }
        let b4 = DMatrix::from_fn(NU, n, |i, j| matrix[(INPUT_ROWS[i], j)]);
        let pseudo_inverse = b4.pseudo_inverse(1e-9).expect("a non-negative tolerance");
        Self { list, matrix, pseudo_inverse }
    }

    /// The 6 x n matrix from per-thruster thrust (N) to `[X, Y, Z, K, M, N]`.
    pub fn allocation_matrix(&self) -> &DMatrix<f64> {
        &self.matrix
    }

    /// `[X, Y, Z, K, M, N]` of per-thruster thrusts (N, thruster order).
    pub fn wrench(&self, thrusts: &[f64]) -> [f64; 6] {
        let w = &self.matrix * DVector::from_column_slice(thrusts);
        std::array::from_fn(|i| w[i])
    }

    /// The body input `[X, Y, Z, Mz]` of the commands on the autopilot's outputs:
    /// `commands_by_channel[c - 1]` is channel `c`'s. A channel that is missing or NaN for
    /// any thruster makes the whole input NaN (never a partial wrench).
    pub fn input_from_commands(&self, commands_by_channel: &[f64]) -> Input {
        let mut thrusts = Vec::with_capacity(self.list.len());
        for t in &self.list {
            match commands_by_channel.get(usize::from(t.channel) - 1) {
                Some(&c) if c.is_finite() => thrusts.push(t.thrust(c)),
                _ => return Input::from([f64::NAN; NU]),
            }
        }
        let w = self.wrench(&thrusts);
        Input::from(INPUT_ROWS.map(|r| w[r]))
    }

    /// Per-thruster thrusts and commands for a body input: the least-norm thrusts that give
    /// it, scaled down as a whole (keeping the input's direction) when a thruster would pass
    /// its curve's range, then each curve inverted.
    pub fn allocate(&self, input: &Input) -> Allocation {
        let want = DVector::from_column_slice(input.as_slice());
        let thrusts = &self.pseudo_inverse * want;
        let scale = self.feasible_scale(thrusts.as_slice()).min(1.0);
        let thrusts: Vec<f64> = thrusts.iter().map(|t| t * scale).collect();
        let commands = self.list.iter().zip(&thrusts).map(|(t, &f)| t.command_for(f)).collect();
        let wrench = self.wrench(&thrusts);
        Allocation { thrusts, commands, scale, wrench }
    }

    /// The largest factor `s` with every `s * thrusts[i]` inside thruster `i`'s range.
    fn feasible_scale(&self, thrusts: &[f64]) -> f64 {
        let mut s = f64::INFINITY;
        for (t, &f) in self.list.iter().zip(thrusts) {
            let (lo, hi) = t.thrust_range();
            if f > 0.0 {
                s = s.min(hi / f);
            } else if f < 0.0 {
                s = s.min(lo / f);
            }
        }
        s
    }

    /// The reachable box `(lo, hi)` of the input: for each of `X`, `Y`, `Z`, `Mz` alone (the
    /// others zero), the largest magnitude either way that [`Thrusters::allocate`] delivers
    /// unscaled. It is the least-norm allocation's reach, not the most the thrusters could
    /// give along that axis with an uneven split (where reverse thrust is weaker than
    /// forward, a linear programme would lean on the stronger side): it is what a controller
    /// bounded by it can count on getting exactly.
    pub fn input_bounds(&self) -> (Input, Input) {
        let mut lo = Input::zeros();
        let mut hi = Input::zeros();
        for j in 0..NU {
            let column: Vec<f64> = self.pseudo_inverse.column(j).iter().copied().collect();
            // What a unit request along axis j gives along it: 1, or 0 for an axis the
            // thrusters cannot push along.
            let reach = self.wrench(&column)[INPUT_ROWS[j]];
            if reach.abs() < 1e-9 {
                continue;
            }
            let negated: Vec<f64> = column.iter().map(|v| -v).collect();
            hi[j] = self.feasible_scale(&column) * reach;
            lo[j] = -self.feasible_scale(&negated) * reach;
        }
        (lo, hi)
    }
}

/// A TOML error on one line (the crate's messages span several, with a source excerpt).
fn one_line(e: &toml::de::Error) -> String {
    e.message().trim().replace('\n', " ")
}

fn build_curve(name: &str, spec: CurveSpec, path: &Path) -> Result<ThrusterCurve, String> {
    let points = match (spec.points, spec.table) {
        (Some(p), None) => p,
        (None, Some(table)) => read_blue_robotics_table(&path.parent().unwrap_or(Path::new(".")).join(table))?,
        _ => return Err("give either `points` or `table`".into()),
    };
    if points.len() < 2 {
        return Err(format!("{} points; a curve needs at least 2", points.len()));
    }
    let command: Vec<f64> = points.iter().map(|p| p[0]).collect();
    let thrust: Vec<f64> = points.iter().map(|p| p[1]).collect();
    if let Some(v) = command.iter().chain(&thrust).find(|v| !v.is_finite()) {
        return Err(format!("a point is not finite ({v})"));
    }
    for i in 1..command.len() {
        if command[i] <= command[i - 1] {
            return Err(format!("commands must increase: {} after {} (point {})", command[i], command[i - 1], i + 1));
        }
        if thrust[i] < thrust[i - 1] {
            return Err(format!(
                "thrust is not monotonic: {} N at {} after {} N at {} (point {})",
                thrust[i],
                command[i],
                thrust[i - 1],
                command[i - 1],
                i + 1
            ));
        }
    }
    let (first, last) = (command[0], command[command.len() - 1]);
    let (min, max) = spec.unit.plausible();
    if first < min || last > max {
        return Err(format!(
            "commands {first}..{last} are not {} commands ({min}..{max}): the curve's unit and its table disagree",
            match spec.unit {
                CommandUnit::Pwm => "PWM",
                CommandUnit::Normalised => "normalised",
            }
        ));
    }
    let deadband = match spec.deadband {
        Some([a, b]) if a <= b && a >= first && b <= last => (a, b),
        Some([a, b]) => return Err(format!("deadband [{a}, {b}] is not an interval inside {first}..{last}")),
        None => {
            let n = spec.unit.neutral();
            (n, n)
        }
    };
    if thrust[0] >= 0.0 || thrust[thrust.len() - 1] <= 0.0 {
        return Err("the table must give reverse (negative) and forward (positive) thrust".into());
    }
    Ok(ThrusterCurve {
        name: name.to_string(),
        unit: spec.unit,
        command,
        thrust,
        deadband,
        voltage: spec.voltage,
        source: spec.source,
    })
}

/// A vehicle file's `[[thruster]]` and `[curve.*]` tables as TOML text that stands alone:
/// every curve read from a table file is written inline as its points (in N, as read), so
/// the text needs no other file. Empty where the file has no thrusters.
///
/// # Errors
/// The file cannot be read or is not TOML, or a curve's table cannot be read.
pub fn standalone_thruster_tables(path: &Path) -> Result<String, VehicleFileError> {
    let text = std::fs::read_to_string(path).map_err(|source| VehicleFileError::Io { path: path.into(), source })?;
    let syntax = |message: String| VehicleFileError::Syntax { path: path.into(), message };
    let table: toml::Table = text.parse().map_err(|e: toml::de::Error| syntax(e.to_string()))?;
    let mut kept: toml::Table = table.into_iter().filter(|(k, _)| k == "thruster" || k == "curve").collect();
    if let Some(curves) = kept.get_mut("curve").and_then(toml::Value::as_table_mut) {
        for (name, curve) in curves.iter_mut() {
            let Some(spec) = curve.as_table_mut() else { continue };
            let Some(file) = spec.remove("table") else { continue };
            let file = file.as_str().ok_or_else(|| syntax(format!("curve {name}: `table` must be a path")))?;
            let points = read_blue_robotics_table(&path.parent().unwrap_or(Path::new(".")).join(file))
                .map_err(|e| syntax(format!("curve {name}: {e}")))?;
            let rows = points.iter().map(|p| toml::Value::Array(vec![p[0].into(), p[1].into()])).collect();
            spec.insert("points".into(), toml::Value::Array(rows));
        }
    }
    if kept.is_empty() {
        return Ok(String::new());
    }
    toml::to_string(&kept).map_err(|e| syntax(e.to_string()))
}

/// `(PWM, thrust N)` rows of a table in Blue Robotics' published layout: a header with a
/// `PWM` column and a `Force (Kg f)` column, force in kgf.
fn read_blue_robotics_table(path: &Path) -> Result<Vec<[f64; 2]>, String> {
    let shown = path.display();
    let mut reader =
        csv::ReaderBuilder::new().trim(csv::Trim::All).from_path(path).map_err(|e| format!("table {shown}: {e}"))?;
    let header = reader.headers().map_err(|e| format!("table {shown}: {e}"))?.clone();
    let find = |prefix: &str| header.iter().position(|h| h.to_ascii_lowercase().starts_with(prefix));
    let (Some(pwm), Some(force)) = (find("pwm"), find("force")) else {
        return Err(format!("table {shown}: needs a PWM column and a Force (Kg f) column, has {:?}", header));
    };
    let mut rows = Vec::new();
    for (i, record) in reader.records().enumerate() {
        let record = record.map_err(|e| format!("table {shown}: {e}"))?;
        let num = |j: usize| -> Result<f64, String> {
            record
                .get(j)
                .and_then(|v| v.parse().ok())
                .ok_or_else(|| format!("table {shown}: line {}: column {} is not a number", i + 2, header[j].trim()))
        };
        rows.push([num(pwm)?, num(force)? * KGF]);
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    const LINEAR: &str = r#"
[curve.lin]
unit = "normalised"
points = [[-1.0, -40.0], [-0.1, 0.0], [0.1, 0.0], [1.0, 50.0]]
deadband = [-0.1, 0.1]
source = "a test"
"#;

    fn parse(text: &str) -> Result<Option<Thrusters>, VehicleFileError> {
        Thrusters::from_toml(text, Path::new("v.toml"))
    }

    fn shipped(name: &str) -> Thrusters {
        Thrusters::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("models").join(name)).unwrap()
    }

    fn thruster(name: &str, channel: u8, position: [f64; 3], direction: [f64; 3]) -> String {
        format!(
            "[[thruster]]\nname = \"{name}\"\nchannel = {channel}\nposition = {position:?}\ndirection = {direction:?}\ncurve = \"lin\"\n"
        )
    }

    #[test]
    fn the_wrench_is_the_sum_of_each_thrusters_force_and_moment() {
        let text = format!(
            "{}{}{LINEAR}",
            thruster("a", 1, [0.2, 0.1, 0.05], [1.0, 0.0, 0.0]),
            thruster("b", 2, [-0.1, -0.3, 0.0], [0.0, 0.6, 0.8])
        );
        let t = parse(&text).unwrap().unwrap();
        // By hand: a = 10 N forward at (0.2, 0.1, 0.05): moment (0, 0.5, -1.0);
        // b = 5 N along (0, 0.6, 0.8) = (0, 3, 4) N at (-0.1, -0.3, 0): moment (-1.2, 0.4, -0.3).
        let w = t.wrench(&[10.0, 5.0]);
        let want = [10.0, 3.0, 4.0, -1.2, 0.9, -1.3];
        for i in 0..6 {
            assert_relative_eq!(w[i], want[i], epsilon = 1e-12);
        }
        // Two thrusters cannot give four independent inputs: the allocation gives the nearest.
        let a = t.allocate(&Input::new(0.0, 0.0, 0.0, 1.0));
        assert!(a.wrench[5] < 1.0 && a.wrench[5] > 0.0, "{:?}", a.wrench);
    }

    #[test]
    fn allocation_round_trips_and_saturation_keeps_the_direction() {
        let t = shipped("bluerov2.toml");
        for input in [Input::new(20.0, -10.0, 15.0, 3.0), Input::new(-5.0, 30.0, -40.0, -6.0), Input::zeros()] {
            let a = t.allocate(&input);
            assert_eq!(a.scale, 1.0, "{input}");
            // Thrusts give the input back; commands through the curves give the thrusts back.
            let back = Input::from(INPUT_ROWS.map(|r| a.wrench[r]));
            assert!((back - input).amax() < 1e-9, "{back} vs {input}");
            let mut by_channel = vec![f64::NAN; 8];
            for (th, c) in t.list.iter().zip(&a.commands) {
                by_channel[usize::from(th.channel) - 1] = *c;
            }
            assert!((t.input_from_commands(&by_channel) - input).amax() < 1e-9);
        }
        // Far outside: scaled down along the request, one thruster at its limit.
        let want = Input::new(400.0, 100.0, 0.0, 20.0);
        let a = t.allocate(&want);
        assert!(a.scale < 1.0);
        let got = Input::from(INPUT_ROWS.map(|r| a.wrench[r]));
        assert!((got - want * a.scale).amax() < 1e-9, "{got} is not {} x {want}", a.scale);
        let at_limit = t.list.iter().zip(&a.thrusts).any(|(th, &f)| {
            let (lo, hi) = th.thrust_range();
            (f - hi).abs() < 1e-9 || (f - lo).abs() < 1e-9
        });
        assert!(at_limit, "{:?}", a.thrusts);
    }

    #[test]
    fn curves_invert_through_the_deadband_and_reversed_motors_mirror() {
        let t = shipped("bluerov2.toml");
        let curve = &t.list[0].curve;
        assert_eq!((curve.thrust(1472.0), curve.thrust(1500.0), curve.thrust(1528.0)), (0.0, 0.0, 0.0));
        assert_eq!(curve.command_for(0.0), 1500.0);
        // 16 V table: 5.25 kgf at 1900 us, -4.07 kgf at 1100 us.
        assert_relative_eq!(curve.thrust(1900.0), 5.25 * KGF, epsilon = 1e-9);
        assert_relative_eq!(curve.thrust(1100.0), -4.07 * KGF, epsilon = 1e-9);
        let (lo, hi) = curve.thrust_range();
        for k in 1..200 {
            let f = lo + (hi - lo) * f64::from(k) / 200.0;
            let c = curve.command_for(f);
            assert!((curve.thrust(c) - f).abs() < 1e-9, "thrust {f}: command {c} gives {}", curve.thrust(c));
            assert!(if f > 0.0 { c >= 1528.0 } else { c <= 1472.0 }, "{f} N at {c} us");
        }
        let mut reversed = t.list[0].clone();
        reversed.reversed = true;
        assert_eq!(reversed.thrust(1300.0), t.list[0].thrust(1700.0));
        assert!((reversed.thrust(reversed.command_for(20.0)) - 20.0).abs() < 1e-9);
        assert!(reversed.command_for(20.0) < 1500.0);
    }

    #[test]
    fn the_shipped_frames_agree_with_ardusubs_mixing_factors() {
        for (file, n) in [("bluerov2.toml", 6), ("bluerov2_heavy.toml", 8)] {
            let t = shipped(file);
            assert_eq!(t.list.len(), n);
            for (j, th) in t.list.iter().enumerate() {
                assert_eq!(usize::from(th.channel), j + 1);
                let col = th.wrench_column();
                let mix = th.mix.unwrap();
                // [roll, pitch, yaw, throttle, forward, lateral] against the wrench
                // [X, Y, Z, K, M, N] of a positive thrust; throttle is up, Z is down.
                let pairs = [(mix[2], col[5]), (mix[3], -col[2]), (mix[4], col[0]), (mix[5], col[1])];
                let vertical_pairs = [(mix[0], col[3]), (mix[1], col[4])];
                for (k, (factor, effect)) in pairs.iter().enumerate() {
                    if *factor != 0.0 {
                        assert_eq!(factor.signum(), effect.signum(), "{file} {}: factor {k}", th.name);
                    }
                }
                if th.direction[2] != 0.0 {
                    for (factor, effect) in vertical_pairs {
                        if factor != 0.0 {
                            assert_eq!(factor.signum(), effect.signum(), "{file} {}: roll/pitch", th.name);
                        }
                    }
                }
            }
            let (lo, hi) = t.input_bounds();
            // The vectored layout: as much sway as surge, either way (two thrusters forward,
            // two in reverse whichever way); heave from the vertical thrusters, all pushing
            // down at full forward thrust or up at full reverse thrust.
            assert_relative_eq!(hi[0], hi[1], max_relative = 1e-9);
            assert_relative_eq!(hi[0], -lo[0], max_relative = 1e-9);
            let vertical = (n - 4) as f64;
            assert_relative_eq!(hi[2], vertical * 5.25 * KGF, max_relative = 1e-9);
            assert_relative_eq!(lo[2], -vertical * 4.07 * KGF, max_relative = 1e-9);
            // Heave from the vertical thrusters alone makes no yaw moment.
            let heave = t.allocate(&Input::new(0.0, 0.0, 30.0, 0.0));
            assert!(heave.wrench[5].abs() < 1e-12 && heave.thrusts[..4].iter().all(|f| f.abs() < 1e-12));
        }
        // The yaw arm of Wu (2018): 0.1888 m.
        let t = shipped("bluerov2.toml");
        assert_relative_eq!(t.allocation_matrix()[(5, 0)], (0.156 + 0.111) * std::f64::consts::FRAC_1_SQRT_2);
    }

    #[test]
    fn bad_thrusters_and_curves_are_errors_naming_the_file_and_thruster() {
        let msg = |text: &str| parse(text).unwrap_err().to_string();
        let a = thruster("a", 1, [0.0; 3], [1.0, 0.0, 0.0]);
        let m = msg(&format!("{a}{}", LINEAR.replace("[1.0, 50.0]", "[1.0, -50.0]")));
        assert!(m.starts_with("v.toml: curve lin: thrust is not monotonic"), "{m}");
        let m = msg(&format!("{}{LINEAR}", thruster("a", 1, [0.0; 3], [1.0, 1.0, 0.0])));
        assert!(m.starts_with("v.toml: thruster a: direction [1.0, 1.0, 0.0] has length"), "{m}");
        let m = msg(&format!("{a}{}{LINEAR}", thruster("b", 1, [0.0; 3], [0.0, 1.0, 0.0])));
        assert_eq!(m, "v.toml: thruster b: channel 1 is already a's");
        let m = msg(&(a.replace("\"lin\"", "\"t200\"") + LINEAR));
        assert_eq!(m, "v.toml: thruster a: curve \"t200\" is not in the file (it has: lin)");
        let m = msg(&format!("{a}{}", LINEAR.replace("normalised", "pwm")));
        assert!(m.contains("curve lin: commands -1..1 are not PWM commands"), "{m}");
        let m = msg(&format!("{a}{LINEAR}").replace("channel = 1", "channel = 0"));
        assert!(m.starts_with("v.toml: thruster a: channel = 0 is not an output channel"), "{m}");
        let m = msg(&format!("{a}{LINEAR}").replace("curve = \"lin\"", "curve = \"lin\"\nspin = 1"));
        assert!(m.starts_with("v.toml: thruster a: unknown field `spin`"), "{m}");
        // A file without thrusters is no error for `from_toml`, and one for `load`.
        assert!(parse("m = 12\n").unwrap().is_none());
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("plain.toml");
        std::fs::write(&p, "m = 12\n").unwrap();
        assert!(Thrusters::load(&p).unwrap_err().to_string().ends_with("the file has no [[thruster]] table"));
    }

    #[test]
    fn missing_or_nan_commands_give_no_partial_wrench() {
        let t = shipped("bluerov2.toml");
        assert!(t.input_from_commands(&[1500.0; 5]).iter().all(|v| v.is_nan()), "channel 6 missing");
        let mut c = [1500.0; 6];
        assert_eq!(t.input_from_commands(&c), Input::zeros());
        c[2] = 0.0;
        assert_eq!(t.input_from_commands(&c), Input::zeros(), "an output that is off pushes nothing");
        c[2] = f64::NAN;
        assert!(t.input_from_commands(&c).iter().all(|v| v.is_nan()));
    }
}
