"""The learned detector (imm_gym.sim.learned_detector): its network against torch, its files
(data, checked before use), its uniform IMM's records against a separate numpy IMM, the TPM it
leads, its order of models, its slots (inactive, reset, repeatable) and the configuration's
errors."""

from __future__ import annotations

import json
from itertools import pairwise

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from safetensors.numpy import save_file

from imm_gym import EnvConfig, TrackingCore
from imm_gym.sim.features import heading_rate
from imm_gym.sim.learned_detector import (
    FORMAT,
    DetectorNetwork,
    features_per_step,
    step_features,
)
from imm_gym.sim.presets import BANK_PRESETS
from imm_gym.tracking.hetero import make_tracker
from imm_gym.validation import ConfigError

M = 3
PAPER_RATES = np.radians([0.0, 4.0, -4.0])  # CV, CT(+4 °/s), CT(-4 °/s)


def random_network(seed: int, window: int = 4, hidden: tuple[int, ...] = (16, 8)
                   ) -> DetectorNetwork:
    rng = np.random.default_rng(seed)
    sizes = [window * features_per_step(M), *hidden, M]
    weights = tuple(rng.normal(0, 0.5, (b, a)) for a, b in pairwise(sizes))
    biases = tuple(rng.normal(0, 0.5, b) for b in sizes[1:])
    return DetectorNetwork(weights, biases, window)


