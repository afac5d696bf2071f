"""Random streams per specimen, common random numbers on request, and what the output says about
the method that ran."""

from __future__ import annotations

import json

import numpy as np

from bench.cli import main
from virtual.engine import specimen_description, specimen_stream_key
from virtual.goniophotometer import VirtualGoniophotometer
from virtual.quadrature import CERTIFY_TOL
from virtual.specimens import parse_specimen
from virtual.spectrophotometer import VirtualSpectrophotometer


def test_the_stream_key_is_the_specimen_however_its_string_is_written():
    a, b, c = (parse_specimen(s) for s in ("ggx:alpha=0.20,eta=1.5", "ggx:eta=1.5,alpha=.2", "ggx:alpha=0.21"))
    assert specimen_description(a) == specimen_description(b) != specimen_description(c)
    assert specimen_stream_key(a) == specimen_stream_key(b) != specimen_stream_key(c)
    assert 0 <= specimen_stream_key(a) < 2 ** 63
    # a spectral table is part of the description, every entry
    t1 = parse_specimen("lambert").__class__(reflectance=((400.0, 700.0), (0.2, 0.3)))
    t2 = parse_specimen("lambert").__class__(reflectance=((400.0, 700.0), (0.2, 0.31)))
    assert specimen_stream_key(t1) != specimen_stream_key(t2)


def test_streams_are_per_specimen_by_default_and_common_on_request():
    """A parameter scan with one seed draws independent streams (the naive key -- seed,
    wavelength, incidence only -- gave every specimen the same rays: correlated results);
    ``common_random_numbers`` gives back exactly that, for comparisons with lower variance."""
    kw = dict(rays=50_000, seed=4, method="rays", collector="equal-psa:3x6")
    g = [VirtualGoniophotometer(s, **kw) for s in ("lambert:albedo=0.5", "lambert:albedo=0.50000001")]
    assert g[0].stream(30.0, 0.0, 550.0).spawn_key != g[1].stream(30.0, 0.0, 550.0).spawn_key
    same = [VirtualGoniophotometer(s, common_random_numbers=True, **kw)
            for s in ("lambert:albedo=0.5", "lambert:albedo=0.50000001")]
    assert same[0].stream(30.0, 0.0, 550.0).spawn_key == same[1].stream(30.0, 0.0, 550.0).spawn_key
    # the Lambertian's rays are batched over wavelengths: one stream per (specimen, incidence), same rule
    assert g[0].batches_wavelengths and g[0].batch_stream_key(30.0, 0.0) != g[1].batch_stream_key(30.0, 0.0)
    assert same[0].batch_stream_key(30.0, 0.0) == same[1].batch_stream_key(30.0, 0.0) == (30_000, 0)
    # common random numbers: two specimens that differ by 1e-8 count (almost) the same rays
    a, b = (x.simulate(30.0, 0.0, 550.0) for x in same)
    assert np.abs(a - b).sum() <= 2
    # independent streams: the counts differ like two independent multinomials (expected L1
    # distance ~ 880 here, standard deviation ~ 150; common streams give <= 2)
    c, d = (x.simulate(30.0, 0.0, 550.0) for x in g)
    assert np.abs(c - d).sum() > 300
    rec = same[0].measure_bsdf(30.0)
    assert rec.meta["common_random_numbers"] is True and g[0].measure_bsdf(30.0).meta["common_random_numbers"] is False
    sp = VirtualSpectrophotometer("lambert:albedo=0.5", rays=10_000, seed=4, common_random_numbers=True)
    assert sp.measure("8/d", "550").meta["common_random_numbers"] is True


def test_record_says_which_method_ran_and_its_quadrature_error():
    g = VirtualGoniophotometer("ggx:alpha=0.2", rays=100_000, seed=1)
    rec = g.measure_bsdf(30.0)
    tot = rec.meta["totals"][0]
    assert rec.meta["method"] == "fast" and rec.meta["method_requested"] == "auto"
    assert tot["method"] == "fast" and tot["quadrature_certified"] is True
    assert 0.0 <= tot["quadrature_error"] <= CERTIFY_TOL
    r = VirtualGoniophotometer("ggx:alpha=0.2", rays=100_000, seed=1, method="rays").measure_bsdf(30.0)
    assert r.meta["method"] == "rays" and "quadrature_error" not in r.meta["totals"][0]


def test_cli_states_the_method_the_quadrature_error_and_the_streams(capsys):
    assert main(["gonio", "--specimen", "dielectric:alpha=0.2,eta=1.0001", "--incidence", "60",
                 "--rays", "100000", "--seed", "1"]) == 0
    out = capsys.readouterr().out
    assert "method fast" in out and "[fast, quadrature error <= " in out and "streams per specimen" in out
    t = float(out.split("transmittance ")[1].split()[0])
    assert abs(t - 0.97247) < 5 * (0.97 * 0.03 / 1e5) ** 0.5  # the refracted lobe a naive fast path lost is found
    assert main(["gonio", "--specimen", "lambert", "--rays", "1000", "--seed", "1", "--common-random-numbers",
                 "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["common_random_numbers"] is True and js["by_wavelength"][0]["method"] == "fast"
    assert main(["spectro", "--specimen", "lambert", "--rays", "1000", "--seed", "1", "--wavelengths", "550",
                 "--common-random-numbers"]) == 0
    assert "streams common to every specimen" in capsys.readouterr().out
