"""Fuzzing the boundaries: Hypothesis generates malformed CLI argument vectors, plan
files, bench configs, sweeps and run ids, runs ``bench`` (``bench.cli.main``) in a guarded child
process, and asserts the policy: exit 2 for bad input (1 only for a run that failed on its own), ONE line on
stderr, never a traceback, never a hang, and no store changed (hashed).

The hang guard: the cases run in one long-lived child process (tests/helpers/cli.py
GuardedWorker), which is killed when a case outlives CASE_SECONDS -- a signal alarm cannot
interrupt compiled numba code, a killed process always stops. About 800 cases per run; the whole
file takes well under a minute.
"""

from __future__ import annotations

import hashlib
import sqlite3
from contextlib import closing
import tomllib
from pathlib import Path

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.core.errors import ConfigError, InputError
from tests.helpers.cli import GuardedWorker

ROOT = Path(__file__).resolve().parents[1]
FIX = ROOT / "fixtures"
VIRTUAL = str(FIX / "benches" / "virtual.toml")
CASE_SECONDS = 30  # a case that runs longer is a hang
FUZZ = settings(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                        HealthCheck.too_slow], derandomize=True)

TALLY: dict[str, dict[str, int]] = {}


WORKER = GuardedWorker(CASE_SECONDS)


@pytest.fixture(scope="module", autouse=True)
def _stop_the_worker():
    yield
    WORKER.close()


def bench(*argv: object) -> tuple[int, str, str]:
    """``bench ARGV`` in the guarded child, with captured stdout/stderr."""
    return WORKER.bench(*argv)


def sweep_outcome(path: str) -> tuple[str, object]:
    """``load_sweep(path)`` as ``bench sweep`` loads it: ("accepted", number of tasks) or
    ("refused", message) -- run in the guarded child."""
    from bench.sweep import load_sweep

    try:
        return "accepted", len(load_sweep(path))
    except (ConfigError, InputError) as exc:
        return "refused", str(exc)


def check_policy(code: int, err: str, allowed: tuple[int, ...], family: str) -> None:
    t = TALLY.setdefault(family, {"cases": 0, "refused": 0, "accepted": 0})
    t["cases"] += 1
    t["accepted" if code == 0 else "refused"] += 1
    assert "Traceback" not in err, err
    assert code in allowed, (code, err)
    if code != 0:
        assert err.count("\n") == 1 and err.startswith("bench"), err


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()




# --- 1. argument vectors with a bad value in one option: always exit 2 -------------------------------

NON_FINITE = st.sampled_from(["nan", "NaN", "inf", "-inf", "1e400", "-1e400", "Infinity"])
GARBAGE = st.sampled_from(["", " ", "abc", "1..2", "--", "0x1g", "1,", ",", "1e", "\udcff", "½", "1_0_", "5 5"])


def _num_outside(lo: float, hi: float):
    return st.one_of(st.floats(max_value=lo, exclude_max=False, allow_nan=False, allow_infinity=False),
                     st.floats(min_value=hi, allow_nan=False, allow_infinity=False, exclude_min=True)
                     ).map(lambda v: f"{v!r}")


def _int_outside(lo: int, hi: int):
    return st.one_of(st.integers(max_value=lo - 1), st.integers(min_value=hi + 1, max_value=10**40)).map(str)


FRACTION_BAD = st.one_of(NON_FINITE, GARBAGE, _num_outside(0.0, 1.0).filter(lambda s: float(s) <= 0 or float(s) >= 1))
SEED_BAD = st.one_of(NON_FINITE, GARBAGE, _int_outside(0, 2**63 - 1), st.sampled_from(["1.5", "-0.5", "1e19"]))
RAYS_BAD = st.one_of(NON_FINITE, GARBAGE, _int_outside(1, 10**15), st.sampled_from(["2.5", "1e16", "-3"]))
POSITIVE_BAD = st.one_of(NON_FINITE, GARBAGE, st.floats(max_value=0, allow_nan=False, allow_infinity=False).map(repr))
WAVELENGTHS_BAD = st.one_of(NON_FINITE, GARBAGE.filter(lambda s: s not in ("1,",)),
                            st.sampled_from(["400:700:1e-9", "400:700", "700:400:10", "0", "-5", "1:2:3:4", "400:nan:10",
                                             ",".join(["500"] * 10001), "400:700:0"]))
