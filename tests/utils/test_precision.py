"""Precision names: "auto" resolves to bfloat16 only where the device has native kernels."""

import pytest
import torch
from tensordict import TensorDict

from simdist.agents import SimDistAgent, SimDistConfig
from simdist.modules import SimDistWorldModel
from simdist.modules.planner import LatentMPPIPlanner, PlannerConfig
from simdist.utils import precision


@pytest.fixture(params=[True, False], ids=["native", "emulated"])
def cpu_bfloat16(request, monkeypatch):
    """A CPU with (True) or without (False) native bfloat16 matmuls."""
    monkeypatch.setattr(precision, "_cpu_bfloat16", lambda: request.param)
    return request.param


def test_explicit_names_do_not_depend_on_the_device(cpu_bfloat16):
    assert precision.autocast_dtype("none", "cpu") is None
    assert precision.autocast_dtype("bfloat16", "cpu") is torch.bfloat16
    assert precision.resolve_precision("bfloat16", "cpu") == "bfloat16"


def test_auto_is_bfloat16_only_with_native_kernels(cpu_bfloat16):
    assert precision.native_bfloat16("cpu") is cpu_bfloat16
    assert precision.resolve_precision("auto", "cpu") == ("bfloat16" if cpu_bfloat16 else "none")
    assert precision.autocast_dtype("auto", torch.device("cpu")) is (
        torch.bfloat16 if cpu_bfloat16 else None)
    assert precision.resolve_precision("auto", "meta") == "none"  # no kernels at all


def test_this_cpu_is_judged_by_pytorchs_own_onednn_check():
    expected = bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    assert precision.native_bfloat16("cpu") is expected


def test_unknown_names_are_refused():
    with pytest.raises(ValueError, match="unknown mixed_precision 'fp8'; valid: none, bfloat16, auto"):
        precision.check_precision("fp8", "mixed_precision")
    with pytest.raises(ValueError, match="unknown precision 'float16'"):
        precision.autocast_dtype("float16", "cpu")


def test_auto_reaches_the_planners_rollouts_and_the_agents_updates(cpu_bfloat16):
    expected = torch.bfloat16 if cpu_bfloat16 else torch.float32
    torch.manual_seed(0)
    wm = SimDistWorldModel.build(10, 3, size="tiny")
    seen = []
    hook = wm.dynamics.net[0].register_forward_hook(lambda m, i, o: seen.append(o.dtype))
    cfg = PlannerConfig(horizon=3, num_samples=16, num_elites=4, iterations=1, precision="auto")
    planner = LatentMPPIPlanner.from_world_model(wm, cfg, seed=0)
    out = planner(TensorDict({"latent": torch.randn(2, wm.latent_dim)}, [2]))
    assert set(seen) == {expected} and out["action"].dtype == torch.float32
    seen.clear()
    agent = SimDistAgent(wm, SimDistConfig(size="tiny", horizon=3, mixed_precision="auto"))
    with agent._autocast():
        wm.dynamics(torch.randn(2, wm.latent_dim), torch.zeros(2, 3))
    hook.remove()
    assert seen == [expected]
