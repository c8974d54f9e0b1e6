"""``--video PATH`` of ``simulate`` and ``demo``: the recorded run rendered into the command's
outputs (published with them, or none)."""
from __future__ import annotations

from ..io.claim import Transaction
from ..physics.evaluate import force_densities
from ..physics.geometry import node_positions
from .cli_common import EXIT_OUTPUT, CLIError
from .rendering import RendererUnavailable, render_video

__all__ = ["stage_video", "print_video"]


def stage_video(tx: Transaction, args, s, model, t, q, qd, terrain=None) -> int:
    """``--video PATH``: render the recorded trajectory (q, qd: (S, 1, k, 6)) in real time at
    30 frames/s into the transaction (published with the other outputs), on ``terrain`` if one is
    given; returns the frame count."""
    if not getattr(args, "video", None):
        return 0
    q, qd = q.reshape((len(t),) + q.shape[-2:]), qd.reshape((len(t),) + qd.shape[-2:])
    gamma, _, L = force_densities(model, q, qd)
    frames = []
    try:
        tx.stage_file(args.video, lambda tmp: frames.append(
            render_video(tmp, s, node_positions(model, q), gamma * L, t,
                         **({} if terrain is None else {"terrain": terrain}))))
    except (RendererUnavailable, ValueError, OSError) as e:
        raise CLIError(EXIT_OUTPUT, f"--video {args.video}: {e}; no output file was changed") from None
    return frames[0]


def print_video(args, frames: int) -> None:
    if getattr(args, "video", None):
        print(f"wrote {frames} frames -> {args.video}")
