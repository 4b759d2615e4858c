"""The catalogue of bad inputs (issue 7): every entry point, Python and CLI,
answers each with one clear message naming the input, never a traceback from
inside JAX. Checks are on the host, before anything is compiled."""

import pytest

import jaxpile
from jaxpile import fit
from jaxpile.cli import main
from jaxpile.errors import InputError
from jaxpile.laws import baxter, get_law_module, hooke
from jaxpile.protocols import box, pour
from jaxpile.simulate import Simulator

ONE = [[1.0, 0.5]]
GROUND = jaxpile.make_boundaries()

PYTHON = {
    "negative radius": (lambda: jaxpile.make_particles(ONE, -0.5), "radius must be positive"),
    "zero radius": (lambda: jaxpile.make_particles(ONE, 0.0), "radius must be positive"),
    "infinite radius": (lambda: jaxpile.make_particles(ONE, float("inf")), "radius must be positive and finite"),
    "negative mass": (lambda: jaxpile.make_particles(ONE, 0.5, mass=-1.0), "mass must be positive"),
    "NaN position": (lambda: jaxpile.make_particles([[float("nan"), 0.5]], 0.5), "position of particle 0"),
    "infinite velocity": (lambda: jaxpile.make_particles(ONE, 0.5, velocity=[[float("inf"), 0.0]]),
                          "velocity of particle 0"),
    "mu < 0": (lambda: hooke.law().validate(hooke.make_params(mu=-0.1)), "mu must be >= 0"),
    "NaN stiffness": (lambda: hooke.law().validate(hooke.make_params(kn=float("nan"))), "kn must be finite"),
    "n <= 0": (lambda: baxter.law().validate(baxter.make_params(n=0.0)), "n must be > 0"),
    "r0 <= 1": (lambda: baxter.law().validate(baxter.make_params(r0=1.0)), "r0 must be > 1"),
    "dt above the stability limit": (
        lambda: Simulator(hooke.law(), 1.0).init(hooke.make_params(), jaxpile.make_particles(ONE, 0.5), GROUND),
        "above the stability limit"),
    "NaN dt": (lambda: Simulator(hooke.law(), float("nan")), "dt must be positive and finite"),
    "overlapping start": (
        lambda: Simulator(hooke.law(), 1e-4).init(hooke.make_params(), jaxpile.make_particles(ONE * 2, 0.5), GROUND),
        "start overlapped"),
    "NaN gravity": (lambda: jaxpile.make_boundaries(gravity=float("nan")), "gravity must be a finite"),
    "unknown law": (lambda: get_law_module("hertz"), "unknown law 'hertz'"),
    "unknown parameter": (lambda: hooke.make_params(mux=0.3), "unknown hooke parameter"),
    "unknown integrator": (lambda: Simulator(hooke.law(), 1e-4, integrator="rk4"), "unknown integrator 'rk4'"),
    "no disks to pour": (lambda: pour.pour(0), "positive whole number of disks"),
    "no disks in the box": (lambda: box.protocol(0), "n must be"),
}


@pytest.mark.parametrize("case", sorted(PYTHON))
def test_python_entry_points_refuse_bad_input_with_one_clear_message(case):
    call, message = PYTHON[case]
    with pytest.raises(InputError, match=message):
        call()


def test_a_target_csv_with_wrong_columns_names_them(tmp_path):
    (tmp_path / "t.csv").write_text("a,b\n0,1\n")
    with pytest.raises(InputError, match=r"unknown column\(s\) \['a', 'b'\]"):
        fit.load_profile_csv(tmp_path / "t.csv")


CLI = {
    "mu < 0": (["pile", "--layers", "3", "--set", "mu=-1"], "mu must be >= 0"),
    "unknown law": (["pile", "--law", "nope"], "unknown law 'nope'"),
    "unknown parameter": (["pile", "--set", "bogus=1"], "unknown parameter 'bogus'"),
    "no disks": (["pile", "--protocol", "box", "--n", "0"], "positive whole number of disks"),
    "dt above the stability limit": (["pile", "--layers", "3", "--dt", "10"], "above the stability limit"),
    "flag the protocol does not use": (["pile", "--protocol", "box", "--layers", "3"], "--layers is for the lattice"),
    "negative friction in a sweep": (["sweep", "--protocol", "box", "--mu", "-0.1"], "mu must be >= 0"),
}


@pytest.mark.parametrize("case", sorted(CLI))
def test_cli_refuses_bad_input_with_one_line_and_status_2(case, tmp_path, capsys):
    argv, message = CLI[case]
    assert main(argv + ["--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxpile: error:") and message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_cli_unknown_protocol_is_an_argparse_error_not_a_traceback(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["pile", "--protocol", "heap", "--out", str(tmp_path)])
    assert exit_.value.code == 2 and "invalid choice: 'heap'" in capsys.readouterr().err
