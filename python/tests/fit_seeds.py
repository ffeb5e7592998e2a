"""Fits on fresh excitation seeds, each flown beside the simulator's own file (docs/FIT.md, issue 59's
campaign): per seed, FIT.md's path on the firmware at full gain (excitation designed with --seed, `pinc vehicle excite` until its watch stops, `pinc fit`), then the fitted model and the
simulator's own file flown side by side on the default references. Four-axis seeds with the
simulator's GPS. One JSON line per seed. Needs $PINC_ARDUSUB_SITL, $PINC_BIN and $MPC_TRACK_BIN
(release builds with `train` and `vehicle`); every run is in its own network namespace.

Each flight's held heading is scored twice: as the flight's summary does (the estimate against
the reference) and on the simulator's truth (its median offset from the estimate, the magnetic
declination, removed). The heave drag is compared with the simulator's both in true metres
and in the depth pinc reads (1.0236 times longer: the simulator presses 1023.6 kg/m^3 water,
pinc converts with 1000 unless told).

usage: PINC_BIN=... MPC_TRACK_BIN=... fit_seeds.py OUT stock|gps SEED [SEED ...]
       (--reuse OLD_OUT: fit the recordings an earlier campaign made instead of exciting;
        --repeat N: then N more batches of three at once, the model beside the file twice, and the
        held heading's and depth's means over every flight in "repeated")
"""
import bisect, glob, json, math, os, subprocess, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parent))
from mcap.reader import make_reader
from test_ardusub_fit import fly_side_by_side, SIM_VEHICLE
from test_ardusub_live import STOCK, OWNER_VEHICLE
from test_ardusub_sitl import JS_GAIN, run_on_firmware
PINC = os.environ["PINC_BIN"]
args = sys.argv[1:]
reuse, repeat = None, 0
while args[0].startswith("--"):
    if args[0] == "--reuse":
        reuse, args = Path(args[1]), args[2:]
    elif args[0] == "--repeat":
        repeat, args = int(args[1]), args[2:]
    else:
        sys.exit(f"unknown option {args[0]}")
