"""Monte-Carlo campaigns and training sweeps as Ray tasks (`pip install "./python[ray]"`).

    from pinc import closed_loop, distributed
    s = closed_loop.settings(model="models/mpc_pinc_thrust.pinc", scenario="disturbed")
    distributed.monte_carlo(s, runs=1000, address="10.0.0.5:6379", out_dir="out")
    distributed.train_sweep({"seed": [0, 1, 2], "lr": [4e-3, 8e-3]}, out_dir="sweep")

Every run is deterministic per seed, so a task that Ray retries (its worker died) gives the
same result, and a campaign killed half way resumes from its results file, redoing no
finished seed. Ray schedules; pinc builds no scheduler of its own.
"""

import itertools
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time

from . import closed_loop


class DistributedError(RuntimeError):
    """A campaign or sweep that cannot go on: the message names the cluster, run or
    configuration at fault."""


# ---------------------------------------------------------------------------- the cluster


def _ray():
    try:
        import ray
    except ImportError as e:
        raise DistributedError('pinc.distributed needs Ray: pip install "./python[ray]"') from e
    return ray


def connect(address=None):
    """Joins the Ray cluster at `address` ("host:port" of its head; "auto": the one this
    machine belongs to), or starts a local one when `address` is None. An address nothing
    answers at is an error at once, not a long wait."""
    ray = _ray()
    if address not in (None, "auto"):
        host, _, port = address.rpartition(":")
        host = host.removeprefix("ray://") or "127.0.0.1"
        try:
            with socket.create_connection((host, int(port)), timeout=5):
                pass
        except (OSError, ValueError) as e:
            raise DistributedError(f"Ray cluster at {address!r} is unreachable: {e}") from e
    if ray.is_initialized():
        return ray
    try:
        ray.init(address=address, log_to_driver=False, logging_level="ERROR")
    except Exception as e:  # ray raises ConnectionError, RuntimeError, ... by version
        raise DistributedError(f"Ray cluster at {address!r}: {e}") from e
    return ray


class _Progress:
    """tqdm when it is installed, else a line on stderr every few seconds."""

    def __init__(self, total, done, what, show):
        self.bar, self.n, self.total, self.what, self.show, self.last = None, done, total, what, show, 0.0
        if show:
            try:
                from tqdm import tqdm

                self.bar = tqdm(total=total, initial=done, desc=what, unit="run")
            except ImportError:
                pass

    def update(self):
        self.n += 1
        if self.bar is not None:
            self.bar.update(1)
        elif self.show and (time.monotonic() - self.last > 2 or self.n == self.total):
            self.last = time.monotonic()
            print(f"{self.what}: {self.n}/{self.total}", file=sys.stderr)

    def close(self):
        if self.bar is not None:
            self.bar.close()


# ------------------------------------------------------------------------- results files


class _Results:
    """A JSON-lines results file: a header line naming the job, then one line per finished
    item, flushed as it lands; a torn last line (a killed writer) is dropped on reading."""

    def __init__(self, path, header, key):
        self.path, self.key, self.done = path, key, {}
        if os.path.exists(path):
            with open(path) as f:
                lines = f.read().split("\n")
            complete = []
            for i, line in enumerate(lines):
                if not line.strip():
                    continue
                try:
                    complete.append(json.loads(line))
                except json.JSONDecodeError:
                    if i < len(lines) - 1 and any(x.strip() for x in lines[i + 1 :]):
                        raise DistributedError(f"{path}: line {i + 1} is not JSON") from None
            if complete:
                if complete[0] != {"header": header}:
                    raise DistributedError(
                        f"{path}: holds another job ({complete[0]}); remove it or pick another results file"
                    )
                for item in complete[1:]:
                    self.done[item[key]] = item
            # Rewrite without a torn tail, so appends start on a fresh line.
            with open(path, "w") as f:
                for item in complete or [{"header": header}]:
                    f.write(json.dumps(item) + "\n")
        else:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            with open(path, "w") as f:
                f.write(json.dumps({"header": header}) + "\n")
        self.f = open(path, "a")

    def add(self, item):
        self.f.write(json.dumps(item) + "\n")
        self.f.flush()
        os.fsync(self.f.fileno())
        self.done[item[self.key]] = item

    def close(self):
        self.f.close()


