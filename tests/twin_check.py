"""The check that a MuJoCo twin env presents the interface of its project env: the same action
and observation spaces, observation layout and control step, an observation inside its space,
and the same info keys after reset. Used by test_roll_mujoco.py and test_climb_mujoco.py."""


def assert_same_interface(twin, project):
    """``twin`` and ``project`` (envs built with the same arguments) agree; both are reset with
    seed 0."""
    assert twin.action_space == project.action_space
    assert twin.observation_space == project.observation_space
    assert twin.task.observation_layout() == project.task.observation_layout()
    assert twin.dt == project.dt
    obs, info = twin.reset(seed=0)
    _, info_b = project.reset(seed=0)
    assert twin.observation_space.contains(obs)
    assert set(info) == set(info_b)
