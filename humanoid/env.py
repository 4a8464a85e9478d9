"""Gymnasium `Humanoid-v5` helpers: construction, observation layout and body poses.

Physics queries used by controllers live in `humanoid.physics`; this module only knows the
environment's shapes and names.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.envs import mujoco as mujoco_envs  # its assets folder holds Humanoid-v5's XML

ENV_ID = "Humanoid-v5"
EPISODE_STEPS = 1000
FRAME_SKIP = 5
"""MuJoCo steps per env step: Humanoid-v5's default `frame_skip`, which every controller's model of one step takes."""
# LeRobot stores fps as an int; the true rate is 1 / 0.015 s = 66.67 Hz. MCAP timestamps use the
# exact step duration (`step_duration_ns`), LeRobot timestamps are frame_index / LEROBOT_FPS.
LEROBOT_FPS = 67
ROBOT_TYPE = "mujoco_humanoid"


def make_env(max_episode_steps: int = EPISODE_STEPS, render_mode: str | None = None, **options: Any) -> gym.Env:
    """Humanoid-v5 with its default observation (348 floats) and a time limit of `max_episode_steps`.

    `options` go to the environment's constructor: rendering settings such as `default_camera_config`.
    """
    if max_episode_steps <= 0:
        raise ValueError(f"max_episode_steps must be positive, got {max_episode_steps}")
    return gym.make(ENV_ID, max_episode_steps=max_episode_steps, render_mode=render_mode, **options)


def humanoid_xml() -> Path:
    """Gymnasium's own MJCF of the Humanoid-v5 body."""
    return Path(mujoco_envs.__file__).parent / "assets" / "humanoid.xml"


def humanoid_model() -> mujoco.MjModel:
    """Load the model that gymnasium's Humanoid-v5 simulates, from gymnasium's own XML."""
    return mujoco.MjModel.from_xml_path(str(humanoid_xml()))


@functools.cache
def nominal_model() -> mujoco.MjModel:
    """Humanoid-v5's model, one instance per process, never changed, for whatever computes on the nominal body (the
    experts' designs, the tracking's targets, the observation's layout): `task.posture` caches its designs per
    model object, so each new expert, tracked episode or training environment reuses what an earlier one solved."""
    return humanoid_model()


def model_and_data(env: gym.Env) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The MuJoCo model and live data behind a (wrapped) Humanoid env."""
    base = env.unwrapped
    return base.model, base.data


def step_seconds(model: mujoco.MjModel) -> float:
    """Simulated seconds of one env step of `model`: `FRAME_SKIP` of its timesteps (0.015 s for Humanoid-v5)."""
    return FRAME_SKIP * model.opt.timestep


def step_duration_ns(env: gym.Env) -> int:
    """Simulated time of one env step (timestep x frame_skip) in integer nanoseconds."""
    return round(env.unwrapped.dt * 1e9)


def mjcf_path(env: gym.Env) -> Path:
    """The MJCF file the environment was built from."""
    return Path(env.unwrapped.fullpath)


def _names(model: mujoco.MjModel, kind: mujoco.mjtObj, count: int, start: int = 0) -> list[str]:
    return [mujoco.mj_id2name(model, kind, i) for i in range(start, count)]


def body_names(model: mujoco.MjModel) -> list[str]:
    """The moving bodies (world excluded), in MuJoCo's order: the 13 frames shown in Foxglove."""
    return _names(model, mujoco.mjtObj.mjOBJ_BODY, model.nbody, start=1)


def actuator_names(model: mujoco.MjModel) -> list[str]:
    """Actuator names, in action order."""
    return _names(model, mujoco.mjtObj.mjOBJ_ACTUATOR, model.nu)


QPOS_OBS = slice(0, 22)
"""Where qpos[2:] sits in the 348-dim observation (root x, y are excluded by default): the root's height and
orientation, then the joint angles; a recorded frame's observation too."""
QVEL_OBS = slice(22, 45)
"""Where qvel sits in the observation; the rest (cinert, cvel, qfrc_actuator, cfrc_ext) is simulator state no sensor
measures."""


def observation_names(model: mujoco.MjModel) -> list[str]:
    """One name per observation entry, following gymnasium's Humanoid-v5 `_get_obs` order."""
    joints = _names(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt, start=1)  # joint 0 is the free root
    bodies = body_names(model)
    qpos = ["root.z", "root.qw", "root.qx", "root.qy", "root.qz"] + [f"{j}.pos" for j in joints]
    qvel = ["root.vx", "root.vy", "root.vz", "root.wx", "root.wy", "root.wz"] + [f"{j}.vel" for j in joints]
    cinert = [f"{b}.cinert{i}" for b in bodies for i in range(10)]
    cvel = [f"{b}.cvel{i}" for b in bodies for i in range(6)]
    qfrc_actuator = [f"{j}.qfrc_actuator" for j in joints]
    cfrc_ext = [f"{b}.cfrc_ext{i}" for b in bodies for i in range(6)]
    return qpos + qvel + cinert + cvel + qfrc_actuator + cfrc_ext


def body_poses(data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """World positions (13, 3) and orientations (13, 4, MuJoCo's w-x-y-z) of the moving bodies."""
    return data.xpos[1:].copy(), data.xquat[1:].copy()
