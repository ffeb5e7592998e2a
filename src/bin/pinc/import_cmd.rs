//! `pinc dataset import`: recorded runs (CSV or MCAP) to a dataset folder.

use pinc::dataset::import::{ImportOptions, McapTopics, Recording, import, read_csv, read_mcap, sha256_hex};
use std::path::PathBuf;

/// Arguments of `pinc dataset import`.
#[derive(clap::Args)]
pub struct ImportArgs {
    /// Format of the files [default: each file's extension, .csv or .mcap].
    #[arg(long, value_enum)]
    pub format: Option<LogFormat>,
    /// Output dataset folder (written whole or not at all).
    #[arg(long)]
    pub out: PathBuf,
    /// Sample period of the dataset (s); logs at an integer fraction of it are decimated.
    #[arg(long, default_value_t = pinc::DEFAULT_DT)]
    pub dt: f64,
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
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
    /// The recorded runs, one per file.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
}

/// Log formats `pinc dataset import` reads.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum LogFormat {
    /// Header t,x,y,z,psi,u,v,w,r,X,Y,Z,Mz.
    Csv,
    /// JSON messages on a state and a command topic (the logs `mpc_track` writes).
    Mcap,
}

pub fn run_import(a: ImportArgs) -> Result<(), String> {
    let topics = McapTopics {
        state_topic: a.state_topic.clone(),
        state_field: a.state_field.clone(),
        command_topic: a.command_topic.clone(),
        command_field: a.command_field.clone(),
    };
    let split: [f64; 3] =
        a.split.clone().try_into().map_err(|_| "--split: three fractions, e.g. 0.7,0.15,0.15".to_string())?;
    let formats: Vec<LogFormat> = a
        .files
        .iter()
        .map(|path| match a.format {
            Some(f) => Ok(f),
            None => match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
                Some("csv") => Ok(LogFormat::Csv),
                Some("mcap") => Ok(LogFormat::Mcap),
                _ => Err(format!("{}: not .csv or .mcap; give --format", path.display())),
            },
        })
        .collect::<Result<_, _>>()?;
    let name = |f: &LogFormat| match f {
        LogFormat::Csv => "csv",
        LogFormat::Mcap => "mcap",
    };
    let mut names: Vec<&str> = formats.iter().map(name).collect();
    names.dedup();
    let uses_mcap = formats.iter().any(|f| matches!(f, LogFormat::Mcap));
    let options = ImportOptions {
        format: names.join("+"),
        dt: a.dt,
        window: a.window,
        split,
        seed: a.seed,
        collocation_points: a.collocation,
        topics: uses_mcap.then(|| topics.clone()),
    };
    options.check().map_err(|e| e.to_string())?;
    let mut recordings: Vec<Recording> = Vec::with_capacity(a.files.len());
    let mut hashes = Vec::with_capacity(a.files.len());
    for (path, format) in a.files.iter().zip(&formats) {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        hashes.push(sha256_hex(&bytes));
        let rec = match format {
            LogFormat::Csv => read_csv(path),
            LogFormat::Mcap => read_mcap(path, &topics),
        }
        .map_err(|e| e.to_string())?;
        recordings.push(rec);
    }
    let data = import(&recordings, &hashes, &options).map_err(|e| e.to_string())?;
    pinc::dataset::save(&data, &a.out).map_err(|e| e.to_string())?;
    let source = data.source.as_ref().expect("import records its source");
    if a.json {
        let sets: serde_json::Map<String, serde_json::Value> =
            data.sets.iter().map(|s| (s.name.clone(), s.count.into())).collect();
        let v = serde_json::json!({
            "out": a.out.display().to_string(),
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
        "{} files -> {}: {} windows of {} points at {} s ({}), split by {}",
        a.files.len(),
        a.out.display(),
        data.sets.iter().map(|s| s.count).sum::<usize>(),
        a.window,
        a.dt,
        counts.join(", "),
        source.split_by
    );
    println!("  {}", source.skipped);
    for f in &source.files {
        println!("  {:<40} {:>7} rows {:>5} windows -> {}", f.path, f.rows, f.windows, f.split);
    }
    Ok(())
}
