"""The BlueOS extension's packaging, read as BlueOS, its extension store and buildx read it, without
Docker or a network.

blueos/Dockerfile: the LABELs BlueOS's extension manager reads (JSON where it parses JSON, with the
keys it looks up), the container settings in `permissions` (host networking for the MAVLink router
on 127.0.0.1:5777, the data folder, a CPU limit), one stage per platform the workflow publishes, and
every file a COPY takes being one that scripts/cross_build.sh writes (`--list-outputs`).

The store (bluerobotics/BlueOS-Extensions-Repository, blueos_repository/consolidate.py and
extension/extension.py): the rules below are ours, written from what its consolidation does, and
`store_version_problems` / `store_entry_problems` are what test_blueos_image.py applies to the tars
too. blueos/image.json is the one source of the labels, the Dockerfile's block and metadata.json;
its DOCKERHUB_ORG the one placeholder left.
"""

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent.parent
DOCKERFILE = ROOT / "blueos" / "Dockerfile"
SCRIPT = ROOT / "scripts" / "cross_build.sh"
WORKFLOW = ROOT / ".github" / "workflows" / "blueos-extension.yml"
sys.path.insert(0, str(ROOT / "blueos"))
import image_config  # noqa: E402

# Ports BlueOS's own services listen on in the host's network namespace (core/start-blueos-core,
# core/tools/nginx/nginx.conf: nginx, helper, the ArduPilot Manager on 8000, the MAVLink TCP server
# on 5777, mavlink2rest, zenoh, ...): an extension on host networking must stay off them.
BLUEOS_PORTS = {80, 81, 2748, 2770, 5201, 5777, 6020, 6030, 6040, 7447, 7777, 8000, 8081, 8088, 9000, 9090, 9100,
                9101, 9110, 9111, 9120, 9134, 14000, 14001, 14550, 14660, 27353}
# The extension types BlueOS's store knows.
EXTENSION_TYPES = {"device-integration", "example", "theme", "other", "tool", "education"}
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
            # A default may name an earlier ARG, as Docker expands it.
            args[key] = re.sub(r"\$\{(\w+)\}", lambda m: args[m.group(1)], value)
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


# ---------------------------------------------------------------------------------------------------
# The store's rules. Its consolidation reads repos/<company>/<extension>/metadata.json (JSON5; `name`,
# `docker`, `description`, `website` or the entry is skipped), asks Docker Hub (nowhere else) for the
# image's 25 most recently updated tags, keeps those that parse as semantic versions (a leading `v`
# allowed), reads each one's labels from the manifest list's linux/arm* image, and leaves out an
# entry with no version left. A version is lost where `type` is not one of its types; JSON5 labels
# that do not parse lose it too; filter tags other than letters, digits and dashes are dropped, and
# any past 10; `links` gives the website (`website`), the docs (`docs` or `documentation`) and the
# support page, the rest shown as they are; the readme is fetched from the label's URL ({tag}
# replaced by the version) and kept only as text/plain.

# semver.org's grammar (what python-semver's parse accepts).
SEMVER = re.compile(r"(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)"
                    r"(?:-((?:0|[1-9]\d*|\d*[a-zA-Z-][0-9a-zA-Z-]*)(?:\.(?:0|[1-9]\d*|\d*[a-zA-Z-][0-9a-zA-Z-]*))*))?"
                    r"(?:\+([0-9a-zA-Z-]+(?:\.[0-9a-zA-Z-]+)*))?")
# Docker Hub: a namespace of lower-case letters, digits, `-` and `_`; a repository name of lower-case
# path components.
HUB_REPOSITORY = re.compile(r"[a-z0-9][a-z0-9_-]{1,254}/[a-z0-9]+(?:(?:[._]|__|-+)[a-z0-9]+)*")
# Where a readme is served as text/plain.
RAW_README = re.compile(r"https://raw\.githubusercontent\.com/[\w.-]+/[\w.-]+/([^/]+)/\S+\.md")
STORE_REQUIREMENT = "core >= 1.4"


def _json(labels: dict[str, str], name: str, kind: type, problems: list[str]):
    try:
        value = json.loads(labels[name])
    except KeyError:
        problems.append(f"no `{name}` label")
        return None
    except json.JSONDecodeError as e:
        problems.append(f"`{name}` is not JSON ({e})")
        return None
    if not isinstance(value, kind):
        problems.append(f"`{name}` is JSON but not a {kind.__name__}")
        return None
    return value


