"""Self-describing agent checkpoints: save -> load gives the same agent; bad files fail
with an error naming the file; nothing but plain data and tensors is ever stored."""

import pytest
import torch
from tensordict import TensorDict

from simdist.agents import (DreamerAgent, DreamerConfig, SimDistAgent, SimDistConfig,
                            TwistConfig, TwistStudent, load_agent)
from simdist.agents import checkpoint as fmt
from simdist.modules import DreamerWorldModel, PlannerConfig, SimDistWorldModel
from simdist.utils import CorruptCheckpointError
from tests.synthetic import ScaleDynamics

PLANNER = PlannerConfig(horizon=2, num_samples=8, num_elites=2, iterations=1)


def simdist_agent():
    wm = SimDistWorldModel.build(10, 3, size="tiny")
    wm.encoder.set_normalisation(torch.full((10,), 0.5), torch.full((10,), 2.0))
    return SimDistAgent(wm, SimDistConfig(size="tiny", horizon=3, finetune_lr=5e-5),
                        planner_config=PLANNER)


def teacher_agent():
    return DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny", horizon=3,
                                                      exploration_noise=0.2))


def twist_student():
    student = DreamerWorldModel.student(1, size="tiny", norm="layer", input_norm="image")
    return TwistStudent(teacher_agent(), student, TwistConfig(horizon=3, shift_pad=2))


def dreamer_batch(pixels=False):
    nxt = {"state": torch.randn(2, 4, 5), "reward": torch.randn(2, 4, 1)}
    if pixels:
        nxt["pixels"] = torch.randint(0, 255, (2, 4, 64, 64, 3), dtype=torch.uint8)
    return TensorDict({"action": torch.rand(2, 4, 1) * 2 - 1,
                       "is_init": torch.zeros(2, 4, 1, dtype=torch.bool), "next": nxt}, [2, 4])


def simdist_batch():
    torch.manual_seed(1)
    return TensorDict({"observation": torch.randn(2, 6, 10), "action": torch.rand(2, 6, 3),
                       "is_init": torch.zeros(2, 6, 1, dtype=torch.bool),
                       "value_target": torch.randn(2, 6, 1),
                       "expert_active": torch.ones(2, 6, 1, dtype=torch.bool),
                       "next": {"reward": torch.randn(2, 6, 1)}}, [2, 6])


def assert_same_state(a: dict, b: dict):
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_simdist_round_trip_plans_the_same_actions(tmp_path):
    agent = simdist_agent()
    agent.pretrain_update(simdist_batch())  # optimiser state worth restoring
    path = agent.save(tmp_path / "simdist.pt", meta={"task": "quadruped-flat"})
    loaded = SimDistAgent.load(path)
    assert loaded.config == agent.config and loaded.planner_config == PLANNER
    assert loaded.checkpoint_meta == {"task": "quadruped-flat"}
    assert_same_state(loaded.world_model.state_dict(), agent.world_model.state_dict())
    assert torch.equal(loaded.world_model.encoder.obs_std, torch.full((10,), 2.0))
    a, b = agent.pretrain_optim.state_dict(), loaded.pretrain_optim.state_dict()
    assert torch.equal(a["state"][0]["exp_avg"], b["state"][0]["exp_avg"])
    td = TensorDict({"observation": torch.randn(4, 10),
                     "is_init": torch.ones(4, 1, dtype=torch.bool)}, [4])
    low, high = -torch.ones(3), torch.ones(3)
    out_a = agent.policy(low, high, seed=3)(td.clone())
    out_b = loaded.policy(low, high, seed=3)(td.clone())
    assert torch.equal(out_a["action"], out_b["action"])
    assert loaded.policy(low, high).planner.config == PLANNER  # the saved planner is the default


