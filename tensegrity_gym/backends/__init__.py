"""Backends: the same equations, written once per array library.

``numba`` (the package's CPU implementation, compiled loops over packed buffers) and ``torch``
(tensors on any device, batched). Both subpackages use the same module names where they
implement the same thing: ``equations`` (the book's equations), ``driver`` (the stepping loop),
``contact``, ``actuation``, ``divergence``, ``api`` (the entry points the physics layer calls).
:func:`tensegrity_gym.physics.step` picks one by its ``backend`` argument
(:func:`tensegrity_gym.core.integrators.numba_backend`).
"""
