"""Import a class-1 tensegrity from a MuJoCo model (MJCF XML): :func:`from_mjcf`.

SI units throughout (m, kg, s, N). The file is read as the field writes tensegrities in MJCF
(:mod:`tensegrity_gym.core.mjcf_read` reads the XML, its defaults and its masses; MuJoCo is not
needed). The mapping, the approximations and what is refused are in ``docs/mjcf.md``; in short:

* **Rods**: each top-level body with a ``freejoint`` is a rod. Its axis is that of its longest
  capsule or cylinder geom (``fromto`` or ``size`` + frame). Its mass is the sum of its geoms'
  masses (``mass``, else ``density`` x volume), or its ``<inertial>`` where MuJoCo would use it
  (``<compiler inertiafromgeom>``). The centre of mass and the moment of inertia about the
  transverse axes become the rod's mass distribution (``mass_points``: two lumped masses with the
  same mass, centre and transverse moment; none for a uniform rod).
* **Nodes**: the sites that strings attach to are mapped to their points on the rod's axis (a
  class-1 rod neither spins about its axis nor holds strings off it); the rod's two nodes are
  the outermost of these points, and a site between them moves along the axis to the nearer
  node. The report gives each site's offset from the axis and its shift along it. Sites named
  ``node<i>`` (as :func:`tensegrity_gym.io.mjcf.to_mjcf` writes them) keep their index ``i``;
  otherwise nodes are numbered rod by rod. Sites in the world body are fixed anchors.
* **Strings**: spatial tendons between two sites, with ``stiffness``, ``damping`` and
  ``springlength`` (``l0`` or the dead band ``"0 l0"``: a tension-only string of rest length
  ``l0``; absent: the initial length). A tendon actuator with an affine bias (``general`` with
  ``biastype="affine"``, ``position``) is a spring too: ``biasprm = (b0, -k, -c)`` makes a
  string of stiffness ``k``, damping ``c`` and rest length ``(b0 + gain ctrl) / k``, which its
  control moves: it is listed as an actuated string with its rest-length range.
* ``<option>`` gravity (``None`` when zero or disabled) and timestep, and the floor plane with
  its friction go to the report; end-cap spheres give the contact cap radius.

Not class-1, refused with the element, its name and its line: hinge, slide and ball joints,
equality constraints, tendons through more than two sites, pulleys and wrapping geoms, fixed
tendons, nested bodies and bodies without a free joint that hold geoms.
"""
from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from .checks import read_bounded
from .errors import StructureError
from .structure import MAX_FILE_BYTES, Structure
from .mjcf_read import ACTUATOR_TAGS, read_document
from .mjcf_report import ActuatedString, ImportReport
from .mjcf_springs import finish_string, merge_parallel, string_of_tendon

__all__ = ["from_mjcf", "ImportReport", "ActuatedString"]

_IGNORED = {"compiler", "option", "size", "visual", "statistic", "asset", "default", "custom", "extension",
            "worldbody", "tendon", "actuator", "equality", "contact", "sensor", "keyframe"}
_SECTIONS_DROPPED = {"keyframe": "the structure starts at its bodies' placement, at rest",
                     "sensor": "sensors are not part of a structure",
                     "contact": "contact pairs and exclusions are not imported"}
_REFUSED_WORLD = {"frame": "frames", "replicate": "replicated bodies", "composite": "composite objects",
                  "flexcomp": "flexible objects", "attach": "attached models"}


def _read_source(source):
    """(text, label, folder of includes) of a path or an XML string."""
    if isinstance(source, bytes):
        source = source.decode("utf-8-sig")
    if isinstance(source, str) and source.lstrip().startswith("<"):
        return source, "<string>", None
    if not isinstance(source, (str, os.PathLike)):
        raise StructureError(f"source: expected an MJCF path or XML text, got {type(source).__name__}")
    path = Path(source)
    if path.is_dir():
        raise StructureError(f"{path}: is a directory, not an MJCF file")
    try:
        text = read_bounded(path, MAX_FILE_BYTES, "MJCF file")
    except ValueError as e:
        raise StructureError(str(e)) from None
    return text, str(path), path.parent


