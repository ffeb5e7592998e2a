//! What every log reader yields before resampling: each quantity the state and the input are
//! made of, as a time series at its own rate, already in pinc's conventions (world frame
//! NED with z down, body frame forward-right-down, rad, m/s, N, N m, seconds on one time base
//! per file). Converting frames and units is the reader's job; merging the streams onto one
//! sample period is shared (`resample`).

/// One quantity sampled at its own times.
#[derive(Debug, Clone, PartialEq)]
pub struct Series<const N: usize> {
    /// Where it came from, as the user would name it: `ATT.Yaw`, `LOCAL_POSITION_NED`,
    /// `/mavros/local_position/odom`, a CSV column list. Printed in the import report.
    pub source: String,
    /// Time stamps (s), non-decreasing.
    pub t: Vec<f64>,
    /// One value per time stamp.
    pub v: Vec<[f64; N]>,
}

impl<const N: usize> Series<N> {
    /// An empty series named `source`.
    pub fn new(source: impl Into<String>) -> Self {
        Self { source: source.into(), t: Vec::new(), v: Vec::new() }
    }

    /// Appends one sample.
    pub fn push(&mut self, t: f64, v: [f64; N]) {
        self.t.push(t);
        self.v.push(v);
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// True when there is no sample.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
}

/// Everything a reader found in one file, each part optional where logs may lack it.
///
/// The state `[x, y, z, psi, u, v, w, r]` is assembled from: `position` (or `depth` for z
/// alone), `attitude` (roll, pitch, yaw), body velocities either given (`velocity_body`) or
/// rotated from `velocity_ned` by the attitude, and the yaw rate `r` (given, or else the
/// derivative of the yaw). Inputs are body forces `[X, Y, Z, Mz]` held from each sample to
/// the next (a reader that has thruster commands converts them through the vehicle file's
/// thrusters first).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StreamSet {
    /// NED position (m).
    pub position: Option<Series<3>>,
    /// Depth (m, positive down) where no position exists or as a better z.
    pub depth: Option<Series<1>>,
    /// Roll, pitch, yaw (rad; yaw clockwise from north, as NED / forward-right-down implies).
    pub attitude: Option<Series<3>>,
    /// World-frame velocity, NED (m/s).
    pub velocity_ned: Option<Series<3>>,
    /// Body-frame velocity, forward-right-down (m/s).
    pub velocity_body: Option<Series<3>>,
    /// Yaw rate about the body's down axis (rad/s).
    pub yaw_rate: Option<Series<1>>,
    /// Body input `[X, Y, Z, Mz]`, each value held until the next sample.
    pub input: Option<Series<4>>,
    /// What the reader assumed and what it found (frames, units, messages skipped), one line
    /// each, printed with the import report.
    pub notes: Vec<String>,
}
