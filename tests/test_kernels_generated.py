"""The generated kernel code (:mod:`virtual.kernels.lawcode`: the laws' float32 twins and their
dispatch, build products written on import, and the checked-in numba-free law table) is what
``make kernels`` writes from the laws today; a stale build product is rewritten (and an identical
one left alone); and a law that breaks the laws' contract is refused with one line naming its
file."""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

import pytest

from virtual.kernels import generate, lawcode
from virtual.kernels.laws import oren_nayar


def test_the_generated_files_are_current() -> None:
    """The checked-in law table and laws32/__init__.py, and the build products the import of
    virtual.kernels wrote (git ignores those: a precision's copy of a law is not a second source)."""
    assert lawcode.stale() == [], "run `make kernels` (python -m virtual.kernels.generate)"
    built = lawcode.built_files()
    assert lawcode.KERNELS / "law_dispatch.py" in built and lawcode.KERNELS / "laws32" / "oren_nayar.py" in built
    assert all(p.read_text() == text for p, text in built.items())
    tracked = subprocess.run(["git", "ls-files", "--", *map(str, built)], cwd=lawcode.VIRTUAL.parent,
                             capture_output=True, text=True)
    if tracked.returncode == 0:  # a git checkout: none of them checked in
        assert tracked.stdout == ""


def test_a_stale_build_product_is_rewritten_and_a_current_one_left_alone(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """What importing virtual.kernels does (lawcode.ensure_built), on copies in a temporary folder."""
    real = lawcode.built_files()
    twin, dispatch = lawcode.KERNELS / "laws32" / "oren_nayar.py", lawcode.KERNELS / "law_dispatch.py"
    files = {tmp_path / "oren_nayar.py": real[twin], tmp_path / "law_dispatch.py": real[dispatch]}
    (tmp_path / "oren_nayar.py").write_text(real[twin].replace("u3 * den < num", "u3 * den <= num"))  # stale
    (tmp_path / "law_dispatch.py").write_text(real[dispatch])  # current
    before = os.stat(tmp_path / "law_dispatch.py")
    monkeypatch.setattr(lawcode, "built_files", lambda: files)
    assert lawcode.ensure_built() == [tmp_path / "oren_nayar.py"]
    assert (tmp_path / "oren_nayar.py").read_text() == real[twin]
    after = os.stat(tmp_path / "law_dispatch.py")
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)  # numba's cache keeps it
    (tmp_path / "law_dispatch.py").unlink()  # a fresh clone: missing
    assert lawcode.ensure_built() == [tmp_path / "law_dispatch.py"]
    assert lawcode.ensure_built() == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["law_dispatch.py", "oren_nayar.py"]  # no temporary left


