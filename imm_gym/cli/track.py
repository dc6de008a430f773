"""Any policy on recorded measurements (command line: ``python -m imm_gym.track``).

Example::

    python -m imm_gym.track --measurements radar.csv --policy pretrained --out tracks.csv
    python -m imm_gym.track --measurements radar.npz --policy tip-imm \\
        --env-config my_tracker.yaml --out tracks.npz

Runs :func:`imm_gym.sim.replay.run_policy` (the policy's whole observation pipeline, no truth) on
every recorded sequence and writes, per step, the estimate, its covariance, the mode
probabilities and the TPM used. ``--policy`` is a baseline's name, ``pretrained``,
``pretrained-per-model`` (a bank of any size) or a trained agent's directory, resolved as
``python -m imm_gym.evaluate`` resolves them (a tuned baseline such as ``best-fixed`` is tuned on
simulated runs of the configuration, seeds from ``--seed``: 0 to
:data:`~imm_gym.cli.arguments.MAX_SEED`, as for ``python -m imm_gym.evaluate``).
``--env-config FILE`` (YAML or JSON, :mod:`imm_gym.sim.config_file`) is a mapping of
EnvConfig fields: the sensor (whose components ``z`` are), the bank, the filter, the TPM settings,
the scenario (its sampling period); what it says an agent is trained as
(:data:`~imm_gym.sim.mixture.AGENT_FIELDS`: action mode, features, reward) is dropped, a detector
network it names kept, as ``python -m imm_gym.evaluate`` does (every policy's own settings apply:
a training file runs the rules too). A trained agent keeps its own settings and tracks with this
tracker; an agent whose observation or action size it does not give is refused, one trained on
another tracker is said on stderr.

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
  ``P0 (N, 4, 4)`` (read without unpickling).

A CSV is UTF-8 (a byte order mark is dropped); a file that cannot be read is refused naming it.

Without a velocity the track starts at zero velocity with standard deviation
:data:`~imm_gym.sim.replay.UNKNOWN_VELOCITY_STD`; ``--velocity VX VY`` gives one for every
sequence that has none. The sequences run as one batch (one per kind of start: ``x0``/``P0``,
a velocity, none), the shorter ones padded with missed detections and cut back. A network
policy's matrix products round by the batch's shape, so a sequence tracked beside others can
differ from itself tracked alone in the last bits (about 1e-7 m); the rules do not.
A configuration file that names a scenario other than ``random`` tracks at that scenario's
sampling period, said on stderr (``family`` beside it is refused: it would be ignored).

Output, by the suffix of ``--out`` (checked before any work, its missing directories made):

* ``.csv``: one row per filtered step, the sequences in the input's order: ``sequence, step``
  (1..K), ``x, y, vx, vy``, ``P00 .. P33`` (the covariance, row-major), ``mu0 .. mu{M-1}``,
  ``tpm00 .. tpm{M-1}{M-1}`` (row-major; ``tpm{i}_{j}`` for more than ten models),
  ``diverged`` (1 from the step the track diverged at: its estimate not finite or its position
  variance above ``divergence_cov``; such tracks are also named on stderr);
* ``.npz``: ``estimate (N, K, 4)``, ``covariance (N, K, 4, 4)``, ``mode_probs (N, K, M)``,
  ``tpm (N, K, M, M)``, ``x0``, ``P0``, ``diverged (N,)``, the sequences in the input's order
  (one sequence length only: sequences of several are refused before any work).
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import zipfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from baselines import REGISTRY
from imm_gym.cli.arguments import MAX_SEED, output_problem, seed_problem
from imm_gym.cli.comparison import evaluated_config
from imm_gym.cli.policies import agent_overrides, make_policy
from imm_gym.cli.tables import models_differ_note
from imm_gym.sim.config_file import read_env_config
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.replay import TrackResult, run_policy, start_problem
from imm_gym.tracking.sensors import Sonar
from imm_gym.validation import ConfigError

#: Optional input columns of a CSV file besides ``z0 .. z{m-1}``.
OPTIONAL_COLUMNS = ("sequence", "detected", "vx", "vy")


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
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            header = next(reader, [])
            return header, [(reader.line_num, cells) for cells in reader if cells]
    except UnicodeDecodeError as err:
        raise ConfigError(
            f"{path}: not UTF-8 text (byte {err.start}: {err.reason}); save it as UTF-8"
        ) from None
    except csv.Error as err:
        raise ConfigError(f"{path}: not a CSV file ({err})") from None
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
    """A CSV cell of sequence ``name`` as a finite float (an empty cell is NaN)."""
    if text.strip() == "":
        return float("nan")
    try:
        value = float(text)
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


def unusable_row(z: NDArray[np.float64], detected: NDArray[np.bool_]) -> int | None:
    """The first row of one sequence's ``z`` ``(K + 1, dim_z)`` the tracker cannot take: row 0
    unless it is a detection with a number in every cell (it initiates the track), else the
    first detection with a cell that is not a number; None if there is none."""
    finite = np.all(np.isfinite(z), axis=1)
    if not (detected[0] and finite[0]):
        return 0
    rows = np.flatnonzero(detected & ~finite)
    return int(rows[0]) if rows.size else None


def read_npz(path: Path, sensor: Sonar) -> list[dict[str, Any]]:
    """The sequences of a measurement NPZ (see the module docstring): its arrays numbers of the
    shapes z gives, ``detected`` 0 or 1, ``z`` finite or NaN (a missed detection: without
    ``detected``, NaN in every cell of its row), the rest finite, a velocity or ``x0`` and
    ``P0`` (``P0`` symmetric positive definite); anything else refused naming the file."""
    dim_z = sensor.dim_z
    try:  # no pickles: a file that is not an NPZ archive must not run code
        loaded = np.load(path, allow_pickle=False)
    except (ValueError, EOFError, zipfile.BadZipFile) as err:
        raise ConfigError(
            f"{path}: not an NPZ archive of arrays, as numpy.savez writes ({err})"
            if "pickle" not in str(err)
            else f"{path}: not an NPZ archive of arrays, as numpy.savez writes"
        ) from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read ({err.strerror or err})") from None
    if not isinstance(loaded, np.lib.npyio.NpzFile):
        raise ConfigError(
            f"{path}: one .npy array, not an NPZ archive of named arrays (numpy.savez)"
        )
    with loaded as data:
        try:
            arrays = {key: data[key] for key in data.files}
        except (ValueError, EOFError, OSError, zipfile.BadZipFile) as err:
            raise ConfigError(f"{path}: cannot read its arrays ({err})") from None
    if "z" not in arrays:
        raise ConfigError(f"{path}: needs an array 'z' (N, K+1, m)")
    unknown = set(arrays) - {"z", "detected", "velocity", "x0", "P0"}
    if unknown:
        raise ConfigError(f"{path}: unknown arrays {sorted(unknown)}")
    for key, value in arrays.items():
        if value.dtype.kind not in "biuf":
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


def run(
    sequences: list[dict[str, Any]],
    policy: Any,
    config: EnvConfig,
    velocity: Sequence[float] | None,
    overrides: Mapping[str, Any],
) -> list[tuple[str, TrackResult]]:
    """:func:`run_policy` on the sequences: ``(name, result)`` per sequence (``N = 1``), in the
    input's order. Sequences that start alike (from ``x0``/``P0``, a velocity, or none) run as
    one batch, the shorter ones padded with missed detections to the longest and cut back to
    their own length (a step depends on none after it); a sequence's ``diverged_at`` counts its
    own steps only."""
    if not sequences:
        raise ConfigError("no measurements")
    started = []  # each sequence with --velocity where it gives no start of its own
    for seq in sequences:
        if seq.get("velocity") is None and velocity is not None and "x0" not in seq:
            seq = {**seq, "velocity": np.asarray(velocity, dtype=np.float64)}
        started.append(seq)
    results: dict[int, tuple[str, TrackResult]] = {}
    for kind in ("x0", "velocity", None):
        group = [(i, seq) for i, seq in enumerate(started) if _start_kind(seq) == kind]
        if not group:
            continue
        longest = max(seq["z"].shape[0] for _, seq in group)
        z = np.full((len(group), longest, config.sensor.dim_z), np.nan)
        detected = np.zeros((len(group), longest), dtype=bool)
        for row, (_, seq) in enumerate(group):
            n = seq["z"].shape[0]
            z[row, :n] = seq["z"]
            detected[row, :n] = (
                np.all(np.isfinite(seq["z"]), axis=1) if seq.get("detected") is None
                else seq["detected"]
            )
        args: dict[str, Any] = {}
        if kind == "x0":
            args["x0"] = np.stack([seq["x0"] for _, seq in group])
            args["P0"] = np.stack([seq["P0"] for _, seq in group])
        elif kind == "velocity":
            args["velocity"] = np.stack([seq["velocity"] for _, seq in group])
        result = run_policy(z, policy, config, detected=detected, overrides=overrides, **args)
        for row, (i, seq) in enumerate(group):
            results[i] = (seq["name"], _cut(result, row, seq["z"].shape[0] - 1))
    return [results[i] for i in range(len(sequences))]


def _start_kind(seq: dict[str, Any]) -> str | None:
    if seq.get("x0") is not None:
        return "x0"
    return "velocity" if seq.get("velocity") is not None else None


def _cut(result: TrackResult, row: int, steps: int) -> TrackResult:
    """Sequence ``row`` of a batch's result, its first ``steps`` steps (``N = 1``)."""
    return TrackResult(
        result.estimate[row : row + 1, :steps], result.covariance[row : row + 1, :steps],
        result.mode_probs[row : row + 1, :steps], result.tpm[row : row + 1, :steps],
        result.x0[row : row + 1], result.P0[row : row + 1],
        np.minimum(result.diverged_at[row : row + 1], steps),
    )


