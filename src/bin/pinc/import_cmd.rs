//! `pinc dataset import`: recorded runs (CSV or MCAP) to a dataset folder.

use pinc::dataset::import::{
    ArdupilotOptions, BodyFrame, CsvMapping, ImportError, ImportOptions, InputSource, LogFile, McapTopics, Ros2Options,
    StreamSet, WorldFrame, file_bytes, import_logs, load_mapping, log_dt, mcap_is_cdr, read_bin, read_csv,
    read_mapped_csv, read_mcap, read_ros2, read_tlog, sha256_hex, stream_set_of,
};
use pinc::vehicle::Thrusters;
use std::path::{Path, PathBuf};

/// Arguments of `pinc dataset import`.
#[derive(clap::Args)]
pub struct ImportArgs {
    /// Format of the files [default: each file's extension: .csv, .mcap (pinc's JSON or a ROS 2
    /// bag's CDR), .bin, .tlog, .db3; a folder is a ROS 2 bag].
    #[arg(long, value_enum)]
    pub format: Option<LogFormat>,
    /// Output dataset folder (written whole or not at all).
    #[arg(long)]
    pub out: PathBuf,
    /// Sample period of the dataset (s); every stream is resampled to it [default: the
    /// median period of the slowest state stream, to the ms, the longest over the files].
    #[arg(long)]
    pub dt: Option<f64>,
    /// A step between two samples of a stream longer than this (s) is a gap, which ends a
    /// window [default: per stream, 3 of its median periods and at least 2 dt].
    #[arg(long)]
    pub gap_tolerance: Option<f64>,
    /// Points per window (intervals + 1).
    #[arg(long, default_value_t = pinc::dataset::TRAJECTORY_POINTS)]
    pub window: usize,
    /// Fractions of train, dev and test, split by run.
    #[arg(long, value_delimiter = ',', default_value = "0.7,0.15,0.15")]
    pub split: Vec<f64>,
    /// Seed of the run shuffle and of the collocation times.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Physics-loss collocation times per interval of the train split (1: t = dt, as the presets).
    #[arg(long, default_value_t = 1)]
    pub collocation: usize,
    /// MCAP: topic of the state messages.
    #[arg(long, default_value = "/vehicle/state")]
    pub state_topic: String,
    /// MCAP: field of the state message holding x, y, z, psi, u, v, w, r (dotted path).
    #[arg(long, default_value = "sim")]
    pub state_field: String,
    /// MCAP: topic of the command messages.
    #[arg(long, default_value = "/mpc/command")]
    pub command_topic: String,
    /// MCAP: field of the command message holding X, Y, Z, Mz (dotted path).
    #[arg(long, default_value = "input")]
    pub command_field: String,
    /// CSV: a mapping file (TOML, docs/LOGS_CSV.md) naming the columns, units and frames of a
    /// CSV that is not in pinc's own layout.
    #[arg(long, value_name = "FILE")]
    pub mapping: Option<PathBuf>,
    /// The vehicle file whose thrusters turn logged thruster commands (ArduPilot outputs, a
    /// mapped CSV's PWM columns) into body forces.
    #[arg(long, value_name = "V.toml")]
    pub vehicle: Option<PathBuf>,
    /// ArduPilot logs: the inputs from the thruster outputs the autopilot logged (`outputs`),
    /// or from the pilot's commands through ArduSub's MANUAL-mode mixer (`pilot`).
    #[arg(long, value_enum, default_value = "outputs")]
    pub inputs: InputsFrom,
    /// ArduPilot logs with `--inputs pilot`: ArduSub's joystick gain (JS_GAIN_DEFAULT; 0.5
    /// unless changed on the vehicle).
    #[arg(long, default_value_t = 0.5)]
    pub js_gain: f64,
    /// .tlog: water density (kg/m^3) that turns pressure into depth where no position exists.
    #[arg(long, default_value_t = 1000.0)]
    pub water_density: f64,
    /// ROS 2 bags: the nav_msgs/Odometry topic [default: the only one of that type].
    #[arg(long)]
    pub odometry_topic: Option<String>,
    /// ROS 2 bags: a geometry_msgs/PoseStamped topic replacing the odometry's pose.
    #[arg(long)]
    pub pose_topic: Option<String>,
    /// ROS 2 bags: a geometry_msgs/TwistStamped topic replacing the odometry's twist.
    #[arg(long)]
    pub twist_topic: Option<String>,
    /// ROS 2 bags: the geometry_msgs/WrenchStamped topic of the body input.
    #[arg(long)]
    pub wrench_topic: Option<String>,
    /// ROS 2 bags: thruster commands (mavros_msgs/RCOut or px4_msgs/ActuatorOutputs) as the
    /// input, through --vehicle's thrusters.
    #[arg(long)]
    pub outputs_topic: Option<String>,
    /// ROS 2 bags: the world frame's axes, overriding what the frame names say (REP 103:
    /// `map`, `odom` are ENU; a `_ned` suffix is NED).
    #[arg(long, value_parser = ["ned", "enu"])]
    pub world_frame: Option<String>,
    /// ROS 2 bags: the body frame's axes, overriding what the frame names say (`base_link`
    /// is forward-left-up; a `_frd` suffix is forward-right-down).
    #[arg(long, value_parser = ["frd", "flu"])]
    pub body_frame: Option<String>,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
    /// The recorded runs, one per file (a ROS 2 bag: its folder or its .mcap / .db3 file).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
}

