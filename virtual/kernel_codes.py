"""The integer codes and limits the kernels compile in as constants, in a module that imports
nothing, so that the Python side -- routing, the certified fast path, the CLI -- can name them
without loading numba (``bench gonio`` on the fast path never compiles or loads a kernel).

The kernel modules import them from here (their cache stamps therefore include this file:
editing a value recompiles the kernels that use it). Specimen model ids are in
:mod:`virtual.model_ids`.
"""

from virtual.model_ids import (MODEL_ANISO_GGX, MODEL_DIELECTRIC, MODEL_GGX, MODEL_LAMBERT, MODEL_LEAF,
                               MODEL_OREN_NAYAR, MODEL_PHONG, MODEL_PLASTIC, MODEL_ROUGHPLASTIC)
from virtual.law_table import LAW_FLOAT32_MODELS, LAW_MODELS

__all__ = ["BEAM_COLLIMATED", "BEAM_CONICAL", "DISK_POLAR", "DISK_REJECTION", "DISK_AUTO", "B_EMITTER_RADIUS",
           "B_SPECIMEN_RADIUS", "B_DISTANCE", "B_AXIS_X", "B_AXIS_Y", "B_AXIS_Z", "N_BEAM_ARGS",
           "SCHEME_EQUAL_ANGLE", "SCHEME_EQUAL_SOLID_ANGLE", "SCHEME_EQUAL_PSA", "ATAN_MAX_ERROR", "ATAN32_MAX_ERROR",
           "MIN_ALPHA", "MAX_PHONG_EXPONENT", "MAX_ETA", "FX_STRAY", "FX_BANDPASS", "FX_SPHERE", "FX_PATTERN",
           "FX_DETECTORS", "FX_NEAR", "FX_POSITIONS", "N_EFFECT_ARGS", "GIVEN_MODELS", "GIVEN_UNIFORMS",
           "GIVEN4_MODELS", "GIVEN4_UNIFORMS", "BLOCK_RAYS", "BEAM_UNIFORMS", "BLOCK_MODELS", "BLOCK_PARAMS",
           "BLOCK32_MODELS", "BLOCK32_RAYS", "COAT_MODELS", "RP_TABLE", "RP_TABLE_RES", "RP_S_LO", "RP_S_HI", "RP_N_E",
           "RP_E", "FRESNEL_CELLS", "FRESNEL_SAMPLES", "LANES"]

# beams (virtual.kernels.emit)
BEAM_COLLIMATED = 0
BEAM_CONICAL = 1
DISK_POLAR = 0
DISK_REJECTION = 1
DISK_AUTO = 2
# Indices into the beam vector ``b`` (after the 3x3 rotation, row-major at 0..8)
B_EMITTER_RADIUS = 9
B_SPECIMEN_RADIUS = 10
B_DISTANCE = 11
B_AXIS_X = 12
B_AXIS_Y = 13
B_AXIS_Z = 14
#: length of the beam vector
N_BEAM_ARGS = 15

# collector schemes (virtual.kernels.patch_lookup)
SCHEME_EQUAL_ANGLE = 0
SCHEME_EQUAL_SOLID_ANGLE = 1
SCHEME_EQUAL_PSA = 2
#: Largest error (rad) of the float64 first-quadrant atan of :mod:`virtual.kernels.patch_lookup`
#: (1.35e-8 measured on a 2e6-point grid, tested): the margin of its ``guess_bin`` is built on it.
ATAN_MAX_ERROR = 1.4e-8
#: Largest error (rad) of the float32 polynomial atan2 of :mod:`virtual.kernels.f32`, with its
#: input's rounding (tested on a grid).
ATAN32_MAX_ERROR = 4e-7

# what the float32 path takes (virtual.kernels.f32)
#: Smallest roughness (alpha) the float32 path takes: a lobe of width ~alpha spans >= 1e5 float32 ulps.
MIN_ALPHA = 0.01
#: Largest Phong exponent the float32 path takes: the lobe as narrow as GGX's at MIN_ALPHA (n = 2/alpha^2,
#: width sqrt(2/(n+1)) = alpha). Its 1 - cos(alpha) is computed to a relative 3e-7 at any n
#: (:func:`~virtual.kernels.branchfree32.phong_lobe_omc32`), not as 1 - cos, which float32 cannot resolve.
MAX_PHONG_EXPONENT = 2.0 / MIN_ALPHA ** 2
#: Dielectric indices (rough dielectric, plastic coat) the float32 path takes: 1/MAX_ETA <= eta <= MAX_ETA,
#: the specimens' declared range, where the Fresnel terms and the refracted direction stay well scaled.
MAX_ETA = 10.0

