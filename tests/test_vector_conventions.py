"""The vector envs' Gymnasium conventions the RL libraries rely on: ``autoreset_mode``
(``next_step`` default, ``same_step``, ``disabled``) against ``SyncVectorEnv`` of single envs
with the same mode, partial resets by ``reset_mask`` and ``env_idx``, ``call`` / ``get_attr`` /
``set_attr``, ``gymnasium.vector.VectorEnv`` as a direct base, and the episode statistics /
normalisation wrappers that accept the torch env's tensors."""
import numpy as np
import pytest
import gymnasium as gym
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import tensegrity_gym  # noqa: F401  (registers the envs)

SHAPE, ROLL = "TensegrityShape-v0", "TensegrityRoll-v0"


def _vec(env_id, N, **kw):
    return gym.make_vec(env_id, num_envs=N, vectorization_mode="vector_entry_point", **kw)


def _sync(env_id, N, T, mode):
    return SyncVectorEnv([lambda: gym.make(env_id, max_episode_steps=T) for _ in range(N)], autoreset_mode=mode)


def _actions(rng, N, na):
    return rng.uniform(-1, 1, (N, na)).astype(np.float32)


@pytest.mark.parametrize("env_id", [SHAPE, ROLL])
@pytest.mark.parametrize("mode", ["same_step", "next_step"])
def test_autoreset_mode_equals_sync_vector_env_of_single_envs(env_id, mode):
    T, N = 4, 3
    v = _vec(env_id, N, max_episode_steps=T, autoreset_mode=mode)
    s = _sync(env_id, N, T, AutoresetMode(v.autoreset_mode))
    assert v.metadata["autoreset_mode"] is v.autoreset_mode is s.metadata["autoreset_mode"]
    np.testing.assert_array_equal(v.reset(seed=5)[0], s.reset(seed=5)[0])
    rng = np.random.default_rng(1)
    ended = 0
    for _ in range(2 * T + 2):
        a = _actions(rng, N, v.single_action_space.shape[0])
        (o1, r1, te1, tr1, i1), (o2, r2, te2, tr2, i2) = v.step(a), s.step(a)
        for x, y in ((o1, o2), (r1, r2), (te1, te2), (tr1, tr2)):
            np.testing.assert_array_equal(x, y)
        assert ("final_obs" in i1) == ("final_obs" in i2)
        if "final_obs" in i2:
            ended += 1
            np.testing.assert_array_equal(i1["_final_obs"], i2["_final_obs"])
            np.testing.assert_array_equal(i1["_final_info"], i2["_final_info"])
            for i in np.flatnonzero(i2["_final_obs"]):
                np.testing.assert_array_equal(i1["final_obs"][i], i2["final_obs"][i])
                for k, m in i2["final_info"].items():
                    # "TimeLimit.truncated": a key an imported library's TimeLimit patch adds to the
                    # single envs (order-dependent under xdist), not an env info
                    if not k.startswith(("_", "TimeLimit.")) and not isinstance(m, dict):
                        np.testing.assert_allclose(i1["final_info"][k][i], m[i], rtol=1e-12, err_msg=k)
            assert i1["final_obs"][~i1["_final_obs"]].tolist() == [None] * int((~i1["_final_obs"]).sum())
    assert ended == (2 if mode == "same_step" else 0)


def test_default_mode_is_next_step_and_unknown_modes_are_named():
    v = _vec(SHAPE, 2)
    assert v.autoreset_mode is AutoresetMode.NEXT_STEP and v.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert _vec(SHAPE, 2, autoreset_mode=AutoresetMode.DISABLED).autoreset_mode is AutoresetMode.DISABLED
    with pytest.raises(ValueError, match=r"autoreset_mode: expected one of \['next_step', 'same_step', 'disabled'\]"):
        _vec(SHAPE, 2, autoreset_mode="sometimes")


