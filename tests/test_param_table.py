"""The one parameter table (tensegrity_gym.core.param_table) and the steps of
docs/adding_a_parameter.md: every name table is a view of it, every row reaches its per-copy
container, and a row made an env parameter reaches domain randomisation, the NumPy writer, the
torch device reset and the MuJoCo twin's refusal without another edit (the packed layout, flags
and nominal values: tests/test_param_layout.py)."""
import ast
import dataclasses
import importlib.util
import inspect
import pathlib

import gymnasium as gym
import numpy as np
import pytest

import tensegrity_gym  # noqa: F401  (registers the envs)
from tensegrity_gym.physics import actuation
from tensegrity_gym.core import params
from tensegrity_gym.backends.torch.model import PARAM_FIELDS
from tensegrity_gym.physics import contact, terrain
from tensegrity_gym.physics.contact import PRM_FIELDS, GroundContact
from tensegrity_gym.core import param_table as pt
from tensegrity_gym.envs import base, domain, roll, twin_params

ENVS = pathlib.Path(roll.__file__).parent


def _holds(view, rows):
    """``view`` (a dict or a tuple) holds ``rows`` (the same type; a tuple in the same order): a row
    added to the table adds to a view and leaves these as they are (no edit here for a new row)."""
    if isinstance(rows, dict):
        return {k: view[k] for k in rows if k in view} == rows
    return tuple(f for f in view if f in rows) == rows


def test_views_hold_the_tables_they_replaced():
    """Each view is computed from the table (the module's name table is the function's value) and
    still holds the rows of the table it replaced, with the same values and order."""
    assert params.PARAM_FIELDS == pt.params_fields() and PARAM_FIELDS == pt.physics_fields()
    assert contact.PRM_FIELDS == pt.contact_columns() and terrain.PRM_FIELDS == pt.part_columns()
    assert _holds(params.PARAM_FIELDS, {
        "mass": ("rod", "kg", "positive"), "f": ("rod", "kg m", "finite"), "J": ("rod", "kg m^2", "positive"),
        "stiffness": ("string", "N/m", "nonnegative"), "damping": ("string", "N s/m", "nonnegative"),
        "rest_length": ("string", "m", "nonnegative"), "node_damping": ("node", "N s/m", "nonnegative"),
        "gravity": ("component", "m/s^2", "finite"), "anchor_pos": ("anchor", "m", "finite")})
    assert PARAM_FIELDS == tuple(params.PARAM_FIELDS)
    assert _holds(contact.PRM_FIELDS, ("radius", "stiffness", "damping", "exponent", "friction",
                                       "tangential_stiffness", "tangential_damping", "max_damping"))
    assert contact.PRM_FIELDS[-1] == "height" and terrain.PRM_FIELDS == contact.PRM_FIELDS[:-1]   # one layout
    assert _holds({k: (s.per, s.unit, s.absolute) for k, s in domain.SPECS.items()}, {
        "rod_mass": ("rod", "kg", False), "stiffness": ("string", "N/m", False),
        "damping": ("string", "N s/m", False), "node_damping": ("node", "N s/m", False),
        "gravity": ("vector", "m/s^2", False), "rest_length_offset": ("string", "m", True),
        "friction": ("copy", "", False), "ground_stiffness": ("copy", "N/m", False),
        "ground_damping": ("copy", "s/m", False), "max_cable_speed": ("actuated", "m/s", False),
        "max_cable_acceleration": ("copy", "m/s^2", False)})
    assert _holds(base._PHYSICS_FIELDS, {"rod_mass": "mass", "stiffness": "stiffness", "damping": "damping",
                                         "node_damping": "node_damping", "gravity": "gravity",
                                         "rest_length_offset": "rest_length"})
    assert _holds(roll.CONTACT_DOMAIN, {"friction": "friction", "ground_stiffness": "stiffness",
                                        "ground_damping": "damping"})
    assert _holds(roll._CONTACT_ARGS, {"stiffness": "ground_stiffness", "damping": "ground_damping",
                                       "radius": "cap_radius", "max_damping": "ground_max_damping"})
    assert _holds(twin_params.TWIN_PARAMS, ("damping", "friction", "gravity", "ground_damping", "ground_stiffness",
                                            "max_cable_acceleration", "max_cable_speed", "rest_length_offset",
                                            "rod_mass", "stiffness"))
    assert {"node_damping"} <= set(twin_params.NOT_REPRESENTABLE)


