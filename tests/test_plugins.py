"""A lab's package extends goniobench through entry points (bench.core.plugins): its specimen
family and record format reach the CLI, TOML files and Dask workers without an edit to ours.

In-process cases put the lab's package (fixtures/plugins/goniobench-labvelvet) and a
distribution's metadata declaring its entry points on ``sys.path``; the acceptance case installs
the package with pip into a throw-away venv and runs ``bench`` and a two-worker Dask sweep there.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.cli import main
from bench.core import plugins, schemas
from bench.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
LAB = ROOT / "fixtures" / "plugins" / "goniobench-labvelvet"
SWEEP = """\
[sweep]
name = "velvet-on-dask"
seed = 20261202
instrument = "gonio"
specimens = ["velvet:retro=0.25,albedo=0.6", "lambert:albedo=0.5"]
incidences = [0, 30]
collectors = ["equal-psa:3x6"]
wavelengths = 550
rays = 20000
"""


def _declare(site: Path, entry_points: str) -> None:
    """A distribution's metadata in ``site`` declaring ``entry_points`` (entry_points.txt)."""
    info = site / "goniobench_labvelvet-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: goniobench-labvelvet\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text(entry_points)


@pytest.fixture
def lab(tmp_path, monkeypatch):
    """The lab's package importable and declared; the registries as they were afterwards."""
    from bench.io import registry
    from virtual.specimens import declare

    _declare(tmp_path / "site", "[goniobench.specimens]\nvelvet = labvelvet:Velvet\n\n"
                                "[goniobench.formats]\nlabjson = labvelvet:LAB_JSON\n\n"
                                "[goniobench.effects]\nveiling = labvelvet.effects:Veiling\n")
    monkeypatch.syspath_prepend(str(LAB))
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setattr(plugins, "_LOADED", set())
    yield tmp_path
    declare._REGISTRY.pop("velvet", None)
    registry._REGISTRY.pop("labjson", None)
    schemas._PLUGIN_EFFECTS.pop("veiling", None)
    sys.modules.pop("labvelvet", None)
    sys.modules.pop("labvelvet.effects", None)


def test_an_installed_family_and_format_are_found_by_name_and_listed(lab, capsys):
    from bench.io.registry import default_suffix, formats
    from virtual.specimens import known_specimen_names, parse_specimen

    s = parse_specimen("velvet:retro=0.25,albedo=0.6")  # a miss in the registry loads the plugins
    assert type(s).__module__ == "labvelvet" and s.params(550.0).tolist() == [0.25, 0.6]
    assert "velvet" in known_specimen_names()
    assert "labjson" in formats(writable=True) and default_suffix("labjson") == ".lab.jsonl"
    assert main(["specimens", "--json"]) == 0
    assert "velvet" in {f["name"] for f in json.loads(capsys.readouterr().out)}
    assert main(["export", "--help"]) == 0  # bench export offers the registry's writers
    assert "labjson" in capsys.readouterr().out


def test_toml_files_name_an_installed_family(lab):
    from bench.sweep import sweep_from_dict
    from virtual.scene import scene_from_dict

    import tomllib

    spec = sweep_from_dict(tomllib.loads(SWEEP))
    assert {t.specimen for t in spec.tasks} == {"velvet:retro=0.25,albedo=0.6", "lambert:albedo=0.5"}
    scene = scene_from_dict({"specimen": "velvet:albedo=0.7"})
    assert scene.specimen.params(550.0).tolist() == [0.5, 0.7]


def test_a_scene_file_declares_an_installed_effect(lab, tmp_path):
    from virtual.scene import load_scene

    scene = tmp_path / "veiled.toml"
    base = 'specimen = "lambert:reflectance=0.6"\nrays = 20000\nseed = 3\n'
    scene.write_text(base + "[effects.veiling]\nlevel = 0.01\n")
    veiled = load_scene(scene)
    assert veiled.effects.declared() == ["veiling"]
    plain = veiled.with_effects(veiled.effects.only())
    r, r0 = veiled.run(), plain.run()
    assert np.array_equal(r.values, r0.values + 0.01) and np.array_equal(r.ci, r0.ci + 0.01)
    (ref, exact), (ref0, exact0) = veiled.reference(), plain.reference()
    assert exact and exact0 and np.array_equal(ref, ref0 + 0.01)
    scene.write_text(base + "[effects.veiling]\nlevel = 0.5\n")
    with pytest.raises(ConfigError, match=rf"^scene file {scene}: key effects.veiling.level: .*0.1 .got 0.5.$"):
        load_scene(scene)
    scene.write_text(base + "[effects.veiling]\nlevle = 0.01\n")
    with pytest.raises(ConfigError, match=r"unknown key 'effects.veiling.levle'; did you mean 'level'\?"):
        load_scene(scene)


def test_a_broken_plugin_is_one_line_naming_its_entry_point(tmp_path, monkeypatch, capsys):
    from virtual.specimens import parse_specimen

    _declare(tmp_path / "site", "[goniobench.specimens]\nsatin = labsatin:Satin\n")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setattr(plugins, "_LOADED", set())
    with pytest.raises(ConfigError, match=r"^entry point satin = 'labsatin:Satin' in group goniobench.specimens: "
                                          r"cannot load it \(ModuleNotFoundError"):
        parse_specimen("satin:sheen=1")
    assert main(["specimens"]) == 2
    err = capsys.readouterr().err
    assert "entry point satin" in err and len(err.strip().splitlines()) == 1