root = Path(args[0]); kind = args[1]; seeds = args[2:]
DEPTH_SCALE = 1.0236  # pinc's depth per true metre on this simulator


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def held_heading_truth(path, settle=8.0, lead=2.0):
    """Mean |heading - reference| (deg) over the held stretches (the summary's 8 s after a step,
    2 s before the next) of the simulator's truth, on the estimate's clock."""
    ref, tru, est = [], [], []
    for _, c, m in make_reader(open(path, "rb")).iter_messages(topics=["/truth", "/mpc/reference", "/estimate"]):
        d = json.loads(m.data)
        if c.topic == "/mpc/reference":
            ref.append((m.log_time, d["heading_rad"]))
        elif c.topic == "/truth":
            tru.append((m.log_time, d["psi"]))
        else:
            est.append((m.log_time, d["estimate"][3]))
    rt, tt = [r[0] for r in ref], [t[0] for t in tru]
    rows = []
    for t, e in est:
        i, j = bisect.bisect_right(rt, t) - 1, bisect.bisect_right(tt, t) - 1
        if i >= 0 and j >= 0:
            rows.append((t * 1e-9, e, tru[j][1], ref[i][1]))
    off = sorted(wrap(e - tr) for _, e, tr, _ in rows)[len(rows) // 2]
    stretches = []
    for t, _, _, v in rows:
        if stretches and stretches[-1][2] == v:
            stretches[-1][1] = t
        else:
            stretches.append([t, t, v])
    errs = [abs(wrap(tr + off - v)) for t, _, tr, v in rows if any(a + settle <= t < b - lead for a, b, _ in stretches)]
    return math.degrees(sum(errs) / len(errs))


GPS = [JS_GAIN]
for seed in seeds:
    out = root / f"{kind}_{seed}"; out.mkdir(parents=True, exist_ok=True)
    parms = STOCK if kind == "stock" else GPS
    axes = [] if kind == "stock" else ["--axes", "surge,sway,heave,yaw"]
    wait = [] if kind == "stock" else ["--wait-position", "60"]
    t0 = time.time()
    if reuse is None:
        subprocess.run([PINC, "excitation", "--vehicle", OWNER_VEHICLE, "--seed", seed, *axes, "--out", out / "exc.csv"], check=True, capture_output=True)
        r = run_on_firmware(out, parms, [PINC, "vehicle", "excite", "--connect", "tcp:127.0.0.1:5760", "--vehicle", OWNER_VEHICLE,
                                         "--inputs", out / "exc.csv", "--arm", "--depth-band", "0.5,2.5", "--max-depth", "3", *wait,
                                         "--out", out / "rec.mcap"], timeout=900)
        (out / "excite.log").write_text(r.stdout + "\n" + r.stderr)
    else:
        (out / "rec.mcap").write_bytes((reuse / f"{kind}_{seed}" / "rec.mcap").read_bytes())
    r = subprocess.run([PINC, "fit", "--recording", out / "rec.mcap", "--vehicle", OWNER_VEHICLE, "--reference", SIM_VEHICLE,
                        "--out", out / "fitted", "--json"], capture_output=True, text=True)
    (out / "fit.json").write_text(r.stdout); (out / "fit.err").write_text(r.stderr)
    row = {"kind": kind, "seed": seed, "excite_and_fit_s": round(time.time() - t0)}
    try:
        rep = json.loads(r.stdout)
    except json.JSONDecodeError:
        row["error"] = r.stderr[-500:]; print(json.dumps(row), flush=True); continue
    c = {x["name"]: x["fitted"] for x in rep["coefficients"]}
    row.update({"passed": rep["passed"], "warnings": rep["warnings"], "recorded_s": round(rep["recordings"][0]["estimated_s"], 1),
                "coef": {k: round(c[k], 3) for k in ("volume", "z_wd", "z_w", "z_ww", "n_rd", "n_rr", "n_r", "x_uu", "y_vv")},
                "depth_std": round(rep["sensors"]["depth_std_m"], 3), "open_loop_depth": rep.get("open_loop_depth"),
                "model_is_physics": any("the model is its physics" in n for n in rep["notes"])})
    # The effective yaw inertia (the simulator's 0.268 kg m^2, no added inertia).
    izz = next(float(l.split("=")[1]) for l in (out / "fitted" / "vehicle.toml").read_text().splitlines() if l.startswith("izz ="))
    row["yaw_inertia"] = round(izz - c["n_rd"], 4)
    runs = fly_side_by_side({
        "fitted": ((out / "fitted_flight", "--model", out / "fitted" / "model.pinc"), {"vehicle": None, "parms": parms}),
        "file": ((out / "file_flight", "--oracle"), {"vehicle": SIM_VEHICLE, "parms": parms})})
    for who, (run, s) in runs.items():
        f = glob.glob(str(out / f"{who}_flight" / "*.mcap"))[0]
        w = [abs(json.loads(m.data)["w"]) for _, _, m in make_reader(open(f, "rb")).iter_messages(topics=["/truth"])]
        w.sort()
        row[who] = {"depth_truth_rms": round(s["live"]["truth_rms"]["depth_m"], 4),
                    "held_mean": round(s["steady_heading_error_deg"], 3), "held_max": round(s["held_heading_error_max_deg"], 3),
                    "held_mean_truth": round(held_heading_truth(f), 3),
                    "rms_heading": round(s["rms_heading_deg"], 3), "stopped": s["stopped"],
                    "w_rms": round((sum(x * x for x in w) / len(w)) ** 0.5, 3), "w_p95": round(w[int(0.95 * len(w))], 3)}
    # Heave drag at the speeds flown (the fitted flight's true RMS and 95th-percentile |w|), against
    # the simulator's -69 w|w|: the fitted coefficients taken as in true metres, and as they are,
    # in pinc's depth (the same speed DEPTH_SCALE times larger there).
    for key in ("w_rms", "w_p95"):
        v = row["fitted"][key]
        for name, vp in (("", v), ("_depth_scale", DEPTH_SCALE * v)):
            fit_drag = c["z_w"] * vp + c["z_ww"] * vp * vp
            row[f"drag_ratio{name}_at_{key}"] = round(fit_drag / (-69.0 * v * v), 3) if v > 0 else None
    flights = {"fitted": [row["fitted"]], "file": [row["file"]]}
    for b in range(repeat):
        again = fly_side_by_side({
            "fitted": ((out / f"fitted_flight_{b}", "--model", out / "fitted" / "model.pinc"), {"vehicle": None, "parms": parms}),
            "file": ((out / f"file_flight_{b}", "--oracle"), {"vehicle": SIM_VEHICLE, "parms": parms}),
            "file_again": ((out / f"file_again_flight_{b}", "--oracle"), {"vehicle": SIM_VEHICLE, "parms": parms})})
        for who, (run, s) in again.items():
            f = glob.glob(str(out / f"{who}_flight_{b}" / "*.mcap"))[0]
            flights["fitted" if who == "fitted" else "file"].append(
                {"depth_truth_rms": s["live"]["truth_rms"]["depth_m"], "held_mean": s["steady_heading_error_deg"],
                 "held_mean_truth": held_heading_truth(f)})
    if repeat:
        mean = lambda who, key: sum(x[key] for x in flights[who]) / len(flights[who])
        row["repeated"] = {"flights": {w: len(v) for w, v in flights.items()},
                           **{f"ratio_{k}": round(mean("fitted", k) / mean("file", k), 3)
                              for k in ("depth_truth_rms", "held_mean", "held_mean_truth")},
                           "file_held_mean": [round(x["held_mean"], 3) for x in flights["file"]]}
    row["ratio_depth"] = round(row["fitted"]["depth_truth_rms"] / row["file"]["depth_truth_rms"], 3)
    row["ratio_held_mean"] = round(row["fitted"]["held_mean"] / row["file"]["held_mean"], 3)
    row["ratio_held_mean_truth"] = round(row["fitted"]["held_mean_truth"] / row["file"]["held_mean_truth"], 3)
    print(json.dumps(row), flush=True)
