"""One bench description, three bodies; the virtual body refuses what the
real body refuses (same rule names, same geometries) and times a plan with the same motion
profiles; refusals list a few points and say how many more; ``unreachable = "skip"``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.cli import main
from bench.config import load_bench
from bench.core.errors import GeometryError, PlanError
from bench.core.parsing import read_toml
from bench.core.geometry import Geometry
from bench.plans import load_plan, plan_from_dict, validate
from bench.runner import run_scan
from bench.store import RunStore

ROOT = Path(__file__).parent.parent
EMULATED = ROOT / "fixtures" / "benches" / "emulated.toml"
VIRTUAL = ROOT / "fixtures" / "benches" / "virtual.toml"
PLANS = sorted((ROOT / "fixtures" / "plans").glob("*.toml"))
KEYS = ("points", "refused", "seconds", "motion_s")


def _plan_json(plan: Path, body: str, capsys, bench: Path = EMULATED) -> tuple[int, dict]:
    capsys.readouterr()
    code = main(["plan", str(plan), "--bench", str(bench), "--body", body, "--json"])
    return code, json.loads(capsys.readouterr().out)


@pytest.mark.hil
@pytest.mark.parametrize("plan", PLANS, ids=[p.stem for p in PLANS])
def test_shipped_plans_are_refused_or_timed_identically_on_every_body(plan, capsys):
    """Same exit, same refusals (geometry, rule, message), same seconds and motion on the
    virtual body as on the emulated body (real drivers over the emulators) of one description,
    and on the shipped virtual description (the emulated bench's twin)."""
    virtual_code, virtual = _plan_json(plan, "virtual", capsys)
    emulated_code, emulated = _plan_json(plan, "emulated", capsys)
    twin_code, twin = _plan_json(plan, "virtual", capsys, bench=VIRTUAL)
    assert virtual["bench_kind"] == "virtual" and emulated["bench_kind"] == "emulated"
    assert virtual_code == emulated_code == twin_code
    for key in KEYS:
        assert virtual[key] == emulated[key] == twin[key], key
    assert virtual["motion_s"] > 0  # the virtual body has a time model, not 0 s of motion


def test_shipped_virtual_description_is_the_emulated_benchs_twin():
    """fixtures/benches/virtual.toml declares the emulated bench's arm, kinematics and motion:
    every body of either file applies the same rules and time model (the emulated body's are
    computed here from the description, without starting emulators)."""
    from bench.builders.emulated import emulated_arm_config, emulated_motion
    from bench.builders.twin import physical_rules
    from drivers.dynamixel import ArmConfig

    virtual, emulated = read_toml(VIRTUAL), read_toml(EMULATED)
    assert virtual["kind"] == "virtual" and "arm" in virtual
    rules = {name: physical_rules(d) for name, d in (("virtual", virtual), ("emulated", emulated))}
    assert rules["virtual"] == rules["emulated"]
    for d in (virtual, emulated):  # the emulated body of each file
        assert ArmConfig.from_dict(emulated_arm_config(d, "")).kinematics == rules["emulated"].kinematics
        assert emulated_motion(d) == rules["emulated"].motion


def test_hemispherical_refusal_names_rules_and_counts(capsys):
    code, out = _plan_json(ROOT / "fixtures" / "plans" / "hemispherical.toml", "virtual", capsys)
    assert code == 2 and out["points"] == 122 and len(out["refused"]) == 8
    assert _plan_json(ROOT / "fixtures" / "plans" / "hemispherical.toml", "virtual", capsys, VIRTUAL) == (code, {
        **out, "bench": "virtual"})  # the shipped virtual description refuses the same 8
    assert {r["rule"] for r in out["refused"]} == {"beam_block", "arm_collision"}
    assert set(out["refused"][0]) == {"index", "theta_i", "phi_i", "theta_r", "phi_r", "rule", "message"}
    assert main(["plan", str(ROOT / "fixtures" / "plans" / "hemispherical.toml"), "--bench", str(EMULATED),
                 "--body", "virtual"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and len(err) < 700
    assert err.count("point ") == 3 and "and 5 more (bench plan --json lists them all)" in err


def test_virtual_body_moves_refuse_like_the_arm():
    """Not only plans: a move the arm refuses (a Bluesky scan through the beam) is refused on the
    virtual body too, with the same rule name (the shipped virtual description included); a
    plain virtual description (no [arm], no [emulated]) stays ideal."""
    for description in (EMULATED, VIRTUAL):
        with load_bench(description, body="virtual") as bench:
            with pytest.raises(GeometryError, match="^beam_block"):
                bench.goniometer.move_to(Geometry(30, 0, 30, 0))
            bench.goniometer.move_to(Geometry(30, 0, 20, 180))
    plain = {k: v for k, v in read_toml(VIRTUAL).items() if k not in ("arm", "emulated", "turntable")}
    with load_bench(plain) as bench:
        bench.goniometer.check(Geometry(30, 0, 30, 0))
        assert bench.motion is None


def test_unreachable_skip_measures_the_rest_and_records_the_skipped(tmp_path):
    table = {"name": "skip", "kind": "hemispherical", "integration_s": 0.02, "dark": "once",
             "hemispherical": {"theta_i": [20], "theta_r": [15, 30, 45], "phi_r": [0, 90, 180]}}
    with load_bench(EMULATED, body="virtual") as bench, RunStore(tmp_path / "s.sqlite") as store:
        with pytest.raises(PlanError, match=r"3 of 9 points .*arm_collision, beam_block"):
            validate(plan_from_dict(table), bench.goniometer.check)
        res = run_scan(bench, plan_from_dict({**table, "unreachable": "skip"}), store)
        info, summary = store.run(res.run_id), store.summary(res.run_id)
    assert res.status == "completed" and res.points_done == res.points_planned == 6
    skipped = info["meta"]["skipped"]
    assert [(s["theta_r"], s["phi_r"], s["rule"]) for s in skipped] == [
        (15.0, 0.0, "beam_block"), (30.0, 0.0, "arm_collision"), (45.0, 0.0, "arm_collision")]
    assert summary["points_missing"] == 0


def test_body_option_is_on_every_command_taking_bench(capsys):
    for cmd in (["plan", "P"], ["scan", "P"], ["resume", "R"], ["white", "--out", "w.csv"], ["home"]):
        assert main([*cmd, "--help"]) == 0
        assert "--body {virtual,emulated,real}" in " ".join(capsys.readouterr().out.split())


def test_shipped_plans_load():
    assert all(load_plan(p).points for p in PLANS)