def test_disabled_mode_needs_the_caller_to_reset_ended_envs():
    T, N = 3, 2
    v = _vec(SHAPE, N, max_episode_steps=T, autoreset_mode="disabled")
    s = _sync(SHAPE, N, T, AutoresetMode.DISABLED)
    v.reset(seed=0), s.reset(seed=0)
    a = np.zeros((N, v.single_action_space.shape[0]), np.float32)
    for _ in range(T):
        r1, r2 = v.step(a), s.step(a)
    assert r1[3].all() and r2[3].all()
    with pytest.raises(gym.error.ResetNeeded, match="disabled"):
        v.step(a)
    mask = np.array([True, False])
    o1, _ = v.reset(options={"reset_mask": mask})
    o2, _ = s.reset(options={"reset_mask": mask})
    np.testing.assert_array_equal(o1, o2)
    o1, _ = v.reset(options={"env_idx": [1]})
    o2, _ = s.reset(options={"reset_mask": ~mask})
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(v.step(a)[0], s.step(a)[0])


def test_env_idx_reset_equals_reset_mask_reset():
    a, b = _vec(SHAPE, 3), _vec(SHAPE, 3)
    a.reset(seed=2), b.reset(seed=2)
    oa, ia = a.reset(seed=9, options={"env_idx": np.array([0, 2])})
    ob, ib = b.reset(seed=9, options={"reset_mask": np.array([True, False, True])})
    np.testing.assert_array_equal(oa, ob)
    np.testing.assert_array_equal(ia["_is_success"] if "_is_success" in ia else [], ib.get("_is_success", []))
    with pytest.raises(ValueError, match="not both"):
        a.reset(options={"env_idx": [0], "reset_mask": np.ones(3, bool)})
    with pytest.raises(ValueError, match=r"env_idx.*\[0, 3\)"):
        a.reset(options={"env_idx": [3]})


def test_call_get_attr_set_attr_and_direct_vector_env_base():
    v = _vec(SHAPE, 3)
    assert gym.vector.VectorEnv in type(v).__bases__
    v.reset(seed=0)
    assert v.get_attr("dt") == (v.dt,) * 3
    assert v.call("dt") == (v.dt,) * 3
    rngs = v.get_attr("np_random")
    assert len(rngs) == 3 and rngs[0] is v.np_random_list[0] and rngs[0] is not rngs[1]
    v.set_attr("max_episode_steps", 7)
    assert v.max_episode_steps == 7
    v.set_attr("max_episode_steps", [8, 8, 8])
    assert v.max_episode_steps == 8
    with pytest.raises(ValueError, match="share the attribute"):
        v.set_attr("max_episode_steps", [1, 2, 3])
    new = [np.random.default_rng(i) for i in range(3)]
    v.set_attr("np_random", new)
    assert list(v.np_random_list) == new


# ---------------------------------------------------------------- torch env
def _torch_vec(env_id, N, **kw):
    pytest.importorskip("torch")
    return _vec(env_id, N, backend="torch", device="cpu", dtype="float64", **kw)


