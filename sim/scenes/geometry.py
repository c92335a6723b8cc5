"""A rasterized frame as a scene file describes it: the screen ([scene] width and height) and the
triangles ([geometry]: a generator of sim.scenes.raster and its arguments, or explicit triangles).
Shared by the Z-buffer kind, which draws the frame (sim.scenes.zbuffer.scene documents the format),
and the sort kind, whose "zbuffer" keys are the depth codes of a Z-buffer scene's frame
(sim.scenes.sort.keys reads that file's frame with :func:`load_frame`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sim.scenes import raster
from sim.scenes.schema import SCENE_DESCRIPTION, SCENE_KIND, SCENE_NAME, SEED_RANGE, Field, Validator, read_scene, show

KIND = "zbuffer"  # the kind of scene a frame's file is (its loader: sim.scenes.zbuffer.scene)
TABLES = ("scene", "geometry", "run", "claims")  # the top-level tables of such a file
GENERATORS = ("random", "coplanar_far", "steep", "near_far", "tiny", "triangles")
MAX_COORDINATE = 1 << 20  # screens are at most 32768 wide; the plane math stays exact far beyond
MAX_TRIANGLES = raster.MAX_TRIANGLES

# [scene] of a frame's file ([scene] kind may be left out: "zbuffer" is the default kind)
SCENE = (replace(SCENE_KIND, required=False), SCENE_NAME, SCENE_DESCRIPTION,
         Field("width", "int", True, min=1, max=1 << 15, doc="pixels"),
         Field("height", "int", True, min=1, max=1 << 15, doc="pixels"))
GENERATOR = Field("generator", "str", True, choices=GENERATORS, noun="generator")
_SEED = Field("seed", "int", True, span=SEED_RANGE)
_TRIANGLES = Field("triangles", "int", min=1, max=MAX_TRIANGLES, max_note=" (colours are 16-bit: triangle index + 1)")
_Z_RANGE = Field("z_range", "range", doc="depths, 0 <= lo < hi <= 1")
# [geometry]: each generator's arguments (sim.scenes.raster's generator functions)
GENERATOR_FIELDS = {
    "random": (_SEED, replace(_TRIANGLES, required=True), Field("depth_complexity", "number", True), _Z_RANGE),
    "coplanar_far": (_SEED, Field("pairs", "int", min=1, max=MAX_TRIANGLES // 2), _Z_RANGE,
                     Field("separation", "number", doc="depth gap of each pair")),
    "steep": (_SEED, _TRIANGLES, _Z_RANGE),
    "near_far": (_SEED, _TRIANGLES),
    "tiny": (_SEED, _TRIANGLES),
    "triangles": (Field("triangle", "tables", True, doc="[[geometry.triangle]] tables"),),
}
TRIANGLE = (Field("xy", "any", True, doc="[[x, y], [x, y], [x, y]]"), Field("z", "any", True, doc="three in [0, 1)"),
            Field("colour", "int", doc="1..65535 (default: the triangle's index + 1)"))


@dataclass(frozen=True)
class TriangleSpec:
    xy: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    z: tuple[float, float, float]
    colour: int | None = None


@dataclass(frozen=True)
class GeometrySpec:
    """[geometry]: the generator and its arguments (None: the generator's default)."""

    generator: str
    seed: int | None = None
    triangles: int | None = None
    depth_complexity: float | None = None
    z_range: tuple[float, float] | None = None
    pairs: int | None = None
    separation: float | None = None
    triangle_list: tuple[TriangleSpec, ...] = ()

    def build(self, width: int, height: int) -> raster.Geometry:
        g = self.generator
        opt = {k: v for k, v in (("z_range", self.z_range), ("separation", self.separation),
                                 ("pairs", self.pairs)) if v is not None}
        if g == "random":
            return raster.random_scene(width, height, self.triangles, self.depth_complexity, self.seed, **opt)
        if g == "coplanar_far":
            return raster.coplanar_far_scene(width, height, seed=self.seed, **opt)
        if g == "triangles":
            t = self.triangle_list
            colours = np.array([c.colour if c.colour is not None else i + 1 for i, c in enumerate(t)], np.int64)
            return raster.Geometry(np.array([c.xy for c in t], np.float64).reshape(-1, 3, 2),
                                   np.array([c.z for c in t], np.float64).reshape(-1, 3), colours)
        if self.triangles is not None:
            opt["triangles"] = self.triangles
        return raster.GENERATORS[g](width, height, seed=self.seed, **opt)


def _numbers(v, shape: tuple[int, ...]) -> bool:
    if len(shape) == 0:
        return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
    return isinstance(v, list) and len(v) == shape[0] and all(_numbers(x, shape[1:]) for x in v)


def read_geometry(v: Validator, doc: dict) -> GeometrySpec:
    """The [geometry] table of a parsed scene, validated (one SceneError naming file, line and field)."""
    ge = v.table(doc, "geometry")
    if "generator" not in ge:
        v.fail("geometry.generator", f"missing required field (one of: {', '.join(GENERATORS)})", "geometry")
    gen = v.values(ge, (GENERATOR,), "geometry")["generator"]
    fields = GENERATOR_FIELDS[gen]
    vals = v.section(ge, (GENERATOR,) + fields, "geometry", note=f" for generator '{gen}'")
    vals = {f.name: vals[f.name] for f in fields}
    if vals.get("depth_complexity") is not None and not 0 < vals["depth_complexity"] <= MAX_TRIANGLES:
        # a pixel is drawn at most once per triangle: beyond that the target is unreachable (and
        # near the float maximum the generator's area arithmetic overflows)
        v.fail("geometry.depth_complexity", f"must be > 0 and at most {MAX_TRIANGLES} (a pixel is drawn at most "
               f"once per triangle), got {vals['depth_complexity']}", "geometry", "depth_complexity")
    if gen == "coplanar_far" and vals.get("separation") is not None:
        lo, hi = vals.get("z_range") or (0.85, 0.95)
        if not 0 < vals["separation"] < hi - lo:
            v.fail("geometry.separation", f"must be > 0 and smaller than the z range ({hi - lo:g}), "
                   f"got {vals['separation']}", "geometry", "separation")
    triangle_list: list[TriangleSpec] = []
    if gen == "triangles":
        tables = vals.pop("triangle")
        if not tables:
            v.fail("geometry.triangle", "needs at least one [[geometry.triangle]]", "geometry")
        if len(tables) > MAX_TRIANGLES:
            v.fail("geometry.triangle", f"{len(tables)} triangles: at most {MAX_TRIANGLES}", "geometry")
        for i, t in enumerate(tables):
            triangle_list.append(_triangle(v, t, i))
    return GeometrySpec(gen, triangle_list=tuple(triangle_list), **vals)


def _triangle(v: Validator, t: dict, i: int) -> TriangleSpec:
    tname, field = "geometry.triangle", f"geometry.triangle[{i}]"
    v.keys(t, TRIANGLE, tname, i, field)
    if not _numbers(t["xy"], (3, 2)):
        v.fail(f"{field}.xy", f"expected three [x, y] pairs of finite numbers, got {show(t['xy'])}", tname, "xy", i)
    if any(abs(float(c)) > MAX_COORDINATE for p in t["xy"] for c in p):
        # the plane setup multiplies coordinate differences: far beyond the screen they overflow
        v.fail(f"{field}.xy", f"coordinates must be within +-{MAX_COORDINATE:,} pixels, got {show(t['xy'])}",
               tname, "xy", i)
    if not _numbers(t["z"], (3,)):
        v.fail(f"{field}.z", f"expected three finite numbers, got {show(t['z'])}", tname, "z", i)
    if not all(0.0 <= float(z) < 1.0 for z in t["z"]):
        v.fail(f"{field}.z", f"depths must be in [0, 1), got {show(t['z'])}", tname, "z", i)
    colour = v.typed(t, "colour", "int", tname, i, field)
    if colour is not None and not 1 <= colour <= 0xFFFF:
        v.fail(f"{field}.colour", f"must be 1..65535 (0 means 'no triangle'), got {colour}", tname, "colour", i)
    return TriangleSpec(tuple(tuple(float(c) for c in p) for p in t["xy"]), tuple(float(z) for z in t["z"]), colour)


@dataclass(frozen=True)
class Frame:
    """The frame of a scene file: its name, screen and geometry."""

    name: str
    width: int
    height: int
    geometry: GeometrySpec

    def build_geometry(self) -> raster.Geometry:
        return self.geometry.build(self.width, self.height)


def load_frame(path: Path) -> Frame:
    """The frame of the Z-buffer scene file `path`: its [scene] and [geometry] validated as the
    Z-buffer kind's loader validates them (its [run] and [[claims]] are not read)."""
    text, doc = read_scene(path)
    v = Validator(path, text)
    sc = v.scene_header(doc, KIND, TABLES, SCENE)
    return Frame(sc["name"], sc["width"], sc["height"], read_geometry(v, doc))