INCIDENCE_BAD = st.one_of(NON_FINITE, GARBAGE, st.sampled_from(["30,nan", "91", "-1", "30,400", "1,2,3", "30,inf"]),
                          _num_outside(0.0, 90.0).filter(lambda s: not 0 <= float(s) <= 90))
COLLECTOR_BAD = st.one_of(GARBAGE, st.sampled_from(["equal-psa:100000x100000", "equal-psa:0x9", "equal-psa:9",
                                                    "9x36", "equal-psa:1001x1000", "equal-psa:-1x3"]),
                          st.tuples(st.integers(1001, 10**6), st.integers(1001, 10**6)).map(
                              lambda t: f"equal-psa:{t[0]}x{t[1]}"))

GONIO = ["gonio", "--specimen", "lambert:albedo=0.5"]
SPECTRO = ["spectro", "--specimen", "lambert:reflectance=0.5"]
CASES = [
    (GONIO, "--rays", RAYS_BAD), (GONIO, "--seed", SEED_BAD), (GONIO, "--incidence", INCIDENCE_BAD),
    (GONIO, "--max-seconds", POSITIVE_BAD), (GONIO, "--delta", FRACTION_BAD), (GONIO, "--relative-uncertainty", FRACTION_BAD),
    (GONIO, "--wavelengths", WAVELENGTHS_BAD), (GONIO, "--collector", COLLECTOR_BAD),
    (SPECTRO, "--rays", RAYS_BAD), (SPECTRO, "--seed", SEED_BAD), (SPECTRO, "--wavelengths", WAVELENGTHS_BAD),
    (SPECTRO, "--max-seconds", POSITIVE_BAD), (SPECTRO, "--delta", FRACTION_BAD),
    (["rays", "-d", "0.01"], "-u", FRACTION_BAD), (["rays", "-u", "0.01"], "-d", FRACTION_BAD),
    (["rays", "-u", "0.01", "-d", "0.01"], "--patches", _int_outside(1, 1_000_000)),
    (["tradeoff", str(FIX / "scenes" / "lambert-bare.toml")], "--repeats", _int_outside(1, 1000)),
    (["tradeoff", str(FIX / "scenes" / "lambert-bare.toml")], "--seed", SEED_BAD),
    (["tradeoff", str(FIX / "scenes" / "lambert-bare.toml")], "--rays", st.one_of(NON_FINITE, GARBAGE.filter(
        lambda s: s.strip(", ") != "" and s != "1,"), st.sampled_from(["0", "1,-2", "1e13", "5,nan"]))),
    (["emulate", str(FIX / "benches" / "emulated.toml")], "--max-seconds",
     st.one_of(NON_FINITE, GARBAGE, st.floats(max_value=-1e-9, allow_infinity=False).map(repr))),
    (["emulate", str(FIX / "benches" / "emulated.toml")], "--seed", SEED_BAD),
    (["sweep", str(FIX / "sweeps" / "gonio-tasks.toml")], "--scheduler",
     st.one_of(GARBAGE, st.sampled_from(["not a url", "tcp://", "http://x:1", "tcp://host", "tcp://h:99999"]))),
    (["sweep", str(FIX / "sweeps" / "gonio-tasks.toml")], "--workers", _int_outside(1, 1024)),
    (["demo"], "--seed", SEED_BAD),
    (["export", "r1"], "--wavelength", POSITIVE_BAD),
]


@pytest.mark.slow  # 300 fuzzed command lines (12 s under load)
@settings(FUZZ, max_examples=300)
@given(case=st.sampled_from(range(len(CASES))), data=st.data())
def test_a_bad_value_in_any_option_exits_2_naming_it(case, data):
    base, option, values = CASES[case]
    value = data.draw(values, label=option)
    code, out, err = bench(*base, f"{option}={value}")
    check_policy(code, err, (2,), "bad option values")
    assert out == ""


