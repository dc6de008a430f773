"""Rule-based TPM policies with the stable-baselines3 ``predict`` interface (baselines issue)."""
