"""The declared schemas of plan and bench files refuse what they once let through:
unknown keys (with "did you mean"), wrong types, non-finite and out-of-range numbers, empty and
oversized ranges -- one line naming file, key and value."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.core.errors import ConfigError
from bench.core.parsing import read_toml
from bench.core.schemas import BenchFile, PlanFile, SceneFile, SweepFile, validate_document

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
#: fixtures/<folder> -> the schema of its documents
SCHEMAS = {"plans": PlanFile, "benches": BenchFile, "sweeps": SweepFile, "scenes": SceneFile}


@pytest.mark.parametrize("path", [p for d in SCHEMAS for p in sorted((FIXTURES / d).glob("*.toml"))],
                         ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_fixture_document_is_valid(path):
    validate_document(SCHEMAS[path.parent.name], read_toml(path), str(path))


def _refusal(schema, doc, filename: str) -> str:
    """The message ``schema`` refuses ``doc`` with, checked to be one line naming ``filename``."""
    with pytest.raises(ConfigError) as info:
        validate_document(schema, doc, filename)
    msg = str(info.value)
    assert msg.startswith(f"{filename}: ") and "\n" not in msg, msg
    return msg


BAD_PLANS = {
    "typo with a near miss": ({"kind": "in-plane", "avrages": 4}, "unknown key 'avrages'; did you mean 'averages'?"),
    "averages 1.5": ({"kind": "in-plane", "averages": 1.5}, "key averages: expected an integer, got 1.5"),
    "averages inf": ({"kind": "in-plane", "averages": math.inf}, "key averages: expected an integer, got inf"),
    "integration 1e308": ({"kind": "in-plane", "integration_s": 1e308}, "key integration_s"),
    "integration nan": ({"kind": "in-plane", "integration_s": math.nan}, "key integration_s"),
    "empty theta_i": ({"kind": "in-plane", "in_plane": {"theta_i": []}}, "key in_plane.theta_i: an empty list"),
    "phi_i a string": ({"kind": "in-plane", "in_plane": {"phi_i": "abc"}}, "key in_plane.phi_i"),
    "step nan": ({"kind": "in-plane", "in_plane": {"theta_r": {"start": 0, "stop": 10, "step": math.nan}}},
                 "key in_plane.theta_r: step: expected a finite number, got nan"),
    "step 1e-9": ({"kind": "hemispherical", "hemispherical": {"phi_r": {"start": 0, "stop": 330, "step": 1e-9}}},
                  "more than the limit"),
    "nested typo": ({"kind": "hemispherical", "hemispherical": {"theta_rr": 3}},
                    "unknown key 'hemispherical.theta_rr'; did you mean 'theta_r'?"),
    "unknown kind": ({"kind": "nope"}, "key kind"),
    "boolean averages": ({"kind": "in-plane", "averages": True}, "key averages"),
}


@pytest.mark.parametrize("name", sorted(BAD_PLANS))
def test_bad_plans_are_refused_naming_key_and_value(name):
    doc, expected = BAD_PLANS[name]
    assert expected in _refusal(PlanFile, doc, "my-plan.toml")


BAD_BENCHES = {
    "white as a string": ({"kind": "virtual", "white": "x"}, "key white"),
    "time_scale 0": ({"kind": "emulated", "emulated": {"time_scale": 0}}, "key emulated.time_scale"),
    "time_scale -1": ({"kind": "emulated", "emulated": {"time_scale": -1}}, "key emulated.time_scale"),
    "typo in a table": ({"kind": "virtual", "virtual": {"raays": 3}}, "did you mean 'rays'?"),
    "typo at the top": ({"kind": "virtual", "whte": {}}, "did you mean 'white'?"),
    "seed beyond 2^63": ({"kind": "virtual", "seed": 2**64}, "key seed"),
    "negative seed": ({"kind": "virtual", "seed": -1}, "key seed"),
    "unknown kind": ({"kind": "simulated"}, "key kind"),
}


@pytest.mark.parametrize("name", sorted(BAD_BENCHES))
def test_bad_benches_are_refused_naming_key_and_value(name):
    doc, expected = BAD_BENCHES[name]
    assert expected in _refusal(BenchFile, doc, "lab.toml")


_values = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(allow_nan=True),
                    st.text(max_size=8), st.lists(st.floats(allow_nan=True), max_size=5),
                    st.dictionaries(st.sampled_from(["start", "stop", "step", "x"]), st.floats(allow_nan=True),
                                    max_size=4))
_keys = st.sampled_from(["name", "kind", "integration_s", "averages", "dark", "white", "order", "in_plane",
                         "hemispherical", "points", "theta_i", "avrages", "list"])


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(_keys, _values, max_size=6))
def test_fuzzed_plan_documents_give_config_errors_only(doc):
    """Whatever the document, validation returns a model or raises one-line ConfigError."""
    try:
        validate_document(PlanFile, doc, "fuzz.toml")
    except ConfigError as exc:
        assert "\n" not in str(exc)


# --- sweeps and scenes -------------------------------------------------------------------------------

BAD_SWEEPS = {
    "typo": ({"sweep": {"raays": 3}}, "unknown key 'sweep.raays'; did you mean 'rays'?"),
    "delta text": ({"sweep": {"delta": "abc"}}, "key sweep.delta"),
    "collector of 1e10 patches": ({"sweep": {"collectors": ["equal-psa:100000x100000"]}}, "patches"),
    "cone text in a task": ({"sweep": {}, "task": [{"cone_deg": "x"}]}, "key task[0].cone_deg"),
    "rays 1e16": ({"sweep": {"rays": 1e16}}, "key sweep.rays"),
    "wavelength step 1e-9": ({"sweep": {"wavelengths": "400:700:1e-9"}}, "more than the limit"),
    "seed -1": ({"sweep": {"seed": -1}}, "key sweep.seed"),
    "no [sweep]": ({"task": [{"specimen": "x"}]}, "key sweep"),
}


@pytest.mark.parametrize("name", sorted(BAD_SWEEPS))
def test_bad_sweeps_are_refused_naming_key_and_value(name):
    doc, expected = BAD_SWEEPS[name]
    assert expected in _refusal(SweepFile, doc, "s.toml")


BAD_SCENES = {
    "instrument": ({"instrument": "gonio"}, "key instrument"),
    "wall reflectance 2": ({"effects": {"sphere": {"wall_reflectance": 2}}}, "key effects.sphere.wall_reflectance"),
    "tradeoff rays 0": ({"tradeoff": {"rays": [0]}}, "key tradeoff.rays[0]"),
    "effect typo": ({"effects": {"noyse": {}}}, "did you mean 'noise'?"),
    "physical step 1e-9": ({"physical": {"steps_deg": [1e-9]}}, "key physical.steps_deg[0]"),
    "incidence nan": ({"incidence": [math.nan, 0]}, "key incidence"),
    "collector oversized": ({"collector": {"spec": "equal-psa:5000x5000"}}, "patches"),
}


@pytest.mark.parametrize("name", sorted(BAD_SCENES))
def test_bad_scenes_are_refused_naming_key_and_value(name):
    doc, expected = BAD_SCENES[name]
    assert expected in _refusal(SceneFile, doc, "scene.toml")


def test_the_sweep_loader_refuses_through_the_schema(tmp_path):
    from bench.sweep import load_sweep

    p = tmp_path / "s.toml"
    p.write_text('[sweep]\nspecimens = ["lambert:albedo=0.5"]\ndelta = "abc"\n')
    with pytest.raises(ConfigError, match=r"s.toml: key sweep.delta"):
        load_sweep(p)
    p.write_text('[sweep]\nspecimens = ["lambert:albedo=0.5"]\nincidences = ' + str(list(range(80))) + "\n"
                 'collectors = [' + ", ".join(f'"equal-psa:{i}x{j}"' for i in range(1, 41) for j in range(1, 41)) + "]\n")
    with pytest.raises(ConfigError, match="series, more than the limit"):
        load_sweep(p)
