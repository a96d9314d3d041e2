import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from simdist.utils.precision import resolve_precision
from simdist.utils.records import copy_records
from simdist.pipelines.report import REFERENCES
from simdist.utils.sealed import seal
from simdist.utils.stages import read_stage_record
from tests.in_process import run_script

ROOT = Path(__file__).resolve().parents[2]
RECIPE = [sys.executable, str(ROOT / "recipes" / "simdist_quadruped.py")]


@pytest.fixture(scope="module")
def tiny_expert(tmp_path_factory):
    from simdist.experts import Expert, SACExpertConfig
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("expert") / "expert.pt"
    return Expert.untrained(89, 12, hidden=16).save(path, 89, SACExpertConfig(hidden=16))


def _run(*args, timeout=300):
    return subprocess.run([*RECIPE, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def _run_here(*args, capsys):
    """The recipe in this process (tests/in_process.py): for what fails or prints help
    before any work, and for runs whose results are not compared with a subprocess's."""
    return run_script(RECIPE[1], *args, capsys=capsys)


def test_recipe_runs_end_to_end_on_tiny_preset_and_resumes(tmp_path, tiny_expert, capsys):
    proc = _run("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path,
                "--threads", 1)
    assert proc.returncode == 0, proc.stderr
    stages = ["expert", "expert_zero_shot", "dataset", "pretrain", "zero_shot", "frozen_parts",
              "round_1", "round_2"]
    for stage in stages:
        assert (tmp_path / "stages" / f"{stage}.json").exists(), stage
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["torch_threads"] == 1
    # the default "auto" precision, as resolved on this machine's CPU
    auto = resolve_precision("auto", "cpu")
    assert results["precision"] == {"mixed_precision": auto, "planner_precision": auto}
    assert f"precision on cpu: training {auto}, planning {auto}" in proc.stdout
    # the machine its timings were measured on, measured with the run's one thread
    assert results["machine"]["torch_threads"] == 1
    assert results["machine"]["matmul_gflops"] > 0
    assert "machine: " + results["machine"]["cpu"] in proc.stdout
    assert set(results["expert_zero_shot"]) == {"sim", "slippery_slope"}
    assert set(results["planner_zero_shot"]) == {"sim", "slippery_slope"}
    assert results["dataset"]["transitions"] == 4 * 20
    curves = results["curves"]
    # Budgets 0.02 and 0.04 min of 50 Hz data = 60 and 120 steps = 3 and 6 episodes of 20.
    assert curves["minutes"] == [0.0, 0.02, 0.04]
    methods = ["expert (zero-shot)", "SimDist: finetune dynamics",
               "ablation: finetune whole model", "baseline: continue expert SAC"]
    for method in methods:
        assert len(curves[method]) == 3 and all(len(r["progress_m"]) == 2 for r in curves[method])
    # Round 0 of the finetuning methods is the pretrained planner's zero-shot figure.
    assert curves["SimDist: finetune dynamics"][0] == results["planner_zero_shot"]["slippery_slope"]
    # the frozen parts' own figure in the target, printed beside every budget
    assert curves["prior_alone"] == results["frozen_parts"]["prior_alone"]
    assert len(curves["prior_alone"]["fraction"]) == 2 and "simulator_ceiling" not in curves
    assert "(policy prior alone)" in proc.stdout
    assert (tmp_path / "forward_progress.png").stat().st_size > 0
    assert "95% CI" in proc.stdout and "SimDist: finetune dynamics" in proc.stdout
    # every point keeps its episodes' commanded speeds, and the table by speed is printed
    assert all(len(r["command_mps"]) == 2 for m in methods for r in curves[m])
    assert "by commanded speed" in proc.stdout
    # and whether each evaluation episode had the robot on its back, printed by speed
    assert all(len(r["upside_down"]) == 2 for m in methods for r in curves[m])
    assert "Episodes on their back at some step in slippery_slope" in proc.stdout
    # every method is evaluated on the same worlds, so SimDist's paired differences print
    assert "Paired by episode in slippery_slope: SimDist: finetune dynamics minus" in proc.stdout
    # Finetuning touched only the dynamics: every other tensor equals the pretrained one.
    pretrained = torch.load(tmp_path / "stages" / "pretrain" / "world_model.pt", weights_only=True)
    finetuned = torch.load(tmp_path / "stages" / "round_2" / "simdist.pt", weights_only=True)
    assert any(not torch.equal(v, pretrained[k]) for k, v in finetuned.items() if k.startswith("dynamics"))
    assert all(torch.equal(v, pretrained[k]) for k, v in finetuned.items() if not k.startswith("dynamics"))
    whole = torch.load(tmp_path / "stages" / "round_2" / "whole.pt", weights_only=True)
    assert any(not torch.equal(v, pretrained[k]) for k, v in whole.items() if k.startswith("encoder"))
    for name in ("rerun_before.rrd", "rerun_after.rrd", "planner_before_finetuning.mp4",
                 "planner_after_finetuning.mp4"):
        assert (tmp_path / name).stat().st_size > 0
    # every training loop logged its updates (TorchRL CSV logger) and the curves are drawn
    for scalar in ("pretrain/loss_consistency", "round_2/simdist/loss_consistency",
                   "round_2/whole/loss_consistency", "round_2/sac/loss_actor"):
        assert (tmp_path / "logs" / "scalars" / f"{scalar}.csv").exists(), scalar
    assert (tmp_path / "training_curves.png").stat().st_size > 0

    # a rerun without --threads and with another number of dataset workers reuses every
    # stage (both are runtime settings: shards are the same bytes either way); these
    # reruns do no work, so they run in this process (tests/in_process.py)
    again = _run_here("--preset", "tiny", "--expert", tiny_expert, "--dataset-workers", 2,
                      "--output-dir", tmp_path, capsys=capsys)
    assert again.returncode == 0 and again.stdout.count("already done") == len(stages) + 2
    assert json.loads((tmp_path / "results.json").read_text())["curves"] == curves
    # another config's folder is the user's choice, not a crash: an error: line, status 2
    refused = _run_here("--preset", "tiny", "--episodes", 3, "--expert", tiny_expert,
                        "--output-dir", tmp_path, capsys=capsys)
    assert refused.returncode == 2, refused.stderr
    assert refused.stderr.startswith("simdist_quadruped.py: error: ")
    assert "holds results of a different config (changed: ['episodes'])" in refused.stderr
    assert "Traceback" not in refused.stderr
    # The run's records alone (`python -m simdist.utils.records`: config and stage JSONs, no
    # weights, no data) rebuild its tables; a stage that needs the weights is refused by name.
    records = tmp_path.parent / f"{tmp_path.name}_records"
    copied = copy_records(tmp_path, records)
    assert copied and all(p.suffix == ".json" for p in copied)
    weights = tmp_path / "stages" / "pretrain" / "world_model.pt"
    weights.rename(weights.with_suffix(".hidden"))  # as on a machine without the run's files
    try:
        rebuilt = _run_here("--preset", "tiny", "--expert", tiny_expert, "--output-dir",
                            records, capsys=capsys)
        assert rebuilt.returncode == 0, rebuilt.stderr
        assert rebuilt.stdout.count("already done") == len(stages) + 2  # + probe, recordings
        assert json.loads((records / "results.json").read_text())["curves"] == curves
        (records / "stages" / "recordings.json").unlink()  # as if run with --no-record
        refused = _run_here("--preset", "tiny", "--expert", tiny_expert, "--output-dir",
                            records, capsys=capsys)
        assert refused.returncode == 2 and "Traceback" not in refused.stderr
        assert "holds the pretraining's record but not its weights" in refused.stderr
        assert "['recordings'] need: pass --no-record" in refused.stderr
        rebuilt = _run_here("--preset", "tiny", "--expert", tiny_expert, "--no-record",
                            "--output-dir", records, capsys=capsys)
        assert rebuilt.returncode == 0, rebuilt.stderr
        assert json.loads((records / "results.json").read_text())["curves"] == curves
    finally:
        weights.with_suffix(".hidden").rename(weights)
    # A stage record that lacks a target of this config (e.g. copied from another run's
    # folder) is refused by name instead of failing with a KeyError at the end.
    record = tmp_path / "stages" / "expert_zero_shot.json"
    stored = json.loads(record.read_text())
    del stored["result"]["slippery_slope"]
    record.write_text(json.dumps(seal(stored)))  # as written by that other run
    refused = _run_here("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path,
                        capsys=capsys)
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert "simdist_quadruped.py: error: " in refused.stderr
    assert "has no result for ['slippery_slope']" in refused.stderr


def test_a_stage_record_naming_the_shipped_expert_relatively_runs_from_any_directory(
        tmp_path, monkeypatch, capsys):
    """results/ records name the committed expert as checkpoints/quadruped_expert/expert.pt
    (relative to the repository root); a run folder rebuilt from them must not depend on
    the working directory."""
    from simdist.pipelines.simdist import PRESETS, Config
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    (out / "stages").mkdir(parents=True)
    elsewhere.mkdir()
    # the records of results/ come with their config.json (a folder without it is refused)
    config = Config(**{**PRESETS["tiny"], "record": False, "budgets_min": [0.02]})
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(config), default=str))
    (out / "stages" / "expert.json").write_text(json.dumps(
        {"result": {"path": "checkpoints/quadruped_expert/expert.pt"}, "seconds": 0.0}))
    monkeypatch.chdir(elsewhere)
    proc = _run_here("--preset", "tiny", "--output-dir", out, "--threads", 1, "--no-record",
                     "--budgets-min", "0.02", capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    assert "stage expert: already done" in proc.stdout
    assert (out / "stages" / "pretrain.json").exists()  # the stage that reads the expert


def test_a_killed_round_resumes_without_recollecting(tmp_path, tiny_expert, capsys):
    # (without the recordings: they come after the rounds and are checked below)
    args = ("--preset", "tiny", "--expert", tiny_expert, "--no-record", "--output-dir", tmp_path)
    proc = _run(*args)
    assert proc.returncode == 0, proc.stderr
    record = tmp_path / "stages" / "round_2.json"
    first = json.loads(record.read_text())["result"]
    # Simulate a kill after round 2 collected its data and finetuned its dynamics.
    record.unlink()
    (tmp_path / "stages" / "round_2" / "sac.ckpt").unlink()
    data_before = sorted(p.stat().st_mtime_ns for p in (tmp_path / "stages" / "round_2" / "data").rglob("*.memmap"))
    again = _run(*args)
    assert again.returncode == 0, again.stderr
    assert "round 2: finetune dynamics" not in again.stderr  # restored, not retrained
    data_after = sorted(p.stat().st_mtime_ns for p in (tmp_path / "stages" / "round_2" / "data").rglob("*.memmap"))
    assert data_after == data_before
    resumed = json.loads(record.read_text())["result"]
    assert resumed["simdist_eval"] == first["simdist_eval"]
    assert resumed["target_steps"] == first["target_steps"]
    # --no-record skipped the probe and the recordings; a rerun with them adds just those
    assert not (tmp_path / "stages" / "probe.json").exists()
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob("*.mp4"))
    assert "rerun recordings" not in again.stdout
    recorded = run_script(RECIPE[1], *args[:-3], "--output-dir", tmp_path, capsys=capsys)
    assert recorded.returncode == 0, recorded.stderr
    assert recorded.stdout.count("already done") == 8  # every stage but probe, recordings
    assert (tmp_path / "stages" / "probe.json").exists()
    assert (tmp_path / "rerun_after.rrd").stat().st_size > 0
    assert (tmp_path / "planner_after_finetuning.mp4").stat().st_size > 0


