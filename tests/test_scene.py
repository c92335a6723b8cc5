"""Scene files: a valid file loads with typed fields and needs; each problem gives one error line
naming the file and the dotted field."""

import re

import numpy as np
import pytest

from sim.scenes import raster as R
from sim.errors import RetrosimError
from sim.scenes.registry import load_scene
from sim.scenes.schema import SceneError

VALID = """\
[scene]
name = "zbuffer-article"
description = "The article's experiment"
width = 640
height = 480

[geometry]
generator = "random"
seed = 1998
triangles = 300
depth_complexity = 3.0
z_range = [0.05, 0.95]

[run]
variants = ["z32", "z16", "fp16z", "zf32"]
cpus = ["pentium2-233:edo", "pentium2-233:sdram-pc100", "celeron-300a", "celeron-266"]
metrics = ["visibility", "depth_error", "fp16_precision"]
frames = 2
"""

TRIANGLES = """\
[scene]
name = "two"
width = 64
height = 48

[geometry]
generator = "triangles"

[[geometry.triangle]]
xy = [[1.5, 2.25], [40, 3], [10, 30.5]]
z = [0.1, 0.2, 0.3]

[[geometry.triangle]]
xy = [[40, 3], [10, 30.5], [45, 33]]
z = [0.2, 0.3, 0.4]
colour = 9

[run]
variants = ["z16"]
cpus = ["celeron-300a"]
metrics = ["depth_error"]
"""


def write(tmp_path, text, stem="zbuffer-article"):
    path = tmp_path / f"{stem}.toml"
    path.write_text(text)
    return path


def test_valid_scene_loads_typed(tmp_path):
    s = load_scene(write(tmp_path, VALID))
    assert (s.name, s.width, s.height) == ("zbuffer-article", 640, 480)
    g = s.geometry
    assert (g.generator, g.seed, g.triangles, g.depth_complexity, g.z_range) == ("random", 1998, 300, 3.0, (0.05, 0.95))
    assert s.run.variants == ("z32", "z16", "fp16z", "zf32") and s.run.frames == 2
    labels = [c.label for c in s.run.cpus]
    assert labels[:2] == ["pentium2-233:edo", "pentium2-233:sdram-pc100"]
    assert not s.run.cpus[2].memory_given and s.run.cpus[2].memory  # the preset's default memory
    geo = s.build_geometry()
    np.testing.assert_array_equal(geo.xy, R.random_scene(640, 480, 300, 3.0, 1998).xy)
    n = s.needs
    assert n.kernels == ("kernels/zbuffer/z32.S", "kernels/zbuffer/z16.S", "kernels/zbuffer/fp16z.S",
                         "kernels/zbuffer/zf32.S")
    assert n.entries[2] == "fp16z_frame"
    assert n.cpus == ("pentium2-233", "celeron-300a", "celeron-266")
    assert "edo" in n.memories and "sdram-pc100" in n.memories
    assert n.colour_buffer and n.reference
    assert len(s.rasterize()) <= s.span_bound
    assert 640 * 480 * 6 < n.arena_bytes < 16 << 20
    n.as_dict()


def test_triangles_generator_and_depth_only_needs(tmp_path):
    s = load_scene(write(tmp_path, TRIANGLES, "two"))
    g = s.build_geometry()
    assert g.colour.tolist() == [1, 9]
    np.testing.assert_array_equal(g.xy[1], [[40, 3], [10, 30.5], [45, 33]])
    n = s.needs
    assert n.kernels == ("kernels/zbuffer/z16.S",) and n.cpus == ("celeron-300a",)
    assert not n.colour_buffer and n.reference  # depth_error only: no frame buffer is read
    only_table = TRIANGLES.replace('metrics = ["depth_error"]', 'metrics = ["fp16_precision"]')
    n2 = load_scene(write(tmp_path, only_table, "two")).needs
    assert not n2.colour_buffer and not n2.reference
    assert n2.zbuf_bytes == {"z16": 2}


@pytest.mark.parametrize("generator,extra", [
    ("coplanar_far", "pairs = 12\nseparation = 1e-6"),
    ("steep", "triangles = 10"),
    ("near_far", ""),
    ("tiny", "triangles = 50"),
])
def test_other_generators(tmp_path, generator, extra):
    text = VALID.replace('generator = "random"\nseed = 1998\ntriangles = 300\ndepth_complexity = 3.0\n'
                         'z_range = [0.05, 0.95]', f'generator = "{generator}"\nseed = 5\n{extra}')
    if generator == "coplanar_far":
        text = text.replace('"fp16_precision"]', '"z_fighting"]')
    s = load_scene(write(tmp_path, text))
    g = s.build_geometry()
    assert len(g) > 0 and s.needs.colour_buffer
    if generator == "coplanar_far":
        assert len(g) == 24 and g.pairs.shape == (12, 2)


def sub(old, new):
    return lambda text: text.replace(old, new, 1)


