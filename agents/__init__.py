"""PPO agents for the TPM-adaptation environments: training, saving, loading as a policy."""

from pathlib import Path

#: The shipped pretrained agent (policy network, normalizer, environment overrides); the
#: evaluation tool's policy name ``pretrained``. Regenerate it with ``python -m agents.export``.
PRETRAINED = Path(__file__).parent / "pretrained"
