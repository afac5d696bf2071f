"""The detectors and the light as ophyd-async devices.

``SpectrometerDevice``  Triggerable, Readable, Configurable: ``trigger()`` acquires with the
                        configured ``integration_s`` and ``averages``; ``read()`` gives the
                        spectrum (one array DataKey, units ``counts``, ``dims`` =
                        ``["wavelength_nm"]``, the axis itself in the configuration), its
                        standard deviation, the saturation mask and the dark flag; hinted
                        scalars ``mean_counts`` and ``peak_counts`` (and ``n_saturated``) so
                        BestEffortCallback / LiveTable show something per point; and the
                        geometry it read at (``theta_i`` ... ``phi_r``, the goniometer axes'
                        convention), so every stored reading has one.
``ReflectanceDevice``   Triggerable, Readable, Configurable, Stageable: BRDF (sr^-1) and
                        reflectance factor per wavelength with standard uncertainty. ``stage()``
                        measures the white (and dark) reference exactly as ``bench scan`` does
                        (:mod:`bench.runner`), then returns the arm to the setpoint if that
                        moved it; ``trigger()`` takes darks as ``dark_mode`` says
                        and calibrates with :class:`bench.core.calibration.Calibration`.
                        Hinted scalars ``rf_mean`` / ``rf_mean_std``: the band-mean reflectance
                        factor and its standard uncertainty (what a live table or plot shows).
``LightDevice``         Movable (``set(True|False|"on"|"off")``) and Readable.

Every driver call goes through the bench's :class:`~bench.bluesky.worker.BenchWorker`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from event_model.documents.event_descriptor import DataKey
from ophyd_async.core import (
    Array1D,
    AsyncStatus,
    SignalR,
    StandardReadable,
)
from ophyd_async.core import StandardReadableFormat as Format

from bench.bluesky.goniometer import AXES, Mover
from bench.bluesky.signals import hardware_source, hw_signal_r, hw_signal_rw
from bench.bluesky.worker import BenchWorker
from bench.calibration_chain import decide_calibration, stored_white
from bench.config import Bench
from bench.core.calibration import Calibration
from bench.core.errors import BenchError, ConfigError, GeometryError
from bench.core.records import json_default
from bench.core.roles import Reading
from bench.exposure import check_exposure, starting_integration
from bench.plans import DARK_MODES, WHITE_MODES, Plan
from bench.runner import acquire_dark, measure_calibration

__all__ = ["SpectrometerDevice", "ReflectanceDevice", "LightDevice", "ReadingSettings", "WAVELENGTH_DIM",
           "band_mean"]

WAVELENGTH_DIM = "wavelength_nm"
F64 = Array1D[np.float64]


def _array(hardware: str, n: int, units: str | None = None, dtype: Any = np.float64) -> tuple[SignalR, Any]:
    return hw_signal_r(Array1D[dtype], np.zeros(n, dtype=dtype), hardware, units=units)


class _SpectralReadable(StandardReadable):
    """A StandardReadable whose array data keys carry ``dims = ["wavelength_nm"]``."""

    _n: int = 0

    async def describe(self) -> dict[str, DataKey]:
        keys = await super().describe()
        for key in keys.values():
            if list(key.get("shape", [])) == [self._n]:
                key["dims"] = [WAVELENGTH_DIM]
        return keys


def band_mean(values: np.ndarray, std: np.ndarray, masked: np.ndarray) -> tuple[float, float]:
    """Mean of ``values`` over the unmasked pixels and its standard uncertainty (NaN if none).

    The uncertainty is the mean of the pixels' standard uncertainties: the pixels share the white
    standard and the reference, so they are treated as fully correlated -- an upper bound that
    never understates the uncertainty of the mean.
    """
    ok = ~np.asarray(masked, dtype=bool) & np.isfinite(values)
    if not ok.any():
        return math.nan, math.nan
    return float(np.mean(values[ok])), float(np.mean(np.asarray(std)[ok]))


def _geometry_signals(device: Any, setters: dict[str, Any]) -> None:
    """Give ``device`` read-only ``theta_i`` ... ``phi_r`` signals (deg), their setters in ``setters``."""
    for axis in AXES:
        sig, setter = hw_signal_r(float, 0.0, device._hw, units="deg")
        setattr(device, axis, sig)
        setters[axis] = setter


def _publish_geometry(mover: Mover, setters: dict[str, Any]) -> None:
    """The geometry the goniometer reached, in its axes' sign convention (``theta_r`` signed in
    the plane of the requested ``phi_r``), so an event holding the axes and a detector agrees."""
    for axis, value in mover.axes_of(mover.reached).items():
        setters[axis](float(value))


def _check_reading_settings(integration_s: float, averages: int) -> None:
    if not (math.isfinite(integration_s) and integration_s > 0):
        raise ConfigError(f"integration_s must be finite and > 0, got {integration_s!r}")
    if int(averages) != averages or averages < 1:
        raise ConfigError(f"averages must be an integer >= 1, got {averages!r}")


@dataclass
class ReadingSettings:
    """One bench's reading settings, shared by its spectrometer and reflectance devices: the
    ``integration_s`` / ``averages`` signals of both read and write these, so
    ``mv(spectrometer.integration_s, 0.02)`` is what the reflectance detector integrates too
    (one detector, one integration time). ``dark`` / ``white`` are the reflectance's modes."""

    integration_s: float = 0.1
    averages: int = 1
    dark: str = "once"
    white: str = "once"

    @classmethod
    def for_bench(cls, bench: Bench) -> "ReadingSettings":
        """Defaults that match the bench's stored white reading (``[white] reference_file``):
        its integration time, averages and dark treatment; else 0.1 s (less where the white it
        measures first would saturate at 0.1 s: :func:`bench.exposure.starting_integration`), 1,
        ``once``. A file that cannot be read keeps the defaults (staging then refuses it in one line)."""
        try:
            ref = stored_white(bench)
        except (BenchError, OSError):
            ref = None
        if ref is None:
            return cls(integration_s=starting_integration(bench.config, cls.integration_s))
        return cls(float(ref.white.integration_s), int(ref.white.averages), "once" if ref.dark is not None else "none")

    def set_integration_s(self, value: float) -> None:
        _check_reading_settings(float(value), self.averages)
        self.integration_s = float(value)

    def set_averages(self, value: int) -> None:
        _check_reading_settings(self.integration_s, value)
        self.averages = int(value)

    def signals(self, hardware: str) -> tuple[Any, Any]:
        """New ``integration_s`` and ``averages`` signals of ``hardware`` backed by these settings."""
        return (hw_signal_rw(float, self.integration_s, hardware, units="s", getter=lambda: self.integration_s,
                             setter=self.set_integration_s),
                hw_signal_rw(int, self.averages, hardware, getter=lambda: self.averages, setter=self.set_averages))


