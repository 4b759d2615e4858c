"""Vectors of either dimension as tuples of per-component scalars, for kernels
written once for disks (d = 2) and spheres (d = 3).

A law's per-pair kernel is vmapped over the slots, so every scalar here is an
`[n, k]` array: written component by component, XLA on CPU fuses the kernel
into one loop and computes shared scalars (r, F_n) once (benchmarks/
profile_step.py). These helpers keep that form for any d with static Python
loops, and for d = 2 they perform the very operations, in the very order, of
the component-wise 2D kernels they replaced, so 2D results are bit-identical.

A spin is a number for a disk (about z) and a 3-tuple for a sphere;
`spin_cross` and `cross` return the same kinds: the cross product of two
in-plane vectors is the number `a_x b_y - a_y b_x` (its z component).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

Array = Any


def components(a) -> tuple:
    """The `[d]` vector `a` (under vmap) as a tuple of d scalars."""
    return tuple(a[k] for k in range(a.shape[0]))


def dot(a: tuple, b: tuple):
    """a . b: a_0 b_0 + a_1 b_1 [+ a_2 b_2]."""
    total = a[0] * b[0]
    for x, y in zip(a[1:], b[1:]):
        total = total + x * y
    return total


def cross(a: tuple, b: tuple):
    """a x b: a number (the z component) for two 2-vectors, a 3-tuple for 3-vectors."""
    if len(a) == 2:
        return a[0] * b[1] - a[1] * b[0]
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def spin_cross(w, n: tuple) -> tuple:
    """w x n for a spin w (a number about z for disks, a 3-tuple for spheres)."""
    if len(n) == 2:
        return (-w * n[1], w * n[0])  # z x n = (-n_y, n_x)
    return cross(w, n)


def scale(c, a):
    """c a for a vector (tuple) or a number."""
    return tuple(c * x for x in a) if isinstance(a, tuple) else c * a


def pack(a):
    """A vector (tuple) stacked into one `[d]` array; a number as it is."""
    return jnp.stack(a) if isinstance(a, tuple) else a


def spin_dim(w) -> int:
    """How many components a spin has: 1 (a disk's number) or 3."""
    return len(w) if isinstance(w, tuple) else 1


__all__ = ["components", "cross", "dot", "pack", "scale", "spin_cross", "spin_dim"]
