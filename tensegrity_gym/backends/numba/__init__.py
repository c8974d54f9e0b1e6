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
inlines or calls from others: ``cache_guard`` adds to each cached function's stamp the digest
of its module and of every module of the package that one imports, so a kernel compiles again
exactly when one of those changed (the parameter table, whose packed layout the kernels freeze,
is in the closure of ``layout``); it is installed at this import, which ``tensegrity_gym``
runs before any module that compiles. ``watch`` prints progress on stderr while numba compiles
this package's functions.
"""
from .cache_guard import install as _install_cache_guard
from .watch import install as _install_watch

_install_cache_guard()
_install_watch()
