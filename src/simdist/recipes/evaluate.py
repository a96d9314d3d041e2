"""Evaluate a saved agent in any task and target: mean / IQM / bootstrap 95% CI, optional MP4.

Loads one self-describing agent file (``SimDistAgent.save``, ``DreamerAgent.save``,
``TwistStudent.save`` or ``AsymmetricSACAgent.save``: weights and sizes in one file, no recipe code or other checkpoint
needed), runs ``--episodes`` episodes in ``--task`` under ``--target`` and prints the
return's mean, interquartile mean and bootstrap 95% confidence interval (and, for
locomotion, the forward progress as a fraction of the commanded distance).

Usage:
    python recipes/evaluate.py --checkpoint out/student.pt --target unseen_scenes
    python recipes/evaluate.py --checkpoint out/simdist.pt --task quadruped-flat \\
        --target '{"name": "icy", "friction": 0.4}' --episodes 16 --video icy.mp4
    python recipes/evaluate.py --checkpoint agent.pt --target my_target.json --output r.json
    python recipes/evaluate.py --checkpoint simdist/quadruped --target foam --video foam.mp4
    python recipes/evaluate.py --list   # the shipped agents
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import simdist  # noqa: F401  (headless GL set-up before dm_control)
import torch

from simdist.agents import load_agent
from simdist.agents.checkpoint import read_agent_meta
from simdist.envs import get_target, get_task
from simdist.pipelines.evaluate_agent import agent_camera, evaluate_agent, record_video
from simdist.utils import resolve_device, write_json_atomic
from simdist.pretrained import describe_pretrained
from simdist.utils.cli import check, check_builds, check_positive, parse_config, usage_error
from simdist.viz.video import INSTALL_HINT, video_backend_available


@dataclass
class Config:
    """Evaluation settings; every field is a ``--kebab-case`` flag, checked before any work."""

    # agent file written by an agent's save() (SimDist, Dreamer, TWIST, SAC), an expert.pt,
    # or a shipped agent's name (--list shows them, e.g. simdist/quadruped)
    checkpoint: str = ""
    # task to run (a name in simdist.envs.TASKS); empty: the task recorded in the checkpoint
    task: str = ""
    # a name in simdist.envs.TARGETS, a JSON object of TargetDomain fields
    # ('{"name": "icy", "friction": 0.4}') or the path of a .json file holding one
    target: str = "sim"
    episodes: int = 10  # evaluation episodes (batched worlds)
    steps: int = 0  # agent steps per episode; 0: the task's episode length
    seed: int = 0  # seeds the worlds, the policy's noise and the bootstrap
    video: str = ""  # MP4 path for one episode of the same policy (empty: no video)
    video_size: int = 256  # video frame size in pixels (even)
    output: str = ""  # JSON file for the results (empty: print only)
    device: str = "cpu"  # where the agent runs ('cpu', 'cuda', 'cuda:1', 'auto')
    # camera a pixel agent sees; None: the one its file records (the TWIST recipe's
    # --camera-id), else the task's
    camera_id: int | None = None
    list: bool = False  # print the shipped agents (names --checkpoint takes) and exit

    def __post_init__(self):
        check_positive(self, "episodes", "video_size")
        check_positive(self, "steps", allow_zero=True)
        check(self.video_size % 2 == 0, "video_size", f"must be even, got {self.video_size}")
        check_builds("target", get_target, self.target)
        if self.task:
            check_builds("task", get_task, self.task)
        if self.video:
            check(self.video.endswith(".mp4"), "video", f"must end in .mp4, got {self.video!r}")
            check(video_backend_available(), "video", INSTALL_HINT)
        check_builds("device", resolve_device, self.device)
        if self.output:
            check(self.output.endswith(".json") and not Path(self.output).is_dir(), "output",
                  f"must be a .json file path, got {self.output!r}")
        if self.camera_id is not None:
            check(self.camera_id >= 0, "camera_id", f"must be >= 0, got {self.camera_id}")
        if self.checkpoint:  # empty only in the parser's defaults; main() requires it
            check_builds("checkpoint", self.resolve_task)

    def resolve_task(self) -> str:
        """``--task``, else the task the checkpoint records (reads and checks the file)."""
        try:
            meta = read_agent_meta(self.checkpoint)
        except (OSError, RuntimeError, KeyError) as err:  # missing, unreadable or corrupt
            raise ValueError(str(err).strip('"')) from None
        task = self.task or meta.get("task", "")
        if not task:
            raise ValueError(f"{self.checkpoint} records no task; pass --task")
        get_task(task)
        return task


PRESETS = {"default": {}, "tiny": {"episodes": 2, "steps": 10, "video_size": 64}}


def report(result: dict) -> str:
    """The printed summary: return (and forward progress) with IQM and 95% CI."""
    r = result["return"]
    lines = [f"task {result['task']}, target {result['target']}: {result['episodes']} "
             f"episodes x {result['steps']} steps, seed {result['seed']}",
             f"return            mean {r['mean']:.2f}  IQM {r['iqm']:.2f}  "
             f"95% CI [{r['ci_low']:.2f}, {r['ci_high']:.2f}]"]
    if "progress" in result:
        p = result["progress"]
        lines.append(f"forward progress  mean {p['mean_fraction']:.1%}  IQM "
                     f"{p['iqm_fraction']:.1%}  95% CI [{p['ci_fraction'][0]:.1%}, "
                     f"{p['ci_fraction'][1]:.1%}] of the commanded distance")
    return "\n".join(lines)


def run(cfg: Config) -> dict:
    task = cfg.resolve_task()
    agent = load_agent(cfg.checkpoint, map_location=resolve_device(cfg.device))
    print(f"agent: {type(agent).__name__} from {cfg.checkpoint}", flush=True)
    camera_id = agent_camera(agent, task, cfg.camera_id)  # --camera-id, else the file's
    if camera_id is not None:
        print(f"camera: {camera_id}", flush=True)
    result = evaluate_agent(agent, task, cfg.target, cfg.episodes, cfg.steps or None, cfg.seed,
                            camera_id=camera_id)
    result["agent"], result["checkpoint"] = type(agent).__name__, cfg.checkpoint
    print(report(result), flush=True)
    if cfg.video:
        path = record_video(agent, task, cfg.video, cfg.target, cfg.steps or None, cfg.seed,
                            cfg.video_size, camera_id=camera_id)
        result["video"] = str(path)
        print(f"video: {path}", flush=True)
    if cfg.output:
        write_json_atomic(Path(cfg.output), result)
        print(f"results: {cfg.output}", flush=True)
    return result


def main(argv=None):
    cfg, _ = parse_config(Config, PRESETS, argv, description=__doc__.splitlines()[0],
                          prog="evaluate.py")
    if cfg.list:
        print(describe_pretrained())
        return None
    if not cfg.checkpoint:
        usage_error("evaluate.py", "checkpoint: required (--checkpoint PATH or a name from "
                                   "--list)")
    with torch.no_grad():
        return run(cfg)


def cli() -> None:
    """The ``simdist-evaluate`` console script: :func:`main` on ``sys.argv``, exit status 0."""
    main()


if __name__ == "__main__":
    main()
