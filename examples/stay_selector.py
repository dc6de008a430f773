"""A stay chosen by supervision: a network that picks, every step, the switching prior whose
IMM the coming steps favour.

The stay bank (:mod:`imm_gym.sim.stay_bank`) runs beside each slot's tracker one IMM per stay
``s`` of its grid (``1/M`` ... 0.995), each on the ``learned-prior`` rows at that stay::

    Pi_s = r I + (1 - r) 1 q^T,   q = (1 - v) / M + v b,   r = (s - 1/M) / (1 - 1/M),

``b`` the learned detector's belief, ``v`` the share. On the same measurements, their position
errors ``e_s(k)`` are what every stay would have given, so the choice of stay can be learned by
regression instead of from a reward. A network maps the observation before step ``k`` to each
stay's discounted future squared error over the next ``H`` steps, relative to the stays' mean
(scale-free across trackers and sensors)::

    y_s(k) = log( sum_{d<H} g^d e_s(k+d) / sum_{d<H} g^d ) - mean_s'( ... ),

and the policy sets every row to the stay of the smallest prediction — the ``stay`` action that
gives ``Pi_s`` exactly from the uniform base (:func:`agents.selector.stay_action`). It is the
``learned-prior`` rule with its stay chosen online by a network trained across trackers instead
of searched on each tracker's own runs; the TPM stays a switching prior by construction.

Training data: ``--episodes`` episodes spread evenly over the ``--env-config`` files, all
observing the first file's features (or ``--features-from FILE``'s) and the stay bank's
evidence, seeds from :data:`SELECTOR_SEED_BASE` (disjoint from every evaluation, validation and
training seed). While collecting, each slot runs a random stay of the grid, redrawn with
probability 1/30 per step, so the observations cover trackers steered by every stay; every
``--stride``-th step is kept. Then the selector is scored with the evaluation's own code (common
random numbers, paired bootstrap CIs) beside ``best-fixed``, the shipped policy and
``learned-prior``::

    python examples/stay_selector.py --env-config A.yaml B.yaml --episodes 100000 \\
        --runs 100 --seed 0 [--scenario paper ...] [--off-suite FILE ...]

``--targets branch`` replaces each stay's error by what switching the tracker to it gives:
every ``--stride``-th step the tracker's own posterior is restarted under each stay and run
on the episode's measurements for the next ``H`` steps (:func:`branch_errors`); the bank's IMMs
(the default, ``bank``) have run their stay since the episode's start, so their errors also
carry what that history did for them (docs/experiments.md, "Targets from the tracker's own
state").

``--shares V V ...`` chooses the share with the stay: the priors are every stay at every share
``v`` (the ``set`` action sets their rows, :func:`agents.selector.set_action`), their errors
from one core per share replaying the same episodes (docs/experiments.md, "The selector as a
policy, and a share chosen with the stay").

``--save DIR`` writes the selector as a directory of data files (:mod:`agents.selector`), which
``python -m imm_gym.evaluate --policy DIR`` (and every tool that takes an agent) loads;
``--weights A B ...`` scores saved selectors acting as one on their mean prediction without
collecting or fitting, and with ``--save`` writes them as one directory (docs/experiments.md,
"Where in the episode the agents lose, and a stay chosen by supervision").
The fit is torch-seeded and the data seeded: the same arguments give the same numbers on one
machine.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from agents.selector import (
    StaySelector,
    check_priors,
    combine,
    load_selector,
    network,
    save_selector,
    set_action,
    stay_action,
)
from agents.training import set_threads
from imm_gym.cli.comparison import evaluate, evaluated_config
from imm_gym.cli.policies import cannot_run
from imm_gym.cli.suite import suite_configs
from imm_gym.evaluation.metrics import mode_accuracy, mode_prob_tv
from imm_gym.evaluation.rollout import armse_from_squared, paired_bootstrap
from imm_gym.sim.config_file import read_env_config, tracker_of
from imm_gym.sim.core import TrackingCore
from imm_gym.sim.env_config import EnvConfig
from imm_gym.sim.imm_batch import IMMBatch
from imm_gym.sim.stay_bank import detector_tpm_rows
from imm_gym.tracking.imm import IMMState
from imm_gym.validation import ConfigError

Array = NDArray[np.float64]

#: The selector's training episodes: seeds from ``2**60`` on, below the learned detector's
#: (``2**61``) and above every evaluation, validation and SB3 training seed.
SELECTOR_SEED_BASE = 1 << 60
#: The largest ``--fit-seed``: its episodes' seeds ``SELECTOR_SEED_BASE + 10**10 seed + ...``
#: stay below the learned detector's (:data:`~imm_gym.seeding.DETECTOR_SEED_BASE`).
MAX_FIT_SEED = 10**8
#: Logits per unit action of the ``stay`` action: 0.995 from the uniform base within reach.
GAIN = 9.0
#: Features the selector reads beyond a training file's: the stay bank's evidence (the bank
#: whose errors are the targets runs for it), the tracker's tuning, and the belief its action is
#: computed from (last, ``M`` entries).
EXTRA_FEATURES = ("stay_bank_evidence", "tracking_index", "detector_belief")
#: The largest share: every ``q_i >= (1 - v) / M``, and from ``q_i`` the stay action reaches the
#: grid's 0.995 within :data:`GAIN` logits only while ``(1 - v) / M`` is not much below 1/30.
MAX_SHARE = 0.9
#: ``--shares``: the ``set`` action's logits per unit action, and the floor of its rows (every
#: prior's rows exact: ``SET_GAIN >= log(1 / P_MIN) / 2``).
SET_GAIN, P_MIN = 10.0, 1e-4
#: Probability per step that a collecting slot redraws its stay.
REDRAW = 1.0 / 30.0
#: Episodes per collection batch.
BATCH = 256
#: The policies the selector is scored beside (:func:`score`).
COMPARED = ("best-fixed", "pretrained", "learned-prior")


def selector_overrides(
    base: Mapping[str, Any], share: float, q_maneuver: Sequence[float] | None,
    n_segments: Sequence[int] | None, action_mode: str = "stay",
) -> dict[str, Any]:
    """A training file's overrides as the selector runs it: the ``stay`` action from the uniform
    base, the learned detector leaning the share ``share`` of the jumps (of the stay bank's IMMs
    too), :data:`EXTRA_FEATURES` observed; with ``action_mode="set"`` (``--shares``) the ``set``
    action instead (:data:`SET_GAIN`, :data:`P_MIN`), which takes no share: the stay bank runs
    at share 0 and ``share`` is not used. ``q_maneuver`` is added to its ``vary`` and
    ``n_segments`` to its ``family`` where given and the file does not set them."""
    out = dict(base)
    features = [f for f in out.get("obs_features", ()) if f not in EXTRA_FEATURES]
    out.update(action_mode="stay", stay_base="uniform", detector="learned",
               detector_share=share, logit_scale=GAIN,
               obs_features=(*features, *EXTRA_FEATURES))
    if action_mode == "set":
        out.update(action_mode="set", stay_base="tracker", detector_share=0.0,
                   logit_scale=SET_GAIN, p_min=P_MIN)
    if q_maneuver is not None:
        out["vary"] = {"q_maneuver": list(q_maneuver), **out.get("vary", {})}
    if n_segments is not None:
        out["family"] = {"n_segments": list(n_segments), **out.get("family", {})}
    return out


def future_error(errors: Array, gamma: float, horizon: int) -> Array:
    """``(R, K, S)`` targets ``y_s(k)`` of the module docstring from the squared errors
    ``errors (R, K, S)`` (``errors[:, k]``: after step ``k``, the first the action before it
    moves); the window is cut at the episode's end."""
    K = errors.shape[1]
    total = np.zeros(errors.shape)
    weight = np.zeros((1, K, 1))
    for d in range(min(horizon, K)):
        total[:, : K - d] += gamma**d * errors[:, d:]
        weight[:, : K - d] += gamma**d
    y = np.log(total / weight + 1e-6)
    return y - y.mean(axis=2, keepdims=True)