def _stream(ray, refs, on_done, bar):
    """Calls `on_done(tag, value)` as each task finishes and advances `bar` (closed at the
    end, also on an error); a task's error is raised with its tag (the run or configuration it
    belongs to)."""
    try:
        _stream_until_done(ray, refs, on_done, bar)
    finally:
        bar.close()


def _stream_until_done(ray, refs, on_done, bar):
    pending = dict(refs)
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for r in ready:
            tag = pending.pop(r)
            try:
                value = ray.get(r)
            except Exception as e:
                for p in pending:
                    ray.cancel(p, force=True)
                cause = getattr(e, "cause", None) or e
                if isinstance(cause, DistributedError):  # raised in the task, naming the run
                    raise DistributedError(str(cause)) from e
                raise DistributedError(f"{tag}: {cause}") from e
            on_done(tag, value)
            bar.update()


# ------------------------------------------------------------------------------ campaigns


def _run_pair(settings_json, seed):
    """One Monte-Carlo run of both controllers (a Ray task's body)."""
    s = json.loads(settings_json)
    t0 = time.perf_counter()
    marker = os.environ.get("PINC_TASK_PID_DIR")
    if marker:  # the tests find a worker running a task, and count each seed's runs, here
        open(os.path.join(marker, f"{os.getpid()}.running"), "w").close()
        open(os.path.join(marker, f"seed{seed}.{os.getpid()}.{time.time_ns()}"), "w").close()
    try:
        out = {
            "seed": seed,
            "pinc": closed_loop.run(s, seed, "pinc"),
            "oracle": closed_loop.run(s, seed, "oracle"),
        }
    except Exception as e:
        raise DistributedError(f"run seed {seed} on {socket.gethostname()} (pid {os.getpid()}): {e}") from None
    out["run_s"] = time.perf_counter() - t0
    if marker:
        os.remove(os.path.join(marker, f"{os.getpid()}.running"))
    return out


def monte_carlo(
    settings,
    runs,
    seed=0,
    out_dir="out",
    address=None,
    results=None,
    progress=True,
    max_retries=3,
    quiet=False,
):
    """Runs both controllers on the `runs` perturbed plants of seeds seed .. seed+runs-1,
    one Ray task per seed, on the cluster at `address` (None: a local one).

    Each run lands in `results` (JSON lines, default out_dir/mpc_<scenario>_monte_carlo.jsonl)
    as it finishes; calling again with the same arguments resumes, running only the seeds
    not there. Writes `mpc_track --monte-carlo`'s figures file (.json) and histogram (.png)
    to `out_dir`, prints its table (unless `quiet`) and returns the figures as a dict
    (runs, seed, scenario, pinc, oracle, plot, per_run, table)."""
    if int(runs) < 1:
        raise DistributedError("monte_carlo: at least one run")
    s = closed_loop.settings(**settings)
    text = closed_loop.settings_json(s)
    # Checked here first, so a bad setting is one clear error before any task starts.
    scenario = closed_loop.campaign(s).scenario_name()
    seeds = list(range(int(seed), int(seed) + int(runs)))
    os.makedirs(out_dir, exist_ok=True)
    results = results or os.path.join(out_dir, f"mpc_{scenario}_monte_carlo.jsonl")
    store = _Results(results, {"settings": s, "kind": "monte_carlo"}, "seed")
    todo = [k for k in seeds if k not in store.done]
    try:
        if todo:
            ray = connect(address)
            task = ray.remote(max_retries=max_retries, num_cpus=1)(_run_pair)
            bar = _Progress(len(seeds), len(seeds) - len(todo), "Monte Carlo", progress)
            text_ref = ray.put(text)
            refs = {task.remote(text_ref, k): f"run seed {k}" for k in todo}

            _stream(ray, refs, lambda _tag, item: store.add(item), bar)
    finally:
        store.close()
    return _report(s, text, [store.done[k] for k in seeds], int(seed), out_dir, scenario, quiet)


