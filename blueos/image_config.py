#!/usr/bin/env python3
"""blueos/image.json, the BlueOS extension image's one source, rendered for its users.

    image_config.py check                      blueos/Dockerfile's block and metadata.json agree with image.json
    image_config.py sync                       rewrites them from image.json
    image_config.py ref [NAME=VALUE...]        the image's reference (name:tag) for a local tar
    image_config.py umoci-args PLATFORM [NAME=VALUE...]
                                               `umoci config` arguments, one per line
    image_config.py set-variant LAYOUT TAG VARIANT
                                               adds the platform's variant to an OCI image's config
                                               (umoci 0.4 has no flag for it)
    image_config.py arg NAME [NAME=VALUE...]   one build argument's value

NAME=VALUE pairs override build arguments (as `docker build --build-arg` does). Used by
scripts/blueos_image.sh and .github/workflows/blueos-extension.yml; the tests import it.
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
IMAGE_JSON = HERE / "image.json"
DOCKERFILE = HERE / "Dockerfile"
STORE = HERE / "extensions_repository"
BEGIN = "# BEGIN generated from blueos/image.json by `scripts/blueos_image.sh --sync`: edit that file, not these lines"
END = "# END generated"

# Platform -> (OCI architecture, variant): what docker and the store read from an image's config.
PLATFORMS = {"linux-amd64": ("amd64", None), "linux-arm64": ("arm64", "v8"), "linux-arm-v7": ("arm", "v7")}
# Docker Hub namespaces: 2 to 255 lower-case letters, digits, `-`, `_` (4 to 30 on sign-up).
HUB_NAMESPACE = re.compile(r"[a-z0-9][a-z0-9_-]{1,254}")
REFERENCE = re.compile(r"\$\{(\w+)\}")


class ConfigError(Exception):
    pass


def load() -> dict:
    try:
        return json.loads(IMAGE_JSON.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ConfigError(f"{IMAGE_JSON}: {e}") from e


def _expand(text: str, known: dict[str, str], where: str) -> str:
    if "$" in REFERENCE.sub("", text):
        raise ConfigError(f"{where}: a `$` that is not ${{NAME}} in {text!r}")

    def one(m: re.Match) -> str:
        if m.group(1) not in known:
            raise ConfigError(f"{where}: ${{{m.group(1)}}} is not an earlier build argument ({', '.join(known)})")
        return known[m.group(1)]

    return REFERENCE.sub(one, text)


def args(config: dict, overrides: dict[str, str] | None = None) -> dict[str, str]:
    """The build arguments, in order, each expanded with the ones before it (as Dockerfile ARGs are)."""
    overrides = dict(overrides or {})
    unknown = set(overrides) - set(config["args"])
    if unknown:
        raise ConfigError(f"unknown build argument(s) {sorted(unknown)} (known: {', '.join(config['args'])})")
    out: dict[str, str] = {}
    for name, default in config["args"].items():
        value = overrides[name] if name in overrides else _expand(default, out, f"args.{name}")
        # Quotes and backslashes would end a JSON label's string early once substituted.
        if any(c in value for c in '"\\$'):
            raise ConfigError(f"build argument {name}={value!r} holds a quote, backslash or `$`")
        out[name] = value
    return out


def substitute(value, known: dict[str, str], where: str):
    if isinstance(value, str):
        return _expand(value, known, where)
    if isinstance(value, list):
        return [substitute(v, known, where) for v in value]
    if isinstance(value, dict):
        return {k: substitute(v, known, f"{where}.{k}") for k, v in value.items()}
    return value


def label_text(value) -> str:
    """A label's value as BlueOS reads it: a string as it is, anything else as JSON."""
    return value if isinstance(value, str) else json.dumps(value, separators=(", ", ": "))


def labels(config: dict, overrides: dict[str, str] | None = None) -> dict[str, str]:
    known = args(config, overrides)
    return {k: label_text(substitute(v, known, f"labels.{k}")) for k, v in config["labels"].items()}


def org_is_set(config: dict, overrides: dict[str, str] | None = None) -> bool:
    return bool(HUB_NAMESPACE.fullmatch(args(config, overrides)["DOCKERHUB_ORG"]))


def reference(config: dict, overrides: dict[str, str] | None = None) -> str:
    """name:tag of a locally built image: the published name once DOCKERHUB_ORG names a Docker Hub
    organisation, `localhost/<name>` until then (a reference nobody else can publish to)."""
    known = args(config, overrides)
    name = _expand(config["image"], known, "image")
    if not org_is_set(config, overrides):
        name = "localhost/" + name.split("/", 1)[1]
    return f"{name}:{known['VERSION']}"


