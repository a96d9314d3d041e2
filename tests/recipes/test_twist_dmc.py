"""The TWIST recipe end to end on its tiny preset: in a subprocess where the command line
itself is checked (worker processes, SIGKILL and resume), else in this process."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from simdist.agents import load_agent
from simdist.utils import read_run_json
from simdist.viz import entity_paths
from tests.in_process import run_script, script_path

ROOT = Path(__file__).resolve().parents[2]
RECIPE = [sys.executable, str(ROOT / "recipes" / "twist_dmc.py")]
METHODS = ["Oracle (state teacher)", "TWIST (student)", "TWIST w/o imagined alignment",
           "TWIST w/o action noise", "Dreamer from pixels + DR", "Dreamer from pixels, no DR",
           "Dreamer State Recon. + DR", "Asymmetric SAC + DR", "zero action (reference)",
           "random actions (reference)"]
READOUT_ROWS = ["Readout student (privileged state regression)",
                "Readout student w/o imagined alignment", "Readout student w/o action noise"]
# with --student-readout auto on cartpole-balance: the students' rows under their own name
READOUT_METHODS = [METHODS[0], *READOUT_ROWS, *METHODS[4:]]


def _run(*args, timeout=300):
    return subprocess.run([*RECIPE, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def _run_here(*args, capsys):
    """The recipe in this process (tests/in_process.py): for what fails or prints help
    before any work, and for runs whose results are not compared with a subprocess's."""
    return run_script(RECIPE[1], *args, capsys=capsys)


def _benchmark(name: str, *args, capsys):
    """``python experiments/<name>.py args`` (or ``benchmarks/``) in this process (see
    tests/in_process.py)."""
    return run_script(script_path(name), *args, capsys=capsys)


