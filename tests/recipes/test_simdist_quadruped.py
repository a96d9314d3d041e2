import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

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


def test_recipe_runs_end_to_end_on_tiny_preset_and_resumes(tmp_path, tiny_expert):
    proc = _run("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path)
    assert proc.returncode == 0, proc.stderr
    stages = ["expert", "expert_zero_shot", "dataset", "pretrain", "zero_shot", "round_1",
              "round_2"]
    for stage in stages:
        assert (tmp_path / "stages" / f"{stage}.json").exists(), stage
    results = json.loads((tmp_path / "results.json").read_text())
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
    assert (tmp_path / "forward_progress.png").stat().st_size > 0
    assert "95% CI" in proc.stdout and "SimDist: finetune dynamics" in proc.stdout
    # Finetuning touched only the dynamics: every other tensor equals the pretrained one.
    pretrained = torch.load(tmp_path / "stages" / "pretrain" / "world_model.pt", weights_only=True)
    finetuned = torch.load(tmp_path / "stages" / "round_2" / "simdist.pt", weights_only=True)
    assert any(not torch.equal(v, pretrained[k]) for k, v in finetuned.items() if k.startswith("dynamics"))
    assert all(torch.equal(v, pretrained[k]) for k, v in finetuned.items() if not k.startswith("dynamics"))
    whole = torch.load(tmp_path / "stages" / "round_2" / "whole.pt", weights_only=True)
    assert any(not torch.equal(v, pretrained[k]) for k, v in whole.items() if k.startswith("encoder"))
    for name in ("rerun_before.rrd", "rerun_after.rrd"):
        assert (tmp_path / name).stat().st_size > 0

    again = _run("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path)
    assert again.returncode == 0 and again.stdout.count("already done") == len(stages) + 2
    assert json.loads((tmp_path / "results.json").read_text())["curves"] == curves
    changed = _run("--preset", "tiny", "--episodes", 3, "--expert", tiny_expert,
                   "--output-dir", tmp_path)
    assert changed.returncode != 0 and "different config" in changed.stderr


def test_a_killed_round_resumes_without_recollecting(tmp_path, tiny_expert):
    proc = _run("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path)
    assert proc.returncode == 0, proc.stderr
    record = tmp_path / "stages" / "round_2.json"
    first = json.loads(record.read_text())["result"]
    # Simulate a kill after round 2 collected its data and finetuned its dynamics.
    record.unlink()
    (tmp_path / "stages" / "round_2" / "sac.ckpt").unlink()
    data_before = sorted(p.stat().st_mtime_ns for p in (tmp_path / "stages" / "round_2" / "data").rglob("*.memmap"))
    again = _run("--preset", "tiny", "--expert", tiny_expert, "--output-dir", tmp_path)
    assert again.returncode == 0, again.stderr
    assert "round 2: finetune dynamics" not in again.stderr  # restored, not retrained
    data_after = sorted(p.stat().st_mtime_ns for p in (tmp_path / "stages" / "round_2" / "data").rglob("*.memmap"))
    assert data_after == data_before
    resumed = json.loads(record.read_text())["result"]
    assert resumed["simdist_eval"] == first["simdist_eval"]
    assert resumed["target_steps"] == first["target_steps"]


def test_recipe_rejects_unknown_target_and_missing_expert(tmp_path):
    proc = _run("--target", "moon", "--output-dir", tmp_path / "a")
    assert proc.returncode != 0 and "unknown targets ['moon']" in proc.stderr
    proc = _run("--preset", "tiny", "--expert", tmp_path / "none.pt", "--output-dir", tmp_path / "b")
    assert proc.returncode != 0 and "recipes/train_expert.py" in proc.stderr
    proc = _run("--preset", "tiny", "--device", "tpu9", "--output-dir", tmp_path / "c")
    assert proc.returncode == 2 and "unknown device 'tpu9'" in proc.stderr
    assert not (tmp_path / "c").exists()  # refused before any work