def test_dreamer_round_trip_acts_and_trains_the_same(tmp_path):
    agent = teacher_agent()
    agent.update(dreamer_batch())
    loaded = DreamerAgent.load(agent.save(tmp_path / "teacher.pt"))
    assert loaded.config == agent.config and loaded.obs_key == "state"
    for name in ("world_model", "actor", "critic", "target_critic"):
        assert_same_state(agent.weights()[name], loaded.weights()[name])
    td = TensorDict({"state": torch.randn(3, 5), "is_init": torch.ones(3, 1, dtype=torch.bool)}, [3])
    torch.manual_seed(0)
    a = agent.policy(explore=True)(td.clone())["action"]
    torch.manual_seed(0)
    b = loaded.policy(explore=True)(td.clone())["action"]
    assert torch.equal(a, b)
    # optimiser moments came back too: one more identical update gives identical weights
    batch = dreamer_batch()
    torch.manual_seed(5)
    agent.update(batch.clone())
    torch.manual_seed(5)
    loaded.update(batch.clone())
    assert_same_state(agent.actor.state_dict(), loaded.actor.state_dict())


def test_pixel_dreamer_round_trip(tmp_path):
    agent = DreamerAgent.for_pixels(2, DreamerConfig(size="tiny"))
    loaded = DreamerAgent.load(agent.save(tmp_path / "pixels.pt", optimisers=False))
    assert loaded.obs_key == "pixels" and loaded.obs_event_dims == 3
    assert_same_state(agent.world_model.state_dict(), loaded.world_model.state_dict())
    assert "optimisers" not in torch.load(tmp_path / "pixels.pt", weights_only=True)


def test_twist_student_deploys_from_its_file_alone(tmp_path):
    twist = twist_student()
    twist.update(dreamer_batch(pixels=True))
    path = twist.save(tmp_path / "student.pt", meta={"task": "cartpole-balance"})
    td = TensorDict({"pixels": torch.randint(0, 255, (2, 64, 64, 3), dtype=torch.uint8),
                     "is_init": torch.ones(2, 1, dtype=torch.bool)}, [2])
    original = twist.policy()
    del twist.teacher  # nothing of the original teacher object is needed to load
    loaded = TwistStudent.load(path)
    assert loaded.config == twist.config and loaded.pixels_key == ("next", "pixels")
    assert_same_state(loaded.student.state_dict(), twist.student.state_dict())
    assert loaded.student.encoder.norm == "layer" and loaded.augment is not None
    torch.manual_seed(0)
    a = original(td.clone())["action"]
    torch.manual_seed(0)
    b = loaded.policy()(td.clone())["action"]
    assert torch.equal(a, b)
    # the teacher's world model came along: the student keeps training from the file
    assert set(loaded.update(dreamer_batch(pixels=True))) >= {"loss_distillation", "loss_imagined"}


def test_load_agent_dispatches_on_the_class_it_names(tmp_path):
    for agent, cls in ((simdist_agent(), SimDistAgent), (teacher_agent(), DreamerAgent),
                       (twist_student(), TwistStudent)):
        loaded = load_agent(agent.save(tmp_path / f"{cls.__name__}.pt"), map_location="cpu")
        assert type(loaded) is cls and loaded.device == torch.device("cpu")


def test_files_hold_only_tensors_and_plain_data(tmp_path):
    path = twist_student().save(tmp_path / "student.pt")
    ckpt = torch.load(path, weights_only=True)  # raises on any pickled object
    assert (ckpt["format"], ckpt["version"], ckpt["class"]) == ("simdist-agent", 1, "TwistStudent")
    fmt.check_plain(ckpt["config"])
    assert ckpt["config"]["teacher"]["world_model"]["encoder"]["kind"] == "state"


def test_meta_that_is_not_plain_data_is_refused_before_writing(tmp_path):
    path = teacher_agent().save(tmp_path / "a.pt")
    before = path.read_bytes()
    with pytest.raises(TypeError, match=r"meta\['when'\] is a object"):
        teacher_agent().save(path, meta={"when": object()})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pt"]  # no temp file left


def test_custom_dynamics_is_refused_when_saving(tmp_path):
    wm = SimDistWorldModel.build(10, 3, size="tiny", dynamics=ScaleDynamics(action_dim=3))
    with pytest.raises(TypeError, match="MLPDynamics only"):
        SimDistAgent(wm).save(tmp_path / "x.pt")
    assert not (tmp_path / "x.pt").exists()


