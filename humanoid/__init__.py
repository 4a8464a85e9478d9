"""The simulated humanoid: environment, physics queries, perturbations, video, controllers and the rollout."""
