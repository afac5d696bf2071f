"""The scene schema (bench.core.schemas) is the one declaration of the effects' settings: every
value it accepts builds the scene, every value it refuses is one ConfigError line naming the
file, the key and the value -- at each declared bound and beyond it, and for values drawn at
random (a deterministic property test: fixed hypothesis database off, derandomized)."""

from __future__ import annotations

import math

import annotated_types as at
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.core.errors import ConfigError
from bench.core.schemas import EFFECT_SCHEMAS, SceneFile, validate_document
from virtual.scene import EFFECT_NAMES, Effects, scene_from_dict

SOURCE = "scene file lab.toml"
#: the instrument each effect belongs to (an aperture is a goniophotometer's, a sphere a spectrophotometer's)
INSTRUMENT = {"aperture": "goniophotometer"}


def _bounds(effect: str, key: str) -> tuple[float, bool, float, bool] | None:
    """(lo, lo inclusive, hi, hi inclusive) of a numeric setting, from its declaration."""
    lo, lo_in, hi, hi_in = -math.inf, True, math.inf, True
    for m in EFFECT_SCHEMAS[effect].model_fields[key].metadata:
        if isinstance(m, at.Gt):
            lo, lo_in = float(m.gt), False
        elif isinstance(m, at.Ge):
            lo, lo_in = float(m.ge), True
        elif isinstance(m, at.Lt):
            hi, hi_in = float(m.lt), False
        elif isinstance(m, at.Le):
            hi, hi_in = float(m.le), True
    return None if (lo, hi) == (-math.inf, math.inf) else (lo, lo_in, hi, hi_in)


def _edges() -> list[tuple[str, str, float]]:
    """Each bounded setting at its bounds and one ulp either side of them."""
    out = []
    for effect, model in EFFECT_SCHEMAS.items():
        for key in model.model_fields:
            b = _bounds(effect, key)
            if b is None:
                continue
            for edge in (b[0], b[2]):
                if math.isfinite(edge):
                    out += [(effect, key, v) for v in (math.nextafter(edge, -math.inf), edge,
                                                       math.nextafter(edge, math.inf))]
    return out


def _doc(effect: str, table: dict) -> dict:
    return {"instrument": INSTRUMENT.get(effect, "spectrophotometer"), "specimen": "lambert:reflectance=0.5",
            "effects": {effect: table}}


def _check(effect: str, table: dict, key: str | None, value: object) -> bool:
    """Schema verdict, then the scene: built if accepted, else the schema's line. True if accepted."""
    doc = _doc(effect, table)
    try:
        validate_document(SceneFile, doc, SOURCE)
    except ConfigError as exc:
        msg = str(exc)
        assert "\n" not in msg and msg.startswith(f"{SOURCE}: key effects.{effect}"), msg
        if key is not None:
            assert key in msg and (repr(value) in msg or f"{value:g}" in msg), msg
        with pytest.raises(ConfigError) as again:  # the scene loader gives the same line
            scene_from_dict(doc, source=SOURCE)
        assert str(again.value) == msg
        return False
    scene = scene_from_dict(doc, source=SOURCE)
    assert getattr(scene.effects, effect) is not None
    return True


@pytest.mark.parametrize("effect, key, value", _edges(), ids=lambda v: f"{v:.17g}" if isinstance(v, float) else v)
def test_each_bound_is_kept_by_schema_and_scene_alike(effect, key, value):
    lo, lo_in, hi, hi_in = _bounds(effect, key)
    table = {key: value}
    if effect == "sphere" and key in ("detector_port", "specimen_port"):  # ports that fit the sphere
        table = {"port_fraction": 0.10, "detector_port": 1e-3, "specimen_port": 0.0, key: value}
    if effect == "sphere" and key == "port_fraction":
        table = {key: value, "detector_port": min(max(value, 5e-324), 0.10), "specimen_port": 0.0}
    if effect == "aperture" and key == "half_angle_deg":
        table["views"] = [[0.0, 0.0]]
    if effect == "bandpass" and key == "nodes":
        value = int(round(value)) | 1  # an odd count at the bounds (odd-ness has its own case below)
        table = {key: value}
        lo_in = hi_in = True
    inside = (lo < value < hi) or (value == lo and lo_in) or (value == hi and hi_in)
    assert _check(effect, table, key, value) == inside


@pytest.mark.parametrize("effect, table, accepted", [
    ("bandpass", {"nodes": 4}, False), ("bandpass", {"nodes": 5}, True), ("bandpass", {"nodes": 9.0}, True),
    ("sphere", {"port_fraction": 0.05, "detector_port": 0.03, "specimen_port": 0.02}, True),
    ("sphere", {"port_fraction": 0.05, "detector_port": 0.03, "specimen_port": 0.03}, False),
    ("aperture", {"half_angle_deg": 10, "views": [[79.9]]}, True),
    ("aperture", {"half_angle_deg": 10, "views": [[80]]}, False),
    ("aperture", {"views": []}, False),
    ("gloss_trap", {"specular": "maybe"}, False),
    ("specimen", {"uniform": 1}, False),
    ("noise", {"relative": True}, True),
])
def test_rules_across_settings_are_the_schemas(effect, table, accepted):
    assert _check(effect, table, None, None) == accepted


def test_every_declared_effect_has_its_computation():
    assert EFFECT_NAMES == tuple(EFFECT_SCHEMAS)
    assert [f for f in Effects.__dataclass_fields__ if f != "extra"] == list(EFFECT_NAMES)  # extra: plugins'
    assert "did you mean 'uncertainty'" in str(pytest.raises(ConfigError, scene_from_dict,
                                                             _doc("noise", {"uncertainy": 0.01})).value)
    for effect in EFFECT_NAMES:  # `true` declares an effect with its defaults
        assert getattr(scene_from_dict(_doc(effect, True)).effects, effect) is not None


def _setting() -> st.SearchStrategy:
    numeric = [(e, k) for e in EFFECT_SCHEMAS for k in EFFECT_SCHEMAS[e].model_fields if _bounds(e, k)]
    return st.sampled_from(numeric).flatmap(lambda ek: st.tuples(
        st.just(ek[0]), st.just(ek[1]),
        st.floats(allow_nan=False, allow_infinity=False, min_value=-1e4, max_value=1e4)
        if ek[1] != "nodes" else st.integers(-10, 1000)))


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(setting=_setting())
def test_random_values_are_accepted_and_built_or_refused_in_one_line(setting):
    effect, key, value = setting
    _check(effect, {key: value}, key, value)
