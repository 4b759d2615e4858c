"""`jaxpile pile --protocol P` for every protocol besides the lattice (which
tests/test_cli.py covers): each writes the lattice run's files plus its own
measurements and figure, at the smallest size that still builds a pile."""

import json

import numpy as np
import pytest

from jaxpile import export
from jaxpile.engine import checkpoint
from jaxpile.cli import main
from jaxpile.io import load_arrays, read_csv, write_csv

# protocol -> (extra arguments, summary keys the protocol must report, its own figure)
CASES = {
    "sloped": (["--slope", "45", "--n", "21", "--max-steps", "40000"],
               ("central_slope_horizontal", "theory_central_slope_horizontal", "alpha_degrees"), None),
    "drop": (["--n", "6", "--seed", "1"], ("central_dip", "all_inserted", "weight_balance"), None),
    "box": (["--n", "30", "--width", "1.2", "--option", "height=1.0"],  # a protocol's option as its own flag
            ("repose_cumulative_parabola", "theta_ms_theory", "wall_removed_step"), "energy.png"),
    "tilt": (["--n", "30", "--option", "rate_degrees=0.05"], ("theta_t", "theta_t_theory", "theta_r"), "energy.png"),
    "flux": (["--n", "4", "--option", "width=1.0"], ("steady_mean", "angle_cumulative_parabola"), "angles.png"),
    "pour": (["--n", "12", "--release-height", "8", "--option", "substrate_disks=15", "--speed-tol", "1e-3"],
             ("counts", "height", "weight_mg"), None),
}


