"""The cylinder lift (the DEM calibration test): a cylinder of fixed spheres on
a rough plate is filled, the fill settles, the driver raises the cylinder until
it clears the spheres, and the heap left behind is measured as the cone is."""

import numpy as np
import pytest

from jaxpile.errors import InputError
from jaxpile.protocols import lift

OPTIONS = dict(cylinder_radius=2.5, max_fill_steps=60_000, max_settle_steps=100_000)
LAW = dict(law_options={"rolling": "sds"}, params={"k_roll": 5.0e3, "mu_roll": 0.2})


@pytest.fixture(scope="module")
def lifted():
    return lift.SPEC.run("hooke", 60, seed=1, progress=False, **LAW, **OPTIONS)


def test_the_set_up_is_a_plate_a_closed_cylinder_and_a_loose_fill_inside():
    p = lift.SPEC.set_up("hooke", 60, seed=0, **OPTIONS)
    rows, walls = p.info["n_base"], p.info["n_cylinder"]
    x = np.asarray(p.particles.position)
    assert np.asarray(p.particles.fixed)[:rows + walls].all() and not np.asarray(p.particles.fixed)[rows + walls:].any()
    np.testing.assert_allclose(np.hypot(x[rows:rows + walls, 0], x[rows:rows + walls, 1]), 2.5)
    inside = x[rows + walls:]
    assert np.hypot(inside[:, 0], inside[:, 1]).max() <= 1.5 + 0.2 and inside[:, 2].min() > 1.0
    d = np.linalg.norm(inside[:, None] - inside[None], axis=-1) + 9 * np.eye(len(inside))
    assert d.min() > 1.0  # the fill starts apart
    ring = x[rows:rows + walls][np.isclose(x[rows:rows + walls, 2], x[rows:rows + walls, 2].min())]
    gaps = np.linalg.norm(ring[:, None] - ring[None], axis=-1) + 9 * np.eye(len(ring))
    assert gaps.min(1).max() < 1.05  # a ring's spheres touch: no sphere passes between them
    with pytest.raises(InputError, match="cylinder_radius"):
        lift.SPEC.set_up("hooke", 10, cylinder_radius=1.5 - 1e-3)


def test_the_cylinder_rises_once_the_fill_rests_and_leaves_a_heap(lifted):
    state, m = lifted
    ls = state.protocol_state
    assert m["at_rest"] and m["counts"]["lost"] == 0 and bool(ls.done)
    assert 0 < m["lift_started_at"] < m["phases"]["fill and lift"]
    # the cylinder went up by what it rose, its bottom a diameter above the highest sphere
    rows, walls = m["info"]["n_base"], m["info"]["n_cylinder"]
    z = np.asarray(state.particles.position)[:, 2]
    assert z[rows:rows + walls].min() == pytest.approx(1.5 + float(ls.risen), abs=1e-9)
    assert z[rows:rows + walls].min() - 0.5 > (z + np.asarray(state.particles.radius))[rows + walls:].max() + 0.99
    assert abs(m["base_load"] / m["weight"] - 1.0) < 1e-3  # the plate carries the heap, the cylinder nothing
    assert 5.0 < m["angle_height_base"] < 45.0 and m["base_radius"] > 2.5  # the fill spread out of the cylinder
