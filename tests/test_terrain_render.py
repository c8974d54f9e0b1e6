"""Terrain in the renderers and viewers: a sloped plane, a box and a heightfield are drawn (matplotlib,
MuJoCo, video, browser and window viewers, an env-style render-data dict with a ``terrain`` key)."""
import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.terrain import Terrain
from tensegrity_gym.tools.rendering import MujocoRenderer, Renderer, RendererUnavailable

S = tg.prism(3)
x = np.linspace(0.0, 3.0, 12)
TERRAIN = Terrain.from_dict({
    "plane": {"slope_deg": 15.0, "uphill_deg": 30.0},
    "boxes": [{"center": [0.5, 0.0, 0.1], "size": [0.3, 0.6, 0.2], "yaw_deg": 20.0}],
    "heightfield": {"heights": (0.2 * np.sin(x)[:, None] * np.cos(x[:10])[None, :]).tolist(), "cell": 0.2,
                    "origin": [-1.0, -1.0]}})


def _frames(r):
    data = {"nodes": S.nodes, "rods": S.bars, "strings": S.strings, "ground_z": 0.0}
    flat = r.render(**data)
    on = r.render(**dict(data, terrain=TERRAIN))         # an env's render_data with a "terrain" key
    again = r.render(**dict(data, terrain=TERRAIN))
    return flat, on, again


def _check(flat, on, again, shape):
    assert flat.shape == on.shape == shape and on.dtype == np.uint8
    assert np.abs(flat.astype(int) - on).mean() > 2.0          # the terrain is drawn
    assert np.array_equal(on, again)                           # and drawn the same way each frame


def test_matplotlib_draws_the_terrain():
    r = Renderer(160, 120)
    _check(*_frames(r), (120, 160, 3))
    # only a heightfield, only boxes: each is drawn on its own
    blank = r.render(S.nodes, S.bars, S.strings)
    for t in (Terrain(plane=None, heightfield=TERRAIN.heightfield), Terrain(plane=None, boxes=TERRAIN.boxes)):
        assert np.abs(r.render(S.nodes, S.bars, S.strings, terrain=t).astype(int) - blank).mean() > 0.5
    with pytest.raises(ValueError, match="terrain"):
        r.render(S.nodes, S.bars, S.strings, terrain={"plane": None})


def test_mujoco_draws_the_terrain():
    pytest.importorskip("mujoco")
    try:
        r = MujocoRenderer(160, 120)
    except RendererUnavailable as exc:
        pytest.skip(f"no OpenGL backend: {exc}")
    try:
        flat, on, again = _frames(r)
        _check(flat, on, again, (120, 160, 3))
        assert r.model.nhfield == 1 and r.model.ngeom == 1 + 3   # ground (hidden) + plane, box, heightfield
        # back to the level ground: the scene drops the terrain
        assert np.array_equal(r.render(S.nodes, S.bars, S.strings, ground_z=0.0), flat)
    finally:
        r.close()


def test_video_and_viewers_take_the_terrain(tmp_path, monkeypatch):
    imageio = pytest.importorskip("imageio")
    from tensegrity_gym.tools.rendering import render_video
    nodes = np.stack([S.nodes + [0, 0, 0.01 * i] for i in range(4)])
    seen = []
    orig = Renderer.render

    def spy(self, *a, **kw):
        seen.append(kw.get("terrain"))
        return orig(self, *a, **kw)

    monkeypatch.setattr(Renderer, "render", spy)
    assert render_video(tmp_path / "v.gif", S, nodes, width=64, height=64, backend="matplotlib",
                        terrain=TERRAIN) == 4
    assert len(seen) == 4 and all(t is TERRAIN for t in seen)
    assert imageio.v2.mimread(tmp_path / "v.gif")[0].shape[:2] == (64, 64)


def test_window_viewer_draws_the_terrain():
    import matplotlib
    matplotlib.use("Agg")
    from tensegrity_gym.tools.rendering import WindowViewer
    nodes = np.stack([S.nodes] * 3)
    flat = WindowViewer(S, nodes, width=96, height=96, ground_z=0.0).img.get_array()
    v = WindowViewer(S, nodes, width=96, height=96, terrain=TERRAIN)
    assert v.terrain is TERRAIN and not np.array_equal(np.asarray(flat), np.asarray(v.img.get_array()))


def test_browser_viewer_adds_the_terrain():
    pytest.importorskip("viser")
    from tensegrity_gym.tools.rendering import BrowserViewer
    v = BrowserViewer(S, np.stack([S.nodes] * 2), port=0, terrain=TERRAIN)
    try:
        names = set(v.server.scene._handle_from_node_name)
        assert {"/terrain/plane", "/terrain/box0", "/terrain/heightfield"} <= names and "/ground" not in names
    finally:
        v.close()


def test_cli_view_and_simulate_video_pass_the_terrain(tmp_path, monkeypatch, capsys):
    from tensegrity_gym.tools import cli
    from tensegrity_gym.tools import cli_commands
    seen = {}
    monkeypatch.setattr(cli_commands, "view_trajectory", lambda *a, **kw: seen.update(kw))
    out = tmp_path / "t.npz"
    assert cli.main(["simulate", "prism3", "--duration", "0.01", "--out", str(out)]) == 0
    tf = tmp_path / "ter.json"
    tf.write_text('{"plane": {"slope_deg": 5}, "boxes": [{"center": [1, 0, 0], "size": [1, 1, 1]}]}')
    assert cli.main(["view", str(out), "--terrain", str(tf), "--mode", "browser", "--port", "0"]) == 0
    assert isinstance(seen["terrain"], Terrain) and len(seen["terrain"].boxes) == 1
    tf.write_text('{"plane": {"slope_deg": "steep"}}')
    assert cli.main(["view", str(out), "--terrain", str(tf)]) == 3
    err = capsys.readouterr().err
    assert "plane.slope_deg: expected a real number, got 'steep'" in err and "Traceback" not in err
