"""MCAP episodes: values equal to the LeRobot frames, 3D content for Foxglove, integer sim time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from common import columns
from humanoid.env import body_names, body_poses, make_env, mjcf_path, model_and_data
from support import McapEpisode, join_observation, read_mcap_episode
from task.command_fields import COMMAND_FIELDS, COMMAND_NAMES
from teleop.dataset_reader import read_episodes, read_frames
from teleop.mcap_io.schema import Command
from teleop.mcap_io.writer import COMMAND_TOPIC, FINAL_TOPIC, SCENE_TOPIC, STEP_TOPIC, TF_TOPIC
from teleop.store import STATE_NAMES_METADATA

STEP_NS = 15_000_000  # Humanoid-v5: timestep 0.003 s x frame_skip 5


@pytest.fixture(scope="module")
def episodes(recorded: Path) -> list[McapEpisode]:
    """Every MCAP file of the recorded dataset, decoded, in episode order."""
    return [read_mcap_episode(recorded / row[columns.EPISODE_MCAP]) for row in read_episodes(recorded).to_pylist()]


def test_every_step_value_equals_the_lerobot_frame(recorded: Path, episodes: list[McapEpisode]) -> None:
    """Observation, sensed state, actions, reward and end flags in /step equal the parquet frames exactly."""
    frames = read_frames(recorded)
    for index, episode in enumerate(episodes):
        rows = frames["episode_index"] == index
        np.testing.assert_array_equal(episode.steps["frame_index"], frames["frame_index"][rows])
        np.testing.assert_array_equal(
            episode.steps["observation"],
            join_observation(frames[columns.OBS_STATE][rows], frames[columns.OBS_ENV_STATE][rows]),
        )
        for step_field, key in [
            ("state", columns.OBS_STATE),
            ("action", columns.ACTION),
            ("executed_action", columns.EXECUTED_ACTION),
            ("reward", columns.REWARD),
            ("terminated", columns.TERMINATED),
            ("truncated", columns.TRUNCATED),
        ]:
            np.testing.assert_array_equal(episode.steps[step_field], frames[key][rows], err_msg=step_field)


def test_metadata_names_the_state_as_the_dataset_does(recorded: Path, episodes: list[McapEpisode]) -> None:
    """The `state_names` metadata entry is observation.state's `names` in meta/info.json: Foxglove plots by index."""
    names = json.loads((recorded / "meta/info.json").read_text())["features"][columns.OBS_STATE]["names"]
    assert all(json.loads(episode.metadata[STATE_NAMES_METADATA]) == names for episode in episodes)
    assert len(names) == episodes[0].steps["state"].shape[1] == 48


def test_command_channel_equals_the_command_feature_and_tasks(recorded: Path, episodes: list[McapEpisode]) -> None:
    """/command holds observation.command and the task of every step, at the /step times."""
    frames = read_frames(recorded, [columns.OBS_COMMAND, "episode_index"])
    for index, episode in enumerate(episodes):
        np.testing.assert_array_equal(episode.command, frames[columns.OBS_COMMAND][frames["episode_index"] == index])
        np.testing.assert_array_equal(episode.command_times_ns, episode.step_times_ns)
        assert episode.command_tasks == episode.tasks == ["Stand still on both feet."] * len(episode.tasks)


def test_timestamps_are_integer_nanoseconds_of_simulated_time(episodes: list[McapEpisode]) -> None:
    """Message t is logged at t x 15 ms of simulated time, on /step and /tf alike."""
    for episode in episodes:
        expected = np.arange(len(episode.step_times_ns), dtype=np.int64) * STEP_NS
        np.testing.assert_array_equal(episode.step_times_ns, expected)
        np.testing.assert_array_equal(episode.tf_times_ns, expected)


def test_transforms_are_the_13_body_poses(episodes: list[McapEpisode]) -> None:
    """/tf carries every body's world pose; the first equals MuJoCo's after the same reset."""
    env = make_env()
    model, data = model_and_data(env)
    env.reset(seed=0)
    position, orientation = body_poses(data)
    first = episodes[0]
    assert first.body_frames == body_names(model) and len(first.body_frames) == 13
    np.testing.assert_array_equal(first.body_position[0], position)
    np.testing.assert_array_equal(first.body_orientation[0], orientation)
    assert first.body_position.shape == (len(first.step_times_ns), 13, 3)


