"""`jaxpile show`: a run's figures drawn again from its files (finished or
checkpointed), and the files a pile run leaves for other programs."""

import numpy as np
import pytest

from jaxpile import export, io
from jaxpile.cli import main

RUN = ["pile", "--protocol", "lattice", "--layers", "5", "--ramp-steps", "1000", "--max-steps", "3000",
       "--checkpoint-every", "1000", "--no-progress"]


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


@pytest.mark.parametrize("which", ["finished", "checkpoint"])
def test_show_redraws_the_figures_without_running(finished_run, tmp_path, capsys, which):
    flags = ["--checkpoint"] if which == "checkpoint" else []
    assert main(["show", str(finished_run), "--out", str(tmp_path), *flags]) == 0
    assert "pile.png, profile.png" in capsys.readouterr().out
    for name in ("pile.png", "profile.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert (tmp_path / name).stat().st_size > 10_000  # a drawn figure, not an empty canvas


def test_show_of_a_folder_without_a_run_is_a_clear_error(tmp_path, capsys):
    assert main(["show", str(tmp_path)]) == 2
    assert "neither a finished" in capsys.readouterr().err
