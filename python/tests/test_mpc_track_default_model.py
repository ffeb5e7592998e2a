"""An installed mpc_track flies its built-in default model wherever it runs.

`mpc_track` without `--model` flies models/mpc_pinc_thrust.pinc, whose bytes are built into the
binary: run from a folder with no `models/` in it, it must fly exactly as it does given that
file, and say that the model is the built-in one (on stderr, in the summary, in its log).
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "models" / "mpc_pinc_thrust.pinc"


def mpc_track() -> Path:
    given = os.environ.get("MPC_TRACK_BIN")
    path = Path(given) if given else ROOT / "target" / "release" / "mpc_track"
    if not path.is_file():
        pytest.skip(f"{path} is not built: run `cargo build --release` first (CI builds it before pytest)")
    return path


def fly(cwd: Path, *args: str) -> tuple[dict, str]:
    r = subprocess.run([str(mpc_track()), "--duration", "12", "--json", "--out-dir", "out", *args], cwd=cwd,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout), r.stderr


# The tracking figures a run's summary gives (its timings differ from run to run; these do not).
FIGURES = ["samples", "rms_depth_m", "rms_heading_deg", "max_overshoot_depth_m", "max_overshoot_heading_deg",
           "settling_depth_s", "settling_heading_s", "steady_depth_error_m", "steady_heading_error_deg",
           "held_heading_error_max_deg", "input_total_variation", "fallbacks", "bound_violations",
           "saturated_samples", "envelope_exits", "heading_off_circle"]


def test_without_model_it_flies_the_built_in_model_outside_a_checkout(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    built_in, _ = fly(elsewhere)
    given, _ = fly(tmp_path, "--model", str(MODEL))
    for key in FIGURES:
        assert built_in[key] == given[key], key
    assert built_in["samples"] == 150 and built_in["fallbacks"] == 0
    assert built_in["model_built_in"] is True and given["model_built_in"] is False
    written = Path(built_in["controller_model"])
    written = written if written.is_absolute() else elsewhere / written
    assert written == elsewhere / "out" / "built_in_mpc_pinc_thrust.pinc"
    assert hashlib.sha256(written.read_bytes()).digest() == hashlib.sha256(MODEL.read_bytes()).digest()
    assert not (elsewhere / "models").exists()


def test_the_built_in_model_is_said_in_help_and_in_the_summary(tmp_path):
    r = subprocess.run([str(mpc_track()), "--help"], capture_output=True, text=True, timeout=60)
    assert "built-in models/mpc_pinc_thrust.pinc" in " ".join(r.stdout.split())
    r = subprocess.run([str(mpc_track()), "--duration", "2", "--out-dir", "out"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "model: the built-in models/mpc_pinc_thrust.pinc (no --model given)" in r.stderr
    assert "model: built in (models/mpc_pinc_thrust.pinc), as out/built_in_mpc_pinc_thrust.pinc" in r.stdout
    # A second run finds the same bytes there and leaves the file as it is.
    first = (tmp_path / "out" / "built_in_mpc_pinc_thrust.pinc").stat().st_mtime_ns
    r = subprocess.run([str(mpc_track()), "--duration", "2", "--out-dir", "out"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "out" / "built_in_mpc_pinc_thrust.pinc").stat().st_mtime_ns == first


def test_an_out_dir_it_cannot_write_is_one_clear_line(tmp_path):
    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder")
    r = subprocess.run([str(mpc_track()), "--duration", "2", "--out-dir", str(blocked / "out")], cwd=tmp_path,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "cannot create the output folder" in lines[0], lines