def test_recipe_runs_end_to_end_on_tiny_preset_and_resumes(tmp_path, capsys):
    # D with its images: the diagnosis below reads them (the default renders none here);
    # the readout student (not TWIST; the default is TWIST's CNN student, tested below)
    proc = _run("--preset", "tiny", "--output-dir", tmp_path, "--jobs", 2,
                "--teacher-pixels", "always", "--student-readout", "auto")
    assert proc.returncode == 0, proc.stderr
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["machine"]["logical_cpus"] >= 1  # what its timings were measured on
    task = results["results"]["cartpole-balance"]
    assert list(task) == READOUT_METHODS
    for name in READOUT_METHODS:
        # 2 held-out evaluation episodes of 10 agent steps (action repeat 2: <= 20 reward)
        assert len(task[name]["returns"]) == 2
        assert all(0 <= r <= 20 for r in task[name]["returns"])
    summary = results["summary"]["cartpole-balance"]
    assert summary["Oracle (state teacher)"]["normalised"] == 1.0
    run = results["runs"]["cartpole-balance_s0"]
    # the no-DR pixel Dreamer is also scored where it trained (its own scene), same worlds
    own = run["Dreamer from pixels, no DR"]["own_scene"]
    assert len(own["returns"]) == 2 and all(0 <= r <= 20 for r in own["returns"])
    assert "no DR on its own training scene" in proc.stdout
    assert "own_scene" not in run["Dreamer from pixels + DR"]
    assert run["teacher"]["updates"] == 2 * 2  # 40 steps = 2 episodes x (20 / 10) updates
    # the teacher's dataset D holds state and randomised pixels of the same steps
    episode = tmp_path / "stages" / "cartpole-balance_s0_teacher" / "episodes" / "00000"
    assert (episode / "next" / "pixels.memmap").exists()
    assert (episode / "next" / "state.memmap").exists()
    # only the students trained: the teacher checkpoint is what the oracle evaluated
    student = torch.load(tmp_path / "stages" / "cartpole-balance_s0_twist" / "student.pt",
                         weights_only=True)
    assert len(student["history"]) == 3 and "loss_imagined" in student["history"][-1]
    ablation = torch.load(tmp_path / "stages" / "cartpole-balance_s0_no_imagined" /
                          "student.pt", weights_only=True)
    assert "loss_imagined" not in ablation["history"][-1]
    assert "% of Oracle" in proc.stdout and READOUT_ROWS[0] in proc.stdout
    assert "TWIST (student)" not in proc.stdout  # never under TWIST's name
    # cartpole-balance has a committed readout: the student and its ablations see through it
    for name in READOUT_ROWS:
        assert run[name]["student"] == "readout" and run[name]["updates"] == 3
        assert run[name]["readout"].endswith("twist_readout/cartpole-balance.pt")
        # candidates (all of D / its domain runs / all of D from the last snapshot, here
        # the deployed one, so skipped), validated; the best one deployed
        candidates = run[name]["candidates"]
        assert list(candidates) == ["all", "domain", "last_all"]
        assert candidates["last_all"]["validation"] is None
        trained = [n for n in candidates if candidates[n]["validation"] is not None]
        best = max(trained, key=lambda n: (candidates[n]["validation"]["mean"],
                                           -trained.index(n)))
        assert run[name]["chosen"] == best and run[name]["states"] == best
    stages = tmp_path / "stages"
    every = json.loads((stages / "cartpole-balance_s0_twist_all.json").read_text())["result"]
    assert every["train_steps"] == 40  # exact positions: every step of D, domain or not
    assert len(every["validation"]["returns"]) == results["config"]["student_select_episodes"]
    chosen = run[READOUT_ROWS[0]]["chosen"]
    assert (stages / "cartpole-balance_s0_twist" / "student.pt").read_bytes() == (
        stages / f"cartpole-balance_s0_twist_{chosen}" / "student.pt").read_bytes()
    assert load_agent(tmp_path / "stages" / "cartpole-balance_s0_twist" /
                      "student_agent.pt").student.encoder.readout.out_dim == 3
    assert (tmp_path / "returns.png").stat().st_size > 0
    paths = entity_paths(str(tmp_path / "rerun_student.rrd"))
    assert "/student/view" in paths and "/latent/belief_distance" in paths
    assert any(p.startswith("/state/from_student_latent/") for p in paths)

    # every training loop logged its updates, from both worker processes
    scalars = tmp_path / "logs" / "scalars"
    assert list((scalars / "cartpole-balance_s0_twist_all").glob("*.csv"))
    assert list((scalars / "cartpole-balance_s0_twist_domain").glob("*.csv"))
    assert list((scalars / "cartpole-balance_s0_dreamer_dr").glob("*.csv"))
    # the State Recon. baseline stored the state of each step and learned to decode it
    recon = tmp_path / "stages" / "cartpole-balance_s0_dreamer_state_recon"
    assert (recon / "episodes" / "00000" / "next" / "state.memmap").exists()
    recon_agent = torch.load(recon / "dreamer_agent.pt", weights_only=True)
    assert recon_agent["config"]["reconstruct_key"] == "state"
    assert recon_agent["config"]["agent"]["standardise_reconstruction"] is True
    # the Asymmetric SAC baseline trained (2 episodes x 20 / 10 updates) from stored steps
    assert run["Asymmetric SAC + DR"]["updates"] == 4
    # the blind references (zero and uniform random actions) ran on the Oracle's seeds
    assert run["zero action (reference)"]["returns"] != run["random actions (reference)"]["returns"]
    sac_file = tmp_path / "stages" / "cartpole-balance_s0_asymmetric_sac" / "sac_agent.pt"
    assert load_agent(sac_file).checkpoint_meta["task"] == "cartpole-balance"
    assert (tmp_path / "stages" / "cartpole-balance_s0_asymmetric_sac" / "episodes" / "00001" /
            "next" / "state.memmap").exists()
    assert (tmp_path / "training_curves.png").stat().st_size > 0
    # stages ran in two processes (the teacher chain beside the pixel Dreamers)
    assert results["jobs"] == 2 and "wall time this run" in proc.stdout

    # reruns that do no work run in this process (tests/in_process.py)
    again = _run_here("--preset", "tiny", "--output-dir", tmp_path, "--jobs", 1,
                      "--teacher-pixels", "always", "--student-readout", "auto", capsys=capsys)
    assert again.returncode == 0, again.stderr
    # 10 stages per task-seed, 3 candidates for each of the 3 students, and the recording
    assert again.stdout.count("already done") == 20
    refused = _run_here("--preset", "tiny", "--output-dir", tmp_path, "--teacher-pixels",
                        "always", "--student-readout", "auto", "--eval-episodes", 3,
                        capsys=capsys)
    assert refused.returncode == 2 and "Traceback" not in refused.stderr
    assert refused.stderr.startswith("twist_dmc.py: error: ")
    assert "holds results of a different config (changed: ['eval_episodes'])" in refused.stderr
    # a baseline's own setting bars a folder whose baselines ran (not one without them:
    # tests/test_results_records.py)
    refused = _run_here("--preset", "tiny", "--output-dir", tmp_path, "--teacher-pixels",
                        "always", "--student-readout", "auto", "--no-state-recon-standardise",
                        capsys=capsys)
    assert "(changed: ['state_recon_standardise'])" in refused.stderr

    # the gap-diagnosis script runs on a finished recipe output
    # (the second probe: the perception options, re-rendered extra and held-out images)
    # (then H1/H2 of the perception study: camera-randomised training renders for the probe
    # and the student, and the standardised belief distance)
    for variant, extra in (("state", []), ("probe", []),
                           ("probe", ["--depth", "6", "--norm", "layer", "--input-norm", "image",
                                      "--shift", "4", "--extra-renders", "1",
                                      "--heldout-renders"]),
                           ("probe", ["--train-camera"]),
                           ("pixels", ["--train-camera", "--standardise-belief",
                                       "--action-weight", "2", "--name", "h",
                                       "--eval-scenes", "training"]),
                           ("probe", ["--arch", "keypoints"]),
                           ("probe", ["--frames", "2", "--shift", "2"]),
                           ("warm", ["--arch", "keypoints", "--warm-updates", "2"]),
                           ("positions", ["--slices", "3", "--init-rssm"]),
                           ("positions", ["--positions-noise", "0.05", "--name", "noisy"]),
                           # training data: balancing states only, the last episode of D
                           ("probe", ["--train-states", "balancing", "--recent-episodes", "1"]),
                           ("pixels", ["--train-states", "balancing", "--name", "bal"]),
                           # a frozen image -> positions readout trained on the final
                           # teacher's own episodes, read by a positions student
                           ("readout", ["--teacher-episodes", "2", "--recent-episodes", "2",
                                        "--warm-updates", "2", "--shift", "2", "--init-rssm",
                                        "--extra-renders", "1"]),
                           # the same teacher and states through another camera
                           ("probe", ["--render-camera", "1", "--heldout-renders"]),
                           ("pixels", ["--render-camera", "1", "--name", "cam"])):
        diag = _benchmark("twist_diagnosis", variant, "--preset", "tiny", "--outputs",
                          tmp_path, "--updates", "2", "--episodes", "1", "--batch", "4",
                          "--work", tmp_path / "diagnosis", *extra, capsys=capsys)
        assert diag.returncode == 0, diag.stderr
        line = json.loads(diag.stdout.strip().splitlines()[-1])
        assert line["variant"] == variant and line["updates"] == 2
        if variant == "warm":  # the warm start ran, then the student from the teacher's RSSM
            assert '"warm_updates": 2' in diag.stdout and len(line["latent_r2"]) == 5
            continue
        if "--render-camera" in extra:  # D re-rendered once from camera 1, then reused
            renders = tmp_path / "diagnosis" / "probe_renders"
            assert (renders / "camera1_D_all_s0.pt").exists()
            if variant == "probe":
                assert (renders / "heldout_camera1_s0.pt").exists()
                assert len(line["r2_heldout"]) == 5
            else:
                assert len(line["latent_r2"]) == 5 and "rendered" not in diag.stdout
            continue
        if "--train-states" in extra:  # runs of kept steps, each at least a slice long
            if variant == "pixels":
                assert "training slices from" in diag.stdout and len(line["latent_r2"]) == 5
            else:  # the training images come from D's last episode alone
                assert 0 < line["images_train"] <= recipe_cfg_episode_steps(tmp_path)
            continue
        if variant == "pixels":
            assert "mean" in line and len(line["latent_r2"]) == len(line["teacher_r2"]) == 5
            assert -1 <= line["action_corr"] <= 1 and line["action_rmse"] >= 0
            assert set(line["scenes"]) == {"training"} and "mean" in line["scenes"]["training"]
            assert line["action_weight"] == 2 and line["last"]["loss_action"] >= 0
            assert (tmp_path / "diagnosis" / "pixels_h" / "student.pt").exists()
            continue
        if variant == "readout":
            assert "recorded 2 episodes of the final teacher" in diag.stdout
            assert "training slices from 2 runs" in diag.stdout
            assert '"readout_updates": 2' in diag.stdout and len(line["latent_r2"]) == 5
            # the training states rendered once more: twice the training images
            assert '"images": 80,' in diag.stdout  # 2 final-teacher episodes of 20 steps
            # the readout is frozen: the trained student still holds its weights unchanged
            stage = tmp_path / "diagnosis" / "readout_lrNone"
            readout = torch.load(stage / "readout.pt", weights_only=True)
            student = torch.load(stage / "student.pt", weights_only=True)["state"]["twist"]
            weights = {k.removeprefix("encoder.0."): v
                       for k, v in student["student"].items() if k.startswith("encoder.0.")}
            assert readout.keys() == weights.keys()
            assert all(torch.equal(readout[k], weights[k]) for k in readout)
            continue
        if "--positions-noise" in extra:  # (x, cos, sin) read with white noise
            assert line["positions_noise"] == 0.05 and "mean" in line
            continue
        if variant == "positions":  # exact (x, cos, sin) only, the options recorded
            assert "mean" in line and line["slices"] == 3 and line["init_rssm"]
            assert "copied" in diag.stdout
            continue
        assert ("mean" in line) if variant == "state" else len(line["r2_test"]) == 5
        if variant == "probe" and "--frames" not in extra:  # balancing-state precision
            assert len(line["balancing_rmse_test"]) == len(line["balancing_std"]) == 5
            assert line["balancing_states"] >= 0
        if "--frames" in extra:  # each image read with the one before it
            assert line["frames"] == 2
        if "--heldout-renders" in extra:
            assert len(line["r2_heldout"]) == 5 and line["images_train"] % 2 == 0
    # the noisy-Oracle variant: without noise every group is the same rollout
    lines = _oracle_diagnosis(tmp_path, "noisy", "--noise", "0,0.5", capsys=capsys)
    assert [x["dimensions"] for x in lines] == ["all", "all", "sin(pole)", "sin(pole)",
                                                "pole angular velocity",
                                                "pole angular velocity"]
    assert len({x["mean"] for x in lines if x["noise_x_std"] == 0}) == 1
    noiseless = lines[0]["mean"]
    # the Oracle reading the state late: delay 0 is the Oracle itself
    lines = _oracle_diagnosis(tmp_path, "delayed", "--delays", "0,3", capsys=capsys)
    assert [x["delay_steps"] for x in lines] == [0, 3]
    assert lines[0]["mean"] == noiseless  # the same worlds and policy, the state on time
    # a student-specific actor by DAgger on the frozen student's latents: fitted on D,
    # then on D plus the student's own labelled episodes
    dagger = _benchmark("twist_dagger", "--outputs", tmp_path, "--iterations", "1",
                        "--episodes-per-iter", "2", "--updates", "3", "--episodes", "1",
                        capsys=capsys)
    assert dagger.returncode == 0, dagger.stderr
    lines = [json.loads(x) for x in dagger.stdout.splitlines() if x.startswith("{")]
    assert [x["iteration"] for x in lines] == [None, 0, 1]
    assert all(len(x["returns"]) == 1 for x in lines)  # per episode, for paired statistics
    assert lines[2]["steps"] > lines[1]["steps"] > 0 and lines[2]["collected_return"] >= 0
    # the labels are the teacher's actions on its own latent, not the student's
    assert all(x["mse"] >= 0 and x["mse_teacher_actor"] > 0 for x in lines[1:])
    # the run's own settings: tiny episodes (the default preset's are 500 steps)
    assert lines[2]["steps"] - lines[1]["steps"] == 2 * recipe_cfg_episode_steps(tmp_path)
    # one student per teacher snapshot, each validated, on the run's own (tiny) settings
    snap = _benchmark("twist_snapshot_students", "--outputs", tmp_path, "--work",
                      tmp_path / "snapshots", capsys=capsys)
    assert snap.returncode == 0, snap.stderr
    lines = [json.loads(x) for x in snap.stdout.splitlines() if x.startswith("{")]
    assert [x["snapshot"] for x in lines] == ["00000", "00001"]
    assert sum(x["deployed"] for x in lines) == 1
    assert all(x["student_validation"] >= 0 for x in lines)
    trained = torch.load(tmp_path / "snapshots" / "cartpole-balance_s0_twist_snapshot_00000" /
                         "student.pt", weights_only=True)
    assert len(trained["history"]) == 3  # the tiny preset's readout-student updates
    # the selected student re-deployed through the readout it was trained with: the
    # run's own figure to the bit (same weights, same worlds)
    readout = _recipe_module().readout_file(_recipe_module().saved_config(tmp_path),
                                            "cartpole-balance")
    redeploy = _benchmark("twist_redeploy_readout", "--outputs", tmp_path, "--seeds", "0",
                          "--readout", readout, capsys=capsys)
    assert redeploy.returncode == 0, redeploy.stderr
    line = json.loads([x for x in redeploy.stdout.splitlines() if x.startswith("{")][-1])
    assert line["returns"] == line["run_returns"] and line["chosen"] is not None


