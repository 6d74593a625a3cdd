"""The documentation stays true: the README is short and links only to docs pages that exist,
every `scanner` command the user guide shows still parses (each option it uses is in that
command's `--help`), the ones that only print run, the pages name only paths that exist, and the
MkDocs site builds in strict mode."""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest
import yaml

from scanner.commands.main import build_parser, main
from tests.in_process import scanner

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
GUIDE = DOCS / "user-guide.md"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
MAX_README_LINES = 150

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```(\S*)\s*$")
OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def _slug(heading: str) -> str:
    """A heading's anchor as GitHub and MkDocs' toc both make it."""
    text = re.sub(r"[^\w\s-]", "", heading.strip().lower())
    return re.sub(r"\s", "-", text)


def _anchors(page: Path) -> set[str]:
    text = _without_code(page.read_text())
    return {_slug(m) for m in re.findall(r"^#+\s+(.+?)\s*$", text, re.M)}


def _without_code(text: str) -> str:
    return re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)


def _blocks(page: Path) -> list[tuple[str, list[str]]]:
    """Fenced code blocks: (language, lines)."""
    blocks, current, language = [], None, ""
    for line in page.read_text().splitlines():
        fence = FENCE.match(line)
        if fence and current is None:
            current, language = [], fence.group(1)
        elif fence:
            blocks.append((language, current))
            current = None
        elif current is not None:
            current.append(line)
    assert current is None, f"{page.name}: a code block is not closed"
    return blocks


def _commands(lines: list[str]) -> list[str]:
    """The `scanner ...` commands of a block, continuation lines (a trailing backslash, or an
    indented line) joined, comments dropped."""
    commands: list[str] = []
    in_command = joining = False
    for raw in lines:
        line = re.sub(r"(^|\s)#.*$", "", raw).rstrip()
        if in_command and (joining or (raw[:1].isspace() and line.strip())):
            commands[-1] += " " + line.strip().rstrip("\\")
        elif line.strip():
            in_command = line.startswith("scanner ")
            if in_command:
                commands.append(line.rstrip("\\"))
        joining = in_command and line.endswith("\\")
    return [" ".join(c.split()) for c in commands]


def _guide_commands() -> list[str]:
    return [c for lang, lines in _blocks(GUIDE) if lang == "console" for c in _commands(lines)]


@cache
def _help(command: str | None) -> str:
    """`scanner [COMMAND] --help` as printed, in this process (parsing stops at --help)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as e:
        main([command, "--help"] if command else ["--help"])
    assert e.value.code == 0
    return out.getvalue()


def _subcommands() -> set[str]:
    parser = build_parser()
    return set(next(a for a in parser._actions if a.dest == "command").choices)


# (a) The README


def test_readme_is_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines"


def test_readme_links_only_to_docs_pages_that_exist():
    targets = LINK.findall(README.read_text())
    assert targets, "the README links to no docs page"
    for target in targets:
        path, _, anchor = target.partition("#")
        resolved = (ROOT / path).resolve()
        assert resolved.is_relative_to(DOCS), f"README links outside docs/: {target}"
        assert resolved.is_file(), f"README links to a missing file: {target}"
        if anchor:
            assert anchor in _anchors(resolved), f"README: {target}: no such heading"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_pages_stand_alone(page):
    # No text cites a path outside the repository or an issue number.
    text = page.read_text()
    assert "../" not in text, f"{page.name} cites a path outside the repository"
    assert not re.search(r"(?<![\w&/])#\d+\b", text), f"{page.name} cites an issue number"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_paths_the_pages_name_exist(page):
    # Modules move; a page that names a file or folder of the repository names one that is there.
    named = re.findall(
        r"`((?:robots|planners|reconstruction|scanner|scripts|tests|docs)/[\w./-]*)`",
        page.read_text(),
    )
    missing = sorted({p for p in named if not (ROOT / p.rstrip("/")).exists()})
    assert not missing, f"{page.name} names paths that do not exist: {missing}"


# (b) The user guide's commands


def test_the_guide_marks_every_command_as_console():
    for language, lines in _blocks(GUIDE):
        if _commands(lines):
            assert language == "console", f"a ```{language} block holds commands: {lines[0]}"


def test_the_guide_shows_every_subcommand():
    shown = {c.split()[1] for c in _guide_commands()}
    assert _subcommands() <= shown, f"not in the user guide: {_subcommands() - shown}"


@pytest.mark.parametrize("command", _guide_commands())
def test_guide_command_uses_only_options_its_help_lists(command):
    word = command.split()[1]
    subcommand = None if word.startswith("-") else word
    assert subcommand is None or subcommand in _subcommands(), f"no such command: {command}"
    text = _help(subcommand)
    unknown = [
        o
        for o in OPTION.findall(command)
        if not re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", text)
    ]
    assert not unknown, f"{command}: not in `scanner {subcommand or ''} --help`: {unknown}"


def _run(command: str) -> subprocess.CompletedProcess:
    argv = command.split()[1:]
    return subprocess.run(
        [sys.executable, "-m", "scanner", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )


def test_guide_version_runs():
    assert "scanner --version" in _guide_commands()
    r = _run("scanner --version")
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("scanner "), r.stdout


def test_guide_print_config_commands_run(capfd, monkeypatch):
    # The concrete ones (synopses with [optional] parts and a|b choices are not run), through
    # `main` in this process (`test_guide_version_runs` starts the command itself), from the
    # repository's folder as the guide's paths are.
    commands = [
        c for c in _guide_commands() if "--print-config" in c and not re.search(r"[][|]", c)
    ]
    assert "scanner scan --print-config" in commands
    monkeypatch.chdir(ROOT)
    for command in commands:
        r = scanner(capfd, *command.split()[1:])
        assert r.returncode == 0, f"{command}: {r.stderr}"
        config = yaml.safe_load(r.stdout)
        assert {"object", "views", "processing", "monitor"} <= set(config), command
        if "--views 12" in command:
            assert config["views"]["count"] == 12, command
        if "--hangings 2" in command:
            assert config["hangings"] == 2, command


# (c) The MkDocs site


def test_mkdocs_builds_strict(tmp_path):
    pytest.importorskip(
        "mkdocs", reason="mkdocs is not installed (pip install mkdocs) to build the docs site"
    )
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q"]
        + ["-f", str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]
    for entry in nav:
        (page,) = entry.values()
        built = "index.html" if page == "index.md" else f"{page.removesuffix('.md')}/index.html"
        assert (tmp_path / "site" / built).is_file(), built
