"""Helpers shared by the test modules."""

from __future__ import annotations

import importlib.util
import struct
from pathlib import Path
from types import ModuleType

import numpy as np

from imm_gym import EnvConfig, TrackingCore


def random_pd(rng: np.random.Generator, std: np.ndarray) -> np.ndarray:
    """A random covariance with the given standard deviations and random correlations."""
    n = len(std)
    A = rng.standard_normal((n, n))
    C = A @ A.T + 0.5 * np.eye(n)
    d = 1.0 / np.sqrt(np.diag(C))
    return (std[:, None] * std[None, :]) * (d[:, None] * C * d[None, :])


#: A small PPO for training in the tests (8 envs, 32-step rollouts, one epoch).
SMALL = "n_envs: 8\nn_steps: 32\nbatch_size: 128\nn_epochs: 1\n"


def train_small(out: Path, *args: str, extra: str = "") -> int:
    """``train.py`` with :data:`SMALL` (``extra`` YAML on top) writing to ``out``."""
    import train

    cfg = out / "small.yml"
    cfg.write_text(SMALL + extra)
    return train.main(["--config", str(cfg), "--out", str(out), "--no-progress", *args])


def load_example(name: str) -> ModuleType:
    """The script ``examples/NAME.py`` as a module (the examples are not a package)."""
    path = Path(__file__).parents[1] / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def stay_core(n: int, engine: str = "auto", **changes: object) -> TrackingCore:
    """A core of ``n`` slots in ``stay`` mode with the stay bank's evidence observed, missed
    detections and 80-step episodes, reset with seeds 20, 21, ...; ``changes`` on top."""
    config = EnvConfig(
        action_mode="stay",
        obs_features=("stay_bank_evidence",),
        sensor={"detection_prob": 0.8},
        family={"horizon": 80},
        engine=engine,
    ).replace(**changes)
    core = TrackingCore(config, n)
    core.reset(np.arange(n), list(range(20, 20 + n)))
    return core


def printed_row(printed: str, first: str, after: str = "") -> list[str]:
    """The cells of the first table row of ``printed`` (from the text ``after`` on) whose first
    cell is ``first`` (rich's box characters)."""
    for line in printed[printed.index(after):].splitlines():
        cells = [c.strip() for c in line.strip().strip("│┃").split("│")]
        if cells[0] == first:
            return cells
    raise AssertionError(f"no row {first!r} in\n{printed}")


def shipped_agent() -> Path:
    """One trained agent of the shipped ``pretrained`` policy: the directory itself, or its
    first member when it is an ensemble (:mod:`agents.ensemble`)."""
    from agents import PRETRAINED
    from agents.ensemble import is_ensemble, member_paths

    return member_paths(PRETRAINED)[0] if is_ensemble(PRETRAINED) else PRETRAINED


#: Network descriptions of every policy class and option the loader builds (gSDE, empty layer
#: lists, the asymmetric critic, the per-model actor, each LSTM layout): what their tensors and
#: sizes computed from the description are checked against.
NETWORK_SPECS = [
    {"class": "MlpPolicy", "observation_size": 7, "action_size": 3},
    {"class": "MlpPolicy", "observation_size": 7, "action_size": 3, "net_arch": [5, 4],
     "use_sde": True, "full_std": False, "share_features_extractor": False},
    {"class": "MlpPolicy", "observation_size": 7, "action_size": 2,
     "net_arch": {"pi": [], "vf": [6]}, "use_sde": True},
    {"class": "AsymmetricMlpPolicy", "observation_size": 12, "action_size": 3,
     "net_arch": {"pi": [5], "vf": [4, 4]}, "critic_dims": 2, "frame_stack": 3},
    {"class": "AsymmetricMlpPolicy", "observation_size": 12, "action_size": 3,
     "net_arch": {"pi": [], "vf": []}, "critic_dims": 2, "frame_stack": 3, "use_sde": True},
    {"class": "PerModelPolicy", "observation_size": 2 * 16, "action_size": 3,
     "net_arch": {"pi": [6, 5, 7], "vf": [4]}, "critic_dims": 0, "frame_stack": 2,
     "obs_features": ["loglik", "innovation", "speed"], "dim_z": 2},
    {"class": "MlpLstmPolicy", "observation_size": 9, "action_size": 3,
     "lstm_hidden_size": 5, "n_lstm_layers": 3, "net_arch": [4], "shared_lstm": False,
     "enable_critic_lstm": True},
    {"class": "MlpLstmPolicy", "observation_size": 9, "action_size": 3,
     "lstm_hidden_size": 5, "n_lstm_layers": 1, "shared_lstm": False,
     "enable_critic_lstm": False},
    {"class": "MlpLstmPolicy", "observation_size": 9, "action_size": 3,
     "lstm_hidden_size": 5, "n_lstm_layers": 2, "shared_lstm": True,
     "enable_critic_lstm": False},
]


def npy_bytes(header: str, payload: bytes) -> bytes:
    """A .npy file of format 1.0 with the header dict ``header`` and the bytes ``payload``
    (whatever the header claims: a hostile file's)."""
    text = header.encode("latin1")
    text += b" " * (64 - (10 + len(text) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text + payload
