"""Record a TWIST student's episode: what it sees beside what the teacher knows."""

from __future__ import annotations

import os

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from simdist.modules.rssm import RSSMState
from simdist.utils.atomic import temp_path_beside
from simdist.utils.device import module_device
from simdist.utils.lazy import lazy_import

rr = lazy_import("rerun")  # ~0.6 s to import: loaded when a recording starts


@torch.no_grad()
def record_student_episode(env, teacher, twist, path: str, steps: int,
                           application_id: str = "twist_student") -> str:
    """Runs the deployed student (pixels -> student latent -> teacher actor) for ``steps``
    and logs, per step, to a rerun ``.rrd`` file:

    - ``student/view``: the randomised image the student acts from;
    - ``state/true/<field>`` and ``state/from_student_latent/<field>``: the privileged
      state, and the teacher's state decoder applied to the *student's* latent (how much
      of the state the student recovered from pixels alone);
    - ``latent/belief_distance``: ``||h_T - h_S||`` with the teacher filtering the state
      of the same steps alongside;
    - ``action`` and ``reward``.

    Args:
        env: an unbatched pixels env (with ``InitTracker`` and ``twist.make_primer()``).
        teacher: the :class:`~simdist.agents.DreamerAgent` teacher.
        twist: the trained :class:`~simdist.agents.TwistStudent`.

    Returns:
        ``path``.
    """
    stream = rr.RecordingStream(application_id)
    partial = temp_path_beside(path)  # renamed to ``path`` once complete
    stream.save(str(partial))
    names = env.base_env.state_layout.names()
    layout = env.base_env.state_layout
    fields = [(f"{n}/{i}", layout[n].start + i) for n in names
              for i in range(layout[n].stop - layout[n].start)]
    teacher_wm = teacher.world_model
    rssm = teacher_wm.rssm
    policy = twist.policy(explore=False)
    device = module_device(teacher_wm)  # the policy hands back the env's (CPU) tensors
    t_state = RSSMState(torch.zeros(1, rssm.deter_dim, device=device),
                        torch.zeros(1, rssm.stoch_dim, device=device))
    prev_action = torch.zeros(1, rssm.action_dim, device=device)
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for step in range(steps):
            td = policy(td)  # the student filters the image o_t, the actor picks a_t
            stream.set_time("step", sequence=step)
            stream.log("student/view", rr.Image(td["pixels"].numpy()))
            # The teacher filters the privileged state s_t of the same step alongside.
            keep = (~td["is_init"].reshape(1, 1).bool()).float().to(device)
            t_state = rssm.filter_step(t_state, prev_action, teacher_wm.encoder(
                td["state"].reshape(1, -1).to(device)), keep)
            prev_action = td["action"].reshape(1, -1).to(device)
            belief = td["next", "agent", "belief"].reshape(1, -1).to(device)
            stoch = td["next", "agent", "stoch"].reshape(1, -1).to(device)
            decoded = teacher_wm.decode(torch.cat([belief, stoch], -1))[0].cpu()
            state = td["state"]
            for label, index in fields:
                stream.log(f"state/true/{label}", rr.Scalars(float(state[index])))
                stream.log(f"state/from_student_latent/{label}", rr.Scalars(float(decoded[index])))
            stream.log("latent/belief_distance",
                       rr.Scalars(float((t_state.belief - belief).norm())))
            for j, value in enumerate(td["action"].reshape(-1).tolist()):
                stream.log(f"action/{j}", rr.Scalars(value))
            td = env.step(td)
            stream.log("reward", rr.Scalars(float(td["next", "reward"])))
            td = step_mdp(td)
    stream.flush()
    stream.disconnect()
    os.replace(partial, path)
    return path
