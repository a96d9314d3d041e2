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


TWIST = [
    ("md", """# TWIST: distil an image student from a state teacher

What you will learn: how a Dreamer teacher trained on privileged state records the
domain-randomised image of every step it collects (the dataset `D = {(s, o, a, r)}`), how
an image student is distilled from the frozen teacher (latent distillation, TWIST Eq. 3,
plus imagined-rollout alignment, Eq. 4), how the student is deployed with the teacher's
actor, and how to compare it with the teacher on **held-out** scenes.

The small mode runs on 2 CPU cores in a few minutes with a tiny model and budget, so
the returns show the mechanics, not the paper's numbers (see `recipes/twist_dmc.py` and
the README's results). Set `SIMDIST_TUTORIAL_LARGE=1` for a larger budget."""),
    ("code", """import os, tempfile
import simdist  # headless rendering set-up before MuJoCo loads
import torch
import matplotlib.pyplot as plt
from simdist.agents import DreamerAgent, DreamerConfig, TwistConfig, TwistStudent
from simdist.envs import VisualRandomisation
from simdist.modules import DreamerWorldModel
from simdist.pipelines import (OnlineConfig, control_env, dreamer_keys, evaluate_returns,
                               load_episodes, train_dreamer_online, EpisodeReplay)

LARGE = os.environ.get("SIMDIST_TUTORIAL_LARGE") == "1"
SIZE = "compact" if LARGE else "tiny"
EPISODE = 500 if LARGE else 50
torch.manual_seed(0)
workdir = tempfile.mkdtemp()"""),
    ("md", """## 1. The teacher: Dreamer on privileged state, recording randomised images

`train_dreamer_online` alternates collecting an episode and training on replayed slices;
the env renders a domain-randomised frame at every step (train textures, redrawn each
step) while the teacher acts on `"state"`. Episodes are stored on disk, so a crashed run
resumes where it stopped."""),
    ("code", """teacher = DreamerAgent.for_state(5, 1, DreamerConfig(size=SIZE, horizon=5))
env = control_env("cartpole-balance", 0, pixels=True, visual=VisualRandomisation.training(),
                  max_episode_steps=EPISODE, primer=teacher.make_primer())
online = OnlineConfig(env_steps=EPISODE * (8 if LARGE else 4), prefill_steps=EPISODE,
                      train_every=5, episode_steps=EPISODE, slice_len=16, slices=8)
run = train_dreamer_online(teacher, env, online, workdir, dreamer_keys("state", "pixels"))
D = load_episodes(workdir)
print(len(D), "episodes;", D[0]["next", "pixels"].shape, "images next to", D[0]["next", "state"].shape)
fig, axes = plt.subplots(1, 4, figsize=(8, 2))
for i, ax in enumerate(axes):
    ax.imshow(D[-1]["next", "pixels"][i]); ax.axis("off")
plt.suptitle("what the student will see: one frame per step, randomised every step")
plt.show()"""),
    ("md", """## 2. The student: latent distillation + imagined-rollout alignment

The teacher is frozen; the student (same RSSM class, CNN encoder) learns to reproduce the
teacher's beliefs and latent distributions from the images of the same steps, and to
imagine like the teacher under the teacher's (noisy) actions. The ablation without
imagined alignment trains on Eq. 3 alone."""),
    ("code", """def distil(imagined):
    torch.manual_seed(0)
    student = DreamerWorldModel.student(action_dim=1, size=SIZE)
    twist = TwistStudent(teacher, student, TwistConfig(imagined=imagined, horizon=5,
                                                       max_imagination_starts=64))
    replay = EpisodeReplay(len(D) * EPISODE, slice_len=16, slices=8)
    for episode in D:
        replay.add(episode.to_tensordict())
    history = [twist.update(replay.sample()) for _ in range(300 if LARGE else 40)]
    return twist, history

twist, history = distil(imagined=True)
plain, plain_history = distil(imagined=False)
plt.plot([h["loss_distillation"] for h in history], label="Eq. 3 (TWIST)")
plt.plot([h["loss_imagined"] for h in history], label="Eq. 4 (TWIST)")
plt.plot([h["loss_distillation"] for h in plain_history], label="Eq. 3 (w/o Eq. 4)")
plt.yscale("log"); plt.xlabel("student update"); plt.legend(); plt.show()"""),
    ("md", """## 3. Held-out evaluation

Every method meets the same seeds: the Oracle (the teacher on state), and the students
acting from pixels of **held-out** textures (never in the training bank), with the
randomisation drawn once per episode and a jittered camera."""),
    ("code", """episodes, steps = (4, 500) if LARGE else (2, 50)
heldout = VisualRandomisation.heldout_evaluation()
results = {
    "Oracle (state)": evaluate_returns("cartpole-balance", teacher.policy(explore=False),
                                       teacher.make_primer(), 123, episodes, steps, False, None),
    "TWIST student": evaluate_returns("cartpole-balance", twist.policy(), twist.make_primer(),
                                      123, episodes, steps, True, heldout),
    "w/o imagined": evaluate_returns("cartpole-balance", plain.policy(), plain.make_primer(),
                                     123, episodes, steps, True, heldout),
}
oracle = results["Oracle (state)"]["mean"]
for name, r in results.items():
    print(f"{name:16s} {r['mean']:7.1f} +- {r['std']:5.1f}  ({100 * r['mean'] / oracle:4.0f}% of Oracle)")"""),
    ("md", """## 4. The student's latent vs the teacher's

On one held-out episode, the teacher filters the true state while the student filters the
images; the teacher's *state decoder* applied to the **student's** latent shows how much
of the state the student recovered from pixels alone."""),
    ("code", """from simdist.modules.rssm import RSSMState
from torchrl.envs.utils import step_mdp

env = control_env("cartpole-balance", 7, pixels=True, visual=heldout,
                  max_episode_steps=steps, primer=twist.make_primer())
policy, rssm = twist.policy(), teacher.world_model.rssm
t_state = RSSMState(torch.zeros(1, rssm.deter_dim), torch.zeros(1, rssm.stoch_dim))
prev, true, decoded, gap = torch.zeros(1, 1), [], [], []
td = env.reset()
with torch.no_grad():
    for _ in range(steps):
        td = policy(td)
        keep = (~td["is_init"].reshape(1, 1)).float()
        t_state = rssm.filter_step(t_state, prev, teacher.world_model.encoder(td["state"][None]), keep)
        prev = td["action"].reshape(1, 1)
        s_feat = torch.cat([td["next", "agent", "belief"], td["next", "agent", "stoch"]])[None]
        true.append(td["state"]); decoded.append(teacher.world_model.decode(s_feat)[0])
        gap.append((t_state.belief[0] - td["next", "agent", "belief"]).norm().item())
        td = step_mdp(env.step(td))
true, decoded = torch.stack(true), torch.stack(decoded)
fig, axes = plt.subplots(1, 3, figsize=(12, 3))
for ax, (i, name) in zip(axes[:2], [(0, "cart position"), (1, "pole cos")]):
    ax.plot(true[:, i], label="true state"); ax.plot(decoded[:, i], label="decoded from student latent")
    ax.set_title(name); ax.legend(fontsize=7)
axes[2].plot(gap); axes[2].set_title("||h_teacher - h_student||")
plt.show()"""),
    ("md", """## Where to go next

- `recipes/twist_dmc.py`: the whole pipeline with both ablations and Dreamer-from-pixels
  baselines (with and without DR), a Table-I-shaped results table, a plot and a rerun
  recording of the student's view (`rerun outputs/twist_dmc/rerun_student.rrd`).
- `simdist.objectives.TwistDistillationLoss` / `ImaginedAlignmentLoss` for the math
  (README concept map), tutorial 3 for SimDist."""),
]


