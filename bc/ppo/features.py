"""The sensed features (`humanoid.sensors.Proprioception`) computed in torch, inside PPO's policy.

    gymnasium observation (348) ──SensedFeatures──> the 48 sensed features            (INPUTS=proprio)
    observation + estimate (348 + 134, humanoid.estimator.OdometryObservation)
                                ──EstimatedFeatures──> the 48 but the forces, then the estimate (INPUTS=odometry)

PPO's environments give the gymnasium observation, which the critic reads whole (privileged); an actor
cloned on what a robot senses reads these features of it instead: an asymmetric actor-critic
(docs/concepts/inputs.md). The same indices and formulas as `Proprioception`, in
float32: the actions differ from `humanoid.learned.PolicyController`'s (float64 features) by float
rounding only (a test).
"""

from __future__ import annotations

import torch
from torch import nn

from humanoid.estimator import read_sensed
from humanoid.sensors import FORCE_PART, Proprioception


class SensedFeatures(nn.Module):
    """(..., 348) gymnasium observations -> (..., 48) sensed features, as `Proprioception` computes them."""

    def __init__(self, proprioception: Proprioception) -> None:
        super().__init__()
        self.register_buffer("copied", torch.as_tensor(proprioception.copied, dtype=torch.long))
        self.register_buffer("quaternion", torch.as_tensor(proprioception.quaternion, dtype=torch.long))
        self.register_buffer("feet", torch.as_tensor(proprioception.feet, dtype=torch.long))
        self.register_buffer("forces", torch.as_tensor(proprioception.feet[:, FORCE_PART], dtype=torch.long))
        self.size = proprioception.size

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        q = obs[..., self.quaternion]
        w, x, y, z = (q / q.norm(dim=-1, keepdim=True)).unbind(-1)
        # R^T, row i the torso's i-th axis in the world (`humanoid.sensors.body_axes`).
        axes = torch.stack(
            [
                torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], dim=-1),
                torch.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], dim=-1),
                torch.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], dim=-1),
            ],
            dim=-2,
        )
        gravity = -axes[..., 2]  # the world's down direction in the torso frame
        contacts = (obs[..., self.feet] != 0).any(dim=-1).to(obs.dtype)  # (..., 2): a foot's wrench is not zero
        forces = torch.einsum("...ij,...fj->...fi", axes, obs[..., self.forces]).flatten(-2)  # R^T f per foot: (..., 6)
        return torch.cat([obs[..., self.copied], gravity, contacts, forces], dim=-1)


class EstimatedFeatures(nn.Module):
    """(..., 348 + k) observations with `OdometryObservation`'s estimate appended -> (..., 42 + k): the sensed
    features an odometry policy reads (`read_sensed`: not the forces) computed here, then the estimate as the
    env's estimator computed it (`OdometryFeatures`' layout)."""

    def __init__(self, proprioception: Proprioception, observation_size: int) -> None:
        super().__init__()
        self.sensed = SensedFeatures(proprioception)
        self.register_buffer("read", torch.as_tensor(read_sensed(proprioception.names), dtype=torch.long))
        self.observation_size = observation_size

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.sensed(obs)[..., self.read], obs[..., self.observation_size :]], dim=-1)
