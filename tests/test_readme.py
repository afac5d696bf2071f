"""The examples of the README and of the docs site are run and their printed numbers compared
with the text.

The documents are ``README.md`` and every page under ``docs/`` (:data:`DOCUMENTS`), each read the
same way. Every ``$ bench ...`` line of a code block is an example; the lines after it (up to the
next ``$`` line or the end of the block) are what it prints. Each example runs here, in document
order, in one scratch folder where ``fixtures`` points at the repository's (stdout and stderr
together, through a shell for ``; echo "exit $?"`` and ``&&``) and every expected
line must match the printed line token for token: the text exactly, each number to 6 significant
digits (the seeded examples are deterministic; the margin only absorbs last-digit differences of
libm across machines). An example whose budget is too large for a test names a smaller one in a
``# test: --rays N`` comment on its line (then only its first, header, line is compared); one
that takes more than ~10 CPU-seconds says ``# test: slow`` and runs in ``make test-slow`` (CI runs
both), compared in full.

Every ```python block is a script: it runs piped into ``python -`` in the same scratch folder
(a non-interactive matplotlib backend) and must exit 0 printing every ``LiveTable`` field it names,
and end by printing the lines its ``# prints:`` comment lists (numbers to 6 significant digits);
a block opening with ``# with `bench serve ...` running`` needs a server: test_catalog.py runs its steps.

Examples that need a store, a run id or long-running emulators (``scan``, ``runs``, ``resume``,
``show``, ``export``, ``emulate``) are listed in :data:`NOT_RUN` with the test that covers them.

``python tests/test_readme.py --update`` rewrites the documents' outputs from a fresh run (review
the diff before committing).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
#: the documents whose examples run: the README, then the docs site's pages in path order
DOCUMENTS = [README, *sorted((ROOT / "docs").rglob("*.md"))]

#: command words not run here, and the tests that cover them
NOT_RUN = {"scan": "test_runner.py / test_cli.py", "runs": "test_store.py", "resume": "test_runner.py",
           "white": "test_home_white.py", "home": "test_home_white.py",
           "show": "test_store.py", "export": "test_export.py", "emulate": "test_emulated_bench.py",
           "check": "test_assurance.py", "chart": "test_assurance.py"}

_NUMBER = re.compile(r"[-+]?(?:\d[\d,]*\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


@dataclass
class Example:
    line: int
    command: str
    expected: list[str]
    small: str | None
    page: str = "README.md"  # the document, relative to the repository


def _page(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def examples(path: Path = README) -> list[Example]:
    """The ``$ bench`` examples of one document with their expected output lines."""
    out: list[Example] = []
    in_block = False
    current: Example | None = None
    for n, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if raw.startswith("```"):
            if in_block and current:
                out.append(current)
            current = None
            in_block = not in_block
            continue
        if not in_block:
            continue
        if raw.startswith("$ "):
            if current:
                out.append(current)
            cmd, _, note = raw[2:].partition("# test:")
            cmd = cmd.rstrip()
            current = Example(n, cmd, [], note.strip() or None, _page(path)) if cmd.startswith("bench ") else None
        elif current is not None and raw.strip():
            current.expected.append(raw)
    return out


def _skipped(ex: Example) -> str | None:
    word = ex.command.split()[1]
    if word in NOT_RUN or " RUN " in f" {ex.command} " or "--store" in ex.command:
        return f"needs a store or emulators (covered by {NOT_RUN.get(word, 'test_store.py')})"
    return None


def workdir(base: Path) -> Path:
    """A scratch folder where the examples run, with ``fixtures`` linked to the repository's."""
    base.mkdir(parents=True, exist_ok=True)
    link = base / "fixtures"
    if not link.exists():
        link.symlink_to(ROOT / "fixtures", target_is_directory=True)
    return base


