"""PPO agents for the TPM-adaptation environments (lands with the PPO issue)."""