def _oracle_diagnosis(outputs, variant: str, *flags: str, capsys) -> list[dict]:
    """The JSON lines of a student-free twist_diagnosis variant on one tiny episode."""
    diag = _benchmark("twist_diagnosis", variant, "--preset", "tiny", "--outputs", outputs,
                      *flags, "--episodes", "1", capsys=capsys)
    assert diag.returncode == 0, diag.stderr
    return [json.loads(x) for x in diag.stdout.splitlines() if x.startswith("{")]


def recipe_cfg_episode_steps(outputs) -> int:
    return json.loads((outputs / "config.json").read_text())["episode_steps"]


def _recipe_module():
    from simdist.pipelines import twist
    return twist


def _set_everywhere(name: str, value) -> None:
    """Sets ``name`` in every module of :mod:`simdist.pipelines.twist` that imported it
    (each stage module calls the helper by the name it imported)."""
    for module_name, module in list(sys.modules.items()):
        if module_name.startswith("simdist.pipelines.twist.") and hasattr(module, name):
            setattr(module, name, value)


def test_train_camera_records_d_under_camera_randomisation(tmp_path):
    import dataclasses

    import pytest

    from simdist.envs import VisualRandomisation
    from simdist.pipelines import load_episodes
    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    assert recipe.Config().train_camera is False  # default: TWIST's training DR
    assert recipe.training_visual(recipe.Config()) == VisualRandomisation.training()
    visual = recipe.training_visual(recipe.Config(train_camera=True))
    evaluation = VisualRandomisation.heldout_evaluation()
    assert visual.camera and visual.every_step and visual.textures == "train"
    assert visual.camera_position_jitter == pytest.approx(1.5 * evaluation.camera_position_jitter)
    assert visual.camera_angle_jitter_deg == pytest.approx(1.5 * evaluation.camera_angle_jitter_deg)
    with pytest.raises(ConfigError, match="train_camera: must be true or false"):
        recipe.Config(train_camera="yes")

    cfg = dataclasses.replace(recipe.Config(), **recipe.PRESETS["tiny"], train_camera=True,
                              teacher_pixels="always", output_dir=str(tmp_path), jobs=1)
    seen = []
    original = recipe.teacher.control_env

    def spy(*args, **kwargs):
        seen.append(kwargs.get("visual"))
        return original(*args, **kwargs)
    _set_everywhere("control_env", spy)
    try:
        recipe.teacher_stage(cfg, "cartpole-balance", 0, tmp_path / "teacher")
    finally:
        _set_everywhere("control_env", original)
    assert visual in seen
    episodes = [e.to_tensordict() for e in load_episodes(tmp_path / "teacher")]
    pixels = torch.cat([e["next", "pixels"] for e in episodes])
    assert pixels.shape[-3:] == (64, 64, 3) and len(pixels) == cfg.env_steps


def test_teacher_stage_renders_d_only_when_a_student_reads_it(tmp_path):
    import dataclasses

    import pytest

    from simdist.pipelines import load_episodes
    from simdist.utils import load_checkpoint
    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    task = "cartpole-balance"
    assert recipe.Config().teacher_pixels == "auto"
    readout = recipe.Config(student_readout="auto")  # a readout student on exact positions
    assert not recipe.records_images(readout, task)  # exact positions: no images
    assert recipe.records_images(recipe.Config(), task)  # the default: TWIST's CNN student
    assert recipe.records_images(recipe.Config(student_readout="auto",
                                               readout_student_inputs="readings",
                                               readout_student_states=["domain"],
                                               student_last_teacher_states=[]), task)
    assert recipe.records_images(dataclasses.replace(readout, teacher_pixels="always"), task)
    with pytest.raises(ConfigError, match="teacher_pixels"):
        recipe.Config(teacher_pixels="never")
    tiny = dataclasses.replace(readout, **recipe.PRESETS["tiny"],
                               output_dir=str(tmp_path), jobs=1)
    without = recipe.teacher_stage(tiny, task, 0, tmp_path / "auto")
    with_images = recipe.teacher_stage(dataclasses.replace(tiny, teacher_pixels="always"),
                                       task, 0, tmp_path / "always")
    assert without["images"] is False and with_images["images"] is True
    bare = [e.to_tensordict() for e in load_episodes(tmp_path / "auto")]
    full = [e.to_tensordict() for e in load_episodes(tmp_path / "always")]
    assert ("next", "pixels") not in bare[0].keys(True) and ("next", "pixels") in full[0].keys(True)
    with pytest.raises(ValueError, match="holds no images"):  # e.g. the diagnosis's probe
        recipe.recorded_images(bare[0])
    assert torch.equal(recipe.recorded_images(full[0]), full[0]["next", "pixels"])
    # rendering draws nothing the physics or the teacher's training use: the same D, the
    # same selection and the same deployed teacher, to the bit
    assert all(torch.equal(a["next", "state"], b["next", "state"]) and
               torch.equal(a["action"], b["action"]) for a, b in zip(bare, full))
    assert ([c["mean"] for c in without["selection"]["candidates"]] ==
            [c["mean"] for c in with_images["selection"]["candidates"]])
    weights = [load_checkpoint(r["agent"])["weights"] for r in (without, with_images)]
    assert all(torch.equal(weights[0][part][k], v) for part in weights[1]
               for k, v in weights[1][part].items())


def test_a_candidate_of_the_last_snapshot_deploys_with_that_snapshots_actor(tmp_path):
    import dataclasses

    import pytest

    from simdist.agents import load_agent
    from simdist.utils import load_checkpoint

    recipe = _recipe_module()
    task = "cartpole-balance"
    assert recipe.Config().student_last_teacher_states == ["all"]
    readout = recipe.Config(student_readout="auto")
    assert recipe.student_candidates(recipe.Config(), task) == []  # TWIST: no candidates
    assert recipe.student_candidates(readout, task) == ["all", "domain", "last_all"]
    assert recipe.student_candidates(recipe.Config(student_readout="auto",
                                                   readout_student_states=["domain"]),
                                     task) == ["domain", "last_all"]
    cfg = dataclasses.replace(readout, **recipe.PRESETS["tiny"],
                              output_dir=str(tmp_path), jobs=1)
    teacher = recipe.teacher_stage(cfg, task, 0, tmp_path / "teacher")
    first, last = (c["snapshot"] for c in teacher["selection"]["candidates"])
    overrides = recipe.STUDENTS["twist"][1]
    # the last snapshot deployed: nothing else to distil from, the candidate is skipped
    deployed_last = {**teacher, "selection": {**teacher["selection"], "chosen": last}}
    assert recipe.last_snapshot(deployed_last) is None
    skipped = recipe.candidate_student_stage(cfg, task, 0, deployed_last, overrides, "all",
                                             tmp_path / "skipped", snapshot="last")
    assert skipped["validation"] is None and not (tmp_path / "skipped").exists()
    # the first snapshot deployed: the candidate learns from the last one's latents
    teacher = {**teacher, "selection": {**teacher["selection"], "chosen": first}}
    assert recipe.last_snapshot(teacher) == last
    best = recipe.candidate_student_stage(cfg, task, 0, teacher, overrides, "all",
                                          tmp_path / "all")
    other = recipe.candidate_student_stage(cfg, task, 0, teacher, overrides, "all",
                                           tmp_path / "last_all", snapshot="last")
    assert other["teacher_agent"] == str(tmp_path / "last_all" / "teacher_agent.pt")
    saved = load_checkpoint(other["teacher_agent"])["weights"]["actor"]
    snapped = load_checkpoint(last)["weights"]["actor"]
    assert all(torch.equal(saved[k], v) for k, v in snapped.items())
    candidates = {"all": best, "domain": skipped, "last_all": other}
    other["validation"] = {**other["validation"], "mean": best["validation"]["mean"] + 1}
    assert recipe.select_student(candidates) == "last_all"  # the skipped one never
    deployed = recipe.selected_student_stage(cfg, task, 0, teacher, overrides, candidates,
                                             tmp_path / "twist")
    assert deployed["chosen"] == "last_all" and deployed["teacher_agent"] == other["teacher_agent"]
    actor = load_agent(tmp_path / "twist" / "student_agent.pt").teacher.actor.state_dict()
    assert all(torch.equal(actor[k], v) for k, v in snapped.items())
    first_actor = load_checkpoint(first)["weights"]["actor"]
    assert not all(torch.equal(actor[k], v) for k, v in first_actor.items())
    with pytest.raises(RuntimeError, match="no trained candidate"):
        recipe.select_student({"domain": skipped})


