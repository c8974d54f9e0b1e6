"""The numba backend: compiled loops over one packed float64 buffer per model.

Modules: ``layout`` (buffer layout, flag bits, error codes), ``equations`` (rod accelerations,
string forces, projection, great-circle drift), ``contact`` (ground-contact forces),
``driver`` (the one loop driver and its compiled instances), ``entries`` (the compiled entry
kernels with their explicit signatures), ``pack`` (packing a model or a ``Params`` into
buffers), ``compile`` (threading layer, compile-once management), ``api`` (the Python entry
points ``step``, ``step_inplace``, ``accelerations``, ``string_forces``, ``project``,
``contact_steps``), ``plans`` (``Plan``, ``make_plan``, ``lean_plan``, ``packed``: a fixed-step
call prepared once and repeated), ``actuation`` (compiled control updates) and ``divergence``.
numba's on-disk cache notices an edit of a kernel's own module only, not of the kernels it
inlines or calls from others: ``cache_guard`` drops the package's caches when any of its
compiled sources changed, at this import, before any kernel is loaded, and
``layout.check_compiled_layout`` drops them when the parameter table's packed layout (numba
globals the kernels freeze) differs from the cached kernels'. ``watch`` prints progress on
stderr while numba compiles this package's functions.
"""
from . import cache_guard as _cache_guard
from .layout import check_compiled_layout as _check_compiled_layout
from .watch import install as _install_watch


def _drop_all_caches():
    """Delete the package's numba disk caches (their stamps first, so the guard finds them stale)."""
    for f in _cache_guard.SOURCES:
        d = _cache_guard._cache_dir(_cache_guard._PACKAGE / f)
        try:
            if d is not None:
                (d / _cache_guard.STAMP).unlink(missing_ok=True)
        except OSError:         # a directory that cannot be written is left as it is (as the guard does)
            pass
    _cache_guard.drop_stale_caches()


_cache_guard.drop_stale_caches()
_check_compiled_layout(_drop_all_caches)
_install_watch()