def _transverse(I, u):
    """(J, asymmetry, cross): the mean moment of inertia about axes perpendicular to ``u``
    (kg m^2), the relative difference of the two, and the relative size of the product of inertia
    that couples the axis to them (both 0 for an axisymmetric body)."""
    e1 = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    E = np.column_stack([e1, np.cross(u, e1)])
    A = E.T @ I @ E
    ev = np.linalg.eigvalsh(A)
    J = float(np.trace(A) / 2)
    return J, float((ev[1] - ev[0]) / (2 * J)) if J > 0 else 0.0, float(np.linalg.norm(E.T @ I @ u) / J) if J > 0 else 0.0


def _mass_points(m, sigma, J, L, name, notes):
    """None (uniform) or two ``(mu, m)`` lumped masses with mass ``m``, centre ``sigma`` and
    transverse moment ``J``, within the rod (mu in [0, 1])."""
    var = J / (m * L * L)
    if abs(sigma - 0.5) <= 1e-9 and abs(var * 12 - 1) <= 1e-9:
        return None
    if not 0.0 <= sigma <= 1.0:
        notes.append(f"rod {name!r}: centre of mass beyond an end node (fraction {sigma:.4g}); moved to the node")
        sigma = min(max(sigma, 0.0), 1.0)
    if var > sigma * (1 - sigma) * (1 - 1e-12):
        cap = sigma * (1 - sigma)
        notes.append(f"rod {name!r}: mass beyond its end nodes; transverse inertia {J:.6g} kg m^2 reduced to "
                     f"{cap * m * L * L:.6g} (lumped masses lie between the nodes)")
        var = cap
    r = math.sqrt(var)
    if sigma - r >= 0 and sigma + r <= 1:
        return [(sigma - r, m / 2), (sigma + r, m / 2)]
    if sigma - r < 0:
        p = (sigma * sigma + var) / sigma
        return [(0.0, m * (1 - sigma / p)), (p, m * sigma / p)]
    p = 1 - ((1 - sigma) ** 2 + var) / (1 - sigma)
    return [(p, m * (1 - sigma) / (1 - p)), (1.0, m * (1 - (1 - sigma) / (1 - p)))]


def _rod(doc, body):
    """A rod body's geometry and mass: axis origin ``o`` and unit ``u`` (world), geom half-length,
    mass, centre of mass and inertia (world), sites (name -> world point), end-cap radius."""
    child = body.get("childclass")
    bpos, bR = doc.frame(body)
    world = (lambda p, R: (p, R)) if doc.global_coords else (lambda p, R: (bpos + bR @ p, bR @ R))
    free, geoms, sites, inertial = 0, [], {}, None
    for ch in body:
        if ch.tag == "freejoint" or (ch.tag == "joint" and doc.attrs(ch, "joint", child).get("type", "hinge") == "free"):
            free += 1
        elif ch.tag == "joint":
            jt = doc.attrs(ch, "joint", child).get("type", "hinge")
            raise doc.error(ch, f"a {jt} joint is not class-1 (each rod is a free body; a class-1 tensegrity has "
                                "no joints between rods or to the world)")
        elif ch.tag == "body":
            raise doc.error(ch, "a nested body is not class-1 (rods touch each other only through strings)")
        elif ch.tag in _REFUSED_WORLD or ch.tag in ("plugin", "composite", "flexcomp"):
            raise doc.error(ch, f"{ch.tag} inside a body is not supported by the importer")
        elif ch.tag == "geom":
            a = doc.attrs(ch, "geom", child)
            g = doc.geom(ch, a)
            g["pos"], g["R"] = world(g["pos"], g["R"])
            g.update(elem=ch, name=ch.get("name"), group=int(float(a.get("group", 0))))
            geoms.append(g)
        elif ch.tag == "site":
            p, _ = doc.frame(ch, doc.attrs(ch, "site", child))
            sites[ch.get("name")] = (world(p, np.eye(3))[0], ch)
        elif ch.tag == "inertial":
            inertial = ch
    if free == 0:
        if geoms:
            raise doc.error(body, "a body without a freejoint that holds geoms is welded to the world: not a rod of "
                                  "a class-1 tensegrity")
        return None, sites
    if free > 1:
        raise doc.error(body, "more than one free joint")
    rods = [g for g in geoms if g["type"] in ("capsule", "cylinder")]
    if not rods:
        raise doc.error(body, "a free body without a capsule or cylinder geom: no rod axis")
    rg = max(rods, key=lambda g: g["half"])
    u, o = rg["R"][:, 2], rg["pos"]
    lo, hi = (int(v) for v in doc.floats(doc.root, "inertiagrouprange", doc.compiler, 2, [0, 5]))
    mode = doc.compiler.get("inertiafromgeom", "auto")
    if inertial is not None and mode != "true":
        ip, iR = doc.frame(inertial)
        ip, iR = world(ip, iR)
        m = doc.floats(inertial, "mass", n=1)[0]
        diag = doc.floats(inertial, "diaginertia", n=3)
        if diag is not None:
            I = iR @ np.diag(diag) @ iR.T
        else:
            f = doc.floats(inertial, "fullinertia", n=6)
            if f is None:
                raise doc.error(inertial, "needs diaginertia or fullinertia")
            I = iR @ np.array([[f[0], f[3], f[4]], [f[3], f[1], f[5]], [f[4], f[5], f[2]]]) @ iR.T
        com = ip
    else:
        if mode == "false":
            raise doc.error(body, "no <inertial> and <compiler inertiafromgeom=\"false\">: no mass")
        use = [g for g in geoms if lo <= g["group"] <= hi]
        for g in use:
            if g["mass"] is None:
                raise doc.error(g["elem"], f"the importer cannot compute the mass of a {g['type']} geom; give the "
                                           "body an <inertial>")
        m = sum(g["mass"] for g in use)
        if not m > 0:
            raise doc.error(body, "the body has no mass")
        com = sum(g["mass"] * g["pos"] for g in use) / m
        I = np.zeros((3, 3))
        for g in use:
            d = g["pos"] - com
            I += g["R"] @ np.diag(g["inertia"]) @ g["R"].T + g["mass"] * (d @ d * np.eye(3) - np.outer(d, d))
    caps = [g["size"][0] for g in geoms if g["type"] == "sphere"]
    name = body.get("name") or f"body at {doc.where(body)}"
    return {"name": name, "elem": body, "u": u, "o": o, "half": rg["half"], "mass": m, "com": com, "I": I,
            "cap": max(caps) if caps else rg["size"][0], "pos": bpos, "R": bR}, sites


