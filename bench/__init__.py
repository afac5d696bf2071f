"""goniobench: one instrument interface for real, emulated and virtual goniophotometry benches.

The names a user imports are exported here (``from bench import load_bench, run_scan, RunStore``),
each loaded on first use (:mod:`bench.core.exports`), so ``import bench`` stays cheap. The other
public packages are :mod:`bench.bluesky` (ophyd-async devices and plans), :mod:`virtual`,
:mod:`drivers` and :mod:`compare`; the console script is ``bench`` (:func:`bench.cli.main`). Any
other module is an implementation detail and may change without notice.
"""

from typing import TYPE_CHECKING

from bench.core.exports import lazy_exports, type_checking_imports

__version__ = "0.1.0"

if TYPE_CHECKING:  # the public names; at run time each loads on first use (lazy_exports)
    # the instrument interface: roles, records, geometry, the conformance checker
    from bench.core.roles import (Instrument as Instrument, Goniometer as Goniometer, Spectrometer as Spectrometer,
                                  LightSource as LightSource, Spectrophotometer as Spectrophotometer,
                                  InstrumentBase as InstrumentBase, InstrumentInfo as InstrumentInfo)
    from bench.core.records import (Reading as Reading, Spectrum as Spectrum, BSDFRecord as BSDFRecord)
    from bench.core.geometry import (Geometry as Geometry, cie_geometry as cie_geometry,
                                     CIE_GEOMETRIES as CIE_GEOMETRIES)
    from bench.core.conformance import (check_conformance as check_conformance, ConformanceError as ConformanceError)
    # errors: one line naming what is wrong, a typed class per failure
    from bench.core.errors import (BenchError as BenchError, InputError as InputError, ConfigError as ConfigError,
                                   SpecimenError as SpecimenError, GeometryError as GeometryError,
                                   PlanError as PlanError, DeviceError as DeviceError,
                                   CommunicationError as CommunicationError, DeviceTimeoutError as DeviceTimeoutError,
                                   HardwareError as HardwareError, CalibrationError as CalibrationError,
                                   StoreError as StoreError, RunInterrupted as RunInterrupted)
    # benches, plans, runs and the store; record files; sweeps; fits
    from bench.config import (Bench as Bench, load_bench as load_bench)
    from bench.plans import (Plan as Plan, load_plan as load_plan, plan_from_dict as plan_from_dict)
    from bench.runner import (run_scan as run_scan, resume_scan as resume_scan, ScanResult as ScanResult)
    from bench.store import RunStore as RunStore
    from bench.io import (read_record as read_record, export_record as export_record, export_run as export_run,
                          load_run as load_run, FileFormat as FileFormat, register_format as register_format,
                          formats as formats)
    from bench.sweep import (load_sweep as load_sweep, sweep_from_dict as sweep_from_dict, run_sweep as run_sweep,
                             resume_sweep as resume_sweep, SweepResult as SweepResult)
    from bench.identify import (fit_record as fit_record, FitResult as FitResult,
                                parse_model_spec as parse_model_spec, ModelSpec as ModelSpec)

#: each public name and the module that defines it: the imports above, read from this file
_WHERE = type_checking_imports(__file__)

__all__ = ["__version__"] + list(_WHERE)

__getattr__, __dir__ = lazy_exports(__name__, _WHERE)
