"""The architecture doc's module map lists every module of the package (scripts/tools/module_map.py)."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_module_map_is_current():
    r = subprocess.run([sys.executable, "-m", "scripts.tools.module_map", "--check"], capture_output=True,
                       text=True, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr


def test_backend_registry_names_every_backend_subpackage():
    from tensegrity_gym.physics.backends import BACKENDS, get_backend
    subpackages = {p.name for p in (ROOT / "tensegrity_gym" / "backends").iterdir()
                   if (p / "__init__.py").exists()}
    assert set(BACKENDS) == subpackages
    assert get_backend("auto") is BACKENDS["numba"]
