"""Every bench as Bluesky / ophyd-async devices (optional extra ``goniobench[bluesky]``).

>>> from bluesky import RunEngine                                   # doctest: +SKIP
>>> from bluesky.plans import scan
>>> from bench.bluesky import connect, StoreWriter
>>> RE = RunEngine(); devs = connect("fixtures/benches/virtual.toml", run_engine=RE)
>>> RE.subscribe(StoreWriter("runs.sqlite"))
>>> RE(scan([devs.reflectance], devs.goniometer.theta_r, -60, 60, 13))

Modules: :mod:`~bench.bluesky.worker` (the bench's one worker thread),
:mod:`~bench.bluesky.goniometer` (axes and the mover), :mod:`~bench.bluesky.detectors`
(spectrometer, reflectance, light), :mod:`~bench.bluesky.connect`,
:mod:`~bench.bluesky.plans` (``plan_from_toml``, the sequential design ``sequential_fit``),
:mod:`~bench.bluesky.assurance` (``check_standards``: ``bench check``) and :mod:`~bench.bluesky.store_writer`.
Our own runner stays for what the RunEngine lacks (whole-plan validation before the run is
created, resume after SIGKILL).
"""

from bench.bluesky.assurance import check_standards
from bench.bluesky.connect import METADATA_KEY, Devices, connect
from bench.bluesky.plans import sequential_fit, plan_from_toml
from bench.bluesky.store_writer import StoreWriter

__all__ = ["connect", "Devices", "plan_from_toml", "sequential_fit", "check_standards", "StoreWriter", "METADATA_KEY"]
