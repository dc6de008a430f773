r"""The ``learned`` maneuver detector (``EnvConfig.detector``): the belief of the target's turn
rate over the coming step, from a network that reads what an unsteered IMM saw.

Each slot runs a classical IMM at the uniform TPM :math:`1/M` beside its banks
(:class:`~imm_gym.sim.imm_batch.IMMBatch`; no action steers it). After every step it records,
in the tracker's own units and with the models in the order of their turn rates
:math:`\omega_{(1)} < \dots < \omega_{(M)}` (:func:`step_features`):

* the IMM's mode probabilities :math:`\mu_j`;
* its models' log-likelihoods relative to the best, :math:`\operatorname{clip}(\log\Lambda_j -
  \max_i \log\Lambda_i, -20, 0) / 10`;
* its NIS, :math:`\min(\epsilon_\nu, 50) / 10`;
* the heading rate of its combined estimate in units of the bank's fastest turn,
  :math:`\operatorname{clip}(\dot\psi / \max_j |\omega_j|, -3, 3)`.

The last :data:`WINDOW` steps' records (zeros before the first measurement) are the input
:math:`x` of a multilayer perceptron (:class:`DetectorNetwork`: tanh hidden layers, a softmax
output over the models' turn rates), whose output :math:`b(x)` leads the next step's switching
prior like the ``turn_rate`` detector's interpolation weights
(:func:`imm_gym.sim.stay_bank.detector_tpm_rows`). It is fitted by cross-entropy to the
interpolation weights of the target's true turn rate over that step
(:class:`~imm_gym.sim.detectors.TurnRateBelief`), so it learns their expectation given the
window (``python -m agents.detector``). The network is data: a safetensors file of its
weights and biases and a JSON header, checked before use; nothing in it runs.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from safetensors import SafetensorError, safe_open
from safetensors.numpy import save_file

from imm_gym.sim.features import heading_rate
from imm_gym.sim.imm_batch import IMMBatch
from imm_gym.tracking.imm import IMMState, Tracker
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

#: Steps of the uniform IMM's records the network reads.
WINDOW = 20
#: The ``format`` entry of a detector file's header.
FORMAT = "imm_gym-turn-detector"
#: The dtypes (safetensors' names) a detector file's tensors may have.
FLOATS = ("F16", "F32", "F64")
#: The shipped detector (``EnvConfig.detector_weights=None``).
DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "data" / "turn_detector.safetensors"
#: Entries of a record below this in magnitude are 0 (:func:`step_features`).
TINY = 1e-12
#: A network's largest layer count and width (a file beyond them is refused).
MAX_LAYERS, MAX_WIDTH = 8, 4096
#: The most numbers (weights and biases) a network may hold: 128 MiB as float64, some 450 times
#: the shipped network's; a file declaring more is refused from its header, before reading.
MAX_PARAMETERS = 2**24
#: The largest magnitude of a weight or bias a file may hold (float32's largest number).
FLOAT32_MAX = float(np.finfo(np.float32).max)


def features_per_step(n_models: int) -> int:
    """The record of one step: ``2 M + 2`` numbers (module docstring)."""
    return 2 * n_models + 2


def step_features(mu: Array, loglik: Array, nis: Array, rate: Array, scale: float) -> Array:
    r"""``(N, 2 M + 2)`` one step's record (module docstring) from the uniform IMM's mode
    probabilities ``mu (N, M)``, log-likelihoods ``loglik (N, M)``, NIS ``(N,)`` and heading
    rate ``rate (N,)`` (rad/s), ``scale`` the bank's fastest turn rate; a failed filter's NaN
    is 0, and so is every entry below :data:`TINY` in magnitude (no subnormal numbers, which
    would slow the network's products many times over)."""
    relative = np.clip(loglik - loglik.max(axis=1, keepdims=True), -20.0, 0.0) / 10.0
    record = np.nan_to_num(np.column_stack([
        mu, relative, np.clip(nis, 0.0, 50.0) / 10.0, np.clip(rate / scale, -3.0, 3.0),
    ]))
    return np.where(np.abs(record) < TINY, 0.0, record)


@dataclass(frozen=True)
class DetectorNetwork:
    r"""A multilayer perceptron ``x (N, window * (2 M + 2)) -> b (N, M)``: :math:`h_0 = x`,
    :math:`h_{l+1} = \tanh(W_l h_l + c_l)` for the hidden layers, :math:`b =
    \operatorname{softmax}(W_L h_L + c_L)` (float64 throughout)."""

    weights: tuple[Array, ...]
    biases: tuple[Array, ...]
    window: int = WINDOW

    @property
    def n_models(self) -> int:
        """The models it places beliefs on."""
        return self.weights[-1].shape[0]

    @property
    def n_inputs(self) -> int:
        return self.weights[0].shape[1]

    def check_models(self, n_models: int) -> None:
        """Raise :class:`ConfigError` unless the network places beliefs on ``n_models``."""
        if self.n_models != n_models:
            raise ConfigError(f"detector_weights: the network places beliefs on "
                              f"{self.n_models} models, the bank has {n_models}")

    def __call__(self, x: Array) -> Array:
        # one product per row ((N, 1, d) stacked): a slot's belief does not depend on how many
        # slots share the batch (a BLAS product of the whole batch rounds by its shape)
        h = x[..., None, :]
        for W, c in zip(self.weights[:-1], self.biases[:-1], strict=True):
            h = np.tanh(h @ W.T + c)
        logits = (h @ self.weights[-1].T + self.biases[-1])[..., 0, :]
        e = np.exp(logits - logits.max(axis=-1, keepdims=True))
        return e / e.sum(axis=-1, keepdims=True)

    def save(self, path: str | Path, notes: dict | None = None) -> None:
        """Write the network as a detector file (float32 tensors ``layer{l}.weight`` and
        ``layer{l}.bias``; the header's ``format``, ``window`` and ``notes``, JSON)."""
        tensors = {}
        for i, (W, c) in enumerate(zip(self.weights, self.biases, strict=True)):
            tensors[f"layer{i}.weight"] = np.ascontiguousarray(W, dtype=np.float32)
            tensors[f"layer{i}.bias"] = np.ascontiguousarray(c, dtype=np.float32)
        header = {"format": FORMAT, "window": str(self.window), "notes": json.dumps(notes or {})}
        save_file(tensors, str(path), metadata=header)

    @classmethod
    def load(cls, path: str | Path) -> DetectorNetwork:
        """Read and check a detector file: its header, consecutive layers whose shapes chain,
        an input of ``window * (2 M + 2)``, finite numbers. Raises :class:`ConfigError` naming
        what is wrong."""
        path = Path(path)
        where = f"detector_weights {str(path)!r}"
        if not path.is_file():
            raise ConfigError(f"{where}: no such file")
        try:
            with safe_open(str(path), framework="np") as f:
                header = f.metadata() or {}
                # numpy reads neither bfloat16 nor the float8 types: refused before reading
                dtypes = {name: f.get_slice(name).get_dtype() for name in f.keys()}
                other = sorted(name for name, dtype in dtypes.items() if dtype not in FLOATS)
                if other:
                    raise ConfigError(f"{where}: tensor {other[0]!r} is {dtypes[other[0]]}, "
                                      f"not one of {list(FLOATS)}")
                window = _header_window(where, header)
                # names and shapes from the header, before any tensor is read: a file that
                # declares a tensor of gigabytes allocates nothing
                shapes = {name: tuple(f.get_slice(name).get_shape()) for name in f.keys()}
                _check_layout(where, shapes, window)
                tensors = {name: f.get_tensor(name) for name in f.keys()}
        except ConfigError:
            raise
        except (SafetensorError, OSError, ValueError) as error:
            raise ConfigError(f"{where}: not a safetensors file ({error})") from error
        weights, biases = [], []
        for i in range(len(tensors) // 2):
            W, c = tensors[f"layer{i}.weight"], tensors[f"layer{i}.bias"]
            if not (np.abs(W) <= FLOAT32_MAX).all() or not (np.abs(c) <= FLOAT32_MAX).all():
                raise ConfigError(f"{where}: layer{i} holds numbers that are not finite or "
                                  f"beyond float32's range (|x| <= {FLOAT32_MAX:.3g}; beyond it "
                                  "the beliefs overflow to NaN)")
            weights.append(W.astype(np.float64))
            biases.append(c.astype(np.float64))
        return cls(tuple(weights), tuple(biases), window)


def parameter_count(widths: Sequence[int]) -> int:
    """Weights and biases of the layers ``widths[0] -> widths[1] -> ...``:
    ``sum_i (w_i + 1) w_{i+1}``."""
    return sum((a + 1) * b for a, b in itertools.pairwise(widths))


def _header_window(where: str, header: dict[str, str]) -> int:
    """A detector file's header: its format, and its window (decimal digits in [1, 1000])."""
    if header.get("format") != FORMAT:
        raise ConfigError(f"{where}: header format must be {FORMAT!r}, got "
                          f"{header.get('format')!r}")
    # decimal digits only: int() would also take " 8", "+8" and "1_0"
    text = header.get("window", "")
    window = int(text) if text.isascii() and text.isdigit() else 0
    if not 1 <= window <= 1000:
        raise ConfigError(f"{where}: header window must be an integer in [1, 1000], got "
                          f"{header.get('window')!r}")
    return window


def _check_layout(where: str, shapes: dict[str, tuple[int, ...]], window: int) -> None:
    """The tensors' names and shapes: ``layer0.weight, layer0.bias, ...`` (1 to
    :data:`MAX_LAYERS` layers), each weight ``(width <= MAX_WIDTH, previous width)`` with a bias
    of its width, the last layer at least 2 models wide (``M``), the first taking
    ``window * (2 M + 2)`` inputs."""
    layers = len(shapes) // 2
    expected = {f"layer{i}.{kind}" for i in range(layers) for kind in ("weight", "bias")}
    if not 1 <= layers <= MAX_LAYERS or set(shapes) != expected:
        raise ConfigError(f"{where}: tensors must be layer0.weight, layer0.bias, ... "
                          f"(1 to {MAX_LAYERS} layers), got {sorted(shapes)}")
    width = None
    for i in range(layers):
        W, c = shapes[f"layer{i}.weight"], shapes[f"layer{i}.bias"]
        if (
            len(W) != 2 or c != (W[0],) or W[0] > MAX_WIDTH
            or (width is not None and W[1] != width)
        ):
            raise ConfigError(f"{where}: layer{i} has weight {W} and bias {c}: the layers' "
                              "shapes must chain")
        width = W[0]
    M = width
    count = parameter_count([shapes["layer0.weight"][1], *(
        shapes[f"layer{i}.weight"][0] for i in range(layers))])
    if count > MAX_PARAMETERS:
        raise ConfigError(f"{where}: the layers hold {count} numbers, above the "
                          f"{MAX_PARAMETERS} a detector may hold")
    if M < 2:
        raise ConfigError(f"{where}: the last layer must give beliefs of at least 2 models, "
                          f"got {M}")
    inputs = shapes["layer0.weight"][1]
    if inputs != window * features_per_step(M):
        raise ConfigError(f"{where}: the input must be window * (2 M + 2) = "
                          f"{window * features_per_step(M)} for {M} models, got {inputs}")


def turn_rate_order(omegas: Array) -> NDArray[np.int64]:
    """The models in the order of their turn rates (the network's order); raises
    :class:`ConfigError` unless the rates are distinct."""
    omegas = np.asarray(omegas, dtype=np.float64)
    if np.unique(omegas).size != omegas.size:
        raise ConfigError(f"detector 'learned' needs models of distinct turn rates, got "
                          f"{np.degrees(omegas).round(3).tolist()} °/s")
    return np.argsort(omegas, kind="stable")


class LearnedDetector:
    """The ``learned`` detector of N slots (module docstring): the uniform IMM, each slot's
    window of records and the belief it gives the next step.

    Args:
        imm: the slots' tracker (a linear bank).
        n_envs: the number of slots N.
        kernel_args: the core's compiled bank constants (None: the numpy engine).
        omegas: ``(M,)`` the models' turn rates (rad/s), distinct.
        network: the network; None records the windows only (what its training reads).
        window: the records kept (the network's window when it is given).
    """

    def __init__(
        self,
        imm: Tracker,
        n_envs: int,
        kernel_args: tuple | None,
        omegas: Array,
        network: DetectorNetwork | None,
        window: int = WINDOW,
    ) -> None:
        M = imm.n_models
        self.order = turn_rate_order(omegas)
        if network is not None:
            network.check_models(M)
        self.network = network
        self.window_size = network.window if network is not None else window
        self.scale = float(np.abs(omegas).max()) or 1.0
        self.batch = IMMBatch(imm, n_envs, 1, kernel_args, nis=True)
        self._uniform = np.full((n_envs, M, M), 1.0 / M)
        #: ``(N, window, 2 M + 2)`` each slot's last records, the newest last
        self.window = np.zeros((n_envs, self.window_size, features_per_step(M)))
        #: ``(N, 2)`` the velocity of the uniform IMM's last combined estimate
        self.velocity = np.zeros((n_envs, 2))
        #: ``(N, M)`` the belief for the coming step, models in the bank's order
        self.belief = np.full((n_envs, M), 1.0 / M)

    def inputs(self) -> Array:
        """``(N, window * (2 M + 2))`` the network's input: each slot's window, flattened."""
        return self.window.reshape(self.window.shape[0], -1)

    def _believe(self, inputs: Array) -> Array:
        """The belief of the windows ``inputs (n, window * (2 M + 2))``, models in the bank's
        order (uniform without a network)."""
        M = self.belief.shape[1]
        if self.network is None:
            return np.full((len(inputs), M), 1.0 / M)
        belief = np.empty((len(inputs), M))
        belief[:, self.order] = self.network(inputs)
        return belief

    def start(
        self, indices: NDArray[np.int64], init: IMMState, kernel_args: tuple | None
    ) -> None:
        """Start the slots ``indices`` from bank A's initial posterior ``init``: an empty window
        and the belief the network gives it."""
        self.batch.start(indices, init, kernel_args)
        self.window = self.window.copy()
        self.window[indices] = 0.0
        self.velocity = self.velocity.copy()
        self.velocity[indices] = np.einsum("rm,rmi->ri", init.mu, init.x)[:, 2:4]
        self.belief = self.belief.copy()
        self.belief[indices] = self._believe(self.inputs()[indices])

    def step(
        self, z: Array, detected: NDArray[np.bool_], fallback: IMMState, T: Array
    ) -> None:
        """Advance the uniform IMM on ``z (N, m)`` (``detected (N,)``; a failed filter restarts
        from ``fallback``), append the step's record and update the belief; ``T (N,)`` the
        slots' sampling periods."""
        out = self.batch.step(self._uniform, z, detected, fallback)
        velocity = out.estimate[:, 2:4]
        rate = heading_rate(self.velocity, velocity, T)
        if np.count_nonzero(out.failed):  # restarted: the fallback's combined velocity
            restarted = np.einsum("rm,rmi->ri", fallback.mu, fallback.x)[:, 2:4]
            velocity = np.where(out.failed[:, None], restarted, velocity)
        self.velocity = velocity
        o = self.order
        record = step_features(self.batch.state.mu[:, o], out.loglik[:, o], out.nis, rate,
                               self.scale)
        self.window = np.concatenate([self.window[:, 1:], record[:, None]], axis=1)
        self.belief = self._believe(self.inputs())

    def snapshot(self) -> tuple[IMMState, Array, Array, Array]:
        """The detector's state (arrays are replaced, never written, by a step)."""
        return self.batch.snapshot(), self.window, self.velocity, self.belief

    def restore(self, snap: tuple[IMMState, Array, Array, Array], slots: NDArray[np.bool_]) -> None:
        """Put back the values of ``snap`` for the slots where ``slots (N,)`` is True."""
        state, window, velocity, belief = snap
        self.batch.restore(state, slots)
        self.window = np.where(slots[:, None, None], window, self.window)
        self.velocity = np.where(slots[:, None], velocity, self.velocity)
        self.belief = np.where(slots[:, None], belief, self.belief)
