"""The catalogue of bad inputs (issue 7): every entry point, Python and CLI,
answers each with one clear message naming the input, never a traceback from
inside JAX. Checks are on the host, before anything is compiled."""

import re

import pytest

import jaxpile
from jaxpile import fit
from jaxpile.cli import main
from jaxpile.errors import InputError
from jaxpile.laws import baxter, get_law_module, hooke
from jaxpile.protocols import box, pour
from jaxpile.engine.simulate import Simulator

# small boxes on purpose: the box's warning that a pile a layer or two deep means little
# (tests/test_protocol_box.py checks it) is not what these tests read
pytestmark = pytest.mark.filterwarnings("ignore:.*too few to stand as a pile:UserWarning")

ONE = [[1.0, 0.5]]
GROUND = jaxpile.make_boundaries()
NO_WALLS = GROUND.set(wall_normal=GROUND.wall_normal[:0], wall_offset=GROUND.wall_offset[:0],
                      wall_active=GROUND.wall_active[:0])

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
    "no disks to pour": (lambda: pour.SPEC.set_up(size=0), "positive whole number of disks"),
    "an unknown floor": (lambda: pour.SPEC.set_up(size=10, floor="sand"), "floor must be one of .'row', 'flat'.; got 'sand'"),
    "no disks in the box": (lambda: box.SPEC.set_up(size=0), "n must be"),
    # what the law, its model or the set-up does not use is refused, not ignored
    "a rolling parameter without a rolling model": (
        lambda: hooke.law().validate(hooke.make_params(k_roll=1000.0)), "k_roll is set, but the law has no rolling"),
    "a pile given a rolling parameter without a rolling model": (
        lambda: jaxpile.run("box", "lee-herrmann", 72, rotation=True, params={"mu_roll": 0.1}),
        "mu_roll is set, but the law has no rolling"),
    "a sweep over a parameter that does not act": (
        lambda: jaxpile.sweep("box", "lee-herrmann", vary={"mu_roll": [0.1, 0.2]}, seeds=1, rotation=True),
        "mu_roll is set, but the law has no rolling"),
    "a wall parameter for a set-up without walls": (
        lambda: Simulator(hooke.law(), 1e-4).init(hooke.make_params(wall_mu=0.5), jaxpile.make_particles(ONE, 0.5),
                                                  NO_WALLS),
        "wall_mu set, but this set-up has no walls"),
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
    "a rolling parameter without --rolling": (["pile", "--protocol", "box", "--rotation", "on", "--set", "k_roll=1000"],
                                              "k_roll is set, but the law has no rolling"),
    "a sweep over a parameter that does not act": (
        ["sweep", "--protocol", "box", "--rotation", "on", "--vary", "mu_roll=0.1,0.2", "--seeds", "1"],
        "mu_roll is set, but the law has no rolling"),
    "a fit over a parameter that does not act": (
        ["fit", "--protocol", "box", "--rotation", "on", "--params", "mu_roll", "--truth", "mu_roll=0.2", "--ensemble",
         "2"], "mu_roll is set, but the law has no rolling"),
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


def test_the_docs_list_every_declared_range_as_the_checks_use_it():
    """The inputs table of docs/cli.md is generated from the tables the checks use;
    a range changed in the code and not in the page fails here."""
    import pathlib

    from jaxpile.cli import ranges_markdown

    page = (pathlib.Path(__file__).parents[1] / "docs" / "cli.md").read_text()
    start, end = "<!-- ranges: generated by jaxpile.cli.ranges_markdown() -->\n", "\n<!-- /ranges -->"
    assert start in page and end in page
    assert page[page.index(start) + len(start):page.index(end)] == ranges_markdown(), (
        "paste jaxpile.cli.ranges_markdown() between the ranges markers of docs/cli.md")


RANGE_CASES = {  # one value just outside each kind of range, each with its one-line message
    "baxter n above 1000": (lambda: baxter.law().validate(baxter.make_params(n=1001.0)), "n must be > 0 and <= 1000"),
    "a stiffness that is text": (lambda: hooke.make_params(kn="stiff"), "kn must be a number > 0; got 'stiff'"),
    "a list where one option goes": (lambda: pour.SPEC.set_up(size=10, spread=[1.0, 2.0]), "spread must be one number"),
    "a seed beyond 32 bits": (lambda: box.SPEC.set_up(size=10, seed=2**32), "seed must be >= 0 and <= 4,294,967,295, a whole number"),
    "a time step below 1e-12": (lambda: pour.SPEC.set_up(size=10, dt=1e-13), "dt must be >= 1e-12 and <= 1e6"),
    "a hold time beyond the step counter": (lambda: box.SPEC.set_up(size=10, dt=1e-12, hold_time=1e3),
                                            "beyond the 32-bit step counter"),
}


@pytest.mark.parametrize("case", sorted(RANGE_CASES))
def test_a_value_just_outside_its_declared_range_is_refused_in_one_line(case):
    call, message = RANGE_CASES[case]
    with pytest.raises(InputError, match=re.escape(message)) as err:
        call()
    assert "\n" not in str(err.value)
