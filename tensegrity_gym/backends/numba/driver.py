"""The numba backend's ONE loop driver, ``_drive_py``, and its compiled instances.

The driver runs ``n_steps`` fixed steps (semi-implicit Euler or RK4, optional projection,
optional ground contact at each step) of the copies ``lo..hi`` in structure-of-arrays scratch
(k, 6, E). Its instances: ``_drive_one`` (E = 1, in the packed buffer's own scratch reached
through ``numba.carray`` views, ``_view``) and ``_drive_lanes`` (E = 16 or 8 SIMD lanes, fresh
scratch arrays); ``_drive_one_contact`` / ``_drive_lanes_contact`` with ground contact,
``_drive_one_terrain`` / ``_drive_lanes_terrain`` with terrain contact, and
``_drive_one_plane`` / ``_drive_lanes_plane`` on a terrain that is one plane. The
one-copy instances call ``_drive``, the driver compiled once per argument types (E the literal 1),
so that the kernels of a single env share it: numba's inlining copies the whole driver's IR into
each caller, once per basic block, which made most of a single env's cold compile. The SIMD
instances inline it (``_drive_inline``): batched stepping measured 2-7 % faster so. SI units.
"""
from __future__ import annotations

import numba
import numpy as np
from numba import njit

from .contact import _contact_lanes, _contact_load, _contact_store
from .equations import _acc, _drift_rod, _project
from .rod_contact import rods_lanes
from .terrain import has_box, lanes_forces
from .terrain_box import BOX_END_ROWS, BOX_LANE_ROWS, box_load, box_store, boxes_between
from .terrain_hfield import HF_LANE_ROWS, hf_bound_of, hf_lam_load, hf_last
from .terrain_law import add_ext, slots_load, slots_store
from .terrain_plane import plane_first, plane_forces, plane_load, plane_store
from .layout import (_CONS, _EXT, _FD, _L0DEF, _NODE_ROWS, _PROJ, _RK4, _ROD, _STR, ROD_FIXED, STR_FIXED,
                     _opts, _soa_width_nb)

@njit(inline="always", **_opts)
def _lane_physics(PC, N, src, L, k, m, n, e):
    """Lane e of the SoA scratch takes the physical constants of the packed buffer ``src``
    (into ``PC[slot, e]``): each rod's inertia constants (slots 5..11) and table rows (slots
    ROD_FIXED..), each string's table rows (slots STR_FIXED..), the default rest lengths, gravity
    loads and node table rows; and the anchor positions (rows of ``N``)."""
    o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = L
    for j in range(k):
        rj = o_rod + _ROD * j
        for x in range(rj + 5, rj + 12):
            PC[x, e] = src[x]
        for x in range(rj + ROD_FIXED, rj + _ROD):
            PC[x, e] = src[x]
    for s in range(m):
        ps = o_str + _STR * s
        for x in range(ps + STR_FIXED, ps + _STR):
            PC[x, e] = src[x]
        PC[o_l0 + s, e] = src[o_l0 + s]
    for p in range(3 * n):
        PC[o_W0 + p, e] = src[o_W0 + p]
    for p in range(o_cn, o_cn + 3 * n * _NODE_ROWS):
        PC[p, e] = src[p]
    _lane_physics_anchors(N, src, L, n, e)

@njit(inline="always", **_opts)
def _lane_physics_anchors(N, src, L, n, e):
    """Lane e of the node scratch ``N`` takes the node rows of the packed buffer ``src``
    (anchors: their fixed positions; rod nodes are overwritten by every force evaluation)."""
    o_N = L[5]
    for p in range(n):
        for i in range(3):
            N[p, i, e] = src[o_N + 3 * p + i]

@njit(inline="always", **_opts)
def _stage_soa(Q, QD, V, A, c, QS, QDn, k, E):
    """An RK4 stage state of E lanes: ``QS = Q + c V``, ``QDn = QD + c A`` (k, 6, E)."""
    for j in range(k):
        for i in range(6):
            for e in range(E):
                QS[j, i, e] = Q[j, i, e] + c * V[j, i, e]
                QDn[j, i, e] = QD[j, i, e] + c * A[j, i, e]


