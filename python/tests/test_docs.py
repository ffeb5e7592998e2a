"""The docs checked against the programs they describe.

Every command README.md and the owner's guides give (the lines of their shell code blocks and
the inline code that starts with `pinc`, `mpc_track`, `cargo run ... --` or `target/release/`)
is read, and each subcommand and each `--flag` in it is looked up in the program's own `--help`
(clap's, every subcommand's too). Every relative link between the docs pages, and every
`#anchor`, must resolve by GitHub's heading slugs. The checker's own tests feed it a made-up
flag, subcommand and anchor and expect each to be caught.

Needs target/release/pinc and target/release/mpc_track built with every feature (CI's
`cargo test --release --workspace --all-features` builds them first); `$PINC_BIN` and
`$MPC_TRACK_BIN` point elsewhere.
"""

from __future__ import annotations

import functools
import os
import re
import shlex
import subprocess
import unicodedata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# README first, then the owner's guides: the pages whose commands an owner types.
COMMAND_PAGES = ["README.md", "docs/OWNER.md", "docs/TROUBLESHOOTING.md", "docs/FIT.md", "docs/VEHICLE.md",
                 "docs/PILOT.md", "docs/GUIDE_CONTROLLER.md", "docs/BLUEOS.md"]
# Shell code blocks; output (`text`) and other languages are not commands.
SHELL_FENCES = {"", "sh", "bash", "shell", "console"}
# Words that stand for something to fill in, where a subcommand could be.
PLACEHOLDER = re.compile(r"^(\.\.\.|[A-Z][A-Z0-9_.]*(\.\.\.)?)$")


def binary(name: str) -> Path:
    given = os.environ.get({"pinc": "PINC_BIN", "mpc_track": "MPC_TRACK_BIN"}[name])
    path = Path(given) if given else ROOT / "target" / "release" / name
    if not path.is_file():
        pytest.skip(f"{path} is not built: run `cargo build --release --all-features` first (CI builds it before pytest)")
    return path


class Help:
    """One command's `--help`: its subcommands and its flags."""

    def __init__(self, text: str):
        self.subcommands: list[str] = []
        self.flags: set[str] = set()
        section = None
        for line in text.splitlines():
            if re.match(r"^\S.*:$", line):
                section = line[:-1]
                continue
            if section == "Commands":
                m = re.match(r"^  (\S+)", line)
                if m and m.group(1) != "help":
                    self.subcommands.append(m.group(1))
            m = re.match(r"^\s+(?:-(\w), )?--([a-z0-9][a-z0-9-]*)", line)
            if m:
                self.flags.add("--" + m.group(2))
                if m.group(1):
                    self.flags.add("-" + m.group(1))
            m = re.match(r"^\s+-(\w)\s", line)
            if m:
                self.flags.add("-" + m.group(1))


