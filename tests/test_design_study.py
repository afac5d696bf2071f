"""Accuracy per bench-minute (`bench tradeoff --design`, bench.identify.design_study): the rows and
the figure from a study's results, the truth of the bench's specimen, the command's JSON and plot on
the virtual body (one seed, two methods), and its one-line refusals (exit 2)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from bench.cli import main
from bench.core.errors import InputError
from bench.core.parsing import read_toml
from bench.identify import design_study
from bench.identify.model_spec import parse_model_spec

BENCHES = Path(__file__).resolve().parent.parent / "fixtures" / "benches"
MODEL = "plastic:alpha=?,kd=?"


def _bench_file(tmp_path: Path, spec: str = "plastic:alpha=0.15,kd=0.5", source: list[float] | None = None) -> Path:
    """The shipped virtual bench holding ``spec``; ``source`` narrows the source arm's limits."""
    import tomli_w

    d = copy.deepcopy(read_toml(BENCHES / "virtual.toml", "bench config"))
    d["specimen"]["spec"] = spec
    if source is not None:
        d["arm"]["kinematics"]["limits"]["source"] = source
    path = tmp_path / "bench.toml"
    path.write_bytes(tomli_w.dumps(d).encode())
    return path


def _study(fits: dict[str, list[tuple[float, dict[str, tuple[float, float, float]]]]],
           truth: dict[str, float] | None) -> dict:
    """A study's results as measure() returns them, from (seconds, fit) per seed per method."""
    return {"model": MODEL, "specimen": "plastic:alpha=0.15,kd=0.5", "truth": truth, "parameters": ["alpha", "kd"],
            "units": ["1", "1"], "prior": {"alpha": 0.1, "kd": 0.5}, "bench": "virtual", "body": "virtual",
            "seeds": [7, 8, 9], "cpu": {"model": "test CPU"}, "designs": {},
            "results": {name: [{"seed": 7 + k, "seconds": s, "fit": f} for k, (s, f) in enumerate(runs)]
                        for name, runs in fits.items()}}


def _fit(alpha: tuple[float, float], kd: tuple[float, float]) -> dict[str, tuple[float, float, float]]:
    return {"alpha": (sum(alpha) / 2, *alpha), "kd": (sum(kd) / 2, *kd)}


FITS = {"uniform in-plane": [(60.0, _fit((0.14, 0.16), (0.4, 0.6))), (60.0, _fit((0.145, 0.175), (0.45, 0.55))),
                             (60.0, _fit((0.10, 0.14), (0.48, 0.52)))],
        "sequential": [(50.0, _fit((0.149, 0.151), (0.49, 0.51))), (58.0, _fit((0.148, 0.154), (0.3, 0.9))),
                       (54.0, _fit((0.148, 0.152), (0.4, 0.5)))]}


def test_rows_take_median_and_range_over_seeds_and_count_truth_hits():
    m = _study(FITS, {"alpha": 0.15, "kd": 0.5})
    by = {r["method"]: r for r in design_study.rows(m)}
    u, s = by["uniform in-plane"], by["sequential"]
    assert u["widths"]["alpha"] == pytest.approx({"median": 0.03, "min": 0.02, "max": 0.04})
    assert s["seconds"] == 54.0 and s["seconds_min"] == 50.0 and s["seconds_max"] == 58.0
    assert s["widths"]["kd"] == pytest.approx({"median": 0.1, "min": 0.02, "max": 0.6})
    assert s["ratio_to_uniform"]["alpha"] == pytest.approx(0.004 / 0.03)
    assert u["ratio_to_uniform"]["kd"] == pytest.approx(1.0)
    # uniform seed 9's alpha interval [0.10, 0.14] misses 0.15; sequential seed 9's kd [0.4, 0.5] holds 0.5
    assert u["truth_in"] == {"alpha": 2, "kd": 3} and s["truth_in"] == {"alpha": 3, "kd": 3}
    table = design_study.summary(m)
    assert table[1][:5] == ["sequential", 54.0, "0.004 [0.002, 0.006]", "0.13", "3/3"]
    assert len(design_study.header(m)) == len(table[0]) == 2 + 3 * 2


def test_unknown_truth_says_n_a():
    m = _study(FITS, None)
    assert all(v is None for r in design_study.rows(m) for v in r["truth_in"].values())
    assert design_study.summary(m)[0][4] == "n/a" and "truth unknown" in design_study.describe(m)


