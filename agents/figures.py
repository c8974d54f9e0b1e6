"""Figures of an evaluation (:mod:`agents.evaluate`): the learning curve of a run from its monitor
files and evaluations, the final errors of each policy's episodes, and a GIF of one episode.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import envs


def load_monitor(files) -> dict:
    """Episodes of SB3 monitor csv files (several resume segments), ordered in time:
    dict column -> float array (``r`` return, ``l`` length, ``t`` s, info keywords)."""
    import csv
    rows = []
    for f in files:
        with open(f) as fh:
            header = json.loads(fh.readline().lstrip("#"))
            for row in csv.DictReader(fh):
                row = {k: (float(v) if v not in ("", "True", "False") else float(v == "True"))
                       for k, v in row.items()}
                row["t"] += float(header.get("t_start", 0.0))
                rows.append(row)
    rows.sort(key=lambda r: r["t"])
    keys = set.intersection(*(set(r) for r in rows)) if rows else {"r", "l", "t"}
    return {k: np.array([r[k] for r in rows]) for k in keys}


def plot_learning_curve(run_dir: Path, out: Path, title: str, tol: float | None = None) -> bool:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ev = run_dir / "eval" / "evaluations.npz"
    mon = sorted((run_dir / "monitor").glob("*.monitor.csv")) if (run_dir / "monitor").exists() else []
    if not ev.exists() and not mon:
        return False
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    ax = axes[0]
    df = load_monitor(mon) if mon else None
    if df is not None and len(df["r"]):
        steps = np.cumsum(df["l"])
        r = df["r"]
        k = max(1, len(r) // 25)
        smooth = np.convolve(r, np.ones(k) / k, mode="valid")
        ax.plot(steps, r, ".", ms=2, alpha=0.25, color="C0", label="training episodes")
        ax.plot(steps[k - 1:], smooth, color="C0", label=f"training (mean of {k})")
    else:
        df = None
    if ev.exists():
        d = np.load(ev)
        res = d["results"]
        ax.errorbar(d["timesteps"], res.mean(1), yerr=res.std(1), color="C1", marker="o", ms=3, capsize=2,
                    label="evaluation (deterministic)")
    ax.set_xlabel("env steps")
    ax.set_ylabel("episode return")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax = axes[1]
    shown = False
    if ev.exists():
        d = np.load(ev)
        if "successes" in d.files and np.size(d["successes"]):
            ax.plot(d["timesteps"], 100 * d["successes"].mean(1), "o-", color="C2", ms=3,
                    label="evaluation success rate")
            shown = True
    if df is not None and "is_success" in df:
        s = df["is_success"]
        k = max(1, len(s) // 25)
        ax.plot(steps[k - 1:], 100 * np.convolve(s, np.ones(k) / k, mode="valid"), color="C0",
                label="training success rate")
        shown = True
    if df is not None and "max_node_error" in df:
        e = df["max_node_error"]
        k = max(1, len(e) // 25)
        ax2 = ax.twinx()
        ax2.plot(steps[k - 1:], np.convolve(e, np.ones(k) / k, mode="valid"), color="C3",
                 label="training final max node error (m)")
        ax2.set_yscale("log")
        ax2.set_ylabel("final max node error (m)", color="C3")
        if tol is not None:
            ax2.axhline(tol, color="C3", ls="--", lw=1, label="success tolerance")
        ax2.legend(fontsize=8, loc="lower left")
        shown = True
    if df is not None and "distance_rolled" in df:
        ax.plot(steps, df["distance_rolled"], ".", ms=2, color="C3", label="training distance rolled (m)")
        ax.set_ylabel("distance rolled per episode (m)")
        shown = True
    else:
        ax.set_ylabel("success rate (%)")
    if not shown:
        ax.axis("off")
    ax.set_xlabel("env steps")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    for a in axes:
        a.ticklabel_format(axis="x", style="sci", scilimits=(0, 3))
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return True


def plot_episodes(all_eps: dict, scales: dict, out: Path, title: str) -> bool:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    any_eps = next(iter(all_eps.values()))
    if any_eps and any_eps[0]["trace"].get("max_node_error"):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for j, (pol, eps) in enumerate(all_eps.items()):
            E = np.array([e["trace"]["max_node_error"] for e in eps if len(e["trace"]["max_node_error"]) ==
                          len(eps[0]["trace"]["max_node_error"])])
            t = np.arange(1, E.shape[1] + 1) * eps[0]["dt"]
            axes[0].plot(t, np.median(E, 0), color=f"C{j}", label=f"{pol} (median)")
            axes[0].fill_between(t, np.percentile(E, 10, 0), np.percentile(E, 90, 0), color=f"C{j}", alpha=0.2)
            fin = np.sort([e["final"]["max_node_error"] for e in eps])
            axes[1].plot(np.arange(1, fin.size + 1) / fin.size * 100, fin, color=f"C{j}", label=pol)
        for ax in axes:
            ax.set_yscale("log")
            if "success_tolerance" in scales:
                ax.axhline(scales["success_tolerance"], color="k", ls="--", lw=1, label="success tolerance")
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=8)
        axes[0].set_xlabel("time (s)")
        axes[0].set_ylabel("max node error (m); band: 10-90%")
        axes[0].set_title(title)
        axes[1].set_xlabel("episodes (%), sorted")
        axes[1].set_ylabel("final max node error (m)")
        fig.tight_layout()
        fig.savefig(out, dpi=110)
        plt.close(fig)
        return True
    if any_eps and any_eps[0]["trace"].get("com"):
        fig, ax = plt.subplots(figsize=(6, 5))
        for j, (pol, eps) in enumerate(all_eps.items()):
            for i, e in enumerate(eps[:10]):
                c = np.array(e["trace"]["com"])
                if c.size:
                    ax.plot(c[:, 0], c[:, 1], color=f"C{j}", lw=1, alpha=0.8, label=pol if i == 0 else None)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{title}: centre-of-mass paths (10 episodes each)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out, dpi=110)
        plt.close(fig)
        return True
    return False


def write_gif(env_id: str, env_kwargs: dict, policy, seed: int, out: Path, max_frames: int = 50,
              fps: int | None = None, size: int = 256) -> int:
    """GIF of one episode (every k-th control step so that at most ``max_frames`` frames)."""
    import gymnasium as gym
    import imageio.v2 as imageio
    env = gym.make(env_id, render_mode="rgb_array", width=size, height=size, **env_kwargs) \
        if envs.has_vector_entry_point(env_id) else gym.make(env_id, render_mode="rgb_array", **env_kwargs)
    T = env.spec.max_episode_steps or 1000
    every = max(1, int(np.ceil(T / max_frames)))
    obs, _ = env.reset(seed=seed)
    frames = [env.render()]
    done, t = False, 0
    pstate, start = None, np.ones(1, bool)
    while not done:
        a, pstate = policy.predict(obs, state=pstate, episode_start=start, deterministic=True)
        start = np.zeros(1, bool)
        obs, _, term, trunc, _ = env.step(a)
        t += 1
        done = term or trunc
        if t % every == 0 or done:
            frames.append(env.render())
    env_fps = env.metadata.get("render_fps", 30)
    env.close()
    imageio.mimsave(out, frames, duration=1000.0 * every / env_fps / (1.0 if fps is None else fps / env_fps),
                    loop=0)
    return len(frames)
