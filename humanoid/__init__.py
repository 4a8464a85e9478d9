"""The body: the simulated Humanoid-v5, what its sensors read and its estimator makes of them, its static balance and
capture point, and what the conditions do to it (perturbations, randomisation, latency, noise)."""
