"""The runtime built for a Raspberry Pi computes what it computes on x86.

scripts/cross_build.sh builds `runtime_json` (examples/runtime_json.rs) and `mpc_track` for
linux-arm-v7, linux-arm64 and linux-amd64 into dist/. The ARM builds run here under qemu's user
emulation, the amd64 build natively, and their numbers are compared:

- a step, a 50-step rollout and the 50-step horizon linearisation (trajectory, every A_k and B_k)
  of models/mpc_pinc_thrust.pinc, by the f32 predictor on the portable kernels and by the f64
  reference: within 1e-9 of x86's (IEEE arithmetic without fused operations and no libm in the
  network: the same operations in the same order);
- the f32 predictor as each CPU dispatches it: on ARM the portable kernels; on an x86 with AVX2 +
  FMA the fused ones, whose roundings differ (within 1e-4 of the value's scale, as between two x86
  machines with and without AVX2);
- the 60 s simulated closed loop of `mpc_track` (the README's figures): RMS depth and heading
  errors equal to 1e-9 relative to x86's.

Skips, saying why, where dist/ has no cross builds (CI's pytest run does not make them) or qemu
is not installed (apt install qemu-user-static).
"""

import json
import os
import platform
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent.parent
DIST = Path(os.environ.get("PINC_DIST", ROOT / "dist"))
MODEL = ROOT / "models" / "mpc_pinc_thrust.pinc"
# platform -> (qemu user emulators, the cross C library's root for -L)
ARM = {
    "linux-arm-v7": (("qemu-arm-static", "qemu-arm"), Path("/usr/arm-linux-gnueabihf")),
    "linux-arm64": (("qemu-aarch64-static", "qemu-aarch64"), Path("/usr/aarch64-linux-gnu")),
}
SAME_KERNELS = ("f32_portable", "f64_reference")
QUANTITIES = ("step", "rollout", "trajectory", "a", "b")


def built(platform_name: str, binary: str) -> Path:
    path = DIST / platform_name / binary
    if not path.is_file():
        pytest.skip(f"{path} is not built: run scripts/cross_build.sh (it needs Debian 12; CI's pytest run skips this)")
    return path


def native(binary: str) -> list[str]:
    if platform.machine() != "x86_64":
        pytest.skip(f"the reference is the x86-64 build; this machine is {platform.machine()}")
    return [str(built("linux-amd64", binary))]


def emulated(platform_name: str, binary: str) -> list[str]:
    exe = built(platform_name, binary)
    names, sysroot = ARM[platform_name]
    qemu = next((q for q in map(shutil.which, names) if q), None)
    if qemu is None:
        pytest.skip(f"no {' or '.join(names)} on the PATH: apt install qemu-user-static")
    if not sysroot.is_dir():
        pytest.skip(f"{sysroot} is missing: apt install {'libc6-dev-armhf-cross' if 'v7' in platform_name else 'libc6-dev-arm64-cross'}")
    return [qemu, "-L", str(sysroot), str(exe)]


def run_json(command: list[str], *args: str) -> dict:
    r = subprocess.run(command + list(args), capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert r.returncode == 0, f"{' '.join(command + list(args))} exited {r.returncode}:\n{r.stderr[-3000:]}"
    return json.loads(r.stdout)


def flat(value) -> list[float]:
    if isinstance(value, list):
        return [v for item in value for v in flat(item)]
    return [float(value)]


def max_difference(a, b) -> tuple[float, float]:
    """(largest absolute difference, largest absolute value) over two equally shaped nests."""
    fa, fb = flat(a), flat(b)
    assert len(fa) == len(fb), (len(fa), len(fb))
    return max(abs(x - y) for x, y in zip(fa, fb)), max(abs(x) for x in fa)


@pytest.fixture(scope="module")
def x86_runtime() -> dict:
    return run_json(native("runtime_json"), str(MODEL))


@pytest.mark.parametrize("platform_name", sorted(ARM))
def test_step_rollout_and_jacobians_equal_x86(platform_name, x86_runtime):
    arm = run_json(emulated(platform_name, "runtime_json"), str(MODEL))
    assert arm["arch"] == {"linux-arm-v7": "arm", "linux-arm64": "aarch64"}[platform_name]
    assert arm["steps"] == x86_runtime["steps"] == 50
    assert not arm["avx2_fma"]
    report = []
    for run in SAME_KERNELS:
        for q in QUANTITIES:
            diff, scale = max_difference(x86_runtime["runs"][run][q], arm["runs"][run][q])
            report.append(f"{run}.{q}: {diff:.3g} (largest value {scale:.3g})")
            assert diff <= 1e-9, f"{platform_name} {run} {q} differs from x86 by {diff}"
    # ARM dispatches the portable kernels: the same numbers, bit for bit.
    assert arm["runs"]["f32_dispatched"] == arm["runs"]["f32_portable"]
    for q in QUANTITIES:
        diff, scale = max_difference(x86_runtime["runs"]["f32_dispatched"][q], arm["runs"]["f32_dispatched"][q])
        report.append(f"f32_dispatched.{q}: {diff:.3g}")
        if x86_runtime["avx2_fma"]:
            assert diff <= 1e-4 * max(scale, 1.0), f"{platform_name} f32 {q} differs from x86's AVX2 path by {diff}"
        else:
            assert diff <= 1e-9
    print(f"\n{platform_name} against x86 (max abs difference):\n  " + "\n  ".join(report))


def closed_loop(command: list[str], out_dir: Path) -> dict:
    # The solve's wall-clock limit raised: under emulation a solve is 10-50x slower, and one cut at
    # the limit would fall back and change the run.
    return run_json(command, "--json", "--out-dir", str(out_dir), "--solver-time-limit", "10")


@pytest.mark.parametrize("platform_name", sorted(ARM))
def test_closed_loop_figures_equal_x86(platform_name, tmp_path):
    arm_command = emulated(platform_name, "mpc_track")
    x86 = closed_loop(native("mpc_track"), tmp_path / "x86")
    arm = closed_loop(arm_command, tmp_path / "arm")
    keys = [k for k in x86 if k.startswith("rms_")]
    assert keys, f"no rms_* figures in mpc_track's JSON: {sorted(x86)}"
    for k in keys:
        assert arm[k] == pytest.approx(x86[k], rel=1e-9, abs=1e-12), k
    for k in ("fallbacks", "samples"):
        if k in x86:
            assert arm[k] == x86[k], k
