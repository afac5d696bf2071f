"""goniobench: one instrument interface for real, emulated and virtual goniophotometry benches.

The names a user imports are exported here (``from bench import load_bench, run_scan, RunStore``),
each loaded on first use (:mod:`bench.core.exports`), so ``import bench`` stays cheap. The other
public packages are :mod:`bench.bluesky` (ophyd-async devices and plans), :mod:`virtual`,
:mod:`drivers` and :mod:`compare`; the console script is ``bench`` (:func:`bench.cli.main`). Any
other module is an implementation detail and may change without notice.
"""

from bench.core.exports import lazy_exports

__version__ = "0.1.0"

#: each public name and the module that defines it
_WHERE = {
    # the instrument interface: roles, records, geometry, the conformance checker
    **dict.fromkeys(["Instrument", "Goniometer", "Spectrometer", "LightSource", "Spectrophotometer", "InstrumentBase",
                     "InstrumentInfo"], "bench.core.roles"),
    **dict.fromkeys(["Reading", "Spectrum", "BSDFRecord"], "bench.core.records"),
    **dict.fromkeys(["Geometry", "cie_geometry", "CIE_GEOMETRIES"], "bench.core.geometry"),
    **dict.fromkeys(["check_conformance", "ConformanceError"], "bench.core.conformance"),
    # errors: one line naming what is wrong, a typed class per failure
    **dict.fromkeys(["BenchError", "InputError", "ConfigError", "SpecimenError", "GeometryError", "PlanError",
                     "DeviceError", "CommunicationError", "DeviceTimeoutError", "HardwareError", "CalibrationError",
                     "StoreError", "RunInterrupted"], "bench.core.errors"),
    # benches, plans, runs and the store
    **dict.fromkeys(["Bench", "load_bench"], "bench.config"),
    **dict.fromkeys(["Plan", "load_plan", "plan_from_dict"], "bench.plans"),
    **dict.fromkeys(["run_scan", "resume_scan", "ScanResult"], "bench.runner"),
    "RunStore": "bench.store",
    # record files: one registry of formats
    **dict.fromkeys(["read_record", "export_record", "export_run", "load_run", "FileFormat", "register_format",
                     "formats"], "bench.io"),
    # sweeps of virtual measurements
    **dict.fromkeys(["load_sweep", "sweep_from_dict", "run_sweep", "resume_sweep", "SweepResult"], "bench.sweep"),
    # identification: fit a model to a record
    **dict.fromkeys(["fit_record", "FitResult", "parse_model_spec", "ModelSpec"], "bench.identify"),
}

__all__ = ["__version__"] + list(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)
