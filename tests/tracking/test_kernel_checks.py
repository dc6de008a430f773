"""The compiled input checks of ``IMM.step`` (``unclear_inputs``: ``clearly_stochastic`` and
``all_finite`` of :mod:`imm_gym.tracking.kernels.imm`; for one tracker inside
``checked_step_one``'s call): they accept what ``validate_tpm`` and ``used_measurements`` accept
and hand everything else to them, so the errors and the repair of a missed detection's
measurement stay those of the reference validators, for one tracker and for several."""

from __future__ import annotations

import numpy as np
import pytest

from imm_gym import IMM, ConfigError, Sonar, paper_bank, stay_tpm
from imm_gym.tracking.kernels import imm as kernel
from imm_gym.tracking.tpm import ROW_SUM_TOL


def _bank(n: int = 2) -> tuple[IMM, object, np.ndarray]:
    imm = IMM(paper_bank(), Sonar())
    state = imm.init(np.array([[1000.0, 2000.0, 5.0, -3.0]] * n), np.diag([100.0, 100.0, 4.0, 4.0]))
    z = np.array([[2236.0, 1.107], [2237.0, 1.106]])[:n]
    return imm, state, z


def test_clearly_stochastic_flags_every_defect() -> None:
    tpm = stay_tpm(3, 0.95)
    assert kernel.clearly_stochastic(tpm, 0.5 * ROW_SUM_TOL)
    assert kernel.clearly_stochastic(np.stack([tpm, tpm]), 0.5 * ROW_SUM_TOL)
    for row, col, value in ((0, 1, np.nan), (1, 2, np.inf), (2, 0, -1e-3)):
        bad = tpm.copy()
        bad[row, col] = value
        assert not kernel.clearly_stochastic(bad, 0.5 * ROW_SUM_TOL)
    off = tpm.copy()
    off[1, 1] += 0.75 * ROW_SUM_TOL  # within the validator's tolerance, not within half of it
    assert not kernel.clearly_stochastic(off, 0.5 * ROW_SUM_TOL)
    assert kernel.all_finite(np.ones((3, 2)))
    assert not kernel.all_finite(np.array([[1.0, np.nan]]))
    assert not kernel.all_finite(np.array([[1.0], [-np.inf]]))


def test_unclear_inputs_flags_each_input_apart() -> None:
    tpm, tol = stay_tpm(3, 0.95), 0.5 * ROW_SUM_TOL
    bad_tpm, bad_z = tpm.copy(), np.ones((1, 2))
    bad_tpm[2, 0] = np.nan
    bad_z[0, 1] = np.inf
    assert kernel.unclear_inputs(tpm, np.ones((1, 2)), tol) == 0
    assert kernel.unclear_inputs(bad_tpm, np.ones((1, 2)), tol) == kernel.TPM_UNCLEAR
    assert kernel.unclear_inputs(tpm[None], bad_z, tol) == kernel.Z_UNCLEAR
    both = kernel.TPM_UNCLEAR | kernel.Z_UNCLEAR
    assert kernel.unclear_inputs(bad_tpm, bad_z, tol) == both


def test_one_tpm_for_one_tracker_steps_as_its_own_matrix() -> None:
    imm, state, z = _bank()
    one = type(state)(state.x[:1], state.P[:1], state.mu[:1])
    tpm = stay_tpm(3, 0.9)
    shared_state, shared = imm.step(one, tpm, z[:1])
    own_state, own = imm.step(one, tpm[None].copy(), z[:1])
    np.testing.assert_array_equal(shared.x, own.x)
    np.testing.assert_array_equal(shared_state.P, own_state.P)
    np.testing.assert_array_equal(tpm, stay_tpm(3, 0.9))  # the caller's TPM untouched


@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize(
    ("value", "message"),
    [(np.nan, "finite"), (-0.01, ">= 0"), (0.2, "sum to 1")],
)
def test_step_raises_the_validators_errors(value: float, message: str, n: int) -> None:
    imm, state, z = _bank(n)
    tpm = stay_tpm(3, 0.95)
    tpm[0, 1] = value
    with pytest.raises(ConfigError, match=message):
        imm.step(state, tpm, z)


@pytest.mark.parametrize("n", [1, 2])
def test_borderline_and_non_contiguous_tpms_get_the_validators_verdict(n: int) -> None:
    imm, state, z = _bank(n)
    tpm = stay_tpm(3, 0.95)
    _, ref = imm.step(state, tpm, z)
    near = tpm.copy()
    near[1, 1] += 0.75 * ROW_SUM_TOL  # the validator accepts it
    _, out = imm.step(state, near, z)
    assert np.all(np.isfinite(out.x))
    beyond = tpm.copy()
    beyond[1, 1] += 2.0 * ROW_SUM_TOL
    with pytest.raises(ConfigError, match="sum to 1"):
        imm.step(state, beyond, z)
    _, fortran = imm.step(state, np.asfortranarray(tpm.T).T, z)  # a transposed view: F order
    np.testing.assert_array_equal(fortran.x, ref.x)
    _, listed = imm.step(state, tpm.tolist(), z)
    np.testing.assert_array_equal(listed.x, ref.x)
    _, unchecked = imm.step(state, tpm.tolist(), z, check=False)
    np.testing.assert_array_equal(unchecked.x, ref.x)
    with pytest.raises(ConfigError, match=f"tpm has 3 matrices for {n} trackers"):
        imm.step(state, np.stack([tpm] * 3), z)
    with pytest.raises(ConfigError, match="shape"):
        imm.step(state, np.eye(2), z)


