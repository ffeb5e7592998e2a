"""Fits on fresh excitation seeds, each flown beside the simulator's own file (docs/FIT.md, issue 59's
campaign): per seed, FIT.md's path on the firmware at full gain (excitation designed with --seed, `pinc vehicle excite` until its watch stops, `pinc fit`), then the fitted model and the
simulator's own file flown side by side on the default references. Four-axis seeds with the
simulator's GPS. One JSON line per seed. Needs $PINC_ARDUSUB_SITL, $PINC_BIN and $MPC_TRACK_BIN
(release builds with `train` and `vehicle`); every run is in its own network namespace.

usage: PINC_BIN=... MPC_TRACK_BIN=... fit_seeds.py OUT stock|gps SEED [SEED ...]
"""
import glob, json, os, subprocess, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parent))
from mcap.reader import make_reader
from test_ardusub_fit import fly_side_by_side, SIM_VEHICLE
from test_ardusub_live import STOCK, OWNER_VEHICLE
from test_ardusub_sitl import JS_GAIN, run_on_firmware
PINC = os.environ["PINC_BIN"]
root = Path(sys.argv[1]); kind = sys.argv[2]; seeds = sys.argv[3:]
GPS = [JS_GAIN]
for seed in seeds:
    out = root / f"{kind}_{seed}"; out.mkdir(parents=True, exist_ok=True)
    parms = STOCK if kind == "stock" else GPS
    axes = [] if kind == "stock" else ["--axes", "surge,sway,heave,yaw"]
    wait = [] if kind == "stock" else ["--wait-position", "60"]
    t0 = time.time()
    subprocess.run([PINC, "excitation", "--vehicle", OWNER_VEHICLE, "--seed", seed, *axes, "--out", out / "exc.csv"], check=True, capture_output=True)
    r = run_on_firmware(out, parms, [PINC, "vehicle", "excite", "--connect", "tcp:127.0.0.1:5760", "--vehicle", OWNER_VEHICLE,
                                     "--inputs", out / "exc.csv", "--arm", "--depth-band", "0.5,2.5", "--max-depth", "3", *wait,
                                     "--out", out / "rec.mcap"], timeout=900)
    (out / "excite.log").write_text(r.stdout + "\n" + r.stderr)
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
                "coef": {k: round(c[k], 3) for k in ("volume", "z_wd", "z_w", "z_ww", "n_rr", "n_r", "x_uu", "y_vv")},
                "depth_std": round(rep["sensors"]["depth_std_m"], 3), "open_loop_depth": rep.get("open_loop_depth"),
                "model_is_physics": any("the model is its physics" in n for n in rep["notes"])})
    runs = fly_side_by_side({
        "fitted": ((out / "fitted_flight", "--model", out / "fitted" / "model.pinc"), {"vehicle": None, "parms": parms}),
        "file": ((out / "file_flight", "--oracle"), {"vehicle": SIM_VEHICLE, "parms": parms})})
    for who, (run, s) in runs.items():
        f = glob.glob(str(out / f"{who}_flight" / "*.mcap"))[0]
        w = [abs(json.loads(m.data)["sim"]["w"]) for _, _, m in make_reader(open(f, "rb")).iter_messages(topics=["/vehicle/state"])]
        w.sort()
        row[who] = {"depth_truth_rms": round(s["live"]["truth_rms"]["depth_m"], 4),
                    "held_mean": round(s["steady_heading_error_deg"], 3), "held_max": round(s["held_heading_error_max_deg"], 3),
                    "rms_heading": round(s["rms_heading_deg"], 3), "stopped": s["stopped"],
                    "w_rms": round((sum(x * x for x in w) / len(w)) ** 0.5, 3), "w_p95": round(w[int(0.95 * len(w))], 3)}
    # Heave drag at the speeds flown (the fitted flight's RMS and 95th-percentile |w|), against the simulator's -69 w|w|.
    for key in ("w_rms", "w_p95"):
        v = row["fitted"][key]
        fit_drag = c["z_w"] * v + c["z_ww"] * v * v
        row[f"drag_ratio_at_{key}"] = round(fit_drag / (-69.0 * v * v), 3) if v > 0 else None
    row["ratio_depth"] = round(row["fitted"]["depth_truth_rms"] / row["file"]["depth_truth_rms"], 3)
    row["ratio_held_mean"] = round(row["fitted"]["held_mean"] / row["file"]["held_mean"], 3)
    print(json.dumps(row), flush=True)