def test_unknown_task_is_a_clear_error(tmp_path, capsys):
    proc = _run_here("--preset", "tiny", "--tasks", "cartpole-fly", "--output-dir", tmp_path,
                     capsys=capsys)
    assert proc.returncode != 0 and "unknown control-suite tasks" in proc.stderr


def test_an_unavailable_device_is_a_clear_error_before_any_work(tmp_path, capsys):
    device = "cuda:99"  # more CUDA devices than any machine here has
    proc = _run_here("--preset", "tiny", "--device", device, "--output-dir", tmp_path / "run",
                     capsys=capsys)
    assert proc.returncode == 2 and f"device '{device}' asked for" in proc.stderr
    assert not (tmp_path / "run").exists()


def test_help_lists_every_config_field_and_bad_values_fail_before_work(tmp_path, capsys):
    import dataclasses
    recipe = _recipe_module()
    text = " ".join(_run_here("--help", capsys=capsys).stdout.split())
    for f in dataclasses.fields(recipe.Config):
        assert "--" + f.name.replace("_", "-") in text, f.name
    for flags, message in ((["--jobs", "0"], "jobs: must be > 0"),
                           (["--student-norm", "batch"], "student_norm: must be one of"),
                           (["--seeds", "1", "1"], "seeds: need distinct seeds")):
        proc = _run_here(*flags, "--output-dir", tmp_path / "out", capsys=capsys)
        assert proc.returncode == 2 and message in " ".join(proc.stderr.replace("│", " ").split())
        assert not (tmp_path / "out").exists()


# the teacher chain alone, in one process, without the recording: run once for the module
TEACHER_CHAIN = ["--preset", "tiny", "--jobs", "1", "--no-baselines", "--no-record"]


@pytest.fixture(scope="module")
def teacher_chain_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("teacher_chain")
    proc = _run(*TEACHER_CHAIN, "--output-dir", out)
    assert proc.returncode == 0, proc.stderr
    return out


def test_a_run_killed_inside_the_online_teacher_resumes_to_the_uninterrupted_results(
        tmp_path, teacher_chain_run):
    from tests.recipes.kill_helpers import run_killed_when

    args = [*TEACHER_CHAIN, "--output-dir"]
    killed = tmp_path / "killed"
    # the teacher's second episode is on disk: killed between episodes, mid-stage
    marker = killed / "stages" / "cartpole-balance_s0_teacher" / "episodes" / "00001"
    assert run_killed_when([*RECIPE, *args, str(killed)], marker)
    resumed = _run(*args, killed)
    assert resumed.returncode == 0, resumed.stderr
    a = json.loads((teacher_chain_run / "results.json").read_text())
    b = json.loads((killed / "results.json").read_text())
    assert b["results"] == a["results"]
    assert b["runs"]["cartpole-balance_s0"]["teacher"]["episode_returns"] == \
        a["runs"]["cartpole-balance_s0"]["teacher"]["episode_returns"]


def test_teacher_budget_benchmark_resumes_and_reports_a_curve(tmp_path, capsys):
    """experiments/twist_teacher_budget.py: one Oracle figure per chunk, the run resumed
    between chunks (more updates at each point), the blind references beside it."""
    out = tmp_path / "budget"
    run = _benchmark("twist_teacher_budget", "--preset", "tiny", "--steps", "40", "--chunk",
                     "20", "--out", out, capsys=capsys)
    assert run.returncode == 0, run.stderr
    result = json.loads((out / "cartpole-balance.json").read_text())
    curve = result["curves"]["0"]
    assert [p["steps"] for p in curve] == [20, 40]
    assert 0 < curve[0]["updates"] < curve[1]["updates"]
    assert set(result["references"]["0"]) == {"zero", "uniform"}
    assert (out / "cartpole-balance_s0" / "training.pt").exists()
    # DreamerV3's return normalisation: its own run folder and result file
    run = _benchmark("twist_teacher_budget", "--preset", "tiny", "--steps", "20", "--chunk",
                     "20", "--out", out, "--return-normalisation", "percentile",
                     capsys=capsys)
    assert run.returncode == 0, run.stderr
    assert (out / "cartpole-balance_return_percentile.json").exists()
    state = torch.load(out / "cartpole-balance_s0_return_percentile" / "training.pt",
                       weights_only=True)["agent"]  # the online run's training checkpoint
    assert int(state["return_scale"]["count"]) > 0
    # a teacher whose state target is standardised: its own folder, and the statistics
    run = _benchmark("twist_teacher_budget", "--preset", "tiny", "--steps", "20", "--chunk",
                     "20", "--out", out, "--standardise", capsys=capsys)
    assert run.returncode == 0, run.stderr
    state = torch.load(out / "cartpole-balance_s0_standardised" / "training.pt",
                       weights_only=True)["agent"]
    assert int(state["reconstruction_standardiser"]["count"]) > 0


