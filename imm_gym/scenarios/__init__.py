"""Where targets come from: the segment tables (the paper's scenario, the randomized family) and
the source profiles of the seed-002 and seed-003 systems. Every source draws truth with
``truth(rngs)`` from one generator per run."""