def test_truth_is_the_specimen_of_the_model_family_else_none():
    spec = parse_model_spec(MODEL)
    assert design_study.truth_of(spec, "plastic:alpha=0.15,kd=0.5") == pytest.approx({"alpha": 0.15, "kd": 0.5})
    assert design_study.truth_of(spec, "lambert:albedo=0.8") is None
    assert design_study.truth_of(parse_model_spec("lambert:albedo=?"), "lambert:albedo=0.8") == {"reflectance": 0.8}


@pytest.mark.slow  # every method's scans and fits for the figure (9 s under load)
def test_plot_has_one_panel_per_parameter_with_every_method(tmp_path):
    png = tmp_path / "study.png"
    fig = design_study.plot_study(_study(FITS, {"alpha": 0.15, "kd": 0.5}), png)
    axes = [ax for ax in fig.axes if ax.get_xlabel()]
    assert len(axes) == 2 and png.stat().st_size > 10_000
    assert all("(min)" in ax.get_xlabel() and "95 % interval width" in ax.get_ylabel() for ax in axes)
    assert [len(ax.containers) for ax in axes] == [2, 2]  # one errorbar per method
    # alpha's widths span 0.002..0.04 (x20): log; kd's too (0.02..0.6); a narrow span stays linear
    assert [ax.get_yscale() for ax in axes] == ["log", "log"]
    narrow = {k: [(s, _fit((0.14, 0.16), (0.4, 0.6))) for s, _ in v] for k, v in FITS.items()}
    fig = design_study.plot_study(_study(narrow, None), tmp_path / "narrow.png")
    assert [ax.get_yscale() for ax in fig.axes if ax.get_xlabel()] == ["linear", "linear"]
    assert "test CPU" in fig._suptitle.get_text() and "seeds 7,8,9" in fig._suptitle.get_text()


def test_methods_parse_and_must_include_the_uniform_plan():
    assert design_study.parse_methods(None) == tuple(design_study.METHODS)
    assert design_study.parse_methods("sequential,uniform") == ("uniform", "sequential")
    for bad in ("designed", "uniform,nope", ","):
        with pytest.raises(InputError):
            design_study.parse_methods(bad)
    with pytest.raises(InputError, match="at least 1 seed"):
        design_study.measure(MODEL, {}, seeds=[])


