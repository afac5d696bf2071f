"""The README's routing table is the dispatch rule: generated from it, and the
rule probed at the limits the table states."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.docs import documents
from virtual.beam import DISK_POLAR, DISK_REJECTION
from virtual.engine import gonio_kernel_for
from virtual.routing import ROUTING_MARK, routing_table
from virtual.specimens import SPECIMENS, parse_specimen

ROOT = Path(__file__).resolve().parent.parent


def test_readme_table_is_the_generated_one() -> None:
    """The table under the mark, in the README or the docs page that holds it."""
    texts = [t for t in (p.read_text(encoding="utf-8") for p in documents(ROOT)) if ROUTING_MARK in t]
    assert len(texts) == 1, "the routing table's mark must be in exactly one of README.md and docs/"
    text = texts[0]
    own = {name: cls for name, cls in SPECIMENS.items() if cls.__module__.startswith("virtual.specimens.")}
    table = routing_table(own)  # the project's families (a test may have registered its own)
    start = text.index(ROUTING_MARK) + len(ROUTING_MARK) + 1
    assert text[start:start + len(table)] == table, "the docs' routing table differs from virtual.routing.routing_table"


@pytest.mark.parametrize("spec, expected", [
    ("ggx:alpha=0.2,eta=0.05", "block32"),  # a conductor's eta is not limited to [0.1, 10]
    ("ggx:alpha=0.2,eta=20", "block32"),
    ("ggx:alpha=0.009", "block"),
    ("dielectric:alpha=0.2,eta=1.0001", "block32"),
    ("dielectric:alpha=0.2,eta=10", "block32"),
    ("phong:kd=0.2,ks=0.5,n=20000", "block32"),
    ("phong:kd=0.2,ks=0.5,n=20001", "block"),
    ("lambert:reflectance=1e-9", "block32"),
    ("leaf", "block32"),
    ("leaf:roughness=0.01", "block32"),
    ("leaf:roughness=0.009", "block"),
    ("roughplastic:alpha=0.2,eta=1.5,kd=0.5", "block32"),
    ("roughplastic:alpha=0.01,eta=1.5,kd=0.5", "block32"),
    ("roughplastic:alpha=0.009,eta=1.5,kd=0.5", "block"),
])
def test_the_rule_at_the_stated_limits(spec: str, expected: str) -> None:
    sp = parse_specimen(spec)
    assert gonio_kernel_for(sp.model, DISK_POLAR, "auto", sp.params(550.0)) == expected
    if expected != "ray":
        assert gonio_kernel_for(sp.model, DISK_REJECTION, "auto", sp.params(550.0)) == "ray"


def test_non_finite_parameters_leave_float32() -> None:
    sp = parse_specimen("ggx:alpha=0.2")
    p = np.array(sp.params(550.0), dtype=float)
    p[2] = np.inf
    assert gonio_kernel_for(sp.model, DISK_POLAR, "auto", p) == "block"
