"""Flat walls and gravity (run-time values in `state.Boundaries`).

A wall is the half-plane `normal . x >= offset` (a half-space in 3D). It is a contact partner of zero
radius and infinite mass (the rule of Lee & Herrmann 1993, sec. 2), evaluated with
the same contact law as a disk pair, so every law works against every wall.
"""

from __future__ import annotations

import math

import jax
import numpy as np

from jaxpile.errors import InputError
from jaxpile.engine import transfer
from jaxpile.engine.state import Boundaries

GROUND, LEFT_WALL, RIGHT_WALL = 0, 1, 2
FRONT_WALL, BACK_WALL = 3, 4
"""In 3D (`make_boundaries(dim=3)`): the walls normal to y, after the ground (z) and the x walls."""


def make_boundaries(
    *,
    left: float | None = None,
    right: float | None = None,
    ground: float = 0.0,
    gravity: float = 1.0,
    tilt_degrees: float = 0.0,
    sides: bool = True,
    front: float | None = None,
    back: float | None = None,
    dim: int = 2,
    dtype=None,
) -> Boundaries:
    """The ground y = `ground` plus a left and a right wall; in 3D (`dim=3`) the
    ground z = `ground`, the walls x = `left`, `right` and y = `front`, `back`.

    Args:
      left, right: x positions of the side walls; `None` creates the wall
        switched off (it can be switched on at run time with `set_wall`).
      ground: height of the ground.
      gravity: magnitude g.
      tilt_degrees: gravity rotated by this angle (counter-clockwise) from -y,
        which is the same as tilting the whole set-up clockwise.
      sides: False gives the ground alone (one wall, no side-wall slots): for a
        pile that never meets a side wall. Every disk is checked against every
        wall slot at every step, switched on or not, so two unused slots cost
        about a fifth of a step (measured on the 1992 lattice pile).
      front, back: in 3D, the y positions of the walls normal to y (`None`: off).
      dim: 2 (disks in the x, y plane, gravity along -y) or 3 (spheres,
        gravity along -z).
    """
    if dim not in (2, 3):
        raise InputError(f"dim must be 2 or 3; got {dim!r}.")
    if left is not None and right is not None and not left < right:
        raise InputError(f"the left wall (x = {left}) must be left of the right wall (x = {right}).")
    if not (gravity >= 0 and math.isfinite(gravity)):
        raise InputError(f"gravity must be a finite magnitude >= 0; got {gravity}.")
    if not sides and (left is not None or right is not None or front is not None or back is not None):
        raise InputError("sides=False makes the ground alone: side walls cannot be given.")
    dtype = transfer.default_float() if dtype is None else dtype
    if dim == 3:
        return _boundaries_3d(left, right, front, back, ground, gravity, tilt_degrees, sides, dtype)
    if front is not None or back is not None:
        raise InputError("front and back walls are for spheres (dim=3): disks move in the x, y plane.")
    if not sides:
        return Boundaries(gravity=gravity_vector(gravity, tilt_degrees, dtype),
                          wall_normal=transfer.to_device([[0.0, 1.0]], dtype),
                          wall_offset=transfer.to_device([ground], dtype),
                          wall_active=transfer.to_device([True]))
    normal = transfer.to_device([[0.0, 1.0], [1.0, 0.0], [-1.0, 0.0]], dtype)
    offset = transfer.to_device([ground, 0.0 if left is None else left, 0.0 if right is None else -right], dtype)
    active = transfer.to_device([True, left is not None, right is not None])
    return Boundaries(
        gravity=gravity_vector(gravity, tilt_degrees, dtype),
        wall_normal=normal,
        wall_offset=offset,
        wall_active=active,
    )


def _boundaries_3d(left, right, front, back, ground, gravity, tilt_degrees, sides, dtype) -> Boundaries:
    """`make_boundaries(dim=3)`: the ground z = `ground` (wall 0), then the
    walls normal to x (1, 2) and to y (3, 4), each off where not given."""
    if front is not None and back is not None and not front < back:
        raise InputError(f"the front wall (y = {front}) must be in front of the back wall (y = {back}).")
    g = gravity_vector(gravity, tilt_degrees, dtype, dim=3)
    if not sides:
        return Boundaries(gravity=g, wall_normal=transfer.to_device([[0.0, 0.0, 1.0]], dtype),
                          wall_offset=transfer.to_device([ground], dtype), wall_active=transfer.to_device([True]))
    normal = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]
    offset = [ground, 0.0 if left is None else left, 0.0 if right is None else -right,
              0.0 if front is None else front, 0.0 if back is None else -back]
    active = [True, left is not None, right is not None, front is not None, back is not None]
    return Boundaries(gravity=g, wall_normal=transfer.to_device(normal, dtype),
                      wall_offset=transfer.to_device(offset, dtype), wall_active=transfer.to_device(active))


def gravity_vector(g: float, tilt_degrees: float, dtype=None, *, dim: int = 2):
    """`[2]` gravity of magnitude g, rotated counter-clockwise by `tilt_degrees`
    from -y; in 3D `[3]`, from -z towards +x (the set-up tilted about y)."""
    t = math.radians(tilt_degrees)
    if dim == 3:
        return transfer.to_device([g * math.sin(t), 0.0, -g * math.cos(t)], dtype)
    return transfer.to_device([g * math.sin(t), -g * math.cos(t)], dtype)


def set_wall(boundaries: Boundaries, wall: int, *, active: bool | None = None, position=None) -> Boundaries:
    """Switches a wall on or off and/or moves an axis-aligned wall to `position`
    (x for a side wall, y for the ground). Pure: usable inside jit."""
    b = boundaries
    if not 0 <= wall < b.wall_active.shape[0]:  # an index out of range would be clamped silently
        raise InputError(f"wall {wall} does not exist: these boundaries have {b.wall_active.shape[0]} wall(s)"
                         " (made with sides=False?).")
    if active is not None:
        b = b.set(wall_active=_set_entry(b.wall_active, wall, active))
    if position is not None:
        normal = (b.wall_normal if isinstance(b.wall_normal, jax.core.Tracer) else np.asarray(b.wall_normal))[wall]
        # offset = normal . (point on the wall); for an axis-aligned normal that
        # is (n_x + n_y [+ n_z]) * position
        along = normal[0] + normal[1]
        for k in range(2, normal.shape[0]):
            along = along + normal[k]
        b = b.set(wall_offset=_set_entry(b.wall_offset, wall, along * position))
    return b


def _set_entry(array, index: int, value):
    """`array.at[index].set(value)`; on the host when nothing is traced (an
    eager scatter would compile a program per shape)."""
    if any(isinstance(x, jax.core.Tracer) for x in (array, value)):
        return array.at[index].set(value)
    host = np.array(array)
    host[index] = np.asarray(value)
    return transfer.to_device(host)


def wall_distance(boundaries: Boundaries, position):
    """`[n, w]` signed distance of each centre from each wall plane (positive inside)."""
    return position @ boundaries.wall_normal.T - boundaries.wall_offset[None, :]