# ~8 CPU-s: two scans and fits on the virtual body (exact fast path), one seed
@pytest.mark.slow  # a study of two plans on one seed, scanned and fitted (24-39 s under load)
def test_cli_json_and_plot_on_the_virtual_body(tmp_path, capsys):
    bench = _bench_file(tmp_path)
    png = tmp_path / "design.png"
    assert main(["tradeoff", "--design", MODEL, "--bench", str(bench), "--seeds", "7", "--methods",
                 "uniform,uniform-half", "--json", "--plot", str(png)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"model", "truth", "bench", "body", "seeds", "cpu", "rows", "prior", "specimen", "designs"} <= set(out)
    assert out["body"] == "virtual" and out["seeds"] == [7] and out["truth"] == pytest.approx({"alpha": 0.15, "kd": 0.5})
    assert [r["method"] for r in out["rows"]] == ["uniform in-plane", "uniform, 10 deg"]
    for r in out["rows"]:
        assert {"seconds", "seconds_min", "seconds_max", "widths", "ratio_to_uniform", "truth_in"} <= set(r)
        assert set(r["widths"]) == {"alpha", "kd"} and all(w["median"] > 0 for w in r["widths"].values())
    half, full = out["rows"][1], out["rows"][0]
    assert half["seconds"] < 0.75 * full["seconds"]  # half the theta_r points: well under the full plan's time
    assert full["ratio_to_uniform"] == {"alpha": 1.0, "kd": 1.0}
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("argv, says", [
    (["--design", MODEL, "x.toml"], "not both"),
    ([], "give SCENE.toml"),
    (["--design", MODEL], "needs --bench"),
    (["--design", MODEL, "--bench", "B", "--rays", "100"], "--rays applies to SCENE.toml"),
    (["--design", MODEL, "--bench", "B", "--no-costs"], "--no-costs applies"),
    (["scene.toml", "--seeds", "7"], "--seeds applies to --design"),
    (["--design", "nosuch:a=?", "--bench", "BENCH"], "unknown family"),
    (["--design", "plastic:alpha=0.2", "--bench", "BENCH"], "no free parameter"),
    (["--design", MODEL, "--bench", "BENCH", "--methods", "designed"], "must include uniform"),
    (["--design", MODEL, "--bench", "BENCH", "--prior", "eta=1.4"], "not a free parameter"),
])
def test_cli_refuses_bad_input_in_one_line(tmp_path, capsys, argv, says):
    bench = str(_bench_file(tmp_path))
    assert main(["tradeoff", *[bench if a == "BENCH" else a for a in argv]]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "\n" not in err


def test_cli_refuses_no_seed_and_a_bench_that_refuses_the_uniform_plan(tmp_path, capsys):
    bench = _bench_file(tmp_path, source=[0.0, 40.0])  # the source arm cannot reach theta_i 45 and 60
    assert main(["tradeoff", "--design", MODEL, "--bench", str(bench), "--seeds", "7", "--methods", "uniform"]) == 2
    err = capsys.readouterr().err.strip()
    assert "refuses the uniform plan" in err and "\n" not in err
    assert main(["tradeoff", "--design", MODEL, "--bench", str(bench), "--seeds", ","]) == 2  # argparse: no seed
    assert "expected 1 to 50 comma-separated integers" in capsys.readouterr().err


@pytest.mark.slow  # the full study on the emulated body: 18 scans, 24 fits, ~170 CPU-s
def test_full_study_on_the_emulated_body(tmp_path):
    """Every method on seeds 7, 8, 9 (as `python -m benchmarks design`). Half the uniform plan's
    theta_r points widen both intervals by about sqrt(63/33) = 1.38 (accepted 1.2..1.6); the
    uniform plan's 95 % intervals hold the truth in at least 2 of 3 seeds for each parameter (false
    alarm 1 - 0.95^3 - 3 * 0.95^2 * 0.05 = 0.7 % per parameter if the intervals are honest); power:
    a truth moved by 0.2 % of its value (alpha 0.1503, over 5 interval widths) is held in none.
    The designed-plan targets, measured here and in docs/design.md: the D-optimal design at most 0.7x the
    uniform plan's widths in its time, narrower than it in half that time, the sequential design
    at least as good as the one-shot one, each holding the truth in at least 2 of 3 seeds (a
    design for a diagonal covariance, the earlier default, was 2.6x wider: that is the power)."""
    d = copy.deepcopy(read_toml(BENCHES / "emulated.toml", "bench config"))
    d["specimen"]["spec"] = "plastic:alpha=0.15,kd=0.5"
    m = design_study.measure(MODEL, d)
    assert m["body"] == "emulated" and m["seeds"] == [7, 8, 9]
    by = {r["method"]: r for r in design_study.rows(m)}
    assert list(by) == list(design_study.METHODS.values()) and all(r["seeds"] == 3 for r in by.values())
    assert all(1.2 < by["uniform, 10 deg"]["ratio_to_uniform"][p] < 1.6 for p in ("alpha", "kd"))
    assert all(by["uniform in-plane"]["truth_in"][p] >= 2 for p in ("alpha", "kd"))
    for p in ("alpha", "kd"):
        assert by["designed"]["ratio_to_uniform"][p] <= 0.7, by["designed"]
        assert by["designed, half time"]["ratio_to_uniform"][p] < 1.0, by["designed, half time"]
        assert by["sequential"]["ratio_to_uniform"][p] <= by["designed"]["ratio_to_uniform"][p], by["sequential"]
        assert all(by[k]["truth_in"][p] >= 2 for k in ("designed", "designed, half time", "sequential"))
    moved = design_study.rows({**m, "truth": {"alpha": 0.15 * 1.002, "kd": 0.5 * 1.002}})
    assert moved[0]["method"] == "uniform in-plane" and moved[0]["truth_in"] == {"alpha": 0, "kd": 0}
    fig = design_study.plot_study(m, tmp_path / "study.png")
    assert len([ax for ax in fig.axes if ax.get_xlabel()]) == 2
    assert all(len(ax.containers) == 6 for ax in fig.axes if ax.get_xlabel())
