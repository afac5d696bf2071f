"""Source that travels: no line cites a numbered item of a tracker that does not ship with the
code, and no line names a path of one development machine (cite vendors' manuals by their public
titles instead). Each pattern is shown to catch a perturbed line, so an empty scan means
something."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCE_SUFFIXES = {".py", ".toml", ".md", ".cfg", ".ini", ".sh", ".yml", ".yaml", ".txt"}
SKIPPED_DIRS = {".venv", ".git", "__pycache__", "build", ".pytest_cache", ".hypothesis", ".mypy_cache", "demo-out"}

#: the word issue, task, ticket, bug, PR or pull request (or a plural) before a number, "#" or not
TRACKER_NUMBER = re.compile(r"\b(?:issues?|tasks?|tickets?|bugs?|PRs?|pull requests?)\s*#?\d+", re.IGNORECASE)
#: an absolute path of a development machine: its shared work folder or a home directory
MACHINE_PATH = re.compile(r"(?<![\w.])/(?:work|home|Users|root)/[\w.-]+")


def source_files() -> list[Path]:
    """Every text file of the project that ships or documents it."""
    out = []
    for path in ROOT.rglob("*"):
        rel = path.relative_to(ROOT)
        if any(part in SKIPPED_DIRS or part.endswith(".egg-info") for part in rel.parts):
            continue
        if path.is_file() and (path.suffix in SOURCE_SUFFIXES or path.name == "Makefile"):
            out.append(path)
    return sorted(out)


def offending_lines(pattern: re.Pattern[str], files: list[Path]) -> list[str]:
    """``file:line: text`` of every line ``pattern`` finds."""
    return [f"{p.relative_to(ROOT) if p.is_relative_to(ROOT) else p}:{n}: {line.strip()}"
            for p in files
            for n, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines(), start=1)
            if pattern.search(line)]


@pytest.mark.parametrize("pattern", [TRACKER_NUMBER, MACHINE_PATH], ids=["tracker-number", "machine-path"])
def test_no_source_line_matches(pattern):
    files = source_files()
    assert len(files) > 100  # the walk really reached the tree
    assert offending_lines(pattern, files) == []


@pytest.mark.parametrize("pattern, line", [
    (TRACKER_NUMBER, "# the lost lobe of iss" + "ue 16 is found"),
    (TRACKER_NUMBER, '"""Overhead per point (iss' + "ues 4 and 5)." + '"""'),
    (TRACKER_NUMBER, "# see ta" + "sk #9"),
    (TRACKER_NUMBER, "fixed in P" + "R 12"),
    (MACHINE_PATH, "Facts: ``/" + "work/shared/reference/ocean-rs232.md``."),
    (MACHINE_PATH, "cache = '/" + "home/dev/goniobench'"),
])
def test_a_perturbed_line_is_caught(tmp_path, pattern, line):
    # (the lines are split in two here so that this file passes its own scan)
    bad = tmp_path / "module.py"
    bad.write_text(f"x = 1\n{line}\n")
    assert offending_lines(pattern, [bad]) != []


@pytest.mark.parametrize("line", ["operator_note: Spectralon SRS-99 #4471, cleaned",
                                  "#1 s2: ACCEPT", "a 16-lane path", "fixtures/dynamixel/ping.json"])
def test_ordinary_lines_pass(tmp_path, line):
    ok = tmp_path / "module.py"
    ok.write_text(f"{line}\n")
    assert offending_lines(TRACKER_NUMBER, [ok]) == [] and offending_lines(MACHINE_PATH, [ok]) == []
