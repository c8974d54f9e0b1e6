"""The numba cache guard: a change of any compiled source drops the package's cached kernels
(numba itself notices an edit of a kernel's own module only)."""
from pathlib import Path

import tensegrity_gym
from tensegrity_gym.backends.numba import cache_guard as G

PACKAGE = Path(tensegrity_gym.__file__).parent


def test_every_module_with_numba_functions_is_guarded():
    compiled = {p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py")
                if "njit(" in p.read_text() and p.name != "cache_guard.py"}
    assert compiled == set(G.SOURCES)


def test_the_package_caches_carry_the_digest_of_the_sources():
    digest = G.sources_digest([PACKAGE / f for f in G.SOURCES])
    dirs = {G._cache_dir(PACKAGE / f) for f in G.SOURCES} - {None}
    assert dirs
    for d in dirs:
        assert (d / G.STAMP).read_text().strip() == digest


def test_a_changed_source_drops_the_caches_of_every_guarded_module(tmp_path):
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("x = 1\n")
    b.write_text("y = 1\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()

    def fill():
        names = ["a.f-3.py311.nbi", "a.f-3.py311.0.nbc", "b.g-1.py311.nbi", "other.h-2.py311.nbi"]
        for name in names:
            (cache / name).write_bytes(b"")
        return names

    def run():
        return sorted(p.name for p in G.drop_stale_caches([a, b], cache_dir=lambda f: cache))

    fill()
    # no stamp yet: caches of unknown sources are dropped, another module's are kept
    assert run() == ["a.f-3.py311.0.nbc", "a.f-3.py311.nbi", "b.g-1.py311.nbi"]
    assert (cache / "other.h-2.py311.nbi").exists()
    fill()
    assert run() == []                      # the same sources: the caches stay
    b.write_text("y = 2\n")                 # an edit of b drops a's kernels too (they may inline b's)
    assert run() == ["a.f-3.py311.0.nbc", "a.f-3.py311.nbi", "b.g-1.py311.nbi"]
    assert (cache / G.STAMP).read_text().strip() == G.sources_digest([a, b])


def test_an_unwritable_or_missing_cache_directory_is_left_alone(tmp_path):
    a = tmp_path / "a.py"
    a.write_text("x = 1\n")
    assert G.drop_stale_caches([a], cache_dir=lambda f: tmp_path / "missing") == []
    assert G.drop_stale_caches([a], cache_dir=lambda f: None) == []
    assert G.drop_stale_caches([tmp_path / "gone.py"], cache_dir=lambda f: tmp_path) == []