def branch_errors(
    core: TrackingCore, starts: Sequence[IMMState], points: NDArray[np.int64], beliefs: Array,
    stays: Array, gamma: float, horizon: int,
) -> Array:
    r"""``(n, B, S)`` the future error of :func:`future_error` for the tracker restarted at each
    branch point under each prior and held there: the tracker's posterior before step ``b``
    (``starts``, one per step of ``points (B,)``) runs the rows
    :func:`detector_tpm_rows` of each stay ``s`` on the episode's own measurements for the next
    ``H`` steps, ``e_s(b + d) = \lVert \hat p_s(b + d) - p(b + d) \rVert^2`` (capped like the
    collection's), and the log of their weighted mean over the steps left in the episode,

        log( sum_{d<H} g^d e_s(b+d) / sum_{d<H} g^d )

    (not yet centred). Unlike the bank's errors — each stay's IMM run from the
    episode's start — this is what switching the tracker to ``s`` at ``b`` gives, from the
    state its own history left (the learned detector's beliefs, ``beliefs (n, K, M)`` before
    each step, do not depend on the tracker's TPM)."""
    n, B, S, M = core.n_envs, len(points), len(stays), core.M
    K, share, cap = core.horizon, core.config.detector_share, core.config.divergence_error**2
    args = core.batch_kernel_args
    if args is not None and args[0].shape[0] > 1:
        args = (*(np.repeat(a, B, axis=0) for a in args[:3]), *args[3:])
    # the posteriors slot-major: row i * B + j is slot i before step points[j]
    start = IMMState(*(np.stack([getattr(one, a) for one in starts], axis=1).reshape(
        n * B, *getattr(starts[0], a).shape[1:]) for a in ("x", "P", "mu")))
    batch = IMMBatch(core.imm, n * B, S, args)
    batch.start(np.arange(n * B), start, None)
    slot = np.repeat(np.arange(n), B)
    total, weight = np.zeros((n * B, S)), np.zeros((n * B, 1))
    for d in range(min(horizon, K - int(points.min()))):
        t = np.tile(points + d, n)  # the step each row takes now
        live = t < K
        t = np.minimum(t, K - 1)
        rows = detector_tpm_rows(stays[None], beliefs[slot, t][:, None], share)
        out = batch.step(np.ascontiguousarray(rows.reshape(-1, M, M)), core.z[slot, t + 1],
                         core.detected[slot, t + 1], start)
        e2 = np.sum((out.estimate[:, :2].reshape(n * B, S, 2)
                     - core.truth[slot, t + 1, None, :2]) ** 2, axis=-1)
        e2 = np.where(np.isfinite(e2) & (e2 < cap), e2, cap)
        total += np.where(live[:, None], gamma**d * e2, 0.0)
        weight += np.where(live[:, None], gamma**d, 0.0)
    return np.log(total / weight + 1e-6).reshape(n, B, S)