/// Log formats `pinc dataset import` reads.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum LogFormat {
    /// Header t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz, or any CSV with --mapping.
    Csv,
    /// JSON messages on a state and a command topic (the logs `mpc_track` and `pinc vehicle
    /// record` write).
    Mcap,
    /// ArduPilot's onboard dataflash log.
    Bin,
    /// QGroundControl's telemetry log (time-stamped MAVLink).
    Tlog,
    /// A ROS 2 bag (MCAP with CDR messages, or sqlite3 .db3).
    Ros2,
}

/// Where ArduPilot logs' inputs come from.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum InputsFrom {
    /// The thruster outputs (RCOU, SERVO_OUTPUT_RAW) through the vehicle file's thrusters.
    Outputs,
    /// The pilot's commands (MANUAL_CONTROL, RCIN) through ArduSub's MANUAL-mode mixer (the
    /// thrusters' `mix` factors) and then the thrusters.
    Pilot,
}

/// What a reader needs besides the file: the options of every format.
pub struct ReaderOptions {
    /// MCAP topics and fields.
    pub topics: McapTopics,
    /// A CSV mapping.
    pub mapping: Option<CsvMapping>,
    /// The vehicle's thrusters.
    pub thrusters: Option<Thrusters>,
    /// Where ArduPilot logs' inputs come from, and the joystick gain.
    pub inputs: (InputsFrom, f64),
    /// Water density for pressure depth (kg/m^3).
    pub water_density: f64,
    /// ROS 2 topics and frames.
    pub ros2: Ros2Options,
}

impl ReaderOptions {
    /// The ArduPilot readers' options: inputs through the thrusters.
    fn ardupilot(&self, path: &Path) -> Result<ArdupilotOptions, ImportError> {
        let Some(thrusters) = self.thrusters.clone() else {
            return Err(ImportError::Unusable(format!(
                "{}: the inputs of an ArduPilot log are thruster commands; give --vehicle with the vehicle's \
                 [[thruster]] tables (models/bluerov2.toml for a BlueROV2)",
                path.display()
            )));
        };
        let inputs = match self.inputs {
            (InputsFrom::Outputs, _) => InputSource::ThrusterOutputs,
            (InputsFrom::Pilot, gain) => {
                let mix = thrusters
                    .list
                    .iter()
                    .map(|t| t.mix.map(|m| [m[4], m[5], m[3], m[2]]))
                    .collect::<Option<Vec<_>>>()
                    .ok_or_else(|| {
                        ImportError::Unusable(
                            "--inputs pilot needs every thruster's `mix` factors in the vehicle file".into(),
                        )
                    })?;
                InputSource::ManualControl { gain, mix }
            }
        };
        Ok(ArdupilotOptions {
            inputs,
            thrusters: Some(Box::new(move |c: &[f64]| thrusters.input_from_commands(c))),
            water_density: self.water_density,
            ..ArdupilotOptions::default()
        })
    }
}