def _finite(x):
    """`x` with every infinite float as None (JSON has no infinity; mpc_track writes null)."""
    if isinstance(x, float) and math.isinf(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x


def _report(s, text, items, first_seed, out_dir, scenario, quiet):
    from ._pinc import monte_carlo_report

    png = os.path.join(out_dir, f"mpc_{scenario}_monte_carlo.png")
    json_path = os.path.join(out_dir, f"mpc_{scenario}_monte_carlo.json")

    def outcomes(c):
        return json.dumps([_finite(i[c]) for i in items])

    rp, ro, table = monte_carlo_report(text, outcomes("pinc"), outcomes("oracle"), first_seed, png, json_path)
    figures = lambda o: {k: o[k] for k in ("success", "rms_depth_m", "rms_heading_deg")}  # noqa: E731
    report = {
        "runs": len(items),
        "seed": first_seed,
        "scenario": scenario,
        "pinc": json.loads(rp),
        "oracle": json.loads(ro),
        "plot": png,
        "per_run": [{"seed": i["seed"], "pinc": figures(i["pinc"]), "oracle": figures(i["oracle"])} for i in items],
    }
    with open(json_path, "w") as f:
        f.write(json.dumps(_finite(report), indent=2))
    if not quiet:
        print(table + f"histogram: {png}\nfigures:   {json_path}")
    report["table"] = table
    return report


# ------------------------------------------------------------------------ training sweeps


def pinc_binary(pinc_bin=None):
    """The `pinc` command: `pinc_bin`, else $PINC_BIN, else `pinc` on PATH."""
    b = pinc_bin or os.environ.get("PINC_BIN") or shutil.which("pinc")
    if not b:
        raise DistributedError("no pinc binary: pass pinc_bin=, set PINC_BIN, or put `pinc` on PATH")
    return os.fspath(b)


def configurations(grid_or_list):
    """A list of configurations as it is, or the product of a grid {flag: [values]}. Each
    configuration is {flag: value} of `pinc train` (True: a bare flag), its seed included
    (default 0), and an optional "name"."""
    if isinstance(grid_or_list, dict):
        keys = list(grid_or_list)
        values = [v if isinstance(v, (list, tuple)) else [v] for v in grid_or_list.values()]
        configs = [dict(zip(keys, combo)) for combo in itertools.product(*values)]
    else:
        configs = [dict(c) for c in grid_or_list]
    names = set()
    for i, c in enumerate(configs):
        c.setdefault("seed", 0)
        if "out" in c:
            raise DistributedError(f"configuration {i}: `out` is the sweep's to choose")
        c.setdefault("name", "_".join(f"{k}{v}" for k, v in c.items() if k != "name").replace("/", "-") or f"cfg{i}")
        if c["name"] in names:
            raise DistributedError(f"configuration {i}: name {c['name']!r} repeats")
        names.add(c["name"])
    return configs


def _train_args(config):
    args = []
    for k, v in config.items():
        if k == "name" or v is False or v is None:
            continue
        flag = "--" + k.replace("_", "-")
        if v is True:
            args.append(flag)
        elif isinstance(v, (list, tuple)):
            args += [flag, ",".join(str(x) for x in v)]
        else:
            args += [flag, str(v)]
    return args


def _dev_vpt(csv_text, best_epoch):
    """The dev VPT of the kept epoch from the per-epoch CSV `pinc train` writes."""
    rows = [r.split(",") for r in csv_text.strip().split("\n")]
    head = rows[0]
    e, v = head.index("epoch"), head.index("dev_vpt_s")
    for r in rows[1:]:
        if int(r[e]) == best_epoch:
            return float(r[v])
    return None


def _train_one(pinc_bin, config):
    """`pinc train` of one configuration in a scratch folder (a Ray task's body): returns
    the model and CSV bytes and the metrics, since the driver may be on another machine."""
    name = config["name"]
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "model.pinc")
        cmd = [pinc_bin, "train", *_train_args(config), "--out", out, "--json"]
        try:
            p = subprocess.run(cmd, capture_output=True, text=True)
        except OSError as e:
            raise DistributedError(f"configuration {name!r} on {socket.gethostname()}: cannot run {pinc_bin}: {e}") from None
        if p.returncode != 0:
            why = [x.strip() for x in (p.stderr.strip() or p.stdout.strip()).splitlines() if x.strip()]
            raise DistributedError(f"configuration {name!r}: pinc train refused it: {' | '.join(why)[:600]}")
        summary = json.loads(p.stdout)
        with open(out, "rb") as f:
            model = f.read()
        with open(os.path.join(d, "model.csv")) as f:
            csv_text = f.read()
    return {
        "name": name,
        "config": config,
        "dev_vpt_s": _dev_vpt(csv_text, summary["best_epoch"]),
        "train": {k: summary[k] for k in ("best_epoch", "epochs_run", "train_seconds", "stop") if k in summary},
        "metrics": summary.get("metrics") or summary.get("test"),
        "model_bytes": model.hex(),
        "csv": csv_text,
    }


