"""recipes/evaluate.py: a saved agent evaluated in a custom target, with a video; bad
values fail before any work."""

import importlib
import importlib.util
import json
import sys
from pathlib import Path

import imageio_ffmpeg
import pytest

from simdist.agents import DreamerAgent, DreamerConfig, SimDistAgent, TwistStudent
from simdist.modules import DreamerWorldModel, PlannerConfig, SimDistWorldModel
from tests.in_process import run_script

ROOT = Path(__file__).resolve().parents[2]
SPEC = importlib.util.spec_from_file_location("evaluate_recipe", ROOT / "recipes" / "evaluate.py")
recipe = importlib.util.module_from_spec(SPEC)
sys.modules[SPEC.name] = recipe  # dataclasses resolve annotations through it
SPEC.loader.exec_module(recipe)


def unboxed(text: str) -> str:
    """tyro's error box (wrapped to the terminal width) as one line of words."""
    return " ".join(text.replace("\u2502", " ").split())


@pytest.fixture(scope="module")
def student_file(tmp_path_factory):
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    twist = TwistStudent(teacher, DreamerWorldModel.student(1, size="tiny"))
    return twist.save(tmp_path_factory.mktemp("run") / "student.pt",
                      meta={"task": "cartpole-balance"})


def test_cli_evaluates_a_student_in_a_custom_target_with_a_video(student_file, tmp_path, capsys):
    target = tmp_path / "gusty.json"
    target.write_text(json.dumps({"name": "gusty", "motor_strength": 0.6,
                                  "visual": None}))
    out = recipe.main(["--preset", "tiny", "--checkpoint", str(student_file), "--target",
                       str(target), "--episodes", "3", "--steps", "4", "--video",
                       str(tmp_path / "ep.mp4"), "--output", str(tmp_path / "r.json")])
    printed = capsys.readouterr().out
    assert "TwistStudent" in printed and "target gusty" in printed
    assert "IQM" in printed and "95% CI" in printed
    saved = json.loads((tmp_path / "r.json").read_text())
    assert saved["task"] == "cartpole-balance"  # from the checkpoint's meta
    assert len(saved["returns"]) == 3 and saved["return"]["n"] == 3
    assert saved["returns"] == out["returns"]
    assert imageio_ffmpeg.count_frames_and_secs(saved["video"])[0] == 5  # reset + 4 steps


def test_cli_reports_forward_progress_for_a_simdist_agent(tmp_path, capsys):
    agent = SimDistAgent(SimDistWorldModel.build(89, 12, size="tiny"),
                         planner_config=PlannerConfig(horizon=2, num_samples=8, num_elites=2,
                                                      iterations=1))
    path = agent.save(tmp_path / "simdist.pt", optimisers=False)
    out = recipe.main(["--checkpoint", str(path), "--task", "quadruped-flat", "--target",
                       '{"name": "icy", "friction": 0.4}', "--episodes", "2", "--steps", "3"])
    assert out["target"] == "icy" and len(out["progress"]["fraction"]) == 2
    assert "forward progress" in capsys.readouterr().out


