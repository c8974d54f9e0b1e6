"""Metrics of evaluation episodes (:mod:`agents.evaluate`): the scene's scales (structure height,
body length, m), the summary of a policy's episodes (returns, success and failure rates, final
errors in m and as a fraction of the height) and the table of several policies.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np


def scene_scales(env_id: str, env_kwargs: dict) -> dict:
    """Structure height (m) and body length (m) of the env's scene, where it has them."""
    env = gym.make(env_id, **env_kwargs)
    try:
        task = getattr(env.unwrapped, "task", None)
        out = {}
        if task is None:
            return out
        for name in ("height", "body_length", "success_tolerance"):
            if hasattr(task, name):
                out[name] = float(getattr(task, name))
        if "body_length" not in out and hasattr(task, "structure"):
            # body length: the largest distance between two nodes of the structure at rest, m
            nodes = task.structure.nodes
            out["body_length"] = float(np.max(np.linalg.norm(nodes[:, None] - nodes[None], axis=-1)))
            out["body_length_definition"] = "largest node-to-node distance of the structure at rest"
        return out
    finally:
        env.close()


def summarize(episodes: list[dict], scales: dict) -> dict:
    R = np.array([e["return"] for e in episodes])
    L = np.array([e["length"] for e in episodes])
    m = {"n_episodes": len(episodes), "return_mean": float(R.mean()), "return_std": float(R.std()),
         "length_mean": float(L.mean())}
    fin = [e["final"] for e in episodes]
    if all("is_success" in f for f in fin):
        m["success_rate"] = float(np.mean([f["is_success"] for f in fin]))
    if all("diverged" in f for f in fin):
        m["diverged_rate"] = float(np.mean([f["diverged"] for f in fin]))
    if all("tracking_error" in f for f in fin):
        te = np.array([f["tracking_error"] for f in fin])
        m["final_tracking_error_mean_m"] = float(te.mean())
        m["final_tracking_error_median_m"] = float(np.median(te))
    if all("max_node_error" in f for f in fin):
        me = np.array([f["max_node_error"] for f in fin])
        m["final_max_node_error_mean_m"] = float(me.mean())
        m["final_max_node_error_median_m"] = float(np.median(me))
        m["final_max_node_error_p90_m"] = float(np.percentile(me, 90))
        if "height" in scales:
            m["final_max_node_error_median_frac_height"] = float(np.median(me) / scales["height"])
    dist_key = next((k for k in ("distance_rolled", "distance") if all(k in f for f in fin)), None)
    if dist_key:
        d = np.array([f[dist_key] for f in fin])
        dur = L * np.array([e["dt"] for e in episodes])
        v = d / dur
        m["distance_mean_m"] = float(d.mean())
        m["speed_mean_m_s"] = float(v.mean())
        m["speed_std_m_s"] = float(v.std())
        m["speed_min_m_s"] = float(v.min())
        if "body_length" in scales:
            m["speed_mean_body_lengths_s"] = float(v.mean() / scales["body_length"])
    return m


def format_table(results: dict) -> str:
    cols = [("return", lambda m: f"{m['return_mean']:.2f} +- {m['return_std']:.2f}"),
            ("success", lambda m: f"{100 * m['success_rate']:.0f}%" if "success_rate" in m else "-"),
            ("final err mean (m)", lambda m: f"{m['final_tracking_error_mean_m']:.2e}"
             if "final_tracking_error_mean_m" in m else None),
            ("max err median (m)", lambda m: f"{m['final_max_node_error_median_m']:.2e}"
             if "final_max_node_error_median_m" in m else None),
            ("median / height", lambda m: f"{100 * m['final_max_node_error_median_frac_height']:.2f}%"
             if "final_max_node_error_median_frac_height" in m else None),
            ("speed (m/s)", lambda m: f"{m['speed_mean_m_s']:.3f} +- {m['speed_std_m_s']:.3f}"
             if "speed_mean_m_s" in m else None),
            ("body len/s", lambda m: f"{m['speed_mean_body_lengths_s']:.2f}"
             if "speed_mean_body_lengths_s" in m else None),
            ("ep. length", lambda m: f"{m['length_mean']:.0f}")]
    used = [(name, fn) for name, fn in cols if any(fn(m) is not None for m in results.values())]
    rows = [["policy"] + [n for n, _ in used]]
    for pol, m in results.items():
        rows.append([pol] + [fn(m) or "-" for _, fn in used])
    w = [max(len(r[j]) for r in rows) for j in range(len(rows[0]))]
    lines = [" | ".join(c.ljust(w[j]) for j, c in enumerate(r)) for r in rows]
    lines.insert(1, "-+-".join("-" * x for x in w))
    return "\n".join(lines)
