"""Property tests of the inputs at their edges (issue 19): values drawn across and
beyond every declared range (`jaxpile.ranges`: each law's `RANGES`, each
protocol's options, the CLI's `FLAG_RANGES`), zero, negatives, huge,
tiny, NaN, inf and things that are not numbers. Every outcome must be a run (or
a set-up) or one `InputError` line; the command line answers with exit status 2
and one line, never a traceback.

No example database is kept (`database=None`), and each test draws a few dozen
examples so that the file stays within ~30 s on 2 cores."""

import contextlib
import inspect
import io
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxpile import ranges
from jaxpile.cli import FLAG_RANGES, main
from jaxpile.errors import InputError
from jaxpile.laws import LAWS, get_law_module
from jaxpile.protocols import PROTOCOLS, lattice
from jaxpile.protocols.spec import ranges_of

# small boxes on purpose: the box's warning that a pile a layer or two deep means little
# (tests/test_protocol_box.py checks it) is not what these tests read
pytestmark = pytest.mark.filterwarnings("ignore:.*too few to stand as a pile:UserWarning")

PROPERTY = settings(database=None, deadline=None, suppress_health_check=list(HealthCheck))

EDGES = [0, -0.0, -1, 1, 0.5, 1.0 - 1e-12, 1e-300, 5e-324, 1e300, 1e308, 10**30, 2**63, 2**64, -(10**30),
         math.nan, math.inf, -math.inf]
NOT_NUMBERS = ["abc", "", "1.5", None, True, [1.0, 2.0], {}, b"1"]


def edge_values(range_: ranges.Range | None = None):
    """Numbers across and beyond a range: its bounds and their neighbours, the
    generic edges, random floats and integers, and non-numbers."""
    near = []
    if range_ is not None:
        for bound in (range_.low, range_.high):
            if bound is not None:
                near += [bound, math.nextafter(bound, -math.inf), math.nextafter(bound, math.inf), bound + 1, bound - 1]
    return st.one_of(st.sampled_from(EDGES + near), st.floats(allow_nan=True, allow_infinity=True),
                     st.integers(-(10**20), 10**20), st.floats(-2, 2), st.sampled_from(NOT_NUMBERS))


ONE_LINE = re.compile(r"^.+ must be .+; got .+\.$")


@settings(PROPERTY, max_examples=150)
@given(data=st.data())
def test_a_range_either_returns_a_value_inside_it_or_refuses_in_one_line(data):
    range_ = data.draw(st.sampled_from(
        [ranges.POSITIVE, ranges.NON_NEGATIVE, ranges.DISKS, ranges.STEPS, ranges.SEED, ranges.FRACTION,
         ranges.FINITE, ranges.ANGLE, get_law_module("baxter").RANGES["n"], ranges_of(PROTOCOLS["pour"].options)["spacing"]]))
    value = data.draw(edge_values(range_))
    try:
        checked = range_.check("x", value)
    except InputError as err:
        message = str(err)
        assert ONE_LINE.match(message) and "\n" not in message, message
        return
    for v in np.ravel(checked).tolist():  # a list of numbers (batched parameters) is checked element by element
        assert range_.contains(float(v)), (value, checked)
    if range_.whole and np.ndim(checked) == 0:
        assert isinstance(checked, int)


ROLLING_NAMES = ("k_roll", "gamma_roll", "mu_roll")


@settings(PROPERTY, max_examples=120)
@given(data=st.data())
def test_every_law_parameter_is_accepted_exactly_inside_its_declared_range(data):
    """make_params + validate: a number inside `RANGES` passes, anything else is
    one InputError naming the parameter (never OverflowError, TypeError...)."""
    name = data.draw(st.sampled_from(sorted(LAWS)))
    lawmod = get_law_module(name)
    param = data.draw(st.sampled_from(lawmod.PARAM_NAMES))
    value = data.draw(edge_values(lawmod.RANGES[param]))
    defaults = inspect.signature(lawmod.make_params).parameters
    default_is_none = param.startswith("wall_") or (param in defaults and defaults[param].default is None)
    # a rolling parameter is judged by the model that uses them all (without one, any set is refused)
    rolling = param in ROLLING_NAMES and "rolling" in inspect.signature(lawmod.law).parameters  # not liffman's own
    law = lawmod.law(rotation=True, rolling="sds") if rolling else lawmod.law()
    others = {k: 1.0 for k in ("k_roll", "mu_roll") if rolling and k != param}
    try:
        law.validate(lawmod.make_params(**{param: value}, **others))
    except InputError as err:
        assert param in str(err) and "\n" not in str(err)
        inside = _is_number(value) and lawmod.RANGES[param].contains(float(value))
        assert not inside or "float range" in str(err), f"{name} {param}={value!r} is in range but refused: {err}"
        return
    if value is None:
        assert default_is_none, f"{name} {param}=None accepted, but None is not its default"
        return
    if isinstance(value, list):  # batched parameters (an ensemble's): each member's value in range
        assert all(lawmod.RANGES[param].contains(v) for v in value), f"{name} {param}={value!r} accepted"
        return
    assert _is_number(value) and lawmod.RANGES[param].contains(float(value)), f"{name} {param}={value!r} accepted"


