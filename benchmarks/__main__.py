"""Run the benchmark studies: ``python -m benchmarks [NAME ...]``."""

from __future__ import annotations

import importlib
import sys

STUDIES = ["spectro", "gonio", "store", "scan", "effects", "adaptive", "tradeoff", "sweep"]


def main(argv: list[str]) -> int:
    names = argv or STUDIES
    for name in names:
        if name not in STUDIES:
            print(f"unknown study {name!r}; known: {', '.join(STUDIES)}", file=sys.stderr)
            return 2
        module = importlib.import_module(f"benchmarks.bench_{name}")
        print(module.run())
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