# (edit of the valid file, file stem, the line, the field, a phrase of the message)
BAD = {
    "unknown key": (sub("frames = 2", "frames = 2\nframe = 3"), None, 19, "run.frame",
                    "unknown key (allowed: variants, cpus, metrics, frames, machine)"),
    "unknown key for generator": (sub("seed = 1998", "seed = 1998\npairs = 3"), None, 10, "geometry.pairs",
                                  "unknown key for generator 'random'"),
    "wrong type": (sub("seed = 1998", 'seed = "1998"'), None, 9, "geometry.seed",
                   "expected an integer, got string '1998'"),
    "wrong type bool": (sub("width = 640", "width = true"), None, 4, "scene.width", "expected an integer, got boolean"),
    "wrong list item": (sub('"z16", "fp16z"', '"z16", 7'), None, 15, "run.variants[2]", "expected a string"),
    "missing field": (sub("seed = 1998\n", ""), None, 7, "geometry.seed", "missing required field"),
    "missing table": (lambda t: t[:t.index("[run]")], None, None, "run", "missing required table [run]"),
    "unknown table": (lambda t: t + "\n[extra]\nx = 1\n", None, 20, "extra", "unknown table"),
    "unknown variant": (sub('"fp16z"', '"fp24z"'), None, 15, "run.variants[2]",
                        "unknown variant 'fp24z' (known: z32, z16, fp16z, fp16t, zf32)"),
    "duplicate variant": (sub('"fp16z", "zf32"', '"fp16z", "z16"'), None, 15, "run.variants[3]", "'z16' is listed twice"),
    "unknown cpu": (sub('"celeron-266"', '"celeron-433"'), None, 16, "run.cpus[3]", "unknown CPU preset 'celeron-433'"),
    "unknown memory": (sub("pentium2-233:edo", "pentium2-233:ddr-266"), None, 16, "run.cpus[0]",
                       "unknown memory preset 'ddr-266'"),
    "unknown metric": (sub('"depth_error"', '"psnr"'), None, 17, "run.metrics[1]", "unknown metric 'psnr'"),
    "z_fighting needs pairs": (sub('"depth_error"', '"z_fighting"'), None, 17, "run.metrics[1]",
                               "needs coplanar pairs"),
    "unknown generator": (sub('"random"', '"fractal"'), None, 8, "geometry.generator", "unknown generator 'fractal'"),
    "depth complexity": (sub("depth_complexity = 3.0", "depth_complexity = 0"), None, 11,
                         "geometry.depth_complexity", "must be > 0"),
    "z range": (sub("[0.05, 0.95]", "[0.95, 0.05]"), None, 12, "geometry.z_range", "need 0 <= lo < hi <= 1"),
    "too many triangles": (sub("triangles = 300", "triangles = 70000"), None, 10, "geometry.triangles",
                           "must be <= 65535"),
    "frames": (sub("frames = 2", "frames = 0"), None, 18, "run.frames", "must be >= 1"),
    "too-large screen": (lambda t: t.replace("width = 640", "width = 8192").replace("height = 480", "height = 4096"),
                         None, 4, "scene.width", "does not fit in the guest arena: it needs"),
    "name mismatch": (sub('name = "zbuffer-article"', 'name = "zbuffer"'), None, 2, "scene.name",
                      "'zbuffer' must equal the file name 'zbuffer-article'"),
    "name vs stem": (None, "article", 2, "scene.name", "must equal the file name 'article'"),
    "toml syntax": (sub("triangles = 300", "triangles 300"), None, 10, None, "TOML syntax error"),
    "toml duplicate key": (sub("frames = 2", "frames = 2\nframes = 3"), None, 19, None, "TOML syntax error"),
}


@pytest.mark.parametrize("case", BAD)
def test_each_problem_gives_one_error_naming_file_and_field(tmp_path, case):
    edit, stem, line, field, phrase = BAD[case]
    path = write(tmp_path, edit(VALID) if edit else VALID, stem or "zbuffer-article")
    with pytest.raises(SceneError) as info:
        load_scene(path)
    msg = str(info.value)
    assert isinstance(info.value, RetrosimError)
    assert "\n" not in msg
    prefix = f"{path}:{line}: " if line else f"{path}: "
    assert msg.startswith(prefix), msg
    if field:
        assert msg[len(prefix):].startswith(f"{field}: "), msg
    assert phrase in msg, msg


def test_too_large_screen_says_bytes_needed_and_available(monkeypatch, tmp_path):
    text = VALID.replace("width = 640", "width = 4096").replace("height = 480", "height = 3072")
    with pytest.raises(SceneError) as info:
        load_scene(write(tmp_path, text))
    msg = str(info.value)
    nums = [int(n.replace(",", "")) for n in re.findall(r"\d[\d,]{6,}", msg)]
    need, zbuf, fbuf = nums[0], nums[1], nums[2]
    assert zbuf == 4096 * 3072 * 4 and fbuf == 4096 * 3072 * 2 and need > 64 << 20
    assert "67,108,864" in msg
    # a 16-bit-only scene of the same size does fit: 2 + 2 bytes per pixel
    ok = text.replace('["z32", "z16", "fp16z", "zf32"]', '["z16", "fp16z"]')
    monkeypatch.setenv("RETROSIM_MAX_VISITS", str(10**9))  # the arena check alone (host memory: issue 26)
    assert load_scene(write(tmp_path, ok)).needs.arena_bytes <= 64 << 20


def test_triangle_table_errors_name_the_triangle(tmp_path):
    bad = TRIANGLES.replace("z = [0.2, 0.3, 0.4]", "z = [0.2, 0.3, 1.5]")
    with pytest.raises(SceneError, match=r"two\.toml:15: geometry\.triangle\[1\]\.z: depths must be in \[0, 1\)"):
        load_scene(write(tmp_path, bad, "two"))
    bad = TRIANGLES.replace("colour = 9", "color = 9")
    with pytest.raises(SceneError, match=r":16: geometry\.triangle\[1\]\.color: unknown key"):
        load_scene(write(tmp_path, bad, "two"))
    bad = TRIANGLES.replace("xy = [[40, 3], [10, 30.5], [45, 33]]", "xy = [[40, 3], [10, 30.5]]")
    with pytest.raises(SceneError, match=r":14: geometry\.triangle\[1\]\.xy: expected three \[x, y\] pairs"):
        load_scene(write(tmp_path, bad, "two"))


def test_missing_file_is_a_scene_error(tmp_path):
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path / "nope.toml")
