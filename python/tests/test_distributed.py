"""Campaigns and sweeps on a real two-node Ray cluster on loopback (a head and a worker
started by `ray start`, one CPU each), against `mpc_track --monte-carlo` run for run."""

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

import pinc
from pinc import closed_loop

ray = pytest.importorskip("ray", reason='Ray is the optional extra: pip install "./python[ray]"')
from pinc import distributed  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "models" / "mpc_pinc.pinc"
RELEASE = ROOT / "target" / "release"
MPC_TRACK = Path(os.environ.get("PINC_MPC_TRACK", RELEASE / "mpc_track"))
PINC_BIN = Path(os.environ.get("PINC_BIN", RELEASE / "pinc"))
# A short run keeps the 40-run campaign to seconds per run pair on this machine. A solve
# that hits the wall-clock limit falls back, which a loaded machine makes happen at random:
# a generous limit keeps every run a function of its seed alone, on both sides.
SETTINGS = closed_loop.settings(model=str(MODEL), scenario="disturbed", duration=16.0, solver_time_limit=5.0)
RUNS = 40


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ray_cmd(*args, env=None):
    exe = Path(sys.executable).with_name("ray")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=120, env=env)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A head and one worker node on 127.0.0.1, one CPU each; its address."""
    marks = tmp_path_factory.mktemp("marks")
    env = {**os.environ, "PINC_TASK_PID_DIR": str(marks), "RAY_USAGE_STATS_ENABLED": "0"}
    port = free_port()
    address = f"127.0.0.1:{port}"
    common = ["--num-cpus=1", "--node-ip-address=127.0.0.1", "--disable-usage-stats"]
    head = ray_cmd("start", "--head", f"--port={port}", "--include-dashboard=false", *common, env=env)
    assert head.returncode == 0, head.stderr
    try:
        worker = ray_cmd("start", f"--address={address}", *common, env=env)
        assert worker.returncode == 0, worker.stderr
        ray.init(address=address, log_to_driver=False, logging_level="ERROR")
        deadline = time.monotonic() + 60
        while sum(n["Alive"] for n in ray.nodes()) < 2:
            assert time.monotonic() < deadline, f"two nodes never joined: {ray.nodes()}"
            time.sleep(0.5)
        yield address, marks
    finally:
        ray.shutdown()
        ray_cmd("stop", "--force")


def seeds_run(marks):
    """How many times each seed's task started."""
    counts = {}
    for f in marks.iterdir():
        if f.name.startswith("seed"):
            k = int(f.name.split(".")[0][4:])
            counts[k] = counts.get(k, 0) + 1
    return counts


