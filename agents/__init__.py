"""PPO agents for the TPM-adaptation environments: training, saving, loading as a policy."""

from pathlib import Path

#: The shipped pretrained policy: an ensemble (``ensemble.json``) of the default's five training
#: seeds, each a policy network, normalizer and environment overrides in ``seed_S/``, acting on
#: the mean of their actions; the evaluation tool's policy name ``pretrained``. Regenerate it
#: with ``python train.py --seed 0 1 2 3 4 --jobs 2 --no-eval --out runs/final`` and
#: ``python -m agents.export runs/final/ensemble``.
PRETRAINED = Path(__file__).parent / "pretrained"
