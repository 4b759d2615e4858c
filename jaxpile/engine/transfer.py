"""Host values onto the device without compiling anything.

`jnp.asarray` of a numpy array compiles a small copy program (`stage`) for
every new shape and dtype, and `jnp.zeros` a `broadcast_in_dim` and a
`convert_element_type`: each costs milliseconds with its tracing, and setting
up a pile of a new size would run dozens of them
(docs/choices.md#eager-compiles). `jax.device_put` of a numpy array compiles nothing. On a CPU it may alias the
numpy buffer, so `to_device` hands it a private copy: a caller's array edited
later never reaches the pile.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


def default_float():
    """JAX's default float dtype (float64 once `jaxpile.configure()` has run), found
    without running anything (`jnp.zeros(()).dtype` compiles two programs)."""
    return jax.dtypes.canonicalize_dtype(np.float64)


def to_device(x: Any, dtype=None) -> jax.Array:
    """`jnp.asarray(x, dtype)` without a compile: a device array is returned as
    it is (converted if `dtype` differs), a tracer, or a Python scalar without
    a dtype, goes to `jnp.asarray`, and anything else on the host (a numpy
    array or scalar, a list, a Python scalar given a dtype) is copied and put
    on the device."""
    if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x)):  # a list may hold one
        return jnp.asarray(x, dtype)
    if isinstance(x, (bool, int, float, complex)) and dtype is None:
        return jnp.asarray(x)  # weakly typed, as jnp makes it (one compile per dtype and process)
    if isinstance(x, jax.Array) and (dtype is None or x.dtype == jnp.dtype(dtype)):
        return x
    host = np.array(x, dtype=dtype)  # a copy, whatever x is
    if dtype is None and host.dtype != jax.dtypes.canonicalize_dtype(host.dtype):
        host = host.astype(jax.dtypes.canonicalize_dtype(host.dtype))  # as jnp.asarray would (x64 off)
    return jax.device_put(host)


def zeros(shape, dtype) -> jax.Array:
    """`jnp.zeros(shape, dtype)` without a compile."""
    return jax.device_put(np.zeros(shape, dtype))


def full(shape, value, dtype) -> jax.Array:
    """`jnp.full(shape, value, dtype)` without a compile."""
    return jax.device_put(np.full(shape, value, dtype))


__all__ = ["default_float", "to_device", "zeros", "full"]