def _is_number(value) -> bool:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


SETUPS = {  # each protocol's set-up at a size that builds in well under a second
    "lattice": (lambda **o: lattice.equilateral_pile(o.pop("layers", 3), **o), {}),
    "sloped": (lambda **o: PROTOCOLS["sloped"].set_up(**{"alpha_degrees": 30.0, "n": 20, **o}), {}),
    "drop": (lambda **o: PROTOCOLS["drop"].set_up(**{"n": 12, **o}), {}),
    "box": (lambda **o: PROTOCOLS["box"].set_up(**{"n": 12, **o}), {}),
    "flux": (lambda **o: PROTOCOLS["flux"].set_up(**{"insertions": 3, **o}), {}),
    "pour": (lambda **o: PROTOCOLS["pour"].set_up(**{"n": 12, **o}), {}),
}
_SET_UP_ARGS = {  # the options each set-up reads (the rest of each protocol's options belong to its run)
    "lattice": {"layers", "diameter", "mass", "gap"},
    "sloped": {"alpha_degrees", "n", "base", "ramp_steps", "seed"},
    "drop": {"n", "seed", "dt", "drop_height", "jitter", "settle_speed", "quiet_time", "max_interval", "diameter",
             "mass"},
    "box": {"n", "width", "height", "packing_fraction", "placement_fraction", "rest_speed", "hold_time", "dt", "seed"},
    "flux": {"insertions", "width", "pool", "v_cut", "hold_time", "gap", "dt", "seed"},
    "pour": {"n", "spacing", "polydispersity", "release_height", "insert_height", "spread", "interval", "dt",
             "substrate_disks", "seed"},
}
_SMALL = {"n": 12, "layers": 3, "insertions": 3, "pool": 12, "substrate_disks": 40, "ramp_steps": 10}


@settings(PROPERTY, max_examples=60)
@given(data=st.data())
def test_every_protocol_option_sets_up_or_refuses_in_one_line(data):
    """Each protocol's set-up with one option drawn at its edges: a `Setup`
    (or the lattice's particles) or one InputError; counts are drawn small when
    valid so that a set-up stays cheap (their huge values are the memory
    check's, tested in test_budget.py)."""
    name = data.draw(st.sampled_from(sorted(SETUPS)))
    setup, _ = SETUPS[name]
    option = data.draw(st.sampled_from(sorted(_SET_UP_ARGS[name])))
    range_ = {**ranges_of(PROTOCOLS[name].options), "seed": ranges.SEED, "dt": ranges.TIME_STEP}[option]
    value = data.draw(edge_values(range_))
    if range_.whole and _is_number(value) and value > 60:
        value = _SMALL.get(option, value)
    try:
        setup(**{option: value})
    except InputError as err:
        assert "\n" not in str(err).strip(), str(err)


FLAG_TEXT = st.one_of(st.integers(-5, 40).map(str), edge_values().map(str))
_PROTOCOL_OPTIONS = {name: sorted(_SET_UP_ARGS.get(name, set()) - {"n", "layers", "insertions", "seed", "dt"})
                     for name in PROTOCOLS}


@st.composite
def pile_dry_runs(draw):
    protocol = draw(st.sampled_from(["lattice", "sloped", "drop", "box", "flux", "pour"]))
    law = draw(st.sampled_from(sorted(LAWS)))
    argv = ["pile", "--protocol", protocol, "--law", law, "--dry-run", "--no-progress",
            "--layers" if protocol == "lattice" else "--n", draw(st.integers(-2, 30).map(str) | FLAG_TEXT)]
    for flag in draw(st.lists(st.sampled_from(sorted(set(FLAG_RANGES["pile"]) - {"layers", "n"})), max_size=2)):
        argv += ["--" + flag.replace("_", "-"), draw(FLAG_TEXT)]
    lawmod = get_law_module(law)
    for param in draw(st.lists(st.sampled_from(lawmod.PARAM_NAMES), max_size=2)):
        argv += ["--set", f"{param}={draw(FLAG_TEXT)}"]
    if _PROTOCOL_OPTIONS[protocol] and draw(st.booleans()):
        argv += ["--option", f"{draw(st.sampled_from(_PROTOCOL_OPTIONS[protocol]))}={draw(FLAG_TEXT)}"]
    return argv


