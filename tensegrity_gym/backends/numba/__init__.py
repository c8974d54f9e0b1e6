"""The numba backend: compiled loops over one packed float64 buffer per model.

Modules: ``layout`` (buffer layout, flag bits, error codes), ``equations`` (rod accelerations,
string forces, projection, great-circle drift), ``contact`` (ground-contact forces),
``driver`` (the one loop driver and its compiled instances), ``entries`` (the compiled entry
kernels with their explicit signatures), ``pack`` (packing a model or a ``Params`` into
buffers), ``compile`` (threading layer, compile-once management), ``api`` (the Python entry
points ``step``, ``step_inplace``, ``accelerations``, ``string_forces``, ``project``,
``contact_steps``), ``plans`` (``Plan``, ``make_plan``, ``lean_plan``, ``packed``: a fixed-step
call prepared once and repeated), ``actuation`` (compiled control updates) and ``divergence``.
numba's on-disk cache does not notice edits of kernels inlined into kernels of another module:
after editing one run ``find tensegrity_gym -name '*.nbi' -o -name '*.nbc' | xargs rm -f``.
``watch`` prints progress on stderr while numba compiles this package's functions.
"""
from .watch import install as _install_watch

_install_watch()