def test_without_an_mp4_encoder_the_recipe_warns_first_and_still_finishes(
        tmp_path, tiny_expert, capsys, monkeypatch):
    """A user whose install lacks imageio-ffmpeg (e.g. installed with --no-deps) gets the
    tables and the rerun recordings, and hears about the missing videos before any work."""
    from simdist.pipelines.simdist import recording
    from simdist.recipes import simdist_quadruped
    for module in (simdist_quadruped, recording):
        monkeypatch.setattr(module, "video_backend_available", lambda: False)
    with pytest.warns(UserWarning, match="without MP4 videos: writing MP4 videos needs"):
        proc = _run_here("--preset", "tiny", "--expert", tiny_expert, "--threads", 1,
                         "--output-dir", tmp_path, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.index("Training randomisation") < proc.stdout.index("stage")
    results = json.loads((tmp_path / "results.json").read_text())
    assert set(results["recordings"]) == {"before", "after"}
    assert (tmp_path / "rerun_after.rrd").stat().st_size > 0
    assert not list(tmp_path.glob("*.mp4"))


def test_recipe_rejects_unknown_target_and_missing_expert(tmp_path, capsys):
    proc = _run_here("--target", "moon", "--output-dir", tmp_path / "a", capsys=capsys)
    assert proc.returncode != 0 and "unknown target domain 'moon'" in proc.stderr
    proc = _run_here("--preset", "tiny", "--expert", tmp_path / "none.pt", "--output-dir",
                     tmp_path / "b", capsys=capsys)
    assert proc.returncode == 2 and "recipes/train_expert.py" in proc.stderr
    assert not (tmp_path / "b").exists()
    (tmp_path / "notes.pt").write_bytes(b"not an expert")  # exists, but is no expert
    proc = _run_here("--preset", "tiny", "--expert", tmp_path / "notes.pt", "--output-dir",
                     tmp_path / "d", capsys=capsys)
    assert proc.returncode == 2 and "error: expert: " in proc.stderr
    assert "notes.pt' is corrupt" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "d").exists()  # no config.json, no .lock: refused before any work
    proc = _run_here("--preset", "tiny", "--device", "tpu9", "--output-dir", tmp_path / "c",
                     capsys=capsys)
    assert proc.returncode == 2 and "unknown device 'tpu9'" in proc.stderr
    assert not (tmp_path / "c").exists()  # refused before any work