def collect(
    overrides: Mapping[str, Any], episodes: int, first_seed: int, rng: np.random.Generator,
    gamma: float, horizon: int, stride: int, shares: Sequence[float] | None = None,
    branch: bool = False, behaviour: StaySelector | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.int64]]:
    """Observations, targets (:func:`future_error`) and each sample's episode (its seed) of
    ``episodes`` episodes of one configuration (rounded up to whole batches of :data:`BATCH`),
    seeds ``first_seed ...``, every ``stride``-th step; episodes whose tracker diverged are left
    out.

    With ``shares`` (``overrides`` in the ``set`` action mode) the priors are every stay of the
    grid at every share, share-major, and each slot runs a random one of them; their errors
    come from one core per share replaying the same episodes (the same seeds, so the same
    targets and measurements; the observing core's own bank gives share 0).

    With ``branch`` the targets are :func:`branch_errors`' from every ``stride``-th step
    instead of the bank's; with ``behaviour`` the even slots follow that selector (its priors
    must be the collection's) and only the odd ones run random stays."""
    config = EnvConfig.build(overrides)
    n = min(BATCH, episodes)
    core = TrackingCore(config, n)
    grid = core.stay_bank.stays[:, 0]  # type: ignore[union-attr]
    M, cap = core.M, config.divergence_error**2
    if shares is None:
        banks, priors = [core], np.stack([grid, np.full(len(grid), config.detector_share)], 1)
    else:
        banks = [core if v == config.detector_share else TrackingCore(EnvConfig.build(
            {**overrides, "action_mode": "stay", "stay_base": "uniform", "detector_share": v,
             "logit_scale": GAIN}), n) for v in shares]
        priors = np.array([(stay, v) for v in shares for stay in grid])
    if behaviour is not None and not np.array_equal(behaviour.priors, priors):
        raise ConfigError(f"{behaviour.source} chooses among other priors than the collection's")
    others = [bank for bank in banks if bank is not core]
    zero = np.zeros((n, M))  # the other cores' action: their banks run unsteered
    X, Y, E = [], [], []
    for start in range(0, episodes, n):
        seeds = np.arange(first_seed + start, first_seed + start + n, dtype=np.int64)
        for one in (core, *others):
            one.reset(np.arange(n), [int(seed) for seed in seeds])
        obs = core.observe()
        K = core.horizon
        pick = rng.integers(0, len(priors), n)
        seen = np.zeros((n, K, obs.shape[1]), np.float32)
        errors = np.zeros((n, K, len(priors)))
        ended = np.zeros(n, dtype=bool)
        beliefs = np.zeros((n, K, M)) if branch else None
        starts: list[IMMState] = []
        for k in range(K):
            seen[:, k] = obs
            if beliefs is not None:
                beliefs[:, k] = core.detector_belief
                if k % stride == 0:
                    starts.append(core.state_a)
            pick = np.where(rng.random(n) < REDRAW, rng.integers(0, len(priors), n), pick)
            if behaviour is not None:  # the even slots follow it
                pick[::2] = behaviour.choose(obs[::2])
            belief = obs[:, -M:].astype(np.float64)
            stays, v = priors[pick].T
            action = (stay_action(stays, belief, config.detector_share, GAIN) if shares is None
                      else set_action(stays, v, belief, SET_GAIN, P_MIN))
            live = ~core.done
            result = core.step(action) if live.all() else core.step(action, live)
            truth = result.info["true_state"][:, :2]
            for other in others:
                ok = ~other.done
                step = other.step(zero) if ok.all() else other.step(zero, ok)
                both = live & ok
                if not np.array_equal(step.info["true_state"][both, :2], truth[both]):
                    raise RuntimeError("the cores of the shares replay other targets")
                live = both
            ended |= ~live
            obs = result.obs
            if beliefs is not None:  # the targets come from the branches
                continue
            e2 = np.concatenate([np.sum(
                (bank.stay_bank.estimates()[:, :, :2] - truth[:, None]) ** 2, axis=-1  # type: ignore[union-attr]
            ) for bank in banks], axis=1)
            errors[:, k] = np.where(np.isfinite(e2) & (e2 < cap), e2, cap)
        ok = ~ended
        if beliefs is not None:
            y = branch_errors(core, starts, np.arange(0, K, stride), beliefs, priors[:, 0],
                              gamma, horizon)[ok]
            y -= y.mean(axis=2, keepdims=True)
        else:
            y = future_error(errors[ok], gamma, horizon)[:, ::stride]
        X.append(seen[ok][:, ::stride].reshape(-1, seen.shape[-1]))
        Y.append(y.reshape(-1, len(priors)).astype(np.float32))
        E.append(np.repeat(seeds[ok], y.shape[1]))  # the samples episode-major
    return np.concatenate(X), np.concatenate(Y), np.concatenate(E)


