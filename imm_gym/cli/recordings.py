"""Recorded measurements read for ``python -m imm_gym.track``: a CSV or NPZ file's sequences,
each checked before any tracking (a bad cell, row or array refused naming the file, the line and
the sequence; nothing unpickled).

Input, by the file's suffix:

* ``.csv``: a header and one row per step; columns ``z0 .. z{m-1}`` (the sensor's components in
  its order: the sonar's range in m and bearing in rad), optionally ``sequence`` (rows of a
  sequence are consecutive, none empty; default: one sequence), ``detected`` (0/1; default: 1
  where every ``z`` cell is a number, 0 where every one is empty) and ``vx``, ``vy`` (the initial
  velocity in m/s, from a sequence's first row: both empty, none given; later rows leave them
  empty or repeat them). The first row of a sequence initiates the track (a detection); each
  later row is one filter step, at least one. A ``z`` cell is a finite number or empty; a row
  with more or fewer cells than the header, or a bad cell, is refused naming the file, the line
  and the sequence. Detections outside the sensor's units (a negative range, a bearing beyond
  ``2 pi``: degrees, likely) are told of on stderr, the first named, and tracked as given.
* ``.npz``: ``z (N, K+1, m)`` or ``(K+1, m)``, optionally ``detected`` (default: 1 where every
  ``z`` cell is finite, 0 where every one is NaN), ``velocity (N, 2)``, or ``x0 (N, 4)`` and
  ``P0 (N, 4, 4)`` (read without unpickling, each entry's header checked before its array is
  allocated: :func:`_npz_arrays`).

A sequence's first row must start a track (:func:`unstartable`: not a range of 0).

A CSV is UTF-8 (a byte order mark is dropped); a file that cannot be read is refused naming it.
"""

from __future__ import annotations

import csv
import math
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.sim.replay import start_problem
from imm_gym.tracking.initiation import check_factorable
from imm_gym.tracking.sensors import Sonar
from imm_gym.validation import ConfigError

#: Optional input columns of a CSV file besides ``z0 .. z{m-1}``.
OPTIONAL_COLUMNS = ("sequence", "detected", "vx", "vy")
#: The most bytes the arrays of a measurement NPZ may hold together: 1 GiB, 67 million
#: range-bearing rows of float64.
MAX_NPZ_BYTES = 2**30
#: What reading an NPZ entry raises for a file that is not what it says (a bad header or
#: payload, a corrupt or unsupported compression, an entry cut short).
UNREADABLE = (ValueError, EOFError, OSError, zipfile.BadZipFile, zlib.error, NotImplementedError)


