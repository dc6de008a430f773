"""``python -m imm_gym.track`` on files a user (or an attacker) might hand it: an NPZ whose
headers claim more than it holds, object arrays, entries given twice, booleans for numbers; a
first detection that cannot start a track; a CSV cell past the csv module's limit; a path that
is not a regular file; and a long recording beside many short ones. Each is refused naming the
file and the array, line or sequence, before any policy is built and before anything is
allocated, or tracked as its sequences alone are."""

from __future__ import annotations

import os
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers import npy_bytes

import imm_gym
import imm_gym.cli.recordings as recordings
from baselines import make_baseline
from imm_gym import EnvConfig, Sonar
from imm_gym.cli.recordings import read_csv, read_npz
from imm_gym.cli.track import batches, main, run
from imm_gym.validation import ConfigError

_Z = np.array([[1000.0, 0.1], [1010.0, 0.1], [1020.0, 0.1]])


class _Payload:
    """Unpickled, it creates ``marker``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):  # type: ignore[no-untyped-def]
        return (open, (str(self.marker), "w"))


def test_an_npz_whose_header_claims_terabytes_is_refused_before_it_is_allocated(
    tmp_path: Path,
) -> None:
    """A 64-byte payload under a header of shape (1e12, 2) ran numpy into a 14.6 TiB
    allocation and a traceback; the claim is checked against the entry's size first."""
    claims = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 2), }"
    with zipfile.ZipFile(tmp_path / "bomb.npz", "w") as archive:
        archive.writestr("z.npy", npy_bytes(claims, b"\0" * 64))
    with pytest.raises(ConfigError, match=r"bomb\.npz: z claims shape \(1000000000000, 2\) of "
                       r"float64 \(16000000000000 bytes\), but its entry unpacks to \d+ bytes"):
        read_npz(tmp_path / "bomb.npz", Sonar())


def test_arrays_past_the_byte_limit_are_refused_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """However honestly packed (a deflated entry unpacks to what its header says), the arrays
    of one file hold MAX_NPZ_BYTES at most: 3 rows of float64 z are 48 bytes."""
    np.savez_compressed(tmp_path / "z.npz", z=_Z)
    monkeypatch.setattr(recordings, "MAX_NPZ_BYTES", 47)
    with pytest.raises(ConfigError, match=r"z\.npz: its arrays hold more than 47 bytes \(z: "
                       r"shape \(3, 2\) of float64\)"):
        read_npz(tmp_path / "z.npz", Sonar())
    monkeypatch.setattr(recordings, "MAX_NPZ_BYTES", 48)
    np.testing.assert_array_equal(read_npz(tmp_path / "z.npz", Sonar())[0]["z"], _Z)


def test_an_object_array_is_refused_as_not_numbers_and_not_unpickled(tmp_path: Path) -> None:
    marker = tmp_path / "unpickled"
    pickle.loads(pickle.dumps(_Payload(marker))).close()
    assert marker.exists()  # the payload fires when unpickled
    marker.unlink()
    np.savez(tmp_path / "obj.npz", z=np.array([_Payload(marker), 1.0], dtype=object))
    with pytest.raises(ConfigError, match=r"obj\.npz: z must hold numbers, got dtype object"):
        read_npz(tmp_path / "obj.npz", Sonar())
    assert not marker.exists()


@pytest.mark.parametrize(
    ("entries", "message"),
    [
        ([("z.npy", _Z), ("z.npy", np.full_like(_Z, np.nan))],
         r"holds \['z\.npy'\] twice; numpy would read one of them silently"),
        ([("z.npy", _Z), ("notes.txt", None)], r"'notes\.txt' is not a \.npy array"),
        ([("z.npy", _Z.astype(bool))], r"z must hold numbers, got dtype bool"),
    ],
)
def test_entries_given_twice_or_not_arrays_and_boolean_z_are_refused(
    tmp_path: Path, entries, message
) -> None:
    """Two z.npy entries: numpy read the last one silently (another reader may read the
    first); z of booleans was tracked as ranges of 1 m (only ``detected`` may be boolean)."""
    import io
    import warnings

    with zipfile.ZipFile(tmp_path / "f.npz", "w") as archive, warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # zipfile: a duplicate name
        for name, value in entries:
            buffer = io.BytesIO()
            if value is None:
                buffer.write(b"text")
            else:
                np.save(buffer, value)
            archive.writestr(name, buffer.getvalue())
    with pytest.raises(ConfigError, match=message):
        read_npz(tmp_path / "f.npz", Sonar())