/// A log reader: one file to its streams.
type Reader = fn(&Path, &ReaderOptions) -> Result<StreamSet, ImportError>;

/// The reader of each format.
fn reader(format: LogFormat) -> Reader {
    match format {
        LogFormat::Csv => |p, o| match &o.mapping {
            None => read_csv(p).map(|r| stream_set_of(&r)),
            Some(m) => match &o.thrusters {
                Some(t) => read_mapped_csv(p, m, Some(&|c: &[f64]| t.input_from_commands(c))),
                None => read_mapped_csv(p, m, None),
            },
        },
        LogFormat::Mcap => |p, o| read_mcap(p, &o.topics).map(|r| stream_set_of(&r)),
        LogFormat::Bin => |p, o| read_bin(p, &o.ardupilot(p)?),
        LogFormat::Tlog => |p, o| read_tlog(p, &o.ardupilot(p)?),
        LogFormat::Ros2 => |p, o| match &o.thrusters {
            Some(t) => read_ros2(p, &o.ros2, Some(&|c: &[f64]| t.input_from_commands(c))),
            None => read_ros2(p, &o.ros2, None),
        },
    }
}

/// The format of a file from its extension; an MCAP file whose messages are CDR is a ROS 2
/// bag, a folder is a ROS 2 bag's.
fn format_of(path: &Path) -> Option<LogFormat> {
    if path.is_dir() {
        return Some(LogFormat::Ros2);
    }
    match pinc::dataset::import::log_extension(path).as_deref() {
        Some("csv") => Some(LogFormat::Csv),
        Some("mcap") if mcap_is_cdr(path) => Some(LogFormat::Ros2),
        Some("mcap") => Some(LogFormat::Mcap),
        Some("db3") => Some(LogFormat::Ros2),
        Some("bin") => Some(LogFormat::Bin),
        Some("tlog") => Some(LogFormat::Tlog),
        _ => None,
    }
}

fn format_name(f: LogFormat) -> &'static str {
    match f {
        LogFormat::Csv => "csv",
        LogFormat::Mcap => "mcap",
        LogFormat::Bin => "bin",
        LogFormat::Tlog => "tlog",
        LogFormat::Ros2 => "ros2",
    }
}