# --- 2. arbitrary argument vectors on the cheap commands: never a traceback ----------------------------

TOKENS = st.one_of(st.sampled_from(["rays", "runs", "show", "export", "plan", "-u", "-d", "--patches", "--json",
                                    "--store", "--format", "--out", "--wavelength", "--bench", "--rate", "zemax",
                                    "csv", "0.01", "0.5", "2", "-1", "nan", "1e400", "--", "-v", "--help-me"]),
                   st.text(max_size=8))


@settings(FUZZ, max_examples=150)
@given(argv=st.lists(TOKENS, min_size=1, max_size=6))
def test_arbitrary_argument_vectors_never_trace(tmp_path, scanned_store, argv):
    db, _, _ = scanned_store
    before = digest(db)
    argv = [a.replace("{db}", str(db)) for a in argv]
    if "--store" not in argv:
        argv += ["--store", str(db)] if argv[0] in ("runs", "show", "export") else []
    code, _, err = bench(*argv)
    check_policy(code, err, (0, 2), "argument vectors")
    assert digest(db) == before


# --- 3. malformed plan files through `bench plan` ---------------------------------------------------------

SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(allow_nan=True),
                    st.text(max_size=6), st.sampled_from([1e-9, 1e308, -1.0, 0, 0.5, 1.5, "in-plane", "once"]))
RANGES = st.one_of(SCALARS, st.lists(SCALARS, max_size=4),
                   st.dictionaries(st.sampled_from(["start", "stop", "step", "x"]),
                                   st.one_of(st.floats(allow_nan=True), st.sampled_from([1e-9, 0, 10, -5, 90])),
                                   max_size=4))
PLAN_TABLE = st.dictionaries(st.sampled_from(["theta_i", "theta_r", "phi_r", "phi_i", "theta_h", "theta_d",
                                              "phi_d", "phi_h", "geometries", "points", "thetta_r"]), RANGES, max_size=4)
PLAN = st.fixed_dictionaries({"kind": st.sampled_from(["in-plane", "hemispherical", "half-vector", "list",
                                                       "spectral", "spiral", "In-Plane"])},
                             optional={"name": SCALARS, "integration_s": SCALARS, "averages": SCALARS,
                                       "dark": SCALARS, "white": SCALARS, "order": SCALARS, "avrages": SCALARS,
                                       "in_plane": PLAN_TABLE, "hemispherical": PLAN_TABLE,
                                       "half_vector": PLAN_TABLE, "spectral": PLAN_TABLE,
                                       "points": st.lists(st.lists(SCALARS, max_size=5), max_size=3)})


def _toml(doc: dict) -> str:
    def clean(v):  # TOML has no null
        if isinstance(v, dict):
            return {str(k): clean(x) for k, x in v.items() if x is not None}
        if isinstance(v, list):
            return [clean(x) for x in v if x is not None]
        return v

    try:
        return tomli_w.dumps(clean(doc))
    except (TypeError, ValueError):  # a mixed-type array TOML 1.0 cannot hold: write the text anyway
        return "\n".join(f"{k} = {v!r}" for k, v in clean(doc).items())


@pytest.mark.slow  # 150 fuzzed plans (14 s under load)
@settings(FUZZ, max_examples=150)
@given(doc=PLAN)
def test_fuzzed_plans_are_accepted_or_refused_in_one_line(tmp_path, doc):
    path = tmp_path / "fuzz-plan.toml"
    path.write_text(_toml(doc), encoding="utf-8")
    code, _, err = bench("plan", path, "--bench", VIRTUAL)
    check_policy(code, err, (0, 2), "plan files")
    if doc.get("avrages") is not None or (isinstance(doc.get("averages"), float) and not float(doc["averages"]).is_integer()):
        assert code == 2


# --- 4. malformed bench configs ---------------------------------------------------------------------------

