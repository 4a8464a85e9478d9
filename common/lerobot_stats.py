"""The statistics LeRobot keeps of a feature: their names, and those of a camera's frames.

Here, below the cameras that compute them while recording (`humanoid.cameras`) and the dataset writer that stores
them (`teleop.lerobot_io.format`); the tests hold both to LeRobot's own (`tests/teleop/test_lerobot_format.py`,
`tests/teleop/test_cameras.py`).
"""

from __future__ import annotations

import numpy as np

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)


def quantile_key(q: float) -> str:
    return f"q{round(q * 100):02d}"


def image_stats(samples: np.ndarray) -> dict[str, np.ndarray]:
    """Per-channel statistics of a camera's frames in an episode, from `samples` (N, 3, h, w) uint8 (the frames
    LeRobot samples: `humanoid.cameras.stats_indices`, `stats_view`), in [0, 1] and of shape (3, 1, 1) as LeRobot keeps
    them; the count is the frames read. Quantiles exact (`teleop.lerobot_io.format.episode_stats` says why)."""
    pixels = samples.transpose(1, 0, 2, 3).reshape(samples.shape[1], -1).T.astype(np.float64) / 255.0
    quantiles = np.quantile(pixels, QUANTILES, axis=0, method="inverted_cdf")
    channels = (len(pixels[0]), 1, 1)
    return {  # in the order of `teleop.lerobot_io.format.episode_stats`: the episode rows' columns are the same
        "min": pixels.min(axis=0).reshape(channels),
        "max": pixels.max(axis=0).reshape(channels),
        "mean": pixels.mean(axis=0).reshape(channels),
        "std": pixels.std(axis=0).reshape(channels),
        "count": np.array([len(samples)]),
        **{quantile_key(q): quantiles[i].reshape(channels) for i, q in enumerate(QUANTILES)},
    }
