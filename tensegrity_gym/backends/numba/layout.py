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

from ...core.param_table import ITEM_AXES, contact_columns, physics_rows, skipped_fields

# flag bits passed to the kernel (the physics fields' bits come from the parameter table: packed_layout)
_RK4 = 1
_FD = 8
_EXT = 16
_PROJ = 32
_CONS = 64
_L0DEF = 128   # use the model's rest lengths stored in the buffer
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


#: the physics fields the numba backend packs in a form of its own: the rod inertia constants
#: (from mass, f, J: slots 5..11 of a rod), the default rest lengths (o_l0), the gravity nodal
#: loads W0 (o_W0, from mass and gravity) and the anchor rows of the node scratch (o_N)
OWN_PACKING = ("mass", "f", "J", "rest_length", "gravity", "anchor_pos")
#: slots of a rod before its table rows: a, c, constrained, eta_a, eta_c, the 7 inertia
#: constants, Pi (9), offset (3); of a string: i, j
ROD_FIXED = 24
STR_FIXED = 2
#: the flag bits free for the physics fields (below the chunk count, none of the bits above)
_FREE_BITS = (2, 4, 256, 512, 1024, 2048, 4096, 8192, 16384, 32768)


def packed_layout(table=None) -> dict:
    """The packed buffer's slots and flag bits of the physics rows of the parameter table
    (``table``: default :data:`tensegrity_gym.core.param_table.PARAMS`), generated from it:

    * ``rod`` / ``string``: field -> its slot in each rod's / string's block (after
      :data:`ROD_FIXED` / :data:`STR_FIXED` slots), in table order; ``rod_stride`` /
      ``string_stride``: the block sizes;
    * ``node``: field -> its row of the node blocks (3 n slots each, the value repeated for x, y,
      z, from ``o_cn``), in table order; ``node_rows``: their number;
    * ``bits``: field -> its flag bit, for the fields whose term the kernels skip where it is 0
      (:func:`~tensegrity_gym.core.param_table.skipped_fields`).

    Every physics row is packed here or in the backend's own form (:data:`OWN_PACKING`);
    ValueError names a row it cannot place."""
    out = {"rod": {}, "string": {}, "node": {}}
    for r in physics_rows(table):
        if r.field in OWN_PACKING:
            continue
        if r.axis not in ITEM_AXES:
            raise ValueError(f"ParamSpec {r.name!r}: the numba backend packs a physics row per rod, string or "
                             f"node (axis one of {ITEM_AXES}), got axis {r.axis!r}")
        out[r.axis][r.field] = len(out[r.axis])
    out["rod"] = {f: ROD_FIXED + i for f, i in out["rod"].items()}
    out["string"] = {f: STR_FIXED + i for f, i in out["string"].items()}
    out["rod_stride"] = ROD_FIXED + len(out["rod"])
    out["string_stride"] = STR_FIXED + len(out["string"])
    out["node_rows"] = len(out["node"])
    skipped = skipped_fields(table)
    if len(skipped) > len(_FREE_BITS):
        raise ValueError(f"parameter table: {len(skipped)} skip_zero rows, the numba flags have room for "
                         f"{len(_FREE_BITS)}")
    out["bits"] = dict(zip(skipped, _FREE_BITS))
    return out


#: the packed layout of the parameter table (the kernels' slots and flag bits)
PACKED = packed_layout()
_ROD = PACKED["rod_stride"]      # slots per rod in the packed buffer
_STR = PACKED["string_stride"]   # slots per string
_NODE_ROWS = PACKED["node_rows"]  # node blocks (3 n slots each) from o_cn
# the slots and flag bits the equations read (named here once: the law of a row reads its name)
_S_STIFFNESS = PACKED["string"]["stiffness"]
_S_DAMPING = PACKED["string"]["damping"]
_N_NODE_DAMPING = PACKED["node"]["node_damping"]
_DAMP = PACKED["bits"]["damping"]
_GRAV = PACKED["bits"]["gravity"]
_NDAMP = PACKED["bits"]["node_damping"]


def _layout(k, m, n, rod=_ROD, string=_STR, node_rows=_NODE_ROWS):
    """Offsets into the packed model buffer (float64, 1-D; integer fields hold int64 bit patterns
    read through an int64 view of the same memory):

    ========  ======  ==============================================================
    offset    size    content
    ========  ======  ==============================================================
    0         3       k, m, n (int)
    o_rod     _ROD k  per rod: a, c, constrained (int), eta_a, eta_c, 1/m, 1/J, f/J,
                      beta = f^2/J, alpha = m - f^2/J, 1/alpha, f, Pi (9), offset (3), then
                      its table rows (``PACKED["rod"]``)
    o_str     _STR m  per string: i, j (int), then its table rows (``PACKED["string"]``:
                      stiffness, damping)
    o_l0      m       default rest lengths
    o_W0      3 n     gravity nodal loads
    o_ws      60 k    10 stage arrays (k, 6) of the integrators (scratch)
    o_N/V/F   3 n     node positions (anchor rows preset), velocities (anchor rows 0), forces
    o_cn      3 n R   the node table rows (``PACKED["node"]``: node drag coefficients c, N s/m),
                      each value repeated for x, y, z
    o_x       2 m+3n  one copy's rest lengths, force densities, external forces (scratch)
    ========  ======  ==============================================================

    ``rod``, ``string``, ``node_rows``: the block sizes (default :data:`PACKED`'s; another
    table's from its :func:`packed_layout`).
    """
    o_rod = 3
    o_str = o_rod + rod * k
    o_l0 = o_str + string * m
    o_W0 = o_l0 + m
    o_ws = o_W0 + 3 * n
    o_N = o_ws + 60 * k
    o_V = o_N + 3 * n
    o_F = o_V + 3 * n
    o_cn = o_F + 3 * n
    end = o_cn + 3 * n * node_rows + 2 * m + 3 * n
    return (o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end)


def _soa_width(k):
    """E, the copies per block of the SIMD (structure-of-arrays) loop for k rods."""
    return 16 if k <= 24 else 8


#: the columns of the ground contact parameter rows, as the contact kernels index them
CONTACT_COLUMNS = contact_columns()
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

