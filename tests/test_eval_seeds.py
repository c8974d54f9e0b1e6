"""Held-out evaluation seeds (agents.heldout): refused where a run trained or evaluated on one of
them, accepted where clear; every evaluation script and agents.evaluate take ``--seed``; the
per-seed intervals (agents.summary); the varied climbing starts of scripts/eval/eval_climb.py."""
import importlib
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from agents import heldout, summary

ROOT = Path(__file__).resolve().parents[1]

#: the evaluation scripts that evaluate on reset seeds (module under scripts.eval)
SCRIPTS = ("eval_climb", "eval_navigate", "eval_rough", "eval_transfer_terrain", "eval_transfer",
           "eval_model_error", "probe_robot_observation", "gait_stats", "eval_shape_baseline")


def write_run(folder: Path, seed: int = 0, n_envs: int = 128, eval_freq: int = 500_000, n_eval_envs: int = 8,
              **extra) -> Path:
    """A run folder's config.yaml as agents.train writes it (the keys agents.trainer records)."""
    folder.mkdir(parents=True)
    cfg = {"algo": "ppo", "env": "TensegrityClimb-v0", "env_kwargs": {"slope_range": [0.0, 30.0]}, "seed": seed,
           "n_timesteps": 9_000_000, "n_envs": n_envs, "vec_env": "batched", "eval_freq": eval_freq,
           "save_freq": -1, "eval_episodes": 8, "n_eval_envs": n_eval_envs, "eval_seed": seed + 10_000,
           "hyperparams_raw": {"n_envs": n_envs}, "hyperparams_resolved": {"normalize": None}, **extra}
    (folder / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    return folder


def test_run_reset_seeds_follow_the_trainer():
    from agents import trainer
    assert trainer.EVAL_SEED_OFFSET == heldout.EVAL_SEED_OFFSET == 10_000


def test_overlap_with_the_evaluation_seeds_during_training_is_refused(tmp_path):
    run = write_run(tmp_path / "seed_1", seed=1)
    assert [(a, b) for _, a, b, _ in heldout.run_reset_seeds(run)] == [(1, 129), (10_001, 10_009)]
    # the climbing table's former held-out seeds 10000-10007: the run's own evaluation seeds
    with pytest.raises(ValueError, match=r"--seed: .*10000\.\.10007.*seed_1 .*evaluation env during training"
                                         r".*10001\.\.10008\): 10001\.\.10007"):
        heldout.check_heldout(range(10_000, 10_008), [run])
    with pytest.raises(ValueError, match=r"training envs: 1\.\.128\): 100\.\.109"):
        heldout.check_heldout(range(100, 110), [run])
    heldout.check_heldout(range(40_000, 40_008), [run])                 # clear: accepted
    heldout.check_heldout(range(10_009, 10_100), [run])
    heldout.check_heldout(range(129, 10_001), [run])


def test_a_committed_run_folder_is_checked(tmp_path):
    """A config.yaml agents.train wrote (a committed climbing run) in a copied run folder."""
    src = ROOT / "results" / "climb" / "seed_0" / "config.yaml"
    if not src.is_file():
        pytest.skip("results/climb/seed_0 not in this checkout")
    run = tmp_path / "seed_0"
    run.mkdir()
    shutil.copy(src, run / "config.yaml")
    with pytest.raises(ValueError, match="seed_0"):
        heldout.check_heldout(range(10_000, 10_008), [run])
    heldout.check_heldout(range(40_000, 40_008), [run])


def test_without_evaluation_during_training_only_the_training_seeds_count(tmp_path):
    run = write_run(tmp_path / "r", seed=5, n_envs=4, eval_freq=-1)
    heldout.check_heldout(range(10_000, 10_010), [run])
    with pytest.raises(ValueError, match=r"8"):
        heldout.check_heldout([8], [run])


def test_older_configs_count_the_widest_default(tmp_path):
    run = write_run(tmp_path / "old", seed=0, n_envs=2)
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    for k in ("eval_freq", "n_eval_envs", "eval_seed"):
        del cfg[k]
    (run / "config.yaml").write_text(yaml.safe_dump(cfg))
    with pytest.raises(ValueError, match=r"10009"):
        heldout.check_heldout([10_009], [run])
    heldout.check_heldout([10_010], [run])


def test_warm_start_source_and_model_files(tmp_path):
    src = write_run(tmp_path / "source", seed=7000, n_envs=8)
    run = write_run(tmp_path / "climb", seed=0, warm_start={"run": str(src), "model": str(src / "model.zip")})
    with pytest.raises(ValueError, match=r"source \(the warm start of .*climb\).*17000\.\.17007"):
        heldout.check_heldout([17_003], [run])
    # a model file in the run folder or its checkpoints/: that run's seeds
    (run / "checkpoints").mkdir()
    ckpt = run / "checkpoints" / "rl_model_1000_steps.zip"
    ckpt.write_bytes(b"")
    with pytest.raises(ValueError, match="climb"):
        heldout.check_heldout([10_000], [ckpt])
    heldout.check_heldout([10_000], ["gait"])                          # not a path: a baseline, skipped


def test_bad_seeds_are_named():
    with pytest.raises(ValueError, match="--seed: must be an integer"):
        heldout.heldout_seeds(-1, 3)
    with pytest.raises(ValueError, match=r"--seed \+ episodes - 1"):
        heldout.heldout_seeds(2**32 - 2, 3)
    assert list(heldout.heldout_seeds(5, 3)) == [5, 6, 7]


def test_scripts_refuse_an_overlap_with_exit_status_2(tmp_path, capsys):
    run = write_run(tmp_path / "seed_0", seed=0)
    with pytest.raises(SystemExit) as e:
        heldout.script_heldout_seeds(10_000, 8, [run])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --seed:") and "seed_0" in err and len(err.splitlines()) == 1
    eval_climb = importlib.import_module("scripts.eval.eval_climb")
    with pytest.raises(SystemExit) as e:          # refused before any model is loaded
        eval_climb.main([str(run), "--out", str(tmp_path / "out"), "--seed", "10000", "--slopes", "20"])
    assert e.value.code == 2 and "10000..10007" in capsys.readouterr().err


def test_agents_evaluate_and_multiseed_refuse_an_overlap(tmp_path, capsys):
    from agents import evaluate, multiseed
    run = write_run(tmp_path / "seed_2", seed=2)
    assert evaluate.main([str(run), "--seed", "10000", "--n-episodes", "4"]) == 2
    assert "seed_2" in capsys.readouterr().err
    assert multiseed.main([str(run), "--out", str(tmp_path / "m"), "--seed", "100", "--n-episodes", "3"]) == 2
    assert "training envs" in capsys.readouterr().err
    assert evaluate.build_parser().parse_args([str(run)]).seed == evaluate.HELD_OUT_SEED


@pytest.mark.parametrize("name", SCRIPTS)
def test_every_evaluation_script_takes_seed(name, capsys):
    mod = importlib.import_module(f"scripts.eval.{name}")
    with pytest.raises(SystemExit) as e:
        mod.main(["--help"])
    assert e.value.code == 0
    assert "--seed SEED" in capsys.readouterr().out


def test_per_seed_intervals():
    p, lo, hi = summary.rate_interval(169, 200)
    assert p == 0.845 and (round(lo, 3), round(hi, 3)) == (0.788, 0.889)
    assert summary.rate_interval(100, 100)[1:] == (pytest.approx(0.963, abs=1e-3), 1.0)
    m, lo, hi = summary.mean_interval([0.1, 0.2, 0.3, 0.4, 0.5])
    assert m == pytest.approx(0.3) and lo < m < hi and lo >= 0.1 and hi <= 0.5
    assert summary.mean_interval([0.2, 0.2]) == (0.2, 0.2, 0.2)
    with pytest.raises(ValueError, match="successes, n"):
        summary.rate_interval(3, 2)


def test_turned_starts_keep_the_robot_and_vary_with_the_seed():
    import gymnasium as gym
    import tensegrity_gym  # noqa: F401  (registers the envs)
    from scripts.eval.eval_climb import StartSpread, turn_about_normal
    rng = np.random.default_rng(0)
    q, qd = rng.normal(size=(2, 3, 6)), rng.normal(size=(2, 3, 6))
    q2, qd2 = turn_about_normal(q, qd, np.array([0.5, -2.0]))
    np.testing.assert_allclose(q2[..., 2], q[..., 2])                          # heights kept
    np.testing.assert_allclose(np.linalg.norm(q2[..., 3:], axis=-1), np.linalg.norm(q[..., 3:], axis=-1))
    np.testing.assert_allclose(q2[..., :2].mean(1), q[..., :2].mean(1))      # turned about the mean centre
    np.testing.assert_allclose(np.linalg.norm(qd2[..., :3], axis=-1), np.linalg.norm(qd[..., :3], axis=-1))

    kw = {"slope_deg": 20.0}
    plain = gym.make("TensegrityClimb-v0", **kw)
    turned = gym.make("TensegrityClimb-v0", **kw)
    StartSpread(180.0).install(turned)
    o0, _ = plain.reset(seed=40_000)
    o1, info = turned.reset(seed=40_000)
    t0, t1 = plain.unwrapped.task, turned.unwrapped.task
    np.testing.assert_allclose(np.sort(t1.q[0, :, 2]), np.sort(t0.q[0, :, 2]))    # same heights, turned in xy
    assert not np.allclose(t1.q[0, :, 3:5], t0.q[0, :, 3:5])
    np.testing.assert_array_equal(o1, t1.observe()[0])                            # the env wrote the turned start
    np.testing.assert_allclose(info["com_position"], t1.com(t1.q)[0])
    still = gym.make("TensegrityClimb-v0", **kw)
    StartSpread(0.0).install(still)                                               # no turn: the env's own start
    still.reset(seed=40_000)
    np.testing.assert_array_equal(still.unwrapped.task.q, t0.q)
    still.close()
    q_a = t1.q.copy()
    turned.reset(seed=40_000)
    np.testing.assert_array_equal(t1.q, q_a)                                      # drawn from the reset seed
    turned.reset(seed=40_001)
    q_b = t1.q.copy()
    assert not np.allclose(q_b[0, :, 3:5], q_a[0, :, 3:5])
    assert np.all(np.isfinite(turned.step(np.zeros(turned.action_space.shape))[0]))
    # the vector env: one yaw per copy from its own seed, as the single env draws it
    venv = gym.make_vec("TensegrityClimb-v0", num_envs=2, vectorization_mode="vector_entry_point", **kw)
    StartSpread(180.0).install(venv)
    venv.reset(seed=[40_000, 40_001])
    np.testing.assert_allclose(venv.unwrapped.task.q[1], q_b[0], atol=1e-12)
    for env in (plain, turned, venv):
        env.close()
