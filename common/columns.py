"""Dataset keys, in one place (LeRobot's convention: dotted names, `next.*` for step outcomes).

The gymnasium observation (348 floats) is stored split in two so that LeRobot's own policies
(ACT, Diffusion) accept the dataset, which they refuse with `observation.state` alone:

- `observation.state`: what a real humanoid senses (48 named floats: joint encoders, the torso IMU's
  gyro and gravity direction, foot contact and the feet's force sensors; `humanoid.sensors`).
- `observation.environment_state`: the rest of the gymnasium observation, which only a simulator
  gives (root height, orientation and velocity, cinert, cvel, qfrc_actuator, cfrc_ext: 311).

Joined by their recorded names they are the gymnasium observation, bit for bit (both float64):
`humanoid.sensors.ObservationSplit.join`.
"""

from collections.abc import Mapping
from typing import TypeVar

T = TypeVar("T")

# LeRobot's own names (lerobot.utils.constants; a test checks they agree). Spelled out here because
# importing lerobot pulls in torch, which the recorder's simulation process does not need.
OBS_STATE = "observation.state"
OBS_IMAGES = "observation.images"  # a camera's frames are `observation.images.<camera>` (`image_key`)
OBS_ENV_STATE = "observation.environment_state"
ACTION = "action"
REWARD = "next.reward"
DONE = "next.done"
TRUNCATED = "next.truncated"

# The action the environment received: the label plus injected noise (DART), clipped to the bounds.
# Deliberately not prefixed `action.`: LeRobot treats every `action*` key as a training target.
EXECUTED_ACTION = "executed_action"
TERMINATED = "next.terminated"
TASK = "task"

# The operator's command in force at each step, one entry per command field (task.command_fields, which names
# them; all zeros for a controller nobody commands: standing is the zero command). An observation, so a policy can be
# conditioned on it (INPUTS=...+command, students.inputs).
OBS_COMMAND = "observation.command"
# Where the expert's setpoint is at each step on its way to the commanded posture (the same fields): the teacher's
# internal state, not an input a deployed policy gets. A controller without a setpoint of its own records the command.
SETPOINT = "setpoint"
# The push applied to the torso at each step (N, world frame; the keyboard's `p`; its `k` kick as the force that gives
# its impulse over its step): a perturbation, not a command (a
# deployed policy cannot know it), so neither `observation.*` nor `action*`, which LeRobot would read.
PUSH = "push"
PUSH_NAMES = ("push_x", "push_y")

# Columns of meta/episodes/*.parquet that this project adds beside LeRobot's own.
EPISODE_SEED = "seed"
EPISODE_CONTROLLER = "controller"
EPISODE_LABELLER = "labeller"
EPISODE_DAGGER_ROUND = "dagger_round"
EPISODE_NOISE_STD = "noise_std"
EPISODE_RETURN = "return"
EPISODE_TERMINATED = "terminated"
EPISODE_TRUNCATED = "truncated"
EPISODE_MCAP = "mcap_path"
# The observation the last action led to (o_T: a frame holds the observation before its action, so
# an episode of T frames stores o_0..o_T-1 there), split as the frames' features are. With them every
# transition (o_t, a_t, r_t, o_t+1) of the episode is in the dataset, the fallen state included.
EPISODE_FINAL_STATE = "final.observation.state"
EPISODE_FINAL_ENV_STATE = "final.observation.environment_state"

# Columns of meta/episodes/*.parquet holding the physical parameters drawn for the episode
# (`make record RANDOMIZE=... LATENCY=...`, humanoid.conditions): one column per drawn value, PREFIX + its
# name, e.g. `randomization.mass_scale` (13 floats, one per body, the world excluded, in model order),
# `randomization.friction_scale` (one float: every geom's sliding friction), `randomization.strength_scale`
# (17 floats, one per motor's gear, in actuator order), `randomization.latency_steps` (the action delay).
# Only datasets recorded with randomisation have them, and then every episode has the same ones. The MCAP
# metadata record holds them too, under the same keys, as JSON text.
RANDOMIZATION_PREFIX = "randomization."


def drawn_parameters(columns: Mapping[str, T]) -> dict[str, T]:
    """The drawn parameters among `columns` (an episode's row, or its MCAP metadata), by name, in their order:
    the `RANDOMIZATION_PREFIX` columns with the prefix removed, e.g. {"friction_scale": 1.2}."""
    return {
        name.removeprefix(RANDOMIZATION_PREFIX): value
        for name, value in columns.items()
        if name.startswith(RANDOMIZATION_PREFIX)
    }


def image_key(camera: str) -> str:
    """The dataset key of `camera`'s frames (`humanoid.cameras`), a video feature."""
    return f"{OBS_IMAGES}.{camera}"
