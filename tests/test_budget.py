"""Runs too big for the machine are refused before anything is allocated (issue 19)."""

import time

import pytest

import jaxpile  # noqa: F401  (float64)
from jaxpile import budget
from jaxpile.errors import InputError
from jaxpile.protocols import box, drop, flux, lattice, pour, sloped

# small boxes on purpose: the box's warning that a pile a layer or two deep means little
# (tests/test_protocol_box.py checks it) is not what these tests read
pytestmark = pytest.mark.filterwarnings("ignore:.*too few to stand as a pile:UserWarning")


def test_estimate_is_linear_in_disks_and_batch_and_follows_the_measured_bytes():
    one = budget.estimate(10**6, "float64") - budget.FIXED_BYTES
    assert budget.estimate(2 * 10**6, "float64") - budget.FIXED_BYTES == 2 * one
    assert budget.estimate(10**6, "float64", batch=4) - budget.FIXED_BYTES == 4 * one
    assert one == pytest.approx(10**6 * ((258 + 995) * budget.HEADROOM + budget.HOST_BYTES_PER_DISK), rel=1e-6)
    assert budget.bytes_per_disk("float32") < budget.bytes_per_disk("float64")
    memory = 8 * 2**30
    n = budget.largest("float64", memory=memory)
    assert budget.estimate(n, "float64") <= budget.USABLE_FRACTION * memory < budget.estimate(n + 1, "float64")
    with pytest.raises(InputError, match="float32 or float64"):
        budget.bytes_per_disk("float16")


@pytest.mark.parametrize("make", [
    lambda: box.SPEC.set_up(size=10**8),
    lambda: pour.SPEC.set_up(size=10**8),
    lambda: lattice.equilateral_pile(20_000),
    lambda: drop.SPEC.set_up(size=10**8),
    lambda: sloped.SPEC.set_up(alpha_degrees=30, n=10**8),
    lambda: flux.SPEC.set_up(size=10**9, pool=10**8),
], ids=["box", "pour", "lattice", "drop", "sloped", "flux"])
def test_a_1e8_disk_pile_is_refused_at_once_with_its_estimate(make):
    t0 = time.perf_counter()
    with pytest.raises(InputError) as err:
        make()
    assert time.perf_counter() - t0 < 5.0  # nothing was allocated: the set-up never started
    message = str(err.value)
    for words in ("needs about", "GB", "this machine has", "would fit"):
        assert words in message


def test_a_batch_too_big_for_the_machine_is_refused_by_the_sweep(monkeypatch):
    from jaxpile import sweeps

    # room for two members of 40 disks, not for the batch of four: 80 disks over 4 members
    room = (budget.FIXED_BYTES + 2 * 40 * budget.bytes_per_disk("float64")) / budget.USABLE_FRACTION
    monkeypatch.setattr(budget, "available", lambda: (int(room), "test memory"))
    with pytest.raises(InputError, match=r"a batch of the box sweep of 4 x 40 disks .* At most (19|20) disks per member"):
        sweeps.sweep("box", vary={"mu": [0.2, 0.4]}, seeds=2, options={"n": 40}, max_steps=10, progress=False)
