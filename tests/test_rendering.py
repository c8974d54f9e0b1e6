"""Renderers: the MuJoCo (OpenGL) renderer draws what it is given; fallback to matplotlib.

Tests of the MuJoCo renderer skip when mujoco or an OpenGL backend (EGL/OSMesa) is missing.
"""
import warnings

import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.tools import rendering
from tensegrity_gym.tools.rendering import mujoco_renderer
from tensegrity_gym.tools.rendering import MujocoRenderer, Renderer, RendererUnavailable, make_renderer


def _mujoco_renderer(*a, **kw):
    pytest.importorskip("mujoco")
    try:
        return MujocoRenderer(*a, **kw)
    except RendererUnavailable as exc:
        pytest.skip(f"no OpenGL backend: {exc}")


S = tg.prism(3)


def _red_fraction(img):
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return float(np.mean((r > 150) & (g < 90) & (b < 90)))


def test_frame_shape_and_content():
    r = _mujoco_renderer(480, 480, title="prism3")
    f = r.render(S.nodes, S.bars, S.strings, np.full(9, 50.0), ground_z=0.0, caption="t = 0 s")
    assert f.shape == (480, 480, 3) and f.dtype == np.uint8 and f.std() > 10
    # non-square sizes
    r2 = _mujoco_renderer(160, 120)
    assert r2.render(S.nodes, S.bars, S.strings).shape == (120, 160, 3)
    r.close()
    r2.close()


def test_strings_coloured_by_tension():
    r = _mujoco_renderer(240, 240)
    hot = r.render(S.nodes, S.bars, S.strings, np.full(9, 100.0), tension_max=100.0)
    cold = r.render(S.nodes, S.bars, S.strings, np.full(9, 1.0), tension_max=100.0)
    slack = r.render(S.nodes, S.bars, S.strings, np.zeros(9))
    legend = (slice(None), slice(200, None))     # the colour bar has red at its top in all frames
    body = (slice(None), slice(0, 190))
    assert _red_fraction(hot[body]) > 0.005 > _red_fraction(cold[body])
    assert _red_fraction(slack[body]) < 0.001
    assert _red_fraction(hot[legend]) > 0.002
    r.close()


def test_ground_title_and_nonfinite_nodes():
    r = _mujoco_renderer(240, 240, title="TITLE")
    a = r.render(S.nodes, S.bars, S.strings, np.full(9, 50.0), ground_z=0.0)
    b = r.render(S.nodes, S.bars, S.strings, np.full(9, 50.0))
    assert np.abs(a.astype(int) - b).mean() > 5          # the ground changes the picture
    r.title = None
    c = r.render(S.nodes, S.bars, S.strings, np.full(9, 50.0))
    assert np.any(b[:30, :100] != c[:30, :100])           # the title is drawn top left
    bad = S.nodes.copy()
    bad[0] = np.nan
    assert r.render(bad, S.bars, S.strings).shape == (240, 240, 3)
    with pytest.raises(ValueError, match="nodes"):
        r.render(np.zeros((3, 2)), S.bars, S.strings)
    r.close()


def test_extras_targets_path_goal():
    r = _mujoco_renderer(200, 200)
    f = r.render(S.nodes, S.bars, S.strings, targets=S.nodes + 0.1, path=np.linspace([0, 0, 0], [1, 0, 0], 50),
                 goal=[1, 0, 0], ground_z=0.0)
    assert f.shape == (200, 200, 3)
    r.close()


def test_make_renderer_backends(monkeypatch):
    assert isinstance(make_renderer(64, 64, backend="matplotlib"), Renderer)
    with pytest.raises(ValueError, match="backend"):
        make_renderer(64, 64, backend="vulkan")
    # no OpenGL: "auto" falls back to matplotlib with one warning, "mujoco" raises
    monkeypatch.setattr(mujoco_renderer, "_GL_CACHE", {"error": "MuJoCo renderer: no OpenGL backend works here"})
    with pytest.warns(UserWarning, match="matplotlib"):
        r = make_renderer(64, 64, backend="auto")
    assert isinstance(r, Renderer)
    with pytest.raises(RendererUnavailable, match="OpenGL"):
        make_renderer(64, 64, backend="mujoco")
    monkeypatch.setenv("TENSEGRITY_RENDERER", "matplotlib")
    assert isinstance(make_renderer(64, 64), Renderer)


def test_unknown_gl_backend_message(monkeypatch):
    pytest.importorskip("mujoco")
    monkeypatch.setattr(mujoco_renderer, "_GL_CACHE", {})
    monkeypatch.setenv("MUJOCO_GL", "vulkan")
    with pytest.raises(RendererUnavailable, match="MUJOCO_GL='vulkan'"):
        rendering.gl_backend()


