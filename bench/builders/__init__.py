"""Bench builders: one module per bench ``kind``, each with ``build_<kind>_bench(config, seed)``.

* :mod:`bench.builders.virtual` -- a virtual goniophotometer in every role;
* :mod:`bench.builders.emulated` -- the real drivers talking to the wire-level emulators of
  ``virtual/wire`` (and :class:`~bench.builders.emulated.Emulators` for ``bench emulate``);
* :mod:`bench.builders.real` -- the real drivers on real ports;
* :mod:`bench.builders.detector` -- the detector a description declares (``[detector]``), which
  configures the emulated spectrometer and the virtual body's detector alike;
* :mod:`bench.builders.motion` -- the motion profile of emulated and real benches from their
  configured speeds and ramps (``bench plan``);
* :mod:`bench.builders.homing` -- return-to-home of the axes a builder exposes in
  ``Bench.parts`` (``bench home``, plans with ``home = true``).
* :mod:`bench.builders.slopes` -- the slope of a description's specimen model along each axis:
  the positioning sensitivities of the readings' GUM budgets.

:data:`bench.config.BUILDERS` maps each kind to its builder and :func:`bench.config.load_bench`
imports only the one a config asks for (a virtual bench never loads the drivers).
"""
