"""The tar an owner uploads in BlueOS (Extensions, Installed, +, Install from file), checked as BlueOS
reads it: scripts/blueos_image.sh's dist/pinc-blueos-<platform>.tar.

BlueOS's extension service (kraken, core/services/kraken: POST /v2.0/extension/upload) wants a file
named .tar, `docker load`s it and takes the image's name and tag from what it loaded (RepoTags), then
reads the labels: version, type, readme and requirements as text; permissions, authors, company and
links as JSON (an unparsable one silently becomes empty or is passed on as text); with no `name`
label the dialog's name is the company's. It creates the container from the permissions, so the
image's own entry point and command are what runs. Checked here: docker-archive's manifest.json (one
image, its reference, the config and layers it names, their digests), the config (architecture, os,
variant, entry point, command, port, environment), every label as BlueOS and the store parse them,
and the `pinc` inside running `serve --help` from the image's own root file system: for amd64
through its own dynamic loader, for ARM under qemu-user-static with the root as its library prefix.

Which tars: linux-amd64 always, built from target/release (CI's `cargo test --release --workspace
--all-features` build) or dist/linux-amd64/; an ARM one where dist/ has it (scripts/cross_build.sh,
then scripts/blueos_image.sh), else built from dist/<platform>/ when the cross build is there, else
skipped, saying why. Building one needs root and Debian's archive (apt); the script installs umoci,
skopeo and mmdebstrap. About 10 s a platform.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DIST = Path(os.environ.get("PINC_DIST", ROOT / "dist"))
SCRIPT = ROOT / "scripts" / "blueos_image.sh"
sys.path.insert(0, str(ROOT / "blueos"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import image_config  # noqa: E402
from test_blueos_extension import EXTENSION_TYPES, store_version_problems  # noqa: E402

# platform -> architecture, variant, qemu, the dynamic loader inside the image, the library folder.
PLATFORMS = {
    "linux-amd64": ("amd64", None, None, "lib64/ld-linux-x86-64.so.2", "x86_64-linux-gnu"),
    "linux-arm64": ("arm64", "v8", "qemu-aarch64-static", "lib/ld-linux-aarch64.so.1", "aarch64-linux-gnu"),
    "linux-arm-v7": ("arm", "v7", "qemu-arm-static", "lib/ld-linux-armhf.so.3", "arm-linux-gnueabihf"),
}
CONFIG = image_config.load()


def _has_serve(pinc: Path) -> bool:
    try:
        return subprocess.run([pinc, "serve", "--help"], capture_output=True, timeout=30).returncode == 0
    except OSError:
        return False


def _build(platform: str, out: Path, binaries: Path | None) -> Path:
    command = ["bash", str(SCRIPT), "--platforms", platform, "--out", str(out)]
    if binaries is not None:
        command += ["--binaries", str(binaries)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{' '.join(command)} failed:\n{done.stderr[-4000:]}"
    return out / f"pinc-blueos-{platform}.tar"


@pytest.fixture(scope="module")
def tars(tmp_path_factory) -> dict[str, Path | str]:
    """platform -> the tar to check, or why there is none."""
    found: dict[str, Path | str] = {}
    root = os.geteuid() == 0
    out = tmp_path_factory.mktemp("blueos-tars")
    for platform in PLATFORMS:
        ready = DIST / f"pinc-blueos-{platform}.tar"
        if ready.exists():
            found[platform] = ready
            continue
        binaries = None
        if platform == "linux-amd64" and _has_serve(ROOT / "target" / "release" / "pinc"):
            binaries = ROOT / "target" / "release"
        elif not (DIST / platform / "pinc").exists():
            found[platform] = (f"no {ready.relative_to(ROOT)} and no cross build in {(DIST / platform).relative_to(ROOT)}/ "
                               f"(scripts/cross_build.sh --platforms {platform}, then scripts/blueos_image.sh)")
            if platform == "linux-amd64":
                found[platform] += " nor target/release/pinc with `serve` (feature vehicle)"
            continue
        if not root:
            found[platform] = "building the tar needs root (mmdebstrap, umoci)"
            continue
        found[platform] = _build(platform, out, binaries)
    return found


@pytest.fixture(params=list(PLATFORMS))
def image(request, tars, tmp_path) -> dict:
    """The tar unpacked: its manifest entry, config, the layers' paths, the folder."""
    tar = tars[request.param]
    if isinstance(tar, str):
        if request.param == "linux-amd64" and os.environ.get("CI") == "true":
            pytest.fail(f"CI builds the amd64 tar: {tar}")
        pytest.skip(f"{request.param}: {tar}")
    folder = tmp_path / "archive"
    folder.mkdir()
    subprocess.run(["tar", "-xf", str(tar), "-C", str(folder)], check=True)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert isinstance(manifest, list) and len(manifest) == 1, f"{tar}: manifest.json holds {len(manifest)} images"
    entry = manifest[0]
    config = json.loads((folder / entry["Config"]).read_text())
    return {"platform": request.param, "tar": tar, "entry": entry, "config": config, "folder": folder}