def test_env_uses_the_3d_renderer():
    gym = pytest.importorskip("gymnasium")
    _mujoco_renderer(32, 32).close()
    env = gym.make("TensegrityRoll-v0", render_mode="rgb_array", width=200, height=200)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    f = env.render()
    assert f.shape == (200, 200, 3) and isinstance(env.unwrapped._renderer, MujocoRenderer)
    env.close()


def test_write_video_and_cli(tmp_path):
    pytest.importorskip("imageio")
    r = _mujoco_renderer(32, 32)
    r.close()
    from tensegrity_gym.tools.rendering import write_video
    nodes = np.stack([S.nodes + 0.01 * i for i in range(6)])
    n = write_video(tmp_path / "v.gif", S, nodes, np.full((6, 9), 50.0), np.arange(6) * 0.1, fps=10,
                    width=96, height=96)
    assert n == 6 and (tmp_path / "v.gif").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.gif"]
    with pytest.raises(ValueError, match="mp4"):
        write_video(tmp_path / "v.txt", S, nodes)
    from tensegrity_gym.tools.cli import main
    assert main(["simulate", "prism3", "--duration", "0.1", "--out", str(tmp_path / "t.npz"),
                 "--video", str(tmp_path / "v.mp4")]) == 0
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    nframes, _ = imageio_ffmpeg.count_frames_and_secs(str(tmp_path / "v.mp4"))
    meta = next(imageio_ffmpeg.read_frames(str(tmp_path / "v.mp4")))
    assert nframes == 4 and tuple(meta["size"]) == (480, 480)


def test_browser_viewer_slider_and_play():
    pytest.importorskip("viser")
    import time
    import urllib.request
    from tensegrity_gym.tools.rendering import BrowserViewer
    nodes = np.stack([S.nodes + 0.01 * i for i in range(20)])
    T = np.linspace(0, 50, 20)[:, None] * np.ones(9)
    v = BrowserViewer(S, nodes, T, np.arange(20) * 0.05, port=0)
    try:
        assert urllib.request.urlopen(v.url, timeout=10).read().lstrip().lower().startswith(b"<!doctype html")
        v.set_time(0.25)
        assert v.index == 5 and np.abs(v._points.points - nodes[5]).max() < 1e-3
        assert np.abs(v._strings.points - nodes[5][S.strings]).max() < 1e-3
        v.play()
        time.sleep(0.4)
        v.pause()
        assert v.index > 5
    finally:
        v.close()
    with pytest.raises(ValueError, match="nodes"):
        BrowserViewer(S, np.zeros((3, 2)), port=0)


def test_window_viewer_widgets_headless():
    import matplotlib
    matplotlib.use("Agg")
    from tensegrity_gym.tools.rendering import WindowViewer
    nodes = np.stack([S.nodes + 0.01 * i for i in range(5)])
    v = WindowViewer(S, nodes, np.full((5, 9), 20.0), np.arange(5) * 0.1, width=96, height=96)
    first = v.img.get_array().copy()
    v.slider.set_val(0.3)
    assert v.index == 3 and not np.array_equal(first, v.img.get_array())
    v._toggle(None)
    assert v.playing and v.button.label.get_text() == "pause"
    v._tick()
    assert v.index == 3 or v.index == 4


def test_cli_view(tmp_path, monkeypatch, capsys):
    from tensegrity_gym.tools import cli
    from tensegrity_gym.tools import cli_commands
    seen = {}

    def fake_view(structure, nodes, tensions, times, mode, **kw):
        seen.update(structure=structure, nodes=nodes, tensions=tensions, times=times, mode=mode, kw=kw)

    monkeypatch.setattr(cli_commands, "view_trajectory", fake_view)
    out = tmp_path / "t.npz"
    assert cli.main(["simulate", "prism3", "--duration", "0.01", "--out", str(out)]) == 0
    assert cli.main(["view", str(out), "--structure", "prism3", "--mode", "browser", "--port", "0"]) == 0
    assert seen["nodes"].shape == (11, 6, 3) and seen["tensions"].shape == (11, 9) and seen["mode"] == "browser"
    np.testing.assert_allclose(seen["tensions"][0], tg.prism(3).initial_tensions())
    assert cli.main(["view", str(out)]) == 0 and seen["tensions"] is None
    assert cli.main(["view", str(out), "--structure", "icosahedron"]) == 3     # exit codes: tensegrity_gym.tools.cli
    assert cli.main(["view", str(tmp_path / "missing.npz")]) == 3
    err = capsys.readouterr().err
    assert "does not match" in err and "not a simulate output" in err and "Traceback" not in err
