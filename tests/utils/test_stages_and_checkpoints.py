import os
import time
from pathlib import Path

import pytest
import torch

from simdist.utils import (StageRunner, load_checkpoint, move_to_device, resolve_device,
                           run_jobs, save_atomic)


def test_finished_stages_are_skipped_and_killed_ones_rerun(tmp_path):
    calls = []

    def stage(directory):
        calls.append(directory.name)
        return {"value": len(calls)}

    runner = StageRunner(tmp_path, {"seed": 1})
    assert runner.run("a", stage) == {"value": 1}

    def killed(directory):
        (directory / "partial.txt").write_text("half done")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        runner.run("b", killed)
    rerun = StageRunner(tmp_path, {"seed": 1})
    assert rerun.run("a", stage) == {"value": 1} and calls == ["a"]  # not rerun
    assert rerun.run("b", stage) == {"value": 2}  # the killed stage runs again
    assert (tmp_path / "stages" / "b" / "partial.txt").exists()  # its checkpoint is kept
    assert set(rerun.timings) == {"a", "b"}


def test_a_different_config_is_refused(tmp_path):
    StageRunner(tmp_path, {"seed": 1, "steps": 5})
    with pytest.raises(ValueError, match="changed: \\['steps'\\]"):
        StageRunner(tmp_path, {"seed": 1, "steps": 6})


def test_a_field_added_later_reads_as_its_default_in_an_older_folder(tmp_path):
    import dataclasses

    @dataclasses.dataclass
    class Old:
        seed: int = 1

    @dataclasses.dataclass
    class New:
        seed: int = 1
        members: list = dataclasses.field(default_factory=lambda: [1])

    StageRunner(tmp_path, Old()).close()
    StageRunner(tmp_path, New()).close()  # the folder was made before the field existed
    with pytest.raises(ValueError, match="changed: \\['members'\\]"):
        StageRunner(tmp_path, New(members=[2]))


def test_a_field_whose_absence_meant_another_value_refuses_the_new_default(tmp_path):
    import dataclasses

    from simdist.utils.stages import ABSENT_MEANS

    @dataclasses.dataclass
    class Old:
        seed: int = 1

    @dataclasses.dataclass
    class New:  # a behaviour switched on by default; older folders were made without it
        seed: int = 1
        hide: list = dataclasses.field(default_factory=lambda: ["a"],
                                       metadata={ABSENT_MEANS: []})

    StageRunner(tmp_path, Old()).close()
    with pytest.raises(ValueError, match="changed: \\['hide'\\]"):
        StageRunner(tmp_path, New())
    StageRunner(tmp_path, New(hide=[])).close()  # what the folder was made with resumes


def test_runtime_keys_may_change_between_runs_but_nothing_else(tmp_path):
    keys = ("device",)
    StageRunner(tmp_path, {"seed": 1, "device": "cpu"}, runtime_keys=keys)
    StageRunner(tmp_path, {"seed": 1, "device": "cuda"}, runtime_keys=keys)  # resumes
    with pytest.raises(ValueError, match="changed: \\['seed'\\]"):
        StageRunner(tmp_path, {"seed": 2, "device": "cuda"}, runtime_keys=keys)
    with pytest.raises(ValueError, match="device"):
        StageRunner(tmp_path, {"seed": 1, "device": "cuda"})  # only when declared


def test_moved_optimiser_keeps_its_state_on_the_new_parameters():
    net = torch.nn.Linear(3, 2)
    optim = torch.optim.Adam(net.parameters())
    net(torch.ones(4, 3)).sum().backward()
    optim.step()
    exp_avg = optim.state[net.weight]["exp_avg"].clone()
    move_to_device([net], [optim], "meta")  # Module.to makes new Parameters for meta
    assert [id(p) for p in optim.param_groups[0]["params"]] == [id(net.weight), id(net.bias)]
    state = optim.state[net.weight]
    assert state["exp_avg"].device.type == "meta" and state["exp_avg"].shape == exp_avg.shape
    assert state["step"].device.type == "cpu"  # Adam keeps its step counter on the host
    assert len(optim.state) == 2


def test_device_names_are_checked_before_any_work():
    assert resolve_device("cpu") == torch.device("cpu")
    with pytest.raises(ValueError, match="unknown device"):
        resolve_device("gpu")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="0 CUDA device"):
            resolve_device("cuda")
        assert resolve_device("auto") == torch.device("cpu")