@pytest.mark.parametrize("env_id", [SHAPE, ROLL])
def test_torch_same_step_equals_numpy_same_step(env_id):
    torch = pytest.importorskip("torch")
    T, N = 3, 2
    t = _torch_vec(env_id, N, max_episode_steps=T, autoreset_mode="same_step")
    n = _vec(env_id, N, max_episode_steps=T, autoreset_mode="same_step")
    assert gym.vector.VectorEnv in type(t).__bases__ and t.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    t.reset(seed=4), n.reset(seed=4)
    rng = np.random.default_rng(0)
    for k in range(2 * T + 1):
        a = _actions(rng, N, n.single_action_space.shape[0])
        (o1, r1, te1, tr1, i1), (o2, r2, te2, tr2, i2) = t.step(torch.as_tensor(a)), n.step(a)
        np.testing.assert_allclose(o1.numpy(), o2, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(r1.numpy(), r2, rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(tr1.numpy(), tr2)
        assert ("final_obs" in i1) == ("final_obs" in i2)
        if "final_obs" in i2:
            np.testing.assert_array_equal(i1["_final_obs"].numpy(), i2["_final_obs"])
            for i in np.flatnonzero(i2["_final_obs"]):
                np.testing.assert_allclose(i1["final_obs"][i].numpy(), i2["final_obs"][i], rtol=1e-6, atol=1e-9)


def test_torch_disabled_mode_and_env_idx_tensor():
    torch = pytest.importorskip("torch")
    T, N = 2, 3
    t = _torch_vec(SHAPE, N, max_episode_steps=T, autoreset_mode="disabled")
    t.reset(seed=0)
    a = torch.zeros((N, t.single_action_space.shape[0]), dtype=torch.float64)
    for _ in range(T):
        out = t.step(a)
    assert bool(out[3].all())
    with pytest.raises(gym.error.ResetNeeded):
        t.step(a)
    t.reset(options={"env_idx": torch.arange(N)})
    t.step(a)
    assert t.get_attr("device") == (t.device,) * N


def test_torch_episode_statistics_match_gymnasium_on_the_numpy_env():
    torch = pytest.importorskip("torch")
    from gymnasium.wrappers.vector import RecordEpisodeStatistics
    from tensegrity_gym.envs.torch_wrappers import TorchRecordEpisodeStatistics
    for mode in ("next_step", "same_step"):
        T, N = 3, 2
        t = TorchRecordEpisodeStatistics(_torch_vec(SHAPE, N, max_episode_steps=T, autoreset_mode=mode))
        n = RecordEpisodeStatistics(_vec(SHAPE, N, max_episode_steps=T, autoreset_mode=mode))
        m = TorchRecordEpisodeStatistics(_vec(SHAPE, N, max_episode_steps=T, autoreset_mode=mode))
        t.reset(seed=1), n.reset(seed=1), m.reset(seed=1)
        seen = 0
        for _ in range(3 * T + 1):
            a = np.full((N, n.single_action_space.shape[0]), 0.3, np.float32)
            i1, i2, i3 = t.step(torch.as_tensor(a))[4], n.step(a)[4], m.step(a)[4]
            assert ("episode" in i1) == ("episode" in i2) == ("episode" in i3)
            if "episode" in i2:
                seen += 1
                np.testing.assert_array_equal(i1["_episode"].numpy(), i2["_episode"])
                np.testing.assert_array_equal(i3["_episode"], i2["_episode"])
                np.testing.assert_allclose(i1["episode"]["r"].numpy(), i2["episode"]["r"], rtol=1e-6)
                np.testing.assert_allclose(i3["episode"]["r"], i2["episode"]["r"], rtol=1e-12)
                np.testing.assert_array_equal(i1["episode"]["l"].numpy(), i2["episode"]["l"])
        assert seen == (2 if mode == "next_step" else 3)    # next_step: one reset step after each end
        assert list(t.length_queue) == list(n.length_queue)


def test_torch_normalisation_wrappers_accept_tensors():
    torch = pytest.importorskip("torch")
    from tensegrity_gym.envs.torch_wrappers import TorchNormalizeObservation, TorchNormalizeReward
    env = TorchNormalizeReward(TorchNormalizeObservation(_torch_vec(SHAPE, 4)), gamma=0.9)
    obs, _ = env.reset(seed=0)
    assert isinstance(obs, torch.Tensor) and obs.shape == (4, env.single_observation_space.shape[0])
    for _ in range(3):
        obs, rew, *_ = env.step(torch.zeros((4, env.single_action_space.shape[0])))
    assert isinstance(rew, torch.Tensor) and rew.shape == (4,) and bool(torch.isfinite(obs).all())
    # the same wrappers on the NumPy env give arrays
    env = TorchNormalizeObservation(_vec(SHAPE, 2))
    assert isinstance(env.reset(seed=0)[0], np.ndarray)