def _dq(text: str) -> str:
    """A Dockerfile double-quoted word: `${NAME}` left for Docker to substitute."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def dockerfile_block(config: dict) -> str:
    lines = [BEGIN]
    for name, default in config["args"].items():
        _expand(default, {n: "" for n in config["args"]}, f"args.{name}")
        lines.append(f"ARG {name}={_dq(default)}")
    lines.append(f"WORKDIR {config['workdir']}")
    for name, value in config["env"].items():
        lines.append(f"ENV {name}={_dq(value)}")
    lines.append("EXPOSE " + " ".join(config["exposed_ports"]))
    for name, value in config["labels"].items():
        text = label_text(value)
        _expand(text, {n: "" for n in config["args"]}, f"labels.{name}")
        lines.append(f"LABEL {name}={_dq(text)}")
    lines.append("ENTRYPOINT " + json.dumps(config["entrypoint"]))
    lines.append("CMD " + json.dumps(config["cmd"]))
    lines.append(END)
    return "\n".join(lines) + "\n"


def metadata_path(config: dict) -> Path:
    store = config["store"]
    return STORE / store["company"] / store["extension"] / "metadata.json"


def metadata_json(config: dict) -> str:
    """The store's metadata.json, with the build arguments' defaults."""
    known = args(config)
    store = config["store"]
    meta = {
        "name": store["name"],
        "website": _expand(store["website"], known, "store.website"),
        "docker": _expand(config["image"], known, "image"),
        "description": store["description"],
    }
    return json.dumps(meta, indent=2) + "\n"


def _with_block(text: str, block: str) -> str:
    if text.count(BEGIN) != 1 or text.count(END) != 1:
        raise ConfigError(f"{DOCKERFILE}: needs exactly one `{BEGIN}` line and one `{END}` line")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END + "\n", 1)
    return head + block + tail


def out_of_date(config: dict) -> list[str]:
    stale = []
    if DOCKERFILE.read_text() != _with_block(DOCKERFILE.read_text(), dockerfile_block(config)):
        stale.append(str(DOCKERFILE.relative_to(ROOT)))
    meta = metadata_path(config)
    if not meta.exists() or meta.read_text() != metadata_json(config):
        stale.append(str(meta.relative_to(ROOT)))
    return stale


def sync(config: dict) -> list[str]:
    stale = out_of_date(config)
    DOCKERFILE.write_text(_with_block(DOCKERFILE.read_text(), dockerfile_block(config)))
    meta = metadata_path(config)
    meta.parent.mkdir(parents=True, exist_ok=True)
    meta.write_text(metadata_json(config))
    return stale


def umoci_args(config: dict, platform: str, overrides: dict[str, str] | None = None) -> list[str]:
    if platform not in PLATFORMS:
        raise ConfigError(f"unknown platform {platform!r} (known: {', '.join(PLATFORMS)})")
    arch, _ = PLATFORMS[platform]
    out = ["--os=linux", f"--architecture={arch}", f"--config.workingdir={config['workdir']}"]
    out += [f"--config.env={k}={v}" for k, v in config["env"].items()]
    out += [f"--config.exposedports={p}" for p in config["exposed_ports"]]
    out += [f"--config.entrypoint={a}" for a in config["entrypoint"]]
    out += [f"--config.cmd={a}" for a in config["cmd"]]
    for name, value in labels(config, overrides).items():
        if "\n" in value:
            raise ConfigError(f"label {name} holds a line break")
        out.append(f"--config.label={name}={value}")
    return out


def _blob(layout: Path, digest: str) -> Path:
    algo, hexa = digest.split(":", 1)
    return layout / "blobs" / algo / hexa


def _put(layout: Path, data: bytes) -> tuple[str, int]:
    digest = "sha256:" + hashlib.sha256(data).hexdigest()
    path = _blob(layout, digest)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return digest, len(data)


def set_variant(layout: Path, tag: str, variant: str) -> None:
    """Writes the config with `variant` and the manifest pointing at it, and repoints the tag."""
    index_path = layout / "index.json"
    index = json.loads(index_path.read_text())
    entries = [m for m in index["manifests"] if m.get("annotations", {}).get("org.opencontainers.image.ref.name") == tag]
    if len(entries) != 1:
        raise ConfigError(f"{layout}: {len(entries)} manifests tagged {tag!r}, expected 1")
    entry = entries[0]
    manifest = json.loads(_blob(layout, entry["digest"]).read_bytes())
    config = json.loads(_blob(layout, manifest["config"]["digest"]).read_bytes())
    config["variant"] = variant
    manifest["config"]["digest"], manifest["config"]["size"] = _put(layout, json.dumps(config).encode())
    entry["digest"], entry["size"] = _put(layout, json.dumps(manifest).encode())
    index_path.write_text(json.dumps(index))


def _overrides(pairs: list[str]) -> dict[str, str]:
    out = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep:
            raise ConfigError(f"{pair!r} is not NAME=VALUE")
        out[name] = value
    return out


def main(argv: list[str]) -> int:
    if not argv or argv[0] in {"-h", "--help"}:
        print(__doc__)
        return 0 if argv else 2
    command, rest = argv[0], argv[1:]
    config = load()
    if command == "check":
        stale = out_of_date(config)
        if stale:
            print(f"out of date with blueos/image.json: {', '.join(stale)} (run scripts/blueos_image.sh --sync)",
                  file=sys.stderr)
            return 1
        return 0
    if command == "sync":
        for path in sync(config):
            print(f"rewrote {path}", file=sys.stderr)
        return 0
    if command == "ref":
        print(reference(config, _overrides(rest)))
        return 0
    if command == "arg" and rest:
        print(args(config, _overrides(rest[1:]))[rest[0]])
        return 0
    if command == "umoci-args" and rest:
        print("\n".join(umoci_args(config, rest[0], _overrides(rest[1:]))))
        return 0
    if command == "set-variant" and len(rest) == 3:
        set_variant(Path(rest[0]), rest[1], rest[2])
        return 0
    print(f"image_config.py: unknown command or arguments {argv!r} (see --help)", file=sys.stderr)
    return 2


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except (ConfigError, KeyError) as e:
        print(f"image_config.py: error: {e}", file=sys.stderr)
        sys.exit(1)
