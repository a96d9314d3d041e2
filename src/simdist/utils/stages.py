"""Checkpointed pipeline stages: finished stages are skipped on rerun, configs must match."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any, Callable


def _atomic_json(path: Path, payload: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=str))
    tmp.replace(path)


class StageRunner:
    """Runs a recipe's stages once each, under one output directory.

    ``run(name, fn)`` calls ``fn(stage_dir)`` unless ``<out>/stages/<name>.json`` exists,
    in which case the stored result is returned. A stage's result (a JSON-able dict) is
    written atomically only after ``fn`` returns, so a stage killed midway reruns (and can
    resume from whatever it checkpointed in its ``stage_dir``). The recipe config is saved
    as ``<out>/config.json``; rerunning into the same directory with a different config
    raises instead of mixing results.

    Examples:
        >>> import tempfile
        >>> runner = StageRunner(tempfile.mkdtemp(), {"seed": 0})
        >>> runner.run("count", lambda d: {"n": 3})
        {'n': 3}
        >>> runner.run("count", lambda d: {"n": 99})  # finished: not run again
        {'n': 3}
    """

    def __init__(self, out_dir: str | Path, config: Any):
        self.out = Path(out_dir)
        (self.out / "stages").mkdir(parents=True, exist_ok=True)
        config = dataclasses.asdict(config) if dataclasses.is_dataclass(config) else config
        config = json.loads(json.dumps(config, default=str))
        saved = self.out / "config.json"
        if saved.exists():
            previous = json.loads(saved.read_text())
            if previous != config:
                changed = sorted(k for k in set(previous) | set(config)
                                 if previous.get(k) != config.get(k))
                raise ValueError(f"{self.out} holds results of a different config (changed: "
                                 f"{changed}); use another --output-dir or the same settings")
        else:
            _atomic_json(saved, config)
        self.config = config
        self.timings: dict[str, float] = {}

    def stage_dir(self, name: str) -> Path:
        path = self.out / "stages" / name
        path.mkdir(parents=True, exist_ok=True)
        return path

    def done(self, name: str) -> bool:
        return (self.out / "stages" / f"{name}.json").exists()

    def run(self, name: str, fn: Callable[[Path], dict]) -> dict:
        record = self.out / "stages" / f"{name}.json"
        if record.exists():
            stored = json.loads(record.read_text())
            self.timings[name] = stored["seconds"]
            return stored["result"]
        start = time.perf_counter()
        result = fn(self.stage_dir(name))
        seconds = time.perf_counter() - start
        self.timings[name] = seconds
        _atomic_json(record, {"result": result, "seconds": seconds})
        return result
