"""experiments/planner_variants.py: pairing a variant with the recipe's own evaluation."""

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


def test_pool_pairs_with_the_zero_shot_record_per_domain(tmp_path, capsys):
    """zero_shot.json keeps one evaluation per domain: each domain pairs with its own."""
    module = benchmark_module("planner_variants")
    speeds = [0.25, 0.5]
    zero_shot = tmp_path / "zero_shot.json"
    zero_shot.write_text(json.dumps({"result": {
        "sim": {"fraction": [0.9, 1.0], "command_mps": speeds},
        "slippery_slope": {"fraction": [0.1, 0.3], "command_mps": speeds}}}))
    saved = tmp_path / "variant.json"
    saved.write_text(json.dumps({"ens": {"sim": [0.9, 0.9], "slippery_slope": [0.4, 0.4]}}))
    module.main(["--pool", f"{saved}={zero_shot}", "--domains", "sim", "slippery_slope"])
    out = capsys.readouterr().out
    assert "ens (sim) minus the recipe's evaluation" in out and "2 episodes): -5.0" in out
    assert "ens (slippery_slope) minus" in out and "2 episodes): +20.0" in out


def test_a_record_without_the_domain_fails_before_any_evaluation(tmp_path):
    module = benchmark_module("planner_variants")
    zero_shot = tmp_path / "zero_shot.json"
    zero_shot.write_text(json.dumps({"result": {
        "sim": {"fraction": [0.9], "command_mps": [0.5]}}}))
    with pytest.raises(ValueError, match="no SimDist evaluation in 'foam'"):
        module.main(["--run", str(tmp_path / "no_run_here"), "--against", str(zero_shot),
                     "--domains", "foam"])


def test_member0_parts_score_with_member_0_alone_and_are_restored():
    import torch
    from simdist.modules import SimDistWorldModel, WorldModelEnsemble
    module = benchmark_module("planner_variants")
    torch.manual_seed(0)
    members = [SimDistWorldModel.build(10, 3, size="tiny") for _ in range(2)]
    ensemble = WorldModelEnsemble(members)
    z = ensemble.encode(torch.randn(4, 2, 10))
    a = torch.rand(4, 3) * 2 - 1
    L = members[0].latent_dim
    mean_value, mean_reward = ensemble.value(z), ensemble.reward(z, a)
    swapped = module.with_member0_parts(ensemble, ["value", "prior"])
    assert torch.allclose(ensemble.value(z), members[0].value(z[..., :L]))
    assert torch.allclose(ensemble.policy(z), members[0].policy(z[..., :L]))
    assert torch.allclose(ensemble.reward(z, a), mean_reward)  # not swapped: still the mean
    assert not torch.allclose(ensemble.value(z), mean_value)
    module.restore_parts(ensemble, swapped)
    assert torch.allclose(ensemble.value(z), mean_value)
    with pytest.raises(ValueError, match="unknown part"):
        module.with_member0_parts(ensemble, ["dynamics"])
    with pytest.raises(ValueError, match="needs an ensemble"):
        module.with_member0_parts(members[0], ["value"])
