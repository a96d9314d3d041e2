"""Every output is written atomically: a crash mid-write keeps the previous file (item 5)."""

import json

import pytest

from simdist.utils import atomic_path, write_json_atomic, write_text_atomic


def _no_temp_files(folder):
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name) == []


def test_atomic_path_replaces_on_success_and_keeps_the_old_file_on_error(tmp_path):
    out = tmp_path / "sub" / "results.json"
    write_text_atomic(out, "old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(out) as tmp:
            tmp.write_text("half")
            raise KeyboardInterrupt  # killed mid-write
    assert out.read_text() == "old" and _no_temp_files(out.parent)
    with atomic_path(out) as tmp:
        assert tmp.parent == out.parent and tmp.suffix == ".json"  # same file system, format
        tmp.write_text("new")
    assert out.read_text() == "new" and _no_temp_files(out.parent)


def test_json_that_cannot_be_serialised_touches_nothing(tmp_path):
    out = write_json_atomic(tmp_path / "r.json", {"a": 1})
    with pytest.raises(TypeError):
        write_json_atomic(out, {"a": object()})
    assert json.loads(out.read_text()) == {"a": 1} and _no_temp_files(tmp_path)


@pytest.mark.parametrize("which", ["simdist", "twist"])
def test_result_plots_survive_a_crash_mid_write(tmp_path, monkeypatch, which):
    from matplotlib.figure import Figure

    from simdist.pipelines import report, twist_report

    path = tmp_path / "plot.png"
    path.write_bytes(b"previous plot")

    def crash(self, fname, **kwargs):
        with open(fname, "wb") as f:
            f.write(b"\x89PNG half")
        raise OSError("disk full")

    monkeypatch.setattr(Figure, "savefig", crash)
    with pytest.raises(OSError, match="disk full"):
        if which == "simdist":
            report.plot_results({"minutes": [1], "simdist": [
                {"mean_fraction": 0.5, "std_fraction": 0.1}]}, "slippery_slope", path)
        else:
            twist_report.plot_results({"cartpole-balance": {"Oracle (state teacher)": {
                "returns": [1.0, 2.0], "seed_means": [1.5]}}}, path)
    assert path.read_bytes() == b"previous plot" and _no_temp_files(tmp_path)