def from_mjcf(source, name: str | None = None) -> tuple[Structure, ImportReport]:
    """A class-1 :class:`~tensegrity_gym.core.structure.Structure` and an :class:`ImportReport`
    from an MJCF file path or XML text (see the module docstring and ``docs/mjcf.md``).
    Raises :class:`~tensegrity_gym.core.errors.StructureError` (a ``ValueError``) naming the
    element, its name and its line for anything that is not a class-1 tensegrity."""
    text, label, base = _read_source(source)
    doc = read_document(text, label, base, lambda p: read_bounded(p, MAX_FILE_BYTES, "MJCF file"))
    root, rep = doc.root, ImportReport(source=label)
    for eq in root.iter("equality"):
        for ch in eq:
            raise doc.error(ch, "an equality constraint is not class-1 (rods are joined only by strings)")
    for sec in root:
        if sec.tag not in _IGNORED:
            rep.dropped.append(f"<{sec.tag}> at {doc.where(sec)}: not read")
        elif sec.tag in _SECTIONS_DROPPED and len(sec):
            rep.dropped.append(f"<{sec.tag}>: {len(sec)} element(s); {_SECTIONS_DROPPED[sec.tag]}")
    opt = {}
    for o in root.iter("option"):
        opt.update(o.attrib)
    flags = {}
    for f in root.iter("flag"):
        flags.update(f.attrib)
    g = doc.floats(root, "gravity", opt, 3, [0.0, 0.0, -9.81])
    rep.gravity = None if flags.get("gravity") == "disable" or not any(g) else tuple(g)
    rep.timestep = doc.floats(root, "timestep", opt, 1, [0.002])[0]
    rep.integrator = opt.get("integrator", "Euler")
    rep.contact = flags.get("contact") != "disable"
    rods, site_of = [], {}     # site name -> (rod index or None, world point, element)
    for wb in root.iter("worldbody"):
        for ch in wb:
            if ch.tag == "body":
                rod, sites = _rod(doc, ch)
                if rod is not None:
                    rods.append(rod)
                for s, (p, e) in sites.items():
                    site_of[s] = (len(rods) - 1 if rod is not None else None, p, e)
            elif ch.tag == "site":
                site_of[ch.get("name")] = (None, doc.frame(ch, doc.attrs(ch, "site"))[0], ch)
            elif ch.tag == "geom":
                a = doc.attrs(ch, "geom")
                if a.get("type", "sphere") == "plane" and rep.floor is None:
                    p, R = doc.frame(ch, a)
                    fr = doc.floats(ch, "friction", a, default=[1.0])[0]
                    rep.floor = {"name": ch.get("name"), "point": p.tolist(), "normal": R[:, 2].tolist(),
                                 "friction": fr}
                else:
                    rep.dropped.append(f"world geom {ch.get('name')!r} ({a.get('type', 'sphere')}) at {doc.where(ch)}: "
                                       "terrain other than one floor plane is not imported")
            elif ch.tag in _REFUSED_WORLD:
                raise doc.error(ch, f"{_REFUSED_WORLD[ch.tag]} are not supported by the importer")
    if not rods:
        raise StructureError(f"{label}: no body with a freejoint and a rod geom: not a tensegrity")
    acts = {}
    for sec in root.iter("actuator"):
        for a in sec:
            if a.tag in ACTUATOR_TAGS:
                acts.setdefault(a.get("tendon"), []).append(a)
    for key, lst in acts.items():
        if key is None:
            for a in lst:
                rep.add("dropped", "actuators {names}: act on a joint, site or body, not on a tendon",
                        a.get("name") or f"actuator at {doc.where(a)}")
    strings = []       # (tendon name, (site, site), string_of_tendon's row)
    for sec in root.iter("tendon"):
        for t in sec:
            if t.tag == "fixed":
                raise doc.error(t, "a fixed tendon couples joints: not class-1")
            if t.tag != "spatial":
                continue
            kids = list(t)
            for k in kids:
                if k.tag == "pulley":
                    raise doc.error(k, f"a pulley in tendon {t.get('name')!r}: not class-1 (a string joins two points)")
                if k.tag == "geom":
                    raise doc.error(k, f"tendon {t.get('name')!r} wraps around a geom: not class-1 (a string is "
                                       "straight)")
            sites = [k.get("site") for k in kids if k.tag == "site"]
            if len(sites) != 2:
                raise doc.error(t, f"a tendon through {len(sites)} sites: a class-1 string joins exactly two")
            for s in sites:
                if s not in site_of:
                    raise doc.error(t, f"site {s!r} does not exist")
            row = string_of_tendon(doc, t, acts.pop(t.get("name"), []) if t.get("name") else [], rep)
            if row is not None:
                strings.append((t.get("name") or f"tendon at {doc.where(t)}", sites, row))
    for key, lst in acts.items():
        if key is not None:
            raise doc.error(lst[0], f"tendon {key!r} does not exist")
    return _assemble(doc, rods, site_of, strings, rep, name or root.get("model") or Path(label).stem)