def read_csv(path: Path, sensor: Sonar) -> list[dict[str, Any]]:
    """The sequences of a measurement CSV: per sequence ``name``, ``z (K+1, m)``, ``detected``
    and ``velocity`` (None where not given).

    Every row has the header's cells; a ``z`` cell is a finite number or empty, a missed
    detection leaving every ``z`` cell of its row empty (or ``detected`` 0, its ``z`` cells then
    unused); ``detected`` is 0 or 1; a ``sequence`` cell is not empty; a sequence
    has two rows or more (the track's start and a step). Anything else (an empty file too) is
    refused naming the file, the line and the sequence."""
    header, rows = _csv_rows(path)
    z_cols = [f"z{i}" for i in range(sensor.dim_z)]
    if not header:  # no cell in line 1
        raise ConfigError(
            f"{path}: "
            + ("line 1, the header, is empty" if rows else "the file is empty")
            + f": it starts with a header of columns {', '.join(z_cols)} (and optionally "
            f"{', '.join(OPTIONAL_COLUMNS)})"
        )
    unknown = [c for c in header if c not in z_cols and c not in OPTIONAL_COLUMNS]
    if [c for c in z_cols if c not in header] or unknown:
        raise ConfigError(
            f"{path}: columns must be {', '.join(z_cols)} and optionally "
            f"{', '.join(OPTIONAL_COLUMNS)}; got {', '.join(header)}"
        )
    twice = sorted({c for c in header if header.count(c) > 1})
    if twice:
        raise ConfigError(f"{path}: column(s) {', '.join(twice)} given more than once")
    if ("vx" in header) != ("vy" in header):
        raise ConfigError(
            f"{path}: the initial velocity needs both columns vx and vy; got only "
            f"{'vx' if 'vx' in header else 'vy'}"
        )
    column = {c: i for i, c in enumerate(header)}
    groups: dict[str, list[dict[str, str]]] = {}
    lines: dict[str, list[int]] = {}  # the file line of each row of each sequence
    previous = None
    for line, cells in rows:
        if len(cells) != len(header):
            where = f"{path}:{line}"  # and the sequence, where the row says it
            if "sequence" not in column:
                where += ": sequence '0'"
            elif column["sequence"] < len(cells):
                where += f": sequence {cells[column['sequence']]!r}"
            raise ConfigError(
                f"{where}: {len(cells)} cell(s) where the header has {len(header)} "
                f"({', '.join(header)})"
            )
        name = cells[column["sequence"]] if "sequence" in column else "0"
        if name.strip() == "":
            raise ConfigError(
                f"{path}:{line}: the sequence cell is empty: with a column sequence, every row "
                "names its sequence"
            )
        if name in groups and name != previous:
            raise ConfigError(f"{path}:{line}: the rows of sequence {name!r} are not consecutive")
        groups.setdefault(name, []).append(dict(zip(header, cells, strict=True)))
        lines.setdefault(name, []).append(line)
        previous = name
    sequences = []
    for name, group in groups.items():
        at = lines[name]
        z = np.array([
            [_number(path, line, name, c, row[c]) for c in z_cols]
            for line, row in zip(at, group, strict=True)
        ])
        detected = (
            np.array([
                _flag(path, line, name, row["detected"])
                for line, row in zip(at, group, strict=True)
            ])
            if "detected" in header
            else None
        )
        finite = np.all(np.isfinite(z), axis=1)
        bad = unusable_row(z, finite if detected is None else detected)
        if bad == 0:
            raise ConfigError(
                f"{path}:{at[0]}: the first row of sequence {name!r} initiates the track: it "
                "needs a number in every z cell" + ("" if detected is None else " and detected 1")
            )
        partial = ~finite & ~np.all(np.isnan(z), axis=1)
        if detected is None and np.any(partial):
            raise ConfigError(
                f"{path}:{at[int(np.flatnonzero(partial)[0])]}: sequence {name!r}: some z cells "
                "are empty and some not; a missed detection leaves every z cell empty (or give "
                "a column detected)"
            )
        if bad is not None:
            raise ConfigError(
                f"{path}:{at[bad]}: sequence {name!r}: a detection (detected 1) needs a number "
                "in every z cell"
            )
        if unstartable(sensor, z[0]):
            raise ConfigError(
                f"{path}:{at[0]}: the first row of sequence {name!r}, z {z[0].tolist()}, "
                + UNSTARTABLE
            )
        det = finite if detected is None else detected
        odd = implausible_rows(sensor, z, det)
        velocity = _velocity(path, at, name, group) if "vx" in header else None
        sequences.append({
            "name": name, "z": z, "detected": detected, "velocity": velocity,
            "implausible": [f"{path}:{at[k]}: sequence {name!r}: z {z[k].tolist()}" for k in odd],
        })
    for name, at in lines.items():  # after every cell is read: a bad cell is said first
        if len(at) < 2:
            raise ConfigError(
                f"{path}:{at[0]}: sequence {name!r} has one row, the track's start: it needs a "
                "second row (a filter step) or more"
            )
    return sequences