def test_missing_file_names_it(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        SimDistAgent.load(tmp_path / "nope.pt")


@pytest.mark.parametrize("damage, message", [
    ("truncate", "truncated, garbled"),
    ("state_dict", "not a self-describing agent file"),
    ("newer", "format version 2, this simdist reads up to 1"),
    ("class", "holds a DreamerAgent, not a SimDistAgent"),
    ("shape", "world_model weights do not fit"),
    ("field", r"fields this simdist does not know: \['warmup'\]"),
    ("size", "world model description cannot be built"),
    ("optimiser", "optimisers are"),
    ("pickle", "pickled Python objects"),
])
def test_bad_files_fail_naming_the_file(tmp_path, damage, message):
    path = simdist_agent().save(tmp_path / "agent.pt")
    ckpt = torch.load(path, weights_only=True)
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "state_dict":
        torch.save(ckpt["weights"]["world_model"], path)
    elif damage == "newer":
        torch.save({**ckpt, "version": 2}, path)
    elif damage == "class":
        teacher_agent().save(path)
    elif damage == "shape":
        key = "encoder.net.0.weight"
        ckpt["weights"]["world_model"][key] = torch.zeros(3, 3)
        torch.save(ckpt, path)
    elif damage == "field":
        ckpt["config"]["agent"]["warmup"] = 100
        torch.save(ckpt, path)
    elif damage == "size":
        del ckpt["config"]["world_model"]["hidden"]
        torch.save(ckpt, path)
    elif damage == "optimiser":
        del ckpt["optimisers"]["whole_optim"]
        torch.save(ckpt, path)
    elif damage == "pickle":
        torch.save({**ckpt, "meta": {"config": SimDistConfig()}}, path)
    with pytest.raises(CorruptCheckpointError, match=message) as err:
        SimDistAgent.load(path)
    assert str(path) in str(err.value)
    assert "weights_only=False" not in str(err.value)


def test_a_keypoint_student_round_trips_through_its_self_describing_file(tmp_path):
    teacher = DreamerAgent.for_state(5, 2, DreamerConfig(size="tiny"))
    student = DreamerWorldModel.student(2, size="tiny", norm="layer", input_norm="image",
                                        arch="keypoints")
    twist = TwistStudent(teacher, student, TwistConfig(horizon=2))
    loaded = TwistStudent.load(twist.save(tmp_path / "kp.pt"))
    enc = loaded.student.encoder
    assert (enc.arch, enc.keypoints, enc.embed_dim) == ("keypoints", 16, 32)
    for a, b in zip(student.parameters(), loaded.student.parameters()):
        assert torch.equal(a, b)


def test_ignored_inputs_survive_the_round_trip(tmp_path):
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(obs_dim=10, action_dim=3, size="tiny", ignored_inputs=[2, 7])
    path = SimDistAgent(wm).save(tmp_path / "agent.pt")
    loaded = SimDistAgent.load(path).world_model
    assert loaded.encoder.ignored_inputs == (2, 7)
    window = torch.randn(4, loaded.encoder.history, 10)
    torch.testing.assert_close(loaded.encode(window), wm.encode(window))


def test_a_training_checkpoint_is_named_for_what_it_is_and_never_to_be_deleted(tmp_path):
    """Agent files and training checkpoints: one name each (an online run's checkpoint is
    training.pt), and load_agent on a training checkpoint names the file to load instead
    rather than calling it corrupt."""
    from simdist.agents import load_agent
    from simdist.agents.checkpoint import NotAnAgentFileError
    from simdist.utils import save_atomic
    path = tmp_path / "training.pt"
    save_atomic({"agent": {}, "episodes": 3, "history": [{}], "returns": [1.0]}, path)
    with pytest.raises(NotAnAgentFileError, match="is a training checkpoint") as error:
        load_agent(path)
    assert "teacher_agent.pt" in str(error.value)
    assert "delete" not in str(error.value).lower() and "corrupt" not in str(error.value)
