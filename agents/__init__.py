"""PPO agents for the TPM-adaptation environments: training, saving, loading as a policy."""

from pathlib import Path

#: The small pretrained agent shipped with the package (``--policy pretrained``).
PRETRAINED = Path(__file__).parent / "pretrained"
