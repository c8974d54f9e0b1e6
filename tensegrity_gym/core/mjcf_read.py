"""Reading an MJCF (MuJoCo XML) document the way MuJoCo's compiler reads it, for the importer.

The pieces :mod:`tensegrity_gym.core.mjcf_import` needs: the element tree with the file and line of
every element (``<include>`` files inlined), the ``<compiler>`` settings, the ``<default>``
classes (nested classes, ``class`` and ``childclass``), the actuator shortcuts (``motor``,
``position``, ``velocity``, ``intvelocity``) written as ``general`` parameters, frame
orientations (``quat``, ``axisangle``, ``euler``, ``xyaxes``, ``zaxis``; degrees unless
``<compiler angle="radian">``) and each geom's mass, centre and inertia as MuJoCo computes them
from ``mass`` or ``density`` (kg/m^3). SI units: m, kg, kg m^2, s.

Every refusal is a :class:`~tensegrity_gym.core.errors.StructureError` (a ``ValueError``) that
names the file, the line, the element and its name (:meth:`Document.error`).
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

import numpy as np

from .errors import StructureError

__all__ = ["Document", "read_document", "ACTUATOR_TAGS", "quat_z_to", "quat_matrix"]

#: the actuator elements; ``general`` is the full form, the others shortcuts for it
ACTUATOR_TAGS = ("general", "motor", "position", "velocity", "intvelocity", "damper", "cylinder",
                 "muscle", "adhesion", "plugin")
#: element kinds whose attributes a ``<default>`` class holds (the importer reads these)
_DEFAULT_KINDS = ("geom", "site", "joint", "tendon")
#: deepest chain of ``<include>`` files followed (a file including itself is refused long before)
_MAX_INCLUDE_DEPTH = 8
_ACTUATOR_BASE = {"dyntype": "none", "gaintype": "fixed", "biastype": "none",
                  "dynprm": [1.0] + [0.0] * 9, "gainprm": [1.0] + [0.0] * 9, "biasprm": [0.0] * 10,
                  "gear": [1.0, 0, 0, 0, 0, 0], "ctrlrange": None, "forcerange": None, "actrange": None,
                  "ctrllimited": "auto", "forcelimited": "auto", "actlimited": "auto", "kind": "general",
                  "dampratio": 0.0}


def quat_matrix(q) -> np.ndarray:
    """Rotation matrix of the quaternion ``q`` = (w, x, y, z) (normalised here)."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quat_z_to(v) -> np.ndarray:
    """The smallest rotation (w, x, y, z) taking the z axis onto the direction ``v``."""
    b = np.asarray(v, float) / np.linalg.norm(v)
    c = float(b[2])
    if c < -1.0 + 1e-12:
        return np.array([0.0, 1.0, 0.0, 0.0])
    q = np.array([1.0 + c, -b[1], b[0], 0.0])
    return q / np.linalg.norm(q)


