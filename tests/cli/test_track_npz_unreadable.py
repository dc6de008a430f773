"""An NPZ entry that cannot be unpacked — its deflate stream garbled, or the archive ending
before the bytes its entry claims — is refused naming the file and the array (not a zlib or
EOF traceback)."""

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


def test_a_garbled_deflate_stream_is_refused_naming_the_array(tmp_path: Path) -> None:
    buffer = io.BytesIO()
    np.save(buffer, np.column_stack([1000.0 + np.arange(50.0), np.full(50, 0.1)]))
    path = tmp_path / "garbled.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("z.npy", buffer.getvalue())
    raw = bytearray(path.read_bytes())
    start = 30 + len("z.npy")  # the local header, then the deflate stream
    raw[start : start + 8] = b"\xff" * 8  # an invalid block type
    path.write_bytes(bytes(raw))
    with pytest.raises(ConfigError, match=r"garbled\.npz: cannot read its array z \(Error -3 "
                       "while decompressing data"):
        read_npz(path, Sonar())


def test_an_archive_ending_before_its_entry_is_refused_naming_the_array(tmp_path: Path) -> None:
    """z claims (1000, 2) float64, 16 000 bytes, and its entry as many; the file holds 64."""
    npy = npy_bytes("{'descr': '<f8', 'fortran_order': False, 'shape': (1000, 2), }", b"\0" * 64)
    path = tmp_path / "short.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("z.npy", npy)
    raw = bytearray(path.read_bytes())
    at = raw.find(b"PK\x01\x02")  # the central directory: compressed, then unpacked size
    raw[at + 20 : at + 28] = struct.pack("<II", *[len(npy) - 64 + 16_000] * 2)
    path.write_bytes(bytes(raw))
    with pytest.raises(ConfigError, match=r"short\.npz: cannot read its array z"):
        read_npz(path, Sonar())
