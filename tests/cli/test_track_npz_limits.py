"""The byte limit of a measurement NPZ read by ``python -m imm_gym.track`` at its figure: 1 GiB
(2**30 = 1 073 741 824 bytes) of arrays together, counted over every entry from the headers
before an entry past it is allocated; and the ``.npy`` formats it reads (1.0 and 2.0, no
other)."""

from __future__ import annotations

import io
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from helpers import npy_bytes

from imm_gym import Sonar
from imm_gym.cli.recordings import read_npz
from imm_gym.validation import ConfigError

_Z = np.array([[1000.0, 0.1], [1010.0, 0.1], [1020.0, 0.1]])  # 3 x 2 x 8 = 48 bytes
GIB = 1_073_741_824


def _claiming(path: Path, entries: list[tuple[str, bytes, int | None]]) -> None:
    """An NPZ of stored entries ``(name, data, claimed)``: where ``claimed`` is given, the
    archive's central directory says the entry unpacks to that many bytes (an entry whose size
    agrees with the header it holds, as a huge honest entry's would)."""
    with zipfile.ZipFile(path, "w") as archive:
        for name, data, _ in entries:
            archive.writestr(name, data)
    raw = bytearray(path.read_bytes())
    at = raw.find(b"PK\x01\x02")
    for name, _, claimed in entries:
        assert raw[at + 46 : at + 46 + len(name)] == name.encode()
        if claimed is not None:
            raw[at + 24 : at + 28] = struct.pack("<I", claimed)  # uncompressed size
        size_name, size_extra, size_comment = struct.unpack("<HHH", raw[at + 28 : at + 34])
        at += 46 + size_name + size_extra + size_comment
    path.write_bytes(bytes(raw))


def _saved(value: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, value)
    return buffer.getvalue()


def test_arrays_past_one_gib_together_are_refused_before_the_entry_is_read(
    tmp_path: Path,
) -> None:
    """z (48 bytes, read) and a detected whose header and entry claim 2**30 - 47 bytes: 48 +
    1 073 741 777 = 1 073 741 825 bytes together, one past 1 GiB, each entry alone within it.
    Refused naming the limit and detected, before detected is read."""
    claims = "{'descr': '|b1', 'fortran_order': False, 'shape': (1073741777,), }"
    _claiming(tmp_path / "big.npz", [("z.npy", _saved(_Z), None),
                                     ("detected.npy", npy_bytes(claims, b"\1" * 64), 2**30)])
    with pytest.raises(ConfigError, match=rf"big\.npz: its arrays hold more than {GIB} bytes "
                       r"\(detected: shape \(1073741777,\) of bool\); split the recording"):
        read_npz(tmp_path / "big.npz", Sonar())


def test_one_entry_past_one_gib_is_refused_and_one_at_it_is_read(tmp_path: Path) -> None:
    """z claiming (67108865, 2) float64 = 67 108 865 x 16 = 1 073 741 840 bytes, 16 past 1 GiB,
    its entry as large: refused by the limit. At (67108864, 2), 1 GiB exactly, the limit
    passes and the reader goes on to the entry (whose 64 bytes are all it holds: refused as
    unreadable, not as too large)."""
    over = "{'descr': '<f8', 'fortran_order': False, 'shape': (67108865, 2), }"
    entry = npy_bytes(over, b"\0" * 64)
    _claiming(tmp_path / "over.npz", [("z.npy", entry, 67108865 * 16 + 128)])
    with pytest.raises(ConfigError, match=rf"over\.npz: its arrays hold more than {GIB} bytes "
                       r"\(z: shape \(67108865, 2\) of float64\)"):
        read_npz(tmp_path / "over.npz", Sonar())
    at = "{'descr': '<f8', 'fortran_order': False, 'shape': (67108864, 2), }"
    _claiming(tmp_path / "at.npz", [("z.npy", npy_bytes(at, b"\0" * 64), GIB + 128)])
    with pytest.raises(ConfigError, match=r"at\.npz: cannot read its array z") as refused:
        read_npz(tmp_path / "at.npz", Sonar())
    assert "more than" not in str(refused.value)


@pytest.mark.parametrize("version", [(1, 0), (2, 0)])
def test_npy_formats_one_and_two_are_read(tmp_path: Path, version: tuple[int, int]) -> None:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, _Z, version=version)
    _claiming(tmp_path / "z.npz", [("z.npy", buffer.getvalue(), None)])
    np.testing.assert_array_equal(read_npz(tmp_path / "z.npz", Sonar())[0]["z"], _Z)


def test_an_npy_of_another_format_is_refused_naming_it(tmp_path: Path) -> None:
    """Format 3.0 (a UTF-8 header) is not one the reader says it takes: refused, not read."""
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, _Z, version=(3, 0))
    _claiming(tmp_path / "z.npz", [("z.npy", buffer.getvalue(), None)])
    with pytest.raises(ConfigError, match=r"z\.npz: cannot read its array z \(a \.npy of "
                       r"format \(3, 0\), not 1\.0 or 2\.0\)"):
        read_npz(tmp_path / "z.npz", Sonar())
