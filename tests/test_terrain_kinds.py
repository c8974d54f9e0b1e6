"""The table of terrain kinds and the worked example of docs/terrain.md ("Adding a terrain kind"): a
small example kind, a vertical cylinder defined here, registered in the table; every consumer of a
terrain either handles it (the file reader, the NumPy geometry, the CLI's contact overrides) or
refuses it with an error naming the kind (the numba and torch backends, the MJCF writer and so the
MuJoCo twin and renderer, the matplotlib and browser renderers, the JSON Schema). A kind code of no
kind in a ``geom`` array is refused before the numba kernel runs."""
from __future__ import annotations

import json
import types
from dataclasses import dataclass

import numpy as np
import pytest

from tensegrity_gym.core import terrain_kinds as TK
from tensegrity_gym.core.terrain import SCHEMA_PATH, Box, Plane, Terrain


@dataclass(frozen=True, eq=False)
class Cylinder(TK.SurfaceContact):
    """A solid vertical cylinder standing on z = 0: axis at ``center`` (x, y) m, ``radius`` m,
    ``height`` m."""

    center: np.ndarray
    radius: float
    height: float

    def __post_init__(self):
        s = object.__setattr__
        s(self, "center", TK._vector(self.center, 2, "center"))
        s(self, "radius", TK._number(self.radius, "radius", lo=0.0, lo_open=True))
        s(self, "height", TK._number(self.height, "height", lo=0.0, lo_open=True))
        TK._surface(self)

    def closest(self, p):
        """Signed distance (m) of ``p`` (..., 3) m and the outward normal."""
        dx, dy = p[..., 0] - self.center[0], p[..., 1] - self.center[1]
        rho = np.hypot(dx, dy)
        qr, qz = rho - self.radius, np.abs(p[..., 2] - self.height / 2) - self.height / 2
        with np.errstate(invalid="ignore", divide="ignore"):
            ux, uy = np.where(rho > 0, dx / rho, 1.0), np.where(rho > 0, dy / rho, 0.0)
        sz = np.where(p[..., 2] >= self.height / 2, 1.0, -1.0)
        out_r, out_z = np.maximum(qr, 0.0), np.maximum(qz, 0.0)
        dout = np.hypot(out_r, out_z)
        side = qr > qz
        d = np.where(dout > 0, dout, np.maximum(qr, qz))
        nr = np.where(dout > 0, out_r / np.where(dout > 0, dout, 1.0), side * 1.0)
        nz = np.where(dout > 0, out_z / np.where(dout > 0, dout, 1.0), (~side) * 1.0) * sz
        return d, np.stack([nr * ux, nr * uy, nz], axis=-1)

    def top(self, x, y):
        """Height (m) of the top at (x, y) m, -inf beside the cylinder."""
        inside = np.hypot(x - self.center[0], y - self.center[1]) <= self.radius
        return np.where(inside, self.height, -np.inf)


CYLINDERS = {"cylinders": [{"center": [0.5, 0.0], "radius": 0.1, "height": 0.2, "friction": 0.4}]}


@pytest.fixture
def cylinder():
    """The example kind registered in the table (removed again after the test)."""
    kind = TK.register(TK.TerrainKind("cylinder", Cylinder, "cylinders", True, ("center", "radius", "height"),
                                      ("center", "radius", "height")))
    yield kind
    del TK.KINDS[kind.name]


def _terrain():
    return Terrain.from_dict({"plane": {"slope_deg": 0.0}, **CYLINDERS})


def test_table_holds_the_built_in_kinds():
    assert list(TK.KINDS) == ["plane", "box", "heightfield"]
    assert TK.kind_of(Plane()).key == "plane"
    assert TK.kind_of(Box([0, 0, 0], [1, 1, 1])).many
    with pytest.raises(ValueError, match="already registered"):
        TK.register(TK.TerrainKind("plane", Cylinder, "cylinders", True, ()))


def test_unregistered_kind_is_an_error():
    with pytest.raises(ValueError, match="unknown key 'cylinders'"):
        Terrain.from_dict(CYLINDERS)
    with pytest.raises(ValueError, match="terrain part Cylinder: not a terrain kind"):
        Terrain(extra=(Cylinder([0, 0], 0.1, 0.2),))


def test_file_reader_and_geometry_handle_a_registered_kind(cylinder):
    t = _terrain()
    (c,) = t.extra
    assert isinstance(c, Cylinder) and c.friction == 0.4 and t.parts() == [t.plane, c]
    assert t.height_at([0.5, 0.0], [0.0, 0.0]).tolist() == [0.2, 0.0]
    d, n = t.closest(np.array([[0.5, 0.0, 0.3], [0.7, 0.0, 0.15]]))
    assert np.allclose(d, [0.1, 0.1]) and np.allclose(n, [[0, 0, 1], [1, 0, 0]])
    with pytest.raises(ValueError, match=r"cylinders\[0\]: missing required key 'height'"):
        Terrain.from_dict({"cylinders": [{"center": [0, 0], "radius": 1}]})
    with pytest.raises(ValueError, match=r"cylinders\[0\]\.radius: must be > 0"):
        Terrain.from_dict({"cylinders": [{"center": [0, 0], "radius": -1, "height": 1}]})
    assert Terrain.from_parts(t.parts(), friction=0.7) == Terrain(plane=t.plane, extra=t.extra, friction=0.7)