def test_the_archive_is_what_docker_load_takes(image):
    tar, entry, folder = image["tar"], image["entry"], image["folder"]
    # BlueOS's upload refuses any other file name.
    assert tar.name == f"pinc-blueos-{image['platform']}.tar"
    # One reference: BlueOS's Docker image and tag come from it (no reference: a bare image ID).
    (reference,) = entry["RepoTags"]
    name, tag = reference.rsplit(":", 1)
    assert tag == image["config"]["config"]["Labels"]["version"]
    # BlueOS's dialog checks the image name as distribution/reference does: lower-case path
    # components, the first one possibly a registry host.
    parts = name.split("/")
    component = re.compile(r"[a-z0-9]+(?:(?:\.|_|__|-+)[a-z0-9]+)*")
    assert all(component.fullmatch(p) for p in parts[1 if len(parts) > 1 else 0:]), name
    assert re.fullmatch(r"[A-Za-z0-9.-]+(?::\d+)?", parts[0]), name
    # image.json's image: under DOCKERHUB_ORG once that is set, under localhost/ until then.
    given = {"VERSION": tag} if parts[0] == "localhost" else {"VERSION": tag, "DOCKERHUB_ORG": parts[0]}
    assert reference == image_config.reference(CONFIG, given)
    assert re.fullmatch(r"[0-9a-f]{64}\.json", entry["Config"])
    assert hashlib.sha256((folder / entry["Config"]).read_bytes()).hexdigest() == entry["Config"][:-5]
    # Every layer there, an archive tar reads to its end, its digest the config's diff_id.
    diff_ids = image["config"]["rootfs"]["diff_ids"]
    assert len(entry["Layers"]) == len(diff_ids) == 2
    for layer, diff_id in zip(entry["Layers"], diff_ids):
        data = (folder / layer).read_bytes()
        assert "sha256:" + hashlib.sha256(data).hexdigest() == diff_id, layer
        with tarfile.open(folder / layer) as t:
            assert t.getmembers(), layer


def test_the_config_runs_pinc_serve_on_the_pi(image):
    arch, variant, *_ = PLATFORMS[image["platform"]]
    config = image["config"]
    assert config["os"] == "linux" and config["architecture"] == arch
    assert config.get("variant") == variant
    c = config["config"]
    assert c["Entrypoint"] == CONFIG["entrypoint"] == ["/opt/pinc/bin/pinc"]
    assert c["Cmd"] == CONFIG["cmd"] and c["Cmd"][0] == "serve"
    assert c["WorkingDir"] == CONFIG["workdir"]
    assert c["Env"] == [f"{k}={v}" for k, v in CONFIG["env"].items()]
    flags = dict(zip(c["Cmd"][1::2], c["Cmd"][2::2]))
    assert set(c["ExposedPorts"]) == {f"{flags['--port']}/tcp"}
    permissions = json.loads(c["Labels"]["permissions"])
    assert set(permissions["ExposedPorts"]) == set(c["ExposedPorts"])
    assert permissions["HostConfig"]["Binds"][0].endswith(":" + flags["--data"])