@settings(PROPERTY, max_examples=40)
@given(argv=pile_dry_runs())
def test_the_command_line_answers_every_drawn_input_with_a_dry_run_or_one_line(argv, tmp_path_factory):
    out = tmp_path_factory.mktemp("dry")
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        try:
            status = main(argv + ["--out", str(out / "run")])
        except SystemExit as exit_:  # argparse's own errors (a flag that is not a number)
            status = exit_.code
    err = stderr.getvalue().strip()
    assert status in (0, 2), (argv, status, err)
    if status == 2:
        assert err.startswith("jaxpile: error:") and len(err.splitlines()) == 1, (argv, err)
    assert "Traceback" not in err + stdout.getvalue()
    assert not (out / "run").exists()  # a dry run, or a refusal, writes nothing


@pytest.mark.parametrize("command", sorted(FLAG_RANGES))
def test_every_ranged_flag_states_its_range_in_its_help(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for dest, range_ in FLAG_RANGES[command].items():
        assert f"[{range_.describe()}]" in text, (command, dest)


def _ranged_options():
    """(protocol, option) for every `--option` a protocol declares a range for (a tilt's box's too)."""
    from jaxpile.protocols.spec import ranges_of

    return [(name, option) for name, spec in sorted(PROTOCOLS.items())
            for option in sorted(set().union(*(ranges_of(s.options) for s in spec.chain()))
                                 - {s.size for s in spec.chain()})]


@pytest.mark.parametrize("protocol, option", _ranged_options())
def test_a_dry_run_refuses_an_option_out_of_its_range_as_the_run_does(protocol, option, tmp_path, capsys):
    """NaN is outside every declared range: `--dry-run` must say so in one line,
    as the run would before it starts (a tilt's dry run used to set up only
    its box pile, so `--option rate_degrees=nan` passed it)."""
    status = main(["pile", "--protocol", protocol, "--option", f"{option}=nan", "--dry-run", "--no-progress",
                   "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err.strip()
    assert status == 2 and err.startswith("jaxpile: error:") and len(err.splitlines()) == 1, (protocol, option, err)
    assert option in err, (protocol, option, err)


@pytest.mark.parametrize("protocol, vary, options", [
    ("box", {"n": [20, 0]}, {}),                      # a set-up value of the second batch
    ("box", {"mu": [0.1, math.nan]}, {"n": 20}),       # a law value of the last member
    ("tilt", {"rate_degrees": [1.0, 0.0]}, {"n": 20}),  # the later stage's own option, in its second batch
    ("tilt", {"mu": [0.1, 0.2]}, {"n": 20, "rest_speed": 5.0, "move_speed": 1.0}),  # rest above move
])
def test_a_sweep_refuses_a_bad_member_before_any_batch_runs(protocol, vary, options, monkeypatch):
    """Every member's law values and every batch's set-up (a tilt's own options
    too) are checked before the first batch is built: a bad value at the end
    of a grid used to fail only after the batches before it (or, for a tilt,
    the box stage) had run."""
    from jaxpile import sweeps
    from jaxpile.batches import runs

    monkeypatch.setattr(runs, "ensemble_for",
                        lambda *a, **k: pytest.fail("a batch was built before the grid was checked"))
    with pytest.raises(InputError):
        sweeps.sweep(protocol, vary=vary, seeds=1, options=options, progress=False)


@pytest.mark.parametrize("argv, says", [
    (["sweep", "--protocol", "box", "--vary", "n=20,0"], "n must be"),
    (["sweep", "--protocol", "hopper", "--vary", "mu=0.1,nan"], "mu must be"),
    (["sweep", "--protocol", "tilt", "--vary", "rate_degrees=1,0"], "rate_degrees must be"),
    (["fit", "--protocol", "hopper", "--params", "mu", "--truth", "mu=nan", "--ensemble", "2"], "mu must be"),
    (["fit", "--protocol", "box", "--params", "mu", "--truth", "mu=0.3", "--set", "mu=0", "--ensemble", "2"],
     "starting mu"),
    (["fit", "--protocol", "tilt", "--params", "mu", "--truth", "mu=0.3", "--option", "rate_degrees=0",
      "--ensemble", "2"], "rate_degrees must be"),
    (["sweep", "--protocol", "box", "--vary", "mu=0.1,,0.3"], "empty value"),  # not a 2-point sweep in silence
    (["fit", "--protocol", "pour", "--params", "n,n", "--truth", "n=30", "--ensemble", "2"], "twice"),
    (["fit", "--protocol", "tilt", "--params", "mu", "--truth", "mu=0.3", "--ensemble", "2", "--statistics", "theta"],
     "no column 'theta'"),  # the run found out only after the target ensemble had run
    (["fit", "--protocol", "pour", "--params", "mu", "--truth", "mu=0.3", "--ensemble", "2", "--statistics",
      "repose"], "no column 'repose'"),  # a computed row with declared columns (poured_heap.ROW_COLUMNS)
])
def test_sweep_and_fit_dry_runs_refuse_what_their_runs_would(argv, says, tmp_path, capsys):
    """A dry run checks every member of the grid, the fit's start and truth and
    a later stage's options, as the run does before it starts."""
    assert main(argv + ["--dry-run", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jaxpile: error:") and len(err.splitlines()) == 1 and says in err, err


@pytest.mark.parametrize("content", ["{cut sho", "[1, 2]", "{}", '{"protocol": "pour", "law": "x"}', "\udcff"])
def test_a_damaged_or_foreign_json_file_gets_one_line_not_a_traceback(content, tmp_path, capsys):
    """What a crash or a wrong path leaves where a command reads JSON (compare's
    summary.json, fit's --target and --resume, show's sweep.json): one line
    naming the file, exit status 2."""
    data = content.encode("utf-8", "surrogateescape")
    run, fit_dir, sweep_dir = tmp_path / "run", tmp_path / "fit", tmp_path / "sweep"
    for folder, name in ((run, "summary.json"), (fit_dir, "fit_checkpoint.json"), (sweep_dir, "sweep.json")):
        folder.mkdir()
        (folder / name).write_bytes(data)
    (sweep_dir / "sweep.csv").write_text("mu,seed\n0.1,0\n")
    fit = ["fit", "--protocol", "box", "--params", "mu", "--ensemble", "2"]
    commands = [
        ["compare", str(run), str(run)],
        fit + ["--target", str(run / "summary.json"), "--out", str(tmp_path / "out1")],
        fit + ["--truth", "mu=0.3", "--resume", "--out", str(fit_dir)],
        ["show", str(sweep_dir), "--out", str(tmp_path / "out2")],
    ]
    for argv in commands:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("jaxpile: error:") and len(err.splitlines()) == 1, (argv, err)


@pytest.mark.parametrize("kwargs, says", [
    ({"seeds": [1.5]}, "seed"), ({"seeds": "a"}, "seeds"), ({"seeds": 0}, "at least one seed"),
    ({"vary": {"mu": "0.1"}}, "list of numbers"), ({"vary": {"mu": [0.1, "x"]}}, "sweep over 'mu'"),
    ({"vary": None, "points": [{"mu": "x"}]}, "sweep point"), ({"vary": None, "points": [3]}, "list of dicts"),
    ({"vary": {"mu": [0.1, math.nan]}}, "lee-herrmann parameter mu"),  # the law's own range and message
])
def test_the_sweep_api_answers_a_bad_grid_with_an_input_error(kwargs, says):
    """`batches.plan` (what `sweep` checks first) from Python: a seed that is not
    whole was truncated in silence (1.5 ran seed 1), a string of values was
    iterated character by character (a ValueError)."""
    from jaxpile import batches

    args = {"vary": {"mu": [0.1]}, "seeds": 1, **kwargs}
    with pytest.raises(InputError, match=says):
        batches.plan("box", options={"n": 20}, **args)


def test_run_refuses_a_step_count_that_is_not_one_and_a_write_to_a_folder(tmp_path):
    """`Simulator.run(..., nan)` raised numpy's ValueError; writing a state or
    a frame to a folder's path raised IsADirectoryError on a temporary name."""
    from jaxpile import export, io
    from jaxpile.laws import hooke
    from jaxpile.protocols import lattice
    from jaxpile.engine.simulate import Simulator

    particles, boundaries = lattice.equilateral_pile(2)
    params = hooke.make_params(kn=1e4)
    sim = Simulator(hooke.law(), 1e-4)
    state = sim.init(params, particles, boundaries)
    for steps in (math.nan, math.inf, "10", 2.5, -1):
        with pytest.raises(InputError, match="n_steps"):
            sim.run(params, state, steps)
    for write in (lambda: io.save_state(str(tmp_path), state), lambda: export.write_xyz(str(tmp_path), state)):
        with pytest.raises(InputError, match="is a folder"):
            write()


def test_a_negative_zero_jitter_or_spread_acts_as_zero():
    """-0.0 lies inside the drop's jitter range [0, 1) and the pour's spread range;
    numpy's uniform(0.0, -0.0) raised "high - low < 0" (drawn by the property test above)."""
    for make in (lambda x: PROTOCOLS["drop"].set_up(n=12, jitter=x), lambda x: PROTOCOLS["pour"].set_up(n=12, spread=x)):
        a, b = make(-0.0), make(0.0)
        assert np.array_equal(np.asarray(a.particles.position), np.asarray(b.particles.position))
