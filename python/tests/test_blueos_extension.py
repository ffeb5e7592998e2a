"""The BlueOS extension's packaging, read as BlueOS and buildx read it, without Docker or a network.

blueos/Dockerfile: the LABELs BlueOS's extension manager reads (JSON where it parses JSON, with the
keys it looks up), the container settings in `permissions` (host networking for the MAVLink router
on 127.0.0.1:5777, the data folder, a CPU limit), one stage per platform the workflow publishes, and
every file a COPY takes being one that scripts/cross_build.sh writes (`--list-outputs`).
"""

import json
import re
import shlex
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent.parent
DOCKERFILE = ROOT / "blueos" / "Dockerfile"
SCRIPT = ROOT / "scripts" / "cross_build.sh"
WORKFLOW = ROOT / ".github" / "workflows" / "blueos-extension.yml"

# Ports BlueOS's own services listen on in the host's network namespace (core/start-blueos-core,
# core/tools/nginx/nginx.conf: nginx, helper, the ArduPilot Manager on 8000, the MAVLink TCP server
# on 5777, mavlink2rest, zenoh, ...): an extension on host networking must stay off them.
BLUEOS_PORTS = {80, 81, 2748, 2770, 5201, 5777, 6020, 6030, 6040, 7447, 7777, 8000, 8081, 8088, 9000, 9090, 9100,
                9101, 9110, 9111, 9120, 9134, 14000, 14001, 14550, 14660, 27353}
# The extension types BlueOS's store knows.
EXTENSION_TYPES = {"device-integration", "example", "theme", "other", "tool"}
# buildx platform -> the stage name `platform-${TARGETARCH}${TARGETVARIANT}` (arm64's v8
# variant is normalised away by buildx).
STAGES = {"linux/amd64": "platform-amd64", "linux/arm64/v8": "platform-arm64", "linux/arm64": "platform-arm64",
          "linux/arm/v7": "platform-armv7"}


def instructions(path: Path) -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) per logical line: comments dropped, `\\` continuations joined."""
    out, pending = [], ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not pending and (not line or line.startswith("#")):
            continue
        if line.endswith("\\"):
            pending += line[:-1]
            continue
        line = pending + line
        pending = ""
        word, _, rest = line.partition(" ")
        out.append((word.upper(), rest.strip()))
    assert not pending, f"{path}: ends inside a continued line"
    return out


def labels() -> dict[str, str]:
    """The LABELs as an image built with the ARGs' defaults carries them."""
    found, args = {}, {}
    for word, rest in instructions(DOCKERFILE):
        if word == "ARG":
            key, _, value = shlex.split(rest)[0].partition("=")
            args[key] = value
        if word == "LABEL":
            for item in shlex.split(rest):
                key, sep, value = item.partition("=")
                assert sep, f"LABEL {item!r} is not key=value"
                assert key not in found, f"LABEL {key} given twice"
                found[key] = re.sub(r"\$\{(\w+)\}", lambda m: args[m.group(1)], value)
    return found


def json_label(name: str):
    value = labels().get(name)
    assert value is not None, f"blueos/Dockerfile has no LABEL {name}"
    try:
        return json.loads(value)
    except json.JSONDecodeError as e:
        pytest.fail(f"LABEL {name} is not JSON ({e}): {value}")


def test_plain_labels():
    found = labels()
    assert re.fullmatch(r"\d+\.\d+\.\d+", found.get("version", "")), found.get("version")
    assert found.get("type") in EXTENSION_TYPES
    assert re.fullmatch(r"core >= \d+\.\d+(\.\d+)?", found.get("requirements", "")), found.get("requirements")
    # BlueOS 1.4 is the first whose register_service carries extras (Cockpit's widget and actions).
    assert found["requirements"] == "core >= 1.4"
    # BlueOS fills in {tag} with the image tag it installs.
    assert re.fullmatch(r"https://\S+\.md", found.get("readme", "")), found.get("readme")


def test_permissions_are_a_container_create_body():
    p = json_label("permissions")
    assert set(p) <= {"ExposedPorts", "HostConfig", "Env", "Labels"}, set(p)
    (port,) = p["ExposedPorts"]
    assert re.fullmatch(r"\d+/tcp", port) and p["ExposedPorts"][port] == {}
    assert int(port.split("/")[0]) not in BLUEOS_PORTS, f"{port} is taken by BlueOS itself"
    host = p["HostConfig"]
    # Host networking: BlueOS's MAVLink router is reached on the host's 127.0.0.1:5777.
    assert host["NetworkMode"] == "host"
    assert "PortBindings" not in host, "host networking publishes no ports"
    assert host["Binds"] == ["/usr/blueos/extensions/pinc:/data"]
    quota, period = host["CpuQuota"], host["CpuPeriod"]
    assert isinstance(quota, int) and isinstance(period, int) and 1000 <= period <= 1_000_000
    # At most the Pi 4's four cores, at least one.
    assert period <= quota <= 4 * period


def test_people_links_and_tags():
    authors = json_label("authors")
    assert isinstance(authors, list) and authors
    for a in authors:
        assert set(a) == {"name", "email"} and all(isinstance(v, str) and v for v in a.values()), a
    company = json_label("company")
    assert set(company) == {"about", "name", "email"}, company
    links = json_label("links")
    assert isinstance(links, dict) and "source" in links
    for key, url in links.items():
        assert re.fullmatch(r"https://\S+", url), (key, url)
    tags = json_label("tags")
    assert isinstance(tags, list) and tags and all(isinstance(t, str) and t == t.lower() for t in tags)


