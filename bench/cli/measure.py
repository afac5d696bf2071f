"""``bench rays``, ``bench spectro`` and ``bench gonio``: one virtual measurement, printed.

``--uncertainty/--delta`` measurements use the adaptive rule of :mod:`bench.adaptive`; ``--csv``
goes through the one CSV writer of :mod:`bench.io`, ``--plot`` through :mod:`compare.figures`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from bench.cli.common import emit_json, number, positive_int
from bench.core.errors import InputError

__all__ = ["register", "cmd_rays", "cmd_spectro", "cmd_gonio", "gonio_json"]


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


def _spectrum_json(s: Any) -> dict[str, Any]:
    return {
        "N": int(s.N[0]), "seed": s.seed, "geometry": s.geometry, "delta": s.delta,
        "wavelength_nm": s.wavelengths.tolist(), "reflectance": s.reflectance.tolist(),
        "transmittance": s.transmittance.tolist(), "reflectance_ci": s.reflectance_ci.tolist(),
        "transmittance_ci": s.transmittance_ci.tolist(), "absorptance": s.absorptance.tolist(),
        "quantity": s.meta.get("quantity"), "measured_as": s.meta.get("measured_as"),
        "specimen": s.meta.get("specimen"), "beam": s.meta.get("beam"),
    }


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
    from bench.core.geometry import cie_geometry

    cie_geometry(args.geometry)  # bad geometry: exit 2 before any work
    sp = _spectro_instrument(args)
    adaptive = None
    if args.rays is None and not args.no_adaptive:  # --uncertainty/--delta: the adaptive rule
        from bench.adaptive import adaptive_measure

        adaptive = adaptive_measure(sp, args.uncertainty, args.delta, geometry=args.geometry,
                                    wavelengths=args.wavelengths, max_seconds=args.max_seconds)
        s = adaptive["result"]
    else:
        s = sp.measure(args.geometry, args.wavelengths)
    if args.csv:
        from bench.io import spectrum_to_csv

        spectrum_to_csv(s, args.csv)
    if args.plot:
        from compare.figures import plot_spectrum

        plot_spectrum(s, args.plot)
    if args.json:
        out = _spectrum_json(s)
        if adaptive:
            out["budget"] = _budget(adaptive)
        emit_json(out)
        return 0
    print(f"specimen {s.meta['specimen']}  geometry {s.geometry}  beam {sp.beam.kind}  "
          f"N = {int(s.N[0])} rays/wavelength  seed {s.seed}  confidence {1 - s.delta:g}  "
          f"streams {'common to every specimen' if sp.common_random_numbers else 'per specimen'}")
    if adaptive:
        print(adaptive["message"])
    q = "RF" if s.meta.get("quantity") == "reflectance factor" else "R"
    print(f"{'nm':>7} {q:>8} {'[lo, hi]':>20} {'T':>8} {'[lo, hi]':>20}")
    for i, w in enumerate(s.wavelengths):
        print(f"{w:7.1f} {s.reflectance[i]:8.5f} [{s.reflectance_ci[i, 0]:.5f}, {s.reflectance_ci[i, 1]:.5f}] "
              f"{s.transmittance[i]:8.5f} [{s.transmittance_ci[i, 0]:.5f}, {s.transmittance_ci[i, 1]:.5f}]")
    return 0


def _incidence(text: str) -> tuple[float, float]:
    try:
        parts = [float(p) for p in str(text).split(",")]
    except ValueError:
        raise InputError(f"--incidence {text!r}: expected THETA or THETA,PHI in degrees") from None
    if len(parts) not in (1, 2):
        raise InputError(f"--incidence {text!r}: expected THETA or THETA,PHI in degrees")
    return parts[0], (parts[1] if len(parts) == 2 else 0.0)


def gonio_json(record: Any) -> dict[str, Any]:
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
    from virtual.goniophotometer import VirtualGoniophotometer

    theta_i, phi_i = _incidence(args.incidence)
    kw: dict[str, Any] = {"collector": args.collector, "beam": args.beam, "seed": args.seed, "delta": args.delta,
                          "wavelengths": args.wavelengths, "method": args.method,
                          "common_random_numbers": args.common_random_numbers}
    if args.rays is not None:
        kw["rays"] = args.rays
    elif args.uncertainty is not None:
        kw["uncertainty"] = args.uncertainty
    g = VirtualGoniophotometer(args.specimen, **kw)
    adaptive = None
    if args.uncertainty is not None and args.rays is None and not args.no_adaptive:
        from bench.adaptive import adaptive_measure

        adaptive = adaptive_measure(g, args.uncertainty, args.delta, theta_i=theta_i, phi_i=phi_i,
                                    max_seconds=args.max_seconds)
        record = adaptive["result"]
    else:
        record = g.measure_bsdf(theta_i, phi_i)
    if args.csv:
        from bench.io import write_csv

        write_csv(record.table, args.csv, float_format="%.8g")
    if args.plot:
        from compare.figures import plot_bsdf_polar

        plot_bsdf_polar(record, args.plot)
    if args.json:
        out = gonio_json(record)
        if adaptive:
            out["budget"] = _budget(adaptive)
        emit_json(out)
        return 0
    m = record.meta
    print(f"specimen {m['specimen']}  incidence ({theta_i:g}, {phi_i:g}) deg  collector {g.collector}  "
          f"beam {g.beam.kind}  N = {m['rays']:,}  method {m['method']} ({m.get('kernel')} kernel)  seed {g.seed}  "
          f"streams {'common to every specimen' if g.common_random_numbers else 'per specimen'}")
    if adaptive:
        print(adaptive["message"])
    for tot in m["totals"]:
        print(f"  {tot['wavelength_nm']:7.1f} nm  reflectance {tot['reflectance']:.5f}  "
              f"transmittance {tot['transmittance']:.5f}  absorbed {tot['absorbed']:,}  {_method_note(tot)}")
    t = record.table
    top = t.sort_values("value", ascending=False).head(5)
    print("  brightest patches (hemisphere, theta, phi, BSDF [1/sr], interval):")
    for r in top.itertuples(index=False):
        print(f"    {r.hemisphere}  {r.theta_r:6.2f} {r.phi_r:7.2f}  {r.value:.5g}  [{r.ci_lo:.5g}, {r.ci_hi:.5g}]")
    return 0


def _method_note(tot: dict[str, Any]) -> str:
    """Which method counted one wavelength and, for the fast path, its certified quadrature error."""
    if tot.get("method") == "fast":
        return f"[fast, quadrature error <= {tot['quadrature_error']:.1e}]"
    if "fallback_reason" in tot:
        return f"[rays: fast path not certified: {tot['fallback_reason']}]"
    return "[rays]"


def _budget(adaptive: dict[str, Any]) -> dict[str, Any]:
    return {k: adaptive[k] for k in ("N", "hoeffding_N", "saved_rays", "saved_fraction", "per_wavelength", "mode")}


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``rays``, ``spectro`` and ``gonio`` to the ``bench`` subcommands."""
    r = sub.add_parser("rays", help="ray budget of eq. 3.5 (eq. 3.12 with --patches)")
    r.add_argument("--uncertainty", "-u", type=number, required=True, help="uncertainty v of the real instrument")
    r.add_argument("--delta", "-d", type=number, required=True, help="confidence delta, in (0, 1)")
    r.add_argument("--patches", type=int, default=1, help="collector patches m (eq. 3.12)")
    r.add_argument("--rate", type=number, default=5e7, help="rays/s for the time estimate in --json (default 5e7)")
    r.add_argument("--json", action="store_true")
    r.set_defaults(func=cmd_rays)

    s = sub.add_parser("spectro", help="virtual spectrophotometric measurement")
    s.add_argument("--specimen", required=True, help="e.g. 'lambert:reflectance=0.375', 'colorchecker:dark skin'")
    s.add_argument("--geometry", default="8/d", help="CIE geometry: 45/0, 0/45, d/0, 0/d, 8/d, 8/de")
    s.add_argument("--wavelengths", default="400:700:10", help="START:STOP:STEP or a,b,c (nm)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--rays", type=positive_int, help="rays per wavelength")
    g.add_argument("--uncertainty", type=number, default=0.005, help="v for eq. 3.5 (default 0.005)")
    s.add_argument("--delta", type=number, default=0.01, help="confidence delta (default 0.01)")
    s.add_argument("--beam", choices=("collimated", "conical"), default="collimated")
    s.add_argument("--no-adaptive", action="store_true",
                   help="with --uncertainty: the fixed eq. 3.5 ray count instead of the adaptive rule")
    s.add_argument("--max-seconds", type=number, default=3600.0,
                   help="refuse budgets estimated to take longer (reports N and the time)")
    s.add_argument("--seed", type=int)
    s.add_argument("--common-random-numbers", action="store_true",
                   help="one random stream whatever the specimen (default: a stream per specimen)")
    s.add_argument("--json", action="store_true")
    s.add_argument("--plot", metavar="FILE.png")
    s.add_argument("--csv", metavar="FILE")
    s.set_defaults(func=cmd_spectro)

    g = sub.add_parser("gonio", help="virtual goniophotometric measurement (whole collector sphere)")
    g.add_argument("--specimen", required=True, help="e.g. 'lambert:albedo=0.5', 'ggx:alpha=0.2,eta=1.5,k=0'")
    g.add_argument("--incidence", default="30", help="THETA[,PHI] in degrees (default 30)")
    g.add_argument("--collector", default="equal-psa:9x36", help="SCHEME:NTHxNPHI, e.g. equal-psa:9x36")
    gb = g.add_mutually_exclusive_group()
    gb.add_argument("--rays", type=positive_int, help="rays per wavelength (default 1e7)")
    gb.add_argument("--uncertainty", type=number, help="v for eq. 3.12 (patches = collector patches)")
    g.add_argument("--delta", type=number, default=0.01)
    g.add_argument("--wavelengths", default="550", help="START:STOP:STEP or a,b,c (nm)")
    g.add_argument("--beam", choices=("collimated", "conical"), default="collimated")
    g.add_argument("--method", choices=("auto", "rays", "fast"), default="auto",
                   help="rays: count rays; fast: one multinomial over integrated patch probabilities")
    g.add_argument("--no-adaptive", action="store_true",
                   help="with --uncertainty: the fixed eq. 3.12 ray count instead of the adaptive rule")
    g.add_argument("--max-seconds", type=number, default=3600.0,
                   help="refuse budgets estimated to take longer (reports N and the time)")
    g.add_argument("--seed", type=int)
    g.add_argument("--common-random-numbers", action="store_true",
                   help="one random stream whatever the specimen (default: a stream per specimen)")
    g.add_argument("--json", action="store_true")
    g.add_argument("--csv", metavar="FILE")
    g.add_argument("--plot", metavar="FILE.png")
    g.set_defaults(func=cmd_gonio)