def test_help_lists_every_config_field_with_its_default(capsys):
    import dataclasses
    import importlib.util
    spec = importlib.util.spec_from_file_location("simdist_quadruped_recipe",
                                                  ROOT / "recipes" / "simdist_quadruped.py")
    recipe = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = recipe  # dataclasses resolve annotations through it
    spec.loader.exec_module(recipe)
    proc = _run_here("--help", capsys=capsys)
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())  # the help wraps long lines
    for f in dataclasses.fields(recipe.Config):
        assert "--" + f.name.replace("_", "-") in text, f.name
    assert "(default: 32)" in text and "--preset {default,paper,tiny}" in text
    tiny = " ".join(_run_here("--preset", "tiny", "--help", capsys=capsys).stdout.split())
    assert "(default: 2)" in tiny  # a preset's values become the defaults shown


def test_model_history_sets_the_encoders_window():
    from simdist.pipelines.simdist import Config, new_agent
    agent = new_agent(Config(model_size="tiny", model_history=6), obs_dim=10, action_dim=3)
    assert agent.world_model.encoder.history == 6
    # each step: the observation and (the default) the previous action
    assert agent.make_primer(0).primers["simdist", "history"].shape == (6, 10 + 3)
    default = new_agent(Config(model_size="tiny"), obs_dim=10, action_dim=3)
    assert default.world_model.encoder.history == 2  # the size's own


def test_model_previous_action_makes_the_encoder_and_the_primer_carry_the_last_action():
    from simdist.pipelines.simdist import Config, new_agent
    agent = new_agent(Config(model_size="tiny", model_previous_action=True), obs_dim=10,
                      action_dim=3)
    assert agent.world_model.encoder.action_dim == 3
    primers = agent.make_primer(0).primers
    assert primers["simdist", "history"].shape == (2, 13)
    assert primers["simdist", "previous_action"].shape == (3,)
    off = Config(model_size="tiny", model_previous_action=False)
    assert new_agent(off, 10, 3).world_model.encoder.action_dim == 0
    assert Config().model_previous_action  # the default reads it


def test_model_dynamics_hidden_and_latent_dim_resize_the_model_and_survive_save_and_load(tmp_path):
    from simdist.agents import SimDistAgent
    from simdist.pipelines.simdist import Config, new_agent
    agent = new_agent(Config(model_size="tiny", model_dynamics_hidden=48), obs_dim=10, action_dim=3)
    wm = agent.world_model
    assert wm.dynamics.net[0].out_features == 48
    assert wm.encoder.net[0].out_features == 32  # the size's own width elsewhere
    agent.save(tmp_path / "agent.pt", optimisers=False)
    loaded = SimDistAgent.load(tmp_path / "agent.pt")
    assert loaded.world_model.dynamics.net[0].out_features == 48
    for a, b in zip(wm.state_dict().values(), loaded.world_model.state_dict().values()):
        assert torch.equal(a, b)
    wider = new_agent(Config(model_size="tiny", model_latent_dim=24), obs_dim=10, action_dim=3)
    assert wider.world_model.latent_dim == 24
    assert wider.world_model.encoder.simnorm_groups == 3  # groups of 8


def test_model_dynamics_residual_reaches_the_dynamics_and_a_mismatched_pretraining_is_refused(
        tmp_path):
    from simdist.pipelines.simdist import Config, load_agent, new_agent
    from simdist.utils import RunFolderError
    logit = Config(model_size="tiny", model_dynamics_residual="logit")
    assert new_agent(logit, obs_dim=10, action_dim=3).world_model.dynamics.residual == "logit"
    assert Config().model_dynamics_residual == "logit"  # the default since 2026-12-03
    additive = Config(model_size="tiny", model_dynamics_residual="additive")
    weights = new_agent(additive, 10, 3).world_model.state_dict()
    torch.save(weights, tmp_path / "w.pt")
    # a pretraining record from before the field (no "dynamics_residual") was additive:
    # loading its weights as "logit" would step wrongly with the same shapes
    record = {"path": str(tmp_path / "w.pt"), "obs_dim": 10, "action_dim": 3}
    with pytest.raises(RunFolderError, match="trained with --model-dynamics-residual additive"):
        load_agent(logit, record)
    assert load_agent(additive, record).world_model.dynamics.residual == "additive"


def test_finetune_consistency_reaches_every_finetuning_loss():
    from simdist.pipelines.simdist import Config, new_agent
    agent = new_agent(Config(model_size="tiny", finetune_consistency="kl"), obs_dim=10,
                      action_dim=3, dynamics_members=2)
    assert [loss.consistency for loss in agent.finetune_losses] == ["kl", "kl"]
    assert new_agent(Config(model_size="tiny"), 10, 3).finetune_loss.consistency == "squared"


def test_model_prior_bounds_give_the_prior_the_envs_joint_box_and_survive_save_and_load(
        tmp_path):
    from simdist.agents import SimDistAgent
    from simdist.pipelines.simdist import Config, load_agent, new_agent
    from simdist.utils import RunFolderError
    cfg = Config(model_size="tiny", model_prior_bounds=True)
    agent = new_agent(cfg, obs_dim=10, action_dim=12)
    prior = agent.world_model.policy_head
    # the quadruped's per-joint bounds: [-1, 1] yaw, [-1, 1.1] lift, [-0.8, 0.8] extend
    assert prior.action_high.max().item() == pytest.approx(1.1)
    assert prior.action_low.max().item() == pytest.approx(-0.8)
    last = prior.net[-1]
    with torch.no_grad():  # saturate the tanh both ways
        last.weight.zero_()
        last.bias.fill_(20.0)
        top = prior(torch.randn(4, agent.world_model.latent_dim))
        last.bias.fill_(-20.0)
        bottom = prior(torch.randn(4, agent.world_model.latent_dim))
    torch.testing.assert_close(top, prior.action_high.expand(4, -1))
    torch.testing.assert_close(bottom, prior.action_low.expand(4, -1))
    agent.save(tmp_path / "agent.pt", optimisers=False)
    loaded = SimDistAgent.load(tmp_path / "agent.pt").world_model.policy_head
    assert torch.equal(loaded.action_high, prior.action_high)
    assert new_agent(Config(model_size="tiny"), 10, 12).world_model.policy_head.action_low is None
    torch.save(agent.world_model.state_dict(), tmp_path / "w.pt")
    record = {"path": str(tmp_path / "w.pt"), "obs_dim": 10, "action_dim": 12,
              "prior_bounds": True, "dynamics_residual": cfg.model_dynamics_residual}
    with pytest.raises(RunFolderError, match="--model-prior-bounds"):
        load_agent(Config(model_size="tiny"), record)
    assert load_agent(cfg, record).world_model.policy_head.action_low is not None


