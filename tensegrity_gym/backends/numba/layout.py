"""Memory layout of the numba backend: the packed per-model buffer (``_layout``), the flag
bits a kernel call carries, the kernels' error codes and compile options. SI units.

The kernels index one flat float64 buffer ``w`` (model data + scratch, see ``_layout``) with
computed offsets instead of slicing views: every numba array view costs reference-count
traffic that, at B = 1, is larger than the physics of a small structure.
"""
from __future__ import annotations

import numba
from llvmlite import ir as _ir
from numba import njit, types
from numba.core import cgutils



# flag bits passed to the kernel
_RK4 = 1
_DAMP = 2
_GRAV = 4
_FD = 8
_EXT = 16
_PROJ = 32
_CONS = 64
_L0DEF = 128   # use the model's rest lengths stored in the buffer
_NDAMP = 256   # per-node viscous drag (model.node_damping)
_CHUNK_SHIFT = 16   # the parallel kernel's chunk count rides in flags >> _CHUNK_SHIFT
_SINC_SMALL = 1e-4    # rad: below this angle per step sin(x)/x = 1 - x^2/6
_SOA_MIN_BATCH = 16   # serial calls with at least this many environments use the SIMD (SoA) loop

_ERRORS = {
    1: "q: expected shape (B, {k}, 6)",
    2: "qd: expected the same shape as q (B, {k}, 6)",
    3: "rest_length: expected shape ({m},) or (B, {m})",
    4: "force_density: expected shape ({m},) or (B, {m})",
    5: "external: expected shape ({n}, 3) or (B, {n}, 3)",
    6: "output arrays: expected the same shape as q",
    7: "params: expected one row (shared) or one per copy of q",
    9: "internal: a serial kernel was given a batch size of its other instance (one copy / SIMD)",
}


_ROD = 24   # slots per rod in the packed buffer
_STR = 4    # slots per string


def _layout(k, m, n):
    """Offsets into the packed model buffer (float64, 1-D; integer fields hold int64 bit patterns
    read through an int64 view of the same memory):

    ========  ======  ==============================================================
    offset    size    content
    ========  ======  ==============================================================
    0         3       k, m, n (int)
    o_rod     24 k    per rod: a, c, constrained (int), eta_a, eta_c, 1/m, 1/J, f/J,
                      beta = f^2/J, alpha = m - f^2/J, 1/alpha, f, Pi (9), offset (3)
    o_str     4 m     per string: i, j (int), stiffness, damping
    o_l0      m       default rest lengths
    o_W0      3 n     gravity nodal loads
    o_ws      60 k    10 stage arrays (k, 6) of the integrators (scratch)
    o_N/V/F   3 n     node positions (anchor rows preset), velocities (anchor rows 0), forces
    o_cn      3 n     node drag coefficients c (N s/m), repeated for x, y, z
    +3 n      2 m+3n  one copy's rest lengths, force densities, external forces (scratch)
    ========  ======  ==============================================================
    """
    o_rod = 3
    o_str = o_rod + _ROD * k
    o_l0 = o_str + _STR * m
    o_W0 = o_l0 + m
    o_ws = o_W0 + 3 * n
    o_N = o_ws + 60 * k
    o_V = o_N + 3 * n
    o_F = o_V + 3 * n
    o_cn = o_F + 3 * n
    end = o_cn + 3 * n + 2 * m + 3 * n
    return (o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end)


def _soa_width(k):
    """E, the copies per block of the SIMD (structure-of-arrays) loop for k rods."""
    return 16 if k <= 24 else 8


# The kernels index one flat float64 buffer ``w`` (model data + scratch, see _layout) with
# computed offsets instead of slicing views: every numba array view costs reference-count
_opts = dict(cache=True, fastmath=False, error_model="numpy")
_layout_nb = njit(**_opts)(_layout)
_soa_width_nb = njit(inline="always", **_opts)(_soa_width)


_TILE_LANES = 16   # the widest SIMD block, _soa_width's largest E


@numba.extending.intrinsic
def _stack_tile(typingctx, rows):
    """Pointer to ``rows * _TILE_LANES`` float64 (``rows`` a compile-time constant) on the stack
    of the compiled function (allocated once, at its entry): scratch that the compiler knows
    overlaps no array argument, so that a loop over lanes that writes it and reads those
    arrays needs no run-time overlap checks and compiles to SIMD code (numba arrays carry no
    no-alias information; with checks for many arrays LLVM leaves such a loop scalar). Row r
    of lane e of a tile is element ``r * _TILE_LANES + e``."""
    if not isinstance(rows, types.IntegerLiteral):
        return None
    n = rows.literal_value * _TILE_LANES

    def codegen(context, builder, sig, args):
        return cgutils.alloca_once(builder, _ir.DoubleType(), size=_ir.Constant(_ir.IntType(64), n))
    return types.CPointer(types.float64)(rows), codegen


@njit(inline="always", **_opts)
def _lane_width(k, B):
    """E for a serial call on B copies: SIMD blocks from _SOA_MIN_BATCH copies, else one copy
    at a time (a padded block would compute up to 15 copies for nothing)."""
    return _soa_width_nb(k) if B >= _SOA_MIN_BATCH else 1