def test_an_unwritable_package_folder_is_one_line_naming_the_file(tmp_path: Path,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "law_dispatch.py"
    monkeypatch.setattr(lawcode, "built_files", lambda: {target: "x = 1\n"})

    def refuse(*args: object, **kwargs: object) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(lawcode.tempfile, "mkstemp", refuse)
    with pytest.raises(SystemExit) as e:
        lawcode.ensure_built()
    assert str(target) in str(e.value) and "Permission denied" in str(e.value) and "\n" not in str(e.value)
    assert not target.exists()


def test_check_names_a_stale_file_and_exits_1(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture) -> None:
    table = lawcode.VIRTUAL / "law_table.py"
    files = lawcode.generated_files()
    files[table] = files[table] + "# edited\n"
    monkeypatch.setattr(lawcode, "generated_files", lambda: files)
    assert generate.main(["--check"]) == 1
    assert capsys.readouterr().out == "stale: virtual/law_table.py (run `make kernels`)\n"
    monkeypatch.undo()
    assert generate.main(["--check"]) == 0


def test_a_fresh_checkout_imports_the_kernels(tmp_path: Path) -> None:
    """Without the build products (a fresh clone, ``pip install -e .``), importing the dispatch
    and a twin writes them: the laws are copied with the modules the import reads."""
    root = tmp_path / "tree"
    kernels = root / "virtual" / "kernels"
    src = lawcode.VIRTUAL
    for f in src.rglob("*.py"):
        rel = f.relative_to(src)
        if "__pycache__" in rel.parts or lawcode.is_built(f):
            continue
        (root / "virtual" / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / "virtual" / rel).write_bytes(f.read_bytes())
    assert not (kernels / "law_dispatch.py").exists()
    env = {**os.environ, "PYTHONPATH": str(root), "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONDONTWRITEBYTECODE": "1"}
    code = "import virtual.kernels.law_dispatch as d, virtual.kernels.laws32.lambert; print(d.__file__)"
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == str(kernels / "law_dispatch.py")
    for p, text in lawcode.built_files().items():
        assert (kernels / p.relative_to(lawcode.KERNELS)).read_text() == text


def test_each_float32_twin_is_its_source_with_the_other_precision() -> None:
    """The laws' twins and the shared helpers' (ggx -> ggx32)."""
    files = lawcode.generated_files()
    pairs = [(lawcode.KERNELS / "laws" / f"{n}.py", lawcode.KERNELS / "laws32" / f"{n}.py") for n in lawcode.law_names()]
    pairs += [(lawcode.KERNELS / f"{m}.py", lawcode.KERNELS / f"{m}32.py") for m in lawcode.SHARED]
    assert lawcode.KERNELS / "ggx32.py" in files
    for src, twin in pairs:
        if twin not in files:
            continue
        name = src.stem
        law = src.read_text().splitlines()
        body = files[twin].splitlines()[1:]  # after the "generated" header
        diff = [(a, b) for a, b in zip(law, body) if a != b]
        assert len(body) == len(law) and len(diff) == 1, name
        assert diff[0][0].startswith(lawcode.PRECISION_LINE) and "precision32" in diff[0][1]


def test_the_law_table_states_every_law() -> None:
    from virtual import law_table

    assert law_table.MODEL_OREN_NAYAR == oren_nayar.MODEL
    assert set(law_table.LAW_MODELS) == {lawcode._law(n).MODEL for n in lawcode.law_names()}


@pytest.mark.parametrize("change, words", [
    ({"MODEL": 3}, "MODEL 3 is taken"),
    ({"UNIFORMS": 0}, "UNIFORMS must be an int in 1..8"),
    ({"MODEL": "9"}, "MODEL must be an int"),
])
def test_a_law_breaking_the_contract_is_refused_naming_its_file(change: dict, words: str) -> None:
    law = types.ModuleType("bad")
    for attr in ("MODEL", "TITLE", "SPECIMEN", "UNIFORMS", "FLOAT32_LIMITS", "given"):
        setattr(law, attr, getattr(oren_nayar, attr))
    law.MODEL = 99
    for k, v in change.items():
        setattr(law, k, v)
    with pytest.raises(SystemExit, match=words) as e:
        lawcode._check_law("bad", law, {3: "ggx"})
    assert "virtual/kernels/laws/bad.py" in str(e.value)


def test_the_command_refuses_a_broken_law_in_one_line_with_exit_2(monkeypatch: pytest.MonkeyPatch,
                                                                  capsys: pytest.CaptureFixture) -> None:
    """A law taking another's model id: `make kernels` says so in one line and exits 2 (bad input),
    not 1 (which --check means: stale files)."""
    def taken(*_a: object, **_k: object) -> dict:
        raise SystemExit("virtual/kernels/laws/blinn.py: MODEL 3 is taken by ggx")

    monkeypatch.setattr(generate, "generated_files", taken)
    assert generate.main([]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "laws/blinn.py: MODEL 3 is taken by ggx" in err


def test_the_kernels_package_lists_every_module() -> None:
    """virtual/kernels/__init__.py's docstring names each of its modules and packages."""
    doc = (lawcode.KERNELS / "__init__.py").read_text().split('"""')[1]
    names = {p.stem for p in lawcode.KERNELS.glob("*.py") if p.stem != "__init__"}
    names |= {p.name for p in lawcode.KERNELS.iterdir() if (p / "__init__.py").is_file()}
    assert sorted(n for n in names if f"``{n}``" not in doc) == []


def test_a_stale_or_orphaned_generated_file_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    """Power of the first test: an edited law (its twin's text differs from the file) and a twin
    whose law is gone are both reported."""
    files = lawcode.generated_files()
    twin = lawcode.KERNELS / "laws32" / "oren_nayar.py"
    edited = dict(files)
    edited[twin] = files[twin].replace("u3 * den < num", "u3 * den <= num")
    monkeypatch.setattr(lawcode, "generated_files", lambda: edited)
    assert lawcode.stale() == [twin]
    del edited[twin]
    assert lawcode.stale() == [twin]  # on disk, but no law writes it any more