def test_scene_draws_every_geom_attached_to_its_body(episodes: list[McapEpisode], recorded: Path) -> None:
    """The /scene update has an entity per body frame (and the world's floor), capsules as 3 primitives."""
    model, _ = model_and_data(make_env())
    assert episodes[0].scene_entities == ["world", *body_names(model)]
    with (recorded / "mcap/episode_000000.mcap").open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        ((_, _, _, scene),) = reader.iter_decoded_messages(topics=[SCENE_TOPIC])
    assert scene.DESCRIPTOR.full_name == "foxglove.SceneUpdate"
    primitives = sum(len(e.cylinders) + len(e.spheres) + len(e.cubes) for e in scene.entities)
    capsules, spheres, planes = (int(np.sum(model.geom_type == t)) for t in (3, 2, 0))
    assert primitives == 3 * capsules + spheres + planes
    assert all(entity.frame_locked for entity in scene.entities)
    body_color = scene.entities[1].cylinders[0].color
    assert (body_color.r, body_color.g, body_color.b) == pytest.approx((0.8, 0.6, 0.4))  # the MJCF's geom rgba


def test_file_has_metadata_model_and_zstd_protobuf_channels(recorded: Path, episodes: list[McapEpisode]) -> None:
    """Each file holds the episode metadata, the MJCF model, and protobuf channels in zstd chunks."""
    metadata = episodes[1].metadata
    assert metadata["episode_index"] == "1" and metadata["seed"] == "1"
    assert metadata["controller"] == "expert" and metadata["env_id"] == "Humanoid-v5"
    assert metadata["step_duration_ns"] == str(STEP_NS)
    assert episodes[1].attachments["model.xml"] == mjcf_path(make_env()).read_bytes()
    with (recorded / "mcap/episode_000001.mcap").open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert {c.topic: c.message_encoding for c in summary.channels.values()} == {
        SCENE_TOPIC: "protobuf",
        STEP_TOPIC: "protobuf",
        TF_TOPIC: "protobuf",
        COMMAND_TOPIC: "protobuf",
        FINAL_TOPIC: "protobuf",
    }
    assert {s.name for s in summary.schemas.values()} == {
        "foxglove.SceneUpdate",
        "humanoid_bc.Step",
        "foxglove.FrameTransforms",
        "humanoid_bc.Command",
    }
    assert summary.chunk_indexes and all(chunk.compression == "zstd" for chunk in summary.chunk_indexes)


COMMAND_V1 = Path(__file__).parents[1] / "data" / "command_v1.mcap"
"""Three `/command` messages of an operator episode (seed 29: crouch, twist right, arms forward) written at 3b956ff,
before the command's fields became a table: the file embeds that version's schema."""


def test_a_command_file_written_before_the_table_decodes_the_same_with_todays_message() -> None:
    """Each old message's bytes parsed with today's `Command` give, field by field, what the file's own schema gives:
    the field numbers are the rows' (`CommandField.mcap`), not an order that a new field could shift."""
    with COMMAND_V1.open("rb") as stream:
        decoded = list(make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    assert len(decoded) == 3
    for _, _, message, old in decoded:
        today = Command.FromString(message.data)
        for descriptor, value in old.ListFields():
            if descriptor.message_type is not None:  # the timestamp: a message of another descriptor pool
                assert getattr(today, descriptor.name).SerializeToString() == value.SerializeToString()
            else:
                assert getattr(today, descriptor.name) == value, descriptor.name
        assert {name for name in COMMAND_NAMES if getattr(today, name)} == {"height", "twist", "arms"}
        assert today.task == "Crouch, twist right, arms forward while standing."


def test_the_command_message_numbers_are_the_rows_and_unique() -> None:
    numbers = [field.number for field in Command.DESCRIPTOR.fields]
    assert len(set(numbers)) == len(numbers)
    for row in COMMAND_FIELDS:
        assert Command.DESCRIPTOR.fields_by_name[row.name].number == row.mcap[0]
        assert Command.DESCRIPTOR.fields_by_name[f"setpoint_{row.name}"].number == row.mcap[1]
        if row.mcap[2] is not None:
            assert Command.DESCRIPTOR.fields_by_name[f"achieved_{row.name}"].number == row.mcap[2]
