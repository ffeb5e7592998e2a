//! `pinc serve`: the web page that takes an owner from an excitation to a fitted flight. It is
//! BlueOS's page for pinc (an extension) and works as well on a laptop against any autopilot
//! address (docs/BLUEOS.md).
//!
//! The parts: `vehicle_watch` (the server's own link: the vehicle live, a new link after a
//! reboot, STOP's neutral and disarm), `jobs` (one job at a time: excite and fly as child
//! processes, fit in a thread), `orders` (what the page asks, checked against the vehicle's
//! limits), `data_folder` (what is listed, downloaded, deleted), `routes` (HTTP, the token,
//! each refusal), `cockpit` (the extras Cockpit reads: the page as a widget, hold and STOP as
//! actions), and the page itself (`page.html`, no outside resources).

mod cockpit;
mod data_folder;
mod jobs;
mod orders;
mod routes;
mod vehicle_watch;

use crate::link::cli::LinkArgs;
use std::path::PathBuf;

/// Cockpit's MANUAL_CONTROL (system 255, component 240) as BlueOS's mavlink2rest keeps it.
const DEFAULT_JOYSTICK: &str = "http://127.0.0.1:6040/v1/mavlink/vehicles/255/components/240/messages/MANUAL_CONTROL";

/// Arguments of `pinc serve`.
#[derive(clap::Args)]
pub struct ServeArgs {
    /// The server's own link (the page's vehicle view and STOP), as for `pinc vehicle`.
    #[command(flatten)]
    link: LinkArgs,
    /// Where excitations and flights connect [default: --connect]: BlueOS's TCP endpoint
    /// takes several clients; a serial port or a simulator's one-client port needs a second.
    #[arg(long, value_name = "URL")]
    flight_connect: Option<String>,
    /// The data folder: recordings, excitations, models and flights (made if missing).
    #[arg(long, default_value = "pinc-data")]
    data: PathBuf,
    /// Address to listen on (BlueOS: 0.0.0.0, the vehicle's network).
    #[arg(long, default_value = "127.0.0.1")]
    bind: String,
    /// Port to listen on.
    #[arg(long, default_value_t = 8780)]
    port: u16,
    /// The vehicle file (its [[thruster]] tables) excitations and fits start from, unless the
    /// data folder has its own `vehicle.toml` (the owner's, which wins).
    #[arg(long)]
    vehicle: Option<PathBuf>,
    /// Deepest the page may ask for (m): references, the excitation's band, and every run's
    /// --max-depth stop [default: 50]. The limits the owner sets on the page (kept in the data
    /// folder's limits.json) win over these three flags.
    #[arg(long)]
    max_depth: Option<f64>,
    /// Longest excitation or scripted flight (s); the hold and pilot assist run until STOP
    /// [default: 1800].
    #[arg(long)]
    max_duration: Option<f64>,
    /// The farthest a flight may go from where it starts (m): a path reaching past it is
    /// refused, and crossing it stops the flight [default: 100].
    #[arg(long)]
    max_distance: Option<f64>,
    /// The most the data folder may hold (MB): a run that would take it past this is refused
    /// before it starts (delete old runs on the page); the page shows what it holds.
    #[arg(long, default_value_t = 1024.0)]
    max_data_mb: f64,
    /// A flight's figures, and the page's plots, keep its last S seconds (an hour's dive keeps
    /// the memory flat; the flight's log holds all of it).
    #[arg(long, value_name = "S", default_value_t = crate::link::session::DEFAULT_HISTORY_S)]
    history: f64,
    /// Where a flight on the pilot's joystick in Cockpit reads it (mpc_track's --pilot):
    /// mavlink2rest's copy of Cockpit's MANUAL_CONTROL (BlueOS's, as Cockpit sends through it),
    /// or `mavlink:255` where the router hands Cockpit's messages to pinc's link (BlueOS's
    /// MAVLink Server does, mavlink-router does not).
    #[arg(long, value_name = "URL|mavlink:SYSID", default_value = DEFAULT_JOYSTICK)]
    joystick: String,
    /// The system id a flight on Cockpit's joystick sends as: the autopilot's ground station
    /// in Cockpit's place for the flight (docs/PILOT.md).
    #[arg(long, value_name = "SYSID", default_value_t = 254)]
    joystick_flight_sysid: u8,
    /// A website's origin (scheme://host[:port]) whose pages may send commands besides pinc's
    /// own page, BlueOS's pages at the same address and Cockpit desktop (repeat; e.g. a Cockpit
    /// served from a laptop, `http://192.168.2.1:5173`). Every other site's page is refused.
    #[arg(long = "allow-origin", value_name = "ORIGIN")]
    allow_origins: Vec<String>,
    /// One more argument for every excitation and flight (repeat; e.g. `--run-arg=--js-gain
    /// --run-arg=1`, or the estimator's sensor noise).
    #[arg(long = "run-arg", value_name = "ARG", allow_hyphen_values = true)]
    run_args: Vec<String>,
}