pub fn run_import(a: ImportArgs) -> Result<(), String> {
    let reader_options = ReaderOptions {
        topics: McapTopics {
            state_topic: a.state_topic.clone(),
            state_field: a.state_field.clone(),
            command_topic: a.command_topic.clone(),
            command_field: a.command_field.clone(),
        },
        mapping: a.mapping.as_deref().map(load_mapping).transpose().map_err(|e| e.to_string())?,
        thrusters: a.vehicle.as_deref().map(Thrusters::load).transpose().map_err(|e| e.to_string())?,
        inputs: (a.inputs, a.js_gain),
        water_density: a.water_density,
        ros2: Ros2Options {
            odometry_topic: a.odometry_topic.clone(),
            pose_topic: a.pose_topic.clone(),
            twist_topic: a.twist_topic.clone(),
            wrench_topic: a.wrench_topic.clone(),
            outputs_topic: a.outputs_topic.clone(),
            world_frame: a.world_frame.as_deref().map(str::parse::<WorldFrame>).transpose()?,
            body_frame: a.body_frame.as_deref().map(str::parse::<BodyFrame>).transpose()?,
        },
    };
    let split: [f64; 3] =
        a.split.clone().try_into().map_err(|_| "--split: three fractions, e.g. 0.7,0.15,0.15".to_string())?;
    let formats: Vec<LogFormat> = a
        .files
        .iter()
        .map(|path| {
            a.format.or_else(|| format_of(path)).ok_or_else(|| {
                format!(
                    "{}: format not known from the extension (.csv, .mcap, .bin, .tlog, .db3, or a bag folder); give --format",
                    path.display()
                )
            })
        })
        .collect::<Result<_, _>>()?;
    let mut names: Vec<&str> = formats.iter().map(|&f| format_name(f)).collect();
    names.dedup();
    let uses_mcap = formats.iter().any(|f| matches!(f, LogFormat::Mcap));
    let mut options = ImportOptions {
        format: names.join("+"),
        dt: a.dt.unwrap_or(pinc::DEFAULT_DT),
        window: a.window,
        split,
        seed: a.seed,
        collocation_points: a.collocation,
        topics: uses_mcap.then(|| reader_options.topics.clone()),
        gap_tolerance: a.gap_tolerance,
        dt_from_log: a.dt.is_none(),
    };
    options.check().map_err(|e| e.to_string())?;
    let mut logs = Vec::with_capacity(a.files.len());
    for (path, &format) in a.files.iter().zip(&formats) {
        let bytes = file_bytes(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let streams = reader(format)(path, &reader_options).map_err(|e| e.to_string())?;
        logs.push(LogFile { path: path.clone(), sha256: sha256_hex(&bytes), streams });
    }
    if a.dt.is_none() {
        let chosen = logs
            .iter()
            .filter_map(|l| log_dt(&l.streams))
            .fold(None, |m: Option<f64>, d| Some(m.map_or(d, |m| m.max(d))));
        options.dt = chosen.ok_or("no state stream with two samples to take --dt from; give --dt")?;
        options.check().map_err(|e| e.to_string())?;
    }
    let data = import_logs(&logs, &options).map_err(|e| e.to_string())?;
    pinc::dataset::save(&data, &a.out).map_err(|e| e.to_string())?;
    let source = data.source.as_ref().expect("import records its source");
    if a.json {
        let sets: serde_json::Map<String, serde_json::Value> =
            data.sets.iter().map(|s| (s.name.clone(), s.count.into())).collect();
        let v = serde_json::json!({
            "out": a.out.display().to_string(),
            "dt": options.dt,
            "dt_from_log": options.dt_from_log,
            "windows": sets,
            "split_by": source.split_by,
            "skipped": source.skipped,
            "files": source.files,
        });
        println!("{}", serde_json::to_string_pretty(&v).map_err(|e| e.to_string())?);
        return Ok(());
    }
    let counts: Vec<String> = data.sets.iter().map(|s| format!("{} {}", s.count, s.name)).collect();
    println!(
        "{} files -> {}: {} windows of {} points at {} s{} ({}), split by {}",
        a.files.len(),
        a.out.display(),
        data.sets.iter().map(|s| s.count).sum::<usize>(),
        a.window,
        options.dt,
        if options.dt_from_log { " (from the logs)" } else { "" },
        counts.join(", "),
        source.split_by
    );
    println!("  {}", source.skipped);
    for f in &source.files {
        println!("  {:<40} {:>7} rows {:>5} windows -> {}", f.path, f.rows, f.windows, f.split);
        for s in &f.report.streams {
            let rate = s.rate_hz.map_or("-".into(), |r| format!("{r:.2} Hz"));
            let span = s.span_s.map_or("-".into(), |(a, b)| format!("{a:.3}..{b:.3} s"));
            println!(
                "    {:<14} {:<28} {:>7} samples {:>10} {:>22} {} gaps (> {:.3} s), longest step {:.3} s{}",
                s.name,
                s.source,
                s.samples,
                rate,
                span,
                s.gaps,
                s.gap_tolerance_s,
                s.longest_step_s,
                if s.dropped > 0 { format!(", {} dropped (time stamp)", s.dropped) } else { String::new() }
            );
        }
        for n in &f.report.notes {
            println!("    note: {n}");
        }
    }
    Ok(())
}