def run(ex: Example, cwd: Path) -> list[str]:
    cmd = ex.command
    if ex.small and ex.small != "slow":
        cmd = cmd + " " + ex.small  # argparse: the later value wins
    shell = re.sub(r"(^|&& |; )bench ", lambda m: f"{m.group(1)}{sys.executable} -m bench.cli ", cmd)
    r = subprocess.run(f"( {shell} ) 2>&1", shell=True, stdout=subprocess.PIPE, text=True, cwd=cwd, timeout=900,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    return [line for line in r.stdout.splitlines() if line.strip()]


def _tokens(line: str) -> tuple[str, list[float]]:
    nums = []

    def keep(m: re.Match) -> str:
        try:
            nums.append(float(m.group(0).replace(",", "")))
        except ValueError:
            return m.group(0)
        return "#"

    return " ".join(_NUMBER.sub(keep, line).split()), nums


def same(expected: str, got: str) -> bool:
    te, ne = _tokens(expected)
    tg, ng = _tokens(got)
    return te == tg and len(ne) == len(ng) and all(
        a == b or abs(a - b) <= 1e-6 * max(abs(a), abs(b)) for a, b in zip(ne, ng))


def _once(found: list[Example]) -> list[Example]:
    """Each example once: one the README repeats from a docs page word for word runs once."""
    seen: set[tuple] = set()
    out = []
    for ex in found:
        key = (ex.command, tuple(ex.expected), ex.small)
        if key not in seen:
            seen.add(key)
            out.append(ex)
    return out


EXAMPLES = _once([ex for path in DOCUMENTS for ex in examples(path)])


def _where(page: str, line: int) -> str:
    """A test id: ``L12`` in the README (as before the docs site), ``docs/fit.md:L12`` elsewhere."""
    return f"L{line}" if page == "README.md" else f"{page}:L{line}"


def test_readme_has_examples():
    assert len(EXAMPLES) >= 8
    assert any("bench compare" in e.command for e in EXAMPLES)


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    return workdir(tmp_path_factory.mktemp("readme"))


@pytest.mark.parametrize("ex", [pytest.param(e, marks=[pytest.mark.slow] if e.small == "slow" else [])
                                for e in EXAMPLES], ids=[f"{_where(e.page, e.line)}:{e.command[:40]}" for e in EXAMPLES])
def test_readme_example_prints_what_the_readme_says(ex, scratch):
    why = _skipped(ex)
    if why:
        pytest.skip(why)
    got = run(ex, scratch)
    smaller = ex.small is not None and ex.small != "slow"  # a smaller budget than the README's
    expected = ex.expected[:1] if smaller else ex.expected
    assert len(got) >= len(expected), f"{ex.page} line {ex.line}: {ex.command}\nprinted:\n" + "\n".join(got)
    for i, line in enumerate(expected):
        if smaller and i == 0:
            continue  # a smaller budget changes N in the header; the header's shape is checked below
        assert same(line, got[i]), f"{ex.page} line {ex.line + 1 + i}: expected\n  {line}\nprinted\n  {got[i]}"
    if smaller:
        assert _tokens(expected[0])[0] == _tokens(got[0])[0]


def python_blocks(path: Path = README) -> list[tuple[int, str]]:
    """The ```python blocks of one document as ``(first line number, source)``."""
    out: list[tuple[int, str]] = []
    block: list[str] | None = None
    start = 0
    for n, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if block is None and raw.strip() == "```python":
            block, start = [], n + 1
        elif block is not None and not block and raw.startswith("# with `bench serve"):
            block = None  # a block that needs a running server: tests/test_catalog.py runs its steps
        elif block is not None and raw.startswith("```"):
            out.append((start, "\n".join(block) + "\n"))
            block = None
        elif block is not None:
            block.append(raw)
    return out


def printed_lines(source: str) -> list[str]:
    """The lines a python block says it prints: the comment lines after a ``# prints:`` line."""
    lines = source.splitlines()
    if "# prints:" not in lines:
        return []
    return [line[2:] for line in lines[lines.index("# prints:") + 1:] if line.startswith("# ")]


#: every document's python blocks as ``(page, first line number, source)``
PYTHON_BLOCKS = [(_page(path), n, src) for path in DOCUMENTS for n, src in python_blocks(path)]


def test_the_sequential_fit_block_says_what_it_prints():
    blocks = [src for _, _, src in PYTHON_BLOCKS if "sequential_fit(" in src]
    assert blocks and printed_lines(blocks[0]), "the docs' sequential_fit block names no printed line"


@pytest.mark.slow  # ~7-12 CPU-s a block (bluesky, matplotlib, a scan); fast twin: test_bluesky.py live views
@pytest.mark.parametrize("page,start,source", PYTHON_BLOCKS, ids=[_where(p, n) for p, n, _ in PYTHON_BLOCKS])
def test_readme_python_block_runs_from_stdin(page, start, source, scratch):
    r = subprocess.run([sys.executable, "-"], input=source, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                       text=True, cwd=scratch, timeout=600,
                       env={**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"})
    assert r.returncode == 0, f"{page} line {start}: the block failed:\n{r.stdout[-3000:]}"
    expected = printed_lines(source)
    if expected:  # the block's `# prints:` lines are its last printed lines, number by number
        got = [line for line in r.stdout.splitlines() if line.strip()][-len(expected):]
        assert len(got) == len(expected) and all(same(e, g) for e, g in zip(expected, got)), \
            f"{page} line {start}: expected\n  " + "\n  ".join(expected) + "\nprinted\n  " + "\n  ".join(got)
    for fields in re.findall(r"LiveTable\(\[([^\]]*)\]", source):
        for field in re.findall(r"\"([^\"]+)\"", fields):
            header = [line for line in r.stdout.splitlines() if f" {field} " in line]
            assert header, f"{page} line {start}: LiveTable printed no column {field!r}:\n{r.stdout[-3000:]}"
            # the rows under the header hold numbers in that column, not blanks
            col = header[0].split("|").index(f" {field} ") if "|" in header[0] else None
            rows = [line.split("|") for line in r.stdout.splitlines() if re.match(r"\|\s+\d+ \|", line)]
            assert col is not None and rows and all(re.fullmatch(r"\s*-?[\d.]+(e[-+]\d+)?\s*", row[col])
                                                     for row in rows), f"{field}: {rows}"


def _update() -> None:
    import tempfile

    cwd = workdir(Path(tempfile.mkdtemp(prefix="readme-")))
    for path in DOCUMENTS:
        _update_document(path, cwd)


def _update_document(path: Path, cwd: Path) -> None:
    lines = path.read_text(encoding="utf-8").splitlines()
    found = examples(path)
    outputs = {ex.line: run(ex, cwd) for ex in found if not (_skipped(ex) or (ex.small and ex.small != "slow"))}
    for ex in reversed(found):
        if ex.line not in outputs:
            continue
        got = outputs[ex.line]
        start = ex.line  # index of the first output line (0-based) = line number of the command
        end = start
        while end < len(lines) and not lines[end].startswith(("$ ", "```")):
            end += 1
        while end > start and not lines[end - 1].strip():  # keep the blank lines between examples
            end -= 1
        lines[start:end] = got
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__" and "--update" in sys.argv:
    _update()


def demo_compare_block() -> list[str]:
    """The docs' block of the demo's last stage (``compare: emulated-hardware run ...``), in the
    README or the page under docs/ that holds it."""
    opening = "```\ncompare: emulated-hardware run against two virtual candidate models\n"
    text = next(t for t in (p.read_text(encoding="utf-8") for p in DOCUMENTS) if opening in t)
    start = text.index(opening) + 4
    return [line for line in text[start:text.index("```", start)].splitlines() if line.strip()]


@pytest.mark.slow  # the demo's emulated scan, two virtual twins and the comparison (~35 CPU-s)
def test_the_demo_compare_block_is_what_the_demo_prints(tmp_path):
    """`make demo` ends with this comparison: its lines, numbers to 6 significant digits (the report
    is written under the demo's own folder, demo-out/, there)."""
    from bench.demo import _compare_demo, _scan_demo

    scan, _ = _scan_demo(tmp_path, 20261122)
    _, printed = _compare_demo(tmp_path, scan, 20261122)
    printed = [line for line in printed if line.strip()]
    expected = demo_compare_block()
    assert len(printed) == len(expected)
    for want, got in zip(expected, printed):
        if want.strip().startswith("report:"):
            assert got.strip().startswith("report:") and got.endswith("compare/report.html"), got
        else:
            assert same(want, got), f"expected\n  {want}\nprinted\n  {got}"
