"""Writes the tutorial notebooks from the cell sources below (outputs stripped).

Keeping the source here makes notebook diffs reviewable; run
``python tutorials/make_notebooks.py`` after editing and commit both.
"""

from pathlib import Path

import nbformat

PARTS = [
    ("md", """# The parts of simdist

What you will learn: how the simulation side (privileged state + pixels + domain
randomisation + target domains), the world-model modules and the loss objects fit
together, by composing them by hand in a few cells. Everything runs on 2 CPU cores in
about a minute; set `SIMDIST_TUTORIAL_LARGE=1` for bigger budgets."""),
    ("code", """import os
import simdist  # sets up headless rendering (EGL) before MuJoCo loads
import torch
import matplotlib.pyplot as plt
from simdist.envs import make_env, VisualRandomisation, DynamicsRandomisation, describe_ranges

LARGE = os.environ.get("SIMDIST_TUTORIAL_LARGE") == "1"
STEPS = 200 if LARGE else 30
torch.manual_seed(0)"""),
    ("md", """## 1. Environments: state and pixels from the same physics step

`make_env` returns a TorchRL `EnvBase`. The privileged `"state"` has a named layout;
`"pixels"` are uint8 frames; visual randomisation redraws textures, colours, lights (and
optionally the camera) every step, drawing from a **train** bank that never overlaps the
**held-out** bank used for evaluation."""),
    ("code", """env = make_env("cartpole-balance", pixels=True, image_size=64, seed=0,
               visual_randomisation=VisualRandomisation.training())
td = env.rollout(4)
print(env.state_layout.names(), td["next", "state"].shape, td["next", "pixels"].dtype)
heldout = make_env("cartpole-balance", pixels=True, seed=0,
                   visual_randomisation=VisualRandomisation.heldout_evaluation())
fig, axes = plt.subplots(1, 5, figsize=(10, 2))
for i, ax in enumerate(axes[:4]):
    ax.imshow(td["next", "pixels"][i]); ax.set_title(f"train step {i}"); ax.axis("off")
axes[4].imshow(heldout.reset()["pixels"]); axes[4].set_title("held-out"); axes[4].axis("off")
plt.show()"""),
    ("md", """## 2. Target domains: the "real world" stand-ins

Each preset lies outside the training randomisation ranges:"""),
    ("code", """print(describe_ranges())
for target in ("sim", "slippery_slope"):
    robot = make_env("quadruped-flat", target=target, seed=0)
    out = robot.rollout(STEPS)
    print(f"{target:15s} forward progress after {STEPS} random-action steps: "
          f"{out['next', 'forward_progress'][-1].item():+.3f} m")"""),
    ("md", """## 3. World models: a state teacher and a pixel student

TWIST's teacher and student are the same `DreamerWorldModel` class with different
encoders. `observe` filters a `[batch, time]` slice into posterior states."""),
    ("code", """from simdist.modules import DreamerWorldModel
from torchrl.envs import InitTracker, TransformedEnv

teacher = DreamerWorldModel.teacher(state_dim=5, action_dim=1, size="tiny")
student = DreamerWorldModel.student(action_dim=1, size="tiny")
data_env = TransformedEnv(make_env("cartpole-balance", pixels=True, seed=1, num_envs=4,
                                   visual_randomisation=VisualRandomisation.training()),
                          InitTracker())
batch = data_env.rollout(12)            # [4 envs, 12 steps]: state, pixels, action, reward
posterior = teacher.observe(batch["next", "state"], batch["action"], batch["is_init"].squeeze(-1))
print({k: tuple(v.shape) for k, v in posterior.items()})"""),
    ("md", """## 4. Losses name what they train

`TwistDistillationLoss` (TWIST Eq. 3) trains only the student; the teacher runs under
`torch.no_grad`. A few Adam steps reduce the loss, and the teacher's weights do not move."""),
    ("code", """from simdist.objectives import TwistDistillationLoss

loss = TwistDistillationLoss(teacher, student)
opt = torch.optim.Adam(loss.trainable_parameters(), lr=1e-3)
before = {k: v.clone() for k, v in teacher.state_dict().items()}
history = []
for step in range(60 if LARGE else 15):
    out = loss(batch.clone())
    opt.zero_grad(); out["loss_distillation"].backward(); opt.step()
    history.append(out["loss_distillation"].item())
print("distillation loss", [round(h, 2) for h in history[::5]])
print("teacher unchanged:", all(torch.equal(v, before[k]) for k, v in teacher.state_dict().items()))"""),
    ("md", """## 5. SimDist: pretrain, plan, finetune only the dynamics

`SimDistWorldModel` exposes verbs (`encode`, `next`, `rollout`, `reward`, `value`,
`policy`); `DynamicsFinetuneLoss.trainable_parameters()` is the dynamics alone, and the
latent MPPI planner reads a latent and writes an action plus its plan."""),
    ("code", """from tensordict import TensorDict
from simdist.modules import SimDistWorldModel
from simdist.modules.planner import LatentMPPIPlanner, PlannerConfig
from simdist.objectives import DynamicsFinetuneLoss

robot = TransformedEnv(make_env("quadruped-flat", num_envs=4, seed=2), InitTracker())
rollout = robot.rollout(STEPS)
wm = SimDistWorldModel.build(obs_dim=rollout["observation"].shape[-1], action_dim=12, size="tiny")
finetune = DynamicsFinetuneLoss(wm, horizon=3)
print("finetuning trains", sum(p.numel() for p in finetune.trainable_parameters()),
      "of", sum(p.numel() for p in wm.parameters()), "parameters (the dynamics)")
latent = wm.encode_sequence(rollout["observation"], rollout["is_init"].squeeze(-1))[:, -1]
planner = LatentMPPIPlanner.from_world_model(wm, PlannerConfig(), seed=0)
plan = planner(TensorDict({"latent": latent.detach()}, [4]))
print("action", tuple(plan["action"].shape), "plan", tuple(plan["planner", "mean"].shape))"""),
    ("md", """## Where to go next

- `recipes/simdist_quadruped.py` and `recipes/train_expert.py`, `recipes/generate_dataset.py`
- the concept map in the README (which module/loss implements which paper step)
- `benchmarks/` for measured throughput and planner latency"""),
]


def build(cells, path: Path) -> None:
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    nb.cells = [nbformat.v4.new_markdown_cell(src) if kind == "md"
                else nbformat.v4.new_code_cell(src) for kind, src in cells]
    nbformat.write(nb, path)


if __name__ == "__main__":
    here = Path(__file__).parent
    build(PARTS, here / "01_the_parts.ipynb")