@numba.extending.intrinsic
def _address(typingctx, arr, offset):
    """Pointer to ``arr.flat[offset]`` (C-contiguous ``arr``), for numba.carray views into the
    packed buffer that cost no reference counting and no reshape call."""
    def codegen(context, builder, sig, args):
        return builder.gep(context.make_array(sig.args[0])(context, builder, args[0]).data, [args[1]])
    return numba.types.CPointer(arr.dtype)(arr, offset), codegen

@njit(inline="always", **_opts)
def _view(arr, offset, shape):
    """C-contiguous view of ``arr`` from flat index ``offset`` with ``shape`` (no bounds check:
    the caller's layout guarantees it). Unlike slicing and reshape, it costs no reference
    counting and no library call, which matter at one copy and one step per call."""
    return numba.carray(_address(arr, offset), shape)

@njit(inline="always", **_opts)
def _scratch(w, L, k, m, n, E, per_copy):
    """The driver's scratch for E lanes, (S, N, V, F, L0, FD, EX, PC): stage arrays S
    (10, k, 6, E), node positions / velocities / forces (n, 3, E), rest lengths and force
    densities (m, E), external forces (n, 3, E), and the lanes' physical constants PC
    (len, E). Separate arrays (the compiler may assume they do not overlap). Where every
    copy shares ``w`` (``per_copy`` False) its constants and anchor rows are written here,
    once; one copy reads them from ``w`` in place. Reusable across calls of the same model
    and E (V's anchor rows, FD and EX stay 0 where unused)."""
    if E == 1:        # one copy (serial calls, GIL held): the packed buffer's own scratch
        o_rod, o_str, o_l0, o_W0, o_ws, o_N, o_V, o_F, o_cn, end = L
        o_x = o_cn + 3 * n * _NODE_ROWS
        PC = _view(w, 0, (0 if per_copy else w.shape[0], 1))
        return (_view(w, o_ws, (10, k, 6, 1)), _view(w, o_N, (n, 3, 1)), _view(w, o_V, (n, 3, 1)),
                _view(w, o_F, (n, 3, 1)), _view(w, o_x, (m, 1)), _view(w, o_x + m, (m, 1)),
                _view(w, o_x + 2 * m, (n, 3, 1)), PC)
    N = np.empty((n, 3, E))
    if per_copy:
        PC = np.empty((0, E))
    else:
        PC = np.empty((L[9], E))
        for e in range(E):
            _lane_physics(PC, N, w, L, k, m, n, e)
    return (np.empty((10, k, 6, E)), N, np.zeros((n, 3, E)), np.empty((n, 3, E)), np.empty((m, E)),
            np.zeros((m, E)), np.zeros((n, 3, E)), PC)

@njit(inline="always", **_opts)
def _load(q, qd, l0, fd, ext, c0, ne, Q, QD, L0, FD, EX, PC, o_l0, k, m, n, E, flags):
    """Lanes 0..E-1 of the scratch take copies c0..c0+ne-1 (pad lanes repeat copy c0): the
    state ``q``, ``qd`` (B, k, 6) into Q, QD (k, 6, E), the rest lengths (the lane's defaults in
    ``PC`` with _L0DEF, else ``l0`` (1 or B, m)), force densities ``fd`` (with _FD) and external
    forces ``ext`` (with _EXT), each one row shared or one per copy."""
    l0def = (flags & _L0DEF) != 0
    has_fd = (flags & _FD) != 0
    has_ext = (flags & _EXT) != 0
    nl, nf, ne_ = l0.shape[0], fd.shape[0], ext.shape[0]
    for e in range(E):
        src = c0 + e if e < ne else c0          # pad lanes repeat the first environment
        for j in range(k):
            for i in range(6):
                Q[j, i, e] = q[src, j, i]
                QD[j, i, e] = qd[src, j, i]
        for s in range(m):
            L0[s, e] = PC[o_l0 + s, e] if l0def else l0[src if nl > 1 else 0, s]
        if has_fd:
            for s in range(m):
                FD[s, e] = fd[src if nf > 1 else 0, s]
        if has_ext:
            for p in range(n):
                for i in range(3):
                    EX[p, i, e] = ext[src if ne_ > 1 else 0, p, i]


