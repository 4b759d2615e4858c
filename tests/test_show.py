"""`jaxpile show`: a run's figures drawn again from its files (finished or
checkpointed), and the files a pile run leaves for other programs."""

import numpy as np
import pytest

from jaxpile import export, io
from jaxpile.cli import main
from jaxpile.protocols.lattice import equilateral_positions as lattice_positions

RUN = ["pile", "--protocol", "lattice", "--layers", "5", "--ramp-steps", "1000", "--max-steps", "3000",
       "--checkpoint-every", "1000", "--trajectory-every", "500", "--no-progress"]


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    assert main(RUN + ["--out", str(out)]) == 0
    return out


def test_a_pile_run_leaves_an_xyz_frame_and_a_contact_table(finished_run):
    frame = export.read_xyz(finished_run / "final.xyz")[-1]
    state = io.load_arrays(finished_run / "state.npz")
    np.testing.assert_array_equal(frame["pos"][:, :2], state["particles.position"])
    contacts = io.read_csv(finished_run / "contacts.csv")
    base = io.read_csv(finished_run / "base_forces.csv")
    ground = contacts["j"] == -1
    np.testing.assert_allclose(np.sort(contacts["normal"][ground]), np.sort(base["normal"]), rtol=1e-9)


def test_a_pile_run_records_a_trajectory_that_reads_back(finished_run):
    frames = export.read_xyz(finished_run / "trajectory.xyz")
    steps = [f["step"] for f in frames]
    assert steps[0] == 0 and steps == sorted(set(steps)) and all(s % 500 == 0 for s in steps)
    # frames fall on chunk boundaries (the runner's chunks here are 1000 steps): 0, 1000, 2000, ...
    assert len(frames) >= 3 and steps[1] == 1000
    first = frames[0]["pos"][:, :2]
    np.testing.assert_array_equal(first, np.asarray(lattice_positions(5)))
    assert np.any(frames[-1]["force"][:, 1] < 0)  # gravity is on by the end of the ramp


def test_a_trajectory_cut_back_to_a_checkpoint_keeps_the_frames_up_to_it(finished_run, tmp_path):
    path = tmp_path / "t.xyz"
    path.write_text((finished_run / "trajectory.xyz").read_text())
    assert export.truncate(path, 1200) == 2
    assert [f["step"] for f in export.read_xyz(path)] == [0, 1000]


@pytest.mark.parametrize("which", ["finished", "checkpoint"])
def test_show_redraws_the_figures_without_running(finished_run, tmp_path, capsys, which):
    flags = ["--checkpoint"] if which == "checkpoint" else []
    assert main(["show", str(finished_run), "--out", str(tmp_path), *flags]) == 0
    assert "pile.png, profile.png" in capsys.readouterr().out
    for name in ("pile.png", "profile.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert (tmp_path / name).stat().st_size > 10_000  # a drawn figure, not an empty canvas


def test_show_without_out_writes_beside_the_run_not_over_its_figures(finished_run, tmp_path, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(finished_run, run)
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    assert "pile.png" in before
    assert main(["show", str(run)]) == 0
    assert f"wrote {run / 'shown'}/" in capsys.readouterr().out
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before  # the run's own, untouched
    assert (run / "shown" / "pile.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_show_of_a_folder_without_a_run_is_a_clear_error(tmp_path, capsys):
    assert main(["show", str(tmp_path)]) == 2
    assert "neither a finished" in capsys.readouterr().err
