"""``bench rays``, ``bench spectro`` and ``bench gonio``: one virtual measurement, printed.

``--uncertainty/--delta`` measurements use the adaptive rule of :mod:`bench.adaptive`; ``--csv``
goes through the one CSV writer of :mod:`bench.io`, ``--plot`` through :mod:`compare.figures`.

``bench gonio --relative-uncertainty V`` is a *relative* uncertainty of each patch's BSDF: a pilot run
estimates the patch probabilities, and N is sized (:func:`virtual.bounds.relative_patch_rays`)
so the least-populated patch of interest (pilot probability >= :data:`bench.adaptive.INTEREST_FRACTION` of the
brightest patch's) has an interval of relative half-width about V; patches that would need more
than ``--max-seconds`` allows are named. ``--patch-probability-uncertainty V`` keeps eq. 3.12's
meaning (V bounds each patch's *probability*, an absolute quantity: a dim patch's BSDF may be
far off). The output says which was used and prints the achieved relative half-width of the
brightest and the dimmest patch of interest. ``--uncertainty`` is absolute wherever it is taken
(``rays``, ``spectro``): gonio refuses it, naming ``--relative-uncertainty``.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

from bench.cli.argtypes import (MAX_PATCHES, MAX_RAYS, RAYS_PER_SECOND, collector, count, estimated_seconds, renamed,
                                incidence, rays, real, seed, stderr_is_terminal, wavelengths)
from bench.cli.commands import command_help
from bench.cli.common import (PLOT_SUFFIXES, add_force_option, announce_compilation, emit_json, output_file,
                              warn_if_radians)
from bench.core.errors import InputError

if TYPE_CHECKING:  # for the annotations only: the CLI starts without loading the instruments
    from bench.adaptive import GonioMeasurement
    from bench.core.records import BSDFRecord, Spectrum

# numpy and everything heavier are imported inside the functions that use them: `bench rays`
# (eq. 3.5 in decimals) and the parsing of spectro's and gonio's arguments do not pay for them.

__all__ = ["register", "cmd_rays", "cmd_spectro", "cmd_gonio", "gonio_json", "spectrum_colour", "n_label",
           "reciprocity_note", "RAYS_PER_SECOND"]


def cmd_rays(args: argparse.Namespace) -> int:
    from virtual.bounds import budget_report

    report = budget_report(args.uncertainty, args.delta, args.patches, rays_per_second=args.rate)
    if args.json:
        emit_json({**report, "bound": "eq. 3.12" if args.patches > 1 else "eq. 3.5"})
    else:
        print(report["N"])
        if args.verbose:
            print(f"about {report['seconds']:.3g} s at {args.rate:.3g} rays/s", file=sys.stderr)
    return 0


def _spectrum_json(s: Spectrum) -> dict[str, Any]:
    import numpy as np

    return {
        "N": int(s.N[0]), "N_per_wavelength": [int(n) for n in np.broadcast_to(s.N, s.wavelengths.shape)],
        "seed": s.seed, "geometry": s.geometry, "delta": s.delta,
        "wavelength_nm": s.wavelengths.tolist(), "reflectance": s.reflectance.tolist(),
        "transmittance": s.transmittance.tolist(), "reflectance_ci": s.reflectance_ci.tolist(),
        "transmittance_ci": s.transmittance_ci.tolist(), "absorptance": s.absorptance.tolist(),
        "quantity": s.meta.get("quantity"), "measured_as": s.meta.get("measured_as"),
        "specimen": s.meta.get("specimen"), "beam": s.meta.get("beam"),
    }


def spectrum_colour(s: Spectrum) -> dict[str, Any] | None:
    """CIE colour (D65, CIE 1931 2 deg) of the reflectance and transmittance when the wavelengths
    cover 400-700 nm: CIELAB as :func:`compare.stats.spectrum_lab` computes it (colour-science),
    and the XYZ and sRGB of that Lab under the D65 white (Y of the perfect diffuser = 1)."""
    import numpy as np

    wl = np.asarray(s.wavelengths, float)
    if wl.size < 3 or wl.min() > 400.0 or wl.max() < 700.0:
        return None
    import colour

    from compare.stats import DEFAULT_ILLUMINANT, DEFAULT_OBSERVER, spectrum_lab

    white = colour.CCS_ILLUMINANTS[DEFAULT_OBSERVER][DEFAULT_ILLUMINANT]
    out: dict[str, Any] = {"illuminant": DEFAULT_ILLUMINANT, "observer": DEFAULT_OBSERVER}
    for name, values in (("reflectance", s.reflectance), ("transmittance", s.transmittance)):
        lab, _ = spectrum_lab(wl, np.asarray(values, float), DEFAULT_ILLUMINANT, DEFAULT_OBSERVER)
        xyz = colour.Lab_to_XYZ(lab, white)
        rgb = np.clip(colour.XYZ_to_sRGB(xyz), 0.0, 1.0)
        out[name] = {"XYZ": xyz.tolist(), "Lab": lab.tolist(), "sRGB": rgb.tolist(),
                     "hex": "#" + "".join(f"{int(round(255 * c)):02x}" for c in rgb)}
    return out


def _spectro_instrument(args: argparse.Namespace):
    from virtual.spectrophotometer import VirtualSpectrophotometer

    kw: dict[str, Any] = {"beam": args.beam, "seed": args.seed, "delta": args.delta,
                          "common_random_numbers": args.common_random_numbers}
    if args.rays is not None:
        kw["rays"] = args.rays
    else:
        kw["uncertainty"] = args.uncertainty
    return VirtualSpectrophotometer(args.specimen, **kw)


def cmd_spectro(args: argparse.Namespace) -> int:
    import numpy as np

    from bench.core.geometry import cie_geometry
    from bench.core.parsing import parse_wavelengths

    cie_geometry(args.geometry)  # bad geometry: exit 2 before any work
    announce_compilation()
    sp = _spectro_instrument(args)
    if args.rays is not None or args.no_adaptive:
        _refuse_long(sp, parse_wavelengths(args.wavelengths).size, args.max_seconds, "--rays" if args.rays is not None else "the ray budget")
    adaptive = None
    if args.rays is None and not args.no_adaptive:  # --uncertainty/--delta: the adaptive rule
        from bench.adaptive import measure_adaptively

        adaptive = measure_adaptively(sp, args.uncertainty, args.delta, geometry=args.geometry,
                                      wavelengths=args.wavelengths, max_seconds=args.max_seconds,
                                      progress=stderr_is_terminal())
        s = adaptive.result
    elif stderr_is_terminal():  # progress with an ETA, one step per wavelength
        from functools import partial

        from tqdm import tqdm

        s = sp.measure(args.geometry, args.wavelengths,
                       progress=partial(tqdm, desc="spectro", unit="wl", leave=False, dynamic_ncols=True))
    else:
        s = sp.measure(args.geometry, args.wavelengths)
    if args.csv:
        from bench.io import spectrum_to_csv

        spectrum_to_csv(s, args.csv)
    stored = _store_spectrum(args, s) if args.store else None
    if args.plot:
        from compare.figures import plot_spectrum

        plot_spectrum(s, args.plot)
    if args.json:
        out = _spectrum_json(s)
        out["colour"] = spectrum_colour(s)
        if adaptive:
            out["budget"] = _budget(adaptive)
        out["run_id"] = stored
        emit_json(out)
        return 0
    if stored:
        print(f"run {stored} stored in {args.store} (bench runs / show / export / serve)")
    n = np.broadcast_to(np.asarray(s.N), s.wavelengths.shape)
    print(f"specimen {s.meta['specimen']}  geometry {s.geometry}  beam {sp.beam.kind}  "
          f"N = {n_label(n)} rays/wavelength{'' if n.min() == n.max() else ' (per wavelength in the table)'}  "
          f"seed {s.seed}  confidence {1 - s.delta:g}  "
          f"streams {'common to every specimen' if sp.common_random_numbers else 'per specimen'}")
    note = reciprocity_note(s)
    if note:
        print(note)
    if adaptive:
        from bench.adaptive import adaptive_message

        print(adaptive_message(adaptive))
    q = "RF" if s.meta.get("quantity") == "reflectance factor" else "R"
    print(f"{'nm':>7} {q:>8} {'[lo, hi]':>20} {'T':>8} {'[lo, hi]':>20} {'N':>9}")
    for i, w in enumerate(s.wavelengths):
        print(f"{w:7.1f} {s.reflectance[i]:8.5f} [{s.reflectance_ci[i, 0]:.5f}, {s.reflectance_ci[i, 1]:.5f}] "
              f"{s.transmittance[i]:8.5f} [{s.transmittance_ci[i, 0]:.5f}, {s.transmittance_ci[i, 1]:.5f}] "
              f"{int(n[i]):9d}")
    col = spectrum_colour(s)
    if col:
        print(f"colour ({col['illuminant']}, 2 deg): " + "; ".join(
            f"{k[0].upper()} XYZ {' '.join(f'{x:.4f}' for x in col[k]['XYZ'])} Lab {' '.join(f'{x:.2f}' for x in col[k]['Lab'])} "
            f"sRGB {col[k]['hex']}" for k in ("reflectance", "transmittance")))
    return 0


def n_label(n: Any) -> str:
    """``"85,505"`` when every wavelength had the same ray count, else ``"23,861-59,378"``."""
    import numpy as np

    n = np.asarray(n)
    lo, hi = int(n.min()), int(n.max())
    return f"{lo:,}" if lo == hi else f"{lo:,}-{hi:,}"


def reciprocity_note(s: Spectrum) -> str:
    """One line when the geometry was measured as its reciprocal (d/0 as 0/d, d/8 as 8/d)."""
    measured = s.meta.get("measured_as")
    if not measured or str(measured) == str(s.geometry):
        return ""
    return (f"measured as {measured} (Helmholtz reciprocity: {s.geometry} and {measured} give the same "
            f"reflectance; the instrument traces rays from the directional side)")


def _refuse_long(instrument: Any, n_wl: int, max_seconds: float, option: str) -> None:
    """Refuse a fixed ray count whose estimated time exceeds ``--max-seconds`` (every method: the
    exact fast path costs nothing per ray; counting rays runs at the stated rate, and a spectral
    batch costs at most :data:`virtual.goniophotometer.BATCH_COST` single-wavelength measurements)."""
    from virtual.goniophotometer import BATCH_COST

    fast = getattr(instrument, "uses_fast_path", lambda: False)()
    batched = bool(getattr(instrument, "batches_wavelengths", False)) and n_wl > 1
    n = int(getattr(instrument, "rays", 0) or 0)
    seconds = 0.0 if fast else estimated_seconds(n, min(n_wl, BATCH_COST) if batched else n_wl)
    if seconds > max_seconds:
        how = f" (one spectral batch, at most {BATCH_COST}x one wavelength)" if batched else ""
        raise InputError(f"{option} {n:,} x {n_wl} wavelength(s){how} would take about {seconds:,.0f} s at "
                         f"{RAYS_PER_SECOND:.0e} rays/s, more than --max-seconds {max_seconds:g}")


def gonio_json(record: BSDFRecord) -> dict[str, Any]:
    """The stable JSON of a goniophotometric record (scalars for the first wavelength)."""
    t, m = record.table, record.meta
    first = float(t.wavelength_nm.iloc[0])
    sub = t[t.wavelength_nm == first]
    patches = [{"hemisphere": r.hemisphere, "theta_min": r.theta_min, "theta_max": r.theta_max,
                "phi_min": r.phi_min, "phi_max": r.phi_max, "theta": r.theta_r, "phi": r.phi_r,
                "psa": r.psa, "count": int(r.count), "value": r.value, "ci": [r.ci_lo, r.ci_hi]}
               for r in sub.itertuples(index=False)]
    tot = m["totals"][0]
    return {"N": int(m["rays"]), "seed": m["seed"], "collector": m["collector"], "beam": m["beam"],
            "method": m["method"], "common_random_numbers": m.get("common_random_numbers", False),
            "kernel": m.get("kernel"), "specimen": m["specimen"], "incidence": [float(t.theta_i.iloc[0]),
                                                                           float(t.phi_i.iloc[0])],
            "wavelength_nm": first, "delta": m["delta"], "reflectance": tot["reflectance"],
            "transmittance": tot["transmittance"], "absorbed": tot["absorbed"], "missed": tot["missed"],
            "by_wavelength": m["totals"], "patches": patches}


def cmd_gonio(args: argparse.Namespace) -> int:
    from bench.adaptive import choose_gonio_budget, measure_gonio

    theta_i, phi_i = args.incidence
    warn_if_radians("--incidence", [theta_i] + ([phi_i] if phi_i else []))
    announce_compilation()
    kw: dict[str, Any] = {"collector": args.collector, "beam": args.beam, "seed": args.seed, "delta": args.delta,
                          "wavelengths": args.wavelengths, "method": args.method,
                          "common_random_numbers": args.common_random_numbers}
    budget = choose_gonio_budget(args.specimen, theta_i, phi_i, kw, rays=args.rays,
                                 relative_uncertainty=args.relative_uncertainty,
                                 patch_probability_uncertainty=args.patch_probability_uncertainty, delta=args.delta,
                                 adaptive=not args.no_adaptive, max_seconds=args.max_seconds,
                                 rays_per_second=RAYS_PER_SECOND)
    g = budget.instrument(args.specimen)
    if not budget.bounds_its_time:
        _refuse_long(g, len(g.wavelengths), args.max_seconds, "--rays" if args.rays is not None else "the ray budget")
    res = measure_gonio(g, budget, theta_i, phi_i, max_seconds=args.max_seconds, progress=stderr_is_terminal())
    record = res.record
    if args.csv:  # the one tidy CSV (metadata and units in FILE.json), as bench export writes it
        from bench.io import record_to_csv

        record_to_csv(record, args.csv)
    stored = _store_record(args.store, record, g.seed, vars(args)) if args.store else None
    if args.plot:
        from compare.figures import plot_bsdf_polar

        plot_bsdf_polar(record, args.plot)
    if args.json:
        out = gonio_json(record)
        if res.adaptive:
            out["budget"] = _budget(res.adaptive)
        out["uncertainty"] = res.uncertainty
        out["achieved"] = res.achieved
        out["run_id"] = stored
        emit_json(out)
        return 0
    if stored:
        print(f"run {stored} stored in {args.store} (bench runs / show / export / serve)")
    _print_gonio(res, args.max_seconds)
    return 0


def _print_gonio(res: GonioMeasurement, max_seconds: float) -> None:
    """The text report of ``bench gonio`` (a :class:`bench.adaptive.GonioMeasurement`)."""
    from bench.adaptive import INTEREST_FRACTION, PILOT_RAYS, adaptive_message, by_value

    g, m, budget, relative = res.instrument, res.record.meta, res.budget, res.budget.relative
    theta_i, phi_i = res.incidence
    print(f"specimen {m['specimen']}  incidence ({theta_i:g}, {phi_i:g}) deg  collector {g.collector}  "
          f"beam {g.beam.kind}  N = {m['rays']:,}  method {m['method']} ({m.get('kernel')} kernel)  seed {g.seed}  "
          f"streams {'common to every specimen' if g.common_random_numbers else 'per specimen'}")
    if relative is not None:
        print(f"uncertainty: relative BSDF half-width {budget.v:g} per patch of interest (pilot probability "
              f">= {INTEREST_FRACTION:g} x the brightest: {relative['patches_of_interest']} of {relative['patches']} "
              f"patches), each patch's {1 - budget.delta:g} interval; N from a {PILOT_RAYS:,}-ray pilot")
        if relative["capped"]:
            names = ", ".join(f"({t:.1f}, {p:.1f})" for t, p in relative["unreachable_patches"][:8])
            print(f"  cannot meet it for {len(relative['unreachable_patches'])} patches within --max-seconds "
                  f"{max_seconds:g} ({relative['needed']:,} rays needed; capped at {relative['N']:,}): {names}")
    elif budget.kind != "fixed rays":
        print(f"uncertainty: patch probability (eq. 3.12) v = {budget.v:g} -- an absolute "
              f"bound on each patch's probability, not on its BSDF")
    if res.adaptive:
        print(adaptive_message(res.adaptive))
    b, d = res.achieved["brightest"], res.achieved["dimmest_of_interest"]
    print(f"  achieved relative half-width: brightest patch ({b['theta']:.1f}, {b['phi']:.1f}) "
          f"{b['relative_half_width']:.3g}; dimmest patch of interest ({d['theta']:.1f}, {d['phi']:.1f}) "
          f"{d['relative_half_width']:.3g}")
    for tot in m["totals"]:
        print(f"  {tot['wavelength_nm']:7.1f} nm  reflectance {tot['reflectance']:.5f}  "
              f"transmittance {tot['transmittance']:.5f}  absorbed {tot['absorbed']:,}  {_method_note(tot)}")
    top = by_value(res.record.table).head(5)
    print("  brightest patches (hemisphere, theta, phi, BSDF [1/sr], interval):")
    for r in top.itertuples(index=False):
        print(f"    {r.hemisphere}  {r.theta_r:6.2f} {r.phi_r:7.2f}  {r.value:.5g}  [{r.ci_lo:.5g}, {r.ci_hi:.5g}]")


def _store_spectrum(args: argparse.Namespace, s: Spectrum) -> str:
    """Store a spectrum as a run: per wavelength a reflectance (R) and a transmittance (T) row,
    as a spectrophotometric sweep stores them (:func:`bench.sweep.task.spectrum_rows`)."""
    import numpy as np

    from bench.core.geometry import cie_geometry
    from bench.core.records import BSDFRecord
    from bench.sweep.task import spectrum_rows

    rows = spectrum_rows(s, args.geometry)
    rows["theta_i"], rows["phi_i"] = float(cie_geometry(args.geometry).theta_i), 0.0
    r_quantity = "reflectance factor" if s.meta.get("quantity") == "reflectance factor" else "reflectance"
    rows["quantity"] = np.where(rows["hemisphere"] == "T", "transmittance", r_quantity)
    meta = {"specimen": s.meta.get("specimen"), "geometry": str(s.geometry), "quantity": "reflectance",
            "body": "virtual", "bench_name": "virtual-spectro", "plan_name": "spectro", "seed": s.seed,
            "delta": s.delta, "instrument": "spectro"}
    return _store_record(args.store, BSDFRecord(rows, meta), s.seed, vars(args), "spectro")


def _store_record(path: str, record: BSDFRecord, seed: int | None, options: dict[str, Any], command: str = "gonio") -> str:
    """Store a virtual measurement as a completed run of kind ``virtual``; return its id."""
    from bench.cli.common import open_store

    plan = {"name": command, "command": f"bench {command}",
            "options": {k: v for k, v in options.items()
                        if k not in ("func", "store", "csv", "plot", "json", "force", "output_dests", "output_sidecars")}}
    with open_store(path) as store:
        rid = store.create_run("virtual", plan=plan, seed=seed, n_planned=1,
                               meta={k: v for k, v in record.meta.items() if k != "totals"})
        store.add_record(rid, record, merge_meta=False)
        store.set_status(rid, "completed")
    return rid


def _method_note(tot: dict[str, Any]) -> str:
    """Which method counted one wavelength and, for the fast path, its certified quadrature error."""
    if tot.get("method") == "fast":
        return f"[fast, quadrature error <= {tot['quadrature_error']:.1e}]"
    if "fallback_reason" in tot:
        return f"[rays: fast path not certified: {tot['fallback_reason']}]"
    return "[rays]"


def _budget(adaptive: Any) -> dict[str, Any]:
    """The ``budget`` object of ``--json`` (a :class:`bench.adaptive.AdaptiveOutcome`)."""
    return {k: getattr(adaptive, k) for k in ("N", "hoeffding_N", "saved_rays", "saved_fraction", "per_wavelength",
                                              "mode")}


def _run_options(p: argparse.ArgumentParser) -> None:
    """The options spectro and gonio share: the time limit, the seed, the streams, JSON output."""
    p.add_argument("--max-seconds", type=real(0.0, 1e9, lo_open=True), default=3600.0,
                   help=f"time limit, s: refuse work estimated to take longer, for every method (rays counted at "
                        f"{RAYS_PER_SECOND:.0e} rays/s; default %(default)g)")
    p.add_argument("--seed", type=seed, help="root seed, integer 0..2^63-1 (default: a fresh one, printed)")
    p.add_argument("--common-random-numbers", action="store_true",
                   help="one random stream whatever the specimen, for lower-variance model comparisons "
                        "(default: a stream per specimen)")
    p.add_argument("--json", action="store_true", help="one JSON object with stable keys")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``rays``, ``spectro`` and ``gonio`` to the ``bench`` subcommands."""
    r = sub.add_parser("rays", help=command_help("rays"))
    r.add_argument("--uncertainty", "-u", type=real(0.0, 1.0, lo_open=True, hi_open=True), required=True,
                   help="absolute uncertainty v of the real instrument (a fraction in (0, 1); required)")
    r.add_argument("--delta", "-d", type=real(0.0, 1.0, lo_open=True, hi_open=True), required=True,
                   help="confidence delta, in (0, 1) (required)")
    r.add_argument("--patches", type=count(1, MAX_PATCHES), default=1,
                   help="collector patches m for eq. 3.12 (count; default %(default)s)")
    r.add_argument("--rate", type=real(0.0, 1e15, lo_open=True), default=5e7,
                   help="rays/s for the time estimate in --json (default %(default)g)")
    r.add_argument("--json", action="store_true", help="one JSON object instead of the ray count")
    r.set_defaults(func=cmd_rays)

    s = sub.add_parser("spectro", help=command_help("spectro"))
    s.add_argument("--specimen", required=True, help="e.g. 'lambert:reflectance=0.375', 'colorchecker:dark skin' "
                   "(required; `bench specimens` lists the families)")
    s.add_argument("--geometry", default="8/d", help="CIE geometry: 45/0, 0/45, d/0, 0/d, 8/d, 8/de (default %(default)s)")
    s.add_argument("--wavelengths", type=wavelengths, default="400:700:10",
                   help="START:STOP:STEP or a,b,c in nm (default %(default)s)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--rays", type=rays, help=f"rays per wavelength (count, 1 to {MAX_RAYS:.0e}; default: from --uncertainty)")
    g.add_argument("--uncertainty", type=real(0.0, 1.0, lo_open=True, hi_open=True), default=0.005,
                   help="absolute uncertainty v of R and T for eq. 3.5, a fraction in (0, 1) (default %(default)s)")
    s.add_argument("--delta", type=real(0.0, 1.0, lo_open=True, hi_open=True), default=0.01,
                   help="confidence delta in (0, 1) (default %(default)s)")
    s.add_argument("--beam", choices=("collimated", "conical"), default="collimated", help="beam (default %(default)s)")
    s.add_argument("--no-adaptive", action="store_true",
                   help="with --uncertainty: the fixed eq. 3.5 ray count instead of the adaptive rule")
    _run_options(s)
    s.add_argument("--plot", type=output_file(PLOT_SUFFIXES), metavar="FILE.png",
                   help="also draw the spectrum to this image (png, pdf, svg, ...; default: none)")
    s.add_argument("--csv", type=output_file(), metavar="FILE", help="also write the spectrum as CSV (default: none)")
    s.add_argument("--store", metavar="FILE.sqlite", default=None,
                   help="also store the spectrum as a run (bench runs/show/export/serve read it; default: not stored)")
    add_force_option(s, "csv", "plot")
    s.set_defaults(func=cmd_spectro)

    g = sub.add_parser("gonio", help=command_help("gonio"))
    g.add_argument("--specimen", required=True, help="e.g. 'lambert:albedo=0.5', 'ggx:alpha=0.2,eta=1.5,k=0' "
                   "(required; `bench specimens` lists the families)")
    g.add_argument("--incidence", type=incidence, default=(30.0, 0.0), metavar="THETA[,PHI]",
                   help="incidence in degrees, THETA in [0, 90] (default 30,0)")
    g.add_argument("--collector", type=collector, default="equal-psa:9x36",
                   help=f"SCHEME:RINGSxSECTORS, at most {MAX_PATCHES:,} patches (default %(default)s)")
    gb = g.add_mutually_exclusive_group()
    gb.add_argument("--rays", type=rays, help="rays per wavelength (count; default 1e7)")
    gb.add_argument("--relative-uncertainty", type=real(0.0, 1.0, lo_open=True, hi_open=True), metavar="V",
                    help="relative uncertainty of each patch's BSDF (interval half-width / value), a fraction in "
                         "(0, 1), for every patch of interest; N from a pilot run (default: --rays)")
    gb.add_argument("--patch-probability-uncertainty", type=real(0.0, 1.0, lo_open=True, hi_open=True), metavar="V",
                    help="v of eq. 3.12: an absolute bound on each patch's probability, in (0, 1) (the seed's "
                         "meaning; default: none)")
    renamed(g, "--uncertainty", "--relative-uncertainty", "is an absolute uncertainty in every command (bench rays, "
            "bench spectro); gonio's relative uncertainty of each patch's BSDF is spelled out")
    g.add_argument("--delta", type=real(0.0, 1.0, lo_open=True, hi_open=True), default=0.01,
                   help="confidence delta in (0, 1) (default %(default)s)")
    g.add_argument("--wavelengths", type=wavelengths, default="550", help="START:STOP:STEP or a,b,c in nm (default %(default)s)")
    g.add_argument("--beam", choices=("collimated", "conical"), default="collimated", help="beam (default %(default)s)")
    g.add_argument("--method", choices=("auto", "rays", "fast"), default="auto",
                   help="rays: count rays; fast: one multinomial over integrated patch probabilities; "
                        "auto: fast when exact, except rays for several wavelengths of a specimen whose "
                        "wavelengths batch (default %(default)s)")
    g.add_argument("--no-adaptive", action="store_true",
                   help="with --patch-probability-uncertainty: the fixed eq. 3.12 ray count instead of the "
                        "adaptive rule")
    _run_options(g)
    g.add_argument("--csv", type=output_file(), metavar="FILE",
                   help="also write the record as tidy CSV, metadata and units in FILE.json (default: none)")
    g.add_argument("--store", metavar="FILE.sqlite", default=None,
                   help="also store the record as a run (bench runs/show/export/serve read it; default: not stored)")
    g.add_argument("--plot", type=output_file(PLOT_SUFFIXES), metavar="FILE.png",
                   help="also draw a polar plot to this image (png, pdf, svg, ...; default: none)")
    add_force_option(g, "csv", "plot", sidecars=("csv",))
    g.set_defaults(func=cmd_gonio)
