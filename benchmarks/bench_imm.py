"""Single-core throughput of imm_gym's batched IMM tracker, and FilterPy for reference.

What is measured (all on one CPU core: the BLAS/OpenMP thread pools are limited to one thread
before numpy is imported):

1. imm_gym: ``IMM(paper_bank(), Sonar())`` — M = 3 models (CV, CT(+4°/s), CT(-4°/s)) on
   ``[x, y, vx, vy]``, range-bearing sonar, SVD-UKF — for N = 1, 64 and 1024 trackers, and the
   same bank with ``filter="ekf"`` for N = 1 and 1024. The timed call is ``imm.step(state, tpm,
   z_k)`` (default arguments, input validation included) on the real measurements of
   ``draw_batch(paper_scenario(), Sonar(), N, seed)``: the 150 steps of the paper scenario are
   stepped through, and the trackers are re-initialised (outside the timed region) when they run
   out.
2. FilterPy: ``filterpy.kalman.IMMEstimator`` over three ``UnscentedKalmanFilter``s set up on the
   same models (F and Q from ``imm.F`` / ``imm.Q``, ``R = Sonar().R``, Merwe sigma points with
   ``alpha=1, beta=2, kappa=0``, bearing-wrapping residual and mean), one tracker; the timed call is
   ``predict()`` followed by ``update(z)``.
3. Speed-up of imm_gym over FilterPy per tracker-step, and imm_gym's tracker-steps/s against the
   150,000 tracker-steps/s target.

Each configuration is warmed up first (imm_gym's numba kernel compiles on its first call), then
timed with ``time.perf_counter`` over ``--repeats`` repeats (garbage collection off while timing,
as ``timeit`` does), the configurations' repeats taking turns, each after an untimed warm-up of
its own (``harness.measure_interleaved``): the speed-ups over FilterPy divide medians taken over
the same stretch of time. A repeat runs whole 150-step episodes, enough of them to last at least
``MIN_REPEAT_S`` (one episode with ``--quick``). Reported figures are medians over the repeats:
microseconds per batch step and tracker-steps per second (N / time per batch step), wall time,
and beside it the process CPU time per batch step (of the same timed loops; on a shared machine
the wall time also holds the waits for a core).

A sanity check runs both implementations on the same measurements (run 0 of the batch) and prints
how far apart their position estimates are; more than ``SANITY_TOL_M`` metres at any of the 150
steps means the FilterPy setup is wrong (the script then exits with status 1). They are not
identical: both draw the update's sigma points from the predicted covariance (FilterPy 2.0's
``predict`` redraws them), but FilterPy takes a Cholesky square root of P, imm_gym the symmetric
(eigen) one. Measured: at most 4.3e-3 m apart over the steps for seeds 0-29 (3.8e-3 m for seed
0, 2.8e-6 m at its last step); a FilterPy IMM set up wrongly — Q x 100, R x 10, the CV model in
all three filters or a uniform TPM — is 26-88 m away at its worst step (1.2-12 m at the last,
which the check used to look at, against 50 m: it could not fail).

Run from the repository root::

    python benchmarks/bench_imm.py                 # full run (~25 s)
    python benchmarks/bench_imm.py --quick         # 3 repeats of one episode each
    python benchmarks/bench_imm.py --repeats 11 --json /tmp/bench.json
"""

from __future__ import annotations

import os

import harness

os.environ.update(harness.ONE_THREAD)  # single core: before numpy (and numba) are imported

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import filterpy
import numpy as np
from filterpy.kalman import IMMEstimator, MerweScaledSigmaPoints, UnscentedKalmanFilter
from rich.console import Console
from rich.table import Column

from imm_gym import IMM, Sonar, draw_batch, paper_bank, paper_scenario, stay_tpm

