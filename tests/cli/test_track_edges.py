"""python -m imm_gym.track at its edges, each against a value worked by hand."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from imm_gym.cli.track import main, tpm_columns


def test_tpm_columns_of_ten_models_are_digits_and_of_eleven_separated() -> None:
    """Ten models name entry (i, j) tpm{i}{j} without ambiguity (one digit each); from eleven
    on, tpm{i}_{j}."""
    ten = tpm_columns(10)
    assert ten[:3] == ["tpm00", "tpm01", "tpm02"] and ten[-1] == "tpm99" and len(set(ten)) == 100
    eleven = tpm_columns(11)
    assert eleven[:2] == ["tpm0_0", "tpm0_1"] and eleven[-1] == "tpm10_10"


def test_eleven_diverged_tracks_name_ten_and_count_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Eleven sequences each sent to NaN by an absurd range at its second step: stderr counts
    eleven, names the first ten with their step and says "and 1 more"."""
    names = [f"s{i:02d}" for i in range(11)]
    rows = ["sequence,z0,z1"]
    for name in names:
        rows += [f"{name},1000,0.1", f"{name},1010,0.1", f"{name},1e300,0.1", f"{name},1030,0.1"]
    (tmp_path / "z.csv").write_text("\n".join(rows) + "\n")
    assert main(["--measurements", str(tmp_path / "z.csv"), "--policy", "fixed",
                 "--out", str(tmp_path / "out.csv")]) == 0
    err = " ".join(capsys.readouterr().err.split())
    listed = ", ".join(f"'{name}' at step 2" for name in names[:10])
    assert "warning: 11 track(s) diverged" in err
    assert f"1 from then on): {listed} and 1 more" in err, err
    assert "'s10'" not in err


def test_an_npz_with_a_velocity_and_x0_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """x0 and P0 start the track themselves: a velocity beside them would be ignored, so the
    file is refused naming it."""
    z = np.array([[1000.0, 0.1], [1010.0, 0.1], [1020.0, 0.1]])
    np.savez(tmp_path / "z.npz", z=z, x0=np.array([995.0, 99.8, 0.0, 0.0]),
             P0=100.0 * np.eye(4), velocity=np.array([3.0, -4.0]))
    with pytest.raises(SystemExit) as exit_info:
        main(["--measurements", str(tmp_path / "z.npz"), "--policy", "fixed",
              "--out", str(tmp_path / "out.npz")])
    assert exit_info.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert re.search(r"z.npz: a track starts from velocity, or from x0 and P0 together, got "
                     r"velocity, x0, P0", err), err
    assert not (tmp_path / "out.npz").exists()
