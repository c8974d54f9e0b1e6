"""Inputs that gave a silently wrong result, a hang or a traceback: each is now a clear error (one
line from the CLI) or a correct result. Vector-env seeding and reset order, the core step's rod
axes, system identification inputs, MJCF names, the viewer's port and window, bounded reads of
input files, the video writer on a full disk, pickling, and the MuJoCo twin's divergence."""
from __future__ import annotations

import os
import pickle
import xml.etree.ElementTree as ET

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym as tg
from tensegrity_gym.core.model import State, compile_model, initial_state
from tensegrity_gym.tools.cli import main

SHAPE, ROLL = "TensegrityShape-v0", "TensegrityRoll-v0"


def _one_error_line(capsys):
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip()]
    assert "Traceback" not in err and lines and lines[-1].startswith("error: "), err
    assert sum(x.startswith("error: ") for x in lines) == 1, err
    return lines[-1]


# ---------------------------------------------------------------- vector env
@pytest.fixture(scope="module")
def venv():
    v = gym.make_vec(SHAPE, num_envs=3, vectorization_mode="vector_entry_point")
    yield v
    v.close()


@pytest.mark.parametrize("seed, where", [([1.9, 2, 3], r"seed: env 0: .*got 1.9"), ([1, True, 3], r"seed: env 1: .*got True"),
                                         ([1, 2, "7"], r"seed: env 2: .*got '7'"), ([1, -2, 3], r"seed: env 1: .*got -2")])
def test_vector_reset_refuses_non_integer_seeds(venv, seed, where):
    with pytest.raises(ValueError, match=where):
        venv.reset(seed=seed)
    venv.reset(seed=[1, None, np.int64(3)])    # ints, NumPy ints and None (keep) stay accepted


def test_vector_step_before_reset_raises_reset_needed():
    v = gym.make_vec(SHAPE, num_envs=2, vectorization_mode="vector_entry_point")
    with pytest.raises(gym.error.ResetNeeded):
        v.step(np.zeros((2, v.single_action_space.shape[0])))
    v.reset(seed=0)
    v.step(np.zeros((2, v.single_action_space.shape[0])))
    v.close()


def test_autoreset_mode_requests_named():
    from gymnasium.vector import AutoresetMode
    with pytest.raises(ValueError, match=r"autoreset_mode: expected one of \['next_step', 'same_step', 'disabled'\]"):
        gym.make_vec(SHAPE, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode="every_step")
    v = gym.make_vec(SHAPE, num_envs=2, vectorization_mode="vector_entry_point", autoreset_mode="next_step")
    assert v.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    v.close()


# ---------------------------------------------------------------- core step
@pytest.mark.parametrize("scale", [0.0, 2.0])
def test_core_step_refuses_rod_axis_not_unit(scale):
    m = compile_model(tg.load_structure("prism3"))
    st = initial_state(m)
    q = st.q.copy()
    q[0, 1, 3:] *= scale    # 0: NaN before; 2: rods twice as long
    with pytest.raises(ValueError, match=r"state.q: rod axis b of rod 1 .*has length .*must be a unit vector"):
        tg.step(m, State(q, st.qd, 0.0), 1e-3)
    out = tg.step(m, st, 1e-3)     # a valid state steps as before
    assert np.all(np.isfinite(out.q))


# ---------------------------------------------------------------- system identification inputs
def test_identify_refuses_complex_inputs():
    from tensegrity_gym.tools.sysid import identify
    m = compile_model(tg.load_structure("prism3"))
    t = np.arange(10) * 0.01
    nodes = np.repeat(m.structure.nodes[None], 10, axis=0)
    with pytest.raises(ValueError, match=r"t: complex numbers are not accepted"):
        identify(m, t + 1e-3j, nodes)
    with pytest.raises(ValueError, match=r"nodes: complex numbers are not accepted"):
        identify(m, t, nodes + 0j)


def test_csv_node_index_inf_and_bom(tmp_path):
    from tensegrity_gym.tools.sysid import load_csv
    p = tmp_path / "a.csv"
    p.write_text("t,node,x,y,z\n0,inf,0,0,0\n")
    with pytest.raises(ValueError, match=r"line 2: node 'inf' is not a node index 0..5"):
        load_csv(p, 6)
    p.write_text("t,node,x,y,z\n0,nan,0,0,0\n")
    with pytest.raises(ValueError, match=r"line 2: node 'nan' is not a node index"):
        load_csv(p, 6)
    p.write_bytes(b"\xef\xbb\xbft,node,x,y,z\n0,0,1,2,3\n0.1,0,1,2,3\n")   # UTF-8 with a BOM (Excel)
    t, nodes, mask = load_csv(p, 6)
    assert t.tolist() == [0.0, 0.1] and nodes[0, 0].tolist() == [1.0, 2.0, 3.0] and mask[:, 0].all()


def test_cli_identify_csv_inf_node_one_line(tmp_path, capsys):
    p = tmp_path / "a.csv"
    p.write_text("t,node,x,y,z\n0,inf,0,0,0\n")
    code = main(["identify", "prism3", str(p), "--out", str(tmp_path / "fit.json")])
    assert code == 3
    assert "node 'inf'" in _one_error_line(capsys)