TARGET_TRACKER_STEPS_PER_S = 150_000.0
STAY = 0.995
N_IMM_GYM_UKF = (1, 64, 1024)
N_IMM_GYM_EKF = (1, 1024)
MIN_REPEAT_S = 0.5  # a repeat runs whole episodes until at least this long (not with --quick)
WARMUP_STEPS = 10
# largest position difference imm_gym vs FilterPy over all steps: ~10x the 4.3e-3 m measured
# (Cholesky against symmetric square roots), far below the 26 m of the least wrong setup tried
SANITY_TOL_M = 0.05
IMM_GYM = "imm_gym"
FP_KEY = ("FilterPy IMMEstimator", "ukf", 1)  # the FilterPy reference among the timed cases

Array = np.ndarray


@dataclass
class Result:
    """Timing of one configuration."""

    impl: str
    filter: str
    n_trackers: int
    us_per_step: float  # median microseconds per batch step
    tracker_steps_per_s: float  # N / median time per batch step
    us_per_step_min: float
    us_per_step_max: float
    cpu_us_per_step: float  # median process-CPU microseconds per batch step
    episodes_per_repeat: int
    steps_timed: int
    per_repeat_us: list[float] = field(default_factory=list)
    per_repeat_cpu_us: list[float] = field(default_factory=list)

    @property
    def us_per_tracker_step(self) -> float:
        return self.us_per_step / self.n_trackers


# ---------------------------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------------------------


def case(episode: harness.Episode, horizon: int) -> tuple[Callable[[], float], harness.Block, int]:
    """The ``(warmup, block, unit_steps)`` of :func:`harness.measure_interleaved` for episodes of
    ``horizon`` steps."""
    return (
        harness.episode_warmup(episode, WARMUP_STEPS),
        harness.episode_block(episode, horizon),
        horizon,
    )


def result(impl: str, filt: str, n: int, m: harness.Measurement) -> Result:
    """The :class:`Result` of a measurement of ``n`` trackers."""
    return Result(
        impl=impl,
        filter=filt,
        n_trackers=n,
        us_per_step=m.us_per_step,
        tracker_steps_per_s=n / m.median_s,
        us_per_step_min=m.us_per_step_min,
        us_per_step_max=m.us_per_step_max,
        cpu_us_per_step=m.cpu_us_per_step,
        episodes_per_repeat=m.units,
        steps_timed=m.steps,
        per_repeat_us=m.per_repeat_us,
        per_repeat_cpu_us=m.per_repeat_cpu_us,
    )


# ---------------------------------------------------------------------------------------------
# imm_gym
# ---------------------------------------------------------------------------------------------


def imm_gym_episode(imm: IMM, z: Array, x0: Array, P0: Array, tpm: Array) -> harness.Episode:
    """Episodes of ``imm.step`` over measurements ``z`` of shape ``(N, K+1, 2)``.

    ``z[:, 0]`` initiated the track (it gave ``x0, P0``); steps 1..K are filtered.
    """
    zs = [np.ascontiguousarray(z[:, k]) for k in range(1, z.shape[1])]

    def episode(steps: int) -> float:
        state = imm.init(x0, P0)
        step = imm.step
        todo = zs[:steps]

        def loop() -> None:
            s = state
            for zk in todo:
                s, _ = step(s, tpm, zk)

        return harness.timed(loop)

    return episode


# ---------------------------------------------------------------------------------------------
# FilterPy
# ---------------------------------------------------------------------------------------------