@pytest.mark.parametrize("protocol", list(CASES))
def test_pile_command_runs_every_protocol_and_writes_its_files(protocol, tmp_path, capsys):
    extra, keys, figure = CASES[protocol]
    out = tmp_path / protocol
    dump = protocol == "tilt"  # one protocol records a LAMMPS dump, the others extended XYZ
    trajectory_file = out / ("trajectory.lammpstrj" if dump else "trajectory.xyz")
    assert main(["pile", "--protocol", protocol, *extra, "--no-progress", "--out", str(out),
                 "--checkpoint-every", "2000", "--trajectory-every", "2000",
                 "--trajectory-format", "lammps" if dump else "xyz"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["protocol"] == protocol and summary["n_particles"] > 0
    for key in keys:
        assert key in summary, key
    table = read_csv(out / "base_forces.csv")
    assert set(table) == {"x", "normal", "horizontal"} and len(table["x"]) > 0
    assert np.all(np.asarray(table["normal"]) > 0)  # the base pushes up
    state = load_arrays(out / "state.npz")
    assert state["particles.position"].shape[1] == 2
    for name in ("pile.png", "profile.png") + ((figure,) if figure else ()):
        assert (out / name).stat().st_size > 10_000, name
    printed = capsys.readouterr().out
    assert f"{protocol} pile" in printed and "wrote" in printed
    assert main(["compare", str(out)]) == 0
    assert protocol in capsys.readouterr().out
    # `jaxpile show` draws the protocol's own figure again from the files, without running
    assert main(["show", str(out), "--out", str(tmp_path / "redrawn")]) == 0
    for name in ("pile.png", "profile.png") + ((figure,) if figure else ()):
        assert (tmp_path / "redrawn" / name).stat().st_size > 10_000, name
    if figure == "energy.png":  # and from the checkpoint, with the energy sampled so far
        assert main(["show", str(out), "--checkpoint", "--out", str(tmp_path / "from_checkpoint")]) == 0
        assert (tmp_path / "from_checkpoint" / "energy.png").stat().st_size > 10_000

    # the run was checkpointed (the tilt also saved the box run that built its pile);
    # resuming the finished run takes no step and writes the same pile
    saved = checkpoint.read_metadata(out / "checkpoint.npz")
    assert saved["extra"]["argv"][:3] == ["pile", "--protocol", protocol]
    assert (out / "checkpoint.box.npz").exists() == (protocol == "tilt")
    read = export.read_lammps_dump if dump else export.read_xyz
    steps = [f["step"] for f in read(trajectory_file)]  # through every stage and phase
    assert steps[0] == 0 and len(steps) >= 2 and steps == sorted(set(steps))
    trajectory = trajectory_file.read_text()
    assert main(["pile", "--resume", str(out), "--no-progress"]) == 0
    assert trajectory_file.read_text() == trajectory
    assert f"resuming {out} at step {saved['step']}" in capsys.readouterr().out
    again = load_arrays(out / "state.npz")
    np.testing.assert_array_equal(again["particles.position"], state["particles.position"])
    assert json.loads((out / "summary.json").read_text())["resumed_from_step"] == saved["step"]


@pytest.mark.parametrize("argv, message", [
    (["--protocol", "box", "--slope", "30"], "--slope"),
    (["--protocol", "box", "--layers", "5"], "--layers"),
    (["--protocol", "lattice", "--n", "5"], "--n"),
    (["--protocol", "box", "--option", "colour=red"], "unknown --option"),
    (["--protocol", "box", "--option", "width"], "NAME=VALUE"),
    (["--protocol", "box", "--hard-collisions", "0.5,0.3"], "--hard-collisions"),
    (["--protocol", "pour", "--set", "stiffness=3"], "unknown parameter"),
    (["--protocol", "flux", "--law", "coulomb"], "unknown law"),
])
def test_pile_command_refuses_flags_a_protocol_does_not_use(argv, message, tmp_path, capsys):
    assert main(["pile", *argv, "--no-progress", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert not (tmp_path / "x").exists()  # refused before anything ran or was written


def test_a_base_force_table_with_no_contacts_reads_back_as_empty_columns(tmp_path):
    path = tmp_path / "empty.csv"
    write_csv(path, {"x": [], "normal": [], "horizontal": []})
    table = read_csv(path)
    assert set(table) == {"x", "normal", "horizontal"} and all(len(v) == 0 for v in table.values())


# ----------------------------------------------------- the protocols' own flags
def test_every_option_of_every_protocol_is_a_flag_of_pile_sweep_and_fit_with_its_help_and_range(capsys):
    """A protocol's options appear as `--NAME` flags, read from the fields of
    its options dataclass (no table beside them)."""
    from jaxpile.cli import build_parser, merge_protocol_flags, protocol_flags
    from jaxpile.protocols import PROTOCOLS

    for command in ("pile", "sweep", "fit"):
        for protocol in PROTOCOLS:
            argv = [command, "--protocol", protocol]
            flags = protocol_flags(command, protocol)
            assert flags, (command, protocol)  # the lattice's run options are generic flags of `pile`, its geometry not
            subparser = build_parser(argv)._subparsers._group_actions[0].choices[command]
            for option in flags.values():
                assert option.flag in subparser._option_string_actions, (command, protocol, option.flag)
    with pytest.raises(SystemExit) as done:
        main(["pile", "--protocol", "pour", "--help"])
    assert done.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "options of the pour protocol" in text
    assert "--polydispersity X delta (a fraction, 0.05 for the paper's 5%)" in text and "[>= 0 and < 0.5]" in text
    argv = ["pile", "--protocol", "tilt", "--settle", "on", "--rate-degrees", "0.05", "--out", "x"]
    args = build_parser(argv).parse_args(argv)
    merge_protocol_flags(args)
    assert args.option == ["settle=on", "rate_degrees=0.05"]


def test_a_flag_of_another_protocol_or_an_option_given_twice_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as done:  # box has no polydispersity
        main(["pile", "--protocol", "box", "--polydispersity", "0.05", "--out", str(tmp_path)])
    assert done.value.code == 2 and "unrecognized arguments: --polydispersity" in capsys.readouterr().err
    assert main(["pile", "--protocol", "pour", "--polydispersity", "0.05", "--option", "polydispersity=0.1",
                 "--out", str(tmp_path)]) == 2
    assert "given both as a flag and as --option" in capsys.readouterr().err


def test_every_protocol_option_has_help_and_its_flag_states_the_fields_words(capsys):
    """A protocol's options are the fields of its options dataclass: each has
    help, and `--help` shows that help, its unit, its range and its default."""
    from jaxpile.protocols import PROTOCOLS
    from jaxpile.protocols.spec import declared

    for name, spec in PROTOCOLS.items():
        for option in declared(spec.options).values():
            assert option.help, (name, option.name)
    with pytest.raises(SystemExit):
        main(["pile", "--protocol", "pour", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    polydispersity = declared(PROTOCOLS["pour"].options)["polydispersity"]
    assert f"--polydispersity X {polydispersity.help}" in text
    assert f"[{polydispersity.range.describe()}]" in text and f"(default {polydispersity.default})" in text


def test_every_protocol_module_registers_its_spec_and_its_presentation_names_its_options():
    """The registry is the modules that declare a `SPEC` (no list to edit), in
    the papers' order; each spec's size and generic flags name its options."""
    import importlib
    import pkgutil

    from jaxpile.batches import BATCHES
    from jaxpile.cli.presentation import PRESENTATIONS, listed, presentation

    from jaxpile import protocols
    from jaxpile.laws import LAWS
    from jaxpile.protocols import PROTOCOLS

    declaring = [getattr(importlib.import_module(f"jaxpile.protocols.{info.name}"), "SPEC", None)
                 for info in pkgutil.iter_modules(protocols.__path__)]
    assert sorted(PROTOCOLS) == sorted(s.name for s in declaring if s is not None)
    # the commands list the papers' seven first, in the papers' order; a protocol added later after them
    assert listed(PROTOCOLS)[:7] == ["lattice", "sloped", "drop", "box", "tilt", "flux", "pour"]
    assert set(PRESENTATIONS) == set(PROTOCOLS) == set(BATCHES)  # each shown and batched by name
    for name, spec in PROTOCOLS.items():
        assert spec.default_law in LAWS and presentation(name).help
        names = set().union(*(s.options.names() for s in spec.chain()))
        assert spec.chain()[0].size in names, (name, spec.size)
        assert set(presentation(name).flags.values()) <= names | {"seed"}, name


def test_a_new_protocol_spec_appears_in_pile_sweep_and_fit_by_declaring_itself(monkeypatch):
    """A registered `ProtocolSpec` is all a new protocol needs for the commands to take it."""
    import dataclasses

    from jaxpile import batches, cli
    from jaxpile.batches import BATCHES
    from jaxpile.cli.presentation import PRESENTATIONS
    from jaxpile.protocols import PROTOCOLS

    box = PROTOCOLS["box"]
    silo = dataclasses.replace(box, name="silo")
    monkeypatch.setitem(PROTOCOLS, "silo", silo)
    monkeypatch.setitem(PRESENTATIONS, "silo", dataclasses.replace(
        PRESENTATIONS["box"], order=99, help="a silo emptied through an orifice"))
    monkeypatch.setitem(BATCHES, "silo", BATCHES["box"])
    assert cli.sweep_protocols()[-1] == "silo" and batches.spec_of("silo") is silo
    for command in ("pile", "sweep", "fit"):
        argv = [command, "--protocol", "silo", "--out", "x"] + (["--params", "mu"] if command == "fit" else [])
        assert cli.build_parser(argv).parse_args(argv).protocol == "silo"
