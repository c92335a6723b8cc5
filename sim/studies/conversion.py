"""The conversion study: how the article's three instructions (BSR / SHRD / SHRD) decode and what
they cost per CPU, back to back and interleaved with simple instructions (kernels/convert/loops.S).
Its report (sim/reports/conversion.py) is generated with the scene reports by `retrosim report`;
never edited by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim import reference as ref
from sim.errors import RetrosimError
from sim.guest.kernels import kernels_root
from sim.reports.conversion import conversion_markdown
from sim.reports.render import atomic_write
from sim.timing.kernel import emulate, time_emulation
from sim.reports.views import explain_rows

KERNEL = "convert/loops.S"
ENTRIES = ("convert_plain", "convert_interleaved")
ELEMENTS = 1024  # 4 KB in, 2 KB out: fits every L1D (8 KB on the Pentium Pro), so decode is what varies
DEFAULT_CPUS = ("pentium-pro-200", "pentium2-233", "celeron-300a", "pentium3-500", "k6-233", "k6-2-300", "k6-3-450")


def _inputs() -> np.ndarray:
    # depths of a typical frame: 24-bit-or-more magnitudes, where the stale-EDX hazard cannot occur
    return np.random.default_rng(1998).integers(1 << 12, 1 << 31, ELEMENTS + 1).astype(np.uint32)


def conversion_results(cpus=DEFAULT_CPUS) -> dict:
    values = _inputs()
    out = {"elements": ELEMENTS, "cpus": {}}
    for entry in ENTRIES:
        dst: list[int] = []

        def setup(m):
            dst.append(m.arena.alloc(2 * ELEMENTS + 64))
            return [m.arena.put(values), dst[-1], ELEMENTS]

        emu = emulate(kernels_root() / KERNEL, entry, setup, repeat=2)
        got = emu.machine.arena.get(dst[-1], np.uint16, ELEMENTS)
        want = ref.fp16z_encode(values[:ELEMENTS])
        if not np.array_equal(got, want):
            raise RetrosimError(f"{KERNEL}:{entry}: results differ from the reference conversion")
        for cpu in cpus:
            r = time_emulation(emu, cpu)
            c = r.last
            rows = {row["instruction"].split()[0] + " " + row["instruction"].split(" ", 1)[1]: row
                    for row in explain_rows(r) if row["instruction"].startswith(("bsr", "shrd"))}
            out["cpus"].setdefault(cpu, {})[entry] = {
                "cycles_per_element": round(c["cycles"] / ELEMENTS, 3),
                "decode_groups_per_element": round(c["decode_groups"] / ELEMENTS, 3),
                "decoders_per_element": [round(c[f"decoder{k}"] / ELEMENTS, 3) for k in range(3)],
                "uops_per_element": round(c["uops"] / ELEMENTS, 3),
                "conversion": [{k: row[k] for k in ("instruction", "decoder", "decoder_class", "uops", "ports",
                                                    "issue_to_retire", "row", "source")} for row in rows.values()],
            }
    return out


def write_report(path: Path, cpus=DEFAULT_CPUS) -> Path:
    """Time the conversion and write its report to `path` (the checked writer)."""
    atomic_write(path, conversion_markdown(conversion_results(cpus)).encode())
    return path
