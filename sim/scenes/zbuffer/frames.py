"""Z-buffer frames in the guest: lay a scene's spans out in the workload arena, draw frames with a
variant's `<variant>_frame` driver (clear + one span call per span, kernels/zbuffer/draw.inc), and
read the buffers back. The emulation is CPU-independent; timing it per preset is sim.timing's job.

Arena layout, in allocation order (so addresses, and cache behaviour, are the same every run):
span records (32 bytes each), then the depth buffer, then the colour buffer, each 4 KB aligned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.scenes import raster
from sim.guest.kernels import kernels_root
from sim.timing.kernel import Emulation, emulate

VARIANTS = {v: f"zbuffer/{v}.S" for v in raster.VARIANTS}  # kernel source per variant
VARIANT_LABELS = {"z32": "32-bit integer", "z16": "16-bit integer", "fp16z": "16-bit float (BSR/SHRD/SHRD)",
                  "fp16t": "16-bit float (table, no BSR)", "zf32": "32-bit float (x87)"}


@dataclass(frozen=True)
class FrameLayout:
    records: int
    nspans: int
    zbuf: int
    zwords: int
    fbuf: int


def span_records(spans, variant: str, width: int, zbuf: int, fbuf: int, colours: np.ndarray) -> np.ndarray:
    """[n, 8] uint32 records for the driver: zbuf pointer, fbuf pointer, count, z, dz, colour, 0, 0."""
    size = raster.ZBUF_DTYPE[variant].itemsize
    pixel = spans.y.astype(np.int64) * width + spans.x0.astype(np.int64)
    z0, dz = raster.span_parameters(spans, variant)
    rec = np.zeros((spans.y.size, 8), np.uint32)
    rec[:, 0] = zbuf + size * pixel
    rec[:, 1] = fbuf + 2 * pixel
    rec[:, 2] = spans.count
    if variant == "zf32":
        rec[:, 3] = np.asarray(z0, np.float32).view(np.uint32)
        rec[:, 4] = np.asarray(dz, np.float32).view(np.uint32)
    else:
        rec[:, 3] = np.asarray(z0).astype(np.uint64) & 0xFFFFFFFF
        rec[:, 4] = np.asarray(dz).astype(np.int64).astype(np.uint64) & 0xFFFFFFFF
    rec[:, 5] = np.asarray(colours)[spans.tri]
    return rec


def frame_setup(spans, variant: str, width: int, height: int, colours: np.ndarray, layout: list):
    """A setup function for sim.timing.kernel.emulate: builds the frame in a fresh machine's arena and
    returns the driver's arguments. The chosen addresses are appended to `layout`."""
    zbytes = -(-width * height * raster.ZBUF_DTYPE[variant].itemsize // 32) * 32  # the clear works in 32-byte lines

    def setup(machine):
        arena = machine.arena
        records = arena.alloc(32 * max(1, spans.y.size), align=4096)
        zbuf = arena.alloc(zbytes, align=4096)
        fbuf = arena.alloc(2 * width * height, align=4096)
        machine.uc.mem_write(records, span_records(spans, variant, width, zbuf, fbuf, colours).tobytes())
        layout.append(FrameLayout(records, int(spans.y.size), zbuf, zbytes // 4, fbuf))
        return [records, int(spans.y.size), zbuf, zbytes // 4, raster.clear_dword(variant)]

    return setup


@dataclass
class FrameRun:
    variant: str
    emulation: Emulation
    zbuf: np.ndarray   # [height, width], the variant's stored depths after the last frame
    fbuf: np.ndarray   # [height, width] uint16 colours
    pixels: int        # pixels drawn per frame (sum of span lengths)


def draw_frames(spans, variant: str, width: int, height: int, frames: int = 2,
                colours: np.ndarray | None = None) -> FrameRun:
    """Emulate `frames` frames of one variant (the last one is the one a report times)."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown Z-buffer variant '{variant}' (choose one of: {', '.join(VARIANTS)})")
    path, dtype = VARIANTS[variant], raster.ZBUF_DTYPE[variant]
    if colours is None:
        colours = (np.arange(int(spans.tri.max(initial=-1)) + 1) + 1).astype(np.uint16)
    layout: list[FrameLayout] = []
    emu = emulate(kernels_root() / path, f"{variant}_frame", frame_setup(spans, variant, width, height, colours, layout),
                  repeat=frames, budget=0)
    lay = layout[-1]
    arena = emu.machine.arena
    zbuf = arena.get(lay.zbuf, dtype, width * height).reshape(height, width)
    fbuf = arena.get(lay.fbuf, np.uint16, width * height).reshape(height, width)
    return FrameRun(variant, emu, zbuf, fbuf, int(spans.count.sum()))