SIMDIST = [
    ("md", """# SimDist: pretrain in simulation, plan, finetune only the dynamics

What you will learn: how the committed SAC expert generates a perturbed-expert dataset,
how the SimDist world model is pretrained on robot-measurable observations only, how the
latent MPPI planner uses it, and how finetuning **only the dynamics** on a little
target-domain data changes the planner, with proof that nothing else moved. Ends with a
rerun recording of a planning episode.

The small mode runs on 2 CPU cores in a few minutes with a tiny model and tiny budgets,
so the figures show the mechanics, not transfer quality (for that, run
`recipes/simdist_quadruped.py` and see the README's results). Set
`SIMDIST_TUTORIAL_LARGE=1` for bigger budgets."""),
    ("code", """import os, json, tempfile
from pathlib import Path
import simdist  # headless rendering set-up before MuJoCo loads
import torch
import matplotlib.pyplot as plt
from simdist.agents import SimDistAgent, SimDistConfig
from simdist.data import DatasetConfig, generate_dataset, load_dataset
from simdist.envs import get_target
from simdist.experts import Expert, committed_expert
from simdist.modules import SimDistWorldModel
from simdist.modules.planner import PlannerConfig
from simdist.pipelines import as_slices, locomotion_env, progress_stats, rollout, weights

LARGE = os.environ.get("SIMDIST_TUTORIAL_LARGE") == "1"
STEPS = 250 if LARGE else 40          # steps per episode (50 Hz)
EXPERT = committed_expert()  # the shipped quadruped expert (package data)
workdir = Path(tempfile.mkdtemp())
torch.manual_seed(0)"""),
    ("md", """## 1. A perturbed-expert dataset

The final expert and its earlier snapshots are mixed per episode; SimDist's burst/pause
action noise perturbs them; the expert's critic labels values. The dataset is a
memory-mapped TensorDict on disk (resumable, sharded)."""),
    ("code", """expert = Expert.load(EXPERT)
snapshots = [Expert.load(EXPERT, snapshot=s) for s in sorted(torch.load(EXPERT, weights_only=True)["snapshots"])]
path = generate_dataset(DatasetConfig(episodes=64 if LARGE else 8, episode_steps=STEPS,
                                      shard_episodes=8, seed=0), workdir / "data", expert, snapshots)
meta = json.loads((path / "meta.json").read_text())
print(meta["transitions"], "transitions,", meta["bytes"] / 1e6, "MB")"""),
    ("md", """## 2. Pretrain the world model

Encoder (history of robot-measurable observations -> latent), latent dynamics, reward,
value and policy-prior heads, trained together on slices that never cross episodes."""),
    ("code", """buffer = load_dataset(path, slice_len=8, batch_size=8 * 16)
obs = buffer[:]["observation"]  # the whole dataset, a view of the memory map
wm = SimDistWorldModel.build(obs.shape[-1], 12, size="tiny")
wm.encoder.set_normalisation(obs.reshape(-1, obs.shape[-1]).mean(0), obs.reshape(-1, obs.shape[-1]).std(0))
agent = SimDistAgent(wm, SimDistConfig(size="tiny", horizon=3, value_weight=1e-3))
history = [agent.pretrain_update(buffer.sample().reshape(-1, 8)) for _ in range(600 if LARGE else 60)]
for key in ("loss_consistency", "loss_reward", "loss_bc"):
    plt.plot([h[key] for h in history], label=key)
plt.yscale("log"); plt.xlabel("update"); plt.legend(); plt.show()"""),
    ("md", """## 3. Plan with latent MPPI, in simulation and in the target

`agent.policy(...)` encodes the observation history and plans in latent space each step;
forward progress is reported in metres and as a fraction of the commanded distance."""),
    ("code", """planner = PlannerConfig(horizon=3, num_samples=32, iterations=2, num_elites=4)

def evaluate(agent, target, episodes=2):
    env = locomotion_env(get_target(target), episodes, STEPS, 10_000, primers=[agent.make_primer()])
    spec = env.action_spec
    td = rollout(env, agent.policy(spec.space.low[0], spec.space.high[0], planner, seed=0), STEPS)
    stats = progress_stats(td, env.base_env.observation_layout["command"].start)
    env.close()
    return stats, td

for target in ("sim", "slippery_slope"):
    stats, _ = evaluate(agent, target)
    print(f"{target:15s} {stats['mean_m']:+.2f} m ({100 * stats['mean_fraction']:.0f}% of commanded)")"""),
    ("md", """## 4. Finetune only the dynamics on target data

Collect a few target episodes with the planner, then `finetune_update` trains the
dynamics alone: the encoder and every head stay bit-identical."""),
    ("code", """_, target_data = evaluate(agent, "slippery_slope", episodes=4)
keys = ["observation", "action", "is_init", ("next", "observation"), ("next", "reward"),
        ("next", "done"), ("next", "terminated")]
slices = as_slices(target_data.select(*keys), slice_len=8, batch_slices=16)
before = weights(agent.world_model)
losses = [agent.finetune_update(slices.sample().reshape(-1, 8))["loss_consistency"]
          for _ in range(300 if LARGE else 30)]
after = weights(agent.world_model)
changed = sorted({k.split(".")[0] for k in before if not torch.equal(before[k], after[k])})
print("parts that changed:", changed)
stats, _ = evaluate(agent, "slippery_slope")
print(f"after finetuning: {stats['mean_m']:+.2f} m ({100 * stats['mean_fraction']:.0f}% of commanded)")
plt.plot(losses); plt.xlabel("finetuning update"); plt.ylabel("latent consistency loss"); plt.show()"""),
    ("md", """## 5. A rerun recording

`record_planning_episode` logs the robot, the plan and the executed path, with predicted
vs actual reward and value; open the file with `rerun FILE` (installed with rerun-sdk).
Plans are drawn through a probe (latent -> privileged state); an untrained probe is used
here only to make the file, the recipe trains one (`ProbeLoss`)."""),
    ("code", """from simdist.modules import StateDecoder
from simdist.viz import entity_paths, record_planning_episode

env = locomotion_env(get_target("slippery_slope"), 1, STEPS, 10_000, primers=[agent.make_primer()])
probe = StateDecoder(wm.latent_dim, env.base_env.state_layout.size, hidden=64, layers=2)
spec = env.action_spec
rrd = record_planning_episode(env, agent.policy(spec.space.low[0], spec.space.high[0], planner),
                              probe, str(workdir / "episode.rrd"), steps=20)
print(rrd, sorted(entity_paths(rrd))[:6])"""),
    ("md", """## Where to go next

- `recipes/simdist_quadruped.py`: the whole pipeline with the whole-model ablation and a
  continued-SAC baseline over 1-8 minutes of target data, results table, plot, and rerun
  recordings before/after finetuning.
- `benchmarks/planner_latency.py` for the planner against TorchRL's `MPPIPlanner`."""),
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
    build(TWIST, here / "02_twist.ipynb")
    build(SIMDIST, here / "03_simdist.ipynb")