@pytest.mark.parametrize("args, message", [
    (["--episodes", "0"], "episodes: must be > 0"),
    (["--target", "atlantis"], "target: unknown target domain 'atlantis'"),
    (["--task", "swim"], "task: "),
    (["--video", "ep.gif"], "video: must end in .mp4"),
    (["--video-size", "63"], "video_size: must be even"),
    (["--camera-id", "-1"], "camera_id: must be >= 0"),
    (["--output", "."], "output: must be a .json file path, got '.'"),  # a folder: refused now
])
def test_bad_values_fail_before_any_work(student_file, tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exit_:
        recipe.main(["--checkpoint", str(student_file), "--output",
                     str(tmp_path / "r.json"), *args])
    assert exit_.value.code == 2
    assert message in unboxed(capsys.readouterr().err)
    assert not (tmp_path / "r.json").exists()


def test_missing_corrupt_or_taskless_checkpoints_are_named(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny")).save(tmp_path / "t.pt")
    for path, message in ((tmp_path / "none.pt", "none.pt' does not exist"),
                          (bad, "bad.pt' is corrupt"), (teacher, "records no task")):
        with pytest.raises(SystemExit):
            recipe.main(["--checkpoint", str(path)])
        err = unboxed(capsys.readouterr().err)
        assert "checkpoint: " in err and message in err, err
    with pytest.raises(SystemExit) as exit_:
        recipe.main([])
    assert exit_.value.code == 2  # the user's input, as for any bad flag
    assert "evaluate.py: error: checkpoint: required" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        recipe.main(["--checkpoint", "simdist/humanoid"])  # not a file, not a shipped name
    assert "simdist/humanoid' does not exist" in unboxed(capsys.readouterr().err)


def test_shipped_agents_are_listed_and_evaluated_by_name(tmp_path, capsys):
    """``--list`` names every shipped agent; a name stands for its file everywhere."""
    from simdist.agents import load_agent
    from simdist.experts import Expert
    from simdist.pretrained import PRETRAINED, pretrained_path
    assert recipe.main(["--list"]) is None
    listed = capsys.readouterr().out
    for name, entry in PRETRAINED.items():
        assert name in listed and entry.kind in listed
    expert = load_agent("expert/quadruped")
    assert isinstance(expert, Expert) and expert.checkpoint_meta["task"] == "quadruped-terrain"
    out = recipe.main(["--checkpoint", "expert/quadruped", "--task", "quadruped-flat",
                       "--target", "foam", "--episodes", "2", "--steps", "5",
                       "--output", str(tmp_path / "r.json")])
    assert out["agent"] == "Expert" and out["target"] == "foam"
    assert json.loads((tmp_path / "r.json").read_text())["returns"] == out["returns"]
    # the shipped world model plans by name, from its own file's planner settings
    planned = recipe.main(["--checkpoint", "simdist/quadruped", "--target", "foam",
                           "--episodes", "1", "--steps", "2"])
    assert planned["agent"] == "SimDistAgent" and planned["task"] == "quadruped-flat"
    for name, entry in PRETRAINED.items():  # every shipped file is in the package
        assert pretrained_path(name).is_file(), name
        assert (pretrained_path(name).parents[1] / entry.record).is_file(), name


def test_help_lists_every_field_with_its_default(capsys):
    proc = run_script(ROOT / "recipes" / "evaluate.py", "--help", capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    for flag in ("--checkpoint", "--task", "--target", "--episodes", "--steps", "--seed",
                 "--video", "--video-size", "--output", "--device", "--preset",
                 "--camera-id"):
        assert flag in proc.stdout, flag
    assert "(default: sim)" in proc.stdout and "(default: 10)" in proc.stdout


def test_a_pixel_agent_is_evaluated_from_the_camera_its_file_records(student_file, tmp_path,
                                                                      monkeypatch):
    # the module, not the function of the same name that simdist.pipelines exports
    evaluate_agent = importlib.import_module("simdist.pipelines.evaluate_agent")
    seen = []
    original = evaluate_agent.make_env

    def spy(*args, **kwargs):
        seen.append(kwargs.get("camera_id"))
        return original(*args, **kwargs)
    monkeypatch.setattr(evaluate_agent, "make_env", spy)
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    twist = TwistStudent(teacher, DreamerWorldModel.student(1, size="tiny"))
    path = twist.save(tmp_path / "cam1.pt", meta={"task": "cartpole-balance", "camera_id": 1})
    args = ["--preset", "tiny", "--episodes", "1", "--steps", "2"]
    assert recipe.main([*args, "--checkpoint", str(path), "--video",
                        str(tmp_path / "cam1.mp4")])["camera_id"] == 1
    assert recipe.main([*args, "--checkpoint", str(path), "--camera-id", "0"])["camera_id"] == 0
    assert recipe.main([*args, "--checkpoint", str(student_file)])["camera_id"] is None
    # what the envs rendered from (the evaluation, then the video's), not only the report
    assert seen == [1, 1, 0, None]
    # the Python API reads the file's camera too; not for another task's model
    from simdist.agents import load_agent
    loaded = load_agent(path)
    seen.clear()
    assert evaluate_agent.evaluate_agent(loaded, "cartpole-balance", episodes=1,
                                         steps=2)["camera_id"] == 1
    assert seen == [1]
    assert evaluate_agent.agent_camera(loaded, "cartpole-swingup") is None
    assert evaluate_agent.agent_camera(loaded, "cartpole-balance", 0) == 0