def test_ignored_observation_groups_reach_the_encoder():
    from simdist.pipelines.simdist import Config, new_agent, observation_layout
    layout = observation_layout("quadruped-terrain")
    cfg = Config(model_size="tiny", model_ignored_observations=["toe_force", "accelerometer"])
    agent = new_agent(cfg, obs_dim=layout.size, action_dim=12)
    expected = [*range(layout.size)[layout["accelerometer"]], *range(layout.size)[layout["toe_force"]]]
    assert list(agent.world_model.encoder.ignored_inputs) == sorted(expected)
    assert new_agent(Config(model_size="tiny"), layout.size, 12).world_model.encoder.ignored_inputs == ()


def test_a_finished_run_from_before_a_field_existed_loads_with_what_it_was_made_with(
        tmp_path, monkeypatch):
    import copy
    import dataclasses
    from types import MappingProxyType
    from simdist.pipelines import simdist as recipe
    from simdist.utils.stages import ABSENT_MEANS
    stored = json.loads(json.dumps(dataclasses.asdict(recipe.Config(model_size="tiny")), default=str))
    del stored["model_history"], stored["model_ignored_observations"]  # an older folder
    del stored["planner_value_lambda"], stored["planner_value_every"]
    stored["a_field_since_removed"] = 1
    (tmp_path / "stages").mkdir()
    (tmp_path / "config.json").write_text(json.dumps({"config": stored}))
    (tmp_path / "stages" / "pretrain.json").write_text(json.dumps({"result": {"world_model": "w.pt"}}))
    cfg, pretrained = recipe.load_finished_run(tmp_path, seed=3)
    assert (cfg.model_size, cfg.seed, pretrained) == ("tiny", 3, {"world_model": "w.pt"})
    assert cfg.model_ignored_observations == [] and cfg.model_history == 0
    # planned with the terminal value alone, the default before the lambda-return
    assert (cfg.planner_value_lambda, cfg.planner_value_every) == (1.0, 1)
    # a field whose default changed reads as what older folders were made with
    patched = copy.copy(recipe.Config.__dataclass_fields__["model_history"])
    patched.metadata = MappingProxyType({ABSENT_MEANS: 7})
    monkeypatch.setitem(recipe.Config.__dataclass_fields__, "model_history", patched)
    assert recipe.load_finished_run(tmp_path)[0].model_history == 7


def test_hiding_observation_groups_needs_a_robot_data_task():
    from simdist.pipelines.simdist import Config
    with pytest.raises(ValueError, match="model_ignored_observations"):
        Config(model_size="tiny", data_task="cartpole-balance", model_ignored_observations=["gyro"])
    with pytest.raises(ValueError, match="unknown observation groups"):
        Config(model_size="tiny", model_ignored_observations=["no_such_sensor"])


def test_dataset_dither_reaches_the_perturbation_schedule():
    from simdist.pipelines.simdist import Config, dataset_config
    assert dataset_config(Config(dataset_dither_std=0.3)).schedule.dither_std == 0.3
    assert dataset_config(Config()).schedule.dither_std == 0.0  # the reference schedule


def test_planner_flags_reach_the_planner_config():
    from simdist.pipelines.simdist import Config
    assert Config(planner_policy_noise_steps=1).planner().policy_noise_steps == 1
    assert Config().planner().policy_noise_steps == 0  # noise on every step of the plan
    assert Config(planner_value_lambda=1.0).planner().value_lambda == 1.0  # terminal value
    assert Config().planner().value_lambda == 0.95  # a lambda-return
    assert Config(planner_value_every=1).planner().value_every == 1
    assert Config().planner().value_every == 2
    assert Config(planner_precision="bfloat16").planner().precision == "bfloat16"
    # bfloat16 only where it is fast (simdist.utils.precision)
    assert Config().planner().precision == Config().mixed_precision == "auto"


def test_the_collection_planner_is_the_planner_unless_its_own_search_is_set():
    from simdist.pipelines.simdist import PRESETS, Config
    unset = dict(collect_planner_samples=0, collect_planner_iterations=0,
                 collect_planner_elites=0)
    assert Config(**unset).collect_planner() == Config().planner()
    # the default collects with about half the search and evaluates with the full one
    expected = dataclasses.replace(Config().planner(), num_samples=48, iterations=2,
                                   num_elites=6)
    assert Config().collect_planner() == expected
    assert Config().planner() == Config(**unset).planner()
    # one field set, the others follow the planner
    assert Config(**{**unset, "collect_planner_iterations": 1}).collect_planner() == \
        dataclasses.replace(Config().planner(), iterations=1)
    # the presets with their own planner collect with it
    for preset in ("tiny", "paper"):
        cfg = Config(**PRESETS[preset])
        assert cfg.collect_planner() == cfg.planner(), preset


def test_collection_plans_with_the_collection_planner_and_evaluation_with_the_planner(
        monkeypatch):
    from simdist.pipelines import simdist as recipe
    cfg = recipe.Config(model_size="tiny", model_latent_dim=0, episode_steps=8, slice_len=8,
                        model_horizon=3, collect_episodes=2, episodes=2, planner_horizon=3,
                        planner_samples=16, planner_iterations=2, planner_elites=4,
                        planner_precision="none", expert_targets=["sim"],
                        collect_planner_samples=8, collect_planner_iterations=1,
                        collect_planner_elites=2)
    agent = recipe.new_agent(cfg, obs_dim=89, action_dim=12)
    searches, make_policy = [], agent.policy

    def spy(low, high, planner, **kwargs):
        searches.append((planner.num_samples, planner.iterations, planner.num_elites))
        return make_policy(low, high, planner, **kwargs)

    monkeypatch.setattr(agent, "policy", spy)
    recipe.collect_target_data(cfg, agent, steps=8, seed=0)
    recipe.evaluate_planner(cfg, agent, "sim")
    assert searches == [(8, 1, 2), (16, 2, 4)]