def test_cli_contact_overrides_handle_a_registered_kind(cylinder):
    from tensegrity_gym.tools.cli_terrain import with_contact
    t = with_contact(_terrain(), friction=0.9)
    assert t.friction == 0.9 and t.extra[0].friction is None and t.extra[0].radius == 0.1


def test_schema_lists_every_kind(cylinder):
    """The JSON Schema is a document: a kind missing from it is named here."""
    props = json.loads(SCHEMA_PATH.read_text())["properties"]
    assert [k.name for k in TK.KINDS.values() if k.key not in props] == ["cylinder"]


def test_numba_backend_refuses_the_kind(cylinder):
    from tensegrity_gym.physics.terrain import TerrainContact
    with pytest.raises(ValueError, match="terrain kind 'cylinder': the numba backend"):
        TerrainContact(_terrain())


def test_mjcf_writer_and_twin_refuse_the_kind(cylinder):
    import tensegrity_gym as tg
    from tensegrity_gym.io.mjcf import TERRAIN_GEOMS, terrain_xml, to_mjcf
    with pytest.raises(ValueError, match="terrain kind 'cylinder': the MJCF writer"):
        to_mjcf(tg.build("prism3"), terrain=_terrain())
    # a row of its own makes it a MuJoCo cylinder
    TERRAIN_GEOMS["cylinder"] = lambda c, i, attrs: ([], [
        f'    <geom name="terrain_cylinder{i}" type="cylinder" size="{c.radius} {c.height / 2}" '
        f'pos="{c.center[0]} {c.center[1]} {c.height / 2}" {attrs}/>'])
    try:
        assert 'type="cylinder"' in terrain_xml(_terrain())[1][1]
    finally:
        del TERRAIN_GEOMS["cylinder"]
    # the MuJoCo twin's scene is the MJCF writer's
    from tensegrity_gym.envs import twin_terrain
    assert twin_terrain.floor_height(_terrain()) is None


def test_renderers_refuse_the_kind(cylinder):
    pytest.importorskip("matplotlib")
    from tensegrity_gym.tools.rendering import browser_viewer, matplotlib_renderer
    with pytest.raises(ValueError, match="terrain kind 'cylinder': the matplotlib renderer"):
        matplotlib_renderer.Renderer()._draw_terrain(_terrain())
    calls = []
    scene = types.SimpleNamespace(add_grid=lambda *a, **k: calls.append("plane"))
    viewer = types.SimpleNamespace(nodes=np.zeros((1, 3, 3)))
    with pytest.raises(ValueError, match="terrain kind 'cylinder': the browser viewer"):
        browser_viewer.BrowserViewer._add_terrain(viewer, scene, _terrain(), 1.0)
    assert calls == ["plane"]


def test_unknown_kind_code_is_refused_before_the_numba_kernel(monkeypatch):
    import tensegrity_gym as tg
    from tensegrity_gym.physics import terrain as T

    def kernel(*args):
        raise AssertionError("the kernel ran on an unknown kind code")
    m = tg.compile_model(tg.build("prism3"))
    tc = T.TerrainContact(Terrain(boxes=[Box([0, 0, 0], [1, 1, 1])]))
    ts = T.init_terrain_state(tc, m, 1)
    st = tg.initial_state(m, 1)
    geom = tc.geom.copy()
    geom[0, 1, 0] = 7.0
    monkeypatch.setattr(T, "terrain_forces_kernel", kernel)
    with pytest.raises(ValueError, match=r"geom\[0, 1, 0\]: unknown terrain kind code 7\.0"):
        T.contact_forces(tc, m, st.q, st.qd, ts, geom=geom)
    with pytest.raises(ValueError, match=r"geom\[0, 1, 0\]: unknown terrain kind code 7\.0"):
        T.step(m, st, 1e-3, tc, ts, geom=geom)
    with pytest.raises(ValueError, match=r"geom\[0, 1, 0\]: unknown terrain kind code 7\.0"):
        T.advance(tc, m, st.q.copy(), st.qd.copy(), 1e-3, "semi_implicit_euler", ts.copy(), geom=geom,
                  compiled=False)


def test_torch_backend_refuses_an_unknown_kind_code():
    torch = pytest.importorskip("torch")
    import tensegrity_gym as tg
    from tensegrity_gym.backends.torch import terrain as TT
    from tensegrity_gym.backends.torch.terrain_kinds import top_height
    from tensegrity_gym.physics.terrain import TerrainContact
    m = tg.compile_model(tg.build("prism3"))
    tc = TerrainContact(Terrain(boxes=[Box([0, 0, 0], [1, 1, 1])]))
    geom = tc.geom.copy()
    geom[0, 1, 0] = 7.0
    with pytest.raises(ValueError, match=r"geom\[:, 1, 0\]: unknown terrain kind code 7\.0"):
        TT.terrain_layout(geom, tc.prm, m)
    x = torch.zeros((1, 2), dtype=torch.float64)
    with pytest.raises(ValueError, match="unknown terrain kind code 7.0"):
        top_height(torch.as_tensor(geom), None, x, x)
    assert top_height(torch.as_tensor(tc.geom.copy()), None, x, x).tolist() == [[0.5, 0.5]]
    assert top_height(torch.as_tensor(tc.geom.copy()), None, x + 3, x).tolist() == [[0.0, 0.0]]