def mpc_track_monte_carlo(tmp_path, runs, seed=0):
    if not MPC_TRACK.exists():
        pytest.skip(f"{MPC_TRACK} is built by `cargo test --release` (CI runs it before pytest)")
    out = tmp_path / "mpc_track"
    args = ["--model", MODEL, "--scenario", "disturbed", "--duration", "16", "--solver-time-limit", "5", "--monte-carlo", runs, "--seed", seed]
    p = subprocess.run([str(MPC_TRACK), *map(str, args), "--json", "--out-dir", str(out)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    return json.loads((out / "mpc_disturbed_monte_carlo.json").read_text())


def test_one_run_is_mpc_tracks_and_draws_repeat():
    a, b = closed_loop.run(SETTINGS, seed=3), closed_loop.run(SETTINGS, seed=3)
    assert {k: v for k, v in a.items() if k != "solve_ms"} == {k: v for k, v in b.items() if k != "solve_ms"}
    assert closed_loop.draw(SETTINGS, 3) == closed_loop.draw(SETTINGS, 3) != closed_loop.draw(SETTINGS, 4)
    nominal = closed_loop.run(SETTINGS)
    assert nominal["samples"] == 200 and nominal["rms_depth_m"] < 1.0


def test_the_riccati_solver_runs_the_same_closed_loop(tmp_path):
    """`qp="riccati"` (the default) reaches the controller: the same run as Clarabel's to the
    solvers' real-time tolerances, on a perturbed plant too; an unknown solver is refused by name."""
    riccati, clarabel = {**SETTINGS, "qp": "riccati"}, {**SETTINGS, "qp": "clarabel"}
    untimed = lambda r: {k: v for k, v in r.items() if "_ms_" not in k}  # noqa: E731
    assert untimed(closed_loop.run(SETTINGS)) == untimed(closed_loop.run(riccati)), "riccati is the default"
    for seed in (None, 3):
        a, b = closed_loop.run(clarabel, seed=seed), closed_loop.run(riccati, seed=seed)
        assert b.get("fallbacks", 0) == 0 and b.get("success", True), b
        for k in ("rms_depth_m", "rms_heading_deg"):
            assert b[k] == pytest.approx(a[k], rel=0.01), (k, a[k], b[k])
    nominal = closed_loop.run(riccati)
    assert nominal["samples"] == 200
    if MPC_TRACK.exists():
        out = tmp_path / "riccati"
        args = ["--model", MODEL, "--scenario", "disturbed", "--duration", "16", "--qp", "riccati", "--json", "--out-dir", out]
        p = subprocess.run([str(MPC_TRACK), *map(str, args)], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        assert json.loads(p.stdout)["rms_depth_m"] == pytest.approx(nominal["rms_depth_m"], rel=1e-3)
    with pytest.raises(Exception, match="riccatti"):
        closed_loop.run({**SETTINGS, "qp": "riccatti"})


def test_four_axis_runs_from_python_equal_mpc_tracks_and_bad_paths_are_refused(tmp_path):
    """A station, a survey and a path file through the same Rust path as `mpc_track`: the
    horizontal figure in the summary (and in a perturbed run's outcome), the same number as
    `mpc_track --json`, and a path past `max_distance` refused naming its line."""
    thrust = ROOT / "models" / "mpc_pinc_thrust.pinc"  # the whole thrust range: a current to fight
    station = closed_loop.settings(model=thrust, scenario="station", duration=20, qp="riccati")
    s = closed_loop.run(station)
    assert s["horizontal"]["judged"] == "station" and s["horizontal"]["rms_m"] < 0.02, s["horizontal"]
    assert s["fallbacks"] == 0
    o = closed_loop.run(station, seed=2, controller="oracle")
    assert o["success"] and o["rms_horizontal_m"] < 0.05, o
    path = tmp_path / "path.csv"
    path.write_text("north_m,east_m,depth_m,speed_m_s\n0,0,1,0.3\n3,0,1,0.3\n3,3,1,0.3\n")
    p = closed_loop.run(closed_loop.settings(model=thrust, path=path, current=[0.1, -0.2], qp="riccati"))
    assert p["horizontal"]["judged"] == "cross-track" and p["horizontal"]["finished_s"] is not None, p["horizontal"]
    if MPC_TRACK.exists():
        args = ["--model", thrust, "--path", path, "--current=0.1,-0.2", "--qp", "riccati", "--json", "--out-dir", tmp_path]
        r = subprocess.run([str(MPC_TRACK), *map(str, args)], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["horizontal"]["rms_m"] == pytest.approx(p["horizontal"]["rms_m"], rel=1e-9)
    with pytest.raises(Exception, match="line 4.*past --max-distance 4"):
        closed_loop.run(closed_loop.settings(model=thrust, path=path, max_distance=4))


def test_campaign_on_two_nodes_equals_mpc_track_despite_a_killed_worker(cluster, tmp_path):
    address, marks = cluster
    expected = mpc_track_monte_carlo(tmp_path, RUNS)
    killed = []

    def kill_one_running_worker():
        # Once a few runs are in, kill a worker process in the middle of a task.
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not killed:
            running = [f for f in marks.iterdir() if f.name.endswith(".running")]
            if len(seeds_run(marks)) >= 6 and running:
                pid = int(running[0].name.split(".")[0])
                try:
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                except ProcessLookupError:
                    pass
            time.sleep(0.05)

    killer = threading.Thread(target=kill_one_running_worker)
    killer.start()
    report = distributed.monte_carlo(SETTINGS, RUNS, address=address, out_dir=tmp_path / "ray", progress=False, quiet=True)
    killer.join()
    assert killed, "no worker was killed during the campaign"
    assert report["per_run"] == expected["per_run"]
    assert report["pinc"]["success_rate"] == expected["pinc"]["success_rate"]
    assert report["pinc"]["rms_depth_m"] == expected["pinc"]["rms_depth_m"]
    assert report["oracle"]["failures"] == expected["oracle"]["failures"]
    assert (tmp_path / "ray" / "mpc_disturbed_monte_carlo.png").stat().st_size > 0
    # The killed task ran again (on some node) and its result is the same as everyone's.
    assert max(seeds_run(marks).values()) >= 2


def test_stopped_campaign_resumes_without_redoing_finished_seeds(cluster, tmp_path):
    address, marks = cluster
    for f in marks.iterdir():
        f.unlink()
    out = tmp_path / "resume"
    results = out / "runs.jsonl"
    script = (
        "import sys; from pinc import closed_loop, distributed; "
        f"distributed.monte_carlo({SETTINGS!r}, 24, seed=100, address={address!r}, out_dir={str(out)!r}, "
        f"results={str(results)!r}, progress=False, quiet=True)"
    )
    driver = subprocess.Popen([sys.executable, "-c", script])
    deadline = time.monotonic() + 300
    while not (results.exists() and len(results.read_text().splitlines()) >= 1 + 6):
        assert driver.poll() is None, "the campaign ended before it could be stopped"
        assert time.monotonic() < deadline
        time.sleep(0.1)
    driver.send_signal(signal.SIGKILL)
    driver.wait(timeout=60)
    finished = {json.loads(line)["seed"] for line in results.read_text().splitlines()[1:] if line.endswith("}")}
    assert 6 <= len(finished) < 24
    time.sleep(2)  # Ray ends the dead driver's job and its tasks
    before = seeds_run(marks)
    report = distributed.monte_carlo(
        SETTINGS, 24, seed=100, address=address, out_dir=out, results=results, progress=False, quiet=True
    )
    after = seeds_run(marks)
    rerun = {k for k in finished if after.get(k, 0) > before.get(k, 0)}
    assert not rerun, f"finished seeds run again: {sorted(rerun)}"
    assert [r["seed"] for r in report["per_run"]] == list(range(100, 124))
    # The resumed campaign's figures are those of one uninterrupted run of each seed.
    for r in report["per_run"][:3]:
        one = closed_loop.run(SETTINGS, seed=r["seed"])
        assert r["pinc"] == {k: one[k] for k in ("success", "rms_depth_m", "rms_heading_deg")}


def test_training_sweep_gives_two_models_ranked_by_dev_vpt(cluster, tmp_path):
    if not PINC_BIN.exists():
        pytest.skip(f"{PINC_BIN} (with the train feature) is built by `cargo test --release --all-features`")
    address, _ = cluster
    tiny = {"epochs": 2, "layers": 1, "width": 8, "train_count": 20, "dev_count": 10, "eval_count": 10}
    configs = [{**tiny, "seed": 1, "name": "a"}, {**tiny, "seed": 2, "lr": 2e-3, "name": "b"}]
    ranked = distributed.train_sweep(configs, out_dir=tmp_path, address=address, pinc_bin=PINC_BIN, progress=False)
    assert sorted(r["name"] for r in ranked) == ["a", "b"]
    assert ranked[0]["dev_vpt_s"] >= ranked[1]["dev_vpt_s"]
    for r in ranked:
        p = pinc.Predictor(str(tmp_path / f"{r['name']}.pinc"))
        assert p.dt > 0
        # The ranking's figure is the dev VPT the model file recorded for its kept epoch.
        rows = (tmp_path / f"{r['name']}.csv").read_text().splitlines()
        head = rows[0].split(",")
        kept = [x.split(",") for x in rows[1:] if int(x.split(",")[head.index("epoch")]) == r["train"]["best_epoch"]]
        assert kept and float(kept[0][head.index("dev_vpt_s")]) == r["dev_vpt_s"]


def test_configuration_with_more_members_than_a_node_has_cpus_is_refused(cluster, tmp_path):
    address, _ = cluster  # two nodes of one CPU each
    bad = [{"epochs": 1, "members": 2, "name": "wide"}]
    with pytest.raises(distributed.DistributedError, match=r"configuration 'wide': members 2 needs 2 CPUs on one node; the largest node has 1"):
        distributed.train_sweep(bad, out_dir=tmp_path, address=address, pinc_bin=PINC_BIN, progress=False)


def test_unreachable_cluster_is_one_clear_error(tmp_path):
    port = free_port()  # nothing listens there
    with pytest.raises(distributed.DistributedError, match=f"127.0.0.1:{port}.*unreachable"):
        distributed.monte_carlo(SETTINGS, 2, address=f"127.0.0.1:{port}", out_dir=tmp_path, progress=False)


def test_model_missing_on_a_worker_names_the_run(cluster, tmp_path):
    address, _ = cluster
    model = tmp_path / "here_only.pinc"
    model.write_bytes(MODEL.read_bytes())
    s = closed_loop.settings(model=str(model), scenario="disturbed", duration=4.0)
    closed_loop.campaign(s)  # loaded here, in the driver, before the file goes
    model.unlink()
    with pytest.raises(distributed.DistributedError, match=r"run seed \d+.*here_only.pinc"):
        distributed.monte_carlo(s, 2, address=address, out_dir=tmp_path, progress=False, quiet=True)


def test_configuration_pinc_train_refuses_names_it(cluster, tmp_path):
    if not PINC_BIN.exists():
        pytest.skip(f"{PINC_BIN} is built by `cargo test --release --all-features`")
    address, _ = cluster
    bad = [{"epochs": 1, "grad": "no-such-scheme", "name": "broken"}]
    with pytest.raises(distributed.DistributedError, match=r"configuration 'broken': pinc train refused it.*no-such-scheme"):
        distributed.train_sweep(bad, out_dir=tmp_path, address=address, pinc_bin=PINC_BIN, progress=False)
