"""Train the ``learned`` maneuver detector (:mod:`imm_gym.sim.learned_detector`) by supervision.

``python -m agents.detector --env-config FILE [FILE ...] --runs N --out FILE.safetensors``
draws N episodes spread evenly over the configurations (seeds from
:data:`~imm_gym.seeding.DETECTOR_SEED_BASE`, disjoint from every evaluation, validation and
training seed), runs the detector's uniform IMM on each (:class:`LearnedDetector` without a
network: the same code that feeds the network in the env) and records, before every step, its
window and the interpolation weights of the target's true turn rate over that step. A
multilayer perceptron is fitted to them by cross-entropy (Adam; ``torch.manual_seed(seed)``,
the header's metadata in sorted order: the same arguments give the same file, byte for byte, on
one machine), scored on held-out episodes against the best constant belief, and written as a
detector file (data only: safetensors, a JSON header with what was run).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from imm_gym.seeding import DETECTOR_SEED_BASE
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.detectors import TurnRateBelief, model_turn_rates, true_turn_rates
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.learned_detector import (
    MAX_LAYERS,
    MAX_PARAMETERS,
    MAX_WIDTH,
    WINDOW,
    DetectorNetwork,
    LearnedDetector,
    features_per_step,
    parameter_count,
    turn_rate_order,
)
from imm_gym.validation import ConfigError, check_int

Array = NDArray[np.float64]

#: Episodes per batch of the collection.
BATCH_RUNS = 500
#: Seeds of the held-out episodes the file's score is measured on: ``DETECTOR_SEED_BASE +
#: HELD_OUT_OFFSET + 10**6 seed + r``, a block of their own (every seed's training runs stay
#: below ``DETECTOR_SEED_BASE + 10**15 + 10**6``).
HELD_OUT_OFFSET = 1 << 60


@dataclass(frozen=True)
class Samples:
    """What the detector reads and what it learns: ``inputs (S, window * (2 M + 2))`` and
    ``targets (S, M)`` (the models in the order of their turn rates)."""

    inputs: NDArray[np.float32]
    targets: NDArray[np.float32]


def collection_config(overrides: Mapping[str, Any]) -> EnvConfig:
    """The configuration's targets, sensor and tracker, with the slots' own TPMs, no detector,
    no shadow and no features: what the uniform IMM sees does not depend on them, and the
    collection runs nothing else."""
    config = EnvConfig.build(dict(overrides))
    if model_turn_rates(config.bank) is None:
        raise ConfigError("the learned detector needs a linear bank (the models' turn rates)")
    return config.replace(
        detector="shadow", detector_share=0.0, detector_weights=None, stay_base="tracker",
        stay_grid="stays", obs_features=(), shadow="none", reward="error", mode_reward=0.0,
        tpm_change_cost=0.0, tpm_cost=0.0,
    )


def collect(overrides: Mapping[str, Any], seeds: Sequence[int], window: int = WINDOW) -> Samples:
    """The detector's window before every step of the episodes ``seeds`` of ``overrides`` and
    the belief of the true turn rate over that step (a diverged episode's steps after it ended
    are left out)."""
    config = collection_config(overrides)
    omegas = model_turn_rates(config.bank)
    core = TrackingCore(config, len(seeds))
    core.reset(np.arange(len(seeds)), list(seeds))
    detector = LearnedDetector(
        core.imm, len(seeds), core.batch_kernel_args, omegas, None, window  # type: ignore[arg-type]
    )
    detector.start(np.arange(len(seeds)), core.state_a, core.kernel_args)
    truth_belief = TurnRateBelief(omegas)  # type: ignore[arg-type]
    rates = true_turn_rates(core.truth, core.sampling_period)
    rows = np.arange(len(seeds))
    inputs, targets = [], []
    zero = np.zeros((len(seeds), core.action_dim))
    for k in range(core.horizon):
        live = ~core.done
        if not live.any():
            break
        inputs.append(detector.inputs()[live].astype(np.float32))
        targets.append(truth_belief(rates[live, k])[:, detector.order].astype(np.float32))
        core.step(zero, active=live)
        detector.step(core.z[rows, k + 1], core.detected[rows, k + 1], core.state_a,
                      core.sampling_period)
    return Samples(np.concatenate(inputs), np.concatenate(targets))


def collect_runs(configs: Sequence[Mapping[str, Any]], runs: int, first_seed: int) -> Samples:
    """:func:`collect` over ``runs`` episodes spread evenly over ``configs`` (seeds
    ``first_seed ..``, in batches of :data:`BATCH_RUNS`).

    Raises:
        ValueError: fewer runs than configurations (a configuration would get no episode).
    """
    if runs < len(configs):
        raise ValueError(f"{runs} runs for {len(configs)} configurations: each needs one at least")
    parts = []
    seed = first_seed
    for i, overrides in enumerate(configs):
        share = runs // len(configs) + (i < runs % len(configs))
        for start in range(0, share, BATCH_RUNS):
            n = min(BATCH_RUNS, share - start)
            parts.append(collect(overrides, range(seed, seed + n)))
            seed += n
    return Samples(np.concatenate([p.inputs for p in parts]),
                   np.concatenate([p.targets for p in parts]))


def cross_entropy(belief: Array, targets: Array) -> float:
    """Mean cross-entropy (nats) of beliefs ``(S, M)`` against targets ``(S, M)``."""
    return float(-np.mean(np.sum(targets * np.log(np.maximum(belief, 1e-12)), axis=1)))


def fit(samples: Samples, hidden: Sequence[int], epochs: int, seed: int,
        batch: int = 1024, rate: float = 1e-3) -> DetectorNetwork:
    """An MLP with tanh ``hidden`` layers fitted by cross-entropy to ``samples`` (Adam at
    ``rate``, shuffled batches of ``batch``, ``torch.manual_seed(seed)``)."""
    import torch

    torch.manual_seed(seed)
    x = torch.from_numpy(samples.inputs)
    y = torch.from_numpy(samples.targets)
    sizes = [x.shape[1], *hidden, y.shape[1]]
    layers: list[torch.nn.Module] = []
    for i, (a, b) in enumerate(pairwise(sizes)):
        layers.append(torch.nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(torch.nn.Tanh())
    net = torch.nn.Sequential(*layers)
    optimizer = torch.optim.Adam(net.parameters(), lr=rate)
    for _ in range(epochs):
        for rows in torch.randperm(len(x)).split(batch):
            loss = -(y[rows] * torch.log_softmax(net(x[rows]), -1)).sum(-1).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    linear = [m for m in net if isinstance(m, torch.nn.Linear)]
    return DetectorNetwork(
        tuple(m.weight.detach().double().numpy().copy() for m in linear),
        tuple(m.bias.detach().double().numpy().copy() for m in linear),
        samples.inputs.shape[1] // (2 * y.shape[1] + 2),
    )


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m agents.detector", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--env-config", nargs="+", required=True, metavar="FILE",
                        help="configuration files whose episodes it learns from (evenly)")
    parser.add_argument("--runs", type=int, default=4000, help="training episodes (4000)")
    parser.add_argument("--held-out-runs", type=int, default=500,
                        help="episodes of the held-out score (500)")
    parser.add_argument("--seed", type=int, default=0,
                        help="training seed: episodes from DETECTOR_SEED_BASE + 10**6 seed (0)")
    parser.add_argument("--epochs", type=int, default=8, help="passes over the samples (8)")
    parser.add_argument("--hidden", type=int, nargs="+", default=[128, 128],
                        help="hidden layers' widths (128 128)")
    parser.add_argument("--out", type=Path, required=True, help="the detector file to write")
    args = parser.parse_args(argv)
    check_int("runs", args.runs, 1, 10**6)
    check_int("held_out_runs", args.held_out_runs, 1, 10**6)
    files = len(args.env_config)
    for flag, runs in (("runs", args.runs), ("held_out_runs", args.held_out_runs)):
        if runs < files:
            raise ConfigError(f"{flag} must be at least the {files} --env-config files (every "
                              f"file gets its share of the episodes), got {runs}")
    check_int("seed", args.seed, 0, 10**9)
    check_int("epochs", args.epochs, 1, 1000)
    for width in args.hidden:
        check_int("hidden", width, 1, MAX_WIDTH)
    if len(args.hidden) + 1 > MAX_LAYERS:
        raise ConfigError(f"hidden: {len(args.hidden)} hidden layers and the output are "
                          f"{len(args.hidden) + 1} layers, above the {MAX_LAYERS} a detector "
                          "file may hold")
    return args


def check_configs(
    files: Sequence[Path | str], configs: Sequence[Mapping[str, Any]], hidden: Sequence[int]
) -> None:
    """Refuse, before any episode is run, a file whose bank is not linear or has repeated turn
    rates, files of different numbers of models (one network reads them all) and a network above
    :data:`MAX_PARAMETERS`.

    Raises:
        ConfigError: naming the file (``env_config``) or ``hidden``.
    """
    sizes = []
    for name, overrides in zip(files, configs, strict=True):
        try:
            omegas = model_turn_rates(collection_config(overrides).bank)
            turn_rate_order(omegas)  # type: ignore[arg-type]
        except ConfigError as err:
            raise ConfigError(f"env_config {str(name)!r}: {err}") from None
        sizes.append(len(omegas))  # type: ignore[arg-type]
    if len(set(sizes)) > 1:
        raise ConfigError(f"env_config: the files' banks have {sizes} models; one detector reads "
                          "them all, so every file must have as many")
    M = sizes[0]
    count = parameter_count([WINDOW * features_per_step(M), *hidden, M])
    if count > MAX_PARAMETERS:
        raise ConfigError(f"hidden: a network of {count} numbers for {M} models, above the "
                          f"{MAX_PARAMETERS} a detector file may hold")


def check_out(out: Path) -> None:
    """Refuse, before any work, an ``--out`` that is a directory or whose nearest existing
    parent is not a writable directory (the network would be lost after the training)."""
    if out.is_dir():
        raise ConfigError(f"out: {str(out)!r} is a directory; give the detector file's path")
    parent = next(p for p in out.absolute().parents if p.exists())
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError(f"out: cannot write {str(out)!r} ({str(parent)!r} is not a writable "
                          "directory)")


def sort_header(path: Path) -> None:
    """Rewrite the safetensors file ``path`` with its header's metadata in sorted key order.

    The writer keeps the metadata in a hash map whose order changes from one run to the next;
    sorted, the same arguments give a byte-identical file. The header is written compact and
    padded with spaces to a multiple of 8 bytes, as the writer does; the tensors' bytes (their
    offsets count from the end of the header) are kept as they are.
    """
    data = path.read_bytes()
    size = int.from_bytes(data[:8], "little")
    header = json.loads(data[8 : 8 + size])
    header["__metadata__"] = dict(sorted(header.get("__metadata__", {}).items()))
    text = json.dumps(header, separators=(",", ":"), ensure_ascii=False).encode()
    text += b" " * (-len(text) % 8)
    path.write_bytes(len(text).to_bytes(8, "little") + text + data[8 + size :])


def main(argv: Sequence[str] | None = None) -> None:
    from agents.training import set_threads
    from imm_gym.sim.config_file import read_env_config

    args = parse_args(argv)
    configs = [read_env_config(f) for f in args.env_config]
    check_configs(args.env_config, configs, args.hidden)  # all before the long work
    check_out(args.out)
    set_threads(1)
    import torch

    first = DETECTOR_SEED_BASE + 1_000_000 * args.seed
    train = collect_runs(configs, args.runs, first)
    held_out_first = first + HELD_OUT_OFFSET
    held_out = collect_runs(configs, args.held_out_runs, held_out_first)
    network = fit(train, args.hidden, args.epochs, args.seed)
    score = cross_entropy(network(held_out.inputs.astype(np.float64)), held_out.targets)
    constant = cross_entropy(np.broadcast_to(train.targets.mean(axis=0), held_out.targets.shape),
                             held_out.targets)
    notes = {
        "env_config": [str(f) for f in args.env_config],
        "runs": args.runs, "seeds": [first, first + args.runs - 1],
        "held_out_runs": args.held_out_runs,
        "held_out_seeds": [held_out_first, held_out_first + args.held_out_runs - 1],
        "epochs": args.epochs, "hidden": args.hidden,
        "samples": len(train.inputs), "held_out_cross_entropy": score,
        "constant_cross_entropy": constant,
        "versions": {"python": platform.python_version(), "numpy": np.__version__,
                     "torch": torch.__version__},
        "command": " ".join(["python -m agents.detector", *(argv or sys.argv[1:])]),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    network.save(args.out, notes)
    sort_header(args.out)
    print(json.dumps({k: notes[k] for k in ("samples", "held_out_cross_entropy",
                                            "constant_cross_entropy")}))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    try:
        main()
    except ConfigError as err:  # a usage error, said in one line (exit 2), before any work
        print(f"python -m agents.detector: error: {err}", file=sys.stderr)
        sys.exit(2)
