//! The HTTP routes. Reads are GETs; everything that moves the vehicle or changes the data
//! folder is a POST carrying the token the page was given in an `X-Pinc-Token` header. The
//! token is not the guard against other websites: behind BlueOS's proxy every answer carries
//! `Access-Control-Allow-Origin: *`, so any page a pilot's browser opens can read it. The guard
//! is the `Origin` a browser sends with every POST and cannot be made to forge: a command is
//! taken from pinc's own page (its own origin, as BlueOS serves it), Cockpit desktop (`file://`),
//! an origin `--allow-origin` names, or no browser at all; another site's page is refused, and
//! its browser's preflight is refused too. Every refusal is a JSON `{"error": ...}` with its
//! status, and a line in the server's log.

use super::data_folder::DataFolder;
use super::jobs::{Handle, Jobs, Kind, Step};
use super::orders::{self, DiveLimits, ExciteOrder, FitOrder, FlyOrder, Limits, References};
use super::vehicle_watch::Watcher;
use serde::de::DeserializeOwned;
use serde_json::{Value, json};
use std::io::Read;
use std::path::PathBuf;
use std::sync::Arc;
use tiny_http::{Header, Method, Request, Response, Server};

/// The largest request body read (bytes).
const MAX_BODY: u64 = 64 * 1024;
/// The page, with `__PINC_TOKEN__` for the token.
const PAGE: &str = include_str!("page.html");

/// Everything the routes share.
pub struct App {
    pub data: DataFolder,
    pub watcher: Watcher,
    pub jobs: Jobs,
    pub token: String,
    /// The owner's limits (the page sets them between runs).
    pub limits: std::sync::Mutex<Limits>,
    /// The ground station whose place the hold takes (Cockpit's id).
    pub ground_station: u8,
    pub vehicle: Option<PathBuf>,
    pub flight_connect: String,
    pub run_args: Vec<String>,
    /// Where a flight on Cockpit's joystick reads it, and the system id that flight sends as.
    pub joystick: String,
    pub joystick_flight_sysid: u8,
    /// A flight's figures keep its last this many seconds (`--history`).
    pub history_s: f64,
    /// The job id of the flight running until STOP (the hold, pilot assist): what "resume"
    /// hands back to the pilot.
    pub until_stop: std::sync::Mutex<Option<u64>>,
    /// Origins besides the page's own and Cockpit desktop's whose pages may send commands.
    pub allowed_origins: Vec<String>,
    pub pinc: PathBuf,
    pub mpc_track: PathBuf,
    /// What the data folder holds and its disk's free space (bytes), and when they were read:
    /// the state is polled five times a second per page, the folder walked at most every 2 s.
    pub storage: std::sync::Mutex<Option<(std::time::Instant, u64, Option<u64>)>>,
}

/// The `Origin` Cockpit desktop's fetches carry: Electron loads its page from a file, and with
/// the file protocol's privileges Electron grants by default its requests say `file://` (a plain
/// browser's file page and a sandboxed frame say `null`, refused).
const COCKPIT_DESKTOP_ORIGIN: &str = "file://";

/// Where a request comes from ([`App::origin_of`]).
enum Origin {
    /// No `Origin` header: not a browser's page (a script, a ground station's own HTTP client).
    None,
    Allowed(String),
    /// Another website's page: nothing it sends moves the vehicle.
    Other(String),
}

/// This server's own origin, as a request reaches it: the scheme (BlueOS's nginx says it in
/// `X-Forwarded-Proto`), the `Host` asked for, and whether a proxy passed it on.
struct Own {
    scheme: String,
    host: Option<String>,
    proxied: bool,
}

impl Own {
    /// Whether `origin` is this server's own. BlueOS's nginx passes its `$host`, which has no
    /// port: behind it (it adds `X-Forwarded-For`) a page of the vehicle's address on another port
    /// is its own too.
    fn is(&self, origin: &str) -> bool {
        let Some(host) = &self.host else { return false };
        let own = format!("{}://{host}", self.scheme);
        let without_port = |o: &str| {
            o.rsplit_once(':').filter(|(_, p)| p.parse::<u16>().is_ok()).map_or(o, |(h, _)| h).to_ascii_lowercase()
        };
        own.eq_ignore_ascii_case(origin) || (self.proxied && without_port(&own) == without_port(origin))
    }
}

