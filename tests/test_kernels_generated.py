"""The generated kernel code (:mod:`virtual.kernels.generate`: the laws' float32 twins, their
dispatch, the numba-free law table) is what ``make kernels`` writes from the laws today, and a
law that breaks the laws' contract is refused with one line naming its file."""

from __future__ import annotations

import types

import pytest

from virtual.kernels import generate
from virtual.kernels.laws import oren_nayar


def test_the_checked_in_generated_files_are_current() -> None:
    assert generate.stale() == [], "run `make kernels` (python -m virtual.kernels.generate)"


def test_each_float32_twin_is_its_law_with_the_other_precision() -> None:
    files = generate.generated_files()
    for name in generate.law_names():
        twin = generate.KERNELS / "laws32" / f"{name}.py"
        if twin not in files:
            continue
        law = (generate.KERNELS / "laws" / f"{name}.py").read_text().splitlines()
        body = files[twin].splitlines()[1:]  # after the "generated" header
        diff = [(a, b) for a, b in zip(law, body) if a != b]
        assert len(body) == len(law) and len(diff) == 1, name
        assert diff[0][0].startswith(generate.PRECISION_LINE) and "precision32" in diff[0][1]


def test_the_law_table_states_every_law() -> None:
    from virtual import law_table

    assert law_table.MODEL_OREN_NAYAR == oren_nayar.MODEL
    assert set(law_table.LAW_MODELS) == {generate._law(n).MODEL for n in generate.law_names()}


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
        generate._check_law("bad", law, {3: "ggx"})
    assert "virtual/kernels/laws/bad.py" in str(e.value)


def test_the_kernels_package_lists_every_module() -> None:
    """virtual/kernels/__init__.py's docstring names each of its modules and packages."""
    doc = (generate.KERNELS / "__init__.py").read_text().split('"""')[1]
    names = {p.stem for p in generate.KERNELS.glob("*.py") if p.stem != "__init__"}
    names |= {p.name for p in generate.KERNELS.iterdir() if (p / "__init__.py").is_file()}
    assert sorted(n for n in names if f"``{n}``" not in doc) == []


def test_a_stale_or_orphaned_generated_file_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    """Power of the first test: an edited law (its twin's text differs from the file) and a twin
    whose law is gone are both reported."""
    files = generate.generated_files()
    twin = generate.KERNELS / "laws32" / "oren_nayar.py"
    edited = dict(files)
    edited[twin] = files[twin].replace("u3 * den < num", "u3 * den <= num")
    monkeypatch.setattr(generate, "generated_files", lambda: edited)
    assert generate.stale() == [twin]
    del edited[twin]
    assert generate.stale() == [twin]  # on disk, but no law writes it any more