def held_out_episodes(episode: NDArray[np.int64], seed: int) -> NDArray[np.bool_]:
    """Which samples are held out: those of a random twentieth of the episodes (at least one
    while two or more, none of one), whole, so that no held-out sample has a neighbouring step
    of its own episode among the training samples. ``episode``: each sample's episode."""
    names = np.unique(episode)
    count = max(1, len(names) // 20) if len(names) > 1 else 0
    held = np.random.default_rng(seed).permutation(names)[:count]
    return np.isin(episode, held)


def fit(X: NDArray[np.float32], Y: NDArray[np.float32], episode: NDArray[np.int64], epochs: int,
        seed: int) -> tuple[torch.nn.Sequential, dict[str, float]]:
    """The network fitted by mean squared error (Adam, batches of 4096; ``torch.manual_seed``),
    with its held-out score on the samples of a twentieth of the episodes
    (:func:`held_out_episodes`; ``episode``: each sample's): the error, the targets' variance,
    and the regret of choosing the predicted best stay (nats of future squared error)."""
    torch.manual_seed(seed)
    mask = held_out_episodes(episode, seed)
    held, used = np.flatnonzero(mask), np.flatnonzero(~mask)
    x, y = torch.from_numpy(X[used]), torch.from_numpy(Y[used])
    net = network(X.shape[1], Y.shape[1])
    optimizer = torch.optim.Adam(net.parameters(), 1e-3)
    for _ in range(epochs):
        for batch in torch.randperm(len(x)).split(4096):
            loss = torch.mean((net(x[batch]) - y[batch]) ** 2)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    with torch.no_grad():
        xh, yh = torch.from_numpy(X[held]), torch.from_numpy(Y[held])
        pred = net(xh)
        chosen = yh.gather(1, pred.argmin(1, keepdim=True)).squeeze(1)
        score = {"mse": float(torch.mean((pred - yh) ** 2)), "variance": float(yh.var(0).mean()),
                 "regret": float((chosen - yh.min(1).values).mean())}
    return net, score


def score(selector: StaySelector, configs: Mapping[str, Mapping[str, Any]], runs: int,
          seed: int) -> None:
    """Print the selector beside ``best-fixed``, ``pretrained`` and ``learned-prior`` on each
    configuration: ARMSE (m), mode accuracy, the selector's mode-probability total variation and
    its paired difference from ``best-fixed`` with a 95 % CI."""
    policies = list(COMPARED)
    print("| configuration | selector | " + " | ".join(policies)
          + " | selector − best-fixed (m) | mode acc. selector / best-fixed | TV |")
    print("|---" * (5 + len(policies)) + "|")
    for name, config in configs.items():
        extra = {"selector": (selector, selector.env_overrides)}
        _, rollouts = evaluate(policies, config.get("scenario", "random"), runs, seed,
                               clairvoyant=False, extra=extra, env_config=config)
        err = {k: r.squared_position_error for k, r in rollouts.items()}
        armse = " | ".join(f"{armse_from_squared(err[k]):.2f}" for k in ["selector", *policies])
        d = paired_bootstrap(err["selector"], err["best-fixed"])
        acc = [mode_accuracy(rollouts[k].mode_probs, rollouts[k].true_model)
               for k in ("selector", "best-fixed")]
        tv = mode_prob_tv(rollouts["selector"].mode_probs, rollouts["selector"].live)
        # None: nothing to score (every run lost at once)
        accuracy = " / ".join("—" if a is None else f"{a:.1%}" for a in acc)
        tv_cell = "—" if tv is None else f"{tv:.3f}"
        print(f"| {name} | {armse} | {d['diff']:+.2f} [{d['low']:+.2f}, {d['high']:+.2f}] "
              f"| {accuracy} | {tv_cell} |", flush=True)


def train(files: Sequence[Mapping[str, Any]], args: argparse.Namespace,
          behaviour: StaySelector | None = None) -> torch.nn.Sequential:
    """Collect ``args.episodes`` episodes spread over ``files`` (``behaviour``: the selector
    half of the slots follow) and fit the network to them, printing what it took and its
    held-out score."""
    rng = np.random.default_rng(args.fit_seed)
    start = time.perf_counter()
    first = SELECTOR_SEED_BASE + 10**10 * args.fit_seed
    parts = [collect(o, args.episodes // len(files), first + j * 10**9, rng, args.gamma,
                     args.horizon, args.stride, args.shares, args.targets == "branch",
                     behaviour) for j, o in enumerate(files)]
    X = np.concatenate([x for x, _, _ in parts])
    Y = np.concatenate([y for _, y, _ in parts])
    episode = np.concatenate([e for _, _, e in parts])  # seeds: distinct across the files
    collected = time.perf_counter() - start
    net, held_out = fit(X, Y, episode, args.epochs, args.fit_seed)
    print(f"{len(X)} samples ({collected:.0f} s), fitted in "
          f"{time.perf_counter() - start - collected:.0f} s; held-out: "
          + ", ".join(f"{k} {v:.4f}" for k, v in held_out.items()))
    return net


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--env-config", nargs="+", default=[], metavar="FILE",
                   help="training configurations (episodes spread evenly over them); unused "
                        "with --weights (a selector records its environment)")
    p.add_argument("--episodes", type=int, default=100_000)
    p.add_argument("--share", type=float, default=0.75,
                   help=f"the detector's share v, at most {MAX_SHARE}")
    p.add_argument("--shares", type=float, nargs="+", default=None, metavar="V",
                   help="choose the share too, among these (in [0, 1]; the set action)")
    p.add_argument("--features-from", default=None, metavar="FILE",
                   help="observe this file's obs_features on every training file (default: the "
                        "first file's)")
    p.add_argument("--q-maneuver", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                   help="vary.q_maneuver of every training file that does not set it")
    p.add_argument("--n-segments", type=int, nargs=2, default=None, metavar=("LO", "HI"),
                   help="family.n_segments of every training file that does not set it")
    p.add_argument("--gamma", type=float, default=1.0)
    p.add_argument("--horizon", type=int, default=30, help="steps of future error (H)")
    p.add_argument("--stride", type=int, default=3, help="keep every N-th step")
    p.add_argument("--behaviour", nargs="+", default=[], metavar="DIR",
                   help="while collecting, half of the slots follow these selectors (as one) "
                        "instead of random stays")
    p.add_argument("--targets", choices=("bank", "branch"), default="bank",
                   help="each stay's future error: its stay bank IMM's, run from the episode's "
                        "start (bank), or the tracker's switched to it at the step (branch)")
    p.add_argument("--epochs", type=int, default=6)
    p.add_argument("--fit-seed", type=int, default=0,
                   help="seed of the data (episodes from SELECTOR_SEED_BASE + 10**10 seed) "
                        "and of the fit")
    p.add_argument("--save", default=None, metavar="DIR",
                   help="write the selector (a directory of data files: agents.selector)")
    p.add_argument("--weights", nargs="+", default=[], metavar="DIR",
                   help="selectors written by --save, acting as one (mean prediction); "
                        "nothing is collected or fitted")
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scenario", action="append", default=[],
                   help="a scenario of the benchmark suite (repeatable; default: all)")
    p.add_argument("--off-suite", nargs="*", default=[], metavar="FILE",
                   help="configuration files scored after the suite")
    args = p.parse_args(argv)
    if not 0.0 <= args.share <= MAX_SHARE:
        p.error(f"--share must be in [0, {MAX_SHARE}], got {args.share}")
    if args.shares is not None and (
        not all(0.0 <= v <= 1.0 for v in args.shares) or len(set(args.shares)) < 2
        or len(set(args.shares)) != len(args.shares)
    ):
        p.error(f"--shares must be at least two distinct shares in [0, 1], got {args.shares}")
    if args.targets == "branch" and args.shares is not None:
        p.error("--targets branch takes one share (--share), not --shares")
    if not args.weights and not args.env_config:
        p.error("give --env-config FILE ... (collect and fit) or --weights DIR ... (score saved "
                "selectors)")
    if args.episodes < len(args.env_config):
        p.error(f"--episodes must be at least one per file ({len(args.env_config)})")
    if not 0.0 < args.gamma <= 1.0:
        p.error(f"--gamma must be in (0, 1], got {args.gamma}")
    for name in ("horizon", "stride", "epochs", "runs"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be at least 1, got {getattr(args, name)}")
    if args.seed < 0:
        p.error(f"--seed must be >= 0, got {args.seed}")
    if not 0 <= args.fit_seed <= MAX_FIT_SEED:
        p.error(f"--fit-seed must be in [0, {MAX_FIT_SEED}] (the training episodes' seeds stay "
                f"below the learned detector's), got {args.fit_seed}")
    suite = suite_configs("benchmark")
    unknown = sorted(set(args.scenario) - set(suite))
    if unknown:
        p.error(f"--scenario {unknown[0]!r} is not in the benchmark suite ({', '.join(suite)})")
    off_suite = {}
    for f in args.off_suite:  # read and checked before collecting and fitting
        try:
            off_suite[f] = read_env_config(f)
            base = evaluated_config(off_suite[f].get("scenario", "random"), off_suite[f])
        except ConfigError as err:
            p.error(f"--off-suite: {err}")
        for name in COMPARED:  # as evaluate checks them, before any roll-out
            reason = cannot_run(name, base, args.seed)
            if reason:
                p.error(f"--off-suite: {f}: {name} cannot run on this configuration: {reason}")
    set_threads(1)  # one BLAS and torch thread: jobs beside it do not wait on each other
    if args.weights:
        try:
            selector = combine([load_selector(d) for d in args.weights])
        except ConfigError as err:
            p.error(f"--weights: {err}")
        if args.save:
            selector = save_selector(args.save, selector.nets, selector.priors,
                                     selector.env_overrides, trained_across=selector.trained_across,
                                     fit={"members_from": list(args.weights)})
    else:
        try:
            features = read_env_config(args.features_from or args.env_config[0]).get(
                "obs_features", ())
        except ConfigError as err:
            p.error(f"{'--features-from' if args.features_from else '--env-config'}: {err}")
        mode = "stay" if args.shares is None else "set"
        files = []
        for f in args.env_config:  # each read and built as the selector runs it
            try:
                files.append(selector_overrides({**read_env_config(f), "obs_features": features},
                                                args.share, args.q_maneuver, args.n_segments,
                                                mode))
                EnvConfig.build(files[-1])
            except ConfigError as err:  # a file's own errors name it, the built config's not
                where = "" if str(err).startswith(f) else f"{f}: "
                p.error(f"--env-config: {where}{err}")
        core = TrackingCore(EnvConfig.build(files[0]), 1)
        grid = core.stay_bank.stays[:, 0].copy()  # type: ignore[union-attr]
        priors = (np.stack([grid, np.full(len(grid), args.share)], axis=1) if args.shares is None
                  else np.array([(stay, v) for v in args.shares for stay in grid]))
        try:  # priors the action cannot set would be refused when saved, after the fit
            check_priors(f"--env-config {args.env_config[0]}", priors, core.config)
        except ConfigError as err:
            p.error(str(err))
        try:
            behaviour = (combine([load_selector(d) for d in args.behaviour]) if args.behaviour
                         else None)
        except ConfigError as err:
            p.error(f"--behaviour: {err}")
        nets = [train(files, args, behaviour)]
        across = tuple(tracker_of(f) for f in files[1:])
        fit_record = {k: v for k, v in vars(args).items() if k not in ("save", "weights")}
        selector = (save_selector(args.save, nets, priors, files[0], trained_across=across,
                                  fit=fit_record) if args.save
                    else StaySelector(nets, priors, files[0], core.observe().shape[1],
                                      trained_across=across))
    if args.save:
        print(f"wrote {args.save} ({len(selector.nets)} network"
              f"{'s' * (len(selector.nets) > 1)})")
    configs = {k: v for k, v in suite.items() if not args.scenario or k in args.scenario}
    configs.update(off_suite)
    score(selector, configs, args.runs, args.seed)


if __name__ == "__main__":
    main()