def _assemble(doc, rods, site_of, strings, rep, name):
    """The structure from the rods, the sites the strings use and the strings."""
    used = {}
    for _, sites, _ in strings:
        for s in sites:
            used.setdefault(site_of[s][0], []).append(s)
    keys, point, frames = [], {}, {}
    for j, rod in enumerate(rods):
        u, o = rod["u"], rod["o"]
        ts = {s: float(u @ (site_of[s][1] - o)) for s in used.get(j, [])}
        t_lo, t_hi = (min(ts.values()), max(ts.values())) if ts else (-rod["half"], rod["half"])
        if t_hi - t_lo <= 1e-9 * rod["half"]:
            t_lo, t_hi = (t_lo, rod["half"]) if t_lo <= 0 else (-rod["half"], t_hi)
        for end, t in (("a", t_lo), ("c", t_hi)):
            point[(j, end)] = o + t * u
        for s, t in ts.items():
            end = "a" if abs(t - t_lo) <= abs(t - t_hi) else "c"
            p = site_of[s][1]
            radial = float(np.linalg.norm(p - o - t * u))
            shift = abs(t - (t_lo if end == "a" else t_hi))
            rep.site_offsets[s] = (radial, shift)
            frames[s] = (j, end)
        keys += [(j, "a"), (j, "c")]
        rod["t"] = (t_lo, t_hi)
    for s in used.get(None, []):
        if (None, s) not in point:
            point[(None, s)] = site_of[s][1]
            keys.append((None, s))
        frames[s] = (None, s)
    node_sites = {k: [] for k in keys}
    for s, k in frames.items():
        node_sites[k].append(s)
    names = [node_sites[k] for k in keys]
    idx = [re.fullmatch(r"node(\d+)", ns[0]) if len(ns) == 1 else None for ns in names]
    if all(idx) and sorted(int(m.group(1)) for m in idx) == list(range(len(keys))):
        order = {k: int(m.group(1)) for k, m in zip(keys, idx)}
    else:
        order = {k: i for i, k in enumerate(keys)}
    n = len(keys)
    nodes = np.zeros((n, 3))
    rep.node_sites, rep.node_frames = [None] * n, [None] * n
    for k in keys:
        i = order[k]
        nodes[i] = point[k]
        rep.node_sites[i] = sorted(node_sites[k])
        if k[0] is None:
            rep.node_frames[i] = (None, tuple(point[k]))
        else:
            rod = rods[k[0]]
            rep.node_frames[i] = (rod["name"], tuple(rod["R"].T @ (point[k] - rod["pos"])))
    bars = [[order[(j, "a")], order[(j, "c")]] for j in range(len(rods))]
    rep.rods = [r["name"] for r in rods]
    pairs = {}
    for tname, sites, row in strings:
        a, c = (order[frames[s]] for s in sites)
        j = frames[sites[0]][0]
        if a == c or (j is not None and {a, c} == set(bars[j])):
            rep.add("dropped", f"tendons {{names}}: both sites map to {'one node' if a == c else 'the ends of one rod'}",
                    tname)
            continue
        l0, act = finish_string(row, float(np.linalg.norm(nodes[a] - nodes[c])), rep)
        pairs.setdefault(frozenset((a, c)), []).append({"name": tname, "a": a, "c": c, "k": row["k"], "c_": row["c"],
                                                        "l0": l0, "act": act})
    kept = [merge_parallel(parts, rep) for parts in pairs.values()]
    for i, st in enumerate(kept):
        if st["act"] is not None:
            st["act"].string = i
            rep.actuated.append(st["act"])
    rep.strings = [st["name"] for st in kept]
    masses, points = [], []
    for j, rod in enumerate(rods):
        t_lo, t_hi = rod["t"]
        L = t_hi - t_lo
        cu = float(rod["u"] @ (rod["com"] - rod["o"]))
        off = float(np.linalg.norm(rod["com"] - rod["o"] - cu * rod["u"]))
        if off > 1e-6 * L:
            rep.notes.append(f"rod {rod['name']!r}: centre of mass {off:.3g} m off the axis, moved onto it")
        J, asym, cross = _transverse(rod["I"], rod["u"])
        if asym > 1e-6 or cross > 1e-6:
            rep.notes.append(f"rod {rod['name']!r}: not axisymmetric (transverse moments differ by {asym:.2g}, "
                             f"axis coupling {cross:.2g}); their mean {J:.6g} kg m^2 is used")
        masses.append(rod["mass"])
        points.append(_mass_points(rod["mass"], (cu - t_lo) / L, J, L, rod["name"], rep.notes))
    caps = sorted({round(r["cap"], 12) for r in rods})
    rep.cap_radius = caps[-1]
    if len(caps) > 1:
        rep.notes.append(f"end-cap radii differ ({caps[0]:g}..{caps[-1]:g} m); the largest is the cap radius")
    if rep.site_offsets:
        rep.max_axis_offset = max(v[0] for v in rep.site_offsets.values())
        rep.max_axial_shift = max(v[1] for v in rep.site_offsets.values())
    rep.close()
    try:
        s = Structure(nodes, bars, [[st["a"], st["c"]] for st in kept], bar_mass=masses,
                      stiffness=[st["k"] for st in kept] or 1.0, rest_length=[st["l0"] for st in kept] if kept else None,
                      damping=[st["c_"] for st in kept] or 0.0, gravity=rep.gravity,
                      mass_points=None if all(p is None for p in points) else points, name=name)
    except StructureError as e:
        raise StructureError(f"{rep.source}: the imported structure is not valid: {e}") from None
    return s, rep