def _check_members_fit(ray, configs):
    """A configuration with `members` trains one thread per member on one node: refuse one
    that no node of the cluster has the CPUs for, which Ray would otherwise wait on forever."""
    most = max((n["Resources"].get("CPU", 0) for n in ray.nodes() if n.get("Alive")), default=0)
    for c in configs:
        m = int(c.get("members", 1))
        if m > most:  # zero or negative: `pinc train` refuses it with its own message
            raise DistributedError(
                f"configuration {c['name']!r}: members {m} needs {m} CPUs on one node; the largest node has {most:g}"
            )


def train_sweep(grid_or_list, out_dir="sweep", address=None, pinc_bin=None, results=None, progress=True, max_retries=1):
    """Trains every configuration (see `configurations`) as a Ray task running `pinc train`
    on the worker, collects each model as out_dir/<name>.pinc (and .csv), and returns the
    configurations ranked by dev VPT of the kept epoch (best first; dev only, never test).
    Results land in `results` (JSON lines, default out_dir/sweep.jsonl) as they finish; a
    second call resumes, training only the configurations not there."""
    configs = configurations(grid_or_list)
    pinc_bin = pinc_binary(pinc_bin)
    os.makedirs(out_dir, exist_ok=True)
    results = results or os.path.join(out_dir, "sweep.jsonl")
    store = _Results(results, {"kind": "train_sweep"}, "name")
    todo = [c for c in configs if c["name"] not in store.done]
    try:
        if todo:
            ray = connect(address)
            _check_members_fit(ray, todo)
            task = ray.remote(max_retries=max_retries, num_cpus=1)(_train_one)
            bar = _Progress(len(configs), len(configs) - len(todo), "training sweep", progress)
            # A configuration with members trains one thread per member: reserve that many CPUs.
            refs = {
                task.options(num_cpus=int(c.get("members", 1))).remote(pinc_bin, c): f"configuration {c['name']!r}"
                for c in todo
            }

            def done(_tag, item):
                with open(os.path.join(out_dir, item["name"] + ".pinc"), "wb") as f:
                    f.write(bytes.fromhex(item.pop("model_bytes")))
                with open(os.path.join(out_dir, item["name"] + ".csv"), "w") as f:
                    f.write(item.pop("csv"))
                item["model"] = os.path.join(out_dir, item["name"] + ".pinc")
                store.add(item)

            _stream(ray, refs, done, bar)
    finally:
        store.close()
    ranked = [store.done[c["name"]] for c in configs]
    ranked.sort(key=lambda r: -(r["dev_vpt_s"] if r["dev_vpt_s"] is not None else float("-inf")))
    return ranked