def _wrap(a: Array | float) -> Array | float:
    """Angle(s) wrapped to (-pi, pi], as imm_gym does."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def sonar_hx(x: Array) -> Array:
    """Range and bearing of a sonar at the origin."""
    return np.array([math.sqrt(x[0] * x[0] + x[1] * x[1]), math.atan2(x[1], x[0])])


def residual_z(a: Array, b: Array) -> Array:
    """``a - b`` with the bearing difference wrapped."""
    d = np.subtract(a, b)
    d[1] = _wrap(d[1])
    return d


def z_mean(sigmas: Array, wm: Array) -> Array:
    """Weighted mean of range-bearing sigma points: bearings averaged as wrapped residuals about
    the centre point (as imm_gym does), so points straddling ±pi average correctly."""
    ref = sigmas[0]
    d = sigmas - ref
    d[:, 1] = _wrap(d[:, 1])
    m = ref + wm @ d
    m[1] = _wrap(m[1])
    return m


def _make_fx(F: Array) -> Callable[[Array, float], Array]:
    def fx(x: Array, dt: float) -> Array:
        return F @ x

    return fx


def make_filterpy_imm(
    F: Array, Q: Array, R: Array, x0: Array, P0: Array, tpm: Array
) -> IMMEstimator:
    """FilterPy IMM over one UKF per model (F[j], Q[j]), all starting at ``(x0, P0)``."""
    filters = []
    for Fj, Qj in zip(F, Q, strict=True):
        ukf = UnscentedKalmanFilter(
            dim_x=4,
            dim_z=2,
            dt=1.0,
            hx=sonar_hx,
            fx=_make_fx(Fj.copy()),
            points=MerweScaledSigmaPoints(4, alpha=1.0, beta=2.0, kappa=0.0),
            residual_z=residual_z,
            z_mean_fn=z_mean,
        )
        ukf.x = x0.copy()
        ukf.P = P0.copy()
        ukf.Q = Qj.copy()
        ukf.R = R.copy()
        filters.append(ukf)
    return IMMEstimator(filters, mu=[1.0 / 3.0] * 3, M=tpm.copy())


def filterpy_episode(
    F: Array, Q: Array, R: Array, z: Array, x0: Array, P0: Array
) -> harness.Episode:
    """Episodes of FilterPy ``predict(); update(z)`` over one tracker's ``z`` of shape (K+1, 2)."""
    zs = [np.array(z[k]) for k in range(1, z.shape[0])]
    tpm = stay_tpm(3, STAY)

    def episode(steps: int) -> float:
        est = make_filterpy_imm(F, Q, R, x0, P0, tpm)
        predict, update = est.predict, est.update
        todo = zs[:steps]

        def loop() -> None:
            for zk in todo:
                predict()
                update(zk)

        return harness.timed(loop)

    return episode


# ---------------------------------------------------------------------------------------------
# Sanity check: same measurements through both implementations
# ---------------------------------------------------------------------------------------------


def sanity_check(imm: IMM, seed: int) -> dict[str, Any]:
    batch = draw_batch(paper_scenario(), Sonar(), 1, seed)
    z = batch.measurements.z[0]
    truth = batch.truth.states[0, 1:, :2]
    tpm = stay_tpm(3, STAY)

    state = imm.init(batch.x0, batch.P0)
    ours = []
    for k in range(1, z.shape[0]):
        state, out = imm.step(state, tpm, z[None, k])
        ours.append(out.x[0, :2])
    ours_mu = out.mode_probs[0]
    ours = np.array(ours)

    est = make_filterpy_imm(imm.F, imm.Q, Sonar().R, batch.x0[0], batch.P0[0], tpm)
    theirs = []
    for k in range(1, z.shape[0]):
        est.predict()
        est.update(z[k])
        theirs.append(est.x[:2].copy())
    theirs = np.array(theirs)

    diff = np.linalg.norm(ours - theirs, axis=1)
    err_ours = np.linalg.norm(ours - truth, axis=1)
    err_theirs = np.linalg.norm(theirs - truth, axis=1)
    worst = float(diff.max())
    return {
        "seed": seed,
        "steps": int(diff.size),
        "final_pos_imm_gym_m": ours[-1].tolist(),
        "final_pos_filterpy_m": theirs[-1].tolist(),
        "final_pos_diff_m": float(diff[-1]),
        "max_pos_diff_m": worst,
        "mean_pos_diff_m": float(diff.mean()),
        "final_truth_err_imm_gym_m": float(err_ours[-1]),
        "final_truth_err_filterpy_m": float(err_theirs[-1]),
        "pos_rmse_imm_gym_m": float(np.sqrt(np.mean(err_ours**2))),
        "pos_rmse_filterpy_m": float(np.sqrt(np.mean(err_theirs**2))),
        "final_mode_probs_imm_gym": ours_mu.tolist(),
        "final_mode_probs_filterpy": est.mu.tolist(),
        "tolerance_m": SANITY_TOL_M,
        "ok": worst <= SANITY_TOL_M,
    }


