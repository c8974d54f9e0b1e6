"""One MJCF spatial tendon and the actuators on it as one class-1 string (the importer's strings).

SI units: stiffness N/m, damping N s/m, lengths m, forces N, time constants s.

A tendon's own spring (``stiffness`` k_p, ``springlength`` rest length l_p) and a tendon
actuator with an affine bias act in parallel. MuJoCo's actuator force on a tendon of length L is
``F = gain u + b0 + b1 (gear L) + b2 (gear L')`` (``u`` the control, or the activation of
filter and integrator dynamics), applied as ``gear F`` along the tendon. With ``b1 < 0`` it is a
spring of stiffness ``k_a = -b1 gear^2``, damping ``-b2 gear^2`` and rest length
``l_a(u) = (b0 + gain u) / (-b1 gear)`` that the control moves. Both springs taut, the string has
``k = k_p + k_a`` and rest length ``(k_p l_p + k_a l_a(u)) / k``.
"""
from __future__ import annotations

from .mjcf_report import ActuatedString

__all__ = ["string_of_tendon", "finish_string", "merge_parallel"]

_DYNAMICS = ("none", "filter", "filterexact", "integrator")


def _spring_actuator(doc, a, p, tname, rep):
    """The actuator ``a`` (general parameters ``p``) as a spring, or None (dropped, reported)."""
    label = a.get("name") or f"actuator at {doc.where(a)}"
    gear = p["gear"][0]
    if p["kind"] not in ("general", "motor", "position", "velocity", "intvelocity") or p["gaintype"] != "fixed" \
            or p["biastype"] not in ("none", "affine") or p["dyntype"] not in _DYNAMICS:
        rep.add("dropped", f"actuators {{names}} ({p['kind']}: gain {p['gaintype']}, bias {p['biastype']}, dynamics "
                           f"{p['dyntype']}): not a rest-length control", label)
        return None
    b0, b1, b2 = p["biasprm"][:3]
    if p["biastype"] != "affine" or not b1 < 0 or not gear > 0:
        rep.add("dropped", "actuators {names}: force actuators (the control sets a tension, with no length "
                           "feedback); the actuation here sets rest lengths or force densities", label)
        return None
    if b2 > 0:
        raise doc.error(a, f"biasprm[2] = {b2} gives negative damping")
    gain = p["gainprm"][0]
    ctrl = tuple(p["ctrlrange"]) if doc.limited(p, "ctrlrange") else None
    dyn = p["dyntype"]
    if dyn == "integrator":
        u0, urange = 0.0, tuple(p["actrange"]) if doc.limited(p, "actrange") else None
    elif dyn == "none":
        u0, urange = (min(max(0.0, ctrl[0]), ctrl[1]) if ctrl else 0.0), ctrl
    else:
        u0, urange = 0.0, ctrl
    la = lambda u: (b0 + gain * u) / (-b1 * gear)
    per = gain / (-b1 * gear)
    fr = p["forcerange"] if doc.limited(p, "forcerange") else None
    if fr is None or fr[1] > 0:
        rep.add("notes", "actuators {names}: their force range lets them push in MuJoCo; imported tension-only", label)
    if p["dampratio"]:
        rep.add("notes", "actuators {names}: dampratio is not mapped (damping from kv only)", label)
    return {"k": -b1 * gear * gear, "c": -b2 * gear * gear, "l0": la(u0), "per": per,
            "range": None if urange is None else tuple(sorted((la(urange[0]), la(urange[1])))),
            "tau": p["dynprm"][0] if dyn in ("filter", "filterexact") else None,
            "rate": tuple(sorted((per * ctrl[0], per * ctrl[1]))) if dyn == "integrator" and ctrl else None,
            "max_tension": -fr[0] * gear if fr is not None and fr[0] < 0 else None,
            "name": a.get("name") or f"actuator at {doc.where(a)}", "ctrl": ctrl}