def store_version_problems(labels: dict[str, str], tag: str) -> list[str]:
    """Why the store would skip, or show wrongly, the version `tag` of an image with these labels."""
    problems = []
    if not SEMVER.fullmatch(tag.removeprefix("v")):
        problems.append(f"tag {tag!r} is not a semantic version: the store skips it")
    if labels.get("version") != tag.removeprefix("v"):
        problems.append(f"`version` label {labels.get('version')!r} is not the tag's version {tag!r}")
    if labels.get("type") not in EXTENSION_TYPES:
        problems.append(f"`type` {labels.get('type')!r} is none of {sorted(EXTENSION_TYPES)}: the version is lost")
    if labels.get("requirements") != STORE_REQUIREMENT:
        problems.append(f"`requirements` {labels.get('requirements')!r}, not {STORE_REQUIREMENT!r}")
    authors = _json(labels, "authors", list, problems)
    for a in authors or []:
        if not (isinstance(a, dict) and isinstance(a.get("name"), str) and isinstance(a.get("email"), str)):
            problems.append(f"author {a!r} is not {{name, email}}")
    company = _json(labels, "company", dict, problems)
    if company is not None and not isinstance(company.get("name"), str):
        problems.append("`company` has no name")
    _json(labels, "permissions", dict, problems)
    links = _json(labels, "links", dict, problems)
    if links is not None:
        if not str(links.get("website", "")).startswith("https://"):
            problems.append("`links` has no https website")
        if not ("docs" in links or "documentation" in links):
            problems.append("`links` has no docs or documentation")
        for key, url in links.items():
            if not (isinstance(url, str) and url.startswith("https://")):
                problems.append(f"link {key} = {url!r} is not an https URL")
    tags = _json(labels, "tags", list, problems)
    if tags is not None:
        kept = [t.lower() for t in tags if isinstance(t, str) and t.replace("-", "").isalnum()][:10]
        if kept != tags:
            problems.append(f"filter tags {tags} would be cut to {kept}")
    readme = labels.get("readme", "").replace("{tag}", tag)
    m = RAW_README.fullmatch(readme)
    if not m:
        problems.append(f"readme {readme!r} is not a raw.githubusercontent.com Markdown file (text/plain)")
    elif m.group(1) in {"main", "master", "HEAD"}:
        problems.append(f"readme {readme!r} follows a branch, not the version")
    elif "-" not in tag and m.group(1) != "v" + tag.removeprefix("v"):
        problems.append(f"readme {readme!r} is not at the release's git tag v{tag.removeprefix('v')}")
    return problems


def store_entry_problems(metadata: Path, org: str) -> list[str]:
    """Why the store would skip the entry at repos/<company>/<extension>/metadata.json, its Docker Hub
    organisation taken as `org` (DOCKERHUB_ORG's placeholder replaced)."""
    problems = []
    try:
        meta = json.loads(metadata.read_text())
    except (OSError, json.JSONDecodeError) as e:
        return [f"{metadata}: {e}"]
    for key in ("name", "docker", "description", "website"):
        if not (isinstance(meta.get(key), str) and meta[key].strip()):
            problems.append(f"metadata.json has no {key}: the entry is skipped")
    config = image_config.load()
    placeholder = image_config.args(config)["DOCKERHUB_ORG"]
    docker = str(meta.get("docker", "")).replace(placeholder, org, 1)
    if not HUB_REPOSITORY.fullmatch(docker):
        problems.append(f"docker {docker!r} is not a Docker Hub repository (namespace/name)")
    if not str(meta.get("website", "")).startswith("https://"):
        problems.append(f"website {meta.get('website')!r} is not an https URL")
    for logo in (metadata.parent / "extension_logo.png", metadata.parent.parent / "company_logo.png"):
        head = logo.read_bytes()[:24] if logo.exists() else b""
        if head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
            problems.append(f"{logo.name} is not a PNG")
            continue
        width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        if not width == height >= 64:
            problems.append(f"{logo.name} is {width}x{height}, not square and at least 64 px")
    return problems


RELEASE = {"DOCKERHUB_ORG": "example-org", "VERSION": "1.2.3", "GIT_REF": "v1.2.3",
           "GITHUB_REPOSITORY": "example-org/pinc"}


def test_image_json_is_the_one_source():
    assert image_config.out_of_date(image_config.load()) == [], "run scripts/blueos_image.sh --sync"
    # The Dockerfile, built with the ARGs' defaults, carries image.json's labels.
    assert labels() == image_config.labels(image_config.load())
    # The workflow's tag, the Dockerfile's and the script's: image.json's default version is the crate's.
    cargo = re.search(r'^version = "([^"]+)"', (ROOT / "Cargo.toml").read_text(), re.M).group(1)
    assert image_config.args(image_config.load())["VERSION"] == cargo


def test_the_labels_pass_the_stores_rules():
    config = image_config.load()
    # As the workflow builds a release (v1.2.3 pushed as 1.2.3), and with the defaults.
    assert store_version_problems(image_config.labels(config, RELEASE), "1.2.3") == []
    assert store_version_problems(labels(), image_config.args(config)["VERSION"]) == []
    released = image_config.labels(config, RELEASE)
    assert "/v1.2.3/" in released["readme"] and "/v1.2.3/" in json.loads(released["links"])["documentation"]
    assert json.loads(released["links"])["website"] == "https://github.com/example-org/pinc"


