"""The same seed gives the same counts on every x86-64 CPU, on every kernel path.

Two checks: the digests of :mod:`tests.same_bits` (every kernel path at fixed seeds) equal the
pinned ones, so a change that moves a count fails on any machine; and a process whose kernels
numba compiled for the baseline x86-64 instruction set (SSE2: 2 float64 / 4 float32 lanes, no
FMA) gives the digests of this machine's own build (AVX2 or AVX-512 here: 4-8 / 8-16 lanes,
FMA), so no count depends on the vector unit. The second check has power: the same comparison
applied to a kernel compiled with numba's ``fastmath=True`` (the flags the kernels had before)
finds a difference.

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


def _in_baseline_isa(script: str, tmp_path: Path, *args: str) -> str:
    """stdout of ``script`` in a fresh process whose kernels are compiled for plain x86-64."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(NUMBA_CPU_NAME="x86-64", NUMBA_CPU_FEATURES="", NUMBA_CACHE_DIR=str(tmp_path / "numba-x86-64"),
               PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, script, *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=1800)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()[-1]


@pytest.mark.slow
def test_counts_do_not_depend_on_the_instruction_set(tmp_path):
    baseline = json.loads(_in_baseline_isa(str(ROOT / "tests" / "same_bits.py"), tmp_path))
    assert baseline == digests()


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

    assert here("kernels") == _in_baseline_isa(str(probe), tmp_path, "kernels")
    assert here("fast") != _in_baseline_isa(str(probe), tmp_path, "fast")


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