/// Runs `pinc serve`: checks the limits, opens the data folder, watches the vehicle and serves
/// the page until the process ends (its address on stderr).
pub fn run_serve(a: ServeArgs) -> Result<(), String> {
    for (flag, v) in [("--max-data-mb", a.max_data_mb), ("--history", a.history)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(format!("{flag} must be a positive number, got {v}"));
        }
    }
    if a.history < 10.0 {
        return Err(format!("--history must be at least 10 s, got {}", a.history));
    }
    let data = data_folder::DataFolder::open(&a.data).map_err(|e| e.to_string())?;
    let flags = orders::DiveLimits {
        max_depth: a.max_depth.unwrap_or(orders::DIVE_LIMITS.max_depth),
        max_distance: a.max_distance.unwrap_or(orders::DIVE_LIMITS.max_distance),
        max_duration: a.max_duration.unwrap_or(orders::DIVE_LIMITS.max_duration),
    };
    flags.check().map_err(|e| format!("--{}", e.replacen('_', "-", 2)))?;
    let dive = match data.limits().map_err(|e| e.to_string())? {
        Some(own) => {
            eprintln!("pinc serve: the owner's limits from the data folder's limits.json: {own:?}");
            own
        }
        None => flags,
    };
    let limits = dive.with_data_bytes(a.max_data_mb * 1e6);
    let here = std::env::current_exe().map_err(|e| format!("cannot find this program: {e}"))?;
    let bin = here.parent().map(PathBuf::from).unwrap_or_default();
    let mpc_track = bin.join("mpc_track");
    if !mpc_track.is_file() {
        return Err(format!("{} is missing: pinc serve runs mpc_track from its own folder", mpc_track.display()));
    }
    // One cycle per 0.08 s at most, the model's usual period.
    let jobs = jobs::Jobs::keeping((a.history / 0.08).ceil() as usize);
    let ground = crate::link::session::ground_station_of(&a.joystick)
        .map_err(|e| e.replace("--pilot", "--joystick"))?
        .ok_or_else(|| format!("--joystick {}: not a ground station's joystick (docs/PILOT.md)", a.joystick))?;
    let left = vehicle_watch::LeftPlace { flight: a.joystick_flight_sysid, ground, jobs: jobs.clone() };
    let watcher = vehicle_watch::Watcher::default();
    watcher.start(a.link.connect.clone(), a.link.options.clone(), left);
    let token = data.token().map_err(|e| e.to_string())?;
    let app = routes::App {
        data,
        watcher,
        jobs,
        history_s: a.history,
        until_stop: Default::default(),
        ground_station: ground,
        allowed_origins: a.allow_origins.iter().map(|o| o.trim_end_matches('/').to_string()).collect(),
        token,
        limits: std::sync::Mutex::new(limits),
        vehicle: a.vehicle.clone(),
        flight_connect: a.flight_connect.clone().unwrap_or_else(|| a.link.connect.clone()),
        run_args: a.run_args.clone(),
        joystick: a.joystick.clone(),
        joystick_flight_sysid: a.joystick_flight_sysid,
        pinc: here,
        mpc_track,
        storage: Default::default(),
    };
    let server = tiny_http::Server::http((a.bind.as_str(), a.port))
        .map_err(|e| format!("cannot listen on {}:{}: {e}", a.bind, a.port))?;
    // Scripts (and the tests) read the address from this line.
    eprintln!("pinc serve: http://{} (data {}, vehicle at {})", server.server_addr(), a.data.display(), a.link.connect);
    routes::serve(server, std::sync::Arc::new(app));
    Ok(())
}