BENCH = st.fixed_dictionaries(
    {"kind": st.sampled_from(["virtual", "virtual", "simulated", "Virtual"])},
    optional={"name": SCALARS, "seed": st.one_of(SCALARS, st.sampled_from([-1, 2**63, 2**64])),
              "specimen": st.one_of(SCALARS, st.fixed_dictionaries({"spec": st.sampled_from(
                  ["lambert:albedo=0.8", "lambert:albedo=2", "chalk", "ggx:alpha=0.2,eta=1.5,k=0", ""])})),
              "white": st.one_of(SCALARS, st.dictionaries(st.sampled_from(
                  ["reflectance_factor", "uncertainty", "geometry", "refletance"]), RANGES, max_size=3)),
              "virtual": st.one_of(SCALARS, st.dictionaries(st.sampled_from(
                  ["collector", "rays", "beam", "wavelengths", "method", "raays", "delta"]),
                  st.one_of(SCALARS, st.sampled_from(["equal-psa:100000x100000", "equal-psa:9x36", "400:700:1e-9",
                                                      "rays", 10**16])), max_size=3)),
              "emulated": st.dictionaries(st.sampled_from(["time_scale", "seed", "bands"]), SCALARS, max_size=2),
              "whte": SCALARS})


_FIXTURE_BENCH = tomllib.loads((FIX / "benches" / "virtual.toml").read_text())
_PATHS = [(t, k) for t, v in _FIXTURE_BENCH.items() if isinstance(v, dict) for k in v] + \
    [(None, k) for k in _FIXTURE_BENCH] + [("virtual", "raays"), ("white", "refletance"), (None, "whte")]


def _mutated(path_value):
    (table, key), value = path_value
    doc = {k: (dict(v) if isinstance(v, dict) else v) for k, v in _FIXTURE_BENCH.items()}
    doc["virtual"] = {**doc["virtual"], "rays": 1000}  # keep an accepted config cheap
    (doc if table is None else doc[table])[key] = value
    return doc


MUTATED_BENCH = st.tuples(st.sampled_from(_PATHS), st.one_of(SCALARS, st.sampled_from(
    ["equal-psa:100000x100000", "equal-psa:9x36", "400:700:1e-9", "500:600:50", "fast", 10**16, [0, 0, 45, 180]]))
).map(_mutated)


@settings(FUZZ, max_examples=120)
@given(doc=st.one_of(BENCH, MUTATED_BENCH))
def test_fuzzed_bench_configs_are_accepted_or_refused_in_one_line(tmp_path, scanned_store, doc):
    _, _, plan = scanned_store
    path = tmp_path / "fuzz-bench.toml"
    path.write_text(_toml(doc), encoding="utf-8")
    code, _, err = bench("plan", plan, "--bench", path)
    check_policy(code, err, (0, 2), "bench configs")
    if "whte" in doc and doc["whte"] is not None:
        assert code == 2


# --- 5. malformed sweeps (loaded as `bench sweep` loads them, before any work) --------------------------

SWEEP_RANDOM = st.fixed_dictionaries(
    {"sweep": st.dictionaries(st.sampled_from(["name", "seed", "instrument", "specimens", "incidences", "collectors",
                                               "wavelengths", "rays", "method", "delta", "wavelengths_per_task",
                                               "uncertainty", "raays", "beam", "geometries"]),
                              st.one_of(SCALARS, RANGES, st.lists(st.sampled_from(
                                  ["lambert:albedo=0.5", "equal-psa:9x36", "chalk", 30, [30, 90]]), max_size=3)),
                              max_size=7)},
    optional={"task": st.lists(st.dictionaries(st.sampled_from(["specimen", "incidence", "collector", "rays", "x"]),
                                               SCALARS, max_size=3), max_size=3)})


_FIXTURE_SWEEP = tomllib.loads((FIX / "sweeps" / "gonio-product.toml").read_text())


def _mutated_sweep(key_value):
    key, value = key_value
    doc = {"sweep": {**_FIXTURE_SWEEP["sweep"], "rays": 1000}}
    doc["sweep"][key] = value
    return doc


MUTATED_SWEEP = st.tuples(
    st.sampled_from(sorted(_FIXTURE_SWEEP["sweep"]) + ["raays", "cone_deg", "uncertainty", "geometries"]),
    st.one_of(SCALARS, RANGES, st.sampled_from(["equal-psa:100000x100000", ["equal-psa:9x36"], "450:650:1e-9",
                                                [0, 30], "rays", "fast", 10**16, [[30, 90]], ["chalk"]]))
).map(_mutated_sweep)
SWEEP = st.one_of(SWEEP_RANDOM, MUTATED_SWEEP)