def test_entry_point_serves_on_the_port_and_folder_it_is_given():
    ins = dict((w, r) for w, r in instructions(DOCKERFILE) if w in {"ENTRYPOINT", "CMD"})
    command = json.loads(ins["ENTRYPOINT"]) + json.loads(ins["CMD"])
    assert command[0].endswith("/pinc") and command[1] == "serve"
    flags = dict(zip(command[2::2], command[3::2]))
    assert set(flags) == {"--data", "--port", "--bind", "--connect", "--vehicle"}
    assert flags["--data"] == "/data" and flags["--connect"] == "tcp:127.0.0.1:5777"
    # Reachable from the topside's browser (host networking: the vehicle's own address).
    assert flags["--bind"] == "0.0.0.0"
    copied = [r.split()[-1] for w, r in instructions(DOCKERFILE) if w == "COPY"]
    assert flags["--vehicle"] in copied
    host = json_label("permissions")["HostConfig"]
    assert host["Binds"][0].split(":")[1] == flags["--data"]
    assert f"{flags['--port']}/tcp" in json_label("permissions")["ExposedPorts"]
    assert [r for w, r in instructions(DOCKERFILE) if w == "EXPOSE"] == [f"{flags['--port']}/tcp"]


def test_every_copied_file_is_one_the_cross_build_writes():
    listed = subprocess.run(["bash", str(SCRIPT), "--list-outputs"], capture_output=True, text=True, check=True)
    written = set(listed.stdout.split())
    assert written, "cross_build.sh --list-outputs printed nothing"
    copied = []
    for word, rest in instructions(DOCKERFILE):
        if word == "ADD":
            pytest.fail("blueos/Dockerfile uses ADD: COPY only, from dist/")
        if word == "COPY":
            args = shlex.split(rest)
            assert not any(a.startswith("--from") for a in args), f"COPY from another stage: {rest}"
            copied += [a for a in args if not a.startswith("--")][:-1]
    assert copied
    missing = [c for c in copied if c not in written]
    assert not missing, f"COPY takes files cross_build.sh does not write: {missing}"
    # The context the Dockerfile is built with keeps dist/.
    ignore = [line.strip() for line in (DOCKERFILE.parent / "Dockerfile.dockerignore").read_text().splitlines()
              if line.strip() and not line.startswith("#")]
    assert ignore[0] == "*" and "!dist" in ignore


def test_one_stage_per_published_platform_and_no_run():
    ins = instructions(DOCKERFILE)
    assert not [r for w, r in ins if w == "RUN"], "a RUN would execute under emulation on the ARM platforms"
    stages = {}
    for word, rest in ins:
        if word == "FROM":
            parts = rest.split()
            if len(parts) == 3 and parts[1].upper() == "AS":
                stages[parts[2]] = parts[0]
    last = [r for w, r in ins if w == "FROM"][-1]
    assert last == "platform-${TARGETARCH}${TARGETVARIANT}"
    global_args = []
    for word, rest in ins:
        if word == "FROM":
            break
        if word == "ARG":
            global_args.append(rest)
    assert {"TARGETARCH", "TARGETVARIANT"} <= set(global_args)
    platforms = re.search(r"platforms:\s*(\S+)", WORKFLOW.read_text()).group(1).split(",")
    assert set(platforms) == {"linux/arm/v7", "linux/arm64/v8", "linux/amd64"}
    for platform in platforms:
        assert STAGES[platform] in stages, f"no stage for {platform}"
    # Each platform stage copies its own platform's binaries.
    current = None
    for word, rest in ins:
        if word == "FROM":
            current = rest.split()[-1]
        elif word == "COPY" and current in STAGES.values():
            arch = current.removeprefix("platform-")
            want = {"amd64": "dist/linux-amd64/", "arm64": "dist/linux-arm64/", "armv7": "dist/linux-arm-v7/"}[arch]
            assert all(a.startswith(want) for a in shlex.split(rest)[:-1]), (current, rest)


ENTRY = ROOT / "blueos" / "extensions_repository" / "pinc"


def test_the_extension_store_entry_is_complete():
    # bluerobotics/BlueOS-Extensions-Repository reads repos/<company>/<extension>/metadata.json
    # (name, website, docker, description: a missing one skips the entry), the extension's logo
    # beside it and the company's logo one folder up; the rest comes from the image's labels.
    meta = json.loads((ENTRY / "pinc" / "metadata.json").read_text())
    assert set(meta) == {"name", "website", "docker", "description"}, meta
    assert all(isinstance(v, str) and v for v in meta.values()), meta
    assert re.fullmatch(r"[\w.-]+/[\w.-]+", meta["docker"]), meta["docker"]
    for logo in (ENTRY / "pinc" / "extension_logo.png", ENTRY / "company_logo.png"):
        head = logo.read_bytes()[:24]
        assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR", logo
        width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        assert width == height >= 64, (logo, width, height)
    # The store keeps at most 10 tags of lower-case letters, digits and dashes.
    tags = json_label("tags")
    assert len(tags) <= 10 and all(re.fullmatch(r"[a-z0-9-]+", t) for t in tags), tags