@pytest.mark.parametrize("n", [1, 2])
def test_non_finite_measurements_checked_and_repaired_as_before(n: int) -> None:
    imm, state, z = _bank(n)
    detected = np.array([True, False])[-n:]
    _, ref = imm.step(state, stay_tpm(3, 0.95), np.where(detected[:, None], z, 0.0), detected)
    _, out = imm.step(state, stay_tpm(3, 0.95), np.where(detected[:, None], z, np.nan), detected)
    np.testing.assert_array_equal(out.x, ref.x)
    with pytest.raises(ConfigError, match="finite where detected"):
        imm.step(state, stay_tpm(3, 0.95), np.where(detected[:, None], z, np.nan))
    with pytest.raises(ConfigError, match="finite where detected"):
        imm.step(state, stay_tpm(3, 0.95), np.full_like(z, np.nan), np.ones(n, dtype=bool))
    with pytest.raises(ConfigError, match="finite where detected"):
        imm.step(state, stay_tpm(3, 0.95), np.full_like(z, np.inf))


def test_one_tracker_entry_checks_before_it_steps() -> None:
    """``checked_step_one`` returns minus ``unclear_inputs``' flags and writes no output where
    the inputs need the reference checks; with a negative tolerance it steps without them."""
    imm, state, z = _bank(1)
    assert imm._bank_one is not None
    tpm = stay_tpm(3, 0.95)[None].copy()
    bad_tpm, bad_z = tpm.copy(), z.copy()
    bad_tpm[0, 1, 1] = np.nan
    bad_z[0, 0] = np.inf
    shapes = [(1, 3, 4), (1, 3, 4, 4), (1, 3), (1, 3), (1, 3), (1, 3), (1, 3, 2), (1,), (1, 4),
              (1, 4, 4)]
    tol = 0.5 * ROW_SUM_TOL
    for t, m, flags in ((bad_tpm, z, kernel.TPM_UNCLEAR), (tpm, bad_z, kernel.Z_UNCLEAR),
                        (bad_tpm, bad_z, kernel.TPM_UNCLEAR | kernel.Z_UNCLEAR)):
        outs = [np.full(shape, 7.0) for shape in shapes] + [np.ones(1, dtype=bool)]
        code = kernel.checked_step_one(state.x, state.P, state.mu, t, m, np.ones(1, dtype=bool),
                                       imm._bank_one, tol, *outs)
        assert code == -flags
        assert all((a == 7.0).all() for a in outs[:-1]) and outs[-1].all()
    outs = [np.full(shape, 7.0) for shape in shapes] + [np.ones(1, dtype=bool)]
    code = kernel.checked_step_one(state.x, state.P, state.mu, tpm, z, np.ones(1, dtype=bool),
                                   imm._bank_one, -1.0, *outs)
    assert code == 0 and not outs[-1][0]
    _, ref = imm.step(state, tpm, z)
    np.testing.assert_array_equal(outs[8], ref.x)


@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("check", [True, False])
def test_a_tpm_of_more_than_three_axes_is_refused(n: int, check: bool) -> None:
    imm, state, z = _bank(n)
    with pytest.raises(ConfigError, match=r"tpm must have shape \(3, 3\) or \(N, 3, 3\)"):
        imm.step(state, stay_tpm(3, 0.9)[None, None], z, check=check)


@pytest.mark.parametrize("engine", ["compiled", "numpy"])
def test_a_small_negative_entry_in_rows_summing_to_1_is_refused(engine: str) -> None:
    """A TPM whose rows sum to 1 but which holds the entry -1e-4 is no probability matrix (every
    entry must be >= 0): the fast check does not call it clear, and ``IMM.step`` of three
    trackers raises the validator's ConfigError, in both engines."""
    tpm = np.array([[0.9501, -0.0001, 0.05], [0.025, 0.95, 0.025], [0.025, 0.025, 0.95]])
    np.testing.assert_allclose(tpm.sum(axis=1), 1.0, rtol=0, atol=1e-15)
    assert not kernel.clearly_stochastic(tpm, 0.5 * ROW_SUM_TOL)
    imm = IMM(paper_bank(), Sonar(), engine=engine)
    state = imm.init(np.array([[1000.0, 2000.0, 5.0, -3.0]] * 3), np.diag([100.0, 100.0, 4.0, 4.0]))
    z = np.array([[2236.0, 1.107], [2237.0, 1.106], [2235.0, 1.108]])
    with pytest.raises(ConfigError, match=">= 0"):
        imm.step(state, tpm, z)
