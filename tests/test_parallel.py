"""report/check --jobs: a scene's timings in forked workers that share its emulation; the same
results for any number of workers."""

import subprocess
import sys
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from sim.cli import main
from sim.parallel import SharedPool
from sim.scenes.registry import load_scene, run_scene

ROOT = Path(__file__).resolve().parent.parent


def _task(shared, i):
    array, unpicklable = shared
    return int(array[i::4].sum()) + unpicklable(i)


def test_workers_read_the_shared_object_without_pickling_it():
    # a lambda cannot be pickled: the workers can only have it by inheritance (fork)
    shared = (np.arange(1000, dtype=np.int64), lambda i: 1000 * i)
    expect = [_task(shared, i) for i in range(4)]
    with SharedPool(shared, 2) as pool:
        assert [pool.submit(_task, i).result() for i in range(4)] == expect
    with SharedPool(shared, 1) as pool:
        assert [pool.submit(_task, i).result() for i in range(4)] == expect


def test_scene_results_do_not_depend_on_jobs():
    scene = load_scene(ROOT / "scenes/zbuffer-small.toml")
    one = run_scene(scene, jobs=1)
    two = run_scene(scene, jobs=2)
    assert [(t.variant, t.key) for t in one.timings] == [(t.variant, t.key) for t in two.timings]
    assert [t.counters for t in one.timings] == [t.counters for t in two.timings]
    assert len(one.timings) == len(scene.variants) * len(scene.cpus)


CLAIMS_SCENE = """[scene]
name = "par"
width = 48
height = 32
[geometry]
generator = "random"
seed = 7
triangles = 6
depth_complexity = 2.0
[run]
variants = ["z32", "fp16z"]
cpus = ["pentium2-233:edo", "k6-2-300"]
[[run.machine]]
cpu = "k6-233"
set = { "write_allocate.mode" = "full" }
[[claims]]
text = "BSR is dear on the K6"
families = ["k6"]
variants = ["fp16z", "z32"]
expect = "slower"
"""


def test_claim_robustness_does_not_depend_on_jobs(tmp_path):
    path = tmp_path / "par.toml"
    path.write_text(CLAIMS_SCENE)
    scene = load_scene(path)
    one, two = run_scene(scene, jobs=1), run_scene(scene, jobs=2)
    assert [t.counters for t in one.timings] == [t.counters for t in two.timings]
    assert set(one.sensitivity) == {(v, k) for v in ("z32", "fp16z")
                                    for k in ("k6-2-300:sdram-pc100", "k6-233{write_allocate.mode=full}:sdram-pc66")}
    assert one.sensitivity == two.sensitivity


def test_jobs_must_be_positive():
    r = CliRunner().invoke(main, ["report", "zbuffer-small", "--jobs", "0", "--out", "/nonexistent/x"],
                           catch_exceptions=False)
    assert r.exit_code == 2


def test_warm_compiles_the_largest_core_here_and_the_others_in_children():
    # in a fresh process, so that no family is warm yet; the children's work reaches this process
    # only through numba's on-disk cache, so each family must end warm here too
    code = """
from sim import parallel
from sim.cpus.build import make_model
models = [make_model(c) for c in ("pentium-mmx-233", "k6-233", "pentium2-233", "pentium2-300")]
forks = []
real = parallel._fork
parallel._fork = lambda task, *args: forks.append([m.family for m in args[0]]) or real(task, *args)
parallel.warm(models, jobs=2)
print(sorted(parallel._WARM), forks, max(models, key=parallel._core_bytes).family)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")[0]
    assert out == "['k6', 'p5', 'p6'] [['k6', 'p5']] p6"
