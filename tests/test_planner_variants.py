"""benchmarks/planner_variants.py: pairing a variant with the recipe's own evaluation."""

import json

import pytest

from tests.in_process import benchmark_module


def _round(path, fraction, speeds):
    path.write_text(json.dumps({"result": {"simdist_eval": {
        "fraction": fraction, "command_mps": speeds}}}))
    return path


def test_paired_rows_are_per_episode_points_and_means_per_speed():
    module = benchmark_module("planner_variants")
    evaluation = {"fraction": [0.1, 0.5, 0.2, 0.6], "command_mps": [0.25, 0.5, 0.25, 0.5]}
    diff, by_speed = module.paired_rows([0.3, 0.5, 0.0, 0.9], evaluation)
    assert diff == pytest.approx([20.0, 0.0, -20.0, 30.0])
    assert by_speed[0.25] == pytest.approx((15.0, 15.0, 2))
    assert by_speed[0.5] == pytest.approx((70.0, 55.0, 2))
    with pytest.raises(ValueError, match="same worlds"):
        module.paired_rows([0.3], evaluation)


def test_pool_stratifies_the_saved_comparisons_of_several_seeds(tmp_path, capsys):
    module = benchmark_module("planner_variants")
    speeds = [0.25, 0.5, 0.75, 0.25]
    pairs = []
    for seed, shift in ((0, 0.1), (1, 0.3)):
        recipe = [0.2, 0.4, 0.6, 0.8]
        round_json = _round(tmp_path / f"round_{seed}.json", recipe, speeds)
        saved = tmp_path / f"variant_{seed}.json"
        saved.write_text(json.dumps({"H60": {"slippery_slope": [f + shift for f in recipe]}}))
        pairs.append(f"{saved}={round_json}")
    module.main(["--pool", *pairs, "--domains", "slippery_slope"])
    out = capsys.readouterr().out
    # every episode is 10 points ahead on seed 0 and 30 on seed 1: mean +20
    assert "H60 (slippery_slope) minus the recipe's evaluation" in out
    assert "2 run(s), 8 episodes): +20.0" in out
    assert "0.25 m/s 70% vs 50%" in out