@settings(FUZZ, max_examples=120)
@given(doc=SWEEP)
def test_fuzzed_sweeps_are_accepted_or_refused_in_one_line(tmp_path, doc):
    path = tmp_path / "fuzz-sweep.toml"
    path.write_text(_toml(doc), encoding="utf-8")
    fam = TALLY.setdefault("sweep files", {"cases": 0, "refused": 0, "accepted": 0})
    fam["cases"] += 1
    status, result, _, _ = WORKER.call("tests.test_fuzz_cli:sweep_outcome", str(path))
    assert status == "ok", result  # anything but a project error is a failure, with its traceback
    verdict, detail = result
    fam[verdict] += 1
    if verdict == "accepted":
        assert detail >= 1
    else:
        assert "\n" not in detail


# --- 6. malformed scenes: refused by `bench tradeoff` in one line, or accepted by the scene too ------

_FIXTURE_SCENE = tomllib.loads((FIX / "scenes" / "sphere-effects.toml").read_text())
_SCENE_PATHS = [(None, k) for k in _FIXTURE_SCENE if not isinstance(_FIXTURE_SCENE[k], dict)] + \
    [("beam", "kind"), ("effects", "sphere"), ("effects", "noise"), ("effects", "noyse"), ("tradeoff", "rays"),
     ("tradeoff", "repeats"), (None, "collector"), (None, "physical"), (None, "instrument")]


def _mutated_scene(path_value):
    (table, key), value = path_value
    doc = {k: (dict(v) if isinstance(v, dict) else v) for k, v in _FIXTURE_SCENE.items()}
    (doc if table is None else doc.setdefault(table, {}))[key] = value
    return doc


SCENE = st.tuples(st.sampled_from(_SCENE_PATHS), st.one_of(
    SCALARS, RANGES, st.sampled_from(["equal-psa:5000x5000", "gonio", "goniophotometer", [0], [10, 100], True,
                                      {"wall_reflectance": 2}, {"steps_deg": [1e-9]}, "400:700:1e-9"]))
).map(_mutated_scene)


@settings(FUZZ, max_examples=100)
@given(doc=SCENE)
def test_fuzzed_scenes_are_refused_in_one_line_or_loadable(tmp_path, doc):
    from bench.core.schemas import SceneFile, validate_document
    from virtual.scene import scene_from_dict

    path = tmp_path / "fuzz-scene.toml"
    path.write_text(_toml(doc), encoding="utf-8")
    try:
        validate_document(SceneFile, tomllib.loads(path.read_text()), str(path))
    except ConfigError:  # refused by the schema: the CLI says so in one line before any work
        code, _, err = bench("tradeoff", path)
        check_policy(code, err, (2,), "scene files")
        return
    except tomllib.TOMLDecodeError:
        return
    fam = TALLY.setdefault("scene files", {"cases": 0, "refused": 0, "accepted": 0})
    fam["cases"] += 1
    try:  # accepted by the schema: the scene builds, or refuses with a project error (never a raw one)
        scene_from_dict(tomllib.loads(path.read_text()))
        fam["accepted"] += 1
    except InputError as exc:
        fam["refused"] += 1
        assert "\n" not in str(exc)


# --- 7. readers with fuzzed run ids and options never change the store ----------------------------------

@settings(FUZZ, max_examples=80)
@given(cmd=st.sampled_from(["show", "export", "resume"]),
       rid=st.one_of(st.text(max_size=20), st.sampled_from(["", "x\udcff", "../../etc", "a" * 500, "r'; DROP TABLE"])),
       fmt=st.sampled_from(["csv", "parquet", "astm", "zemax", "xml"]))