def test_the_store_rules_catch_what_the_store_drops():
    good = image_config.labels(image_config.load(), RELEASE)

    def caught(tag="1.2.3", **changed) -> str:
        return " | ".join(store_version_problems({**good, **changed}, tag))

    assert "not a semantic version" in caught(tag="main")
    assert "not the tag's version" in caught(version="1.2.4")
    assert "the version is lost" in caught(type="plugin")
    assert "follows a branch" in caught(readme=good["readme"].replace("v1.2.3", "main"))
    assert "git tag v1.2.3" in caught(readme=good["readme"].replace("v1.2.3", "v1.0.0"))
    assert "text/plain" in caught(readme="https://github.com/example-org/pinc/blob/v1.2.3/docs/BLUEOS.md")
    assert "no https website" in caught(links=json.dumps({"documentation": "https://example.org"}))
    assert "cut to" in caught(tags=json.dumps(["mpc", "machine learning"]))
    assert "not JSON" in caught(permissions="{NetworkMode: host")
    assert "no name" in caught(company=json.dumps({"about": "x"}))
    assert "core >= 1.4" in caught(requirements="core >= 1.1")


def test_the_extension_store_entry_is_complete():
    config = image_config.load()
    meta_path = image_config.metadata_path(config)
    # repos/<company>/<extension>/metadata.json: the store's identifier is company.extension.
    assert meta_path.relative_to(image_config.STORE).parts == ("pinc", "pinc", "metadata.json")
    assert store_entry_problems(meta_path, "example-org") == []
    meta = json.loads(meta_path.read_text())
    assert set(meta) == {"name", "website", "docker", "description"}, meta
    org = image_config.args(config)["DOCKERHUB_ORG"]
    # The image the workflow pushes, and the website the labels name.
    assert meta["docker"] == f"{org}/blueos-pinc"
    assert meta["website"] == json.loads(image_config.labels(config)["links"])["website"]


def test_the_only_placeholder_is_the_docker_hub_organisation():
    config = image_config.load()
    org = image_config.args(config)["DOCKERHUB_ORG"]
    if image_config.org_is_set(config):
        return
    # Every file of the extension's packaging and docs, with the placeholder's occurrences that come
    # from DOCKERHUB_ORG (image.json's own, and what --sync writes from it) taken out.
    derived = [f'"DOCKERHUB_ORG": "{org}"', f'ARG DOCKERHUB_ORG="{org}"', f'"https://github.com/{org}/pinc"',
               f'"{org}/blueos-pinc"']
    files = [p for p in (ROOT / "blueos").rglob("*") if p.is_file() and p.suffix != ".png"]
    files += [WORKFLOW, ROOT / "docs" / "BLUEOS.md", ROOT / "scripts" / "blueos_image.sh"]
    left = []
    for path in files:
        text = path.read_text()
        for d in derived:
            text = text.replace(d, "")
        # OWNER.md is a page's name, not a placeholder.
        left += [f"{path.relative_to(ROOT)}: {m.group(0)}" for m in re.finditer(rf"\b{org}\b(?!\.md)", text)]
    assert not left, left


def test_the_workflow_publishes_where_the_store_reads():
    flow = yaml.safe_load(WORKFLOW.read_text())
    jobs = flow["jobs"]
    steps = [s for job in jobs.values() for s in job["steps"]]
    logins = [s for s in steps if str(s.get("uses", "")).startswith("docker/login-action")]
    assert len(logins) == 1
    login = logins[0]["with"]
    # Docker Hub: the login action's default registry.
    assert login.get("registry", "docker.io") in {"docker.io", "registry-1.docker.io"}, login
    assert login["username"] == "${{ secrets.DOCKER_USERNAME }}"
    assert login["password"] == "${{ secrets.DOCKER_PASSWORD }}"
    (push,) = [s for s in steps if str(s.get("uses", "")).startswith("docker/build-push-action")]
    options = push["with"]
    # One tag: the release's version (the store reads only semantic versions, the 25 newest).
    assert options["tags"] == "${{ needs.meta.outputs.image }}:${{ needs.meta.outputs.version }}"
    assert options["push"] == "${{ needs.meta.outputs.publish == 'true' }}"
    given = dict(line.split("=", 1) for line in options["build-args"].split("\n") if line.strip())
    assert given["VERSION"] == "${{ needs.meta.outputs.version }}"
    assert given["GIT_REF"] == "${{ needs.meta.outputs.git_ref }}"
    assert set(given) <= set(image_config.load()["args"]), set(given)
    assert any(p.startswith("linux/arm") for p in options["platforms"].split(","))
    # The version from the tag, the organisation from image.json, nothing published off a v* tag.
    meta = "\n".join(s.get("run", "") for s in jobs["meta"]["steps"])
    assert 'version="${GITHUB_REF_NAME#v}"' in meta
    assert "image_config.py arg DOCKERHUB_ORG" in meta
    assert flow[True]["push"] == {"tags": ["v*"]}  # YAML reads the key `on` as true


def test_one_blueos_version_everywhere():
    docs = (ROOT / "docs" / "BLUEOS.md").read_text()
    assert image_config.labels(image_config.load())["requirements"] == STORE_REQUIREMENT
    assert STORE_REQUIREMENT in docs
    for m in re.finditer(r"(?:BlueOS|core\s*>=)\s*(\d+\.\d+)", docs):
        assert m.group(1) in {"1.4", "1.5"}, f"docs/BLUEOS.md names BlueOS {m.group(1)}: {m.group(0)!r}"