@pytest.mark.parametrize("flags, message", [
    (["--episodes", "0"], "episodes: must be > 0"),
    (["--dataset-dither-std", "-0.5"], "dither_std must be finite and >= 0"),
    (["--budgets-min", "2", "1"], "budgets_min: must be positive and increasing"),
    (["--planner-elites", "100"], "num_elites (100) must be <= num_samples"),
    (["--planner-policy-noise-steps", "-1"], "policy_noise_steps must be >= 0"),
    (["--planner-value-lambda", "1.5"], "value_lambda must lie in"),
    (["--planner-value-every", "0"], "value_every must be >= 1"),
    (["--collect-planner-elites", "100"], "num_elites (100) must be <= num_samples"),
    (["--collect-planner-samples", "-4"], "collect_planner_samples: must be >= 0"),
    (["--model-size", "huge"], "model_size: unknown size 'huge'"),
    (["--mixed-precision", "fp8"], "mixed_precision: unknown precision 'fp8'"),
    (["--planner-precision", "fp8"], "planner_precision: unknown precision 'fp8'"),
    (["--target", "unseen_scenes"], "change only what a camera"),
    (["--target", '{"friction": true}'], "target: TargetDomain.friction must be a number"),
    (["--target", '{"payload_kg": 1e30}'], "target: TargetDomain.payload_kg must lie in"),
    (["--target", '{"action_latency": 100000}'], "TargetDomain.action_latency must lie in"),
    (["--slice-len", "2"], "needs model_horizon < slice_len"),
    (["--model-history", "-1"], "model_history: must be >= 0"),
    (["--model-dynamics-hidden", "-8"], "model_dynamics_hidden: must be >= 0"),
    (["--model-latent-dim", "100"], "model_latent_dim: must be a multiple of 8"),
    (["--model-history", "11", "--model-previous-action"],
     "slice_len: needs slice_len >= model_horizon + 12"),
    (["--threads", "-1"], "threads: must be >= 0"),
    (["--finetune-priority-alpha", "inf"], "finetune_priority_alpha: must be >= 0 and finite"),
    (["--finetune-priority-beta", "-0.5"], "finetune_priority_beta: must be >= 0"),
    (["--ensemble-size", "0"], "ensemble_size: must be > 0"),
    (["--reward-upright-power", "0"], "reward_upright_power: must be > 0"),
    (["--reward-upright-power", "nan"], "reward_upright_power: must be > 0 and finite"),
    (["--finetune-sim-fraction", "1"], "finetune_sim_fraction: needs 0 <= fraction < 1"),
    (["--finetune-sim-fraction", "0.001"], "(0 simulation slices)"),
    (["--finetune-sim-fraction", "0.5", "--finetune-priority-alpha", "1"],
     "cannot be combined with --finetune-priority-alpha"),
    (["--ensemble-shared-encoder"], "ensemble_shared_encoder: needs --ensemble-size > 1"),
    (["--finetune-consistency", "cosine"], "finetune_consistency: unknown consistency 'cosine'"),
    (["--model-ignored-observations", "toes"], "unknown observation groups ['toes']"),
])
def test_a_bad_value_fails_before_any_work_naming_the_field(tmp_path, flags, message, capsys):
    proc = _run_here(*flags, "--output-dir", tmp_path / "out", capsys=capsys)
    assert proc.returncode == 2
    assert message in " ".join(proc.stderr.replace("│", " ").split())
    assert not (tmp_path / "out").exists()


