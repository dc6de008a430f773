"""PPO agents for the TPM-adaptation environments: training, saving, loading as a policy."""

from pathlib import Path

#: The shipped pretrained policy: an ensemble (``ensemble.json``) of the default's five training
#: seeds, each a policy network, normalizer and environment overrides in ``seed_S/``, acting on
#: the mean of their actions; the evaluation tool's policy name ``pretrained``. Regenerate it
#: with ``python train.py --seed 0 1 2 3 4 --jobs 2 --no-eval --out runs/final`` and
#: ``python -m agents.export runs/final/ensemble``.
PRETRAINED = Path(__file__).parent / "pretrained"

#: The shipped policy for a bank of any size: an ensemble of five seeds of the policy shared by
#: the models (:mod:`agents.per_model`), the evaluation tool's policy name
#: ``pretrained-per-model``. Regenerate it with ``python train.py --config
#: agents/hyperparams/per_model.yml --seed 0 1 2 3 4 --jobs 2 --no-eval --out runs/pm`` and
#: ``python -m agents.export runs/pm/ensemble --to agents/pretrained_per_model``.
PRETRAINED_PER_MODEL = Path(__file__).parent / "pretrained_per_model"

#: The shipped policies by their names in the evaluation and tracking tools.
SHIPPED = {"pretrained": PRETRAINED, "pretrained-per-model": PRETRAINED_PER_MODEL}
