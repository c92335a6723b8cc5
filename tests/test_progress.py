"""Progress of `retrosim report` and `check`: a scene's bar counts its machine runs (every timing of a
variant on a machine, each robustness re-timing that runs included), reported from the forked
workers that run them (sim.parallel.report), up to a total that ends equal to the runs done; on a
pipe, nothing."""

import io
import re
from pathlib import Path

import pytest
from click.testing import CliRunner
from rich.console import Console

import sim.timing.kernel as kernel
from sim.cli import main, scene_cmds
from sim.scenes.progress import RunCount
from sim.scenes.registry import load_scene, run_scene
from test_parallel import CLAIMS_SCENE
from test_snapscene import SMALL as SNAP_SCENE
from test_sort import TINY as SORT_SCENE
from test_texture_scene import SMALL as TEXTURE_SCENE

SCENES = {"par": CLAIMS_SCENE, "sort-tiny": SORT_SCENE.format(name="sort-tiny", zscene="", zdist=""),
          "snap-small": SNAP_SCENE.replace("{name}", "snap-small"),
          "tex-small": TEXTURE_SCENE.replace("{name}", "tex-small")}


def scene_file(tmp_path: Path, name: str) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(SCENES[name])
    return path


def counted_run(path: Path, jobs: int) -> tuple[RunCount, list, object]:
    """A scene run with a tallying progress; every report's (done, total, what) in order."""
    seen = []
    count = RunCount(lambda c: seen.append((c.done, c.total, c.what)))
    result = run_scene(load_scene(path), progress=count, jobs=jobs)
    return count, seen, result


@pytest.mark.parametrize("name", ["par", "sort-tiny", "snap-small"])
def test_the_count_is_every_timing_that_runs_re_timings_included(tmp_path, monkeypatch, name):
    """In one process every timing goes through sim.timing.kernel.time_emulation: the bar's total ends
    equal to its calls, and no report ever counts more runs done than announced."""
    calls = []
    real = kernel.time_emulation
    monkeypatch.setattr(kernel, "time_emulation", lambda *a, **kw: calls.append(1) or real(*a, **kw))
    count, seen, result = counted_run(scene_file(tmp_path, name), jobs=1)
    assert count.done == count.total == len(calls)
    assert all(done <= total for done, total, _ in seen)
    if name != "snap-small":  # the kinds whose faster/slower claims are re-timed
        assert result.sensitivity
        assert len(calls) > len(result.timings)
        assert any(": re-timing 1 of " in what for _, _, what in seen)


def test_texture_probes_count_as_one_run_per_machine(tmp_path):
    count, _, result = counted_run(scene_file(tmp_path, "tex-small"), jobs=1)
    assert count.done == count.total == len(result.timings) + len(result.probes)


@pytest.mark.parametrize("name", ["par", "sort-tiny", "tex-small"])
def test_forked_workers_report_every_run_to_the_parent(tmp_path, name):
    """With two workers the runs happen in other processes: their reports reach the parent's
    progress through the pool's pipe, the same count as in one process."""
    path = scene_file(tmp_path, name)
    one, seen_one, _ = counted_run(path, jobs=1)
    two, seen_two, _ = counted_run(path, jobs=2)
    assert two.done == two.total == one.total
    assert {what for _, _, what in seen_two} == {what for _, _, what in seen_one}  # each run named


def test_a_terminal_shows_each_scene_and_its_runs_a_pipe_nothing(tmp_path, monkeypatch):
    path = scene_file(tmp_path, "sort-tiny")
    expected, _, _ = counted_run(path, jobs=1)
    piped = CliRunner().invoke(main, ["report", str(path), "--out", str(tmp_path / "piped"), "-j", "2"])
    assert piped.exit_code == 0, piped.output
    assert piped.stderr.splitlines() and all(line.startswith("wrote ") for line in piped.stderr.splitlines())

    screen = io.StringIO()
    monkeypatch.setattr(scene_cmds, "err_console", Console(file=screen, force_terminal=True,
                                                                   color_system=None, width=120))
    shown = CliRunner().invoke(main, ["report", str(path), "--out", str(tmp_path / "shown"), "-j", "2"])
    assert shown.exit_code == 0, shown.output
    frames = re.findall(r"sort-tiny: ([^\n\r]*?) [ ━╸╺]+ (\d+)/(\d+)", screen.getvalue())
    assert any("re-timing" in what for what, _, _ in frames)
    assert frames[-1][0].startswith("done") and frames[-1][1:] == (str(expected.total),) * 2
    for name in ("sort-tiny.md", "sort-tiny.json", "sort-tiny.csv"):  # the display changes no output
        assert (tmp_path / "shown" / name).read_bytes() == (tmp_path / "piped" / name).read_bytes()
