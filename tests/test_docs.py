"""The docs site: ``make docs`` builds it with MkDocs (warnings are errors) from ``docs/``, its
command-line reference generated from the argparse parser and its API reference from the
docstrings. The examples of its pages are run by tests/test_readme.py, as the README's are."""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from bench.cli import build_parser
from bench.docs import cli_reference

ROOT = Path(__file__).resolve().parent.parent


def _nav_pages(nav) -> list[str]:
    """Every page a ``nav`` entry of mkdocs.yml names, nested sections included."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, dict):
        return [p for v in nav.values() for p in _nav_pages(v)]
    return [p for item in nav for p in _nav_pages(item)]


def _config() -> dict:
    yaml = pytest.importorskip("yaml")
    return yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))


def test_the_cli_reference_has_every_command_and_option_of_the_parser():
    parser = build_parser()
    page = cli_reference(parser)
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)][0].choices
    assert len(subs) >= 15
    for name, sub in subs.items():
        assert f"\n## bench {name}\n" in page, name
        for action in sub._actions:
            if action.help == argparse.SUPPRESS:  # a retired spelling, refused (tests/test_flag_meanings.py)
                continue
            for flag in action.option_strings:
                assert flag in page, f"bench {name} {flag}"
    # a parser with one more option gives a page with it: the page is written from the parser
    extra = build_parser()
    [a for a in extra._actions if isinstance(a, argparse._SubParsersAction)][0].choices["gonio"].add_argument(
        "--test-only-flag", help="only in this test")
    assert "--test-only-flag" not in page and "--test-only-flag" in cli_reference(extra)


def test_the_cli_reference_is_wrapped_the_same_whatever_the_terminal(monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    wide = cli_reference(build_parser())
    monkeypatch.setenv("COLUMNS", "40")
    assert cli_reference(build_parser()) == wide and os.environ["COLUMNS"] == "40"


def test_every_page_is_in_the_nav_and_every_nav_entry_is_a_page():
    config = _config()
    nav = set(_nav_pages(config["nav"]))
    docs = ROOT / config["docs_dir"]
    on_disk = {p.relative_to(docs).as_posix() for p in docs.rglob("*.md")}
    generated = {"reference/cli.md"}  # written by docs/hooks.py at build time
    assert on_disk | generated == nav
    assert config["strict"] is True


def test_make_docs_builds_the_site_strictly_into_an_ignored_folder():
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    proc = subprocess.run(["make", "-n", "-o", ".venv/.goniobench-installed", "docs"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "-m bench.docs" in proc.stdout and "mkdocs build --strict" in proc.stdout
    site = _config()["site_dir"]
    ignored = subprocess.run(["git", "check-ignore", "-q", f"{site}/index.html"], cwd=ROOT)
    assert ignored.returncode == 0, f"{site}/ is not ignored by git"


@pytest.mark.slow  # mkdocs with mkdocstrings: ~10-15 s on 2 loaded cores
def test_the_site_builds_with_warnings_as_errors(tmp_path):
    pytest.importorskip("mkdocs")
    site = tmp_path / "site"
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-d", str(site)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    cli = (site / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    assert "bench gonio" in cli and "--uncertainty" in cli
    api = (site / "reference" / "api" / "index.html").read_text(encoding="utf-8")
    assert 'id="bench.io.registry.register_format"' in api
    assert 'id="virtual.specimens.declare.register_specimen"' in api
    for page in ("howto/add-specimen", "howto/add-instrument", "howto/add-export-format"):
        assert (site / page / "index.html").is_file(), page
