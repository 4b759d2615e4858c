"""The cone (spheres poured from a narrow source onto a rough plate: Smid &
Novosad's experiment in 3D): its set-up, a small heap at rest whose plate
carries its weight, the measurements a person reads off it, and a resume bit
for bit from its checkpoint."""

import glob
import math
import os

import jax
import numpy as np
import pytest

from jaxpile.errors import InputError
from jaxpile.measure import cone_heap
from jaxpile.protocols import cone

N = 40
OPTIONS = dict(release_height=8.0, insert_height=6.5, interval=0.7, max_settle_steps=120_000)
LAW = dict(law_options={"rolling": "sds"}, params={"k_roll": 5.0e3, "mu_roll": 0.2})


@pytest.fixture(scope="module")
def heap(tmp_path_factory):
    """A 40-sphere cone with rolling resistance, checkpointed every 20,000 steps."""
    folder = tmp_path_factory.mktemp("cone")
    state, measured = cone.SPEC.run("hooke", N, seed=3, checkpoint=(str(folder / "ck-{step}.npz"), 20_000),
                                    progress=False, **LAW, **OPTIONS)
    return folder, state, measured


def test_the_set_up_is_a_plate_a_source_and_spheres_parked_above():
    p = cone.SPEC.set_up("hooke", N, seed=0, **OPTIONS)
    rows = p.info["n_base"]
    x = np.asarray(p.particles.position)
    fixed, active = np.asarray(p.particles.fixed), np.asarray(p.particles.active)
    assert fixed[:rows].all() and active[:rows].all() and not fixed[rows:].any() and not active[rows:].any()
    np.testing.assert_allclose(x[:rows, 2], 0.5)
    assert np.hypot(x[:rows, 0], x[:rows, 1]).max() <= p.info["base_radius"]
    # a triangular lattice 1.1 apart: each plate sphere's nearest neighbour 1.1 away
    d = np.linalg.norm(x[:rows, None, :2] - x[None, :rows, :2], axis=-1) + np.eye(rows) * 9
    np.testing.assert_allclose(d.min(1), 1.1, rtol=1e-12)
    release = np.asarray(p.protocol_state.release_position)[rows:]
    assert np.hypot(release[:, 0], release[:, 1]).max() <= 1.0 and np.allclose(release[:, 2], 0.5 + 6.5)
    assert x[rows:, 2].min() > 0.5 + 8.0  # parked above the release height
    np.testing.assert_allclose(p.protocol_state.release_velocity, [0.0, 0.0, -math.sqrt(2 * 1.5)])
    with pytest.raises(InputError, match="release_height must be at least"):
        cone.SPEC.set_up("hooke", N, release_height=4.0)
    with pytest.raises(InputError, match="interval 0.3 is too short"):
        cone.SPEC.set_up("hooke", N, **{**OPTIONS, "interval": 0.3})
    with pytest.raises(InputError, match="for disks only"):
        cone.SPEC.run("baxter", N, **OPTIONS)


def test_a_small_cone_rests_on_its_plate_which_carries_its_weight(heap):
    _, state, m = heap
    assert m["at_rest"] and m["counts"]["poured"] == N and m["counts"]["in_play"] + m["counts"]["lost"] == N
    assert m["counts"]["in_play"] >= N - 4
    assert abs(m["base_load"] / m["weight"] - 1.0) < 1e-3  # at rest the plate carries the heap
    assert 0.5 < m["height"] < 6.0 and 5.0 < m["angle_height_base"] < 45.0
    # p(r) is normalised by the mean pressure: its area-weighted mean over the base is 1
    p, radius = m["pressure"], m["base_radius"]
    edges = np.linspace(0.0, radius, len(p.value) + 1)
    area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    assert float(np.nansum(p.value * area) / (math.pi * radius ** 2)) == pytest.approx(1.0, rel=1e-9)
    assert 0.3 < m["packing_fraction"] < 0.8
    s = cone_heap.summary(m)
    assert s["counts"] == m["counts"] and len(s["pressure"]["value"]) == len(p.value)
    # a sweep row reads p at the ten default rings' centres (r / R = 0.05 .. 0.95): the rings' own values
    row = cone_heap.sweep_row(m)
    assert set(row) == set(cone_heap.ROW_COLUMNS)
    np.testing.assert_allclose([row[c] for c in cone_heap.PRESSURE_COLUMNS], p.value, rtol=1e-12, atol=1e-12)


def test_the_surface_and_its_angle_read_a_cone_of_known_slope():
    """h(r) of points filling a 30-degree cone, its angle within the rings' discreteness."""
    rng = np.random.default_rng(0)
    r, t = 10 * np.sqrt(rng.uniform(size=4000)), rng.uniform(0, 2 * np.pi, 4000)
    h = np.maximum(6 - r * np.tan(np.radians(30)), 0.0)
    points = np.stack([r * np.cos(t), r * np.sin(t), 1.0 + rng.uniform(size=4000) * np.maximum(h, 0.01)], 1)
    profile = cone_heap.surface(points, np.zeros(4000), (0.0, 0.0), base=1.0)
    assert 26.0 < cone_heap.repose_angle(profile) < 31.0
    # a dip at the centre, read in the fixed windows: a ring loaded twice the centre
    points2 = np.array([[0.1, 0.0], [0.0, 0.1], [4.0, 0.0], [0.0, -4.0], [-4.5, 0.0], [0.0, 4.5]])
    forces = np.array([1.0, 1.0, 20.0, 20.0, 20.0, 20.0])
    dip = cone_heap.central_dip(points2, forces, (0.0, 0.0), 10.0)
    inner = 2.0 / (math.pi * 1.0 ** 2)
    outer = 80.0 / (math.pi * (6.0 ** 2 - 3.0 ** 2))
    assert dip == pytest.approx(1.0 - inner / outer)


def test_a_cone_resumes_bit_for_bit_from_its_checkpoint(heap):
    folder, whole, m = heap
    saved = sorted(glob.glob(os.path.join(folder, "ck-*.npz")), key=lambda f: int(os.path.basename(f)[3:-4]))
    assert len(saved) >= 3
    resumed, r = cone.SPEC.run("hooke", N, seed=3, resume=saved[len(saved) // 2], progress=False, **LAW, **OPTIONS)
    for a, b in zip(jax.tree_util.tree_leaves(resumed), jax.tree_util.tree_leaves(whole)):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    assert r["angle_height_base"] == m["angle_height_base"] and r["steps"] == m["steps"]


def test_jaxpile_pile_pours_a_cone_and_writes_its_summary_and_figures(tmp_path):
    import json

    from jaxpile.cli import main

    out = tmp_path / "cone"
    assert main(["pile", "--protocol", "cone", "--n", "20", "--release-height", "8", "--insert-height", "6.5",
                 "--interval", "0.7", "--rolling", "sds", "--set", "k_roll=5e3", "--set", "mu_roll=0.2",
                 "--out", str(out), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"]["poured"] == 20 and summary["run"]["at_rest"]
    assert set(summary["pressure"]) == {"r", "value", "width"} and summary["setup"]["n_base"] > 0
    for figure in ("pile.png", "cone_pressure.png", "cone_surface.png"):
        assert (out / figure).stat().st_size > 10_000
    from jaxpile.export import read_xyz

    frame = read_xyz(out / "final.xyz")[0]
    assert frame["omega"].shape == (summary["setup"]["n_base"] + 20, 3)