# ---------------------------------------------------------------- MJCF names
def test_mjcf_control_characters_in_the_name_give_parsable_xml(tmp_path, capsys):
    from tensegrity_gym.io.mjcf import to_mjcf
    s = tg.load_structure("prism3").replace(name="robot\x01\x1b[31m\x00\ttab")
    root = ET.fromstring(to_mjcf(s))
    assert root.get("model") == "robot\\x01\\x1b[31m\\x00\ttab"
    path = tmp_path / "s.json"
    tg.save_json(s, path)
    assert main(["export", str(path), "--format", "mjcf", "--out", str(tmp_path / "m.xml")]) == 0
    ET.parse(tmp_path / "m.xml")


# ---------------------------------------------------------------- CLI: port, window, bounded reads, video
@pytest.mark.parametrize("port", ["99999", "-1", "http"])
def test_view_port_checked_when_parsed(tmp_path, capsys, port):
    code = main(["view", str(tmp_path / "none.npz"), "--port", port])
    assert code == 2
    assert "--port" in _one_error_line(capsys)


def test_view_window_on_a_headless_machine_exits_non_zero(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    traj = tmp_path / "t.npz"
    assert main(["simulate", "prism3", "--duration", "0.01", "--out", str(traj), "--no-progress"]) == 0
    capsys.readouterr()
    code = main(["view", str(traj), "--mode", "window"])
    assert code == 4
    assert "no display" in _one_error_line(capsys)


def test_info_on_dev_zero_and_a_fifo_ends_with_one_line(tmp_path, capsys):
    for p in ("/dev/zero",):
        if os.path.exists(p):
            code = main(["info", p])
            assert code == 3
            assert "not a regular file" in _one_error_line(capsys)
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    code = main(["info", str(fifo)])
    assert code == 3
    assert "not a regular file" in _one_error_line(capsys)


def test_bounded_read_stops_at_the_cap(tmp_path):
    from tensegrity_gym.core.checks import read_bounded
    p = tmp_path / "big.json"
    p.write_bytes(b" " * 5000)
    with pytest.raises(ValueError, match=r"larger than .* MiB a structure file may have"):
        read_bounded(p, 4096, "structure file")
    assert read_bounded(p, 5000, "x") == " " * 5000


def test_structure_file_over_the_cap_is_refused_before_parsing(tmp_path, capsys):
    """A structure file over MAX_FILE_BYTES (a 250 MB file took minutes and 4 GB to parse) is refused
    after reading at most the cap, with the cap named."""
    import time
    from tensegrity_gym.core.structure import MAX_FILE_BYTES
    p = tmp_path / "huge.json"
    with open(p, "wb") as fh:
        fh.write(b'{"nodes": [' + b"[0, 0, 0], " * ((MAX_FILE_BYTES // 11) + 10) + b"[0, 0, 0]]}")
    t0 = time.perf_counter()
    code = main(["info", str(p)])
    assert code == 3 and time.perf_counter() - t0 < 30
    assert "MiB a structure file may have" in _one_error_line(capsys)


def test_simulate_video_on_a_full_disk_closes_the_writer(tmp_path, capsys, monkeypatch):
    imageio = pytest.importorskip("imageio.v2")
    closed = []

    class FullDisk:
        def append_data(self, frame):
            raise OSError(28, "No space left on device")

        def close(self):
            closed.append(True)
            raise RuntimeError("ffmpeg: broken pipe")   # what a writer may add on close after the error

    monkeypatch.setattr(imageio, "get_writer", lambda *a, **k: FullDisk())
    monkeypatch.setenv("TENSEGRITY_RENDERER", "matplotlib")
    code = main(["simulate", "prism3", "--duration", "0.02", "--out", str(tmp_path / "t.npz"), "--no-progress",
                 "--video", str(tmp_path / "v.gif")])
    assert code == 4
    assert "No space left on device" in _one_error_line(capsys)
    assert closed == [True]
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".v.")]   # no temporary video left


# ---------------------------------------------------------------- pickling
def test_env_pickles_after_render():
    env = gym.make(SHAPE, render_mode="rgb_array", width=64, height=64)
    env.reset(seed=0)
    env.render()
    env2 = pickle.loads(pickle.dumps(env))
    a = np.zeros(env.action_space.shape)
    o1 = env.step(a)[0]
    o2 = env2.step(a)[0]
    assert np.array_equal(o1, o2)
    assert env2.render().shape == (64, 64, 3)
    env.close()
    env2.close()


def test_mujoco_twin_pickles():
    pytest.importorskip("mujoco")
    env = gym.make("TensegrityRollMuJoCo-v0")
    env.reset(seed=0)
    env2 = pickle.loads(pickle.dumps(env))
    a = np.zeros(env.action_space.shape)
    assert np.array_equal(env.step(a)[0], env2.step(a)[0])
    env.close()
    env2.close()


# ---------------------------------------------------------------- the MuJoCo twin's divergence
def test_twin_flags_an_unstable_run(tmp_path, monkeypatch):
    pytest.importorskip("mujoco")
    monkeypatch.chdir(tmp_path)     # MuJoCo logs its warning to MUJOCO_LOG.TXT in the working folder
    env = gym.make("TensegrityRollMuJoCo-v0", params={"stiffness": 1e9}, allow_unstable_dt=True,
                   max_episode_steps=50)
    env.reset(seed=0)
    flagged = False
    rng = np.random.default_rng(0)
    for _ in range(50):
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        assert np.all(np.isfinite(obs))
        if info["diverged"]:
            assert trunc
            flagged = True
            break
        if trunc:
            break
    assert flagged
    env.close()