def test_co_training_mixes_dataset_slices_into_both_finetuned_methods(tmp_path, tiny_expert,
                                                                      capsys, monkeypatch):
    from simdist.agents import SimDistAgent
    from simdist.data import load_dataset
    seen = {"finetune_update": [], "finetune_whole_update": []}
    for name in seen:
        def spy(self, batch, *args, _original=getattr(SimDistAgent, name), _name=name, **kwargs):
            seen[_name].append(batch.clone())
            return _original(self, batch, *args, **kwargs)
        monkeypatch.setattr(SimDistAgent, name, spy)
    proc = _run_here("--preset", "tiny", "--expert", tiny_expert, "--no-record",
                     "--finetune-sim-fraction", 0.5, "--output-dir", tmp_path, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    dataset = load_dataset(tmp_path / "stages" / "dataset" / "data", 8, 8)[:]["observation"]
    for name, batches in seen.items():
        assert len(batches) == 2 * 3  # two rounds of the tiny preset's 3 updates
        for batch in batches:  # tiny: 4 slices per batch, 2 of them from the dataset
            assert batch["from_simulation"][:, :, 0].all(1).tolist() == [False, False, True, True]
            assert not batch["from_simulation"][:2].any()
            first = batch["observation"][:, 0]  # each slice's first step, found in the dataset?
            found = [(dataset == row).all(-1).any().item() for row in first]
            assert found[2:] == [True, True] and found[:2] == [False, False], name
    config = json.loads((tmp_path / "config.json").read_text())
    assert config["finetune_sim_fraction"] == 0.5


def test_an_ensemble_pretrains_finetunes_and_plans_with_every_member(tmp_path, tiny_expert,
                                                                     capsys):
    # with prioritised finetuning slices: each member ranks the slices by its own error;
    # and an encoder of observations alone (the default reads the previous action too)
    proc = _run_here("--preset", "tiny", "--expert", tiny_expert, "--ensemble-size", 2,
                     "--budgets-min", 0.02, "--finetune-priority-alpha", 0.6,
                     "--no-model-previous-action",
                     "--output-dir", tmp_path, "--threads", 1, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    stages = tmp_path / "stages"
    pretrain = read_stage_record(tmp_path, "pretrain")["result"]
    assert len(pretrain["members"]) == 2 and pretrain["path"] == pretrain["members"][0]
    first, second = (torch.load(m, weights_only=True) for m in pretrain["members"])
    assert any(not torch.equal(v, second[k]) for k, v in first.items())  # two models
    round_1 = read_stage_record(tmp_path, "round_1")["result"]
    for method in ("simdist", "whole"):
        assert len(round_1[f"{method}_members"]) == 2
        assert len(round_1[f"{method}_member_agents"]) == 2
    # every member's finetuning touched only its own dynamics
    for before, after in zip(pretrain["members"], round_1["simdist_members"]):
        before, after = (torch.load(x, weights_only=True) for x in (before, after))
        assert any(not torch.equal(v, before[k]) for k, v in after.items() if k.startswith("dynamics"))
        assert all(torch.equal(v, before[k]) for k, v in after.items() if not k.startswith("dynamics"))
    results = json.loads((tmp_path / "results.json").read_text())
    assert len(results["curves"]["SimDist: finetune dynamics"]) == 2
    assert (tmp_path / "rerun_after.rrd").stat().st_size > 0
    # every member's checkpoint keeps its own measured priorities (resume draws the same)
    member_0, member_1 = (torch.load(stages / "round_1" / f"simdist{tag}.ckpt",
                                     weights_only=True)["state"]["priorities"]["priority"]
                          for tag in ("", "_member_1"))
    assert member_0.shape == member_1.shape and (member_0 > 0).all()
    assert not torch.equal(member_0, member_1) and not torch.equal(member_0, torch.ones_like(member_0))


def test_members_pretrained_side_by_side_equal_those_trained_one_after_the_other(
        tmp_path, tiny_expert, monkeypatch):
    from simdist.pipelines import simdist as recipe
    cfg = recipe.Config(**{**recipe.PRESETS["tiny"], "pretrain_updates": 6},
                        ensemble_size=2, threads=2)
    assert recipe.member_jobs(cfg) == (2, 1)  # two processes of one thread each
    assert recipe.member_jobs(recipe.Config(ensemble_size=2, threads=1)) == (1, 1)
    assert recipe.member_jobs(recipe.Config(ensemble_size=3, threads=4)) == (3, 1)
    assert recipe.member_jobs(recipe.Config(ensemble_size=2, ensemble_shared_encoder=True,
                                            threads=2)) == (1, 2)
    dataset = recipe.dataset_stage(cfg, tiny_expert, tmp_path / "dataset")["path"]
    logged = []
    monkeypatch.setattr(recipe.jobs, "log_metrics", lambda _, prefix, m, step: logged.append(
        (prefix, step)))
    side_by_side = recipe.pretrain_stage(cfg, dataset, tiny_expert, tmp_path / "jobs")
    assert logged == [("pretrain", s) for s in range(1, 7)] + [
        ("pretrain/member_1", s) for s in range(1, 7)]  # the workers' updates, once each
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # what each worker had
    try:
        in_turn = recipe.pretrain_stage(dataclasses.replace(cfg, ensemble_jobs=1), dataset,
                                        tiny_expert, tmp_path / "in_turn")
    finally:
        torch.set_num_threads(threads)
    for a, b in zip(side_by_side["members"], in_turn["members"], strict=True):
        a, b = (torch.load(x, weights_only=True) for x in (a, b))
        assert all(torch.equal(v, b[k]) for k, v in a.items())
    assert side_by_side["last"] == in_turn["last"]
    # a rerun finds both members trained: nothing is trained or logged again
    logged.clear()
    assert recipe.pretrain_stage(cfg, dataset, tiny_expert, tmp_path / "jobs")["last"] == \
        side_by_side["last"]
    assert logged == []


def test_members_finetuned_side_by_side_equal_those_finetuned_one_after_the_other(
        tmp_path, tiny_expert, monkeypatch):
    from simdist.pipelines import simdist as recipe
    cfg = recipe.Config(**{**recipe.PRESETS["tiny"], "finetune_updates": 5},
                        ensemble_size=2, threads=2, ensemble_jobs=1, expert=tiny_expert)
    assert recipe.member_jobs(cfg, 2) == (1, 2)
    assert recipe.member_jobs(recipe.Config(ensemble_size=2, threads=2,
                                            ensemble_shared_encoder=True), 2) == (2, 1)
    dataset = recipe.dataset_stage(cfg, tiny_expert, tmp_path / "dataset")["path"]
    pretrained = recipe.pretrain_stage(cfg, dataset, tiny_expert, tmp_path / "pretrain")
    logged = []
    monkeypatch.setattr(recipe.jobs, "log_metrics", lambda _, prefix, m, step: logged.append(
        (prefix, step)))
    side = recipe.round_stage(dataclasses.replace(cfg, ensemble_jobs=2), 0, pretrained,
                              tiny_expert, tmp_path / "side", None)
    assert sorted(logged) == sorted((f"round_1/{m}{tag}", s) for m in ("simdist", "whole")
                                    for tag in ("", "_member_1") for s in range(1, 6))
    shutil.copytree(tmp_path / "side" / "data", tmp_path / "turn" / "data")  # same data
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # what each worker had
    try:
        turn = recipe.round_stage(cfg, 0, pretrained, tiny_expert, tmp_path / "turn", None)
    finally:
        torch.set_num_threads(threads)
    for key in ("simdist_members", "whole_members"):
        for a, b in zip(side[key], turn[key], strict=True):
            a, b = (torch.load(x, weights_only=True) for x in (a, b))
            assert all(torch.equal(v, b[k]) for k, v in a.items()), key
    assert side["simdist_loss"] == turn["simdist_loss"] and side["target_steps"] == turn["target_steps"]


def test_the_planner_stages_side_by_side_give_the_figures_of_one_process(tmp_path, tiny_expert,
                                                                          capsys):
    from simdist.pipelines import simdist as recipe
    from simdist.utils import load_memmap
    assert recipe.stage_jobs(recipe.Config(threads=2), 3) == (2, 1)  # the 2-core default
    assert recipe.stage_jobs(recipe.Config(threads=2, jobs=1), 3) == (1, 2)
    assert recipe.stage_jobs(recipe.Config(threads=4, jobs=8), 2) == (2, 2)
    # one thread per process either way: the dataset's two shards, the zero-shot
    # evaluations, both rounds' collection batches (3 episodes, 2 at a time) and their
    # three methods side by side or in turn
    common = ("--preset", "tiny", "--expert", tiny_expert, "--no-record", "--threads", 1)
    side, turn = tmp_path / "side", tmp_path / "turn"
    for jobs, out in ((2, side), (1, turn)):
        proc = _run_here(*common, "--jobs", jobs, "--output-dir", out, capsys=capsys)
        assert proc.returncode == 0, proc.stderr
    a, b = (json.loads((out / "results.json").read_text()) for out in (side, turn))
    assert a["curves"] == b["curves"] and a["planner_zero_shot"] == b["planner_zero_shot"]
    datasets = [load_memmap(out / "stages" / "dataset" / "data" / "data") for out in (side, turn)]
    assert datasets[0].shape[0] == 4 and (datasets[0] == datasets[1]).all()
    for k in (1, 2):
        stages = [out / "stages" / f"round_{k}" for out in (side, turn)]
        first, second = (load_memmap(s / "data") for s in stages)
        assert (first == second).all()
        for name in ("simdist.pt", "whole.pt"):
            x, y = (torch.load(s / name, weights_only=True) for s in stages)
            assert all(torch.equal(v, y[key]) for key, v in x.items()), name
        logs = [sorted(p.relative_to(out) for p in (out / "logs" / "scalars" / f"round_{k}")
                       .rglob("*") if p.is_file()) for out in (side, turn)]
        assert logs[0] == logs[1] and any("sac" in str(p) for p in logs[0])
    # how many processes is not part of the results: the other count reuses every stage
    proc = _run_here(*common, "--jobs", 2, "--output-dir", turn, capsys=capsys)
    assert proc.returncode == 0 and "already done" in proc.stdout
    assert json.loads((turn / "results.json").read_text())["curves"] == b["curves"]


def test_a_shared_encoder_ensemble_differs_only_in_its_dynamics(tmp_path, tiny_expert, capsys):
    # (with the default encoder, which reads previous actions, through every stage)
    proc = _run_here("--preset", "tiny", "--expert", tiny_expert, "--ensemble-size", 2,
                     "--ensemble-shared-encoder", "--budgets-min", 0.02, "--no-record",
                     "--output-dir", tmp_path, "--threads", 1, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    pretrain = read_stage_record(tmp_path, "pretrain")["result"]
    round_1 = read_stage_record(tmp_path, "round_1")["result"]
    for paths in (pretrain["members"], round_1["simdist_members"]):
        first, second = (torch.load(m, weights_only=True) for m in paths)
        for k, v in first.items():  # one encoder and heads, two dynamics
            assert torch.equal(v, second[k]) != k.startswith("dynamics"), k
    assert "pretrain world model (member 1)" not in proc.stderr  # one joint pretraining


def test_several_seeds_run_into_their_own_folders_and_aggregate(tmp_path, tiny_expert, capsys):
    icy = '{"name": "icy_ramp", "friction": 0.4, "slope_deg": 6.0}'  # a custom target
    proc = _run_here("--preset", "tiny", "--expert", tiny_expert, "--seeds", 0, 1,
                     "--budgets-min", 0.02, "--target", icy, "--no-record", "--output-dir",
                     tmp_path, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    assert "Forward progress in icy_ramp" in proc.stdout
    per_seed = [json.loads((tmp_path / f"seed_{s}" / "results.json").read_text())
                for s in (0, 1)]
    assert [r["config"]["seed"] for r in per_seed] == [0, 1]
    merged = json.loads((tmp_path / "results.json").read_text())
    assert merged["seeds"] == [0, 1] and (tmp_path / "forward_progress.png").exists()
    for name, points in merged["curves"].items():
        if name == "minutes" or name in REFERENCES:
            continue
        for i, point in enumerate(points):
            fractions = [r["curves"][name][i]["fraction"] for r in per_seed]
            assert point["fraction"] == fractions[0] + fractions[1]  # pooled episodes
            speeds = [r["curves"][name][i]["command_mps"] for r in per_seed]
            assert point["command_mps"] == speeds[0] + speeds[1]  # in the same order
            assert point["seed_means"] == pytest.approx([sum(f) / len(f) for f in fractions])
            assert point["ci_fraction"][0] <= point["mean_fraction"] <= point["ci_fraction"][1]
            low, high = point["ci_fraction_seeds"]  # the interval that resamples the seeds
            assert low <= point["mean_fraction"] <= high
    assert "CI over seeds" in proc.stdout


@pytest.fixture(scope="module")
def uninterrupted_tiny_run(tmp_path_factory, tiny_expert):
    out = tmp_path_factory.mktemp("uninterrupted")
    proc = _run("--preset", "tiny", "--expert", tiny_expert, "--no-record", "--output-dir", out)
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.mark.parametrize("marker", ["stages/pretrain/training.pt", "stages/round_1/simdist.ckpt"])
def test_a_run_killed_inside_a_stage_resumes_to_the_uninterrupted_results(
        tmp_path, tiny_expert, uninterrupted_tiny_run, marker):
    """SIGKILL inside pretraining, and inside a finetuning round between its methods."""
    from tests.recipes.kill_helpers import run_killed_when

    args = ["--preset", "tiny", "--expert", str(tiny_expert), "--no-record", "--output-dir"]
    full = uninterrupted_tiny_run
    killed = tmp_path / "killed"
    assert run_killed_when([*RECIPE, *args, str(killed)], killed / marker)
    assert not (killed / "results.json").exists()
    resumed = _run(*args, killed)
    assert resumed.returncode == 0, resumed.stderr
    a = json.loads((full / "results.json").read_text())
    b = json.loads((killed / "results.json").read_text())
    assert b["curves"] == a["curves"] and b["pretrain"]["last"] == a["pretrain"]["last"]
    for name in ("simdist.pt", "whole.pt"):
        wa = torch.load(full / "stages" / "round_2" / name, weights_only=True)
        wb = torch.load(killed / "stages" / "round_2" / name, weights_only=True)
        assert all(torch.equal(wa[k], wb[k]) for k in wa), name


def test_a_copied_run_folder_resumes_from_its_own_files(tmp_path, tiny_expert,
                                                       uninterrupted_tiny_run):
    """A run folder moved elsewhere (the original gone) recomputes a stage from the
    copy's dataset and weights, to the original's figures; stage records store no
    absolute path into the folder."""
    original = uninterrupted_tiny_run
    copy = tmp_path / "copy"
    shutil.copytree(original, copy)
    for record in (copy / "stages").glob("*.json"):
        assert str(original) not in record.read_text(), record.name
    (copy / "stages" / "round_2.json").unlink()
    shutil.rmtree(copy / "stages" / "round_2")
    hidden = original.with_name(original.name + "_hidden")
    original.rename(hidden)  # as on another machine: only the copy exists
    try:
        proc = _run("--preset", "tiny", "--expert", tiny_expert, "--no-record",
                    "--output-dir", copy)
    finally:
        hidden.rename(original)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("already done") == 7  # every stage but round 2
    a = json.loads((original / "results.json").read_text())
    b = json.loads((copy / "results.json").read_text())
    assert b["curves"] == a["curves"]
    assert b["pretrain"]["path"] == "stages/pretrain/world_model.pt"  # relative to the folder


def test_a_finished_run_ships_as_a_named_agent_with_its_training_record(
        tmp_path, uninterrupted_tiny_run):
    """``python -m simdist.pipelines.simdist.shipping RUN``: the pretrained agent and how
    it was made, as ``simdist/quadruped`` is shipped."""
    from simdist.agents import SimDistAgent, load_agent
    from simdist.pipelines.simdist.shipping import main as ship_main
    ship_main([str(uninterrupted_tiny_run), "--dest", str(tmp_path)])
    agent = load_agent(tmp_path / "agent.pt")
    assert isinstance(agent, SimDistAgent) and agent.checkpoint_meta["task"] == "quadruped-flat"
    assert agent.planner_config.horizon == 3  # the tiny preset's planner travels with it
    record = json.loads((tmp_path / "training_record.json").read_text())
    config = json.loads((uninterrupted_tiny_run / "config.json").read_text())
    assert record["config"] == config and record["name"] == "simdist/quadruped"
    assert set(record["stage_seconds"]) >= {"dataset", "pretrain", "zero_shot"}
    assert record["dataset"]["transitions"] == 4 * 20
    assert "consistency" in " ".join(record["loss_curve"])  # from the run's CSV logs
    assert set(record["zero_shot"]) == {"sim", "slippery_slope"}
    assert "cpu" in record["machine"]


def test_the_frozen_parts_reference_is_the_prior_alone_and_the_simulator_ceiling(
        uninterrupted_tiny_run):
    """The prior-only planner acts as the prior's mean at the current latent; the ceiling
    plans with MuJoCo in the target over the first --ceiling-episodes worlds."""
    from tensordict import TensorDict
    from simdist.pipelines.simdist import (frozen_parts_stage, load_finished_run,
                                           planning_agent, prior_only)
    cfg, pretrained = load_finished_run(uninterrupted_tiny_run, ceiling_episodes=1,
                                        threads=1)
    agent = planning_agent(cfg, pretrained)
    model = agent.world_model
    obs = torch.randn(3, model.encoder.obs_dim)
    td = TensorDict({"observation": obs, "is_init": torch.ones(3, 1, dtype=torch.bool),
                     "simdist": {"previous_action": torch.zeros(3, 12)}}, [3])
    out = agent.policy(-torch.ones(12), torch.ones(12), prior_only(cfg.planner()))(td)
    latent = model.encode(out["next", "simdist", "history"])
    assert torch.allclose(out["action"], model.policy(latent).clamp(-1, 1), atol=1e-5)
    frozen = frozen_parts_stage(cfg, pretrained)
    assert len(frozen["prior_alone"]["fraction"]) == cfg.episodes
    assert len(frozen["simulator_ceiling"]["fraction"]) == 1
    assert frozen_parts_stage(dataclasses.replace(cfg, ceiling_episodes=0),
                              pretrained)["simulator_ceiling"] is None


@pytest.mark.parametrize("reset", [True, False])
def test_collecting_with_reset_upside_down_starts_a_fallen_world_again(reset, monkeypatch):
    from simdist.pipelines import simdist as recipe
    cfg = recipe.Config(model_size="tiny", model_latent_dim=0, episode_steps=12, slice_len=8,
                        model_horizon=3, collect_episodes=2, planner_horizon=3, planner_samples=16,
                        planner_iterations=1, planner_elites=4, planner_precision="none",
                        collect_reset_upside_down=reset, expert_targets=["sim"])
    agent = recipe.new_agent(cfg, obs_dim=89, action_dim=12)
    envs, make_env, make_policy = [], recipe.evaluation.locomotion_env, agent.policy
    for module in (recipe.evaluation, recipe.collection):
        monkeypatch.setattr(module, "locomotion_env",
                            lambda *a, **k: envs.append(make_env(*a, **k)) or envs[-1])

    def flipping_policy(*args, **kwargs):  # turns world 1 onto its back before step 5
        policy, calls = make_policy(*args, **kwargs), []

        def act(td):
            calls.append(None)
            if len(calls) == 5:
                physics = envs[-1].base_env.sims[1].physics
                physics.data.qpos[3:7] = [0.0, 1.0, 0.0, 0.0]
                physics.forward()
            return policy(td)
        return act

    monkeypatch.setattr(agent, "policy", flipping_policy)
    data = recipe.collect_target_data(cfg, agent, steps=24, seed=0)
    assert data.shape == (2, 12)
    starts = data["is_init"][1, :, 0].nonzero().flatten().tolist()
    assert starts == ([0, 5] if reset else [0])
    assert data["next", "terminated"][1, 4].item() is reset
    assert not data["is_init"][0, 1:].any()  # the upright world runs on


def test_the_reward_exponent_reaches_every_env_the_recipe_steps(monkeypatch):
    """``--reward-upright-power``: the dataset's config and the envs of collection,
    evaluation and planner evaluation all carry it (their rewards: tests/envs)."""
    from simdist.pipelines import simdist as recipe
    cfg = recipe.Config(model_size="tiny", model_latent_dim=0, episode_steps=8, slice_len=6,
                        model_horizon=3, collect_episodes=2, episodes=2, planner_horizon=3,
                        planner_samples=16, planner_iterations=1, planner_elites=4,
                        planner_precision="none", expert_targets=["sim"],
                        reward_upright_power=10.0)
    assert recipe.dataset_config(cfg).upright_power == 10.0
    assert recipe.dataset_config(recipe.Config()).upright_power == 1.0
    agent = recipe.new_agent(cfg, obs_dim=89, action_dim=12)
    powers, make_env = [], recipe.evaluation.locomotion_env

    def spy(*args, **kwargs):
        env = make_env(*args, **kwargs)
        powers.append({sim.task.upright_power for sim in env.base_env.sims})
        return env

    for module in (recipe.evaluation, recipe.collection):
        monkeypatch.setattr(module, "locomotion_env", spy)
    recipe.collect_target_data(cfg, agent, steps=16, seed=0)
    recipe.evaluate_planner(cfg, agent, "sim")
    recipe.evaluate(cfg, "sim", lambda td: td.set("action", torch.zeros(*td.batch_size, 12)))
    assert powers == [{10.0}] * 3


def test_a_runs_config_json_given_back_repeats_it_and_a_flag_changes_one_field(
        tmp_path, capsys):
    """``--config PATH``: a run's saved config.json (or its results.json) is the starting
    point, flags still override; a bad file is refused before any work, by name."""
    from simdist.pipelines.simdist import PRESETS, Config
    from simdist.utils.cli import parse_config
    saved = Config(**{**PRESETS["tiny"], "target": "foam", "episodes": 3,
                      "planner_proposal_commands": (0.25, 0.5)})
    path = tmp_path / "config.json"
    path.write_text(json.dumps(dataclasses.asdict(saved)))
    again, _ = parse_config(Config, PRESETS, ["--config", str(path)])
    assert again == saved
    changed, _ = parse_config(Config, PRESETS, ["--config", str(path), "--episodes", "5"])
    assert changed == dataclasses.replace(saved, episodes=5)
    (tmp_path / "results.json").write_text(json.dumps({"config": dataclasses.asdict(saved)}))
    assert parse_config(Config, PRESETS, ["--config", str(tmp_path / "results.json")])[0] == saved
    shown = " ".join(_run_here("--config", path, "--help", capsys=capsys).stdout.split())
    assert "--target STR" in shown and "(default: foam)" in shown
    path.write_text(json.dumps({**dataclasses.asdict(saved), "planner_samples": -1}))
    (tmp_path / "other.json").write_text(json.dumps({"episodes": 3, "no_such_field": 1}))
    (tmp_path / "broken.json").write_text("{")
    for file, message in ((tmp_path / "none.json", "config: no file at"),
                          (tmp_path / "other.json", "fields this program does not have: "
                                                    "['no_such_field']"),
                          (tmp_path / "broken.json", "is not a readable JSON file"),
                          (path, "planner_*: ")):
        proc = _run_here("--config", file, "--output-dir", tmp_path / "out", capsys=capsys)
        assert proc.returncode == 2 and message in " ".join(proc.stderr.split()), proc.stderr
        assert not (tmp_path / "out").exists()