/// A browser's question before a command with the token's header (`OPTIONS`): answered yes
/// for the page's own origin, Cockpit desktop's and those `--allow-origin` names, refused for any
/// other (BlueOS's proxy adds `Access-Control-Allow-Origin: *` to every answer, but without the
/// allowed headers the browser still never sends the command).
fn preflight(path: &str, origin: Origin) -> Reply {
    match origin {
        Origin::Allowed(o) if path.starts_with("/api/") => Ok(Response::from_data(Vec::new())
            .with_status_code(204)
            .with_header(header("Access-Control-Allow-Origin", &o))
            .with_header(header("Access-Control-Allow-Methods", "POST"))
            .with_header(header("Access-Control-Allow-Headers", "Content-Type, X-Pinc-Token"))
            // A page on a laptop asking the vehicle's private address (Chromium's private
            // network access) is asked too.
            .with_header(header("Access-Control-Allow-Private-Network", "true"))
            .with_header(header("Access-Control-Max-Age", "600"))
            .with_header(header("Vary", "Origin"))),
        Origin::Other(o) => {
            Err(Refused(403, format!("refused: another website's page ({o}) may not send commands here")))
        }
        _ => Err(Refused(404, format!("nothing to ask about at {path}"))),
    }
}

/// A refusal: status and message.
struct Refused(u16, String);

type Reply = Result<Response<std::io::Cursor<Vec<u8>>>, Refused>;

fn header(name: &str, value: &str) -> Header {
    Header::from_bytes(name.as_bytes(), value.as_bytes()).expect("ASCII header")
}

fn json_reply(status: u16, v: &Value) -> Response<std::io::Cursor<Vec<u8>>> {
    Response::from_data(v.to_string().into_bytes())
        .with_status_code(status)
        .with_header(header("Content-Type", "application/json"))
        .with_header(header("Cache-Control", "no-store"))
}

/// Answers requests for ever, each on its own thread (a download must not hold the page's polls).
pub fn serve(server: Server, app: Arc<App>) {
    for request in server.incoming_requests() {
        let app = app.clone();
        std::thread::spawn(move || app.answer(request));
    }
}

impl App {
    fn answer(&self, mut request: Request) {
        let method = request.method().clone();
        let url = request.url().to_string();
        let (path, query) = url.split_once('?').unwrap_or((&url, ""));
        let query: Vec<(String, String)> = form_urlencoded::parse(query.as_bytes()).into_owned().collect();
        let origin = self.origin_of(&request);
        let reply = if method == Method::Get {
            self.get(path, &query)
        } else if method == Method::Options {
            preflight(path, origin)
        } else if method == Method::Post {
            match origin {
                Origin::Other(o) => Err(Refused(
                    403,
                    format!(
                        "refused: a command from another website's page ({o}) moves nothing (pinc serve --allow-origin)"
                    ),
                )),
                _ => self.post(path, &mut request),
            }
        } else {
            Err(Refused(405, format!("{method} is not answered here")))
        };
        let response = reply.unwrap_or_else(|Refused(status, message)| {
            eprintln!("serve: refused {method} {path}: {message}");
            json_reply(status, &json!({"error": message}))
        });
        let _ = request.respond(response);
    }