# ---------------------------------------------------------------------------------------------
# Reporting
# ---------------------------------------------------------------------------------------------


def environment() -> dict[str, Any]:
    return harness.environment(filterpy=filterpy.__version__)


def _fmt_rate(x: float) -> str:
    return f"{x:,.0f}"


def render(
    console: Console,
    results: list[Result],
    fp: Result,
    sanity: dict[str, Any],
    env: dict[str, Any],
    repeats: int,
) -> dict[str, float]:
    fp_us_per_tracker_step = fp.us_per_tracker_step
    table = harness.table(
        "IMM bank step throughput — M = 3 models, paper scenario, sonar, 1 core",
        Column("implementation", no_wrap=True),
        "filter",
        harness.right("N"),
        harness.right("µs / batch step"),
        harness.range_column(),
        harness.right("CPU µs / batch step"),
        harness.right("µs / tracker-step"),
        harness.right("tracker-steps/s (1 core)"),
        harness.right("speed-up vs FilterPy"),
        harness.right("vs 150k target"),
        caption=(
            f"median of {repeats} repeats, the rows' taken in turn; µs per batch step = one step "
            "of all N trackers, wall time; CPU = process CPU time; speed-up = FilterPy µs per "
            "tracker-step / this row's (wall)"
        ),
    )
    for r in [*results, fp]:
        if r is fp:
            table.add_section()
        table.add_row(
            r.impl,
            r.filter,
            str(r.n_trackers),
            f"{r.us_per_step:,.1f}",
            harness.range_cell(r.us_per_step_min, r.us_per_step_max),
            f"{r.cpu_us_per_step:,.1f}",
            f"{r.us_per_tracker_step:,.2f}",
            _fmt_rate(r.tracker_steps_per_s),
            f"{fp_us_per_tracker_step / r.us_per_tracker_step:,.1f}×",
            f"{r.tracker_steps_per_s / TARGET_TRACKER_STEPS_PER_S:.3f}",
        )
    console.print(table)

    ukf = {r.n_trackers: r for r in results if r.impl == IMM_GYM and r.filter == "ukf"}
    speedup_n1 = fp.us_per_step / ukf[1].us_per_step
    speedup_n1_cpu = fp.cpu_us_per_step / ukf[1].cpu_us_per_step
    target_ratio = ukf[1024].tracker_steps_per_s / TARGET_TRACKER_STEPS_PER_S
    cpu_rate = 1024 / (ukf[1024].cpu_us_per_step * 1e-6)
    headline = harness.table(
        "Headline (imm_gym SVD-UKF)",
        "metric",
        harness.right("wall time"),
        harness.right("CPU time"),
    )
    headline.add_row(
        "speed-up: imm_gym N=1 per step vs FilterPy per step",
        f"{speedup_n1:,.1f}×  ({ukf[1].us_per_step:,.1f} vs {fp.us_per_step:,.1f} µs)",
        f"{speedup_n1_cpu:,.1f}×  ({ukf[1].cpu_us_per_step:,.1f} vs "
        f"{fp.cpu_us_per_step:,.1f} µs)",
    )
    headline.add_row(
        "imm_gym N=1024 tracker-steps/s vs 150,000 target",
        f"{target_ratio:.3f}  ({_fmt_rate(ukf[1024].tracker_steps_per_s)} / 150,000)",
        f"{cpu_rate / TARGET_TRACKER_STEPS_PER_S:.3f}  ({_fmt_rate(cpu_rate)} / 150,000)",
    )
    console.print(headline)

    status = "[green]OK[/green]" if sanity["ok"] else "[bold red]SUSPECT[/bold red]"
    console.print(
        f"Sanity check (seed {sanity['seed']}, {sanity['steps']} steps, same measurements): "
        f"largest position difference imm_gym vs FilterPy over the steps = "
        f"{sanity['max_pos_diff_m']:.3g} m (last step {sanity['final_pos_diff_m']:.3g} m, "
        f"mean {sanity['mean_pos_diff_m']:.3g} m) — {status} (tolerance {SANITY_TOL_M:g} m)"
    )
    console.print(
        f"  final position error vs truth: imm_gym {sanity['final_truth_err_imm_gym_m']:.2f} m, "
        f"FilterPy {sanity['final_truth_err_filterpy_m']:.2f} m; position RMSE: imm_gym "
        f"{sanity['pos_rmse_imm_gym_m']:.2f} m, FilterPy {sanity['pos_rmse_filterpy_m']:.2f} m"
    )
    console.print(
        f"[dim]{env['processor']}; {harness.thread_summary(env)}; numpy {env['numpy']}, "
        f"filterpy {env['filterpy']}, Python {env['python']}; load avg at start "
        f"{env['loadavg_at_start'][0] if env['loadavg_at_start'] else float('nan'):.2f}[/dim]"
    )
    return {
        "speedup_n1_vs_filterpy": speedup_n1,
        "speedup_n1_vs_filterpy_cpu": speedup_n1_cpu,
        "n1024_vs_target": target_ratio,
        "n1024_vs_target_cpu": cpu_rate / TARGET_TRACKER_STEPS_PER_S,
    }


