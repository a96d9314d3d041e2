"""Evaluation and collection rollouts show a progress bar when given a description."""

from __future__ import annotations

from tqdm import tqdm

import simdist.pipelines.locomotion as locomotion
from simdist.envs import get_target
from simdist.pipelines import locomotion_env, rollout


class RecordingBar(tqdm):
    """A tqdm that remembers, per description, how many steps it counted when closed."""

    closed: dict = {}

    def close(self):
        RecordingBar.closed[self.desc] = (self.n, self.total)
        super().close()


def test_rollout_with_desc_counts_every_step(monkeypatch, capsys):
    monkeypatch.setattr(locomotion, "tqdm", RecordingBar)
    updates = []
    monkeypatch.setattr(RecordingBar, "update", lambda self, n=1: (
        updates.append(n), tqdm.update(self, n))[1])
    env = locomotion_env(get_target("sim"), episodes=2, steps=6, seed=0)
    td = rollout(env, None, 6, desc="evaluate in sim")
    env.close()
    assert td.shape == (2, 6)
    assert RecordingBar.closed["evaluate in sim"] == (6, 6)
    assert len(updates) >= 5  # one per step from TorchRL's callback, not one jump at the end
    assert "evaluate in sim" in capsys.readouterr().err


def test_rollout_without_desc_is_silent(capsys):
    env = locomotion_env(get_target("sim"), episodes=2, steps=4, seed=0)
    rollout(env, None, 4)
    env.close()
    assert "step" not in capsys.readouterr().err
