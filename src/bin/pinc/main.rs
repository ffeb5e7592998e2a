//! `pinc`: simulate the vehicle, generate and import datasets, identify the vehicle, inspect and run frozen models. Thin: argument parsing, calls into the library,
//! one-line errors with exit code 1 (runtime) or 2 (usage).

use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use pinc::dataset::{self, DatasetPreset};
use pinc::model::{Activation, ModelError, ModelSummary, PincModel, import_state_dict};
use pinc::runtime::{Predictor, Quantity};
use pinc::trajectory_csv::{parse_sim_state, read_inputs, write_inputs, write_record, write_trajectory};
use pinc::vehicle::{Rk4Vehicle, VehicleParams, to_network, to_simulator};
use pinc::{Input, SimState, State};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

mod estimate_cmd;
mod eval_cmd;
#[cfg(all(feature = "train", feature = "vehicle"))]
mod fit_cmd;
mod identify_cmd;
mod import_cmd;
mod sweep_cmd;
mod thrusters_cmd;
#[cfg(feature = "train")]
mod train_cmd;

#[derive(Parser)]
#[command(name = "pinc", version, about = "Physics-informed neural network with control for a BlueROV2")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate the analytic vehicle under held inputs; prints CSV t,x,y,z,psi,u,v,w,r.
    Simulate {
        /// Initial state x,y,z,psi,u,v,w,r (m, rad, m/s, rad/s).
        #[arg(long, allow_hyphen_values = true)]
        x0: String,
        /// CSV with header X,Y,Z,Mz, one row per sample interval.
        #[arg(long)]
        inputs: PathBuf,
        /// Sample period (s).
        #[arg(long, default_value_t = pinc::DEFAULT_DT)]
        dt: f64,
        /// Vehicle file (TOML, keys of models/bluerov2.toml) [default: the BlueROV2].
        #[arg(long)]
        vehicle: Option<PathBuf>,
        /// Print a recorded run as `pinc dataset import --format csv` reads it: the inputs
        /// in each row (t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz).
        #[arg(long)]
        record: bool,
    },
    /// Write an excitation input file (X,Y,Z,Mz per sample period) to play on a vehicle with
    /// `pinc vehicle excite`. By default it is designed for `pinc fit` (docs/FIT.md): reversals
    /// between levels of a ladder on the chosen axes, pauses at zero, the other axes still;
    /// `--design generic` gives random steps, ramps and multisines on every channel.
    Excitation {
        /// Output CSV.
        #[arg(long)]
        out: PathBuf,
        /// Length (s): `pinc vehicle excite` stops earlier once the fit's coefficients are
        /// determined.
        #[arg(long, default_value_t = 600.0)]
        duration: f64,
        /// Sample period (s).
        #[arg(long, default_value_t = pinc::DEFAULT_DT)]
        dt: f64,
        /// Seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// `fit` (designed for the fit's coefficients) or `generic`.
        #[arg(long, default_value = "fit")]
        design: String,
        /// Axes the designed excitation drives: heave and yaw for a stock vehicle; add surge
        /// and sway where a position source (DVL, GPS, positioning system) measures them.
        #[arg(long, value_delimiter = ',', default_value = "heave,yaw")]
        axes: Vec<String>,
        /// Segment length of the generic excitation (s): each segment draws its own steps,
        /// ramps or multisines.
        #[arg(long, default_value_t = 10.0)]
        segment: f64,
        /// Vehicle file whose [[thruster]] tables bound the inputs [default: the BlueROV2 constants].
        #[arg(long)]
        vehicle: Option<PathBuf>,
    },
    /// Generate every set of a dataset preset as .npy arrays plus manifest.json.
    GenData {
        /// Which preset.
        #[arg(long, value_enum)]
        preset: PresetName,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Seed (the paper uses 0).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Vehicle file the trajectories are simulated with [default: the BlueROV2].
        #[arg(long)]
        vehicle: Option<PathBuf>,
    },
    /// Roll a frozen model out autoregressively; prints CSV t,x,y,z,psi,u,v,w,r.
    Predict {
        /// The .pinc model.
        #[arg(long)]
        model: PathBuf,
        /// Initial state x,y,z,psi,u,v,w,r (m, rad, m/s, rad/s).
        #[arg(long, allow_hyphen_values = true)]
        x0: String,
        /// CSV with header X,Y,Z,Mz, one row per sample interval.
        #[arg(long)]
        inputs: PathBuf,
        /// Time step (s); default: the model's sample period.
        #[arg(long)]
        dt: Option<f64>,
        /// Leave the predicted (cos psi, sin psi) as the network gives it (what PyTorch
        /// computes) instead of rescaling it to unit length after every step.
        #[arg(long)]
        no_renormalise_yaw: bool,
    },
    /// Print a model's header: architecture, envelope, provenance.
    Inspect {
        /// The .pinc model.
        model: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Convert a PyTorch state dict (safetensors, layout of the paper's code) to .pinc.
    ImportTorch {
        /// The safetensors state dict.
        #[arg(long)]
        weights: PathBuf,
        /// Output .pinc file.
        #[arg(long)]
        out: PathBuf,
        /// Sample period the network was trained for (s).
        #[arg(long, default_value_t = pinc::DEFAULT_DT)]
        dt: f64,
        /// Hidden-layer activation of the checkpoint.
        #[arg(long, value_enum, default_value = "softplus")]
        activation: ActivationName,
    },
    /// Train a PINC (or a data-only baseline, or with --hybrid a learned correction of a vehicle file) and freeze the best-on-dev weights.
    ///
    /// Writes OUT (the model), OUT with .csv (metrics per epoch) and .png (curves).
    #[cfg(feature = "train")]
    Train(Box<train_cmd::TrainArgs>),
    /// Redraw the training curves (PNG) from the per-epoch CSV `pinc train` wrote.
    #[cfg(feature = "train")]
    PlotTraining(train_cmd::PlotTrainingArgs),
    /// Train a PINC: needs the `train` feature (burn), which this build does not have.
    #[cfg(not(feature = "train"))]
    #[command(disable_help_flag = true)]
    Train {
        /// Whatever was given; nothing runs without the feature.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// The paper's metrics L1..L5 and VPT1..3 on freshly generated sets (or the metrics on a
    /// dataset folder's test split with --data), and a rollout plot.
    Eval(eval_cmd::EvalArgs),
    /// Mean VPT against the sample period for one or more models on the same generated sets,
    /// as a table (or --json) and a PNG.
    VptSweep(sweep_cmd::SweepArgs),
    /// Datasets from recorded runs.
    Dataset {
        #[command(subcommand)]
        action: Box<DatasetAction>,
    },
    /// Estimate the vehicle's added masses, damping and buoyancy from a dataset's train split.
    Identify(identify_cmd::IdentifyArgs),
    /// A vehicle file's thrusters: the allocation matrix and the reachable body inputs.
    Thrusters(thrusters_cmd::ThrustersArgs),
    /// The state estimator on a recorded .tlog (smoothed): body velocities for a log without
    /// them, as pinc's CSV log for `pinc dataset import`.
    Estimate(estimate_cmd::EstimateArgs),
    /// Fit a model to your vehicle from its recordings (stock ones too): the estimate, the
    /// identified vehicle, its sensor model, a hybrid, and a report; the model flies with
    /// `mpc_track --connect URL --model OUT/model.pinc` (docs/FIT.md).
    #[cfg(all(feature = "train", feature = "vehicle"))]
    Fit(Box<fit_cmd::FitArgs>),
    /// Fit a model to your vehicle: needs the `train` (burn) and `vehicle` features, which this build does not have.
    #[cfg(not(all(feature = "train", feature = "vehicle")))]
    #[command(disable_help_flag = true)]
    Fit {
        /// Whatever was given; nothing runs without the feature.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// A live ArduSub vehicle over MAVLink: check the link, record a session.
    #[cfg(feature = "vehicle")]
    Vehicle {
        #[command(subcommand)]
        action: pinc::vehicle_actions::VehicleAction,
    },
    /// A live ArduSub vehicle: needs the `vehicle` feature (MAVLink), which this build does not have.
    #[cfg(not(feature = "vehicle"))]
    #[command(disable_help_flag = true)]
    Vehicle {
        /// Whatever was given; nothing runs without the feature.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// The web page that takes an owner from an excitation to a fitted flight: the vehicle
    /// live, excite, fit, fly, STOP, the data folder (BlueOS's page for pinc; docs/BLUEOS.md).
    #[cfg(feature = "vehicle")]
    Serve(Box<pinc::serve::ServeArgs>),
}

#[derive(Subcommand)]
enum DatasetAction {
    /// Windows of recorded runs (CSV, or MCAP logs such as mpc_track's) as a dataset folder
    /// that `pinc train --data`, `pinc eval --data` and `pinc identify --data` read.
    Import(import_cmd::ImportArgs),
}

#[derive(Clone, Copy, ValueEnum)]
enum ActivationName {
    Softplus,
    Tanh,
}

/// Where `pinc train --data` and `pinc identify --data` start each prediction.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum Start {
    /// The recorded state.
    Recorded,
    /// The estimator's state from the samples before it (`pinc::estimation::window_starts`).
    Estimated,
}

/// What `pinc train --start estimated` and `pinc identify --start estimated` fit to.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum Targets {
    /// The recorded states.
    Recorded,
    /// The recorded states with u, v, w, r smoothed by the estimator over each run.
    Smoothed,
}

/// The targets asked for, else those that go with `start`: smoothed with estimated starts
/// (the velocity change measured on one footing: identified on them, the tank recordings'
/// physics predicted 0.72 s from estimated starts, against 0.52 s on the recorded targets).
pub(crate) fn targets_for(start: Start, asked: Option<Targets>) -> Targets {
    asked.unwrap_or(if start == Start::Estimated { Targets::Smoothed } else { Targets::Recorded })
}

impl From<Targets> for pinc::estimation::window_starts::Targets {
    fn from(t: Targets) -> Self {
        match t {
            Targets::Recorded => Self::Recorded,
            Targets::Smoothed => Self::Smoothed,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
pub(crate) enum PresetName {
    Paper,
    Mpc,
}

impl PresetName {
    pub(crate) fn preset(self) -> DatasetPreset {
        self.preset_for(VehicleParams::default())
    }

    /// The preset simulated with `vehicle`.
    pub(crate) fn preset_for(self, vehicle: VehicleParams) -> DatasetPreset {
        match self {
            PresetName::Paper => DatasetPreset { vehicle, ..DatasetPreset::paper() },
            PresetName::Mpc => DatasetPreset::mpc_for(vehicle),
        }
    }
}

fn main() -> ExitCode {
    pinc::broken_pipe::exit_quietly_on_broken_pipe();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate { x0, inputs, dt, vehicle, record } => {
            load_vehicle(vehicle.as_deref()).and_then(|v| run_simulate(&x0, &inputs, dt, v, record))
        }
        Command::Excitation { out, duration, dt, seed, design, axes, segment, vehicle } => {
            run_excitation(&out, duration, dt, seed, (&design, &axes, segment), vehicle.as_deref())
        }
        Command::GenData { preset, out, seed, vehicle } => load_vehicle(vehicle.as_deref()).and_then(|v| {
            // The `mpc` preset takes its input bounds from the file's thrusters when it has some.
            let preset = match (preset, thruster_bounds(vehicle.as_deref())?) {
                (PresetName::Mpc, Some((lo, hi))) => DatasetPreset::mpc_with_bounds(v, lo, hi),
                _ => preset.preset_for(v),
            };
            run_gen_data(preset, &out, seed)
        }),
        Command::Predict { model, x0, inputs, dt, no_renormalise_yaw } => {
            run_predict(&model, &x0, &inputs, dt, !no_renormalise_yaw)
        }
        Command::Inspect { model, json } => run_inspect(&model, json),
        Command::ImportTorch { weights, out, dt, activation } => run_import_torch(&weights, &out, dt, activation),
        #[cfg(feature = "train")]
        Command::Train(args) => train_cmd::run_train(*args),
        #[cfg(feature = "train")]
        Command::PlotTraining(args) => train_cmd::run_plot_training(args),
        #[cfg(not(feature = "train"))]
        Command::Train { .. } => {
            // Burn takes ~4x the rest of the build, so the default build leaves the trainer out.
            eprintln!(
                "error: this pinc was built without the trainer; run `cargo run --release --features train -- train ...`"
            );
            return ExitCode::from(2);
        }
        Command::Eval(args) => eval_cmd::run_eval(args),
        Command::VptSweep(args) => sweep_cmd::run_sweep(args),
        Command::Dataset { action } => match *action {
            DatasetAction::Import(args) => import_cmd::run_import(args),
        },
        Command::Identify(args) => identify_cmd::run_identify(args),
        Command::Thrusters(args) => thrusters_cmd::run_thrusters(args),
        Command::Estimate(args) => estimate_cmd::run_estimate(args),
        #[cfg(all(feature = "train", feature = "vehicle"))]
        Command::Fit(args) => fit_cmd::run_fit(*args),
        #[cfg(not(all(feature = "train", feature = "vehicle")))]
        Command::Fit { .. } => {
            eprintln!(
                "error: this pinc was built without the trainer or the vehicle link; run `cargo run --release --features train,vehicle -- fit ...`"
            );
            return ExitCode::from(2);
        }
        #[cfg(feature = "vehicle")]
        Command::Vehicle { action } => pinc::vehicle_actions::run_vehicle(action),
        #[cfg(feature = "vehicle")]
        Command::Serve(args) => pinc::serve::run_serve(*args),
        #[cfg(not(feature = "vehicle"))]
        Command::Vehicle { .. } => {
            eprintln!(
                "error: this pinc was built without the vehicle link; run `cargo run --release --features vehicle -- vehicle ...`"
            );
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        // The reader of our output went away (`pinc ... | head`): it has what it wanted.
        Err(message) if pinc::broken_pipe::is_broken_pipe(&message) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::from(1)
        }
    }
}

/// The shared arguments of `simulate` and `predict`, checked.
fn initial_and_inputs(x0: &str, inputs: &Path, dt: f64) -> Result<(SimState, Vec<Input>), String> {
    let s0 = parse_sim_state(x0).map_err(|e| format!("--x0: {e}"))?;
    if !(dt.is_finite() && dt > 0.0) {
        return Err(format!("--dt must be a positive number of seconds, got {dt}"));
    }
    let file = std::fs::File::open(inputs).map_err(|e| format!("{}: {e}", inputs.display()))?;
    let inputs_seq = read_inputs(file).map_err(|e| format!("{}: {e}", inputs.display()))?;
    Ok((s0, inputs_seq))
}

/// The vehicle of `--vehicle FILE`, or the BlueROV2 without one.
pub(crate) fn load_vehicle(path: Option<&Path>) -> Result<VehicleParams, String> {
    path.map_or(Ok(VehicleParams::default()), |p| VehicleParams::load(p).map_err(|e| e.to_string()))
}

fn run_simulate(x0: &str, inputs: &Path, dt: f64, vehicle: VehicleParams, record: bool) -> Result<(), String> {
    let (s0, inputs_seq) = initial_and_inputs(x0, inputs, dt)?;
    let traj = Rk4Vehicle { params: vehicle, ..Rk4Vehicle::with_dt(dt) }.simulate(&s0, &inputs_seq);
    let out = std::io::stdout().lock();
    if record { write_record(out, dt, &traj, &inputs_seq) } else { write_trajectory(out, dt, &traj) }
        .map_err(|e| format!("writing output: {e}"))
}

/// The reachable input box of `--vehicle FILE`'s thrusters; `None` without a file or thrusters.
fn thruster_bounds(path: Option<&Path>) -> Result<Option<dataset::InputBounds>, String> {
    path.map_or(Ok(None), |p| dataset::input_bounds_from_file(p).map_err(|e| e.to_string()))
}

/// `pinc excitation`; `design` is the kind (`fit` or `generic`), the designed excitation's
/// axes and the generic one's segment length (s).
fn run_excitation(
    out: &Path,
    duration: f64,
    dt: f64,
    seed: u64,
    (kind, axes, segment): (&str, &[String], f64),
    vehicle: Option<&Path>,
) -> Result<(), String> {
    use rand::SeedableRng;
    for (name, v) in [("--duration", duration), ("--dt", dt), ("--segment", segment)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(format!("{name} must be a positive number of seconds, got {v}"));
        }
    }
    let n = (duration / dt).round() as usize;
    let bounds = thruster_bounds(vehicle)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let inputs = dataset::design::excitation_inputs(kind, axes, segment, n, dt, bounds, &mut rng)?;
    let file = std::fs::File::create(out).map_err(|e| format!("{}: {e}", out.display()))?;
    write_inputs(std::io::BufWriter::new(file), &inputs).map_err(|e| format!("{}: {e}", out.display()))?;
    println!("{n} inputs ({duration} s at {dt} s, seed {seed}, design {kind}) -> {}", out.display());
    Ok(())
}

pub(crate) fn load_model(path: &Path) -> Result<PincModel, String> {
    PincModel::load(path).map_err(|e| match e {
        ModelError::Io { .. } => e.to_string(),
        other => format!("{}: {other}", path.display()),
    })
}

fn run_predict(model: &Path, x0: &str, inputs: &Path, dt: Option<f64>, renormalise: bool) -> Result<(), String> {
    let m = load_model(model)?;
    let dt = dt.unwrap_or(m.dt);
    let (s0, inputs_seq) = initial_and_inputs(x0, inputs, dt)?;
    let p = Predictor::new(&m).with_yaw_renormalisation(renormalise);
    let mut ws = p.workspace();
    let mut traj = vec![State::zeros(); inputs_seq.len() + 1];
    p.rollout_dt(&mut ws, &to_network(&s0), &inputs_seq, dt, &mut traj)
        .map_err(|e| format!("prediction failed: {e}"))?;
    let status = ws.envelope_status();
    if !status.inside() {
        let name = |q: Quantity| match q {
            Quantity::State(i) => pinc::STATE_NAMES[i],
            Quantity::Input(i) => pinc::INPUT_NAMES[i],
        };
        let each: Vec<String> = status
            .worst_exits()
            .iter()
            .map(|e| {
                format!("{} = {} at step {} (trained on [{}, {}])", name(e.quantity), e.value, e.step, e.min, e.max)
            })
            .collect();
        eprintln!(
            "warning: {} of {} steps outside the training envelope; farthest first: {}",
            status.exits,
            inputs_seq.len(),
            each.join("; ")
        );
    }
    if let Some(w) = status.heading_worst {
        eprintln!(
            "warning: at {} of {} steps the predicted (cos psi, sin psi) was off unit length by more than {} % \
             (farthest {:+.2} % at step {}){}",
            status.heading_off_circle,
            inputs_seq.len(),
            pinc::runtime::HEADING_TOLERANCE * 100.0,
            w.deviation * 100.0,
            w.step,
            if renormalise { "; rescaled" } else { "" }
        );
    }
    let sim: Vec<SimState> = traj.iter().map(to_simulator).collect();
    write_trajectory(std::io::stdout().lock(), dt, &sim).map_err(|e| format!("writing output: {e}"))
}

fn run_inspect(path: &Path, json: bool) -> Result<(), String> {
    let m = load_model(path)?;
    let size = std::fs::metadata(path).map(|md| md.len() as usize).ok();
    let mut summary = ModelSummary::new(&m, size);
    // The version the file was written in (it loaded, so its header is whole).
    let mut header = [0u8; 12];
    if std::io::Read::read_exact(&mut std::fs::File::open(path).map_err(|e| e.to_string())?, &mut header).is_ok() {
        summary.format_version = u32::from_le_bytes([header[8], header[9], header[10], header[11]]);
    }
    if json {
        println!("{}", serde_json::to_string_pretty(&summary).map_err(|e| e.to_string())?);
    } else {
        print!("{summary}");
    }
    Ok(())
}

fn run_import_torch(weights: &Path, out: &Path, dt: f64, activation: ActivationName) -> Result<(), String> {
    if !(dt.is_finite() && dt > 0.0) {
        return Err(format!("--dt must be a positive number of seconds, got {dt}"));
    }
    let bytes = std::fs::read(weights).map_err(|e| format!("{}: {e}", weights.display()))?;
    let activation = match activation {
        ActivationName::Softplus => Activation::Softplus,
        ActivationName::Tanh => Activation::Tanh,
    };
    let model = import_state_dict(&bytes, dt, activation).map_err(|e| format!("{}: {e}", weights.display()))?;
    model.save(out).map_err(|e| e.to_string())?;
    let a = &model.architecture;
    println!(
        "{} -> {}: {} x {} network, {} parameters, LayerNorm after hidden layers {:?}",
        weights.display(),
        out.display(),
        a.hidden_layers,
        a.width,
        model.parameter_count(),
        ModelSummary::new(&model, None).layer_norm_after
    );
    Ok(())
}

fn run_gen_data(preset: DatasetPreset, out: &Path, seed: u64) -> Result<(), String> {
    let start = Instant::now();
    let total: usize = preset.sets.iter().map(|s| s.count).sum();
    let bar = ProgressBar::new(total as u64).with_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} trajectories ({eta})")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.set_message(format!("{} seed {seed}", preset.name));
    let data = dataset::generate(&preset, seed, || bar.inc(1));
    bar.finish_and_clear();
    dataset::save(&data, out).map_err(|e| e.to_string())?;
    println!(
        "{} preset, seed {seed}: {} trajectories in {:.2} s -> {}",
        preset.name,
        total,
        start.elapsed().as_secs_f64(),
        out.display()
    );
    for s in &data.sets {
        println!("  {:<9} {:>5} x {} points, dt {} s", s.name, s.count, s.points, s.dt);
    }
    Ok(())
}