def test_a_first_detection_that_cannot_start_a_track_is_refused_by_its_line_or_sequence(
    tmp_path: Path,
) -> None:
    """A range of 0 (no bearing across it) or of 1e-300 m makes the start's position
    covariance singular: refused naming the CSV line and sequence, or the NPZ sequence (it was
    refused after tracking began, naming the sensor's noise and no row); a small range later
    in a sequence is a filter step like any."""
    rows = ["z0,z1,sequence", "5000,0.5,A", "5010,0.5,A", "0,0,B", "5010,0.5,B"]
    (tmp_path / "z.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(ConfigError, match=r"z\.csv:4: the first row of sequence 'B', z \[0\.0, "
                       r"0\.0\], cannot start a track: .* a range of 0 has no bearing"):
        read_csv(tmp_path / "z.csv", Sonar())
    z = np.stack([_Z, np.vstack([[1e-300, 0.2], _Z[1:]])])
    np.savez(tmp_path / "z.npz", z=z)
    with pytest.raises(ConfigError, match=r"z\.npz: sequence 1: z's first row, \[1e-300, 0\.2\], "
                       "cannot start a track"):
        read_npz(tmp_path / "z.npz", Sonar())
    np.savez(tmp_path / "late.npz", z=np.vstack([_Z, [[0.0, 0.0]]]))
    assert read_npz(tmp_path / "late.npz", Sonar())[0]["z"][3].tolist() == [0.0, 0.0]


def test_a_digit_separator_is_not_a_number_in_data(tmp_path: Path) -> None:
    """Python's float reads '5_000' as 5000; a CSV cell with one is refused, as '5,0' is."""
    (tmp_path / "z.csv").write_text("z0,z1\n5000,0.5\n5_010,0.5\n")
    with pytest.raises(ConfigError, match=r"z\.csv:3: sequence '0': column z0: '5_010' is not a "
                       "number"):
        read_csv(tmp_path / "z.csv", Sonar())


def test_a_cell_past_the_csv_limit_names_its_line(tmp_path: Path) -> None:
    (tmp_path / "z.csv").write_text("z0,z1\n5000,0.5\n" + "7" * 200_000 + ",0.5\n")
    with pytest.raises(ConfigError, match=r"z\.csv:3: not a row of measurements \(field larger "
                       r"than field limit .*: a quote left open, or a cell of more than"):
        read_csv(tmp_path / "z.csv", Sonar())


def test_a_path_that_is_not_a_regular_file_is_said_so(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A named pipe is refused (not opened: it would wait for a writer) as not a regular file,
    not as missing."""
    os.mkfifo(tmp_path / "pipe.csv")
    with pytest.raises(SystemExit) as exit_info:
        main(["--measurements", str(tmp_path / "pipe.csv"), "--policy", "fixed",
              "--out", str(tmp_path / "o.csv")])
    assert exit_info.value.code == 2
    assert "pipe.csv: not a regular file" in capsys.readouterr().err


def test_batches_pad_like_lengths_together_and_split_a_long_one_from_many_short() -> None:
    """By hand, longest first, a sequence joining while the batch's padded steps stay within
    twice its own or the floor (12): 10, 9, 6, 2, 2, 2 pad to 20, 30, 40, 50, 60 steps against
    twice 19, 25, 27, 29, 31: one batch. 40, 2, 2, 2: the first 2 joins the 40 (80 <= 84), the
    next would make 120 > 88 and starts a batch the last joins (4 <= 12)."""
    seq = [(i, {"z": np.zeros((n, 2))}) for i, n in enumerate((2, 10, 2, 6, 9, 2))]
    assert [[i for i, _ in b] for b in batches(seq, 12)] == [[1, 4, 3, 0, 2, 5]]
    seq = [(i, {"z": np.zeros((n, 2))}) for i, n in enumerate((2, 40, 2, 2))]
    assert [[i for i, _ in b] for b in batches(seq, 12)] == [[1, 0], [2, 3]]
    assert len(batches(seq, 1000)) == 1  # within the floor: one batch however padded


def test_sequences_split_into_batches_track_as_each_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A long sequence and three short ones, split into two batches by a small floor: each
    sequence's estimates are those it gets alone, bit for bit (a rule), in the input's order."""
    import imm_gym.cli.track as track

    core = imm_gym.TrackingCore(EnvConfig(), n_envs=4)
    core.reset(np.arange(4), [5, 6, 7, 8])
    lengths = (60, 3, 4, 3)
    sequences = [{"name": str(n), "z": core.z[n, : k + 1]} for n, k in enumerate(lengths)]
    calls = []

    def counted(z, *args, **kwargs):
        calls.append(np.shape(z)[:2])
        return imm_gym.run_policy(z, *args, **kwargs)

    monkeypatch.setattr(track, "run_policy", counted)
    monkeypatch.setattr(track, "PADDED_STEPS", 12)
    results = run(sequences, make_baseline("fixed"), EnvConfig(), None, {})
    assert calls == [(2, 61), (2, 4)]  # 61 and 5 rows (122 <= 132), then 4 and 4
    for (name, result), n, k in zip(results, range(4), lengths, strict=True):
        alone = imm_gym.run_policy(core.z[n, : k + 1], make_baseline("fixed"), EnvConfig())
        assert name == str(n)
        np.testing.assert_array_equal(result.estimate[0], alone.estimate[0])
