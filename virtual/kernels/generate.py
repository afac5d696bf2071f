"""``python -m virtual.kernels.generate`` (``make kernels``): write the code generated from the
laws of :mod:`virtual.kernels.laws` (:mod:`virtual.kernels.lawcode`: the float32 twins and the
dispatch, build products git ignores, and the checked-in :mod:`virtual.law_table`), each file only
when its text differs. ``--check`` writes nothing and exits 1 naming every stale file.

Importing :mod:`virtual.kernels` already writes the build products when missing or stale; this
command also writes the law table, removes the twins of laws that are gone, and says what it wrote.
"""

from __future__ import annotations

import argparse
import sys

from virtual.kernels.lawcode import KERNELS, VIRTUAL, generated_files, stale, write_changed

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Exit 0 when written, 1 when ``--check`` finds stale files, 2 (one line) for a law that breaks
    its contract (:mod:`virtual.kernels.laws`: a taken model id, a missing constant, ...)."""
    try:
        return _main(argv)
    except SystemExit as e:
        if isinstance(e.code, str):  # the generator's refusals are one line naming the file
            print(f"python -m virtual.kernels.generate: error: {e.code}", file=sys.stderr)
            return 2
        raise


def _main(argv: list[str] | None) -> int:
    ap = argparse.ArgumentParser(prog="python -m virtual.kernels.generate", description="Write the kernel code generated from the scattering laws.")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 naming the stale files")
    args = ap.parse_args(argv)
    if args.check:
        bad = stale()
        for p in bad:
            print(f"stale: {p.relative_to(VIRTUAL.parent)} (run `make kernels`)")
        return 1 if bad else 0
    files = generated_files()
    for p in (KERNELS / "laws32").glob("*.py"):
        if p not in files:
            p.unlink()
    for p in write_changed(files):
        print(f"wrote {p.relative_to(VIRTUAL.parent)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