def tpm_columns(M: int) -> list[str]:
    """The TPM's CSV columns, row-major: ``tpm{i}{j}``, or ``tpm{i}_{j}`` for banks of more
    than ten models (where ``tpm110`` would name both entry (1, 10) and (11, 0))."""
    sep = "_" if M > 10 else ""
    return [f"tpm{i}{sep}{j}" for i in range(M) for j in range(M)]


def write(path: Path, results: list[tuple[str, TrackResult]]) -> None:
    """Write the results as CSV or NPZ (see the module docstring), the sequences in the order
    given; missing parent directories are made."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".npz":
        lengths = sorted({r.estimate.shape[1] for _, r in results})
        if len(lengths) != 1:  # main checks it before the tracking
            raise ConfigError(f"{path}: an NPZ output holds sequences of one length only")
        arrays = {
            key: np.concatenate([getattr(r, key) for _, r in results])
            for key in ("estimate", "covariance", "mode_probs", "tpm", "x0", "P0", "diverged")
        }
        np.savez(path, **arrays)
        return
    M = results[0][1].mode_probs.shape[-1]
    header = ["sequence", "step", "x", "y", "vx", "vy"]
    header += [f"P{i}{j}" for i in range(4) for j in range(4)]
    header += [f"mu{i}" for i in range(M)] + tpm_columns(M) + ["diverged"]
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(header)
        for name, r in results:
            for k in range(r.estimate.shape[1]):
                values = np.concatenate([
                    r.estimate[0, k], r.covariance[0, k].ravel(), r.mode_probs[0, k],
                    r.tpm[0, k].ravel(),
                ])
                writer.writerow([name, k + 1, *(repr(float(v)) for v in values),
                                 int(k >= r.diverged_at[0])])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m imm_gym.track",
        description="Run a TPM policy on recorded measurements (no truth): estimates, "
        "covariances, mode probabilities and the TPM used at each step.",
    )
    parser.add_argument("--measurements", required=True, type=Path,
                        help="CSV (columns z0.., optional sequence, detected, vx, vy) or NPZ")
    parser.add_argument("--policy", required=True,
                        help="a baseline's name, 'pretrained', 'pretrained-per-model' or a trained "
                             "agent's directory")
    parser.add_argument("--env-config", type=Path, default=None,
                        help="YAML or JSON mapping of EnvConfig fields (sensor, bank, filter...)")
    parser.add_argument("--out", required=True, type=Path, help="output file: .csv or .npz")
    parser.add_argument("--velocity", type=float, nargs=2, metavar=("VX", "VY"), default=None,
                        help="initial velocity (m/s) of sequences that give none "
                        "(default: zero, standard deviation 30 m/s)")
    parser.add_argument("--seed", type=int, default=0,
                        help=f"seed of a tuned baseline's simulated training runs (0 to "
                        f"{MAX_SEED})")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The command line; returns the exit status (2: a usage or input error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    problem = seed_problem(args.seed, 1)  # a tuned baseline's seeds, checked as evaluate's
    if problem:
        parser.error(problem)
    for name, path in (("--measurements", args.measurements), ("--out", args.out)):
        if path.suffix not in (".csv", ".npz"):
            parser.error(f"{name} must end in .csv or .npz, got {path}")
    problem = output_problem(args.out, "file")  # before any work, as evaluate's outputs
    if problem:
        parser.error(f"--out {str(args.out)!r}: {problem}")
    if args.out.resolve() == args.measurements.resolve() or (  # or a hard link to it
        args.out.exists() and args.measurements.exists()
        and os.path.samefile(args.out, args.measurements)
    ):
        parser.error(f"--out {str(args.out)!r} is the --measurements file: it would be "
                     "overwritten; give another output file")
    if args.velocity is not None and not np.all(np.isfinite(args.velocity)):
        parser.error(f"--velocity must be two finite numbers (m/s), got {args.velocity}")
    try:
        # as evaluate's: what the file says an agent is trained as is each policy's own
        overrides = {} if args.env_config is None else read_env_config(args.env_config)
        scenario = overrides.pop("scenario", "random")
        if "family" in overrides and scenario != "random":
            raise ConfigError(
                f"{args.env_config}: family applies to scenario 'random' only, and the "
                f"scenario ({_scenario_name(scenario)}) gives the sampling period: give one of "
                "them"
            )
        config = evaluated_config(scenario, overrides)
        if not args.measurements.is_file():
            what = "is a directory" if args.measurements.is_dir() else "no such file"
            raise ConfigError(f"{args.measurements}: {what}")
        sequences = (
            read_csv(args.measurements, config.sensor)
            if args.measurements.suffix == ".csv"
            else read_npz(args.measurements, config.sensor)
        )
        if not sequences:
            raise ConfigError(f"{args.measurements}: no measurements (no sequence)")
        odd = [where for seq in sequences for where in seq["implausible"]]
        if odd:
            print(f"warning: {len(odd)} detection(s) outside the sensor's units (it takes "
                  f"{config.sensor.measurement_units}; degrees, or a sign, likely), first at "
                  f"{odd[0]}: tracked as given", file=sys.stderr)
        lengths = sorted({s["z"].shape[0] - 1 for s in sequences})
        if args.out.suffix == ".npz" and len(lengths) > 1:
            raise ConfigError(
                f"--out {str(args.out)!r}: an NPZ output holds sequences of one length (its arrays "
                f"are (N, K, ...)); the input's have {', '.join(map(str, lengths))} steps: write "
                "a CSV"
            )
        policy, overrides, _ = make_policy(args.policy, config, args.seed)
        if args.policy not in REGISTRY:  # a trained agent: sizes checked, tracker config's
            overrides, notes = agent_overrides(policy, overrides, config)
            if notes["tracker_differs"]:
                fields = notes["tracker_differs"]
                verb = "differs" if len(fields) == 1 else "differ"
                print(f"{args.policy} was trained on another tracker (its {' and '.join(fields)} "
                      f"{verb}): it tracks with the configured one", file=sys.stderr)
            if "models_differ" in notes:
                print(models_differ_note(args.policy, notes["models_differ"]), file=sys.stderr)
        print(f"tracking at T = {config.source.T:g} s, the sampling period of the scenario "
              f"({_scenario_name(config.scenario)})", file=sys.stderr)
        results = run(sequences, policy, config, args.velocity, overrides)
        try:
            write(args.out, results)
        except OSError as err:  # checked up front; a full disk, say
            raise ConfigError(f"--out {str(args.out)!r}: cannot write ({err})") from None
    except ConfigError as err:
        parser.error(str(err))
    diverged = [(name, int(r.diverged_at[0]) + 1) for name, r in results if r.diverged[0]]
    if diverged:
        listed = ", ".join(f"{name!r} at step {k}" for name, k in diverged[:10])
        more = f" and {len(diverged) - 10} more" if len(diverged) > 10 else ""
        print(f"warning: {len(diverged)} track(s) diverged (estimate not finite or position "
              f"variance above divergence_cov, {config.divergence_cov:g} m²; column diverged "
              f"1 from then on): {listed}{more}", file=sys.stderr)
    print(f"{args.policy}: {len(results)} sequence(s) tracked -> {args.out}")
    return 0


def _scenario_name(scenario: Any) -> str:
    """A scenario as a user names it: ``'paper'``, or one a file gives in full."""
    return repr(scenario) if isinstance(scenario, str) else "the file's own"