def test_a_plugin_may_not_take_a_builtin_name(tmp_path, monkeypatch):
    from virtual.specimens import specimen_families

    _declare(tmp_path / "site", "[goniobench.specimens]\nlambert = labvelvet:Velvet\n")
    (tmp_path / "pkg" / "labvelvet").mkdir(parents=True)
    (tmp_path / "pkg" / "labvelvet" / "__init__.py").write_text(
        "from virtual import MODEL_PYTHON, DeclaredSpecimen\n"
        "class Velvet(DeclaredSpecimen):\n    name = 'lambert'\n    model = MODEL_PYTHON\n")
    monkeypatch.syspath_prepend(str(tmp_path / "pkg"))
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setattr(plugins, "_LOADED", set())
    try:
        with pytest.raises(ConfigError, match="entry point lambert .* already taken"):
            specimen_families()
    finally:
        sys.modules.pop("labvelvet", None)


# --- acceptance: pip-installed into a venv, seen by bench and by Dask workers ----------------------


def _venv_with_the_lab_package(tmp_path: Path) -> Path:
    """A throw-away venv seeing this interpreter's packages, with the lab's package pip-installed
    (no network: no dependencies, no build isolation; setuptools and wheel come from the
    project's test extra). Returns its python."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(venv)], check=True)
    py = venv / "bin" / "python"
    site = Path(subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    # this interpreter may itself be a venv (the project's): its packages are the "system" ones here
    ours = dict.fromkeys([sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]])
    (site / "goniobench-base.pth").write_text("\n".join(ours) + "\n")
    src = shutil.copytree(LAB, tmp_path / "labvelvet-src")  # pip builds in the tree: keep ours clean
    built = subprocess.run([py, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", "-q",
                            str(src)], capture_output=True, text=True)
    if built.returncode != 0 and "bdist_wheel" in built.stderr:
        pytest.skip("building the lab's package needs the 'wheel' package (the test extra: make install)")
    assert built.returncode == 0, built.stderr
    return py


def _bench(py: Path, *argv: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([py, "-m", "bench.cli", *argv], capture_output=True, text=True, env=env, cwd=cwd,
                          timeout=600)


@pytest.mark.slow
def test_a_pip_installed_lab_package_is_listed_and_runs_in_a_sweep_on_dask_workers(tmp_path):
    py = _venv_with_the_lab_package(tmp_path)
    listed = _bench(py, "specimens", cwd=tmp_path)
    assert listed.returncode == 0, listed.stderr
    lines = listed.stdout.splitlines()  # one block per family: "name: convention", then its parameters
    assert any(line.startswith("velvet: ") for line in lines), listed.stdout
    assert any(line.startswith("  retro: 0 .. 1, default 0.5") for line in lines), listed.stdout

    (tmp_path / "velvet.toml").write_text(SWEEP)
    runs = {}
    for where in (["--workers", "2"], []):  # two Dask worker processes, then in-process
        r = _bench(py, "sweep", "velvet.toml", *where, "--store", "s.sqlite", "--json", "-q", cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        d = json.loads(r.stdout)
        assert d["tasks_done"] == d["tasks_planned"] == 4
        runs[d["executor"]] = d["run_id"]
    assert set(runs) == {"dask", "in-process"}

    from bench.store import RunStore
    from bench.sweep import sweep_readings

    with RunStore(tmp_path / "s.sqlite") as store:
        dask = sweep_readings(store, runs["dask"])
        same = [store.readings(runs[k]).drop(columns=["t_start", "t_end"]) for k in ("dask", "in-process")]
    velvet = dask[dask["specimen"] == "velvet:retro=0.25,albedo=0.6"]
    assert len(velvet) > 0 and velvet["worker"].str.startswith("tcp://").all()
    # the workers ran the lab's model with the string's parameters: every surviving ray leaves
    # upward, so the reflected fraction is albedo = 0.6 (5 binomial standard errors: a false alarm
    # below 1e-6 per incidence; the family's default albedo 0.8 lies 57 of them away)
    for _, series in velvet.groupby("theta_i"):
        up = series[series["hemisphere"] == "R"]
        n = int(series["N"].iloc[0])
        assert abs(up["count"].sum() / n - 0.6) < 5 * math.sqrt(0.6 * 0.4 / n)
    a, b = (t.sort_values(list(t.columns)).reset_index(drop=True) for t in same)
    pd.testing.assert_frame_equal(a, b, check_exact=True)  # the workers counted what one process counts

    exported = _bench(py, "export", runs["dask"], "--store", "s.sqlite", "--format", "labjson", cwd=tmp_path)
    assert exported.returncode == 0, exported.stderr
    paths = exported.stdout.split()  # a two-specimen sweep: one file per specimen
    assert len(paths) == 2 and any("velvet" in p for p in paths), paths
    lines = [line for p in paths for line in Path(tmp_path / p).read_text().splitlines()]
    assert len(lines) == len(dask) and {"value", "count", "N"} <= set(json.loads(lines[0]))
