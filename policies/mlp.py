"""The behaviour-cloning policy: an MLP from the observation to an action inside the motor range.

Everything the policy needs at run time is in its state_dict: the input normalisation (mean and
floored std of the training inputs) and the action bounds are buffers, so a checkpoint is the
weights file plus the `MLPSpec` that sizes the layers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

# Floor on the input standard deviations, in the observation's own units (rad, m/s, N, kg m^2...).
# The gymnasium observation has exactly constant entries (body masses in cinert; contact forces
# of bodies that never touch anything), which need some floor. Beyond that, the floor decides how
# much the policy may amplify inputs that barely vary in the demonstrations (waist inertia terms
# with std 3e-5 in clean data): flooring them at 0.1 rather than 1e-6 gave a lower validation loss
# on every training seed and higher returns under pushes (measured: docs/decisions/input-floor.md). Joint
# angles and velocities, the signals that matter for balance, keep a scale of order one.
STD_FLOOR = 0.1

ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "elu": nn.ELU}
"""ELU, what `make train-bc` writes (`bc.train.ACTIVATION`), and ReLU, what checkpoints before 2026-11-26 hold."""


@dataclass(frozen=True)
class MLPSpec:
    """What sizes an `MLPPolicy` (stored in the checkpoint's config.json; the weights hold the rest)."""

    input_keys: tuple[str, ...]
    """Dataset columns the input is built from (`students.inputs.InputSet.columns` of `inputs`)."""
    input_dim: int
    action_dim: int
    hidden: tuple[int, ...] = (256, 256)
    activation: str = "relu"
    """Hidden units (ACTIVATIONS). `make train-bc` writes ELU networks (`bc.train.ACTIVATION` says why); this
    default stays the ReLU that spec had before, so a spec built without the field means what it meant."""
    inputs: str = "full"
    """What the policy reads: the name of an input set (`students.inputs.INPUT_SETS`: docs/concepts/inputs.md).
    Checkpoints written before this field read "full"."""
    inputs_version: int = 1
    """Which computation of that set it was trained on (`students.inputs.InputSet.version`). Checkpoints written
    before this field read 1."""

    def __post_init__(self) -> None:
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation {self.activation!r} (known: {', '.join(ACTIVATIONS)})")
        if not self.hidden or min(self.hidden) <= 0:
            raise ValueError(f"hidden sizes must be positive, got {self.hidden}")

    @classmethod
    def from_dict(cls, values: dict) -> MLPSpec:
        """Inverse of `dataclasses.asdict` after a JSON round trip (lists back to tuples)."""
        return cls(**{**values, "input_keys": tuple(values["input_keys"]), "hidden": tuple(values["hidden"])})


def normalisation(inputs: torch.Tensor, std_floor: float = STD_FLOOR) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and std (floored at `std_floor`) of inputs (N, dim), in float64."""
    # float64: a float32 variance of 50 k rows loses the small spreads the floor must tell apart.
    data = inputs.to(torch.float64)
    return data.mean(dim=0), data.std(dim=0, correction=0).clamp_min(std_floor)


class MLPPolicy(nn.Module):
    """(x - mean) / std -> hidden layers -> tanh, scaled to [action_low, action_high]."""

    def __init__(
        self, spec: MLPSpec, action_low: np.ndarray | None = None, action_high: np.ndarray | None = None
    ) -> None:
        """A fresh policy; bounds default to +-1 (a checkpoint's state_dict restores the real ones)."""
        super().__init__()
        self.spec = spec
        layers: list[nn.Module] = []
        width = spec.input_dim
        for size in spec.hidden:
            layers += [nn.Linear(width, size), ACTIVATIONS[spec.activation]()]
            width = size
        layers.append(nn.Linear(width, spec.action_dim))
        self.net = nn.Sequential(*layers)
        low = torch.as_tensor(-np.ones(spec.action_dim) if action_low is None else action_low, dtype=torch.float32)
        high = torch.as_tensor(np.ones(spec.action_dim) if action_high is None else action_high, dtype=torch.float32)
        if low.shape != (spec.action_dim,) or high.shape != (spec.action_dim,) or not bool((low < high).all()):
            raise ValueError(f"action bounds must be ({spec.action_dim},) arrays with low < high")
        # Until `fit_normalisation` runs, inputs pass through unchanged.
        self.register_buffer("input_mean", torch.zeros(spec.input_dim))
        self.register_buffer("input_std", torch.ones(spec.input_dim))
        self.register_buffer("action_mid", (high + low) / 2)
        self.register_buffer("action_half_range", (high - low) / 2)

    def fit_normalisation(self, inputs: torch.Tensor, std_floor: float = STD_FLOOR) -> None:
        """Set the input mean and std from training inputs (N, input_dim), the std floored at `std_floor`."""
        mean, std = normalisation(inputs, std_floor)
        self.input_mean.copy_(mean)
        self.input_std.copy_(std)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        """Actions (..., action_dim) for raw, unnormalised inputs (..., input_dim)."""
        z = (inputs - self.input_mean) / self.input_std
        return self.action_mid + self.action_half_range * torch.tanh(self.net(z))
