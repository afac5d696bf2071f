"""Run the benchmark studies: ``python -m benchmarks [NAME ...]``.

``python -m benchmarks gonio --json`` prints the goniophotometer's rows and ratios as JSON
(:func:`benchmarks.bench_gonio.measure`), ``python -m benchmarks cli --json`` the CLI's warm
command times (:func:`benchmarks.bench_cli.measure`). ``python -m benchmarks --check`` measures them and
fails (exit 1) when a ratio fell by more than :data:`benchmarks.guard.TOLERANCE` against the
accepted ones of this CPU's family (``benchmarks/accepted_ratios.json``, keyed by
:func:`benchmarks.guard.family`); ``--accept`` rewrites that family's entry with this run's ratios. Neither is part of ``make test``: timings on a shared machine are noisy.
``python -m benchmarks gonio --isa avx2`` compiles both sides of the comparison for AVX2 on a
wider CPU (:mod:`benchmarks.isa`), so one machine measures what an AVX2 one would see.
``python -m benchmarks soak --minutes N --json`` (``make soak``) is the fault-injection soak of
:mod:`benchmarks.soak`.
"""

from __future__ import annotations

import importlib
import json
import sys

STUDIES = ["spectro", "gonio", "store", "scan", "effects", "adaptive", "tradeoff", "sweep", "cli", "design", "serve"]
FLAGS = ("--json", "--check", "--accept")


def _isa_option(argv: list[str]) -> tuple[str | None, list[str]]:
    """``--isa NAME`` / ``--isa=NAME`` taken out of ``argv``: (NAME or None, the rest)."""
    isa, rest, i = None, [], 0
    while i < len(argv):
        a = argv[i]
        if a == "--isa":
            isa = argv[i + 1] if i + 1 < len(argv) else ""
            i += 2
            continue
        if a.startswith("--isa="):
            isa = a.split("=", 1)[1]
        else:
            rest.append(a)
        i += 1
    return isa, rest


def main(argv: list[str]) -> int:
    isa, argv = _isa_option(argv)
    if isa is not None:
        from benchmarks.isa import ISAS, reexec, requested

        if isa not in ISAS:
            print(f"--isa must be one of {', '.join(ISAS)}, got {isa!r}", file=sys.stderr)
            return 2
        if any(n != "gonio" for n in argv if not n.startswith("--")) or not argv:
            print("--isa applies to the gonio study only: python -m benchmarks gonio --isa avx2", file=sys.stderr)
            return 2
        if isa != requested():
            reexec(isa, argv)  # numba reads its target at import: a fresh interpreter
    if argv[:1] == ["soak"]:  # its own options (benchmarks/soak.py); not a timing study
        from benchmarks.soak import main as soak

        return soak(argv[1:])
    flags = [a for a in argv if a.startswith("--")]
    names = [a for a in argv if not a.startswith("--")]
    bad = [f for f in flags if f not in FLAGS]
    if bad:
        print(f"unknown option {bad[0]!r}; known: {', '.join(FLAGS)}", file=sys.stderr)
        return 2
    if flags == ["--json"] and names == ["cli"]:
        from benchmarks.bench_cli import measure as measure_cli

        print(json.dumps(measure_cli(), indent=2))
        return 0
    if flags:
        if any(n != "gonio" for n in names):
            print("--json applies to the gonio and cli studies, --check and --accept to gonio only",
                  file=sys.stderr)
            return 2
        from benchmarks import guard
        from benchmarks.bench_gonio import measure

        m = measure()
        if "--json" in flags:
            print(json.dumps(m, indent=2))
        code, fam = 0, guard.family(m["cpu"])
        if "--check" in flags:
            code, report = guard.check(m["ratios"], guard.load(fam))
            print(f"CPU family {fam}\n{report}", file=sys.stderr if "--json" in flags else sys.stdout)
        if "--accept" in flags:
            path = guard.accept(m["ratios"], fam)
            print(f"accepted ratios of CPU family {fam} written to {path}", file=sys.stderr)
        return code
    for name in names or STUDIES:
        if name not in STUDIES:
            print(f"unknown study {name!r}; known: {', '.join(STUDIES)}", file=sys.stderr)
            return 2
        module = importlib.import_module(f"benchmarks.bench_{name}")
        print(module.run())
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
