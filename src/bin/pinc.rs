//! `pinc`: simulate the vehicle, generate datasets, and (with later subcommands) train,
//! evaluate, inspect and run frozen models. Thin: argument parsing, calls into the library,
//! one-line errors with exit code 1 (runtime) or 2 (usage).

use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use pinc::dataset::{self, DatasetPreset};
use pinc::trajectory_csv::{parse_sim_state, read_inputs, write_trajectory};
use pinc::vehicle::Rk4Vehicle;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

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
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum PresetName {
    Paper,
    Mpc,
}

impl PresetName {
    fn preset(self) -> DatasetPreset {
        match self {
            PresetName::Paper => DatasetPreset::paper(),
            PresetName::Mpc => DatasetPreset::mpc(),
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate { x0, inputs, dt } => run_simulate(&x0, &inputs, dt),
        Command::GenData { preset, out, seed } => run_gen_data(preset.preset(), &out, seed),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::from(1)
        }
    }
}

fn run_simulate(x0: &str, inputs: &Path, dt: f64) -> Result<(), String> {
    let s0 = parse_sim_state(x0).map_err(|e| format!("--x0: {e}"))?;
    if !(dt.is_finite() && dt > 0.0) {
        return Err(format!("--dt must be a positive number of seconds, got {dt}"));
    }
    let file = std::fs::File::open(inputs).map_err(|e| format!("{}: {e}", inputs.display()))?;
    let inputs_seq = read_inputs(file).map_err(|e| format!("{}: {e}", inputs.display()))?;
    let traj = Rk4Vehicle::with_dt(dt).simulate(&s0, &inputs_seq);
    write_trajectory(std::io::stdout().lock(), dt, &traj).map_err(|e| format!("writing output: {e}"))
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