@functools.lru_cache(maxsize=None)
def help_of(program: str, path: tuple[str, ...]) -> Help:
    r = subprocess.run([str(binary(program)), *path, "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, f"{program} {' '.join(path)} --help: {r.stderr}"
    return Help(r.stdout)


def flags_below(program: str, path: tuple[str, ...]) -> set[str]:
    """The flags of a command and of every subcommand under it."""
    h = help_of(program, path)
    flags = set(h.flags)
    for sub in h.subcommands:
        flags |= flags_below(program, path + (sub,))
    return flags


def words(command: str) -> list[str]:
    try:
        return shlex.split(command, comments=True)
    except ValueError:  # an apostrophe in prose
        return command.split()


def program_and_args(tokens: list[str]) -> tuple[str, list[str]] | None:
    """Which of pinc's programs a command runs, and its arguments; None for anything else."""
    while tokens and re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", tokens[0]):  # VAR=value prefixes
        tokens = tokens[1:]
    if not tokens:
        return None
    head = tokens[0]
    for name in ("pinc", "mpc_track"):
        if head == name or head.endswith("/release/" + name) or head == "/opt/pinc/bin/" + name:
            return name, tokens[1:]
    if tokens[:2] == ["cargo", "run"]:
        own = tokens[2:tokens.index("--")] if "--" in tokens else tokens[2:]
        if "--example" in own or "-p" in own or "--package" in own:
            return None
        name = own[own.index("--bin") + 1] if "--bin" in own else "pinc"
        if name not in ("pinc", "mpc_track"):
            return None
        return name, tokens[tokens.index("--") + 1:] if "--" in tokens else []
    return None


def check_command(program: str, args: list[str]) -> list[str]:
    """What in one command the program does not know: each an error's text."""
    errors = []
    paths: list[tuple[str, ...]] = [()]
    rest = list(args)
    open_ended = False
    while rest and not rest[0].startswith("-"):
        token = rest[0].strip("[]")
        if not help_of(program, paths[0]).subcommands:
            break
        if PLACEHOLDER.match(token):
            open_ended = True
            break
        alternatives = token.split("|")
        nexts = []
        for path in paths:
            known = help_of(program, path).subcommands
            for alt in alternatives:
                if alt in known:
                    nexts.append(path + (alt,))
                else:
                    errors.append(f"{program} {' '.join(path + (alt,))}: no such subcommand (it has: {', '.join(known)})")
        if not nexts:
            return errors
        paths = nexts
        rest = rest[1:]
    for token in rest:
        token = token.strip("[]()")
        if not token.startswith("-") or token in ("-", "--") or re.match(r"^-[0-9.]", token):
            continue
        flag = token.split("=", 1)[0]
        for path in paths:
            known = flags_below(program, path) if open_ended else help_of(program, path).flags
            if flag not in known:
                errors.append(f"{program} {' '.join(path)}: no flag {flag}".replace("  ", " "))
    return errors


def segments(line: str) -> list[list[str]]:
    """A shell line's commands, split at `&&`, `||`, `;` and `|` standing alone."""
    out, current = [], []
    for t in words(line):
        if t in ("&&", "||", ";", "|"):
            out.append(current)
            current = []
        else:
            current.append(t)
    out.append(current)
    return [s for s in out if s]


def commands_in(text: str) -> list[tuple[int, str]]:
    """(line number, command) for every command the page gives."""
    found = []
    lines = text.splitlines()
    fence = None
    i = 0
    while i < len(lines):
        line = lines[i]
        m = re.match(r"^\s*(```+|~~~+)\s*([\w-]*)", line)
        if m:
            fence = None if fence is not None else m.group(2).lower()
            i += 1
            continue
        if fence is not None:
            if fence in SHELL_FENCES:
                start, joined = i + 1, line
                while joined.rstrip().endswith("\\") and i + 1 < len(lines):
                    i += 1
                    joined = joined.rstrip()[:-1] + " " + lines[i]
                found.append((start, re.sub(r"^\s*\$\s+", "", joined)))
        else:
            for span in re.findall(r"`([^`]+)`", line):
                span = span.replace("\\|", "|")
                if re.match(r"^(pinc|mpc_track|cargo run|target/release/)(\s|$)", span) or span.startswith("target/release/"):
                    found.append((i + 1, span))
        i += 1
    return found


def command_errors(text: str, page: str) -> list[str]:
    errors = []
    for line_no, command in commands_in(text):
        for segment in segments(command):
            run = program_and_args(segment)
            if run:
                errors += [f"{page}:{line_no}: {e}  [{command.strip()}]" for e in check_command(*run)]
    return errors


# Flags an owner's page names in prose (`--fix-latency`) that belong to no program of pinc's.
CARGO_FLAGS = {"--features", "--release", "--bin", "--locked", "--path", "--example", "--test", "--workspace",
               "--all-features", "--no-default-features", "--bench"}


def known_flags() -> set[str]:
    """Every flag of pinc (each subcommand), mpc_track, cargo's above and the test helpers' scripts."""
    helpers = "".join(p.read_text() for p in (ROOT / "python" / "tests").glob("*.py") if p.name != "test_docs.py")
    own = set(re.findall(r"add_argument\(\s*\"(--[a-z0-9-]+)\"", helpers))
    return flags_below("pinc", ()) | flags_below("mpc_track", ()) | CARGO_FLAGS | own


def prose_flag_errors(text: str, page: str, known: set[str]) -> list[str]:
    """Flags in inline code outside the commands (`--fix-latency 0.5`) that no program takes."""
    errors, fence = [], False
    for i, line in enumerate(text.splitlines(), 1):
        if re.match(r"^\s*(```|~~~)", line):
            fence = not fence
            continue
        if fence:
            continue
        for span in re.findall(r"`([^`]+)`", line):
            if re.match(r"^(pinc|mpc_track|cargo|target/release/|python|pytest|docker|scp|ssh|sudo|curl|git|rustup|rustc)\b", span):
                continue  # a command: checked against its own program above
            for flag in re.findall(r"(?:^|[\s\[(])(--[a-z0-9][a-z0-9-]*)", span):
                if flag not in known:
                    errors.append(f"{page}:{i}: {flag}: no program of pinc's takes it  [{span}]")
    return errors


# Links and anchors.

def slug(heading: str) -> str:
    """GitHub's anchor for a heading: the rendered text lowercased, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link's text
    text = re.sub(r"[`*]", "", text).strip().lower()
    kept = []
    for ch in text:
        cat = unicodedata.category(ch)
        if ch in " -" or cat[0] in "LMN" or cat == "Pc":
            kept.append(ch)
    return "".join(kept).replace(" ", "-")


def anchors(text: str) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    fence = False
    for line in text.splitlines():
        if re.match(r"^\s*(```|~~~)", line):
            fence = not fence
            continue
        m = None if fence else re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m:
            s = slug(m.group(1))
            n = seen.get(s, 0)
            seen[s] = n + 1
            out.add(s if n == 0 else f"{s}-{n}")
    out |= set(re.findall(r'<a\s+(?:name|id)="([^"]+)"', text))
    return out


def links_in(text: str) -> list[tuple[int, str]]:
    found, fence = [], False
    for i, line in enumerate(text.splitlines(), 1):
        if re.match(r"^\s*(```|~~~)", line):
            fence = not fence
            continue
        if fence:
            continue
        line = re.sub(r"`[^`]*`", "", line)
        found += [(i, target) for target in re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", line)]
    return found


def link_errors(page: Path, text: str) -> list[str]:
    errors = []
    name = page.relative_to(ROOT)
    for line_no, target in links_in(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        if not path:  # this page's own heading
            if anchor not in anchors(text):
                errors.append(f"{name}:{line_no}: {target}: no heading with anchor #{anchor} on this page")
            continue
        dest = (page.parent / path).resolve()
        if not dest.exists():
            errors.append(f"{name}:{line_no}: {target}: no file {dest.relative_to(ROOT) if ROOT in dest.parents else dest}")
            continue
        if anchor and dest.suffix == ".md" and anchor not in anchors(dest.read_text()):
            errors.append(f"{name}:{line_no}: {target}: no heading with anchor #{anchor} in {dest.relative_to(ROOT)}")
    return errors


def doc_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


# The checks.

def test_every_command_in_the_owner_docs_is_one_the_programs_take():
    errors = []
    for page in COMMAND_PAGES:
        path = ROOT / page
        if path.exists():
            errors += command_errors(path.read_text(), page)
    assert not errors, "\n".join(errors)


def test_every_flag_the_owner_docs_name_in_prose_exists():
    known = known_flags()
    errors = []
    for page in COMMAND_PAGES:
        path = ROOT / page
        if path.exists():
            errors += prose_flag_errors(path.read_text(), page, known)
    assert not errors, "\n".join(errors)
    assert prose_flag_errors("with `--fix-latenc 0.5`", "x.md", known), "a misspelt flag passed"


def test_the_owner_docs_give_commands_to_check():
    # A parser that found nothing would pass everything.
    found = [c for page in COMMAND_PAGES if (ROOT / page).exists() for c in commands_in((ROOT / page).read_text())]
    assert len(found) > 50, found


def test_every_link_and_anchor_between_the_docs_resolves():
    errors = []
    for page in doc_pages():
        errors += link_errors(page, page.read_text())
    assert not errors, "\n".join(errors)


def test_a_made_up_flag_is_caught():
    text = "```sh\npinc fit --recording pool.mcap --no-such-flag 3\n```\n"
    errors = command_errors(text, "made_up.md")
    assert len(errors) == 1 and "no flag --no-such-flag" in errors[0], errors
    assert command_errors("Run `mpc_track --model M.pinc --oracel`.", "made_up.md")[0].endswith(
        "no flag --oracel  [mpc_track --model M.pinc --oracel]")
    # A flag of another subcommand is no flag of this one.
    assert command_errors("`pinc vehicle status --depth-band 0.5,2.5`", "x.md"), "excite's flag passed as status's"


def test_a_made_up_subcommand_is_caught_and_real_ones_pass():
    errors = command_errors("```sh\npinc vehicle chek --connect tcp:127.0.0.1:5777\n```\n", "made_up.md")
    assert len(errors) == 1 and "no such subcommand" in errors[0], errors
    good = ("```sh\ncargo run --release --features train,vehicle -- fit --recording R --vehicle V.toml --out fitted \\\n"
            "    --epochs 30   # a comment --not-a-flag\n"
            "target/release/mpc_track --connect udpout:192.168.2.2:14550 --arm --current -0.1,0.2\n```\n"
            "`pinc vehicle status|record --connect URL`, `pinc vehicle ... --set`, `cargo run --release --bin mpc_track`\n")
    assert command_errors(good, "good.md") == []


def test_a_broken_anchor_and_a_missing_page_are_caught():
    page = ROOT / "docs" / "made_up.md"
    text = "[a](OWNER.md#no-such-heading) [b](NO_SUCH_PAGE.md) [c](#here) [d](OWNER.md#connect)\n\n## Here\n"
    errors = link_errors(page, text)
    assert len(errors) == 2 and "#no-such-heading" in errors[0] and "NO_SUCH_PAGE.md" in errors[1], errors


def test_slugs_follow_githubs_rules():
    assert slug("From C and C++") == "from-c-and-c"
    assert slug("Four axes: holding a point and following a path") == "four-axes-holding-a-point-and-following-a-path"
    assert slug("`pinc vehicle status --connect URL [--window S] [--json]`") == \
        "pinc-vehicle-status---connect-url---window-s---json"
    assert slug("Navigation on a DVL and a USBL") == "navigation-on-a-dvl-and-a-usbl"
    assert anchors("# A\n## A\n```\n# not a heading\n```\n") == {"a", "a-1"}