def _quat_mul(a, b) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _axis_angle(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[math.cos(angle / 2), math.sin(angle / 2) * axis]


class Document:
    """A parsed MJCF document: ``root`` (an ElementTree element), ``compiler`` (merged
    attributes), ``classes`` (class name -> kind -> attributes; ``"actuator"`` -> general
    parameters) and the place of each element (:meth:`where`)."""

    def __init__(self, root, places, label):
        self.root, self._places, self.label = root, places, label
        comp = {}
        for c in root.iter("compiler"):
            comp.update(c.attrib)
        self.compiler = comp
        angle = comp.get("angle", "degree")
        if angle not in ("degree", "radian"):
            raise self.error(next(root.iter("compiler")), f"angle must be degree or radian, got {angle!r}")
        self.angle_unit = math.pi / 180.0 if angle == "degree" else 1.0
        self.eulerseq = comp.get("eulerseq", "xyz")
        self.autolimits = comp.get("autolimits", "true") == "true"
        self.global_coords = comp.get("coordinate", "local") == "global"
        self.classes = {}
        tops = [d for d in root if d.tag == "default"]
        base = {k: {} for k in _DEFAULT_KINDS}
        base["actuator"] = dict(_ACTUATOR_BASE)
        self.classes["main"] = base
        for d in tops:
            self._read_default(d, base, d.get("class", "main"))

    # ------------------------------------------------------------------ places and errors
    def where(self, elem) -> str:
        label, line = self._places.get(elem, (self.label, 0))
        return f"{label} line {line}"

    def describe(self, elem) -> str:
        """``<tag name='x'>`` (or ``(unnamed)``) at its file and line."""
        name = elem.get("name")
        return f"{self.where(elem)}: <{elem.tag} name={name!r}>" if name is not None else \
            f"{self.where(elem)}: <{elem.tag}> (unnamed)"

    def error(self, elem, reason: str) -> StructureError:
        return StructureError(f"{self.describe(elem)}: {reason}")

    # ------------------------------------------------------------------ numbers
    def floats(self, elem, attr, attrs=None, n=None, default=None):
        """The numbers of attribute ``attr`` (from ``attrs``, default the element's own), or
        ``default`` when absent; an error naming the element if they are not ``n`` numbers."""
        raw = (elem.attrib if attrs is None else attrs).get(attr)
        if raw is None:
            return default
        where = "" if attr in elem.attrib or attrs is None else " (from its default class)"
        try:
            vals = [float(x) for x in raw.split()]
        except ValueError:
            raise self.error(elem, f"{attr}={raw!r}{where} is not a list of numbers") from None
        if (n is not None and len(vals) != n) or not vals or not all(math.isfinite(v) for v in vals):
            raise self.error(elem, f"{attr}={raw!r}{where}: expected {n or 'some'} finite number(s)")
        return vals

    # ------------------------------------------------------------------ defaults
    def _read_default(self, d, parent, name):
        vals = {k: dict(parent[k]) for k in _DEFAULT_KINDS}
        vals["actuator"] = dict(parent["actuator"])
        for ch in d:
            if ch.tag in _DEFAULT_KINDS:
                vals[ch.tag].update(ch.attrib)
            elif ch.tag in ACTUATOR_TAGS:
                vals["actuator"] = self.actuator_params(ch, vals["actuator"])
        self.classes[name] = vals
        for ch in d:
            if ch.tag == "default":
                if ch.get("class") is None:
                    raise self.error(ch, "a nested default needs a class name")
                self._read_default(ch, vals, ch.get("class"))

    def class_of(self, elem, childclass=None) -> dict:
        cls = elem.get("class") or childclass or "main"
        if cls not in self.classes:
            raise self.error(elem, f"default class {cls!r} is not defined")
        return self.classes[cls]

    def attrs(self, elem, kind, childclass=None) -> dict:
        """The element's attributes over those of its default class (``kind``: geom, site, joint, tendon)."""
        return {**self.class_of(elem, childclass)[kind], **elem.attrib}

    def actuator_params(self, elem, base=None) -> dict:
        """The ``general`` parameters of an actuator element over ``base`` (its default class's)."""
        p = dict(self.class_of(elem)["actuator"] if base is None else base)
        a = elem.attrib
        for key in ("dynprm", "gainprm", "biasprm", "gear"):
            v = self.floats(elem, key)
            if v is not None:
                p[key] = v + list(p[key][len(v):])
        for key in ("ctrlrange", "forcerange", "actrange"):
            if key in a:
                p[key] = self.floats(elem, key, n=2)
        for key in ("dyntype", "gaintype", "biastype", "ctrllimited", "forcelimited", "actlimited"):
            if key in a:
                p[key] = a[key]
        tag = elem.tag
        one = lambda key, dflt: self.floats(elem, key, n=1, default=[dflt])[0]
        if tag == "general":
            return p
        p["kind"] = tag
        if tag == "motor":
            p.update(gaintype="fixed", biastype="none", dyntype="none", gainprm=[1.0] + [0.0] * 9, biasprm=[0.0] * 10)
        elif tag in ("position", "intvelocity"):
            inherited = p["biastype"] == "affine"
            kp = one("kp", p["gainprm"][0] if inherited else 1.0)
            kv = one("kv", -p["biasprm"][2] if inherited else 0.0)
            p.update(gaintype="fixed", biastype="affine", gainprm=[kp] + [0.0] * 9, biasprm=[0.0, -kp, -kv] + [0.0] * 7)
            p["dampratio"] = one("dampratio", 0.0)
            if tag == "position":
                tc = one("timeconst", p["dynprm"][0] if p["dyntype"] == "filterexact" else 0.0)
                p.update(dyntype="filterexact" if tc > 0 else "none", dynprm=[tc if tc > 0 else 1.0] + [0.0] * 9)
            else:
                p.update(dyntype="integrator", actlimited="true")
        elif tag == "velocity":
            kv = one("kv", 1.0)
            p.update(gaintype="fixed", biastype="affine", dyntype="none", gainprm=[kv] + [0.0] * 9,
                     biasprm=[0.0, 0.0, -kv] + [0.0] * 7)
        return p

    def limited(self, p, key) -> bool:
        """MuJoCo's rule for ``ctrllimited`` / ``forcelimited`` / ``actlimited``: "true", or
        "auto" with ``<compiler autolimits="true">`` (the default) and a range given."""
        flag = p[key.replace("range", "limited")]
        return flag == "true" or (flag == "auto" and self.autolimits and p[key] is not None)

    # ------------------------------------------------------------------ frames
    def frame(self, elem, attrs=None) -> tuple[np.ndarray, np.ndarray]:
        """``(pos, R)`` of an element's frame in its parent's (``pos`` m, ``R`` 3 x 3)."""
        a = elem.attrib if attrs is None else attrs
        pos = np.array(self.floats(elem, "pos", a, 3, [0.0, 0.0, 0.0]))
        given = [k for k in ("quat", "axisangle", "euler", "xyaxes", "zaxis") if k in a]
        if len(given) > 1:
            raise self.error(elem, f"more than one orientation given ({', '.join(given)})")
        q = np.array([1.0, 0.0, 0.0, 0.0])
        if given == ["quat"]:
            q = np.array(self.floats(elem, "quat", a, 4))
        elif given == ["axisangle"]:
            v = self.floats(elem, "axisangle", a, 4)
            q = _axis_angle(v[:3], v[3] * self.angle_unit)
        elif given == ["euler"]:
            v = self.floats(elem, "euler", a, 3)
            seq = self.eulerseq
            if len(seq) != 3 or any(c not in "xyzXYZ" for c in seq):
                raise self.error(elem, f"compiler eulerseq {seq!r} is not three of x, y, z, X, Y, Z")
            for c, ang in zip(seq, v):
                r = _axis_angle(np.eye(3)["xyz".index(c.lower())], ang * self.angle_unit)
                q = _quat_mul(q, r) if c.islower() else _quat_mul(r, q)
        elif given == ["xyaxes"]:
            v = np.array(self.floats(elem, "xyaxes", a, 6))
            x = v[:3] / np.linalg.norm(v[:3])
            y = v[3:] - (v[3:] @ x) * x
            y /= np.linalg.norm(y)
            return pos, np.column_stack([x, y, np.cross(x, y)])
        elif given == ["zaxis"]:
            q = quat_z_to(self.floats(elem, "zaxis", a, 3))
        if not np.linalg.norm(q) > 0:
            raise self.error(elem, "orientation has zero length")
        return pos, quat_matrix(q)

    # ------------------------------------------------------------------ geoms
    def geom(self, elem, attrs) -> dict:
        """A geom's ``type``, ``pos`` (m) and ``R`` in its body's frame, ``size``, ``half``
        (half-length of a capsule or cylinder, m), ``mass`` (kg) and ``inertia`` (3,) about its
        centre in its own frame (kg m^2), as MuJoCo computes them; ``mass`` None for a type whose
        volume is not computed here (mesh, heightfield)."""
        gtype = attrs.get("type", "sphere")
        size = self.floats(elem, "size", attrs, default=[0.0, 0.0, 0.0])
        size = size + [0.0] * (3 - len(size))
        if "fromto" in attrs and gtype in ("capsule", "cylinder", "box", "ellipsoid"):
            ft = np.array(self.floats(elem, "fromto", attrs, 6))
            d = ft[3:] - ft[:3]
            if not np.linalg.norm(d) > 0:
                raise self.error(elem, "fromto has zero length")
            pos, R = 0.5 * (ft[:3] + ft[3:]), quat_matrix(quat_z_to(d))
            size[1 if gtype in ("capsule", "cylinder") else 2] = 0.5 * float(np.linalg.norm(d))
        else:
            pos, R = self.frame(elem, attrs)
        r, h = size[0], size[1]
        vol = {"sphere": 4 / 3 * math.pi * r ** 3, "capsule": math.pi * r * r * 2 * h + 4 / 3 * math.pi * r ** 3,
               "cylinder": math.pi * r * r * 2 * h, "box": 8 * size[0] * size[1] * size[2],
               "ellipsoid": 4 / 3 * math.pi * size[0] * size[1] * size[2]}.get(gtype)
        g = {"type": gtype, "pos": pos, "R": R, "size": size, "half": h, "mass": None, "inertia": np.zeros(3)}
        if vol is None:
            return g
        if "mass" in attrs:
            m = self.floats(elem, "mass", attrs, 1)[0]
        else:
            m = self.floats(elem, "density", attrs, 1, [1000.0])[0] * vol
        if m < 0:
            raise self.error(elem, f"mass {m} kg is negative")
        a, b, c = size
        if gtype == "sphere":
            inertia = [0.4 * m * r * r] * 3
        elif gtype == "capsule":
            ms = m * (4 / 3 * math.pi * r ** 3) / vol if vol > 0 else 0.0
            mc, L = m - ms, 2 * h
            it = mc * (3 * r * r + L * L) / 12 + ms * (0.4 * r * r + L * L / 4 + 3 * L * r / 8)
            inertia = [it, it, mc * r * r / 2 + ms * 0.4 * r * r]
        elif gtype == "cylinder":
            it = m * (3 * r * r + 4 * h * h) / 12
            inertia = [it, it, m * r * r / 2]
        elif gtype == "box":
            inertia = [m / 3 * (b * b + c * c), m / 3 * (a * a + c * c), m / 3 * (a * a + b * b)]
        else:
            inertia = [m / 5 * (b * b + c * c), m / 5 * (a * a + c * c), m / 5 * (a * a + b * b)]
        g.update(mass=float(m), inertia=np.array(inertia, float))
        return g


def _parse(text: str, label: str):
    builder, places = ET.TreeBuilder(), {}
    parser = expat.ParserCreate()

    def start(tag, attrs):
        places[builder.start(tag, attrs)] = (label, parser.CurrentLineNumber)
    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    try:
        parser.Parse(text, True)
    except expat.ExpatError as e:
        raise StructureError(f"{label} line {e.lineno}: not well-formed XML ({expat.errors.messages[e.code]})") from None
    root = builder.close()
    if root.tag != "mujoco":
        raise StructureError(f"{label} line {places[root][1]}: the root element is <{root.tag}>, not <mujoco>: "
                             "not an MJCF model")
    return root, places


def _inline_includes(root, places, base_dir, read_file, depth):
    """Replace every ``<include file=...>`` by the children of the included file's ``<mujoco>``
    (paths relative to the main model's folder, as MuJoCo resolves them)."""
    for parent in list(root.iter()):
        for i, ch in reversed(list(enumerate(parent))):
            if ch.tag != "include":
                continue
            label, line = places[ch]
            what = f"{label} line {line}: <include file={ch.get('file')!r}>"
            if base_dir is None:
                raise StructureError(f"{what}: a model given as text cannot include files; give the model's path")
            if depth >= _MAX_INCLUDE_DEPTH or not ch.get("file"):
                raise StructureError(f"{what}: includes nested deeper than {_MAX_INCLUDE_DEPTH} files, or no file")
            path = Path(base_dir) / ch.get("file")
            try:
                sub_root, sub_places = _parse(read_file(path), str(path))
            except OSError as e:
                raise StructureError(f"{what}: cannot be read ({e.strerror or e})") from None
            _inline_includes(sub_root, sub_places, base_dir, read_file, depth + 1)
            places.update(sub_places)
            parent.remove(ch)
            for k, sub in enumerate(list(sub_root)):
                parent.insert(i + k, sub)


def read_document(text: str, label: str, base_dir: str | os.PathLike | None, read_file) -> Document:
    """Parse MJCF ``text`` (``label``: the file's name in messages; ``base_dir``: the folder that
    ``<include>`` paths are relative to, None for a model given as text; ``read_file(path)``:
    the text of an included file)."""
    root, places = _parse(text, label)
    _inline_includes(root, places, base_dir, read_file, 0)
    return Document(root, places, label)