def test_every_row_reaches_its_container():
    """Step 1 of the doc: a row names a field its container has."""
    names = [r.name for r in pt.PARAMS]
    assert len(names) == len(set(names))
    from tensegrity_gym.core import builders, model as core_model
    nominal = core_model.compile_model(builders.prism(3)).nominal
    set_limits = inspect.signature(actuation.Actuation.set_copy_limits).parameters
    ground = {f.name for f in dataclasses.fields(GroundContact)}
    for r in pt.PARAMS:
        if r.group == "physics":       # a Params field, with one nominal row
            assert getattr(nominal, r.field).shape[0] == 1, r
        elif r.group == "contact":
            assert r.field in PRM_FIELDS and r.field in ground, r
            assert r.argument is None or r.argument in roll.RollTask.__signature__.parameters, r
        else:
            assert r.field in set_limits, r
            assert r.argument in roll.RollTask.__signature__.parameters, r


def test_every_env_parameter_has_a_twin_mapping_or_a_refusal():
    """Step 4 of the doc: the table refuses an env parameter that says nothing about the twin,
    and the twin's writer handles every name it claims to represent."""
    with pytest.raises(ValueError, match="needs exactly one of mujoco"):
        pt.ParamSpec("x", "contact", "friction", "scalar", "1", "positive", "doc", spread="relative")
    src = inspect.getsource(twin_params.TwinParams.apply)
    for name in twin_params.TWIN_PARAMS:
        assert pt.spec(name).group == "actuation" or f'"{name}"' in src, name


def test_bad_rows_are_refused():
    with pytest.raises(ValueError, match="axis must be one of"):
        pt.ParamSpec("x", "physics", "mass", "per_rod", "kg", "positive", "doc")
    with pytest.raises(ValueError, match="group must be one of"):
        pt.ParamSpec("x", "motor", "mass", "rod", "kg", "positive", "doc")
    with pytest.raises(KeyError, match="no parameter 'nope'"):
        pt.spec("nope")


@pytest.fixture
def radius_row(monkeypatch):
    """Step 4 of docs/adding_a_parameter.md: the cap radius (a contact column the kernels already
    read per copy) made an env parameter by its table row alone."""
    rows = tuple(dataclasses.replace(r, spread="relative", no_mujoco="the twin's capsule radius is fixed in "
                                                                     "its MJCF") if r.name == "cap_radius" else r
                 for r in pt.PARAMS)
    monkeypatch.setattr(pt, "PARAMS", rows)
    return rows


def test_an_added_row_shows_up_in_every_view(radius_row):
    assert "cap_radius" in pt.domain_specs() and pt.domain_specs()["cap_radius"].per == "copy"
    assert pt.env_fields("contact")["cap_radius"] == "radius"
    assert "cap_radius" in pt.twin_refusals() and "cap_radius" not in pt.twin_params()
    assert pt.contact_columns() == PRM_FIELDS            # the container itself is unchanged


def test_an_added_row_is_randomised_and_written_per_copy(radius_row):
    col = PRM_FIELDS.index("radius")
    env = gym.make_vec("TensegrityRoll-v0", num_envs=3, vectorization_mode="vector_entry_point",
                       randomize={"cap_radius": 0.2}, frame_skip=2)
    _, info = env.reset(seed=0)
    task = env.unwrapped.task if hasattr(env.unwrapped, "task") else env.task
    drawn = info["params"]["cap_radius"]
    assert drawn.shape == (3,) and len(set(drawn.tolist())) == 3
    assert np.all(np.abs(drawn / 0.02 - 1.0) <= 0.2)
    np.testing.assert_array_equal(task._contact_prm[:, col], drawn)
    env.step(np.zeros((3, task.action_size)))
    single = gym.make("TensegrityRoll-v0", params={"cap_radius": float(drawn[1])}, frame_skip=2)
    single.reset(seed=1)
    assert single.unwrapped.task._contact_prm[0, col] == drawn[1]
    with pytest.raises(ValueError, match=r"randomize\['cap_radius'\]: spread must be in \[0, 1\)"):
        gym.make("TensegrityRoll-v0", randomize={"cap_radius": 1.5})


@pytest.mark.skipif(not importlib.util.find_spec("torch"), reason="needs torch")
def test_an_added_row_reaches_the_torch_device_reset(radius_row):
    col = PRM_FIELDS.index("radius")
    env = gym.make_vec("TensegrityRoll-v0", num_envs=3, vectorization_mode="vector_entry_point", backend="torch",
                       device="cpu", dtype="float64", reset_sampling="device", randomize={"cap_radius": 0.2},
                       frame_skip=2)
    _, info = env.reset(seed=0)
    drawn = info["params"]["cap_radius"].cpu().numpy()
    assert len(set(drawn.tolist())) == 3
    np.testing.assert_array_equal(env._contact_prm[:, col].cpu().numpy(), drawn)