class SpectrometerDevice(_SpectralReadable):
    """The bench's spectrometer (raw counts per wavelength)."""

    def __init__(self, bench: Bench, worker: BenchWorker, name: str = "",
                 settings: ReadingSettings | None = None, mover: Mover | None = None) -> None:
        self._bench, self._worker, self._mover = bench, worker, mover
        self._hw = hardware_source(bench, "spectrometer")
        self.settings = settings if settings is not None else ReadingSettings.for_bench(bench)
        self._geometry_setters: dict[str, Any] = {}
        wl = np.asarray(bench.spectrometer.wavelengths, dtype=float)
        self._n = wl.size
        with self.add_children_as_readables(Format.UNCACHED_SIGNAL):
            self.spectrum, self._set_spectrum = _array(self._hw, self._n, "counts")
            self.spectrum_std, self._set_std = _array(self._hw, self._n, "counts")
            self.saturated, self._set_saturated = _array(self._hw, self._n, None, np.bool_)
            self.dark, self._set_dark = hw_signal_r(bool, False, self._hw)
            self.n_saturated, self._set_n_saturated = hw_signal_r(int, 0, self._hw, units="pixels")
            if mover is not None:  # where it read: a record needs the geometry of every reading
                _geometry_signals(self, self._geometry_setters)
        with self.add_children_as_readables(Format.HINTED_UNCACHED_SIGNAL):
            self.mean_counts, self._set_mean = hw_signal_r(float, 0.0, self._hw, units="counts")
            self.peak_counts, self._set_peak = hw_signal_r(float, 0.0, self._hw, units="counts")
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            self.integration_s, self.averages = self.settings.signals(self._hw)
            self.wavelength_nm, set_wl = _array(self._hw, self._n, "nm")
        set_wl(wl)
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def trigger(self) -> None:
        t, n = self.settings.integration_s, self.settings.averages
        _check_reading_settings(t, n)
        r: Reading = await self._worker.run(self._bench.spectrometer.acquire, float(t), int(n))
        signal, saturated = np.asarray(r.signal, dtype=float), np.asarray(r.saturated, dtype=bool)
        self._set_spectrum(signal)
        self._set_std(np.full(self._n, np.nan) if r.std is None else np.asarray(r.std, dtype=float))
        self._set_saturated(saturated)
        self._set_dark(bool(r.dark))
        self._set_mean(float(signal.mean()) if signal.size else math.nan)
        self._set_peak(float(signal.max()) if signal.size else math.nan)
        self._set_n_saturated(int(saturated.sum()))
        if self._mover is not None:
            _publish_geometry(self._mover, self._geometry_setters)