def string_of_tendon(doc, t, actuators, rep):
    """The string of spatial tendon ``t`` with the actuators on it: a dict with ``k`` (N/m),
    ``c`` (N s/m) and the parts :func:`finish_string` completes, or None where the tendon has no
    spring (dropped, reported)."""
    a = doc.attrs(t, "tendon")
    tname = t.get("name") or f"tendon at {doc.where(t)}"
    kp = doc.floats(t, "stiffness", a, 1, [0.0])[0]
    cp = doc.floats(t, "damping", a, 1, [0.0])[0]
    if kp < 0 or cp < 0:
        raise doc.error(t, f"stiffness {kp} N/m and damping {cp} N s/m must be >= 0")
    band = doc.floats(t, "springlength", a, default=[-1.0, -1.0])
    band = (band * 2)[:2] if len(band) == 1 else band
    if len(band) != 2 or (band[0] != -1 and band[0] > band[1]):
        raise doc.error(t, f"springlength {a.get('springlength')!r}: expected l0 or a dead band 'low high' with low <= high")
    lp = None if band[0] == -1 and band[1] == -1 else band[1]
    if kp > 0 and lp is not None and band[0] > 0:
        rep.add("notes", "tendons {names}: springlength 'low high' with low > 0 (a single value: low = high): "
                         "MuJoCo's spring also pushes below low; imported as tension-only strings of rest length high",
                tname)
    for key, what in (("frictionloss", "dry friction"), ("armature", "inertia")):
        if doc.floats(t, key, a, 1, [0.0])[0] > 0:
            rep.add("dropped", f"tendons {{names}}: {key} ({what}) is not modelled", tname)
    rng = doc.floats(t, "range", a, 2)
    if a.get("limited") == "true" or (a.get("limited", "auto") == "auto" and doc.autolimits and rng is not None):
        rep.add("dropped", "tendons {names}: length limits (a constraint) are not modelled", tname)
    spring = None
    for act in actuators:
        s = _spring_actuator(doc, act, doc.actuator_params(act), tname, rep)
        if s is not None and spring is not None:
            rep.add("dropped", "actuators {names}: a second spring actuator on one tendon", s["name"])
        elif s is not None:
            spring = s
    if kp == 0 and spring is None:
        rep.add("dropped", "tendons {names}: no spring (stiffness 0 and no spring actuator)", tname)
        return None
    if kp > 0 and spring is not None:
        rep.add("notes", "tendons {names}: their own spring and their actuator's act in parallel (exact while both "
                         "are taut)", tname)
    return {"kp": kp, "lp": lp, "k": kp + (spring["k"] if spring else 0.0),
            "push_below": band[0] if kp > 0 and lp is not None and band[0] > 0 else None,
            "c": cp + (spring["c"] if spring else 0.0), "spring": spring, "tendon": tname}


def finish_string(row, length: float, rep):
    """``(rest length m, ActuatedString or None)`` of a string of initial ``length`` (m; the rest
    length of a tendon whose ``springlength`` is not given); the string index is set later."""
    lp = length if row["lp"] is None else row["lp"]
    if row["push_below"] is not None and length < row["push_below"]:
        rep.add("notes", "tendons {names}: start shorter than their springlength: MuJoCo's spring pushes their ends "
                         "apart, here they start slack", row["tendon"])
    sp = row["spring"]
    if sp is None:
        return lp, None
    if sp["max_tension"] is not None and sp["k"] * (length - sp["l0"]) > sp["max_tension"]:
        rep.add("notes", "tendons {names}: start pulled beyond their actuator's force limit (MuJoCo caps that "
                         "tension; the cap is not modelled here)", row["tendon"])
    k = row["k"]
    mix = lambda la: (row["kp"] * lp + sp["k"] * la) / k
    w = sp["k"] / k
    act = ActuatedString(actuator=sp["name"], tendon=row["tendon"], string=-1, per_ctrl=w * sp["per"],
                         rest_length_range=None if sp["range"] is None else (mix(sp["range"][0]), mix(sp["range"][1])),
                         time_constant=sp["tau"],
                         rate_range=None if sp["rate"] is None else (w * sp["rate"][0], w * sp["rate"][1]),
                         max_tension=sp["max_tension"], ctrl_range=sp["ctrl"])
    return mix(sp["l0"]), act


def merge_parallel(parts, rep) -> dict:
    """One string from the tendons ``parts`` that join the same two nodes (dicts with ``name``,
    ``k``, ``c``, ``l0``, ``act``): springs in parallel, exact while all are taut. Stiffness and
    damping add, the rest length is the stiffness-weighted mean, and the first actuator keeps
    control of it (its rest-length range and rate scaled by its share of the stiffness)."""
    if len(parts) == 1:
        return parts[0]
    k, c = sum(p["k"] for p in parts), sum(p["c"] for p in parts)
    kl = sum(p["k"] * p["l0"] for p in parts)
    acts = [p for p in parts if p["act"] is not None]
    act = None
    if acts:
        p0, act = acts[0], acts[0]["act"]
        w, others = p0["k"] / k, kl - p0["k"] * p0["l0"]
        act.per_ctrl *= w
        if act.rest_length_range is not None:
            act.rest_length_range = tuple((others + p0["k"] * x) / k for x in act.rest_length_range)
        if act.rate_range is not None:
            act.rate_range = tuple(w * x for x in act.rate_range)
        for p in acts[1:]:
            rep.add("dropped", "actuators {names}: a second actuator on one string (tendons that join the same "
                               "two nodes)", p["act"].actuator)
    for p in parts:
        rep.add("notes", "tendons {names}: join the same two nodes as another tendon; merged as springs in parallel "
                         "(exact while all are taut)", p["name"])
    return {"name": "+".join(p["name"] for p in parts), "a": parts[0]["a"], "c": parts[0]["c"], "k": k, "c_": c,
            "l0": kl / k, "act": act}
