"""The same seed gives the same counts on every x86-64 CPU, on every kernel path.

Two checks: the digests of :mod:`tests.same_bits` (every kernel path at fixed seeds) equal the
pinned ones, so a change that moves a count fails on any machine; and processes whose kernels
numba compiled for every LLVM target the host can execute (the baseline x86-64 -- SSE2, no FMA --
through x86-64-v2/v3/v4, Haswell, Skylake-SP, Ice Lake, Sapphire Rapids, Zen 3 and Zen 4; AVX-512
targets at 512 and at 256 bits) give the same pinned digests, so no count depends on the vector
unit, the tuning or the width. The second check has power: the same comparison applied to a
kernel compiled with numba's ``fastmath=True`` (the flags the kernels had before) finds a
difference.

After an intended change of a kernel's arithmetic, regenerate the pins with
``python tests/same_bits.py`` and say why in the commit.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.same_bits import digests

ROOT = Path(__file__).resolve().parent.parent

PINNED = {
    "ray/ggx": "86f8f0d28336feae9d2171e878eca0be7a5952126de8cb43d344b14ee109887a",
    "ray/lambert": "8049b60daedb4fc412022be157c240e2a11a706c1ed1588f8ada0e2a79a00e17",
    "block/ggx": "531c4e0128445b64cddcef180a8f1ab416d39331a3f1e50756369469a73f3de2",
    "block/plastic": "90403d7cd8a30b20ca081050041cab58c6453bd9f907f5d95ead1f30cdd2547b",
    "ray/roughplastic": "a42bb71991340c294a1de97f53d1a092f908fcdc619f41ea33874025658121fc",
    "block/roughplastic": "991612701296a8e8ac8491ad84a92d4633ce04417bf05e8221ddd382ed03e01c",
    "block/leaf": "974bbbf5a1ef8b6f6bb443260a3ea138b544a39ece438e9b05c7d129f27aaa4b",
    "block32/lambert": "754770703393316557060465661625551f0458d21f35fcc34ec731ea297067ac",
    "block32/ggx": "9410c3546dbeb9a1873279831864d5a1a3538a1412d15b1e35192b95cbf61b97",
    "block32/ggx-conductor": "9d82538fc5b7d87316a641be68d4f0d163b41e82abd1f92d582f17b50204cc17",
    "block32/aniso-ggx": "e64ed96b0fb88e843a2ce0785504b7d0cee89d74ecf3ee6eafcca636cf2fdb24",
    "block32/phong": "39618ec700c8be260fc678d1fd89104f86d1662d1bdfbf32e52e80a651c0c7b0",
    "block32/oren-nayar": "1d37564eba0b4d7c35a69cf6e4328caf19aa545ac08dff6a18592df8a89e6482",
    "block32/dielectric": "fad527fcc0df5a15fad3cae144f71de975ac79e811226981974369af214ca3e9",
    "block32/plastic": "9caaa2d435a415dc961b1c21a8a5d8ffd0d0d73fc4a58845aec14495e29824d5",
    "block32/roughplastic": "582dba40f33404e38c1fd5b6c810ba2550bf1c5cd2a8ecedb27e70c9c0e35064",
    "block32/leaf": "dc5d499e7c805dd148fd0f764fe102a75b3087dc0c803e499ad42450b5adfc8f",
    "block32/roughplastic-collimated": "d2e17336a9567a79c2a2f00d82a309ca6df4b1dfe235b2eb94c4c8541c79893c",
    "spectral32/lambert": "da9420c5038ae8e75a68198534b04e72f58daeb7d06bf95c8c4913feb2b8c9f2",
    "spectral32/conductor": "3e1bb62bedbe1c0034d5b2ec7bc6b4d0b0eedc5e45d3d0e0b2d5b35bab20d374",
    "spectral/conductor-narrow": "a4342cc9c3ecb1810765a3c967417eed0ec1df989d2fb59cfeb636e212873849",
    "effects/ggx": "b7ce0a565db84dcb90f90aeda3ebc6a9240e074fc28cbac6944516da994dc244",
    "spectro/lambert": "c20e32af3178b2f0fc8a01ea3c03aba79b2326aaab088a344da0356e379e1a5d",
    "fast/ggx": "efa780909593f3c07f345b705fa02cac549c761a95731a377934b75759e52065",
}


def test_counts_of_every_kernel_path_are_pinned():
    got = digests()
    assert got == PINNED, {k: v for k, v in got.items() if PINNED.get(k) != v}


#: The LLVM targets whose code the slow check runs, each with the /proc/cpuinfo flags of the
#: instructions LLVM may emit for it in arithmetic code (vector, bit-manipulation and
#: conversion extensions; not system instructions such as mwaitx or wbnoinvd, which it emits only
#: for intrinsics): a target runs where the host has every one of them. ``x86-64`` is the
#: baseline (SSE2, no FMA). Targets with AVX-512 run at the table's width and at 256 bits.
_V2 = {"cx16", "lahf_lm", "popcnt", "sse4_1", "sse4_2", "ssse3"}
_V3 = _V2 | {"avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave"}
_V4 = _V3 | {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"}
_HASWELL = _V3 | {"aes", "pclmulqdq", "fsgsbase", "rdrand", "xsaveopt", "invpcid", "erms"}
_SKX = _HASWELL | _V4 | {"adx", "rdseed", "3dnowprefetch", "clflushopt", "xsavec", "xsaves", "clwb"}
_ICX = _SKX | {"avx512vbmi", "avx512_vbmi2", "avx512_vnni", "avx512_bitalg", "avx512_vpopcntdq", "avx512ifma",
               "gfni", "vaes", "vpclmulqdq", "sha_ni", "rdpid"}
_SPR = _ICX | {"avx512_bf16", "avx512_fp16", "avx_vnni", "serialize", "movdiri", "movdir64b", "cldemote"}
_ZEN3 = _V3 | {"aes", "pclmulqdq", "adx", "rdseed", "3dnowprefetch", "clflushopt", "clwb", "clzero", "sha_ni",
               "sse4a", "vaes", "vpclmulqdq", "rdpid", "xsavec", "xsaves", "xsaveopt", "fsgsbase", "rdrand"}
_ZEN4 = _ZEN3 | _V4 | {"avx512vbmi", "avx512_vbmi2", "avx512_vnni", "avx512_bitalg", "avx512_vpopcntdq",
                       "avx512ifma", "avx512_bf16", "gfni"}
TARGETS = {"x86-64": set(), "x86-64-v2": _V2, "x86-64-v3": _V3, "x86-64-v4": _V4, "haswell": _HASWELL,
           "skylake-avx512": _SKX, "icelake-server": _ICX, "sapphirerapids": _SPR, "znver3": _ZEN3, "znver4": _ZEN4}


def _host_flags() -> set[str]:
    for line in Path("/proc/cpuinfo").read_text(errors="replace").splitlines():
        if line.split(":")[0].strip() == "flags":
            return set(line.split(":", 1)[1].split())
    return set()


def _target_cases() -> list:
    cases = []
    for cpu, needs in TARGETS.items():
        for width in (("", "256") if "avx512f" in needs else ("",)):
            cases.append(pytest.param(cpu, width, id=f"{cpu}-{width or 'table'}"))
    return cases


def _in_target(script: str, tmp_path: Path, *args: str, cpu: str = "x86-64", width: str = "") -> str:
    """stdout of ``script`` in a fresh process whose kernels numba compiled for LLVM target ``cpu``
    (that target's own features, not the host's) at vector width ``width`` (the table's if "")."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_") and k != "GONIOBENCH_VECTOR_WIDTH"}
    env.update(NUMBA_CPU_NAME=cpu, NUMBA_CPU_FEATURES="", NUMBA_CACHE_DIR=str(tmp_path / f"numba-{cpu}-{width}"),
               PYTHONPATH=str(ROOT))
    if width:
        env["GONIOBENCH_VECTOR_WIDTH"] = width
    proc = subprocess.run([sys.executable, script, *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()[-1]


@pytest.mark.slow
@pytest.mark.parametrize("cpu, width", _target_cases())
def test_counts_do_not_depend_on_the_target_or_the_vector_width(cpu, width, tmp_path):
    """Every kernel path compiled for each LLVM target this host can execute (and, on AVX-512
    targets, at 256 bits as well as the table's width) gives the pinned digests."""
    missing = sorted(TARGETS[cpu] - _host_flags())
    if missing:  # its code would stop on an illegal instruction here; another machine runs it
        pytest.skip(f"this CPU cannot execute {cpu} code (lacks {', '.join(missing)})")
    got = json.loads(_in_target(str(ROOT / "tests" / "same_bits.py"), tmp_path, cpu=cpu, width=width))
    assert got == PINNED, {k: v for k, v in got.items() if PINNED.get(k) != v}


FASTMATH_PROBE = '''
import hashlib, sys
import numba, numpy as np
from virtual.kernels import FASTMATH

@numba.njit(fastmath=True if sys.argv[1] == "fast" else set(FASTMATH), cache=False)
def kernel(u, v):
    out = np.empty_like(u)
    acc = np.float32(0.0)
    for i in range(u.size):  # vectorized: a normalization and a dot product, in float32
        x = u[i] * np.float32(3.0) - np.float32(1.0)
        out[i] = x / np.float32(np.sqrt(x * x + v[i]))
        acc += u[i] * v[i]
    return out, acc

rng = np.random.default_rng(1)
u, v = rng.random(1 << 16).astype(np.float32), rng.random(1 << 16).astype(np.float32)
out, acc = kernel(u, v)
print(hashlib.sha256(out.tobytes() + np.float32(acc).tobytes()).hexdigest())
'''


@pytest.mark.slow
def test_the_isa_comparison_detects_fastmath(tmp_path):
    """Power of the check above: numba's fastmath=True lets LLVM fuse multiply-adds where the
    CPU has FMA, sum by the vector width and use reciprocal estimates, so this machine's build
    and the baseline build differ; without those flags they agree."""
    probe = tmp_path / "probe.py"
    probe.write_text(FASTMATH_PROBE)

    def here(mode: str) -> str:
        env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
        env.update(PYTHONPATH=str(ROOT))
        proc = subprocess.run([sys.executable, str(probe), mode], env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        return proc.stdout.strip().splitlines()[-1]

    assert here("kernels") == _in_target(str(probe), tmp_path, "kernels")
    assert here("fast") != _in_target(str(probe), tmp_path, "fast")


@pytest.mark.parametrize("w", [5, 20])
def test_the_float32_ggx_batch_does_not_depend_on_the_vector_width(monkeypatch, w):
    """The float32 GGX batch pads its wavelength table to the machine's vector width (speed
    only): the counts are the same whatever width it assumes, and the tables did differ."""
    import numpy as np

    import virtual.engine as engine
    from tests.same_bits import COLLECTOR, CONICAL, CONDUCTOR
    from virtual.engine import gonio_counts_spectral, measurement_seed
    from virtual.model_ids import MODEL_GGX

    rows = [np.array([0.2, 0.2, *CONDUCTOR[k % 3], 0.0]) for k in range(w)]
    counts, widths = [], []
    for lanes in (4, 8, 16):
        monkeypatch.setattr(engine, "float32_lanes", lambda lanes=lanes: lanes)
        widths.append(engine._padded_wavelengths(w))
        counts.append(gonio_counts_spectral(MODEL_GGX, rows, CONICAL.code, CONICAL.disk_code, CONICAL.kernel_args(30.0, 0.0),
                                            COLLECTOR.kernel_args(), 200_000, measurement_seed(5)))
    assert all((c == counts[0]).all() for c in counts)
    assert len(set(widths)) > 1