class ReflectanceDevice(_SpectralReadable):
    """Calibrated BRDF and reflectance factor per wavelength, as ``bench scan`` computes them.

    Readings: ``brdf`` (sr^-1), ``brdf_std``, ``reflectance_factor`` and its ``_std``, ``masked`` (pixels not
    calibrated: reference saturated or at dark, signal saturated), the raw ``signal`` /
    ``signal_std`` / ``dark`` / ``dark_std`` / ``saturated`` it was computed from, and the
    geometry reached (``theta_i`` ... ``phi_r``, degrees, in the goniometer axes' convention:
    ``theta_r`` signed in the plane of the requested ``phi_r``, so an event holding both says
    the same angles). Configuration:
    ``integration_s``, ``averages``, ``dark_mode`` (none, once, per-incidence, per-point),
    ``white_mode`` (none, once), the wavelength axis and the ``calibration`` (JSON of
    :meth:`Calibration.as_dict`, measured at ``stage()``). Hinted: ``rf_mean`` and
    ``rf_mean_std`` (:func:`band_mean` of the reflectance factor), the columns and plots
    BestEffortCallback shows.
    """

    def __init__(self, bench: Bench, worker: BenchWorker, mover: Mover, name: str = "",
                 settings: ReadingSettings | None = None) -> None:
        self._bench, self._worker, self._mover = bench, worker, mover
        self._hw = hardware_source(bench, "spectrometer")  # the spectrometer, calibrated
        self.settings = settings if settings is not None else ReadingSettings.for_bench(bench)
        wl = np.asarray(bench.spectrometer.wavelengths, dtype=float)
        self._n = wl.size
        self._cal: Calibration | None = None
        self._dark: Reading | None = None
        self._last_incidence: tuple[float, float] | None = None
        self._staged = False
        with self.add_children_as_readables(Format.UNCACHED_SIGNAL):
            self.brdf, self._set_brdf = _array(self._hw, self._n, "1/sr")
            self.brdf_std, self._set_brdf_std = _array(self._hw, self._n, "1/sr")
            self.reflectance_factor, self._set_rf = _array(self._hw, self._n, "1")
            self.reflectance_factor_std, self._set_rf_std = _array(self._hw, self._n, "1")
            self.masked, self._set_masked = _array(self._hw, self._n, None, np.bool_)
            self.signal, self._set_signal = _array(self._hw, self._n, "counts")
            self.signal_std, self._set_signal_std = _array(self._hw, self._n, "counts")
            self.dark, self._set_dark = _array(self._hw, self._n, "counts")
            self.dark_std, self._set_dark_std = _array(self._hw, self._n, "counts")
            self.has_dark, self._set_has_dark = hw_signal_r(bool, False, self._hw)
            self.saturated, self._set_saturated = _array(self._hw, self._n, None, np.bool_)
            self._geometry_setters: dict[str, Any] = {}
            _geometry_signals(self, self._geometry_setters)
        with self.add_children_as_readables(Format.HINTED_UNCACHED_SIGNAL):
            self.rf_mean, self._set_rf_mean = hw_signal_r(float, math.nan, self._hw, units="1", precision=4)
            self.rf_mean_std, self._set_rf_mean_std = hw_signal_r(float, math.nan, self._hw, units="1",
                                                                   precision=4)
        with self.add_children_as_readables(Format.CONFIG_SIGNAL):
            self.integration_s, self.averages = self.settings.signals(self._hw)
            self.dark_mode = hw_signal_rw(str, self.settings.dark, self._hw, getter=lambda: self.settings.dark,
                                            setter=self._set_dark_mode)
            self.white_mode = hw_signal_rw(str, self.settings.white, self._hw, getter=lambda: self.settings.white,
                                             setter=self._set_white_mode)
            self.wavelength_nm, set_wl = _array(self._hw, self._n, "nm")
            self.calibration, self._set_calibration = hw_signal_r(str, "null", self._hw)
        set_wl(wl)
        super().__init__(name=name)

    def _set_dark_mode(self, value: str) -> None:
        if value not in DARK_MODES:
            raise ConfigError(f"{self.name} dark_mode must be one of {', '.join(DARK_MODES)}, got {value!r}")
        self.settings.dark = value

    def _set_white_mode(self, value: str) -> None:
        if value not in WHITE_MODES:
            raise ConfigError(f"{self.name} white_mode must be one of {', '.join(WHITE_MODES)}, got {value!r}")
        self.settings.white = value

    def _settings(self) -> Plan:
        """The reading settings as the runner's :class:`Plan` (no points) and checked."""
        st = self.settings
        t, n, dark, white = float(st.integration_s), int(st.averages), st.dark, st.white
        _check_reading_settings(t, n)
        if dark not in DARK_MODES:
            raise ConfigError(f"{self.name} dark_mode must be one of {', '.join(DARK_MODES)}, got {dark!r}")
        if white not in WHITE_MODES:
            raise ConfigError(f"{self.name} white_mode must be one of {', '.join(WHITE_MODES)}, got {white!r}")
        if white == "repeated":  # its drift correction counts lit readings, which only the runner does
            raise ConfigError(f"{self.name} white_mode 'repeated' is taken by `bench scan` (the runner) only: "
                              f"use 'once' here")
        return Plan(name=self.name, kind="list", points=(), integration_s=t, averages=n, dark=dark, white=white)

    def stage(self) -> AsyncStatus:
        """Measure the white reference (and its dark), then the run's dark when ``once``; then
        return the arm to the goniometer's setpoint if measuring the white moved it.

        The settings are checked first, synchronously: a step the bench cannot take, a stored
        white taken with other settings, or an exposure predicted to saturate the detector on the
        white it measures now or at the setpoint the first trigger reads at (:mod:`bench.exposure`,
        as ``bench scan`` refuses a plan; a Bluesky plan's later points are not known here: their
        saturated readings are masked and the stored run says so) raises its one-line
        :class:`~bench.core.errors.CalibrationRefused` (or ``ConfigError``) straight out of
        ``RE(...)``, before any motion, instead of failing a status."""
        plan = self._settings()
        try:
            decide_calibration(self._bench, plan)  # the runner's decision: which white, which darks
            # the white it measures now and the first trigger, at the setpoint (a count reads only there),
            # predicted as bench scan predicts a plan's: refused before any motion when they would saturate
            setpoint = self._mover.geometry_of(self._mover.target)
            try:  # a parked setpoint is never read at (a scan moves the arm first; a count is refused there)
                self._bench.goniometer.check(setpoint)
                first: tuple = (setpoint,)
            except GeometryError:
                first = ()
            check_exposure(replace(plan, points=first), self._bench.config)
        except BenchError as exc:
            raise type(exc)(f"{self.name} (integration_s {plan.integration_s:g} s, averages {plan.averages}, "
                            f"dark_mode {plan.dark!r}, white_mode {plan.white!r}): {exc}") from None
        return self._stage(plan)

    @AsyncStatus.wrap
    async def _stage(self, plan: Plan) -> None:
        before = self._mover.reached
        try:
            self._cal = await self._worker.run(measure_calibration, self._bench, plan)
            self._dark = await self._worker.run(acquire_dark, self._bench, plan) if plan.dark == "once" else None
        except BaseException:
            await self._mover.refresh()  # measuring the white may have moved the arm
            raise
        # measuring the white moves a physical arm to the white geometry: back to the setpoint,
        # so the first trigger reads where the goniometer says it is
        await self._mover.restore(before)
        self._last_incidence = None
        self._set_calibration(json.dumps(None if self._cal is None else self._cal.as_dict(), default=json_default))
        self._staged = True

    @AsyncStatus.wrap
    async def unstage(self) -> None:
        self._staged = False

    @AsyncStatus.wrap
    async def trigger(self) -> None:
        if not self._staged:  # a bare trigger (no stage): calibrate first, as a plan would
            await self.stage()
        self._mover.check_at_setpoint()  # no reading where the white left a parked arm
        plan = self._settings()
        target = self._mover.geometry_of(self._mover.target)
        incidence = (target.theta_i, target.phi_i)
        if plan.dark == "per-point" or (plan.dark == "per-incidence" and incidence != self._last_incidence):
            self._dark = await self._worker.run(acquire_dark, self._bench, plan)
        self._last_incidence = incidence
        reading: Reading = await self._worker.run(self._bench.spectrometer.acquire, plan.integration_s,
                                                  plan.averages)
        g = self._mover.reached
        nan = np.full(self._n, np.nan)
        if self._cal is not None:
            c = self._cal.apply(reading, g, self._dark)
            self._set_brdf(c.brdf)
            self._set_brdf_std(c.std)
            self._set_rf(c.reflectance_factor)
            self._set_rf_std(c.std * math.pi)
            self._set_masked(c.masked.astype(bool))
            mean, u = band_mean(c.reflectance_factor, c.std * math.pi, c.masked)
        else:
            self._set_brdf(nan)
            self._set_brdf_std(nan)
            self._set_rf(nan)
            self._set_rf_std(nan)
            self._set_masked(np.ones(self._n, dtype=bool))
            mean, u = math.nan, math.nan
        self._set_rf_mean(mean)
        self._set_rf_mean_std(u)
        self._set_signal(np.asarray(reading.signal, dtype=float))
        self._set_signal_std(nan if reading.std is None else np.asarray(reading.std, dtype=float))
        d = self._dark
        self._set_has_dark(d is not None)
        self._set_dark(np.zeros(self._n) if d is None else np.asarray(d.signal, dtype=float))
        self._set_dark_std(nan if d is None or d.std is None else np.asarray(d.std, dtype=float))
        self._set_saturated(np.asarray(reading.saturated, dtype=bool))
        _publish_geometry(self._mover, self._geometry_setters)


def _on_off(value: Any) -> bool:
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    text = str(getattr(value, "value", value)).strip().lower()
    if text in ("on", "1", "true", "open"):
        return True
    if text in ("off", "0", "false", "closed"):
        return False
    raise ConfigError(f"a light is set to on/off (True/False, 'on'/'off'), got {value!r}")


class LightDevice(StandardReadable):
    """The bench's light source: ``set(True)`` / ``set("off")``; reads ``on``."""

    def __init__(self, bench: Bench, worker: BenchWorker, name: str = "") -> None:
        if bench.light is None:
            raise ConfigError(f"bench {bench.name!r} has no light source")
        self._light, self._worker = bench.light, worker
        self._hw = hardware_source(bench, "light")
        with self.add_children_as_readables(Format.HINTED_SIGNAL):
            self.on, self._set_on = hw_signal_r(bool, True, self._hw)
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def set(self, value: Any) -> None:
        on = _on_off(value)
        await self._worker.run(self._light.on if on else self._light.off)
        self._set_on(on)
