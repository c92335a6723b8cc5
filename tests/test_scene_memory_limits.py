"""Issue 26: scenes within the documented limits stay under about 2 GB of host memory; a scene just
over a limit is refused at load (no emulation), in one line naming the file, the field and the limit."""

from __future__ import annotations

import time

import pytest

from sim.scenes.registry import load_scene
from sim.scenes.schema import SceneError
from sim.scenes.snap import scene as snap_scene
from sim.scenes.zbuffer import scene as zb_scene

TWO_GB = 2 << 30


def _refusal(path) -> str:
    t = time.monotonic()
    with pytest.raises(SceneError) as e:
        load_scene(path)
    assert time.monotonic() - t < 30  # validation only
    line = str(e.value)
    assert "\n" not in line and path.name in line
    return line


def _zbuffer(tmp_path, name, depth, frames):
    p = tmp_path / f"{name}.toml"
    p.write_text(f'[scene]\nname = "{name}"\nwidth = 640\nheight = 480\n[geometry]\ngenerator = "random"\nseed = 1\n'
                 f'triangles = 400\ndepth_complexity = {depth}\n[run]\nvariants = ["fp16t"]\ncpus = ["pentium2-233"]\n'
                 f'frames = {frames}\n')
    return p


def test_zbuffer_work_over_all_frames_is_bounded(tmp_path):
    # depth complexity 3 on 640x480 is about 0.9 M visits a frame: 9 frames pass 8 M, 4 do not
    line = _refusal(_zbuffer(tmp_path, "many", 3.0, 9))
    assert "geometry" in line and "run.frames" in line and "8,000,000" in line and "RETROSIM_MAX_VISITS" in line
    load_scene(_zbuffer(tmp_path, "few", 3.0, 4))


def test_zbuffer_deep_single_frame_is_refused(tmp_path):
    line = _refusal(_zbuffer(tmp_path, "deep", 30.0, 1))
    assert "geometry" in line and "RETROSIM_MAX_VISITS" in line


def test_zbuffer_spans_count_toward_the_limit():
    # many small triangles (the 65,535-triangle scene of the issue: 7.3 M visits, 1 M spans) pass
    # the limit through their spans though their visits alone would not
    assert zb_scene.frame_work(7_300_000, 0, 1) < zb_scene.DEFAULT_MAX_VISITS < zb_scene.frame_work(7_300_000, 1_000_000, 1)


def test_the_largest_zbuffer_scene_is_estimated_under_2_gb():
    assert zb_scene.estimate_bytes(zb_scene.DEFAULT_MAX_VISITS) < TWO_GB


def test_snap_vertices_just_over_the_limit_are_refused(tmp_path):
    n = snap_scene.MAX_VERTICES + 1
    p = tmp_path / "huge.toml"
    p.write_text(f'[scene]\nname = "huge"\nkind = "snap"\n[workloads]\nnames = ["screen"]\nvertices = {n}\nseed = 1\n'
                 '[run]\nvariants = ["trick-24"]\ncpus = ["pentium2-233"]\n')
    line = _refusal(p)
    assert "workloads.vertices" in line and str(snap_scene.MAX_VERTICES) in line
    assert snap_scene.MAX_VERTICES * snap_scene.VERTEX_BYTES < TWO_GB