def test_every_label_as_blueos_and_the_store_read_it(image):
    labels = image["config"]["config"]["Labels"]
    assert set(labels) == set(CONFIG["labels"]), set(labels) ^ set(CONFIG["labels"])
    # kraken's _metadata_from_labels: these four as text...
    for key in ("version", "type", "readme", "requirements"):
        assert isinstance(labels[key], str) and labels[key], key
    assert labels["type"] in EXTENSION_TYPES
    # ... these as JSON of this kind (kraken would fall back to an empty one, or hand Docker the text).
    kinds = {"permissions": dict, "authors": list, "company": dict, "links": dict, "tags": list}
    parsed = {}
    for key, kind in kinds.items():
        try:
            parsed[key] = json.loads(labels[key])
        except json.JSONDecodeError as e:
            pytest.fail(f"label {key} is not JSON ({e}): {labels[key]}")
        assert isinstance(parsed[key], kind), (key, parsed[key])
    # Labels without build arguments are image.json's as they are.
    for key, value in CONFIG["labels"].items():
        if "${" not in json.dumps(value):
            assert parsed.get(key, labels[key]) == value, key
    # The dialog's name with no `name` label: the company's.
    assert parsed["company"]["name"]
    # The readme and the docs at one git ref, never a branch; a release's is its tag.
    version = labels["version"]
    readme_ref = re.fullmatch(r"https://raw\.githubusercontent\.com/[\w.-]+/[\w.-]+/([^/]+)/docs/BLUEOS\.md",
                              labels["readme"]).group(1)
    assert f"/blob/{readme_ref}/" in parsed["links"]["documentation"]
    # The store's rules, for the tag the workflow would push this image as.
    assert store_version_problems(labels, version) == []


def _inside(root: Path, path: str) -> Path:
    """`path` in the image, its symbolic links resolved within `root` (as the container sees them)."""
    current = root
    for part in Path(path.lstrip("/")).parts:
        current = current / part
        for _ in range(40):
            if not current.is_symlink():
                break
            target = os.readlink(current)
            current = (root / target.lstrip("/")) if target.startswith("/") else current.parent / target
    return current


def test_the_pinc_inside_runs_serve_help(image, tmp_path):
    platform = image["platform"]
    _, _, qemu, loader, triplet = PLATFORMS[platform]
    root = tmp_path / "root"
    root.mkdir()
    for layer in image["entry"]["Layers"]:
        subprocess.run(["tar", "-xf", str(image["folder"] / layer), "-C", str(root)], check=True)
    pinc = root / "opt/pinc/bin/pinc"
    assert os.access(pinc, os.X_OK) and os.access(root / "opt/pinc/bin/mpc_track", os.X_OK)
    cmd = image["config"]["config"]["Cmd"]
    flags = dict(zip(cmd[1::2], cmd[2::2]))
    # The files the command names, and the folders a container needs.
    assert _inside(root, flags["--vehicle"]).is_file()
    assert _inside(root, "/opt/pinc/models/mpc_pinc_thrust.pinc").is_file()
    assert (root / "data").is_dir() and (root / "tmp").stat().st_mode & 0o1777 == 0o1777
    assert not list((root / "dev").iterdir()), "device nodes in the image"
    assert not (root / "etc/resolv.conf").exists() and not (root / "etc/hostname").exists()
    # The image's own glibc, not this machine's.
    if qemu is None:
        ld = _inside(root, "/" + loader)
        assert ld.is_file() and root in ld.parents, ld
        libs = f"{root}/lib/{triplet}:{root}/usr/lib/{triplet}"
        run = [str(ld), "--library-path", libs]
    else:
        if shutil.which(qemu) is None:
            pytest.skip(f"{platform}: no {qemu} (Debian's qemu-user-static) to run it")
        assert _inside(root, "/" + loader).is_file(), loader
        run = [qemu, "-L", str(root)]
    for program in ("pinc", "mpc_track"):
        args = ["serve", "--help"] if program == "pinc" else ["--help"]
        done = subprocess.run(run + [str(root / "opt/pinc/bin" / program)] + args, capture_output=True, text=True,
                              timeout=120, env={"PATH": "/usr/bin:/bin", "LC_ALL": "C"})
        assert done.returncode == 0, f"{platform} {program} {' '.join(args)}: {done.stderr[-2000:]}"
        if program == "pinc":
            # Every flag the image's command gives, known to this pinc.
            missing = [f for f in flags if f not in done.stdout]
            assert not missing, f"pinc serve --help lacks {missing}"
