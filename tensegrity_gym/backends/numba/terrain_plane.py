"""The plane kind of the numba terrain contact over the loop driver's SIMD lanes: the node slots
of a plane that is feature 0 of the terrain, in lane scratch (a plane's nearest point of a rod is
an end, so its interior slot never touches). SI units: m.

A plane's geom row (:mod:`.terrain_kinds`): outward unit normal (1:4) and offset (4) m, the solid
is ``n.p <= offset``.
"""
from __future__ import annotations

from numba import njit

from .layout import _TILE_LANES, _opts, _stack_tile
from .terrain_kinds import PLANE
from .terrain_law import _lane_point, _slot_force, _tile_slot_store, slots_load, slots_store


@njit(inline="always", **_opts)
def plane_first(geom):
    """True when feature 0 of every copy's terrain ``geom`` (G, F, 10) is a plane."""
    if geom.shape[1] == 0:
        return False
    for c in range(geom.shape[0]):
        if geom[c, 0, 0] != PLANE:
            return False
    return True


@njit(inline="always", **_opts)
def plane_only(geom):
    """True when every copy's terrain ``geom`` (G, F, 10) is one plane and nothing else."""
    return geom.shape[1] == 1 and plane_first(geom)


@njit(inline="always", **_opts)
def plane_load(anchor, eta0, active, AN, AC, PP, eta, geom, prm, c0, ne, k, F, E):
    """Lanes 0..E-1 of the plane scratch take the node slots of feature 0, a plane, of copies
    c0..c0+ne-1 (:func:`slots_load`), and PP (12, E) the plane's row (normal, offset: rows 0..3)
    and contact parameters (radius .. cmax: rows 4..11) of each lane, constant over a call; the
    interior slots of that feature, which never touch a plane, are released as
    :func:`rows_forces` releases them (the anchored point kept if it was active), once per
    call: every step would do the same."""
    slots_load(anchor, active, AN, AC, c0, ne, k, F, 0, E)
    for e in range(E):
        c = c0 + e if e < ne else c0
        gr = c if geom.shape[0] > 1 else 0
        pc = c if prm.shape[0] > 1 else 0
        for i in range(4):
            PP[i, e] = geom[gr, 0, 1 + i]
        for i in range(8):
            PP[4 + i, e] = prm[pc, 0, i]
    for e in range(ne):
        for j in range(k):
            ci = 3 * j * F + 2
            if not active[c0 + e, ci]:
                eta0[c0 + e, ci] = 0.5 * (eta[j, 0] + eta[j, 1])
            active[c0 + e, ci] = False


@njit(inline="always", **_opts)
def plane_store(anchor, eta0, active, slip, AN, AC, SL, eta, c0, ne, k, F):
    """Copies c0..c0+ne-1 take their lanes' node slots of feature 0 (:func:`slots_store`) and no
    slip at its interior slots."""
    slots_store(anchor, eta0, active, slip, AN, AC, SL, eta, c0, ne, k, F, 0)
    for e in range(ne):
        for j in range(k):
            slip[c0 + e, 3 * j * F + 2] = False


@njit(inline="always", **_opts)
def plane_forces(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, n, E):
    """:func:`rows_forces` of E lanes of the loop driver for feature 0 of the terrain, a plane
    (:func:`plane_first`), read in the lanes (Q, QD (k, 6, E) m, m/s), into EX (n, 3, E) N; the
    node slots' state and each lane's plane and contact parameters PP in the lane scratch of
    :func:`plane_load`. The same force law (:func:`_slot_force`) on the same numbers in the
    same order, so the same bits, without what a plane never needs (the transposed copy of the
    state, the far test, the interior slot: a plane's nearest point of a rod is an end, and a
    node slot's force goes to its own node whole). The lanes are the innermost loop, so that the
    law compiles to SIMD code over them (a slot clear of the plane adds the law's zero force,
    which leaves EX's bits as they are: EX starts at +0 and a sum is never -0); with a force
    exponent other than 1 in some lane the same loop runs with the exponent read per lane.
    The loop driver's plane instances call it (their step loop carries no code for boxes or
    heights: a branch to it, never taken, made the step of a plane 1.5 times slower at one
    copy), and its general terrain instance for a terrain whose feature 0 is a plane (the
    ground under steps and walls), before :func:`lanes_forces` adds the other features."""
    for p in range(n):
        for i in range(3):
            for e in range(E):
                EX[p, i, e] = 0.0
    linear = True
    for e in range(E):
        if PP[7, e] != 1.0:
            linear = False
    if E == 1:
        _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, False, True)
    elif linear:
        _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, True, False)
    else:
        _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, False, False)


@njit(inline="always", **_opts)
def _plane_slots(Q, QD, EX, AN, AC, SL, PP, eta, rod_a, rod_c, k, E, linear, skip):
    """The node slots' forces of :func:`plane_forces`, lanes innermost: the law of each slot
    over the lanes into a stack tile T (:func:`.layout._stack_tile`: written there, the loop
    compiles to SIMD code), then its anchors, flags and forces from T into the lane scratch.
    ``linear``: every lane's force exponent is 1 (the law's power then compiles away, and with
    it the one call that keeps the loop scalar). ``skip`` (one lane, scalar code): a slot clear
    of the plane takes the law's no-contact values without computing the law (its sqrt and
    divisions), as :func:`rows_forces` does; the same numbers."""
    T = _stack_tile(8)      # row r of lane e at T[r W + e]
    W = _TILE_LANES
    for j in range(k):
        for s in range(2):
            ci = 2 * j + s
            h = eta[j, s]
            node = rod_a[j] if s == 0 else rod_c[j]
            for e in range(E):
                px, py, pz = _lane_point(Q, j, h, e)
                vx, vy, vz = _lane_point(QD, j, h, e)
                g1, g2, g3, g4 = PP[0, e], PP[1, e], PP[2, e], PP[3, e]
                sd = g1 * px + g2 * py + g3 * pz - g4
                if skip and not (PP[4, e] - sd > 0.0):
                    for i in range(8):
                        T[i * W + e] = 0.0
                    T[3 * W + e], T[4 * W + e], T[5 * W + e] = AN[ci, 0, e], AN[ci, 1, e], AN[ci, 2, e]
                    continue
                (touch, T[e], T[W + e], T[2 * W + e], T[3 * W + e], T[4 * W + e], T[5 * W + e], slip, en,
                 fn) = _slot_force(
                    px, py, pz, px, py, pz, vx, vy, vz, sd, g1, g2, g3, 1.0,
                    AN[ci, 0, e], AN[ci, 1, e], AN[ci, 2, e], AC[ci, e], PP[4, e], PP[5, e], PP[6, e],
                    1.0 if linear else PP[7, e], PP[8, e], PP[9, e], PP[10, e], PP[11, e])
                T[6 * W + e] = 1.0 if touch else 0.0
                T[7 * W + e] = 1.0 if slip else 0.0
            _tile_slot_store(T, AN, AC, SL, EX, ci, node, E)
