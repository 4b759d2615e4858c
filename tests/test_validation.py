"""Bad input gives one clear error naming the problem."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import jaxpile
from jaxpile import InputError
from jaxpile.cli import main
from jaxpile.laws import hooke
from jaxpile.engine.simulate import Simulator


def _pair(**kw):
    return jaxpile.make_particles([[1.0, 0.5], [2.0, 0.5]], 0.5, **kw)


@pytest.mark.parametrize("radius", [-0.5, 0.0, np.nan])
def test_non_positive_or_nan_radius(radius):
    with pytest.raises(InputError, match="radius"):
        jaxpile.make_particles([[1.0, 1.0], [3.0, 1.0]], [0.5, radius])


def test_non_positive_mass():
    with pytest.raises(InputError, match="mass"):
        _pair(mass=[1.0, -1.0])


def test_nan_position():
    with pytest.raises(InputError, match="position of particle 1"):
        jaxpile.make_particles([[1.0, 1.0], [np.nan, 1.0]], 0.5)


def test_nan_in_state_handed_to_init():
    p = _pair()
    p = p.set(velocity=p.velocity.at[1, 0].set(jnp.inf))
    with pytest.raises(InputError, match="particle 1"):
        Simulator(hooke.law(), 1e-4).init(hooke.make_params(), p, jaxpile.make_boundaries())


def test_negative_friction():
    with pytest.raises(InputError, match="mu"):
        Simulator(hooke.law(), 1e-4).init(hooke.make_params(mu=-0.1), _pair(), jaxpile.make_boundaries())


def test_negative_wall_friction():
    with pytest.raises(InputError, match="wall_mu"):
        Simulator(hooke.law(), 1e-4).init(hooke.make_params(wall_mu=-1.0), _pair(), jaxpile.make_boundaries())


def test_time_step_above_stability_limit():
    with pytest.raises(InputError, match="stability limit"):
        Simulator(hooke.law(), 0.05).init(hooke.make_params(kn=1e4), _pair(), jaxpile.make_boundaries())


def test_deeply_overlapping_start():
    p = jaxpile.make_particles([[1.0, 0.5], [1.3, 0.5]], 0.5)
    with pytest.raises(InputError, match="particles 0 and 1 start overlapped by 70"):
        Simulator(hooke.law(), 1e-4).init(hooke.make_params(), p, jaxpile.make_boundaries())


def test_start_inside_a_wall():
    p = jaxpile.make_particles([[1.0, 0.1]], 0.5)
    with pytest.raises(InputError, match="inside wall 0"):
        Simulator(hooke.law(), 1e-4).init(hooke.make_params(), p, jaxpile.make_boundaries())


def test_nan_during_run_is_reported_with_step_and_particle():
    params = hooke.make_params(kn=1e4)
    # a law copy without parameter checks, so a NaN can reach the compiled run
    unchecked = dataclasses.replace(hooke.law(), validate=lambda p: None)
    sim = Simulator(unchecked, 1e-4, chunk_steps=10)
    state = sim.init(params, _pair(), jaxpile.make_boundaries())
    state = sim.run(params, state, 10, progress=False)
    bad = params.set(gamma_n=jnp.asarray(jnp.nan))  # NaN reaches the disks touching the ground
    with pytest.raises(jaxpile.SimulationError, match="by step 20: first offending particle 0") as err:
        sim.run(bad, state, 30, progress=False)
    assert int(err.value.last_good_state.step) == 10


def test_bad_values_in_the_dataclass_are_caught_before_running():
    with pytest.raises(InputError, match="gamma_n must be finite"):
        Simulator(hooke.law(), 1e-4).init(hooke.make_params(gamma_n=np.nan), _pair(), jaxpile.make_boundaries())


def test_dt_must_be_positive():
    with pytest.raises(InputError, match="dt"):
        Simulator(hooke.law(), -1.0)


def test_cli_unknown_parameter_and_law(tmp_path, capsys):
    assert main(["pile", "--layers", "3", "--set", "stiffness=3", "--out", str(tmp_path)]) == 2
    assert "unknown parameter 'stiffness'" in capsys.readouterr().err
    assert main(["pile", "--layers", "3", "--law", "nope", "--out", str(tmp_path)]) == 2
    assert "unknown law 'nope'" in capsys.readouterr().err


def test_negative_skin_and_small_capacity_multiplier():
    with pytest.raises(InputError, match="skin"):
        Simulator(hooke.law(), 1e-4, skin=-0.1)
    with pytest.raises(InputError, match="capacity_multiplier"):
        Simulator(hooke.law(), 1e-4, capacity_multiplier=0.5)


def test_per_particle_arrays_of_the_wrong_length():
    with pytest.raises(InputError, match="radius must be a scalar or have one value per particle"):
        jaxpile.make_particles([[1.0, 1.0], [3.0, 1.0]], [0.5, 0.5, 0.5])
    with pytest.raises(InputError, match="no particles"):
        jaxpile.make_particles(np.zeros((0, 2)), 0.5)


def test_fixed_disks_cannot_move():
    with pytest.raises(InputError, match="fixed particle 0"):
        jaxpile.make_particles([[1.0, 1.0]], 0.5, velocity=[[1.0, 0.0]], fixed=True)


def test_walls_in_the_wrong_order_and_bad_ramp():
    with pytest.raises(InputError, match="left wall"):
        jaxpile.make_boundaries(left=5.0, right=0.0)
    with pytest.raises(InputError, match="gravity ramp"):
        jaxpile.engine.simulate.gravity_ramp(0)


def test_overlapping_fixed_disks_are_allowed():
    p = jaxpile.make_particles([[1.0, 0.5], [1.5, 0.5]], 0.5, fixed=True)
    Simulator(hooke.law(), 1e-4).init(hooke.make_params(), p, jaxpile.make_boundaries())


def test_cli_error_paths(tmp_path, capsys):
    assert main(["compare", str(tmp_path / "missing")]) == 2
    assert "summary.json not found" in capsys.readouterr().err
    assert main(["pile", "--layers", "3", "--ramp-steps", "0", "--out", str(tmp_path)]) == 2
    assert "gravity ramp" in capsys.readouterr().err
    assert main(["pile", "--layers", "3", "--speed-tol", "0", "--out", str(tmp_path)]) == 2
    assert "speed_tolerance" in capsys.readouterr().err
    assert main(["pile", "--layers", "3", "--hard-collisions", "0.5", "--out", str(tmp_path)]) == 2
    assert "EPS,MU" in capsys.readouterr().err
    assert main(["pile", "--layers", "3", "--hard-collisions", "1.5,0.2", "--out", str(tmp_path)]) == 2
    assert "restitution" in capsys.readouterr().err


def test_unknown_integrator():
    with pytest.raises(InputError, match="unknown integrator 'gear3'"):
        Simulator(hooke.law(), 1e-4, integrator="gear3")