    /// Who sent the request, by its `Origin` (what a browser always sends with a cross-origin
    /// request and with a POST, and a page cannot forge): none (not a browser), this server's own
    /// origin (its page, or BlueOS's pages behind the same address), Cockpit desktop (`file://`),
    /// one `--allow-origin` names, or another website's page.
    fn origin_of(&self, request: &Request) -> Origin {
        let value = |name: &'static str| {
            request.headers().iter().find(|h| h.field.equiv(name)).map(|h| h.value.as_str().trim().to_string())
        };
        let Some(origin) = value("Origin") else { return Origin::None };
        let own = Own {
            scheme: value("X-Forwarded-Proto").unwrap_or_else(|| "http".into()),
            host: value("Host"),
            proxied: value("X-Forwarded-For").is_some(),
        };
        if own.is(&origin)
            || origin == COCKPIT_DESKTOP_ORIGIN
            || self.allowed_origins.iter().any(|a| a.eq_ignore_ascii_case(&origin))
        {
            Origin::Allowed(origin)
        } else {
            Origin::Other(origin)
        }
    }

    fn get(&self, path: &str, query: &[(String, String)]) -> Reply {
        let arg = |k: &str| query.iter().find(|(key, _)| key == k).map(|(_, v)| v.as_str());
        match path {
            "/" | "/index.html" => Ok(Response::from_data(PAGE.replace("__PINC_TOKEN__", &self.token).into_bytes())
                .with_header(header("Content-Type", "text/html; charset=utf-8"))
                .with_header(header("Cache-Control", "no-store"))),
            // BlueOS scans the vehicle's ports for this and shows `/` in its interface.
            "/register_service" => Ok(json_reply(
                200,
                &json!({
                    "name": "pinc",
                    "description": "Excite, fit and fly your vehicle with a learned model and an MPC",
                    "icon": "mdi-chart-bell-curve-cumulative",
                    "company": "pinc",
                    "version": env!("CARGO_PKG_VERSION"),
                    "webpage": env!("CARGO_PKG_REPOSITORY"),
                    "api": "",
                    "works_in_relative_paths": true,
                    "extras": {"cockpit": super::cockpit::EXTRAS_PATH},
                }),
            )),
            super::cockpit::EXTRAS_PATH => Ok(json_reply(200, &super::cockpit::extras(&self.token))),
            "/icon.svg" => Ok(Response::from_data(super::cockpit::ICON_SVG.as_bytes().to_vec())
                .with_header(header("Content-Type", "image/svg+xml"))),
            "/api/state" => {
                let since = arg("since").and_then(|s| s.parse().ok()).unwrap_or(0);
                let vehicle = self.watcher.view.lock().expect("view").to_json();
                let (used, free) = self.storage();
                let limits = self.limits();
                Ok(json_reply(
                    200,
                    &json!({
                        "vehicle": vehicle,
                        "job": self.jobs.to_json(since),
                        "server": {
                            "version": env!("CARGO_PKG_VERSION"),
                            "flight_connect": self.flight_connect,
                            "vehicle_file": self.vehicle_file().ok().map(|p| p.display().to_string()),
                            "limits": {"max_depth": limits.max_depth, "max_duration": limits.max_duration,
                                       "max_distance": limits.max_distance,
                                       "max_data_mb": limits.max_data_bytes / 1e6,
                                       "defaults": orders::DIVE_LIMITS,
                                       "owners": self.data.limits().ok().flatten().is_some()},
                            "data_mb": used as f64 / 1e6,
                            "disk_free_mb": free.map(|b| b as f64 / 1e6),
                            "trainer": cfg!(feature = "train"),
                        },
                    }),
                ))
            }
            "/api/files" => Ok(json_reply(200, &self.data.list())),
            "/api/download" => {
                let (kind, name) = (arg("kind").unwrap_or(""), arg("name").unwrap_or(""));
                let path = self.data.existing(kind, name, arg("file")).map_err(|e| Refused(404, e.to_string()))?;
                if path.is_dir() {
                    return Err(Refused(400, format!("{kind}/{name} is a folder: ask for one of its files")));
                }
                let bytes = std::fs::read(&path).map_err(|e| Refused(500, format!("{}: {e}", path.display())))?;
                let file = path.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default();
                let kind = match path.extension().and_then(|e| e.to_str()) {
                    Some("png") => "image/png",
                    Some("json") => "application/json",
                    Some("md" | "csv" | "toml") => "text/plain; charset=utf-8",
                    _ => "application/octet-stream",
                };
                let mut response = Response::from_data(bytes).with_header(header("Content-Type", kind));
                if arg("attachment").is_some() {
                    response = response
                        .with_header(header("Content-Disposition", &format!("attachment; filename=\"{file}\"")));
                }
                Ok(response)
            }
            _ => Err(Refused(404, format!("nothing at {path}"))),
        }
    }

    fn post(&self, path: &str, request: &mut Request) -> Reply {
        let token =
            request.headers().iter().find(|h| h.field.equiv("X-Pinc-Token")).map(|h| h.value.as_str().to_string());
        if token.as_deref() != Some(self.token.as_str()) {
            return Err(Refused(
                403,
                "missing or wrong token: commands come only from pinc's own page (reload it)".into(),
            ));
        }
        let mut body = String::new();
        request
            .as_reader()
            .take(MAX_BODY + 1)
            .read_to_string(&mut body)
            .map_err(|e| Refused(400, format!("cannot read the request: {e}")))?;
        if body.len() as u64 > MAX_BODY {
            return Err(Refused(413, format!("the request is over {MAX_BODY} bytes")));
        }
        match path {
            "/api/stop" => {
                self.watcher.stop();
                let job = self.jobs.stop();
                eprintln!("serve: STOP (neutral and disarm sent{})", if job { ", the job told to stop" } else { "" });
                Ok(json_reply(200, &json!({"stopped": true, "job": job})))
            }
            "/api/excite" => self.excite(parse(&body)?),
            "/api/fit" => self.fit(parse(&body)?),
            "/api/fly" => self.fly(parse(&body)?),
            // Cockpit's "hold here" (and the page's hold): the newest fitted model holds the
            // depth, heading and position the vehicle has at the press, until STOP or resume.
            "/api/hold" => self.hold(),
            // Cockpit's "resume" (and the page's): the hold or pilot assist running ends by
            // handing the vehicle back as the pilot had it (its mode, still armed, the ground
            // station's place returned).
            "/api/resume" => self.resume(),
            "/api/limits" => {
                let limits: DiveLimits = parse(&body)?;
                limits.check().map_err(|e| Refused(400, e))?;
                if self.jobs.running() {
                    return Err(Refused(409, "refused: the limits change between runs (STOP or wait first)".into()));
                }
                self.data.save_limits(&limits).map_err(|e| Refused(500, e.to_string()))?;
                let mut kept = self.limits.lock().expect("limits");
                *kept = limits.with_data_bytes(kept.max_data_bytes);
                eprintln!("serve: the owner's limits set: {limits:?}");
                Ok(json_reply(200, &json!({"limits": limits})))
            }
            "/api/sticks" => {
                // Checked here too: a refusal reaches the page at once, and nothing bad reaches
                // the flight (which checks again and holds).
                crate::pilot::Sticks::from_json(&body).map_err(|e| Refused(400, format!("{e}: refused, holding")))?;
                self.jobs.send_sticks(body.trim()).map_err(|e| Refused(409, e))?;
                Ok(json_reply(200, &json!({"taken": true})))
            }
            "/api/delete" => {
                let order: DeleteOrder = parse(&body)?;
                if self.jobs.running() {
                    return Err(Refused(409, "refused: nothing is deleted while a job runs".into()));
                }
                self.data.delete(&order.kind, &order.name).map_err(|e| Refused(400, e.to_string()))?;
                eprintln!("serve: deleted {}/{}", order.kind, order.name);
                Ok(json_reply(200, &json!({"deleted": format!("{}/{}", order.kind, order.name)})))
            }
            _ => Err(Refused(404, format!("nothing at {path}"))),
        }
    }

    /// The limits in force.
    fn limits(&self) -> Limits {
        *self.limits.lock().expect("limits")
    }

    /// "Hold here": refused before anything is sent where the vehicle is past a limit, or where
    /// there is no model or no depth to hold.
    fn hold(&self) -> Reply {
        let model = self
            .data
            .newest("models", "model.pinc")
            .ok_or_else(|| Refused(409, "no fitted model to hold with: excite and fit first".to_string()))?;
        let limits = self.limits();
        let view = self.watcher.view.lock().expect("view").to_json();
        let depth = view["depth_m"].as_f64();
        match depth {
            None => {
                return Err(Refused(
                    409,
                    "refused: the vehicle's depth is not known (no link to the autopilot, or no depth reading in 2 s): \
                     nothing sent"
                        .into(),
                ));
            }
            Some(d) if d > limits.max_depth => {
                return Err(Refused(
                    409,
                    format!(
                        "refused: the vehicle is at {d:.2} m, deeper than the depth limit {} m: nothing sent (the \
                         limits are on the page)",
                        limits.max_depth
                    ),
                ));
            }
            Some(_) => {}
        }
        // Held where it was pressed: the depth (its readings' mean over the last second), heading
        // and position (where one is known) the server's own link saw at the press, not where the flight's control starts a second or
        // two later (the current carries the vehicle meanwhile).
        let mut at = vec![view["depth_mean_1s_m"].as_f64(), view["heading_deg"].as_f64()];
        if let Some(p) = view["position_ne_m"].as_array().filter(|_| view["position_source"] == true) {
            at.extend([p.first().and_then(Value::as_f64), p.get(1).and_then(Value::as_f64)]);
        }
        let hold_at = at
            .into_iter()
            .collect::<Option<Vec<f64>>>()
            .map(|v| format!("--hold-at={}", v.iter().map(f64::to_string).collect::<Vec<_>>().join(",")));
        self.fly_with(FlyOrder { model, references: References::Hold, duration: orders::UNTIL_STOP_S }, hold_at)
    }

    /// "Resume": the flight running until STOP hands the vehicle back and ends (waited for, 10 s
    /// at most); anything else running is left alone and said.
    fn resume(&self) -> Reply {
        let current = self.jobs.to_json(usize::MAX);
        let id = current["id"].as_u64();
        if !self.jobs.running() {
            return Err(Refused(409, "nothing to resume from: no hold or pilot flight is running".into()));
        }
        if id.is_none() || id != *self.until_stop.lock().expect("until stop") {
            return Err(Refused(
                409,
                format!(
                    "refused: {} is running; resume ends only a hold or a pilot flight (STOP ends any)",
                    current["what"]
                ),
            ));
        }
        self.jobs.hand_back();
        let until = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while self.jobs.running() && std::time::Instant::now() < until {
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        let view = self.watcher.view.lock().expect("view").to_json();
        eprintln!("serve: resume: the vehicle handed back (mode {}, armed {})", view["mode"], view["armed"]);
        Ok(json_reply(
            200,
            &json!({"handed_back": true, "ended": !self.jobs.running(), "mode": view["mode"], "armed": view["armed"]}),
        ))
    }

    /// The data folder's `vehicle.toml` (the owner's), else `--vehicle`.
    fn vehicle_file(&self) -> Result<PathBuf, Refused> {
        let own = self.data.root().join("vehicle.toml");
        own.is_file().then_some(own).or_else(|| self.vehicle.clone()).ok_or_else(|| {
            Refused(
                400,
                "no vehicle file: start pinc serve with --vehicle V.toml or put vehicle.toml in the data folder".into(),
            )
        })
    }

    fn started(
        &self,
        kind: Kind,
        what: String,
        work: impl FnOnce(&Handle) -> Result<Value, String> + Send + 'static,
    ) -> Reply {
        let id = self.jobs.start(kind, what.clone(), work).map_err(|e| Refused(409, e))?;
        eprintln!("serve: job {id}: {} {what}", kind.name());
        Ok(json_reply(200, &json!({"job": id, "what": what})))
    }

    /// What the data folder holds and its disk's free space, read again when 2 s old.
    fn storage(&self) -> (u64, Option<u64>) {
        let mut cached = self.storage.lock().expect("storage");
        match *cached {
            Some((at, used, free)) if at.elapsed() < std::time::Duration::from_secs(2) => (used, free),
            _ => {
                let (used, free) = (self.data.size(), self.data.free());
                *cached = Some((std::time::Instant::now(), used, free));
                (used, free)
            }
        }
    }

    /// Refuses a run of `duration` s that the data folder has no room for (its limit, its
    /// disk), before anything is sent.
    fn room_for(&self, duration: f64) -> Result<(), Refused> {
        orders::room_for(duration, self.data.size(), self.data.free(), &self.limits()).map_err(|e| Refused(507, e))
    }

    fn excite(&self, order: ExciteOrder) -> Reply {
        let limits = self.limits();
        order.check(&limits).map_err(|e| Refused(400, e))?;
        self.room_for(order.duration)?;
        let vehicle = self.vehicle_file()?;
        let name = self.data.new_name("recordings", "excite", ".mcap").map_err(|e| Refused(500, e.to_string()))?;
        let base = name.trim_end_matches(".mcap").to_string();
        let inputs =
            self.data.path("excitations", &format!("{base}.csv"), None).map_err(|e| Refused(500, e.to_string()))?;
        let out = self.data.path("recordings", &name, None).map_err(|e| Refused(500, e.to_string()))?;
        let [top, bottom] = order.depth_band;
        let design = Step {
            program: self.pinc.clone(),
            args: os_args([
                "excitation".into(),
                "--vehicle".into(),
                path(&vehicle),
                "--out".into(),
                path(&inputs),
                "--duration".into(),
                order.duration.to_string(),
                "--seed".into(),
                order.seed.to_string(),
                "--axes".into(),
                order.axes.join(","),
            ]),
            sticks: false,
        };
        let mut args = vec![
            "vehicle".to_string(),
            "excite".into(),
            "--connect".into(),
            self.flight_connect.clone(),
            "--vehicle".into(),
            path(&vehicle),
            "--inputs".into(),
            path(&inputs),
            "--arm".into(),
            format!("--depth-band={top},{bottom}"),
            "--max-depth".into(),
            limits.max_depth.to_string(),
            "--out".into(),
            path(&out),
        ];
        if order.keep_going {
            args.push("--keep-going".into());
        }
        args.extend(self.run_args.iter().cloned());
        let excite = Step { program: self.pinc.clone(), args: os_args(args), sticks: false };
        let data = self.data.clone();
        self.started(Kind::Excite, format!("{name} ({} s at most, {top}-{bottom} m)", order.duration), move |h| {
            let designed = h.run(&design)?;
            if designed.code != Some(0) {
                return Err(format!("the excitation could not be designed ({})", exit_text(designed.code)));
            }
            let ran = h.run(&excite)?;
            // A killed or failed run leaves its recording as .partial, which the fit reads.
            let kept = [name.clone(), format!("{name}.partial")]
                .into_iter()
                .find(|n| data.existing("recordings", n, None).is_ok());
            match (ran.code, kept) {
                (Some(0), Some(kept)) => Ok(json!({"recording": kept})),
                (code, kept) => Err(format!(
                    "the excitation ended with {}; kept: {}",
                    exit_text(code),
                    kept.as_deref().unwrap_or("nothing")
                )),
            }
        })
    }

    fn fit(&self, order: FitOrder) -> Reply {
        order.check().map_err(|e| Refused(400, e))?;
        let recording =
            self.data.existing("recordings", &order.recording, None).map_err(|e| Refused(400, e.to_string()))?;
        let vehicle = self.vehicle_file()?;
        let name = self.data.new_name("models", "fit", "").map_err(|e| Refused(500, e.to_string()))?;
        let out = self.data.path("models", &name, None).map_err(|e| Refused(500, e.to_string()))?;
        let command = format!(
            "pinc fit --recording {} --vehicle {} --out {} --epochs {}",
            recording.display(),
            vehicle.display(),
            out.display(),
            order.epochs
        );
        if !cfg!(feature = "train") {
            return Err(Refused(
                501,
                format!(
                    "this build has no trainer (a Raspberry Pi's): download the recording and run on a laptop \
                     `pinc fit --recording {} --vehicle V.toml --out fitted`, then copy fitted/ into the data \
                     folder's models/",
                    order.recording
                ),
            ));
        }
        let epochs = order.epochs;
        self.started(Kind::Fit, format!("{name} from {}", order.recording), move |h| {
            fit_in_thread(h, recording, vehicle, out, epochs, &command).map(|mut v| {
                v["model"] = json!(name);
                v
            })
        })
    }

    fn fly(&self, order: FlyOrder) -> Reply {
        self.fly_with(order, None)
    }

    /// A flight, with one more argument for mpc_track (the hold's press).
    fn fly_with(&self, order: FlyOrder, extra: Option<String>) -> Reply {
        let limits = self.limits();
        order.check(&limits).map_err(|e| Refused(400, e))?;
        let until_stop = order.until_stop();
        let order = order.flown();
        // A flight until STOP needs room for what it writes at first: its figures keep their
        // last --history seconds, and its log grows with it (the page shows the folder).
        self.room_for(if until_stop { limits.max_duration.min(order.duration) } else { order.duration })?;
        let model =
            self.data.existing("models", &order.model, Some("model.pinc")).map_err(|e| Refused(400, e.to_string()))?;
        let name = self.data.new_name("flights", "fly", "").map_err(|e| Refused(500, e.to_string()))?;
        let dir = self.data.path("flights", &name, None).map_err(|e| Refused(500, e.to_string()))?;
        std::fs::create_dir_all(&dir).map_err(|e| Refused(500, format!("{}: {e}", dir.display())))?;
        let mut args = vec![
            "--connect".to_string(),
            self.flight_connect.clone(),
            "--model".into(),
            path(&model),
            "--arm".into(),
            "--max-depth".into(),
            limits.max_depth.to_string(),
            "--max-distance".into(),
            limits.max_distance.to_string(),
            "--stream-samples".into(),
            "--history".into(),
            self.history_s.to_string(),
            "--json".into(),
            "--out-dir".into(),
            path(&dir),
            "--duration".into(),
            order.duration.to_string(),
        ];
        match &order.references {
            References::Steps { .. } => {
                let file = dir.join("references.csv");
                let csv = order.reference_csv().expect("steps");
                std::fs::write(&file, csv).map_err(|e| Refused(500, format!("{}: {e}", file.display())))?;
                args.extend(["--reference".into(), path(&file)]);
            }
            References::Hold => {
                // One source on the thrusters: pinc takes the ground station's place (Cockpit's
                // joystick moves nothing meanwhile) and gives it back at the end.
                args.extend(["--scenario".into(), "hold".into()]);
                args.extend(["--take-ground-station".into(), self.ground_station.to_string()]);
                args.extend(["--gcs-sysid".into(), self.joystick_flight_sysid.to_string()]);
            }
            References::Survey { width, length, spacing, speed, depth } => {
                args.push(format!("--survey={width},{length},{spacing},{speed},{depth}"));
            }
            References::Pilot { speeds } | References::Joystick { speeds } => {
                if let References::Joystick { .. } = order.references {
                    // pinc takes Cockpit's place as the autopilot's ground station for the flight.
                    args.extend(["--pilot".into(), self.joystick.clone()]);
                    args.extend(["--gcs-sysid".into(), self.joystick_flight_sysid.to_string()]);
                } else {
                    args.extend(["--pilot".into(), "-".into()]);
                }
                if let Some([u, v, w, r]) = speeds {
                    args.push(format!("--pilot-speeds={u},{v},{w},{r}"));
                }
            }
        }
        args.extend(extra);
        args.extend(self.run_args.iter().cloned());
        let sticks = matches!(order.references, References::Pilot { .. });
        let step = Step { program: self.mpc_track.clone(), args: os_args(args), sticks };
        let what = match order.references {
            References::Hold => format!("{name}: hold here on {}", order.model),
            _ => format!("{name} on {}", order.model),
        };
        let reply = self.started(Kind::Fly, what, move |h| {
            let ran = h.run(&step)?;
            let summary: Option<Value> = serde_json::from_str(ran.stdout.trim()).ok();
            if let Some(s) = &summary {
                let _ = std::fs::write(dir.join("summary.json"), serde_json::to_string_pretty(s).unwrap_or_default());
            }
            match (ran.code, summary) {
                (Some(0), Some(s)) => Ok(json!({"flight": name, "summary": s})),
                (code, Some(s)) => Err(format!(
                    "the flight ended with {}: {}",
                    exit_text(code),
                    s["stopped"].as_str().unwrap_or("see the log")
                )),
                (code, None) => Err(format!("the flight ended with {} and no summary", exit_text(code))),
            }
        })?;
        *self.until_stop.lock().expect("until stop") =
            if until_stop { self.jobs.to_json(usize::MAX)["id"].as_u64() } else { None };
        Ok(reply)
    }
}