# ---------------------------------------------------------------------------------------------
# Main
# ---------------------------------------------------------------------------------------------


def run(args: argparse.Namespace, console: Console) -> int:
    repeats = harness.count(args.repeats, args.quick, 7, 3, "--repeats")
    min_repeat_s = 0.0 if args.quick else MIN_REPEAT_S
    env = environment()
    sonar = Sonar()
    tpm = stay_tpm(3, STAY)
    scenario = paper_scenario()
    horizon = scenario.horizon

    batches: dict[int, Any] = {}

    def batch_of(n: int) -> Any:
        if n not in batches:
            batches[n] = draw_batch(scenario, sonar, n, args.seed)
        return batches[n]

    configs = [("ukf", n) for n in N_IMM_GYM_UKF] + [("ekf", n) for n in N_IMM_GYM_EKF]
    cases: dict[tuple[str, str, int], tuple[Callable[[], float], harness.Block, int]] = {}
    for filt, n in configs:
        imm = IMM(paper_bank(), sonar, filter=filt)
        b = batch_of(n)
        cases[IMM_GYM, filt, n] = case(
            imm_gym_episode(imm, b.measurements.z, b.x0, b.P0, tpm), horizon
        )
    imm = IMM(paper_bank(), sonar)
    b = batch_of(1)
    cases[FP_KEY] = case(
        filterpy_episode(imm.F, imm.Q, sonar.R, b.measurements.z[0], b.x0[0], b.P0[0]), horizon
    )
    names = ", ".join(f"{filt} N={n}" for filt, n in configs)
    console.print(
        f"[dim]timing imm_gym {names} and FilterPy IMMEstimator (UKF) N=1, repeats in turn "
        "...[/dim]"
    )
    measured = harness.measure_interleaved(cases, repeats, min_repeat_s)
    results = [result(*key, measured[key]) for key in cases if key != FP_KEY]
    fp = result(*FP_KEY, measured[FP_KEY])

    sanity = sanity_check(imm, args.seed)
    headline = render(console, results, fp, sanity, env, repeats)

    if args.json is not None:
        payload = {
            "benchmark": "bench_imm",
            "settings": {
                "repeats": repeats,
                "quick": args.quick,
                "seed": args.seed,
                "horizon": horizon,
                "min_repeat_s": min_repeat_s,
                "stay": STAY,
                "target_tracker_steps_per_s": TARGET_TRACKER_STEPS_PER_S,
            },
            "environment": env,
            "results": [
                {**asdict(r), "us_per_tracker_step": r.us_per_tracker_step} for r in [*results, fp]
            ],
            "headline": headline,
            "sanity": sanity,
        }
        harness.write_json(args.json, payload, console)
    return 0 if sanity["ok"] else 1


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    harness.add_repeats(p, "timed repeats per configuration, >= 1 (7; 3 quick)")
    harness.add_quick(p, "3 repeats of a single 150-step episode each")
    harness.add_json(p)
    harness.add_seed(p, "draw_batch seed (default 0)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    return harness.main(run, parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
