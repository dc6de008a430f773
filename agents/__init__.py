"""PPO agents for the TPM-adaptation environments: training, saving, loading as a policy."""
