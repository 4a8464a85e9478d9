"""Finished episodes waiting for their turn to be committed: `DATASET/.spool/`.

Parallel recording (`teleop.parallel`) finishes episodes out of seed order, but commits them in
seed order. A worker therefore writes each finished episode here first (one `.npz` per seed,
written then renamed), and the store commits it when its turn comes. A kill -9 at any moment
leaves every finished episode either committed or in the spool; the next `EpisodeStore` to open
the dataset commits what the spool holds (`EpisodeStore.commit_spool`).

Committing an episode from the spool is exactly-once: before info.json counts it, its file is
renamed to `<seed>.index-<episode index>.committing`; after, it is deleted. On recovery a
`.committing` file whose index info.json already counts is a leftover, any other goes back to
the spool. (The folder name starts with a dot: LeRobot and the recorder's emptiness check skip it.)
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from common.files import PARTIAL_SUFFIX, write_atomically
from humanoid.cameras import CameraTrack
from rollout.episode import ARRAY_FIELDS, FINAL_FIELDS, Episode

SPOOL_DIR = ".spool"
DAGGER_SPOOL = ".dagger-spool"
"""A DAgger aggregate's (`bc.dagger`): a round's finished episodes wait there for their turn, and only DAgger commits
them, in seed order. The recorder's SPOOL_DIR is committed whenever the dataset is opened, past a gap in the seeds
too, which would break a resumed round's order."""
SPOOLS = {
    SPOOL_DIR: "the next `make record` commits the finished ones and removes the rest",
    DAGGER_SPOOL: "the next `make dagger` on this aggregate commits the finished ones and removes the rest",
}
"""Each spool folder a dataset may hold, and what becomes of what waits there (`make inspect` says)."""
_READY = ".npz"
_COMMITTING = ".committing"
_FACTS = "_facts"
_CAMERA = "camera.{name}.{part}"


class Spool:
    """The spool folder of one dataset: `name`, SPOOL_DIR for the recorder's (which `teleop.store` commits on open)."""

    def __init__(self, dataset: Path, name: str = SPOOL_DIR) -> None:
        self.folder = dataset / name

    def put(self, episode: Episode) -> Path:
        """Write `episode` under its seed, atomically: a reader sees the whole file or none."""
        self.folder.mkdir(exist_ok=True)
        path = self.folder / f"{episode.seed:012d}{_READY}"
        # Object arrays (the task strings) would need pickle: stored as fixed-width strings instead.
        arrays = {name: np.asarray(getattr(episode, name)) for name in (*ARRAY_FIELDS, *FINAL_FIELDS)}
        arrays = {name: values.astype(str) if values.dtype == object else values for name, values in arrays.items()}
        skipped = {*arrays, "cameras"}
        facts = {f.name: getattr(episode, f.name) for f in dataclasses.fields(Episode) if f.name not in skipped}
        facts["cameras"] = list(episode.cameras)
        for name, track in episode.cameras.items():
            arrays.update(_camera_arrays(name, track))
        arrays[_FACTS] = np.array(json.dumps(facts))

        def save(partial: Path) -> None:
            with partial.open("wb") as stream:  # a stream: given a path, np.savez would add ".npz" to it
                np.savez(stream, **arrays)

        write_atomically(path, save)
        return path

    def ready(self) -> list[Path]:
        """The spooled episodes, in seed order."""
        return sorted(self.folder.glob(f"*{_READY}")) if self.folder.is_dir() else []

    def contents(self, committed_episodes: int) -> tuple[int, int]:
        """(finished episodes, partial files) in the folder, with the dataset's info.json counting
        `committed_episodes`: those waiting or taken out for a commit info.json does not count yet (what `recover`
        returns to the spool), and those a kill cut short (what it drops). A commit a kill stopped after info.json
        leaves its `.committing` file, a leftover: not counted."""
        if not self.folder.is_dir():
            return 0, 0
        taken = [self._committing_index(path) for path in self.folder.glob(f"*{_COMMITTING}")]
        finished = len(self.ready()) + sum(index >= committed_episodes for index in taken)
        return finished, len(list(self.folder.glob(f"*{PARTIAL_SUFFIX}")))

    @staticmethod
    def _committing_index(path: Path) -> int:
        """The episode index a `.committing` file was being committed as (`begin_commit`)."""
        return int(path.name.removesuffix(_COMMITTING).split(".index-")[1])

    def path_of(self, seed: int) -> Path:
        return self.folder / f"{seed:012d}{_READY}"

    @staticmethod
    def load(path: Path) -> Episode:
        with np.load(path, allow_pickle=False) as stored:
            facts = json.loads(str(stored[_FACTS]))
            cameras = {name: _camera_track(stored, name) for name in facts.pop("cameras", [])}
            arrays = {name: stored[name] for name in (*ARRAY_FIELDS, *FINAL_FIELDS)}
            return Episode(**facts, **arrays, cameras=cameras)

    def begin_commit(self, path: Path, episode_index: int) -> Path:
        """Mark `path` as being committed as episode `episode_index` (call before info.json counts it)."""
        committing = path.with_name(f"{path.name.removesuffix(_READY)}.index-{episode_index}{_COMMITTING}")
        os.replace(path, committing)
        return committing

    def recover(self, committed_episodes: int) -> None:
        """Settle what a kill left: drop partial files and committed leftovers, return the rest to the spool."""
        if not self.folder.is_dir():
            return
        for partial in self.folder.glob(f"*{PARTIAL_SUFFIX}"):
            partial.unlink()
        for committing in self.folder.glob(f"*{_COMMITTING}"):
            if self._committing_index(committing) < committed_episodes:
                committing.unlink()
            else:
                seed = committing.name.split(".index-")[0]
                os.replace(committing, self.folder / f"{seed}{_READY}")

    def remove_if_empty(self) -> None:
        if self.folder.is_dir() and not any(self.folder.iterdir()):
            self.folder.rmdir()


def _camera_arrays(name: str, track: CameraTrack) -> dict[str, np.ndarray]:
    """`track` as arrays (its bytes as uint8, its JPEGs end to end with their ends)."""
    parts = {
        "video": np.frombuffer(track.video, np.uint8),
        "images": np.frombuffer(b"".join(track.images), np.uint8),
        "image_ends": np.cumsum([len(image) for image in track.images], dtype=np.int64),
        "position": track.position,
        "orientation": track.orientation,
        **{f"stats.{stat}": value for stat, value in track.stats.items()},
    }
    return {_CAMERA.format(name=name, part=part): values for part, values in parts.items()}


def _camera_track(stored: np.lib.npyio.NpzFile, name: str) -> CameraTrack:
    """The inverse of `_camera_arrays`."""

    def part(key: str) -> np.ndarray:
        return stored[_CAMERA.format(name=name, part=key)]

    images, ends = part("images").tobytes(), part("image_ends").tolist()
    prefix = _CAMERA.format(name=name, part="stats.")
    return CameraTrack(
        video=part("video").tobytes(),
        images=[images[start:end] for start, end in zip([0, *ends[:-1]], ends, strict=True)],
        position=part("position"),
        orientation=part("orientation"),
        stats={key.removeprefix(prefix): stored[key] for key in stored.files if key.startswith(prefix)},
    )