@pytest.mark.skipif(not importlib.util.find_spec("mujoco"), reason="needs mujoco")
def test_an_added_row_is_refused_by_the_twin_with_its_reason(radius_row):
    with pytest.raises(ValueError, match=r"randomize\['cap_radius'\]: TensegrityRollMuJoCo-v0 cannot represent it "
                                         r"\(the twin's capsule radius"):
        gym.make("TensegrityRollMuJoCo-v0", randomize={"cap_radius": 0.1})


def _functions(path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node


def test_envs_have_no_function_local_package_imports_and_no_long_signatures():
    """No import cycle inside envs/ dodged by an import inside a function (optional dependencies
    such as the renderers stay lazy), and no function with more than 20 parameters."""
    lazy_ok = {"tools.rendering", "load_structure"}
    for path in sorted(ENVS.glob("*.py")):
        for fn in _functions(path):
            a = fn.args
            n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
            assert n <= 20, f"{path.name}:{fn.name} takes {n} parameters"
            for node in ast.walk(fn):
                if isinstance(node, ast.ImportFrom) and node.level > 0:
                    names = {node.module or ""} | {x.name for x in node.names}
                    assert names & lazy_ok, f"{path.name}:{fn.name} imports {node.module} inside a function"


def test_grouped_config_equals_the_flat_arguments():
    from tensegrity_gym.envs.config import roll_config, shape_config
    cfg = roll_config()
    cfg = dataclasses.replace(cfg, contact=dataclasses.replace(cfg.contact, friction=0.7),
                              simulation=dataclasses.replace(cfg.simulation, frame_skip=5))
    a = roll.RollTask(config=cfg, dt=5e-4)
    b = roll.RollTask(friction=0.7, frame_skip=5, dt=5e-4)
    assert a.config == b.config and a.contact == b.contact and a.frame_skip == b.frame_skip == 5
    assert a.dt == 5e-4
    with pytest.raises(TypeError, match=r"RollTask.__init__\(\) got an unexpected keyword argument 'frictoin'"):
        roll.RollTask(frictoin=0.7)
    from tensegrity_gym.envs.shape import ShapeTask
    with pytest.raises(TypeError, match=r"ShapeTask.__init__\(\) got an unexpected keyword argument 'fricton'"):
        ShapeTask(fricton=0.7)
    flat = set(inspect.signature(roll.RollTask).parameters) - {"num_envs", "config"}
    assert len(flat) == 38 and {"cap_radius", "history", "reset_noise_scale", "rod_contact", "terrain",
                                 "terrain_difficulty"} <= flat
    assert len(set(inspect.signature(ShapeTask).parameters) - {"num_envs", "config"}) == 29
    assert shape_config().randomization.reset_noise_scale == 5e-3


@pytest.mark.skipif(not importlib.util.find_spec("mujoco"), reason="needs mujoco")
def test_twin_checks_a_grouped_config_as_the_flat_arguments():
    from tensegrity_gym.envs.config import roll_config
    cfg = roll_config()
    cfg = dataclasses.replace(cfg, actuation=dataclasses.replace(cfg.actuation, action_delay=2))
    with pytest.raises(ValueError, match=r"action_delay: not supported by TensegrityRollMuJoCo-v0"):
        gym.make("TensegrityRollMuJoCo-v0", config=cfg)
    with pytest.raises(TypeError, match=r"unexpected keyword argument 'frictoin'"):
        gym.make("TensegrityRollMuJoCo-v0", frictoin=0.5)


@pytest.mark.parametrize("env_id", ["TensegrityRoll-v0", "TensegrityShape-v0"])
def test_config_of_another_type_is_named(env_id):
    from tensegrity_gym.envs.config import roll_config
    with pytest.raises(ValueError, match=r"config: expected a (Roll|Shape)Config"):
        gym.make(env_id, config={"dt": 1e-3})
    if env_id == "TensegrityShape-v0":
        with pytest.raises(ValueError, match=r"config: expected a ShapeConfig"):
            gym.make(env_id, config=roll_config())


def test_the_manuals_name_every_env_parameter():
    """The user docs of the robot parameters (envs/domain.py) and of the twin's mapping
    (envs/twin_params.py) list every env parameter of the table."""
    for name in pt.env_params():
        assert f"``{name}``" in domain.__doc__, name
        assert f"``{name}``" in twin_params.__doc__, name
