"""``bench compare ACTUAL CANDIDATE [CANDIDATE ...]``: discrepancy statistics and a report.

Each record is a run id in ``--store`` or a file in any format of the :mod:`bench.io` registry
(tidy CSV, Parquet, ASTM CSV, Zemax ``.bsdf``, spectrum CSV); ``NAME=RUN`` labels a record. The
files are read here, through :func:`bench.io.read_record`: :mod:`compare` takes records only.
The summary keys of ``--json`` are stable.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from bench.cli.common import DEFAULT_STORE, output_dir
from bench.core.errors import InputError

HEADLINE = ("n_points", "mean_abs_discrepancy_pct", "rmse", "bias", "max_abs", "chi2", "p_value",
            "fraction_within_uncertainty", "delta_e2000_mean")


def _load(ref: str, store_path: str) -> tuple[str, Any]:
    """(label, record) for ``[NAME=]RUN_OR_FILE``."""
    name, _, what = ref.rpartition("=") if "=" in ref and not Path(ref).exists() else ("", "", ref)
    path = Path(what)
    if path.exists():
        from bench.io import read_record

        return name or path.stem, read_record(path)
    from bench.store import RunStore

    if not Path(store_path).exists():
        raise InputError(f"{what!r} is neither a file nor a run (no store at {store_path})")
    with RunStore(store_path, create=False, readonly=True) as store:
        record = store.to_record(what)
    spec = (record.meta.get("bench") or {}).get("specimen", {}).get("spec")
    return name or (f"{what} ({spec})" if spec else what), record


def cmd_compare(args: argparse.Namespace) -> int:
    from compare.report import compare_records

    actual_name, actual = _load(args.actual, args.store)
    candidates = dict(_load(c, args.store) for c in args.candidates)
    out = Path(args.report or "compare-report")
    summary = compare_records(actual, candidates, out, primary_metric=args.metric,
                              title=args.title or f"{', '.join(candidates)} against {actual_name}",
                              on_error="skip" if args.skip_bad else "raise")
    if args.json:
        print(json.dumps(summary))
        return 0
    print(f"actual: {actual_name}")
    for rank, entry in enumerate(summary["ranking"], 1):
        name = entry["name"]
        s = summary["candidates"][name]
        parts = [f"{k} {s[k]:.4g}" for k in HEADLINE if isinstance(s.get(k), (int, float))]
        print(f"  #{rank} {name}: " + ", ".join(parts))
    for name, err in summary["errors"].items():
        print(f"  not compared: {name}: {err}")
    for w in summary["warnings"]:
        print(f"  warning: {w}")
    print(f"report: {summary['report_html']} (and {summary['report_md']})")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="compare candidate records (virtual models) with an actual one")
    p.add_argument("actual", metavar="ACTUAL", help="[NAME=]RUN or FILE")
    p.add_argument("candidates", metavar="CANDIDATE", nargs="+", help="[NAME=]RUN or FILE")
    p.add_argument("--store", default=DEFAULT_STORE, metavar="FILE.sqlite",
                   help="the run store holding RUN ids, opened read-only (default %(default)s)")
    p.add_argument("--report", type=output_dir, metavar="DIR", help="report folder (default ./compare-report)")
    p.add_argument("--metric", default="chi2_per_dof",
                   choices=("chi2_per_dof", "mean_abs_discrepancy_pct", "rmse", "abs_bias", "max_abs",
                            "delta_e2000_mean"), help="ranking metric, lower is better (default %(default)s)")
    p.add_argument("--title", help="report title (default: the candidates against the actual)")
    p.add_argument("--skip-bad", action="store_true", help="leave out candidates that cannot be compared")
    p.add_argument("--json", action="store_true", help="the summary as one JSON object with stable keys")
    p.set_defaults(func=cmd_compare)
