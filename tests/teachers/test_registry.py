"""One teacher registry: a teacher declares what it can do, and every stage's choices derive from it.

A toy teacher (`support.StandingWalker`: the LQR expert declared to walk) is registered in one place, and the recorder
(in worker processes too), DAgger and the evaluation accept it; a name not registered is refused in one line listing
the registered ones; the walking students' hand-over flag is the rule every teacher that hands over runs.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bc import dagger
from common import columns
from common.cli import UserError
from evaluation import evaluate
from students.inputs import HANDOVER, INPUT_SETS
from support import StandingWalker, record_short, registered
from teachers.registry import TEACHERS, able, teacher_named
from teleop.dataset_reader import read_episodes, read_frames

STEPS = 30


def test_every_registered_teacher_declares_its_capabilities_on_its_class() -> None:
    for name, teacher in TEACHERS.items():
        assert teacher.name == name
        assert {type(getattr(teacher, what)) for what in ("takes_command", "walks")} == {bool}
    assert able("walks") == ("expert-stepping", "expert-sensed-stepping", "walker", "walker-sensed")


def test_a_walking_students_hand_over_flag_is_the_rule_of_every_teacher_that_hands_over() -> None:
    """The walking input sets compute `HANDOVER` (`pending+walk`'s flag; `pending+gait`'s gait clock starts on it); a
    teacher that hands over runs that very rule, so a student of it reads the step its teacher switches laws on
    (tests/students/test_inputs.py, tests/teachers/test_walker.py: step for step)."""
    handing_over = [teacher for teacher in TEACHERS.values() if teacher.handover is not None]
    assert handing_over and all(teacher.handover is HANDOVER for teacher in handing_over)
    assert all(teacher.walks for teacher in handing_over)  # what a walking set learns from
    assert [name for name, inputs in INPUT_SETS.items() if inputs.walks] == ["pending+walk", "pending+gait"]


def test_a_name_that_is_not_registered_is_refused_listing_the_registered_ones() -> None:
    with pytest.raises(UserError, match=r"^unknown --expert 'toy-walker'; registered teachers: expert, expert-sensed"):
        teacher_named("toy-walker", "--expert")


@pytest.mark.slow  # a recording, a BC training and an evaluation
def test_a_toy_teacher_registered_in_one_place_records_labels_and_is_evaluated(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """One registry line (`support.registered`) and the recorder records it on a walking task (two worker processes,
    which get the class), DAgger labels with it, and `make eval` runs it."""
    with registered(StandingWalker):
        dataset = tmp_path / "toy"
        record_short(dataset, controller="toy-walker", task="walk", episodes=3, max_steps=STEPS, workers=2)
        episodes = read_episodes(dataset, [columns.EPISODE_LABELLER]).to_pydict()
        assert episodes[columns.EPISODE_LABELLER] == ["toy-walker"] * 3
        assert read_frames(dataset, [columns.OBS_COMMAND])[columns.OBS_COMMAND].shape[0] == 3 * STEPS

        config = dagger.DaggerConfig(
            dataset=dataset,
            output=tmp_path / "toy_dagger",
            policy=tmp_path / "policy",
            inputs="full",
            expert="toy-walker",
            rounds=1,
            episodes=1,
            epochs=1,
            min_updates=0,
            eval_episodes=0,
            workers=1,
            progress=False,
        )
        dagger.main(config)
        labelled = read_episodes(config.output, [columns.EPISODE_LABELLER, columns.EPISODE_DAGGER_ROUND]).to_pydict()
        assert labelled[columns.EPISODE_DAGGER_ROUND] == [0, 0, 0, 1]
        assert set(labelled[columns.EPISODE_LABELLER]) == {"toy-walker"}

        code = evaluate.cli(["--policy", "toy-walker", "--episodes", "1", "--task", "walk", "--progress", "false"])
        result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        assert code == 0 and result["policy"] == "toy-walker" and result["walks"] is True
    with pytest.raises(UserError, match="unknown --expert 'toy-walker'"):
        dagger.check_settings(config)
