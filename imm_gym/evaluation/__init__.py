"""Monte-Carlo evaluation of TPM policies: rollouts on common random numbers, metrics (ARMSE,
NEES/NIS, mode accuracy), the clairvoyant bound, paired bootstrap intervals and figures."""