def _csv_rows(path: Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """A CSV file's header and its rows as ``(file line, cells)``, a blank line skipped (as
    :class:`csv.DictReader` does); UTF-8, a byte order mark (a spreadsheet's) dropped.

    Raises:
        ConfigError: the file cannot be read, is not UTF-8 text or not CSV, naming it.
    """
    reader = None
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            header = next(reader, [])
            return header, [(reader.line_num, cells) for cells in reader if cells]
    except UnicodeDecodeError as err:
        raise ConfigError(
            f"{path}: not UTF-8 text (byte {err.start}: {err.reason}); save it as UTF-8"
        ) from None
    except csv.Error as err:  # a cell past the csv module's limit, or a quote left open
        line = "" if reader is None else f":{reader.line_num}"
        raise ConfigError(
            f"{path}{line}: not a row of measurements ({err}: a quote left open, or a cell of "
            f"more than {csv.field_size_limit()} characters)"
        ) from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read ({err.strerror or err})") from None


def _velocity(
    path: Path, lines: list[int], name: str, group: list[dict[str, str]]
) -> np.ndarray | None:
    """A sequence's initial velocity: its first row's ``vx, vy`` (both empty: none given).
    Later rows leave them empty or repeat them; a row that gives another velocity is refused,
    since only the first row's is used."""
    cells = tuple([row[c].strip() for row in group] for c in ("vx", "vy"))
    if (cells[0][0] == "") != (cells[1][0] == ""):
        raise ConfigError(
            f"{path}:{lines[0]}: sequence {name!r} gives only one of vx and vy in its first row "
            "(both or neither)"
        )
    first = [_number(path, lines[0], name, c, group[0][c]) for c in ("vx", "vy")]
    for i in range(1, len(group)):
        later = (cells[0][i], cells[1][i])
        if later == ("", ""):
            continue
        values = [_number(path, lines[i], name, c, group[i][c]) for c in ("vx", "vy")]
        if not np.array_equal(values, first, equal_nan=True):  # 3 and 3.0 are the same
            raise ConfigError(
                f"{path}:{lines[i]}: vx, vy are the initial velocity, read from sequence "
                f"{name!r}'s first row ({cells[0][0]}, {cells[1][0]}); later rows leave them "
                f"empty or repeat them, got ({later[0]}, {later[1]})"
            )
    return None if cells[0][0] == "" else np.array(first)


def _number(path: Path, line: int, name: str, column: str, text: str) -> float:
    """A CSV cell of sequence ``name`` as a finite float (an empty cell is NaN); a digit
    separator, which Python's ``float`` takes (``5_000``), is not a number in data."""
    if text.strip() == "":
        return float("nan")
    try:
        value = None if "_" in text else float(text)
    except ValueError:
        value = None
    if value is None or not np.isfinite(value):
        raise ConfigError(
            f"{path}:{line}: sequence {name!r}: column {column}: {text!r} is not a "
            + ("number" if value is None else "finite number")
        )
    return value


def _flag(path: Path, line: int, name: str, text: str) -> bool:
    """A ``detected`` cell: 1 (a detection) or 0 (a missed one)."""
    try:
        value = float(text)
    except ValueError:
        value = None
    if value not in (0.0, 1.0):
        raise ConfigError(
            f"{path}:{line}: sequence {name!r}: column detected: {text!r} is not 0 or 1"
        )
    return value == 1.0


def unstartable(sensor: Sonar, z0: NDArray[np.float64]) -> bool:
    """Whether a first detection ``z0 (m,)`` cannot start a track: the covariance of its
    position, ``J R J^T`` (:meth:`~imm_gym.tracking.sensors.Sonar.initial_position`), does not
    factor in float64 — a range of 0 (no bearing across it), or one at which ``sigma_r`` and
    ``range * sigma_theta`` differ by about 1e7 or more
    (:func:`~imm_gym.tracking.initiation.check_factorable`)."""
    _, cov = sensor.initial_position(z0[None])
    try:
        check_factorable(sensor, cov)
    except ConfigError:
        return True
    return False


#: Why :func:`unstartable` refuses a first row.
UNSTARTABLE = (
    "cannot start a track: its position's covariance (the sonar's sigma_r along range, range x "
    "sigma_theta across it) is singular in float64 — a range of 0 has no bearing, and the two "
    "may differ by a factor of about 1e7 at most"
)


def unusable_row(z: NDArray[np.float64], detected: NDArray[np.bool_]) -> int | None:
    """The first row of one sequence's ``z`` ``(K + 1, dim_z)`` the tracker cannot take: row 0
    unless it is a detection with a number in every cell (it initiates the track), else the
    first detection with a cell that is not a number; None if there is none."""
    finite = np.all(np.isfinite(z), axis=1)
    if not (detected[0] and finite[0]):
        return 0
    rows = np.flatnonzero(detected & ~finite)
    return int(rows[0]) if rows.size else None


def _npz_arrays(path: Path) -> dict[str, NDArray[Any]]:
    """The arrays of an NPZ archive by name, read without unpickling: each entry a ``.npy``
    array (format 1.0 or 2.0) of a numeric dtype, named once, its header's shape within the
    bytes its entry unpacks to and the arrays within :data:`MAX_NPZ_BYTES` together — checked
    from the headers before any array is allocated, so that a small file claiming or unpacking
    to terabytes is refused, not allocated.

    Raises:
        ConfigError: anything else, naming the file and the array.
    """
    single = False
    try:
        with path.open("rb") as handle:
            single = handle.read(6) == b"\x93NUMPY"
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, EOFError, ValueError) as err:
        if single:
            raise ConfigError(
                f"{path}: one .npy array, not an NPZ archive of named arrays (numpy.savez)"
            ) from None
        raise ConfigError(
            f"{path}: not an NPZ archive of arrays, as numpy.savez writes ({err})"
        ) from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read ({err.strerror or err})") from None
    arrays: dict[str, NDArray[Any]] = {}
    total = 0
    with archive:
        members = archive.infolist()
        names = [member.filename for member in members]
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:
            raise ConfigError(f"{path}: holds {twice} twice; numpy would read one of them silently")
        for member in members:
            key = member.filename.removesuffix(".npy")
            if key == member.filename:
                raise ConfigError(
                    f"{path}: {member.filename!r} is not a .npy array; an NPZ holds arrays only"
                )
            try:
                with archive.open(member) as handle:
                    version = np.lib.format.read_magic(handle)
                    if version not in ((1, 0), (2, 0)):
                        raise ValueError(f"a .npy of format {version}, not 1.0 or 2.0")
                    header = (
                        np.lib.format.read_array_header_1_0
                        if version == (1, 0)
                        else np.lib.format.read_array_header_2_0
                    )
                    shape, _, dtype = header(handle)
            except UNREADABLE as err:
                raise ConfigError(f"{path}: cannot read its array {key} ({err})") from None
            if dtype.hasobject:
                raise ConfigError(f"{path}: {key} must hold numbers, got dtype {dtype}")
            size = math.prod(shape) * dtype.itemsize
            if size > member.file_size:
                raise ConfigError(
                    f"{path}: {key} claims shape {shape} of {dtype} ({size} bytes), but its "
                    f"entry unpacks to {member.file_size} bytes"
                )
            total += size
            if total > MAX_NPZ_BYTES:
                raise ConfigError(
                    f"{path}: its arrays hold more than {MAX_NPZ_BYTES} bytes ({key}: shape "
                    f"{shape} of {dtype}); split the recording"
                )
            try:
                with archive.open(member) as handle:
                    arrays[key] = np.lib.format.read_array(handle, allow_pickle=False)
            except UNREADABLE as err:
                raise ConfigError(f"{path}: cannot read its array {key} ({err})") from None
    return arrays