/// `POST api/delete`.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct DeleteOrder {
    kind: String,
    name: String,
}

/// A child's end in words.
fn exit_text(code: Option<i32>) -> String {
    code.map_or_else(|| "no exit code (killed by a signal)".to_string(), |c| format!("exit code {c}"))
}

fn parse<T: DeserializeOwned>(body: &str) -> Result<T, Refused> {
    serde_json::from_str(body).map_err(|e| Refused(400, format!("the request is not what this command takes: {e}")))
}

fn path(p: &std::path::Path) -> String {
    p.display().to_string()
}

fn os_args(args: impl IntoIterator<Item = String>) -> Vec<std::ffi::OsString> {
    args.into_iter().map(Into::into).collect()
}

/// The fit on this machine, its stages and epochs shown on the page; the report's figures.
#[cfg(feature = "train")]
fn fit_in_thread(
    h: &Handle,
    recording: PathBuf,
    vehicle: PathBuf,
    out: PathBuf,
    epochs: usize,
    command: &str,
) -> Result<Value, String> {
    use crate::fit::{FitSettings, fit, report};
    let mut settings = FitSettings::new(vec![recording], vehicle);
    settings.epochs = epochs;
    h.say(format!("$ {command}"));
    let on_stage = |stage| {
        let text = crate::fit::stage_text(&stage);
        h.say(text.clone());
        h.update(|j| j.stage = Some(text));
    };
    let on_epoch = |r: &crate::train::EpochRecord| h.update(|j| j.epochs = Some((r.epoch, epochs)));
    let result = fit(&settings, h.interrupt(), on_stage, on_epoch).map_err(|e| e.to_string())?;
    if h.interrupt().load(std::sync::atomic::Ordering::Relaxed) {
        return Err("stopped: nothing written".into());
    }
    let written = report::write(&result, &out, command).map_err(|e| e.to_string())?;
    let text = std::fs::read_to_string(&written.report_json).map_err(|e| e.to_string())?;
    let report: Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    Ok(json!({"passed": report["passed"], "warnings": report["warnings"], "report": report}))
}

#[cfg(not(feature = "train"))]
fn fit_in_thread(_: &Handle, _: PathBuf, _: PathBuf, _: PathBuf, _: usize, _: &str) -> Result<Value, String> {
    Err("this build has no trainer".into())
}

#[cfg(test)]
mod tests {
    use super::Own;

    #[test]
    fn the_own_origin_is_the_host_asked_for_and_behind_blueos_any_port_of_it() {
        let direct = Own { scheme: "http".into(), host: Some("192.168.2.2:8780".into()), proxied: false };
        assert!(direct.is("http://192.168.2.2:8780"));
        assert!(!direct.is("http://192.168.2.2"));
        assert!(!direct.is("http://evil.example:8780"));
        assert!(!direct.is("null"));
        let behind = Own { scheme: "http".into(), host: Some("192.168.2.2".into()), proxied: true };
        assert!(behind.is("http://192.168.2.2"));
        assert!(behind.is("http://192.168.2.2:8080"));
        assert!(!behind.is("http://192.168.2.20"));
        assert!(!behind.is("https://192.168.2.2"));
        assert!(!Own { host: None, ..behind }.is("http://192.168.2.2"));
    }
}
