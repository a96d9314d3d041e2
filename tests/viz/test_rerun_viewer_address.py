"""A spawned rerun viewer listens on localhost only, unless asked otherwise (issue 18, item 2)."""

import os
import shutil
import signal
import socket
import sys
import time

import pytest
import rerun as rr
import rerun_bindings

from simdist.viz import PlanningRecorder, spawn_viewer


@pytest.fixture
def spawned(monkeypatch):
    calls = {}
    monkeypatch.delenv("_RERUN_TEST_FORCE_SAVE", raising=False)
    monkeypatch.setattr(rerun_bindings, "spawn", lambda **kw: calls.setdefault("spawn", kw))
    monkeypatch.setattr(rr.RecordingStream, "connect_grpc",
                        lambda self, url=None, **kw: calls.setdefault("url", url))
    return calls


def test_spawned_viewer_binds_to_localhost_by_default(spawned):
    PlanningRecorder(None, spawn=True)
    args = spawned["spawn"]["extra_args"]
    assert args[args.index("--bind") + 1] == "127.0.0.1" and spawned["spawn"]["port"] == 9876
    assert spawned["url"] == "rerun+http://127.0.0.1:9876/proxy"


def test_the_address_and_port_can_be_chosen(spawned):
    PlanningRecorder(None, spawn=True, port=9999, bind="0.0.0.0")
    args = spawned["spawn"]["extra_args"]
    assert args[args.index("--bind") + 1] == "0.0.0.0" and spawned["spawn"]["port"] == 9999
    assert spawned["url"] == "rerun+http://127.0.0.1:9999/proxy"  # still connects locally


@pytest.mark.skipif(shutil.which("rerun") is None or not sys.platform.startswith("linux"),
                    reason="needs the rerun executable")
def test_the_real_viewer_reports_listening_on_localhost(capfd):
    with socket.socket() as s:  # a free port
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    pid = spawn_viewer(port=port, headless=True, detach_process=False)
    try:
        time.sleep(0.5)
    finally:
        if pid:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass  # a headless viewer without a GPU exits on its own once listening
            try:
                os.waitpid(pid, 0)  # our child: reap it
            except ChildProcessError:
                pass
    log = capfd.readouterr().err
    lines = [line for line in log.splitlines() if "Listening for gRPC connections" in line]
    if not lines:
        pytest.skip("this rerun version logs no listening address")
    assert f"127.0.0.1:{port}" in lines[0] and "0.0.0.0" not in lines[0]


def test_a_recording_appears_under_its_name_only_when_complete(tmp_path):
    path = tmp_path / "episode.rrd"
    recorder = PlanningRecorder(str(path))
    recorder.log_scalars(0, predicted_reward=1.0)
    assert not path.exists()  # a crash now leaves no truncated episode.rrd
    recorder.close()
    assert path.stat().st_size > 0 and [p.name for p in tmp_path.iterdir()] == ["episode.rrd"]