def read_npz(path: Path, sensor: Sonar) -> list[dict[str, Any]]:
    """The sequences of a measurement NPZ (see the module docstring): its arrays numbers of the
    shapes z gives, ``detected`` 0 or 1, ``z`` finite or NaN (a missed detection: without
    ``detected``, NaN in every cell of its row), the rest finite, a velocity or ``x0`` and
    ``P0`` (``P0`` symmetric positive definite); anything else refused naming the file."""
    dim_z = sensor.dim_z
    arrays = _npz_arrays(path)
    if "z" not in arrays:
        raise ConfigError(f"{path}: needs an array 'z' (N, K+1, m)")
    unknown = set(arrays) - {"z", "detected", "velocity", "x0", "P0"}
    if unknown:
        raise ConfigError(f"{path}: unknown arrays {sorted(unknown)}")
    for key, value in arrays.items():
        if value.dtype.kind not in ("biuf" if key == "detected" else "iuf"):
            raise ConfigError(f"{path}: {key} must hold numbers, got dtype {value.dtype}")
    z = arrays.pop("z").astype(np.float64)
    given = z.shape
    single = z.ndim == 2
    z = z[None] if single else z
    if z.ndim != 3 or z.shape[2] != dim_z or z.shape[1] < 2:
        raise ConfigError(
            f"{path}: z must be (N, K+1, {dim_z}) or (K+1, {dim_z}) with K >= 1 (the track's "
            f"start and a step or more), got {given}"
        )
    N, K1 = z.shape[:2]
    if ("x0" in arrays) != ("P0" in arrays) or ("x0" in arrays and "velocity" in arrays):
        raise ConfigError(
            f"{path}: a track starts from velocity, or from x0 and P0 together, got "
            f"{', '.join(k for k in ('velocity', 'x0', 'P0') if k in arrays)}"
        )
    shapes = {"detected": (K1,), "velocity": (2,), "x0": (4,), "P0": (4, 4)}
    extra = {}
    for key, value in arrays.items():
        want = shapes[key] if single else (N, *shapes[key])
        if value.shape != want:
            raise ConfigError(f"{path}: {key} must be {want} for z of shape {given}, got "
                              f"{value.shape}")
        if key == "detected":
            if not np.all((value == 0) | (value == 1)):
                raise ConfigError(f"{path}: detected must be 0 or 1 (or booleans)")
            value = value.astype(bool)
        elif not np.all(np.isfinite(value)):
            raise ConfigError(f"{path}: {key} must be finite")
        extra[key] = value[None] if single else value
    if np.any(np.isinf(z)):
        where = tuple(int(i) for i in np.argwhere(np.isinf(z))[0][1 if single else 0:])
        raise ConfigError(f"{path}: z{list(where)} is infinite (NaN is a missed detection)")
    detected = extra.get("detected", np.all(np.isfinite(z), axis=2))
    partial = ~detected & ~np.all(np.isnan(z), axis=2)  # without detected: some cells NaN
    for i in range(N):
        name = "" if single else f"sequence {i}: "
        bad = unusable_row(z[i], detected[i])
        if bad == 0:
            raise ConfigError(
                f"{path}: {name}z's first row initiates the track: it must be a finite "
                "detection"
            )
        if "detected" not in extra and np.any(partial[i]):
            raise ConfigError(
                f"{path}: {name}z's row {int(np.flatnonzero(partial[i])[0])} has some cells NaN "
                "and some not; a missed detection is NaN in every cell (or give an array "
                "detected)"
            )
        if bad is not None:
            raise ConfigError(f"{path}: {name}z's row {bad} is a detection and not finite")
        if "x0" not in extra and unstartable(sensor, z[i, 0]):
            raise ConfigError(
                f"{path}: {name}z's first row, {z[i, 0].tolist()}, " + UNSTARTABLE
            )
    if "x0" in extra:
        problem = start_problem(extra["x0"], extra["P0"])
        if problem is not None:
            said = problem.removeprefix("sequence 0: ") if single else problem
            raise ConfigError(f"{path}: {said}")
    sequences = []
    for i in range(N):
        name = "" if single else f"sequence {i}: "
        odd = implausible_rows(sensor, z[i], detected[i])
        sequences.append({
            "name": str(i), "z": z[i], **{k: v[i] for k, v in extra.items()},
            "implausible": [f"{path}: {name}z's row {k} {z[i, k].tolist()}" for k in odd],
        })
    return sequences


def implausible_rows(
    sensor: Sonar, z: NDArray[np.float64], detected: NDArray[np.bool_]
) -> list[int]:
    """The detections of one sequence's ``z (K + 1, m)`` outside the sensor's units
    (:meth:`~imm_gym.tracking.sensors.Sonar.implausible`: a negative range, a bearing in
    degrees, likely): told of on stderr, tracked as given."""
    return [int(k) for k in np.flatnonzero(
        detected & sensor.implausible(np.where(detected[:, None], z, 0.0)))]
