"""Hardening III: inputs of a hostile pass that gave a wrong result, a silent no-op or a traceback,
each now a clear error naming the argument (one line from the CLI) or a correct result. The
curriculum hooks (a climb's slope range, the vector env's ``set_attr``, ``env_idx``), terrain
numbers out of any physical range, a navigation grid or scan too large for memory, and system
identification's verdict, initial values and help."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from tensegrity_gym.envs.vector_rules import reset_mask_option     # (importing the package registers the envs)

CLIMB, ROLL, SHAPE = "TensegrityClimb-v0", "TensegrityRoll-v0", "TensegrityShape-v0"
VEC = dict(vectorization_mode="vector_entry_point")


# ---------------------------------------------------------------- curriculum hooks
@pytest.fixture(scope="module")
def climb_vec():
    v = gym.make_vec(CLIMB, num_envs=3, slope_range=(5.0, 10.0), **VEC)
    yield v
    v.close()


@pytest.mark.parametrize("value, match", [
    ((89.0, 300.0), r"slope_range\[0\]: must be in \[0, 60\] degrees, got 89"),
    ((float("nan"), float("nan")), r"slope_range\[0\]: must be in \[0, 60\] degrees, got nan"),
    ("ab", r"slope_range: expected \(low, high\) degrees, got 'ab'"),
    ((1e400, 1e400), r"slope_range\[0\]: must be in"),
    ((10**400, 5.0), r"slope_range\[0\]: must be in \[0, 60\] degrees, got an integer of 1329 bits"),
    ((30.0, 10.0), r"slope_range: low 30 is above high 10"),
])
def test_slope_range_is_validated_when_set(climb_vec, value, match):
    task = climb_vec.unwrapped.task
    with pytest.raises(ValueError, match=match):
        task.slope_range = value
    assert task.slope_range == (5.0, 10.0)


def test_slope_range_set_between_episodes_draws_from_it(climb_vec):
    task = climb_vec.unwrapped.task
    try:
        task.slope_range = (20.0, 30.0)
        _, info = climb_vec.reset(seed=1)
        assert np.all((info["slope_deg"] >= 20.0) & (info["slope_deg"] <= 30.0))
        climb_vec.set_attr("slope_range", (40.0, 40.0))       # through set_attr: one (low, high) pair
        assert climb_vec.get_attr("slope_range") == ((40.0, 40.0),) * 3
        _, info = climb_vec.reset(seed=1)
        np.testing.assert_array_equal(info["slope_deg"], 40.0)
        with pytest.raises(ValueError, match=r"slope_range\[1\]"):
            climb_vec.set_attr("slope_range", (0.0, 61.0))
    finally:
        task.slope_range = (5.0, 10.0)


def test_slope_range_on_a_fixed_slope_env_is_refused_not_ignored():
    env = gym.make(CLIMB, slope_deg=10.0)
    task = env.unwrapped.task
    with pytest.raises(ValueError, match=r"slope_range: this env was built with the fixed slope_deg=10 degrees"):
        task.slope_range = (5.0, 20.0)
    with pytest.raises(ValueError, match=r"slope_range: .*fixed slope_deg=10"):
        task.slope_range = (20.0, 20.0)
    task.slope_range = (10.0, 10.0)                      # its own slope: nothing changes
    _, info = env.reset(seed=0)
    assert info["slope_deg"] == 10.0
    env.close()


def test_vector_set_attr_forwards_terrain_difficulty_to_the_task():
    v = gym.make_vec(ROLL, num_envs=2, **VEC)
    v.set_attr("terrain_difficulty", 0.0)
    assert v.unwrapped.task.terrain_difficulty == 0.0
    assert "terrain_difficulty" not in vars(v)           # not a new attribute on the shell
    assert v.get_attr("terrain_difficulty") == (0.0, 0.0)
    with pytest.raises(ValueError, match=r"terrain_difficulty: must be in \[0, 1\], got 2"):
        v.set_attr("terrain_difficulty", 2)
    v.close()


@pytest.mark.parametrize("name, value, match", [
    ("num_envs", 7, r"set_attr\('num_envs'\): is read-only on TensegrityRollVectorEnv; settable: \["),
    ("courses", None, r"set_attr\('courses'\): is not an attribute of TensegrityRollVectorEnv"),
    ("task", None, r"set_attr\('task'\): is read-only"),
    ("np_random", [1, 2], r"set_attr\('np_random'\): env 0: expected a numpy.random.Generator, got 1"),
    ("max_episode_steps", 0, r"max_episode_steps"),
    ("autoreset_mode", "sometimes", r"autoreset_mode: expected one of"),
])
def test_vector_set_attr_refuses_read_only_unknown_and_bad_values(name, value, match):
    v = gym.make_vec(ROLL, num_envs=2, **VEC)
    with pytest.raises(ValueError, match=match):
        v.set_attr(name, value)
    assert v.num_envs == 2 and len(v.np_random_list) == 2
    v.reset(seed=0)
    v.step(np.zeros((2, v.single_action_space.shape[0])))     # nothing broken
    v.close()


def test_terrain_difficulty_is_not_a_hook_of_the_climb_env(climb_vec):
    with pytest.raises(ValueError, match=r"set_attr\('terrain_difficulty'\): .*settable: .*'slope_range'"):
        climb_vec.set_attr("terrain_difficulty", 0.0)


@pytest.mark.parametrize("idx", [[-1], [0, -3], [3]])
def test_env_idx_refuses_negative_indices_as_out_of_range(idx):
    with pytest.raises(ValueError, match=r"options\['env_idx'\]: indices must lie in \[0, 3\)"):
        reset_mask_option({"env_idx": idx}, 3)
    mask, _ = reset_mask_option({"env_idx": [2, 0]}, 3)
    np.testing.assert_array_equal(mask, [True, False, True])


# ---------------------------------------------------------------- terrain numbers
BIG = 10 ** 400          # a JSON integer of 400 digits: too large for a float


@pytest.mark.parametrize("d, match", [
    ({"friction": BIG}, r"^friction: must be finite, got an integer of 1329 bits"),
    ({"boxes": [{"center": [0, 0, BIG], "size": [1, 1, 1]}]}, r"^boxes\[0\]\.center\[2\]: must be finite, got an integer"),
    ({"plane": {"slope_deg": BIG}}, r"^plane\.slope_deg: must be finite"),
    ({"heightfield": {"heights": [[0, BIG], [0, 0]], "cell": 0.1}}, r"^heightfield\.heights\[0, 1\]: must be finite, got an integer"),
    ({"heightfield": {"heights": [[0, 1], [0, 0]], "cell": BIG}}, r"^heightfield\.cell: must be finite"),
    ({"generator": "steps", "n_steps": BIG}, r"^terrain\.n_steps: must be an integer in \[1, 1000\], got an integer of 1329 bits"),
    ({"generator": "steps", "tread": BIG}, r"^terrain\.tread: must be a positive number of at most 1e\+06 m"),
    ({"generator": "slope", "slope_range": [0, BIG]}, r"^terrain\.slope_range: expected \(low, high\) degrees"),
])
def test_a_huge_integer_in_a_terrain_is_a_named_error(d, match):
    from tensegrity_gym.tasks.terrain import resolve_terrain
    with pytest.raises(ValueError, match=match):
        resolve_terrain(d, {})


def test_a_huge_integer_in_a_terrain_file_is_one_cli_line(tmp_path, capsys):
    from tensegrity_gym.tools.cli import main
    path = tmp_path / "t.json"
    path.write_text('{"boxes": [{"center": [0, 0, ' + "9" * 400 + '], "size": [1, 1, 1]}]}')
    huge = tmp_path / "u.json"
    huge.write_text('{"friction": ' + "9" * 5000 + '}')         # beyond Python's 4300-digit int parsing
    for p, pattern in ((path, r"boxes\[0\]\.center\[2\]: must be finite, got an integer of 1329 bits"),
                       (huge, r"terrain file: not valid JSON \(.*u\.json.*Exceeds the limit")):
        assert main(["simulate", "prism3", "--terrain", str(p), "--out", str(tmp_path / "x.npz"), "--no-progress"]) == 3
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err, err
        assert __import__("re").search(pattern, err), err


# ---------------------------------------------------------------- navigation grid and scan sizes
@pytest.mark.parametrize("kw, match", [
    (dict(cell=1e-6), r"^cell, arena: a cell of 1e-06 m over the arena \+-3 m .* about 7\.6e\+06 x 7\.6e\+06 cells; at most 2000"),
    (dict(arena=1e6), r"^cell, arena: a cell of 0\.1 m over the arena \+-1e\+06 m"),
    (dict(arena=1e300), r"^cell, arena: "),
    (dict(lookahead=10 ** 9), r"^lookahead: 1000000000 cells reaches beyond the planner grid of 77 x 77 cells; at most 77"),
    (dict(height_scan=(100000, 0.1)), r"^height_scan: n = 100000 makes a scan of 100000 x 100000 points; at most 2000"),
    (dict(n_goals=10 ** 9), r"^num_envs, cell, arena, n_goals, height_scan: 1 copies' courses need about .* GiB"),
])
def test_navigate_grid_and_scan_too_large_are_refused_before_allocation(kw, match):
    from tensegrity_gym.envs.navigate import NavigateTask
    with pytest.raises(ValueError, match=match):
        NavigateTask(**kw)


# ---------------------------------------------------------------- terrain values out of any physical range
@pytest.mark.parametrize("d, match", [
    ({"boxes": [{"center": [0, 0, 0], "size": [1e300, 1, 1]}]},
     r"^boxes\[0\]\.size\[0\]: must be within \+-1e\+06 m \(a terrain's physical extent\), got 1e\+300"),
    ({"boxes": [{"center": [0, -2e6, 0], "size": [1, 1, 1]}]}, r"^boxes\[0\]\.center\[1\]: must be within \+-1e\+06 m"),
    ({"heightfield": {"heights": [[1e308, -1e308], [0, 0]], "cell": 0.1}},
     r"^heightfield\.heights\[0, 0\]: must be within \+-1e\+06 m \(a terrain's physical extent\), got 1e\+308"),
    ({"heightfield": {"heights": [[0, 0], [0, 0]], "cell": 0.1, "origin": [0, 1e7]}},
     r"^heightfield\.origin\[1\]: must be within \+-1e\+06 m"),
    ({"heightfield": {"heights": [[0, 0], [0, 0]], "cell": 2e6}}, r"^heightfield\.cell: must be within \+-1e\+06 m"),
    ({"heightfield": {"heights": [[True, False], [0, 0]], "cell": 0.1}},
     r"^heightfield\.heights\[0, 0\]: expected a real number, got True"),
    ({"heightfield": {"heights": [[0.0, 1 + 2j], [0, 0]], "cell": 0.1}},
     r"^heightfield\.heights\[0, 1\]: expected a real number, got \(1\+2j\)"),
    ({"heightfield": {"heights": np.array([[0, 1 + 2j], [0, 0]]), "cell": 0.1}},
     r"^heightfield\.heights: expected an array of real numbers \(m\), got dtype complex128"),
    ({"heightfield": {"heights": np.ones((2, 2), bool), "cell": 0.1}},
     r"^heightfield\.heights: expected an array of real numbers \(m\), got dtype bool"),
    ({"generator": "steps", "step_height": 1e308}, r"^terrain\.step_height: must be a non-negative number of at most 1e\+06 m"),
    ({"generator": "steps", "step_height": 4e5}, r"^terrain\.step_height: 400000 m x 4 steps rises above 1e\+06 m"),
    ({"generator": "rough", "amplitude": 1e300}, r"^terrain\.amplitude: must be a non-negative number of at most 1e\+06 m"),
])
def test_terrain_values_beyond_physical_bounds_are_named(d, match):
    from tensegrity_gym.tasks.terrain import resolve_terrain
    with pytest.raises(ValueError, match=match):
        resolve_terrain(d, {})


def test_bool_and_complex_heightfield_files_are_refused(tmp_path):
    from tensegrity_gym.core.terrain import Terrain
    for name, arr in (("b.npy", np.ones((3, 3), bool)), ("c.npy", np.ones((3, 3), complex))):
        np.save(tmp_path / name, arr)
        with pytest.raises(ValueError, match=rf"^heightfield\.heights: expected an array of real numbers \(m\), got dtype {arr.dtype}"):
            Terrain.from_dict({"heightfield": {"file": name, "cell": 0.1}}, base_dir=tmp_path)
    np.save(tmp_path / "i.npy", np.arange(9, dtype=np.int32).reshape(3, 3))      # integers stay heights (m)
    t = Terrain.from_dict({"heightfield": {"file": "i.npy", "cell": 0.1}}, base_dir=tmp_path)
    assert t.heightfield.heights.dtype == float and t.heightfield.heights[2, 2] == 8.0


# ---------------------------------------------------------------- system identification
def _free_record(structure, T=0.21, amp=0.03, seed=0, sub=4):
    """(t, nodes) of ``structure`` released off equilibrium: samples 2 ms apart (rk4 at 2 ms / sub)."""
    import tensegrity_gym as tg
    from tensegrity_gym.core.model import State
    from tensegrity_gym.physics.evaluate import project
    from tensegrity_gym.physics.geometry import node_positions
    model = tg.compile_model(structure)
    rng = np.random.default_rng(seed)
    st = tg.initial_state(model, nodes=structure.nodes + amp * rng.standard_normal(structure.nodes.shape))
    st = State(*project(model, st.q, st.qd))
    t, q, _ = tg.simulate(model, st, 2e-3 / sub, int(round(T / 2e-3)) * sub, "rk4")
    return t[::sub], node_positions(model, q[::sub, 0])


def test_identify_value_at_the_search_bound_is_not_ok():
    """A record without damping, the fit started at 2 N s/m: the damping runs to the search bound
    (e^-5 of the start), where the residual no longer depends on it; it was reported ok with a
    standard error of 0."""
    import tensegrity_gym as tg
    from tensegrity_gym.tools.sysid import SysIdWarning, identify
    s = tg.prism(3)
    t, nodes = _free_record(s)
    with pytest.warns(SysIdWarning, match=r"at the search bound \(a factor of 148 .*: damping string 0"):
        r = identify(tg.compile_model(s), t, nodes, fit=("damping",), mode="scale", initial={"damping": 2.0})
    assert r.values["damping"][0] == pytest.approx(2.0 * np.exp(-5.0))
    assert r.at_bound["damping"].all() and not r.identifiable["damping"].any()
    assert np.isinf(r.std_errors["damping"]).all() and not r.ok
    d = r.to_dict()
    assert d["ok"] is False and d["at_bound"]["damping"][0] is True and d["std_errors"]["damping"][0] is None


def test_identify_record_of_another_structure_is_a_misfit_not_ok():
    """A record of another prism (same 6 nodes: wider, lower, under gravity) fitted as prism3's
    stiffness: the fit converges, but its error is far above the record's noise and a large part
    of its motion: not ok, and the warning says why."""
    import tensegrity_gym as tg
    from tensegrity_gym.tools.sysid import SysIdWarning, identify
    t, nodes = _free_record(tg.prism(3, radius=0.7, height=0.6, gravity=(0, 0, -9.81)))
    with pytest.warns(SysIdWarning, match=r"the fitted model misses the record: RMS error .* mm is above 10 x the "
                                          r"record's noise .* and 0.1 x its motion"):
        r = identify(tg.compile_model(tg.prism(3)), t, nodes, fit=("stiffness",), mode="scale")
    assert r.misfit and not r.ok
    assert r.rms_m > 10 * r.noise_m and r.rms_m > 0.1 * r.motion_rms_m
    assert r.to_dict()["misfit"] is True
    # the same structure's own record: no misfit, ok
    t, nodes = _free_record(tg.prism(3))
    r = identify(tg.compile_model(tg.prism(3)), t, nodes, fit=("stiffness",), mode="scale")
    assert r.ok and not r.misfit and r.scale["stiffness"] == pytest.approx(1.0, rel=1e-3)


def test_identify_initial_value_that_blows_up_is_the_divergence_error(tmp_path, capsys):
    import tensegrity_gym as tg
    from tensegrity_gym.core.errors import SimulationDiverged
    from tensegrity_gym.tools.cli import main
    from tensegrity_gym.tools.sysid import identify
    t, nodes = _free_record(tg.prism(3))
    with pytest.raises(SimulationDiverged, match=r"the starting values stiffness=1e\+300 N/m blow the simulation up"):
        identify(tg.compile_model(tg.prism(3)), t, nodes, fit=("stiffness",), initial={"stiffness": 1e300})
    np.savez(tmp_path / "rec.npz", t=t, nodes=nodes)
    code = main(["identify", "prism3", str(tmp_path / "rec.npz"), "--fit", "stiffness", "--initial", "stiffness=1e300",
                 "--out", str(tmp_path / "fit.json")])
    err = capsys.readouterr().err
    assert code == 6 and err.count("\n") == 1 and "Traceback" not in err, err
    assert "the simulation diverged during the fit (the starting values stiffness=1e+300 N/m" in err, err
    assert "state.q" not in err


def test_identify_help_names_no_terrain_file(capsys):
    from tensegrity_gym.tools.cli import main
    assert main(["identify", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "terrain file" not in out
    assert "Coulomb friction coefficient of the ground (default 1)" in out
    assert "normal contact stiffness of the ground, N/m (default 10000)" in out
    assert "Hunt-Crossley contact damping of the ground, s/m (default 10)" in out
    assert main(["simulate", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "(default: the terrain file's; 1 with --ground)" in out