# scene effects (virtual.kernels.ray_loop)
FX_STRAY = 1
FX_BANDPASS = 2
FX_SPHERE = 4
FX_PATTERN = 8
FX_DETECTORS = 16
FX_NEAR = 32
#: effects that need the point where a ray meets the specimen
FX_POSITIONS = FX_PATTERN | FX_NEAR
#: length of the effect parameter vector ``e`` (see :mod:`virtual.effects`)
N_EFFECT_ARGS = 10

# block kernels (virtual.kernels.scatter, branchfree, block64, block32)
#: Models with a branch-free form taking their uniforms as arguments (``scatter_given``).
GIVEN_MODELS = (MODEL_LAMBERT, MODEL_GGX, MODEL_ANISO_GGX)
#: Uniforms ``scatter_given`` consumes per ray.
GIVEN_UNIFORMS = 3
#: Models ``scatter_given4`` serves.
GIVEN4_MODELS = (MODEL_OREN_NAYAR, MODEL_PHONG, MODEL_DIELECTRIC)
#: Uniforms ``scatter_given4`` consumes per ray.
GIVEN4_UNIFORMS = 4
#: Rays per block of the block kernel: its 7 uniforms and 4 outputs per ray (88 KiB) stay in L2.
BLOCK_RAYS = 1024
BEAM_UNIFORMS = 4  # two polar disk points
#: Models the block kernel of :mod:`virtual.kernels.block_coat` runs (a table in the parameter
#: vector, or nine uniforms per ray): Mitsuba's roughplastic and the leaf.
COAT_MODELS = (MODEL_ROUGHPLASTIC, MODEL_LEAF)
#: Models a block kernel runs (three uniforms each for the first, four for the second group; the
#: plastic in :func:`~virtual.kernels.block64.gonio_block_chunk`, the COAT_MODELS in their own chunk).
BLOCK_MODELS = GIVEN_MODELS + GIVEN4_MODELS + (MODEL_PLASTIC,) + COAT_MODELS
#: ... and the laws of :mod:`virtual.kernels.laws` (every law has a block form)
BLOCK_MODELS += tuple(m for m in LAW_MODELS if m not in BLOCK_MODELS)
#: Parameters the block kernel passes to a model (as a tuple; shorter vectors are zero-padded).
BLOCK_PARAMS = 6
#: Models with a float32 form (the others run the float64 block or ray-by-ray kernel).
BLOCK32_MODELS = (MODEL_LAMBERT, MODEL_GGX, MODEL_ANISO_GGX, MODEL_PHONG, MODEL_OREN_NAYAR, MODEL_DIELECTRIC,
                  MODEL_PLASTIC)
BLOCK32_MODELS += tuple(m for m in LAW_FLOAT32_MODELS if m not in BLOCK32_MODELS)  # the laws with a float32 form
#: Rays per block of the float32 kernel: up to 11 float32 uniforms and 6 float32 coordinates per ray stay in L1/L2.
BLOCK32_RAYS = 1024

# Mitsuba's roughplastic parameter vector (virtual.specimens.roughplastic, virtual.kernels.coat):
# [alpha, eta, kd_eff, c, t(mu_0..mu_63), s_lo, s_hi, n, E(node_0..node_n-1)], s = sqrt(1 - mu)
#: Where the coat transmittance table t(mu_i), mu_i = i / 63, starts, and its length.
RP_TABLE = 4
RP_TABLE_RES = 64
#: The specular albedo table E_spec on n uniform nodes of s = sqrt(1 - mu) over [s_lo, s_hi] (the
#: incidences the beam delivers), appended by the engine per measurement: its bounds, n, the first node.
RP_S_LO = RP_TABLE + RP_TABLE_RES
RP_S_HI = RP_S_LO + 1
RP_N_E = RP_S_LO + 2
RP_E = RP_S_LO + 3

# the float32 spectral GGX batch (virtual.kernels.spectral32)
#: Cells of c = cos(theta_m) in [0, 1] of the Fresnel bound table.
FRESNEL_CELLS = 512
#: Samples per cell (float64) from which its bounds are taken.
FRESNEL_SAMPLES = 64

# random streams (virtual.kernels.xoshiro)
#: Independent xoshiro streams advanced side by side by ``fill_uniforms`` (one SIMD register
#: holds 8 of them; 64 keeps the vectorized loop free of a scalar remainder).
LANES = 64