def test_pixel_dreamer_budget_benchmark_evaluates_both_scenes_and_resumes(tmp_path, capsys):
    """experiments/pixel_dreamer_budget.py: a pixel Dreamer at another update rate, scored
    on held-out scenes and dm_control's own, beside the blind references; a larger
    --steps continues the same run (more updates, the first episodes' returns kept)."""
    out = tmp_path / "budget"
    def run(steps):
        proc = _benchmark("pixel_dreamer_budget", "--preset", "tiny", "--steps", steps,
                          "--train-every", "10", "--out", out, capsys=capsys)
        assert proc.returncode == 0, proc.stderr
        return json.loads((out / "cartpole-balance_s0_dreamer_no_dr_every10" /
                           f"result_{steps}.json").read_text())
    first, second = run(40), run(80)
    assert first["updates"] == 4 and second["updates"] == 8
    assert second["training_returns"][:2] == first["training_returns"]
    for r in (first, second):
        assert set(r["references"]) == {"zero", "uniform"}
        assert len(r["heldout_scenes"]["returns"]) == len(r["own_scene"]["returns"]) == 2
    # the Asymmetric SAC baseline with stacked frames and an n-step critic
    proc = _benchmark("pixel_dreamer_budget", "--preset", "tiny", "--steps", 40, "--agent",
                      "sac", "--train-every", "10", "--frames", "2", "--n-step", "2",
                      "--tau", "0.05", "--batch", "4", "--out", out, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    sac = json.loads((out / "cartpole-balance_s0_asymmetric_sac_no_dr_every10_frames2_batch4"
                             "_n2_tau0.05" / "result_40.json").read_text())
    assert (sac["updates"], sac["frames"], sac["n_step"], sac["tau"]) == (4, 2, 2, 0.05)
    assert len(sac["own_scene"]["returns"]) == 2
    # Dreamer State Recon. without DR (its decoder reconstructs the state): its own folder
    proc = _benchmark("pixel_dreamer_budget", "--preset", "tiny", "--steps", 40, "--agent",
                      "state_recon", "--train-every", "10", "--out", out, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    folder = out / "cartpole-balance_s0_dreamer_state_recon_no_dr_every10"
    recon = json.loads((folder / "result_40.json").read_text())
    assert (recon["method"], recon["updates"]) == ("Dreamer State Recon., no DR", 4)
    assert len(recon["own_scene"]["returns"]) == 2
    saved = load_agent(folder / "dreamer_agent.pt")
    assert saved.reconstruct_key == "state" and recon["standardised_state_target"] is True
    assert int(saved.model_loss.reconstruction_standardiser.count) == 4  # one per update
    proc = _benchmark("pixel_dreamer_budget", "--preset", "tiny", "--steps", 40, "--agent",
                      "state_recon", "--raw-state-target", "--train-every", "10", "--out", out,
                      capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    raw = load_agent(out / "cartpole-balance_s0_dreamer_state_recon_no_dr_every10_raw_state" /
                     "dreamer_agent.pt")
    assert raw.model_loss.reconstruction_standardiser is None
    # a Dreamer with other slices per update, from another camera: its own folder
    proc = _benchmark("pixel_dreamer_budget", "--preset", "tiny", "--steps", 40,
                      "--train-every", "10", "--slices", "3", "--camera-id", "1", "--out", out,
                      capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    other = json.loads((out / "cartpole-balance_s0_dreamer_no_dr_every10_slices3_camera1" /
                        "result_40.json").read_text())
    assert (other["slices"], other["camera_id"], other["device"]) == (3, 1, "cpu")
    # DreamerV2's actor, explored by sampling, at another learning rate: its own folder
    proc = _benchmark("pixel_dreamer_budget", "--preset", "tiny", "--steps", 40,
                      "--train-every", "10", "--actor-distribution", "trunc_normal",
                      "--exploration", "sample", "--actor-lr", "8e-05",
                      "--return-normalisation", "percentile", "--actor-gradient", "reinforce",
                      "--reward-scale", "100", "--encoder", "keypoints", "--out", out,
                      capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    v2 = json.loads((out / "cartpole-balance_s0_dreamer_no_dr_every10_actor_trunc_normal"
                           "_explore_sample_lr8e-05_return_percentile_grad_reinforce_reward100"
                           "_encoder_keypoints" / "result_40.json").read_text())
    assert (v2["actor_distribution"], v2["exploration"], v2["actor_lr"],
            v2["return_normalisation"], v2["actor_gradient"], v2["reward_scale"],
            v2["encoder"]) == (
        "trunc_normal", "sample", 8e-5, "percentile", "reinforce", 100.0, "keypoints")
    assert first["actor_distribution"] == "tanh_normal" and first["exploration"] == "noise"
    assert first["return_normalisation"] == "none" and first["actor_gradient"] == "dynamics"
    assert first["reward_scale"] == 1.0 and first["encoder"] == "dreamer"
    for flag, value in (("--slices", "3"), ("--exploration", "sample"),
                        ("--return-normalisation", "percentile"),
                        ("--actor-gradient", "reinforce"), ("--reward-scale", "10"),
                        ("--encoder", "keypoints")):
        proc = _benchmark("pixel_dreamer_budget", "--preset", "tiny", "--agent", "sac",
                          flag, value, "--out", out, capsys=capsys)
        assert proc.returncode == 2 and "are the Dreamer's" in proc.stderr
    # its control: the same SAC with a state actor (experiments/state_sac_budget.py)
    proc = _benchmark("state_sac_budget", "--steps", 60, "--prefill", 20, "--train-every",
                      10, "--n-step", 2, "--eval-episodes", 1, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    state = json.loads(proc.stdout.strip().splitlines()[-1])
    assert state["updates"] == 4 and len(state["eval_returns"]) == 1
    assert len(state["eval_sampled_returns"]) == 1
    assert 0 <= state["eval_mean"] <= 1000 and 0 <= state["eval_sampled_mean"] <= 1000
    assert set(state["last_episode_mean_abs_action"]) == {"mean_action", "sampled_action"}


def test_no_baselines_runs_only_the_teacher_chain(teacher_chain_run):
    out = teacher_chain_run
    task = json.loads((out / "results.json").read_text())["results"]["cartpole-balance"]
    assert list(task) == [m for m in METHODS if "Dreamer" not in m and "SAC" not in m]
    assert not list((out / "stages").glob("*dreamer*"))
    assert not list((out / "stages").glob("*sac*"))


def test_a_runs_records_rebuild_its_table_and_take_more_seeds(tmp_path, teacher_chain_run,
                                                               capsys):
    """`python -m simdist.utils.records` keeps config and stage JSONs only: the recipe
    rebuilds the table from them without any weights, and a later run with more seeds
    into that folder (another day, another machine) adds its chains beside them."""
    from simdist.utils.records import copy_records

    copied = copy_records(teacher_chain_run, tmp_path)
    assert copied and all(p.suffix == ".json" for p in copied)
    assert not list(tmp_path.rglob("*.pt"))
    original = json.loads((teacher_chain_run / "results.json").read_text())
    rebuilt = _run_here(*TEACHER_CHAIN, "--output-dir", tmp_path, capsys=capsys)
    assert rebuilt.returncode == 0, rebuilt.stderr
    assert "stage cartpole-balance_s0_teacher: already done" in rebuilt.stdout
    assert json.loads((tmp_path / "results.json").read_text())["results"] == original["results"]
    # seeds (like tasks, students and baselines) pick rows: seed 1 joins seed 0's records
    more = _run_here(*TEACHER_CHAIN, "--seeds", 0, 1, "--students", "twist", "--output-dir",
                     tmp_path, capsys=capsys)
    assert more.returncode == 0, more.stderr
    assert "stage cartpole-balance_s0_twist: already done" in more.stdout
    assert "stage cartpole-balance_s1_teacher: already done" not in more.stdout
    task = json.loads((tmp_path / "results.json").read_text())["results"]["cartpole-balance"]
    twist = original["results"]["cartpole-balance"]["TWIST (student)"]
    assert len(task["TWIST (student)"]["seed_returns"]) == 2  # seeds 0 and 1, in that order
    assert task["TWIST (student)"]["seed_returns"][0] == twist["seed_returns"][0]


def test_students_picks_which_of_twist_and_its_ablations_run(tmp_path, capsys):
    import pytest

    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    assert recipe.Config().students == list(recipe.STUDENTS)
    for bad, match in ((["twist", "dagger"], "need distinct names"), ([], "need distinct"),
                       (["twist", "twist"], "need distinct"),
                       (["no_noise"], "recording shows the TWIST student")):
        with pytest.raises(ConfigError, match=match):
            recipe.Config(students=bad)
    args = ("--preset", "tiny", "--output-dir", tmp_path, "--jobs", 1, "--no-baselines",
            "--no-record")
    proc = _run(*args, "--students", "twist")
    assert proc.returncode == 0, proc.stderr
    results = json.loads((tmp_path / "results.json").read_text())
    task = results["results"]["cartpole-balance"]
    assert recipe.STUDENTS["twist"][0] in task
    # the default student is TWIST's: a CNN trained by Eq. 3 and Eq. 4 alone, no readout,
    # no candidates chosen on privileged state
    twist = results["runs"]["cartpole-balance_s0"][recipe.TWIST]
    assert twist["student"] == "cnn" and twist["readout"] is None and "chosen" not in twist
    assert not list((tmp_path / "stages").glob("*_twist_*"))
    assert not any("w/o" in name for name in task)
    assert not list((tmp_path / "stages").glob("*no_noise*"))
    # a later run adds an ablation into the same folder: students pick rows, not figures
    proc = _run_here(*args, "--students", "twist", "no_noise", capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    assert "stage cartpole-balance_s0_twist: already done" in proc.stdout
    task = json.loads((tmp_path / "results.json").read_text())["results"]["cartpole-balance"]
    assert recipe.STUDENTS["no_noise"][0] in task


def test_camera_id_renders_every_pixel_stage_from_that_camera(tmp_path):
    import dataclasses

    import pytest

    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    assert recipe.Config().camera_id is None  # default: the task's camera (TWIST's protocol)
    with pytest.raises(ConfigError, match="camera_id: must be >= 0"):
        recipe.Config(camera_id=-1)
    cfg = dataclasses.replace(recipe.Config(), **recipe.PRESETS["tiny"], camera_id=1,
                              output_dir=str(tmp_path), jobs=1)
    cameras = []
    original_env, original_eval = recipe.teacher.control_env, recipe.teacher.evaluate_returns

    def env_spy(*args, **kwargs):
        if kwargs.get("pixels"):
            cameras.append(("env", kwargs.get("camera_id")))
        return original_env(*args, **kwargs)

    def eval_spy(*args, **kwargs):
        if kwargs.get("pixels", args[6] if len(args) > 6 else False):  # not the state
            cameras.append(("evaluate", kwargs.get("camera_id")))  # teacher's selection
        return original_eval(*args, **kwargs)
    _set_everywhere("control_env", env_spy)
    _set_everywhere("evaluate_returns", eval_spy)
    try:
        teacher = recipe.teacher_stage(cfg, "cartpole-balance", 0, tmp_path / "teacher")
        recipe.student_stage(cfg, "cartpole-balance", 0, teacher, {}, tmp_path / "student")
        recipe.pixel_dreamer_stage(cfg, "cartpole-balance", 0, None, tmp_path / "dreamer")
    finally:
        _set_everywhere("control_env", original_env)
        _set_everywhere("evaluate_returns", original_eval)
    # D, the student's evaluation, the Dreamer's training env and its two evaluations
    # (held-out scenes, then its own training scene: it trained without DR)
    assert [kind for kind, _ in cameras] == ["env", "evaluate", "env", "evaluate", "evaluate"]
    assert all(camera == 1 for _, camera in cameras), cameras
    # the saved files record the camera, so recipes/evaluate.py sees what the recipe saw
    from simdist.agents import load_agent
    for saved in ("student/student_agent.pt", "dreamer/dreamer_agent.pt"):
        assert load_agent(tmp_path / saved).checkpoint_meta["camera_id"] == 1
    # a camera the task's model does not have is refused by name before any work
    with pytest.raises(ValueError, match="camera_id 7 does not exist in 'cartpole-balance'"):
        recipe.teacher.control_env("cartpole-balance", 0, pixels=True, camera_id=7)


def test_teacher_actor_noise_reaches_only_the_teachers_actor_critic():
    import pytest

    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    assert recipe.Config().teacher_actor_noise == 0.0  # TWIST's teacher by default
    with pytest.raises(ConfigError, match="teacher_actor_noise"):
        recipe.Config(teacher_actor_noise=-0.1)
    cfg = recipe.Config(**recipe.PRESETS["tiny"], teacher_actor_noise=0.3)
    assert recipe.teacher_agent(cfg, "cartpole-balance").behaviour_loss.actor_input_noise == 0.3
    # the pixel Dreamers are baselines, not teachers: they keep DreamerV2's actor
    assert cfg.dreamer().actor_input_noise == 0.0


def test_teacher_selection_deploys_the_best_validated_snapshot(teacher_chain_run):
    import pytest

    from simdist.utils import load_checkpoint
    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    with pytest.raises(ConfigError, match="at most that many snapshots"):
        recipe.Config(**{**recipe.PRESETS["tiny"], "teacher_snapshots": 3})  # 2 episodes
    with pytest.raises(ConfigError, match="teacher_select_episodes"):
        recipe.Config(teacher_select_episodes=0)
    # the teacher chain's run (the tiny preset keeps 2 snapshots); its paths are stored
    # relative to the run folder, read_run_json puts them under it
    results = read_run_json(teacher_chain_run / "results.json")
    run = results["runs"]["cartpole-balance_s0"]
    teacher = run["teacher"]
    candidates = teacher["selection"]["candidates"]
    best = max(candidates, key=lambda c: c["mean"])
    assert len(candidates) == 2 and teacher["selection"]["chosen"] == best["snapshot"]
    # the chosen snapshot's validation figure is reproduced by evaluating it again
    cfg = recipe.Config(**recipe.PRESETS["tiny"])
    agent = recipe.load_teacher(cfg, "cartpole-balance", teacher)
    again = recipe.teacher.evaluate_returns(
        "cartpole-balance", agent.policy(explore=False), agent.make_primer(),
        recipe.teacher.stage_seed(0, "cartpole-balance/teacher_selection"), cfg.teacher_select_episodes,
        cfg.eval_steps, pixels=False, visual=None)
    assert again["mean"] == pytest.approx(best["mean"], rel=1e-5)
    # the deployed teacher file (what the Oracle and the students load) is that snapshot
    chosen = load_checkpoint(best["snapshot"])["weights"]["actor"]
    assert all(torch.equal(agent.actor.state_dict()[k], v) for k, v in chosen.items())
    oracle = recipe.evaluate(cfg, "cartpole-balance", 0, agent.policy(explore=False),
                             agent.make_primer(), pixels=False)
    assert oracle["returns"] == pytest.approx(run["Oracle (state teacher)"]["returns"])


def test_teacher_selection_prefers_an_earlier_snapshot_that_scores_higher(tmp_path):
    import pytest

    from simdist.utils import save_atomic

    recipe = _recipe_module()
    cfg = recipe.Config(**recipe.PRESETS["tiny"])
    calm = recipe.teacher_agent(cfg, "cartpole-balance")
    save_atomic({"weights": calm.weights()}, tmp_path / "00000.pt")
    # a later snapshot whose actor always pushes at full force pays the control cost
    pushing = recipe.teacher_agent(cfg, "cartpole-balance")
    pushing.load_weights(calm.weights())
    last_bias = [k for k in pushing.actor.state_dict() if k.endswith("bias")][-1]
    with torch.no_grad():
        pushing.actor.state_dict()[last_bias].fill_(10.0)
    save_atomic({"weights": pushing.weights()}, tmp_path / "00001.pt")
    paths = [tmp_path / "00000.pt", tmp_path / "00001.pt"]
    out = recipe.select_teacher(cfg, "cartpole-balance", 0, paths)
    calm_mean, pushing_mean = (c["mean"] for c in out["candidates"])
    assert calm_mean > pushing_mean and out["chosen"] == str(paths[0])
    with pytest.raises(RuntimeError, match="kept no snapshot"):
        recipe.select_teacher(cfg, "cartpole-balance", 0, [])


def test_student_readout_picks_the_committed_readout_only_where_it_fits(tmp_path):
    import dataclasses
    import json

    import pytest

    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    committed = recipe.READOUT_DIR / "cartpole-balance.pt"
    assert recipe.readout_file(recipe.Config(), "cartpole-balance") is None  # TWIST's CNN
    cfg = recipe.Config(student_readout="auto")
    assert recipe.readout_file(cfg, "cartpole-balance") == committed
    assert recipe.readout_file(cfg, "cheetah-run") is None  # no readout: the CNN student
    # fitted from the task's camera: a run from another camera gets the CNN student
    assert recipe.readout_file(dataclasses.replace(cfg, camera_id=1), "cartpole-balance") is None
    none = dataclasses.replace(cfg, student_readout="none")
    assert recipe.readout_file(none, "cartpole-balance") is None
    # an explicit file fitted for another task is refused, not silently used
    meta = json.loads(committed.with_suffix(".json").read_text())
    other = tmp_path / "other.pt"
    recipe.readout.StateReadout.load(committed).save(other, {**meta, "task": "cheetah-run"})
    explicit = dataclasses.replace(cfg, student_readout=str(other))
    assert recipe.readout_file(explicit, "cheetah-run") == other
    with pytest.raises(ValueError, match="fitted for task 'cheetah-run'"):
        recipe.readout_file(explicit, "cartpole-balance")
    with pytest.raises(ConfigError, match="student_readout: must be 'auto', 'none' or a readout"):
        recipe.Config(student_readout=str(tmp_path / "absent.pt"))


def test_readout_training_runs_keep_long_runs_inside_the_domain_as_readings():
    import math

    from tensordict import TensorDict

    recipe = _recipe_module()
    readout = recipe.readout.StateReadout.load(recipe.READOUT_DIR / "cartpole-balance.pt")
    # 12 steps: upright for 5, the pole past 0.3 rad for 2, upright for 3, cart at 1.5 m
    # for 2; runs of >= 3 steps: steps 0-4 and 7-9
    angle = torch.tensor([0.0] * 5 + [0.5] * 2 + [0.1] * 3 + [0.0] * 2)
    x = torch.tensor([0.0] * 10 + [1.5] * 2)
    state = torch.stack([x, angle.cos(), angle.sin(), torch.zeros(12), torch.zeros(12)], -1)
    pixels = torch.randint(0, 256, (12, 64, 64, 3), dtype=torch.uint8)
    episode = TensorDict({"action": torch.arange(12.0).unsqueeze(-1),
                          "next": {"state": state, "pixels": pixels}}, [12])
    runs = recipe.readout_training_runs([episode], readout, min_len=3)
    assert [r["action"].flatten().tolist() for r in runs] == [[0, 1, 2, 3, 4], [7, 8, 9]]
    assert torch.allclose(runs[1]["next", "pixels"], readout.read(pixels[7:10]))
    assert episode["next", "pixels"].dtype == torch.uint8  # the caller's data is untouched
    assert math.isclose(recipe.readout_training_runs([episode], readout, 6).__len__(), 0)
    # exact: the same runs, reading the recorded values of the readout's dimensions
    exact = recipe.readout_training_runs([episode], readout, min_len=3, exact=True)
    assert [r["action"].flatten().tolist() for r in exact] == [[0, 1, 2, 3, 4], [7, 8, 9]]
    assert torch.equal(exact[1]["next", "pixels"], state[7:10, :3])
    assert episode["next", "pixels"].dtype == torch.uint8
    # everywhere: the whole episode, its out-of-domain steps included, as exact values
    whole = recipe.readout_training_runs([episode, episode[:2]], readout, min_len=3,
                                         exact=True, everywhere=True)
    assert len(whole) == 1 and torch.equal(whole[0]["action"], episode["action"])
    assert torch.equal(whole[0]["next", "pixels"], state[:, :3])
    assert episode["next", "pixels"].dtype == torch.uint8
    import pytest

    with pytest.raises(ValueError, match="needs exact=True"):
        recipe.readout_training_runs([episode], readout, min_len=3, everywhere=True)


def test_readout_student_states_config_and_selection():
    import pytest

    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    assert recipe.Config().readout_student_states == ["all", "domain"]  # two candidates
    assert recipe.Config(readout_student_states=["domain"]).readout_student_states == ["domain"]
    for bad in (["everything"], [], ["all", "all"], ["all", "domain", "all"]):
        with pytest.raises(ConfigError, match="readout_student_states: must be one or two"):
            recipe.Config(readout_student_states=bad)
    with pytest.raises(ConfigError, match="readout_student_states: 'all' needs"):
        recipe.Config(readout_student_inputs="readings")
    with pytest.raises(ConfigError, match="student_select_episodes"):
        recipe.Config(student_select_episodes=0)
    # one entry, or no readout (the CNN student): a single student, no candidate stages
    assert recipe.student_candidates(recipe.Config(student_readout="auto"),
                                     "cartpole-balance") == ["all", "domain", "last_all"]
    assert recipe.student_candidates(recipe.Config(student_readout="auto",
                                                   readout_student_states=["all"],
                                                   student_last_teacher_states=[]),
                                     "cartpole-balance") == []
    for bad in (["everything"], ["all", "all"]):
        with pytest.raises(ConfigError, match="student_last_teacher_states: must be distinct"):
            recipe.Config(student_last_teacher_states=bad)
    with pytest.raises(ConfigError, match="student_last_teacher_states: 'all' needs"):
        recipe.Config(readout_student_inputs="readings", readout_student_states=["domain"])
    assert recipe.student_candidates(recipe.Config(student_readout="none"),
                                     "cartpole-balance") == []
    # the best validation mean wins; a tie goes to the earlier candidate
    score = {"all": {"validation": {"mean": 700.0}}, "domain": {"validation": {"mean": 900.0}}}
    assert recipe.select_student(score) == "domain"
    score["domain"]["validation"]["mean"] = 700.0
    assert recipe.select_student(score) == "all"


def test_exact_positions_feeds_the_student_the_readouts_dimensions_of_the_state():
    from tensordict import TensorDict

    from simdist.agents import DreamerAgent, DreamerConfig, TwistStudent
    from simdist.modules import DreamerWorldModel, PixelEncoder, StateReadout

    recipe = _recipe_module()
    teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size="tiny"))
    readout = StateReadout(PixelEncoder(4), state_dim=5, dims=[0, 2])
    twist = TwistStudent(teacher, DreamerWorldModel.readout_student(readout, 1, "tiny"))
    seen = []
    twist.student.encoder.register_forward_hook(lambda m, args, out: seen.append(args[0]))
    state = torch.randn(3, 5)
    td = recipe.ExactPositions(twist)(
        TensorDict({"state": state, "is_init": torch.ones(3, 1, dtype=torch.bool)}, [3]))
    assert torch.equal(seen[0], state[:, [0, 2]])  # exact values, no render, no readout
    assert td["action"].shape == (3, 1) and "positions" not in td.keys()


def test_readout_student_inputs_readings_trains_on_the_readouts_readings_of_d(tmp_path, capsys):
    import pytest

    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    assert recipe.Config().readout_student_inputs == "positions"  # D's exact values
    with pytest.raises(ConfigError, match="readout_student_inputs"):
        recipe.Config(readout_student_inputs="state")
    proc = _run_here("--preset", "tiny", "--output-dir", tmp_path, "--jobs", 1,
                     "--no-baselines", "--no-record", "--students", "twist",
                     "--student-readout", "auto",
                     "--readout-student-inputs", "readings", "--readout-student-states",
                     "domain", "--student-last-teacher-states", "domain", capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    twist = json.loads((tmp_path / "results.json").read_text())["runs"]["cartpole-balance_s0"][
        recipe.READOUT_STUDENTS["twist"]]
    assert twist["student"] == "readout" and len(twist["returns"]) == 2  # evaluated on pixels


def test_committed_cartpole_readout_reads_rendered_poses():
    """The committed artefact, on fresh renders under TWIST's training randomisation:
    fitted to ~.01 on the pole's sine and ~.04 m on the cart (its .json), so it must read
    these poses to a few hundredths."""
    readout = _committed_readout()
    poses = torch.tensor([[0.0, 0.0], [0.5, 0.2], [-0.7, -0.25], [0.3, -0.1], [-0.2, 0.1],
                          [0.8, 0.05]])
    images = _render_poses(poses, seed=3)
    readings = readout.read(images)
    assert (readings[:, 0] - poses[:, 0]).abs().max() < 0.15
    assert (readings[:, 2] - poses[:, 1].sin()).abs().max() < 0.05
    # the balancing region is the precise readout's: its fallback never answers there
    assert torch.equal(readings, readout.without_fallback().read(images))


def test_committed_cartpole_readout_does_not_read_a_fallen_pole_as_upright():
    """Outside the balancing region the committed readout's coarse fallback answers
    (docs/methods.md, section 2.7 item 5): a pole at or below the horizontal must not be
    read as upright, which the precise readout alone may do."""
    readout = _committed_readout()
    images = _render_poses(torch.tensor([[0.0, 3.1], [0.3, -3.0], [-0.4, 2.0], [0.2, -1.9],
                                         [0.0, 2.6], [-0.2, -2.5]]), seed=4)
    readings = readout.read(images)
    assert (readings[:, 1] < 0.5).all(), readings  # cos: well below upright
    alone = readout.without_fallback().read(images)
    assert not readout.gated(alone, readout.fallback.read(images)).any()


def _committed_readout():
    recipe = _recipe_module()
    return recipe.readout.StateReadout.load(recipe.READOUT_DIR / "cartpole-balance.pt")


def _render_poses(poses: torch.Tensor, seed: int) -> torch.Tensor:
    """``[N, 64, 64, 3]`` renders of (cart x, pole angle) rows under TWIST's training
    randomisation."""
    from simdist.envs import VisualRandomisation
    from simdist.pipelines import control_env

    env = control_env("cartpole-balance", seed, pixels=True,
                      visual=VisualRandomisation.training())
    try:
        sim = env.base_env.sims[0]
        return torch.stack([torch.from_numpy(sim.render_configuration(q))
                            for q in poses.numpy()])
    finally:
        env.close()


def test_reading_noise_is_drawn_in_updates_at_the_readouts_spread():
    import dataclasses

    from tensordict import TensorDict

    from simdist.agents import DreamerAgent

    recipe = _recipe_module()
    cfg = dataclasses.replace(recipe.Config(), model_size="tiny",
                              readout_student_reading_noise=0.1)
    readout = recipe.readout.StateReadout.load(recipe.READOUT_DIR / "cartpole-balance.pt")
    teacher = recipe.teacher_agent(cfg, "cartpole-balance")
    assert isinstance(teacher, DreamerAgent)
    twist = recipe.new_readout_student(cfg, "cartpole-balance", teacher, readout, {})
    assert isinstance(twist.augment, recipe.readout.ReadingNoise)
    assert torch.allclose(twist.augment.std, 0.1 * readout.std)
    readings = torch.zeros(2, 4, 3)
    batch = TensorDict({"action": torch.zeros(2, 4, 1),
                        "is_init": torch.zeros(2, 4, 1, dtype=torch.bool),
                        "next": {"state": torch.zeros(2, 4, 5), "pixels": readings}}, [2, 4])
    seen = []
    twist.distillation.register_forward_pre_hook(
        lambda module, args: seen.append(args[0]["next", "pixels"].clone()))
    assert "loss_distillation" in twist.update(batch)
    assert not torch.equal(seen[0], readings)  # the student trained on noisy readings
    assert torch.equal(batch["next", "pixels"], readings)  # the caller's batch untouched
    quiet = recipe.new_readout_student(dataclasses.replace(cfg, readout_student_reading_noise=0.0),
                                       "cartpole-balance", teacher, readout, {})
    assert quiet.augment is None


def test_a_folder_from_before_the_sac_critic_options_reads_as_what_it_ran(tmp_path):
    """Folders made before ``sac_frames``/``sac_n_step``/``sac_tau`` existed ran one image,
    1-step returns and tau 0.005: they read so, and the new defaults (3, 3, 0.02) are
    refused there, not resumed, unless the run has no baselines (no stage reads them)."""
    import dataclasses

    from simdist.utils.stages import RunFolderError

    recipe = _recipe_module()
    old = dataclasses.asdict(recipe.Config(output_dir=str(tmp_path)))
    del old["sac_frames"], old["sac_n_step"], old["sac_tau"]
    (tmp_path / "config.json").write_text(json.dumps(old))
    saved = recipe.saved_config(tmp_path)
    assert (saved.sac_frames, saved.sac_n_step, saved.sac_tau) == (1, 1, 0.005)
    now = recipe.Config(output_dir=str(tmp_path))
    assert (now.sac_frames, now.sac_n_step, now.sac_tau) == (3, 3, 0.02)
    with pytest.raises(RunFolderError, match="sac_frames', 'sac_n_step', 'sac_tau"):
        recipe.stage_runner(now)
    recipe.stage_runner(dataclasses.replace(saved, output_dir=str(tmp_path))).close()
    recipe.stage_runner(dataclasses.replace(now, baselines=False)).close()


def test_pixel_dreamers_take_their_own_actor_form_and_the_teacher_keeps_its_own(tmp_path):
    from simdist.utils.cli import ConfigError

    recipe = _recipe_module()
    for field, bad in (("pixel_actor_distribution", "beta"), ("pixel_exploration", "greedy"),
                       ("return_normalisation", "zscore"), ("pixel_actor_gradient", "pathwise"),
                       ("pixel_encoder", "resnet")):
        with pytest.raises(ConfigError, match=f"unknown {field.removeprefix('pixel_')}"):
            recipe.Config(**{field: bad})
    with pytest.raises(ConfigError, match="reward_scale must be > 0"):
        recipe.Config(pixel_reward_scale=0.0)
    # return normalisation is the Dreamers' together: the teacher's and the pixel ones'
    both = recipe.Config(return_normalisation="percentile")
    assert both.dreamer().return_normalisation == "percentile"
    assert both.pixel_dreamer().return_normalisation == "percentile"
    cfg = recipe.Config(**{**recipe.PRESETS["tiny"], "output_dir": str(tmp_path),
                           "pixel_actor_distribution": "trunc_normal",
                           "pixel_exploration": "sample",
                           "pixel_actor_gradient": "reinforce", "pixel_reward_scale": 10.0,
                           "pixel_encoder": "keypoints"})
    assert (cfg.dreamer().actor_distribution, cfg.dreamer().exploration,
            cfg.dreamer().actor_gradient, cfg.dreamer().reward_scale) == (
        "tanh_normal", "noise", "dynamics", 1.0)
    assert cfg.pixel_dreamer().reward_scale == 10.0 and cfg.dreamer().encoder == "dreamer"
    result = recipe.pixel_dreamer_stage(cfg, "cartpole-balance", 0, None, tmp_path / "px")
    agent = load_agent(result["agent"])
    assert (agent.config.actor_distribution, agent.config.exploration,
            agent.config.actor_gradient) == ("trunc_normal", "sample", "reinforce")
    assert agent.behaviour_loss.actor_gradient == "reinforce"
    assert agent.config.reward_scale == agent.model_loss.reward_scale == 10.0
    assert agent.actor.kind == "trunc_normal"
    # the saved agent rebuilds its keypoint encoder from its own description
    assert agent.config.encoder == agent.world_model.encoder.arch == "keypoints"


def test_dreamer_latent_probe_reads_saved_and_training_checkpoints(tmp_path, capsys):
    """experiments/dreamer_latent_probe.py: R^2 per state dimension of a trained and a
    re-drawn pixel Dreamer, from a saved agent or an online run's training checkpoint;
    a state Dreamer is refused."""
    from simdist.agents import DreamerAgent
    from simdist.utils import save_atomic

    recipe = _recipe_module()
    cfg = recipe.Config(**recipe.PRESETS["tiny"])
    agent = DreamerAgent.for_pixels(1, cfg.pixel_dreamer())
    saved = agent.save(tmp_path / "dreamer_agent.pt")
    save_atomic({"agent": agent.state_dict()}, tmp_path / "training.pt")
    for args in (("--agent", saved), ("--training", "--preset", "tiny", "--agent",
                                      tmp_path / "training.pt")):
        out = tmp_path / "probe.json"
        proc = _benchmark("dreamer_latent_probe", *args, "--episodes", 2, "--steps", 6,
                          "--horizon", 4, "--json", out, capsys=capsys)
        assert proc.returncode == 0, proc.stderr
        result = json.loads(out.read_text())
        assert len(result["r2_trained"]) == len(result["r2_untrained"]) == 5
        assert all(r <= 1 for r in result["r2_trained"] + result["r2_untrained"])
        # the simulator's side of the action response: cartpole pays up to 2 per agent
        # step (two control steps), and holding a full push costs its control term
        response = result["action_response"]
        assert set(response) == {"-1", "+0", "+1"}
        assert all(0 < r["true"] <= 2 * 4 for r in response.values())
        assert response["+0"]["true"] > max(response["-1"]["true"], response["+1"]["true"])
        assert all(isinstance(r["imagined"], float) for r in response.values())
    state = DreamerAgent.for_state(5, 1, cfg.dreamer()).save(tmp_path / "state.pt")
    proc = _benchmark("dreamer_latent_probe", "--agent", state, capsys=capsys)
    assert proc.returncode == 2 and "is not a pixel Dreamer agent" in proc.stderr


def test_dreamer_latent_probe_fits_a_world_model_alone_on_random_data(tmp_path, capsys):
    """--fit-random: a fresh pixel Dreamer's world model (here with the keypoint encoder)
    trains alone on random episodes and is probed after each requested update count;
    it cannot be mixed with an agent to read, and needs a positive budget."""
    out = tmp_path / "fit.json"
    proc = _benchmark("dreamer_latent_probe", "--fit-random", 2, "--updates", 2, 1,
                      "--preset", "tiny", "--encoder", "keypoints", "--episodes", 2,
                      "--steps", 6, "--horizon", 3, "--json", out, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result["agent"] is None and result["encoder"] == "keypoints"
    assert [f["updates"] for f in result["fits"]] == [1, 2]
    for fit in result["fits"]:
        assert len(fit["r2_trained"]) == 5 and set(fit["action_response"]) == {"-1", "+0", "+1"}
        assert {"loss_reconstruction", "loss_reward", "loss_kl"} <= set(fit["losses"])
    # State Recon.'s world model (standardised target) and the CNN supervised on frames
    for model in ("state_recon", "frame_cnn"):
        proc = _benchmark("dreamer_latent_probe", "--fit-random", 2, "--updates", 2,
                          "--preset", "tiny", "--model", model, "--episodes", 2, "--steps", 6,
                          "--horizon", 3, "--json", out, capsys=capsys)
        assert proc.returncode == 0, proc.stderr
        result = json.loads(out.read_text())
        assert result["model"] == model and [f["updates"] for f in result["fits"]] == [2]
        fit = result["fits"][0]
        if model == "frame_cnn":
            assert len(fit["r2_frame"]) == len(result["r2_untrained"]) == 5
            assert {"loss_frame", "mse_0", "mse_4"} <= set(fit["losses"])
        else:
            assert len(fit["r2_trained"]) == 5 and "loss_reconstruction" in fit["losses"]
    # --actor-updates: the state Dreamer's model (the control), then an actor on it frozen
    proc = _benchmark("dreamer_latent_probe", "--fit-random", 2, "--updates", 2, "--preset",
                      "tiny", "--model", "state", "--episodes", 2, "--steps", 6, "--horizon", 3,
                      "--actor-updates", 2, 1, "--eval-episodes", 2, "--json", out, capsys=capsys)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result["model"] == "state" and len(result["fits"][0]["r2_trained"]) == 5
    assert [a["updates"] for a in result["actor"]] == [1, 2]
    for actor in result["actor"]:
        assert {"loss_actor", "loss_critic"} <= set(actor["losses"])
        assert len(actor["own_scene"]["returns"]) == 2
    for bad in (("--fit-random", 2, "--agent", "x.pt"), (), ("--fit-random", 0),
                ("--fit-random", 2, "--dr"), ("--agent", "x.pt", "--model", "frame_cnn"),
                ("--agent", "x.pt", "--actor-updates", 2),
                ("--fit-random", 2, "--model", "frame_cnn", "--actor-updates", 2),
                ("--fit-random", 2, "--actor-updates", 0),
                ("--fit-random", 2, "--actor-updates", 2, "--eval-episodes", 0),
                ("--fit-random", 2, "--eval-episodes", 2)):
        proc = _benchmark("dreamer_latent_probe", *bad, capsys=capsys)
        assert proc.returncode == 2, bad


def test_a_runs_config_json_given_back_repeats_it(tmp_path, capsys):
    import dataclasses
    from simdist.pipelines.twist import PRESETS, Config
    from simdist.utils.cli import parse_config
    saved = Config(**{**PRESETS["tiny"], "tasks": ["cheetah-run"], "seeds": [1, 2],
                      "students": ["twist"]})
    path = tmp_path / "config.json"
    path.write_text(json.dumps(dataclasses.asdict(saved)))
    assert parse_config(Config, PRESETS, ["--config", str(path)])[0] == saved
    again = parse_config(Config, PRESETS, ["--config", str(path), "--seeds", "3"])[0]
    assert again == dataclasses.replace(saved, seeds=[3])
    proc = _run_here("--config", tmp_path / "none.json", "--output-dir", tmp_path / "out",
                     capsys=capsys)
    assert proc.returncode == 2 and "config: no file at" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_a_runs_teacher_and_student_ship_as_named_agents_with_their_record(
        tmp_path, teacher_chain_run):
    """``python -m simdist.pipelines.twist.shipping RUN --task T --seed S``."""
    from simdist.agents import DreamerAgent, TwistStudent
    from simdist.pipelines.twist.shipping import main as ship_main
    ship_main([str(teacher_chain_run), "--task", "cartpole-balance", "--seed", "0",
               "--dest", str(tmp_path)])
    assert isinstance(load_agent(tmp_path / "teacher.pt"), DreamerAgent)
    assert isinstance(load_agent(tmp_path / "student.pt"), TwistStudent)
    record = json.loads((tmp_path / "training_record.json").read_text())
    assert record["task"] == "cartpole-balance" and record["teacher"]["updates"] > 0
    assert record["student"]["student"] == "cnn"  # the faithful student, not the readout
    assert len(record["student"]["held_out"]["returns"]) == len(
        record["oracle_held_out"]["returns"])
    assert set(record["references_held_out"]) == {"zero", "uniform"}