def _drive_py(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes, E, contact,
              terrain, plane, rods):
    """``n_steps`` fixed steps of copies lo..hi-1 from (q[e], qd[e]) into (qo[e], qdo[e]) (which
    may be the same arrays): the one loop driver of the numba backend. E copies at a time in
    structure-of-arrays scratch (k, 6, E), so that every inner loop runs over copies and
    compiles to SIMD code; E = 1 (one copy at a time) for small batches. The equations are
    called once per stage (:func:`_acc`, a compiled function shared with the entry ``_run_acc``)
    or inlined (_drift_rod, _project).
    ``w``/``ib``: the packed buffer (topology; its physical constants where every copy shares
    them). ``lanes`` (ceil(B/E), len, E): the copies' packed buffers in blocks of E lanes
    (:func:`_lanes`, or (P, len, 1) for E = 1; per-copy parameters, ``lo`` a multiple of E),
    read in place: no copy per call; or (0, 1, 1): every copy uses ``w``'s constants.
    Its scratch (:func:`_scratch`) is made here: fresh arrays for SIMD blocks (which the
    compiler knows do not overlap), views of ``w``'s own scratch for E = 1.
    ``contact``: None (the instances without ground contact: the compiler prunes every
    ``contact is not None`` branch, so they carry no contact code) or the tuple
    (eta, rod_a, rod_c, prm, anchor, active, slip, cext) of the contact sub-steps: at the start
    of every step the contact forces of the lanes (:func:`_contact_lanes`, from the step's
    start, plus ``cext``) replace the external forces EX for that step (``flags`` carry
    ``_EXT``; ``ext`` is the (B, n, 3) output of the last step's forces); anchors, active and
    slip flags stay in lane scratch for all ``n_steps`` and are stored with the state.
    ``terrain``: None or the tuple of :func:`.terrain.lanes_forces` (terrain contact: its forces
    replace EX at the start of every step, as the ground contact's; the contact state is the
    copies' own arrays; ``ext`` receives each copy's forces of its last step; a feature 0 that
    is a plane in every copy, the ground under steps or walls, runs in the lanes
    (:func:`.terrain.plane_forces`, its node slots' state in lane scratch as the plane
    instance's) and the other features after it; a last feature that is a heightfield in every
    copy, rough ground or a course's ground, runs in the lanes after the others
    (:func:`.terrain.hf_lanes_forces`, its node slots' state in lane scratch too)). ``plane``: None or the tuple of
    :func:`.terrain.plane_forces` (a terrain that is one plane, as ``terrain`` but for that one
    kind: the instance then carries no code for the other kinds). ``rods``: None (no rod-rod
    contact: the compiler prunes its branches) or the tuple (eta, rod_a, rod_c, prm) of
    :func:`.rod_contact.rods_lanes`: at every step, after the ground or terrain forces (and
    their external force), the rod-rod contact forces of the step's start are added to EX."""
    S, N, V, F, L0, FD, EX, PC = _scratch(w, L, k, m, n, E, lanes.shape[0] > 0)
    if rods is not None:
        r_eta, r_rod_a, r_rod_c, r_prm = rods
    if contact is not None:
        eta, rod_a, rod_c, prm, anchor, active, slip, cext = contact
        AN = np.empty((2 * k, 2, E))
        AC = np.zeros((2 * k, E), np.bool_)
        SL = np.zeros((2 * k, E), np.bool_)
    if terrain is not None:
        # unpacked once: unpacking the tuple inside the step loop costs a reference count per array and step
        (t_eta, t_rod_a, t_rod_c, t_geom, t_prm, t_hf, t_anchor, t_eta0, t_active, t_slip, t_info,
         t_ext) = terrain
        t_g = np.empty(t_geom.shape[2])       # rows_forces' scratch for a feature's rows
        t_pr = np.empty(t_prm.shape[2])
        # the boxes' clearance over one call's sub-steps (no rows, not kept, on a terrain without boxes)
        t_rows = E if has_box(t_geom) else 0
        t_clr = np.empty((t_rows, t_geom.shape[1]))
        t_ref = np.empty((t_rows, k, 2, 3))
        # shared heights: their slope bound once per call (per-copy ones: per copy, in lanes_forces)
        t_lam = 1.0 if (t_geom.shape[0] > 1 or t_hf.shape[0] > 1) else hf_bound_of(t_geom[0], t_hf[0])
        # a ground plane first: its node slots in the lanes, the other features after it
        t_f0 = 1 if plane_first(t_geom) else 0
        t_F = t_geom.shape[1]
        # a heightfield last (the ground of rough terrain and courses): its node slots in the lanes too
        t_f1 = t_F - 1 if (hf_last(t_geom) and t_info.shape[0] == 0) else t_F
        HAN = np.empty((2 * k, 3, E))
        HAC = np.zeros((2 * k, E), np.bool_)
        HSL = np.zeros((2 * k, E), np.bool_)
        LAM = np.empty((HF_LANE_ROWS + 8 * k, E))
        # the features between them boxes in every copy (steps, walls, obstacles): their node slots in
        # the lanes too, SIMD blocks only (one copy at a time, rows_forces)
        t_bx = E > 1 and t_info.shape[0] == 0 and boxes_between(t_geom, t_f0, t_f1)
        t_nb = t_f1 - t_f0 if t_bx else 0
        BAN = np.empty((t_nb, 2 * k, 3, E))
        BAC = np.zeros((t_nb, 2 * k, E), np.bool_)
        BSL = np.zeros((t_nb, 2 * k, E), np.bool_)
        BP = np.empty((t_nb, BOX_LANE_ROWS, E))
        BT = np.empty((k, BOX_END_ROWS, E))
    if plane is not None:
        p_eta, p_rod_a, p_rod_c, p_geom, p_prm, p_anchor, p_eta0, p_active, p_slip, p_ext = plane
    if terrain is not None or plane is not None:
        # a plane's node slots in lane scratch (the plane instance's, or the ground plane listed first)
        PAN = np.empty((2 * k, 3, E))
        PAC = np.zeros((2 * k, E), np.bool_)
        PSL = np.zeros((2 * k, E), np.bool_)
        PP = np.empty((12, E))
    Q, QD, A1, A2, A3, A4, QS, QD2, QD3, QD4 = S[0], S[1], S[2], S[3], S[4], S[5], S[6], S[7], S[8], S[9]
    if terrain is not None:
        # the terrain forces read the lanes (k, 6, E) and write EX (n, 3, E) through views indexed
        # by copy first, as rows_forces indexes a batch
        QT, QDT, EXT = Q.transpose((2, 0, 1)), QD.transpose((2, 0, 1)), EX.transpose((2, 0, 1))
    per_copy = lanes.shape[0] > 0
    rk4 = (flags & _RK4) != 0
    n_stages = 4 if rk4 else 1
    do_proj = (flags & _PROJ) != 0
    any_cons = (flags & _CONS) != 0
    h = 0.5 * dt
    c6 = dt / 6.0
    o_l0 = L[2]
    o_rod = L[0]
    o_N = L[5]
    for c0 in range(lo, hi, E):
        ne = min(E, hi - c0)
        if per_copy:                                # this block's lane constants and anchor rows
            PC = lanes[c0 // E]
            if E == 1:
                # one copy at a time: its node scratch is its own buffer's node rows (anchors
                # included); the shared scratch of w would carry this copy's anchors into the
                # next call of copy 0, whose buffer w is
                N = _view(PC, o_N, (n, 3, 1))
            for p in range(n):
                for i in range(3):
                    for e in range(E):
                        N[p, i, e] = PC[o_N + 3 * p + i, e]
        _load(q, qd, l0, fd, ext, c0, ne, Q, QD, L0, FD, EX, PC, o_l0, k, m, n, E, flags)
        if contact is not None:
            _contact_load(anchor, active, AN, AC, c0, ne, k, E)
        if plane is not None:
            plane_load(p_anchor, p_eta0, p_active, PAN, PAC, PP, p_eta, p_geom, p_prm, c0, ne, k, 1, E)
        if terrain is not None and t_f0 > 0:
            plane_load(t_anchor, t_eta0, t_active, PAN, PAC, PP, t_eta, t_geom, t_prm, c0, ne, k, t_F, E)
        if terrain is not None and t_f1 < t_F:
            slots_load(t_anchor, t_active, HAN, HAC, c0, ne, k, t_F, t_f1, E)
            hf_lam_load(LAM, t_geom, t_prm, t_hf, t_lam, c0, ne)
        if terrain is not None and t_bx:
            box_load(t_anchor, t_active, BAN, BAC, BP, t_geom, t_prm, c0, ne, k, t_f0, E)
        for step in range(n_steps):
            if contact is not None:                 # held over the step, as contact_step does
                _contact_lanes(Q, QD, EX, AN, AC, SL, eta, rod_a, rod_c, prm, cext, c0, ne, k, n, E)
            if terrain is not None:
                if t_f0 > 0:
                    plane_forces(Q, QD, EX, PAN, PAC, PSL, PP, t_eta, t_rod_a, t_rod_c, k, n, E)
                lanes_forces(QT, QDT, EXT, EX, t_eta, t_rod_a, t_rod_c, t_geom, t_prm, t_hf, t_anchor, t_eta0,
                             t_active, t_slip, t_info, t_ext, t_lam, t_g, t_pr, (t_clr, t_ref, step == 0), c0, ne, k,
                             n, E, (t_f0, t_f1), (HAN, HAC, HSL, LAM), (t_bx, Q, QD, BAN, BAC, BSL, BP, BT))
            if plane is not None:
                plane_forces(Q, QD, EX, PAN, PAC, PSL, PP, p_eta, p_rod_a, p_rod_c, k, n, E)
                add_ext(EX, p_ext, c0, ne, n, E)
            if rods is not None:
                rods_lanes(Q, QD, EX, r_eta, r_rod_a, r_rod_c, r_prm, k, E)
            Qi = Q
            Vi = QD
            A = A1
            for stage in range(n_stages):
                _acc(w, ib, L, k, m, n, Qi, Vi, A, N, V, F, L0, FD, EX, E, flags, PC)
                if not rk4 and do_proj:
                    for j in range(k):
                        for i in range(6):
                            for e in range(E):
                                QD[j, i, e] = QD[j, i, e] + dt * A1[j, i, e]
                        for e in range(E):
                            (Q[j, 0, e], Q[j, 1, e], Q[j, 2, e], Q[j, 3, e], Q[j, 4, e], Q[j, 5, e],
                             QD[j, 3, e], QD[j, 4, e], QD[j, 5, e]) = _drift_rod(
                                Q[j, 0, e], Q[j, 1, e], Q[j, 2, e], Q[j, 3, e], Q[j, 4, e], Q[j, 5, e],
                                QD[j, 0, e], QD[j, 1, e], QD[j, 2, e], QD[j, 3, e], QD[j, 4, e],
                                QD[j, 5, e], dt)
                elif not rk4:
                    for j in range(k):
                        for i in range(6):
                            for e in range(E):
                                QD[j, i, e] = QD[j, i, e] + dt * A1[j, i, e]
                                Q[j, i, e] = Q[j, i, e] + dt * QD[j, i, e]
                elif stage == 0:
                    _stage_soa(Q, QD, QD, A1, h, QS, QD2, k, E)
                    Qi, Vi, A = QS, QD2, A2
                elif stage == 1:
                    _stage_soa(Q, QD, QD2, A2, h, QS, QD3, k, E)
                    Qi, Vi, A = QS, QD3, A3
                elif stage == 2:
                    _stage_soa(Q, QD, QD3, A3, dt, QS, QD4, k, E)
                    Qi, Vi, A = QS, QD4, A4
                else:
                    for j in range(k):
                        for i in range(6):
                            for e in range(E):
                                Q[j, i, e] = Q[j, i, e] + c6 * (QD[j, i, e] + 2.0 * QD2[j, i, e]
                                                                + 2.0 * QD3[j, i, e] + QD4[j, i, e])
                                QD[j, i, e] = QD[j, i, e] + c6 * (A1[j, i, e] + 2.0 * A2[j, i, e]
                                                                  + 2.0 * A3[j, i, e] + A4[j, i, e])
            if do_proj:
                _project(w, ib, o_rod, k, Q, QD, E, any_cons)
        for e in range(ne):
            for j in range(k):
                for i in range(6):
                    qo[c0 + e, j, i] = Q[j, i, e]
                    qdo[c0 + e, j, i] = QD[j, i, e]
        if contact is not None:
            _contact_store(anchor, active, slip, ext, AN, AC, SL, EX, c0, ne, k, n)
        if plane is not None:
            plane_store(p_anchor, p_eta0, p_active, p_slip, PAN, PAC, PSL, p_eta, c0, ne, k, 1)
        if terrain is not None and t_f0 > 0:
            plane_store(t_anchor, t_eta0, t_active, t_slip, PAN, PAC, PSL, t_eta, c0, ne, k, t_F)
        if terrain is not None and t_f1 < t_F:
            slots_store(t_anchor, t_eta0, t_active, t_slip, HAN, HAC, HSL, t_eta, c0, ne, k, t_F, t_f1)
        if terrain is not None and t_bx:
            box_store(t_anchor, t_eta0, t_active, t_slip, BAN, BAC, BSL, t_eta, c0, ne, k, t_F, t_f0)
        if terrain is not None or plane is not None:
            for e in range(ne):
                for p in range(n):
                    for i in range(3):
                        ext[c0 + e, p, i] = EX[p, i, e]

# The one driver: compiled on its own for the one-copy instances (E passed as the literal 1: its lane
# loops are dropped), inlined into the SIMD ones (E = 16 or 8). Same source, same operations.
_drive = njit(**_opts)(_drive_py)
_drive_inline = njit(inline="always", **_opts)(_drive_py)

@njit(**_opts)
def _drive_lanes(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes):
    """_drive_py in SIMD blocks of E = :func:`_soa_width` copies (fresh scratch arrays)."""
    _drive_inline(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes,
                    _soa_width_nb(k), None, None, None, None)

@njit(**_opts)
def _drive_one(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes):
    """_drive_lanes one copy at a time (E = 1, a compile-time constant), in the scratch of ``w``."""
    _drive(w, ib, L, k, m, n, q, qd, qo, qdo, lo, hi, l0, fd, ext, dt, n_steps, flags, lanes, 1, None, None, None, None)

@njit(**_opts)
def _drive_lanes_contact(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, contact, rods):
    """_drive_lanes with ground contact (``contact`` the tuple of :func:`_drive_py`), in place on
    q, qd; ``W`` (B, n, 3) receives each copy's forces of its last step. ``rods``: None or the
    rod-rod contact tuple of :func:`_drive_py` (here and in the terrain and plane instances)."""
    _drive_inline(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes,
                    _soa_width_nb(k), contact, None, None, rods)

@njit(**_opts)
def _drive_one_contact(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, contact, rods):
    """_drive_one with ground contact (see :func:`_drive_lanes_contact`)."""
    _drive(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, 1, contact, None, None, rods)

@njit(**_opts)
def _drive_lanes_terrain(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, terrain, rods):
    """_drive_lanes with terrain contact (``terrain`` the tuple of :func:`.terrain.lanes_forces`),
    in place on q, qd; ``W`` (B, n, 3) receives each copy's forces of its last step."""
    _drive_inline(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes,
                  _soa_width_nb(k), None, terrain, None, rods)

@njit(**_opts)
def _drive_one_terrain(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, terrain, rods):
    """_drive_one with terrain contact (see :func:`_drive_lanes_terrain`)."""
    _drive(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, 1, None, terrain, None, rods)


@njit(**_opts)
def _drive_lanes_plane(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, plane, rods):
    """_drive_lanes on a terrain that is one plane (``plane`` the tuple of :func:`.terrain.plane_forces`)."""
    _drive_inline(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes,
                  _soa_width_nb(k), None, None, plane, rods)

@njit(**_opts)
def _drive_one_plane(w, ib, L, k, m, n, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, plane, rods):
    """_drive_one on a terrain that is one plane (see :func:`_drive_lanes_plane`)."""
    _drive(w, ib, L, k, m, n, q, qd, q, qd, lo, hi, l0, fd, W, dt, n_steps, flags, lanes, 1, None, None, plane, rods)