def test_readers_with_fuzzed_run_ids_exit_2_and_leave_the_store_alone(tmp_path, scanned_store, cmd, rid, fmt):
    db, _, _ = scanned_store
    before = digest(db)
    argv = [cmd, "--store", db, "--", rid] if cmd != "export" else \
        [cmd, "--store", db, "--format", fmt, "--out", tmp_path / "x.out", "--", rid]
    code, _, err = bench(*argv)
    check_policy(code, err, (2,), "run ids")
    assert digest(db) == before


# --- 8. a damaged store: one field of the run set to a fuzzed value; readers exit 0 or 2, never 70 ----------

JSON_FIELDS = {("runs", c) for c in ("plan", "bench", "versions", "calibration", "meta")} | {("readings", "extra")}
NUMERIC_FIELDS = {("points", c) for c in ("theta_i", "phi_i", "theta_r", "phi_r")} | {
    ("readings", c) for c in ("wavelength_nm", "value", "std", "signal", "dark", "white", "saturated", "count", "N")}
DAMAGEABLE = sorted(JSON_FIELDS | NUMERIC_FIELDS | {("runs", c) for c in ("created_epoch", "finished_epoch", "n_planned",
                                                                          "seed", "kind", "reason")})
DAMAGE = st.one_of(st.sampled_from([None, "", "{", "[]", "null", "abc", '{"uncertainty_budget": "x"}', "1e999",
                                    '{"x": ' + "7" * 5000 + "}",  # past int()'s 4300 digits: a plain ValueError
                                    '{"uncertainty_budget": {"components": [], "combined": -1, "expanded": 0, "k": 2}}']),
                   st.floats(), st.integers(min_value=-10**18, max_value=10**18), st.text(max_size=12))


@settings(FUZZ, max_examples=60)
@given(field=st.sampled_from(DAMAGEABLE), value=DAMAGE, cmd=st.sampled_from(["show", "show --json", "export", "runs"]))
def test_a_damaged_store_is_refused_in_one_line_or_read_never_a_traceback(tmp_path, scanned_store, field, value, cmd):
    db, rid, _ = scanned_store
    copy = tmp_path / "damaged.sqlite"
    for leftover in (copy, tmp_path / "damaged.sqlite-wal", tmp_path / "damaged.sqlite-shm"):
        leftover.unlink(missing_ok=True)  # the last example's WAL must not replay onto this copy
    with closing(sqlite3.connect(db)) as src, closing(sqlite3.connect(copy)) as dst:
        src.backup(dst)
    table, column = field
    with closing(sqlite3.connect(copy)) as c, c:
        try:
            c.execute(f"UPDATE {table} SET {column} = ? WHERE run_id = ?"
                      + (" AND idx = (SELECT MIN(idx) FROM points WHERE run_id = ?)" if table != "runs" else ""),
                      (value, rid, rid) if table != "runs" else (value, rid))
        except sqlite3.Error:  # a NOT NULL or CHECK constraint the store keeps itself
            return
    before = digest(copy)
    argv = {"show": ["show", rid], "show --json": ["show", rid, "--json"], "runs": ["runs"],
            "export": ["export", rid, "--out", tmp_path / "x.csv", "--force"]}[cmd]
    code, _, err = bench(*argv, "--store", copy)
    check_policy(code, err, (0, 2), "damaged stores")
    unparsable_json = field in JSON_FIELDS and isinstance(value, str) and value not in ("null", "[]") and \
        not value.startswith('{"')
    read = cmd != "runs" or table == "runs"  # `bench runs` reads the runs rows, not every reading
    if read and (unparsable_json or (field in NUMERIC_FIELDS and isinstance(value, str) and value in ("abc", "{"))):
        assert code == 2 and rid in err, (field, value, cmd, err)  # named, never read as NaN
    assert digest(copy) == before


def test_zz_fuzz_tally(capsys):
    """Report the tally (cases, refused, accepted per family); the suite asserts at least 500."""
    total = sum(t["cases"] for t in TALLY.values())
    with capsys.disabled():
        print(f"\nfuzz tally: {total} cases, all clean: "
              + "; ".join(f"{k} {v['cases']} ({v['refused']} refused, {v['accepted']} accepted)"
                          for k, v in sorted(TALLY.items())))
    if len(TALLY) == 8:  # the whole file ran (not a -k selection)
        assert total >= 500