def learned_core(n: int, tmp_path, network: DetectorNetwork | None = None,
                 **changes) -> TrackingCore:
    weights = None
    if network is not None:
        weights = str(tmp_path / "detector.safetensors")
        network.save(weights)
    config = EnvConfig(
        action_mode="stay", stay_base="tracker", detector="learned", detector_share=0.5,
        detector_weights=weights, initial_stay=0.8, sojourn=None,
        sensor={"detection_prob": 0.8}, family={"horizon": 60},
    ).replace(**changes)
    core = TrackingCore(config, n)
    core.reset(np.arange(n), list(range(40, 40 + n)))
    return core


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 6))
def test_the_network_is_torch_s_mlp(seed: int, window: int) -> None:
    net = random_network(seed, window)
    x = np.random.default_rng(seed + 1).normal(size=(5, net.n_inputs))
    layers = []
    for i, (W, c) in enumerate(zip(net.weights, net.biases, strict=True)):
        linear = torch.nn.Linear(W.shape[1], W.shape[0]).double()
        linear.weight.data, linear.bias.data = torch.from_numpy(W), torch.from_numpy(c)
        layers += [linear] if i == len(net.weights) - 1 else [linear, torch.nn.Tanh()]
    with torch.no_grad():
        expected = torch.softmax(torch.nn.Sequential(*layers)(torch.from_numpy(x)), -1).numpy()
    belief = net(x)
    np.testing.assert_allclose(belief, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(belief.sum(axis=1), 1.0, atol=1e-12)


def test_step_features_by_hand() -> None:
    """A record is ``mu``, ``clip(loglik - max loglik, -20, 0) / 10``, ``min(NIS, 50) / 10``,
    ``clip(rate / scale, -3, 3)``: gaps 0, -15, -20, -25 and -40 give 0, -1.5, -2, -2 and -2."""
    mu = np.array([[0.98, 0.01, 0.01], [0.2, 0.5, 0.3], [0.1, 0.6, 0.3]])
    loglik = np.array([[-3.0, -18.0, -43.0], [10.0, 10.0, -10.0], [-5.0, -1.0, -26.0]])
    nis = np.array([2.0, 60.0, 0.0])
    rate = np.array([0.05, -1.0, 0.7])
    record = step_features(mu, loglik, nis, rate, 0.2)
    expected = np.array([
        [0.98, 0.01, 0.01, 0.0, -1.5, -2.0, 0.2, 0.25],
        [0.2, 0.5, 0.3, 0.0, 0.0, -2.0, 5.0, -3.0],
        [0.1, 0.6, 0.3, -0.4, 0.0, -2.0, 0.0, 3.0],
    ])
    np.testing.assert_allclose(record, expected, rtol=1e-12, atol=1e-15)


def test_the_softmax_is_finite_for_large_logits() -> None:
    """Logits (800, 0) give the belief (1, 0), (-800, -810) give ``(1, e^-10) / (1 + e^-10)``:
    finite, though ``e^800`` overflows and ``e^-800`` underflows."""
    M2 = 2
    zero = np.zeros((M2, features_per_step(M2)))
    x = np.zeros((1, features_per_step(M2)))
    net = DetectorNetwork((zero,), (np.array([800.0, 0.0]),), window=1)
    np.testing.assert_array_equal(net(x), [[1.0, 0.0]])
    net = DetectorNetwork((zero,), (np.array([-800.0, -810.0]),), window=1)
    tail = np.exp(-10.0)
    np.testing.assert_allclose(net(x), [[1.0 / (1.0 + tail), tail / (1.0 + tail)]], rtol=1e-12)


def test_a_saved_network_loads_as_float32_data(tmp_path) -> None:
    net = random_network(0)
    net.save(tmp_path / "d.safetensors", {"runs": 3})
    loaded = DetectorNetwork.load(tmp_path / "d.safetensors")
    assert loaded.window == net.window and len(loaded.weights) == 3
    for a, b in zip(loaded.weights + loaded.biases, net.weights + net.biases, strict=True):
        np.testing.assert_array_equal(a, b.astype(np.float32))


def _write(path, tensors, header) -> str:
    save_file({k: np.asarray(v, dtype=np.float32) for k, v in tensors.items()}, str(path),
              metadata=header)
    return str(path)


def test_a_bad_file_is_refused_naming_what_is_wrong(tmp_path) -> None:
    good = {"layer0.weight": np.zeros((M, 2 * features_per_step(M))), "layer0.bias": np.zeros(M)}
    header = {"format": FORMAT, "window": "2"}
    DetectorNetwork.load(_write(tmp_path / "ok", good, header))
    cases = [
        (good, {"window": "2"}, "header format must be"),
        (good, {"format": FORMAT, "window": "two"}, "header window must be an integer"),
        *((good, {"format": FORMAT, "window": text}, "header window must be an integer")
          for text in (" 2", "+2", "0_2", "2.0", "")),
        (good, {"format": FORMAT, "window": "3"}, r"input must be window \* \(2 M \+ 2\) = 24"),
        ({"layer0.weight": good["layer0.weight"]}, header, "tensors must be layer0.weight"),
        ({**good, "layer0.bias": np.zeros(M + 1)}, header, "shapes must chain"),
        ({**good, "layer0.bias": np.full(M, np.nan)}, header, "not finite or beyond float32"),
        ({"layer0.weight": np.zeros((1, 2 * features_per_step(1))), "layer0.bias": np.zeros(1)},
         header, "beliefs of at least 2 models, got 1"),
        ({"layer0.weight": np.zeros((4, 16)), "layer0.bias": np.zeros(4),
          "layer1.weight": np.zeros((M, 5)), "layer1.bias": np.zeros(M)}, header, "must chain"),
    ]
    for i, (tensors, head, message) in enumerate(cases):
        path = _write(tmp_path / f"bad{i}", tensors, head)
        with pytest.raises(ConfigError, match=message):
            DetectorNetwork.load(path)
    huge = {"layer0.weight": np.full((M, 2 * features_per_step(M)), 1e308),
            "layer0.bias": np.zeros(M)}  # float64, finite: the belief overflowed to NaN
    save_file(huge, str(tmp_path / "huge"), metadata=header)
    with pytest.raises(ConfigError, match=r"layer0 holds numbers that are not finite or beyond"):
        DetectorNetwork.load(tmp_path / "huge")
    with pytest.raises(ConfigError, match="no such file"):
        DetectorNetwork.load(tmp_path / "missing")


def _declare_huge(path, shape: tuple[int, int]) -> None:
    """A detector file whose header declares layer0.weight of ``shape`` (float32), the data a
    sparse hole: declared, nothing on disk."""
    n = shape[0] * shape[1] * 4
    entries = {
        "__metadata__": {"format": FORMAT, "window": "2"},
        "layer0.bias": {"dtype": "F32", "shape": [shape[0]], "data_offsets": [0, 4 * shape[0]]},
        "layer0.weight": {"dtype": "F32", "shape": list(shape),
                          "data_offsets": [4 * shape[0], 4 * shape[0] + n]},
    }
    header = json.dumps(entries).encode()
    header += b" " * (-len(header) % 8)
    with open(path, "wb") as handle:
        handle.write(len(header).to_bytes(8, "little") + header)
        handle.truncate(8 + len(header) + 4 * shape[0] + n)


def test_a_file_declaring_a_huge_tensor_is_refused_before_reading_it(
    tmp_path, monkeypatch
) -> None:
    """Names and shapes are checked from the header: layers of more numbers than a detector
    may hold (declared, their data a sparse hole) are refused without reading a tensor."""
    import safetensors

    read: list[str] = []
    real = safetensors.safe_open

    class Recording:
        def __init__(self, *args, **kwargs) -> None:
            self.inner = real(*args, **kwargs)

        def __enter__(self):
            self.file = self.inner.__enter__()
            return self

        def __exit__(self, *exc):
            return self.inner.__exit__(*exc)

        def __getattr__(self, name):
            return getattr(self.file, name)

        def get_tensor(self, name):
            read.append(name)
            return self.file.get_tensor(name)

    import imm_gym.sim.learned_detector as learned

    monkeypatch.setattr(learned, "safe_open", Recording)
    _declare_huge(tmp_path / "wide", (M, 2**23))
    with pytest.raises(ConfigError, match=r"the input must be window|above the 16777216"):
        DetectorNetwork.load(tmp_path / "wide")
    _declare_huge(tmp_path / "big", (4096, 8192))
    with pytest.raises(ConfigError, match=r"the layers hold \d+ numbers, above the 16777216"):
        DetectorNetwork.load(tmp_path / "big")
    assert read == []
    pickle = tmp_path / "net.pkl"
    pickle.write_bytes(b"\x80\x04\x95" + b"cos\nsystem\n" * 20)  # a pickle is not read
    with pytest.raises(ConfigError, match="not a safetensors file"):
        DetectorNetwork.load(pickle)


def test_the_records_are_those_of_a_separate_uniform_imm(tmp_path) -> None:
    # the reference: the classical IMM at the uniform TPM on the numpy engine, its outputs put
    # into the records by the module docstring's formulas
    N = 3
    core = learned_core(N, tmp_path, random_network(1, window=5))
    detector = core.learned_detector
    reference = make_tracker(core.config.bank, core.config.sensor, "ukf", 1.0, engine="numpy")
    state = core.state_a
    velocity = np.einsum("rm,rmi->ri", state.mu, state.x)[:, 2:4]
    order = np.argsort(PAPER_RATES)
    records = []
    rng = np.random.default_rng(0)
    for _ in range(40):
        k1 = core.k + 1
        z, det = core.z[np.arange(N), k1], core.detected[np.arange(N), k1]
        state, out = reference.step(state, np.full((M, M), 1.0 / M), z, det)
        rate = heading_rate(velocity, out.x[:, 2:4], 1.0)
        velocity = out.x[:, 2:4]
        relative = out.loglik - out.loglik.max(axis=1, keepdims=True)
        records.append(np.column_stack([
            out.mode_probs[:, order], np.clip(relative[:, order], -20, 0) / 10,
            np.minimum(out.nis, 50) / 10, np.clip(rate / np.radians(4.0), -3, 3),
        ]))
        core.step(rng.uniform(-1, 1, (N, M)))
        np.testing.assert_allclose(detector.window[:, -1], records[-1], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(detector.window, np.stack(records[-5:], axis=1), rtol=1e-6,
                               atol=1e-7)
    assert (~core.detected[:, 1:41]).any()  # missed detections among them
    np.testing.assert_allclose(detector.belief[:, order], detector.network(detector.inputs()),
                               rtol=1e-15)


def test_the_zero_action_is_the_prior_its_belief_leads(tmp_path) -> None:
    N, v = 2, 0.5
    core = learned_core(N, tmp_path, random_network(2))
    keep = (0.8 - 1 / M) / (1 - 1 / M)
    for _ in range(30):
        b = core.learned_detector.belief.copy()
        tpm = core.step(np.zeros((N, M))).info["tpm"]
        q = (1 - v) / M + v * b
        expected = keep * np.eye(M) + (1 - keep) * q[:, None, :]
        np.testing.assert_allclose(tpm, expected, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(tpm.sum(axis=2), 1.0, atol=1e-12)


def test_the_network_s_levels_are_the_models_in_the_order_of_their_turn_rates(tmp_path) -> None:
    # a network that always says "the slowest turn rate" (level 0): the CT(-4 °/s) model
    window = 2
    weights = (np.zeros((M, window * features_per_step(M))),)
    net = DetectorNetwork(weights, (np.array([8.0, 0.0, 0.0]),), window)
    core = learned_core(2, tmp_path, net)
    for _ in range(3):
        assert np.all(np.argmax(core.learned_detector.belief, axis=1) == 2)
        core.step(np.zeros((2, M)))


def test_inactive_slots_keep_their_detector_and_a_reset_empties_the_window(tmp_path) -> None:
    core = learned_core(3, tmp_path, random_network(3))
    for _ in range(6):
        core.step(np.zeros((3, M)))
    d = core.learned_detector
    window, belief, x = d.window.copy(), d.belief.copy(), d.batch.state.x.copy()
    core.step(np.zeros((3, M)), active=np.array([True, False, True]))
    np.testing.assert_array_equal(d.window[1], window[1])
    np.testing.assert_array_equal(d.belief[1], belief[1])
    np.testing.assert_array_equal(d.batch.state.x[1], x[1])
    assert not np.array_equal(d.window[0], window[0])
    core.reset(np.array([2]), [7])
    assert np.all(d.window[2] == 0.0) and np.any(d.window[0] != 0.0)
    assert np.isfinite(d.belief[2]).all()
    fresh = learned_core(1, tmp_path, random_network(3))
    fresh.reset(np.array([0]), [7])
    np.testing.assert_array_equal(d.belief[2], fresh.learned_detector.belief[0])


def test_same_seeds_same_beliefs_on_both_engines_and_under_varied_conditions(tmp_path) -> None:
    beliefs = []
    for engine in ("compiled", "compiled", "numpy"):
        core = learned_core(2, tmp_path, random_network(4), engine=engine)
        run = []
        for _ in range(25):
            core.step(np.zeros((2, M)))
            run.append(core.learned_detector.belief.copy())
        beliefs.append(np.array(run))
    np.testing.assert_array_equal(beliefs[0], beliefs[1])
    np.testing.assert_allclose(beliefs[0], beliefs[2], rtol=1e-6, atol=1e-8)
    varied = learned_core(4, tmp_path, random_network(4), vary={"T": [0.5, 5.0]},
                          **BANK_PRESETS["cv-ct-continuous"])
    for _ in range(25):
        varied.step(np.zeros((4, M)))
    assert np.ptp(varied.sampling_period) > 0.5
    assert np.isfinite(varied.learned_detector.window).all()


def test_the_heading_rate_record_is_per_second_at_each_slot_s_sampling_period(tmp_path) -> None:
    # the record's last entry is heading_rate(v_{k-1}, v_k, T) / scale at the slot's own T
    # (drawn per episode in [0.5, 5] s): a rate per step (divided by 1 s) would pass at T = 1
    core = learned_core(4, tmp_path, random_network(4), vary={"T": [0.5, 5.0]},
                        **BANK_PRESETS["cv-ct-continuous"])
    detector = core.learned_detector
    T = core.sampling_period.copy()
    assert np.min(np.abs(T - 1.0)) > 0.05
    turned = 0.0
    for _ in range(25):
        before = detector.velocity.copy()
        core.step(np.zeros((4, M)))
        rate = heading_rate(before, detector.velocity, T)
        expected = np.clip(rate / detector.scale, -3.0, 3.0)
        np.testing.assert_allclose(detector.window[:, -1, -1], expected, rtol=1e-9, atol=1e-12)
        turned = max(turned, float(np.max(np.abs(expected))))
    assert turned > 1e-3  # heading changes among them


def test_a_nan_measurement_leaves_a_finite_belief(tmp_path) -> None:
    # a failed filter's NaN in the record is 0 (nan_to_num): the window and the belief stay
    # finite and the belief a distribution
    core = learned_core(3, tmp_path, random_network(5))
    for _ in range(3):
        core.step(np.zeros((3, M)))
    detector = core.learned_detector
    for z in (np.full((3, 2), np.nan), np.full((3, 2), np.inf)):
        snap = detector.snapshot()
        detector.step(z, np.ones(3, dtype=bool), core.state_a, core.sampling_period)
        assert np.isfinite(detector.window).all()
        assert np.isfinite(detector.belief).all()
        np.testing.assert_allclose(detector.belief.sum(axis=1), 1.0, rtol=1e-12)
        detector.restore(snap, np.ones(3, dtype=bool))


def test_its_belief_is_an_observation(tmp_path) -> None:
    core = learned_core(2, tmp_path, random_network(5), detector_share=0.0,
                        obs_features=("detector_belief",))
    obs = core.step(np.zeros((2, M))).obs
    np.testing.assert_allclose(obs[:, 2 * M:], core.learned_detector.belief, rtol=1e-6)
    np.testing.assert_allclose(core.tpm[:, 0, 0], 0.8)  # share 0: the tracker's TPM


def test_the_configuration_s_errors(tmp_path) -> None:
    base = {"action_mode": "stay", "detector": "learned"}
    four = DetectorNetwork((np.zeros((4, 2 * features_per_step(4))),), (np.zeros(4),), 2)
    four.save(tmp_path / "four.safetensors")
    with pytest.raises(ConfigError, match="places beliefs on 4 models, the bank has 3"):
        EnvConfig(**base, detector_share=0.5, detector_weights=str(tmp_path / "four.safetensors"))
    with pytest.raises(ConfigError, match="detector_share must be in"):
        EnvConfig(**base)
    with pytest.raises(ConfigError, match="distinct turn rates"):
        EnvConfig(**base, detector_share=0.5, bank=[
            {"kind": "cv"}, {"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 4.0}])
    with pytest.raises(ConfigError, match="needs a linear bank"):
        EnvConfig(**base, detector_share=0.5, **BANK_PRESETS["hetero"])
    with pytest.raises(ConfigError, match=r"detector_weights 'nope\.safetensors': no such file"):
        EnvConfig(**base, detector_share=0.5, detector_weights="nope.safetensors")
    with pytest.raises(ConfigError, match="detector_weights must be a file path"):
        EnvConfig(**base, detector_share=0.5, detector_weights=3)


def test_the_envs_run_it_and_pass_gymnasium_s_checker() -> None:
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    kwargs = {"action_mode": "stay", "detector": "learned", "detector_share": 0.5}
    env = gym.make("imm_gym/TPMAdapt-v0", **kwargs)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.unwrapped.core.learned_detector is not None
    venv = gym.make_vec("imm_gym/TPMAdapt-v0", num_envs=3, vectorization_mode="vector_entry_point",
                        **kwargs)
    venv.reset(seed=0)
    for _ in range(5):
        _, reward, *_ = venv.step(np.zeros((3, M)))
    assert np.isfinite(reward).all()


def test_a_configuration_file_names_its_network_relative_to_itself(tmp_path, monkeypatch) -> None:
    from imm_gym.sim.config_file import read_env_config

    (tmp_path / "cfg").mkdir()
    random_network(6).save(tmp_path / "cfg" / "mine.safetensors")
    file = tmp_path / "cfg" / "tracker.yaml"
    file.write_text("action_mode: stay\ndetector: learned\ndetector_share: 0.5\n"
                    "detector_weights: mine.safetensors\n")
    monkeypatch.chdir(tmp_path)
    config = EnvConfig.build(read_env_config(file))
    assert config.detector_weights == str(tmp_path / "cfg" / "mine.safetensors")
    core = TrackingCore(config, 1)
    assert core.learned_detector.network.window == 4


def test_a_restarted_filter_s_heading_rate_starts_from_the_fallback_s_velocity(tmp_path) -> None:
    """A slot whose uniform IMM fails (a NaN measurement) restarts from the fallback posterior:
    its last velocity is then the fallback's combined one, ``sum_j mu_j x_j[2:4]`` worked here
    by hand, so the next step's heading-rate record is ``heading_rate(that, v_k, T) / scale``,
    finite and not 0 (keeping the failed estimate's NaN velocity left it 0)."""
    core = learned_core(3, tmp_path, random_network(5))
    for _ in range(3):
        core.step(np.zeros((3, M)))
    detector = core.learned_detector
    fallback = core.state_a
    z = core.z[np.arange(3), core.k + 1].copy()
    z[1] = np.nan
    detector.step(z, np.ones(3, dtype=bool), fallback, core.sampling_period)
    by_hand = sum(fallback.mu[1, j] * fallback.x[1, j, 2:4] for j in range(M))
    np.testing.assert_allclose(detector.velocity[1], by_hand, rtol=1e-12)
    before = detector.velocity.copy()
    core.step(np.zeros((3, M)))  # the detector's next step, on slot 1's next measurement
    rate = heading_rate(before, detector.velocity, core.sampling_period)
    expected = np.clip(rate / detector.scale, -3.0, 3.0)
    np.testing.assert_allclose(detector.window[:, -1, -1], expected, rtol=1e-9, atol=1e-12)
    assert abs(expected[1]) > 1e-4


def test_parameter_count_counts_weights_and_biases_as_torch_does() -> None:
    """The numbers a network holds (what :data:`MAX_PARAMETERS` bounds) count its biases: by
    hand ``(120 + 1) 16 + (16 + 1) 8 + (8 + 1) 3 = 2099`` for 120 -> 16 -> 8 -> 3, and torch's
    ``numel`` of the same layers for other widths (weights alone undercount by the widths)."""
    from imm_gym.sim.learned_detector import parameter_count

    assert parameter_count([120, 16, 8, 3]) == 2099
    assert parameter_count([5, 2]) == 12
    for widths in ([7, 3], [40, 64, 32, 5], [1, 1, 1]):
        layers = [torch.nn.Linear(a, b) for a, b in pairwise(widths)]
        assert parameter_count(widths) == sum(p.numel() for lay in layers
                                              for p in lay.parameters())


def test_the_window_s_bounds_1_and_1000_are_accepted_and_1001_refused(tmp_path) -> None:
    """The header's window is an integer in [1, 1000], both ends included: a one-layer network
    of ``window * (2 M + 2)`` inputs loads at 1 and at 1000 (8000 inputs for M = 3) with that
    window, and one of 1001 windows is refused."""
    for window in (1, 1000):
        net = DetectorNetwork((np.zeros((M, window * features_per_step(M))),), (np.zeros(M),),
                              window)
        net.save(tmp_path / f"w{window}")
        assert DetectorNetwork.load(tmp_path / f"w{window}").window == window
    tensors = {"layer0.weight": np.zeros((M, 1001 * features_per_step(M))),
               "layer0.bias": np.zeros(M)}
    path = _write(tmp_path / "w1001", tensors, {"format": FORMAT, "window": "1001"})
    with pytest.raises(ConfigError, match="header window must be an integer in"):
        DetectorNetwork.load(path)


def test_record_entries_below_tiny_are_exactly_zero() -> None:
    """Entries of a record below TINY = 1e-12 in magnitude are 0, not kept (subnormal numbers
    slow the network's products): a mode probability of 1e-300 and a rate of 1e-13 scale units
    give 0, while 1e-11 is kept. By hand, the other entries as in the module docstring."""
    mu = np.array([[1.0 - 1e-11, 1e-11, 1e-300]])
    loglik = np.array([[0.0, -5.0, -30.0]])
    record = step_features(mu, loglik, np.array([3.0]), np.array([2e-14]), 0.2)
    np.testing.assert_array_equal(
        record, [[1.0 - 1e-11, 1e-11, 0.0, 0.0, -0.5, -2.0, 0.3, 0.0]]
    )
    assert record[0, 2] == 0.0 and record[0, 7] == 0.0


def test_the_heading_rate_is_in_units_of_the_fastest_turn_of_either_sign(tmp_path) -> None:
    """The heading-rate record is divided by the bank's fastest turn in magnitude: for turn
    rates 0, +2 and -5 °/s that is 5 °/s (the largest rate, 2 °/s, would inflate it 2.5
    times), so the record is ``clip(heading_rate(v_{k-1}, v_k, T) / 5 °/s, -3, 3)``."""
    bank = [{"kind": "cv"}, {"kind": "ct", "turn_rate_deg": 2.0},
            {"kind": "ct", "turn_rate_deg": -5.0}]
    core = learned_core(3, tmp_path, random_network(7), bank=bank)
    detector = core.learned_detector
    turned = 0.0
    for _ in range(25):
        before = detector.velocity.copy()
        core.step(np.zeros((3, M)))
        rate = heading_rate(before, detector.velocity, core.sampling_period)
        expected = np.clip(rate / np.radians(5.0), -3.0, 3.0)
        np.testing.assert_allclose(detector.window[:, -1, -1], expected, rtol=1e-9, atol=1e-12)
        turned = max(turned, float(np.max(np.abs(expected))))
    assert turned > 1e-3  # heading changes among them


def test_the_layer_count_and_width_bounds_are_inclusive(tmp_path) -> None:
    """A network of :data:`MAX_LAYERS` = 8 layers, and one whose hidden layer is
    :data:`MAX_WIDTH` = 4096 wide, load; 9 layers and a width of 4097 are refused by name
    (window 1, 3 models: 8 inputs)."""

    def network(widths: list[int]) -> DetectorNetwork:
        weights = tuple(np.zeros((b, a)) for a, b in pairwise(widths))
        return DetectorNetwork(weights, tuple(np.zeros(b) for b in widths[1:]), 1)

    inputs = features_per_step(M)
    for name, widths in (("eight", [inputs, *[4] * 7, M]), ("wide", [inputs, 4096, M])):
        network(widths).save(tmp_path / name)
        assert len(DetectorNetwork.load(tmp_path / name).weights) == len(widths) - 1
    network([inputs, *[4] * 8, M]).save(tmp_path / "nine")
    with pytest.raises(ConfigError, match=r"\(1 to 8 layers\), got \['layer0\.bias'"):
        DetectorNetwork.load(tmp_path / "nine")
    network([inputs, 4097, M]).save(tmp_path / "wider")
    with pytest.raises(ConfigError, match=r"layer0 has weight \(4097, 8\).*must chain"):
        DetectorNetwork.load(tmp_path / "wider")


def test_the_parameter_bound_is_inclusive(tmp_path) -> None:
    """A detector may hold :data:`MAX_PARAMETERS` = 2^24 numbers, not one more (declared in
    the header, the data a sparse hole): one layer of 4096 x 4095 weights and 4096 biases holds
    exactly 2^24 and passes that check (it is then refused for its input, 4095 not
    ``2 (2 M + 2)``); 673 x 24928 weights and 673 biases hold ``24929 * 673 = 2^24 + 1``."""
    _declare_huge(tmp_path / "exact", (4096, 4095))
    with pytest.raises(ConfigError, match=r"the input must be window \* \(2 M \+ 2\) = 16388"):
        DetectorNetwork.load(tmp_path / "exact")
    _declare_huge(tmp_path / "over", (673, 24928))
    with pytest.raises(ConfigError, match=r"the layers hold 16777217 numbers, above the 16777216"):
        DetectorNetwork.load(tmp_path / "over")


@pytest.mark.parametrize(
    "names",
    [
        ("layer0.weight", "layer0.bias", "layer1.weight", "extra.bias"),
        ("layer0.weight", "layer0.bias", "layer2.weight", "layer2.bias"),
    ],
)
def test_tensors_of_other_names_are_refused_naming_them(tmp_path, names) -> None:
    """Four tensors that are not ``layer0.weight, layer0.bias, layer1.weight, layer1.bias`` (a
    foreign name, a missing layer 1) are refused listing the names, not a KeyError."""
    shapes = [(4, 2 * features_per_step(M)), (4,), (M, 4), (M,)]
    tensors = {name: np.zeros(shape) for name, shape in zip(names, shapes, strict=True)}
    path = _write(tmp_path / "named", tensors, {"format": FORMAT, "window": "2"})
    refused = r"tensors must be layer0\.weight, .*, got \[.*'layer0\.weight'"
    with pytest.raises(ConfigError, match=refused):
        DetectorNetwork.load(path)


def test_a_saved_network_s_notes_are_json_in_its_header(tmp_path) -> None:
    """The notes given to ``save`` (what the training records of itself) are the header's
    ``notes`` entry as JSON, read back by safetensors itself; no notes are ``{}``."""
    from safetensors import safe_open

    notes = {"runs": 3, "seed": 7, "share": [0.5, 0.25]}
    random_network(0).save(tmp_path / "noted", notes)
    random_network(0).save(tmp_path / "plain")
    with safe_open(str(tmp_path / "noted"), framework="np") as f:
        header = f.metadata()
    assert json.loads(header["notes"]) == notes
    assert header["format"] == FORMAT and header["window"] == "4"
    with safe_open(str(tmp_path / "plain"), framework="np") as f:
        assert json.loads(f.metadata()["notes"]) == {}


def test_the_input_is_the_window_s_records_oldest_first(tmp_path) -> None:
    """The network reads each slot's window flattened record by record, oldest first (the layout
    the shipped network was trained on): the input is the records ``window[:, 0], window[:, 1],
    ...`` side by side, and the belief is the network's on that concatenation."""
    core = learned_core(2, tmp_path, random_network(8))
    detector = core.learned_detector
    for _ in range(6):
        core.step(np.zeros((2, M)))
    window = detector.window
    x = np.concatenate([window[:, k] for k in range(window.shape[1])], axis=1)
    assert x.shape == (2, 4 * features_per_step(M)) and np.any(x[:, -1] != 0.0)
    np.testing.assert_array_equal(detector.inputs(), x)
    order = np.argsort(PAPER_RATES)
    np.testing.assert_allclose(detector.belief[:, order], detector.network(x), rtol=1e-15)


def test_an_inactive_slot_keeps_the_velocity_its_next_heading_rate_starts_from(tmp_path) -> None:
    """A slot left out of a step keeps its uniform IMM's last velocity, so its next record's
    heading rate is ``heading_rate(v before the skipped step, v after the next one, T)``."""
    core = learned_core(3, tmp_path, random_network(3))
    for _ in range(6):
        core.step(np.zeros((3, M)))
    d = core.learned_detector
    kept = d.velocity.copy()
    core.step(np.zeros((3, M)), active=np.array([True, False, True]))
    np.testing.assert_array_equal(d.velocity[1], kept[1])
    before = d.velocity.copy()
    core.step(np.zeros((3, M)))
    rate = heading_rate(before, d.velocity, core.sampling_period)
    expected = np.clip(rate / np.radians(4.0), -3.0, 3.0)
    np.testing.assert_allclose(d.window[:, -1, -1], expected, rtol=1e-9, atol=1e-12)
