"""How often a driver's transactions failed and recovered: :class:`FaultLog`.

Every driver keeps one (``.faults``) and its retry loop reports each failed attempt (by kind:
``timeout``, ``corrupt``, ``foreign`` for a status or reply answering another request, ``nak``,
``exception`` for a transient Modbus exception) and each transaction's outcome. The runner reads
:meth:`FaultLog.snapshot` before and after a point and records the difference with the point, so
a long run says how many transient faults it rode through, and where.
"""

from __future__ import annotations

from collections import Counter

__all__ = ["FaultLog"]


class FaultLog:
    """Counts of failed attempts by kind, recovered and failed transactions, and stale
    statuses discarded without costing an attempt."""

    def __init__(self) -> None:
        self.kinds: Counter[str] = Counter()
        self.retries = 0      # attempts made again after a failed one
        self.recovered = 0    # transactions that failed at least once, then succeeded
        self.failed = 0       # transactions that failed through every attempt (a typed error)
        self.discarded = 0    # stale or foreign statuses skipped inside an attempt

    def attempt_failed(self, kind: str, will_retry: bool) -> None:
        self.kinds[kind] += 1
        if will_retry:
            self.retries += 1

    def finished(self, failed_attempts: int, ok: bool) -> None:
        """One transaction ended after ``failed_attempts`` failed attempts, well or not."""
        if not ok:
            self.failed += 1
        elif failed_attempts:
            self.recovered += 1

    def snapshot(self) -> dict[str, int]:
        """Flat counts: ``retries``, ``recovered``, ``failed``, ``discarded`` and ``fault.KIND``."""
        out = {"retries": self.retries, "recovered": self.recovered, "failed": self.failed,
               "discarded": self.discarded}
        out.update({f"fault.{k}": v for k, v in sorted(self.kinds.items())})
        return out