def test_atomic_save_keeps_the_old_file_when_writing_fails(tmp_path):
    path = tmp_path / "ckpt.pt"
    save_atomic({"w": torch.ones(2)}, path)

    class Unpicklable:
        def __reduce__(self):
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        save_atomic({"w": Unpicklable()}, path)
    assert torch.equal(load_checkpoint(path)["w"], torch.ones(2))
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt.pt"]  # no temp files left


def test_checkpoints_never_run_pickled_code(tmp_path):
    path = tmp_path / "evil.pt"

    class Payload:
        def __reduce__(self):
            return (os.system, ("echo pwned",))

    torch.save({"x": Payload()}, path)
    with pytest.raises(Exception, match="never unpickled"):
        load_checkpoint(path)


def test_stage_result_reads_finished_stages_only(tmp_path):
    runner = StageRunner(tmp_path, {"seed": 0})
    with pytest.raises(KeyError, match="has not finished"):
        runner.result("teacher")
    runner.run("teacher", lambda d: {"return": 5})
    assert StageRunner(tmp_path, {"seed": 0}).result("teacher") == {"return": 5}


def test_run_jobs_in_processes_keeps_order_and_raises_the_first_error():
    calls = [(pow, (2, 10)), (divmod, (7, 2)), (max, (3, 9))]
    assert run_jobs(calls, jobs=2) == run_jobs(calls, jobs=1) == [1024, (3, 1), 9]
    with pytest.raises(ZeroDivisionError):
        run_jobs([(pow, (2, 3)), (divmod, (1, 0))], jobs=2)
    with pytest.raises(ValueError, match="jobs must be >= 1"):
        run_jobs(calls, jobs=0)


def test_run_jobs_gives_each_worker_the_threads_asked_for():
    calls = [(torch.get_num_threads, ())] * 2
    assert run_jobs(calls, jobs=2, threads=1) == [1, 1]
    assert run_jobs(calls, jobs=2, threads=3) == [3, 3]
    with pytest.raises(ValueError, match="threads must be >= 1"):
        run_jobs(calls, jobs=2, threads=0)


def _stamp(path: str, name: str, seconds: float) -> str:
    """Appends ``name start`` and ``name end`` to ``path`` around a sleep (a run_jobs call)."""
    with open(path, "a") as f:
        f.write(f"{name} start\n")
    time.sleep(seconds)
    with open(path, "a") as f:
        f.write(f"{name} end\n")
    return name


def test_run_jobs_starts_a_call_only_after_its_prerequisites_and_in_list_order(tmp_path):
    log = str(tmp_path / "log")
    # teacher (slow) | baseline beside it; the students wait for the teacher and, once
    # it is done, start before the second baseline listed after them
    calls = [(_stamp, (log, "teacher", 1.5)), (_stamp, (log, "student_a", 0.1)),
             (_stamp, (log, "student_b", 0.1)), (_stamp, (log, "baseline_1", 2.5)),
             (_stamp, (log, "baseline_2", 0.1))]
    after = [(), (0,), (0,), (), ()]
    assert run_jobs(calls, jobs=2, after=after) == [c[1][1] for c in calls]
    lines = Path(log).read_text().split("\n")
    at = {line: i for i, line in enumerate(lines)}
    assert at["teacher end"] < at["student_a start"] and at["teacher end"] < at["student_b start"]
    assert at["student_b start"] < at["baseline_2 start"]  # list order is the priority
    assert run_jobs(calls[:3], jobs=1, after=after[:3]) == ["teacher", "student_a", "student_b"]


def test_run_jobs_refuses_a_prerequisite_listed_later_or_a_wrong_length():
    calls = [(pow, (2, 3)), (divmod, (7, 2))]
    with pytest.raises(ValueError, match="only wait for calls listed before it"):
        run_jobs(calls, jobs=2, after=[(1,), ()])
    with pytest.raises(ValueError, match="only wait for calls listed before it"):
        run_jobs(calls, jobs=2, after=[(), (1,)])
    with pytest.raises(ValueError, match="after has 1 entries for 2 calls"):
        run_jobs(calls, jobs=2, after=[()])
