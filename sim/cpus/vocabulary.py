"""The words a family's views use for the shared counters.

The timing cores of every family fill the same counter slots (``port0``..``port4``,
``decoder0``..``decoder2``, ``msrom_uops``, the stall kinds; see :mod:`sim.cpus.contract`), but the
slots mean different hardware on each family: port 0 is a P6 execution port and the K6's X
integer unit. Each model class carries a :class:`Vocabulary` (``Model.vocabulary``) so that tables,
reports and legends name the hardware of the CPU they describe; each family defines its instance
next to its model (``p6.VOCABULARY``, ``k6.VOCABULARY``; the P5 brings its own rows and columns
instead). :data:`GENERIC` is what a model without one gets.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

from sim.errors import RetrosimError

# Stall kinds shared by the per-instruction table, the timeline and the reports: (key, short
# column title). The help text of each is family-specific (Vocabulary.stall_help).
STALL_KINDS = (("dependency", "dep"), ("port", "port"), ("decode", "decode"), ("partial", "partial"),
               ("memory", "mem"), ("store_forward", "fwd"), ("window", "window"), ("mispredict", "branch"))


@dataclass(frozen=True)
class Vocabulary:
    family: str
    op: str                                   # what the `uops` counter counts ("uop", "RISC86 op")
    ports: tuple[str, ...]                    # short names of the counters port0..port4, in order
    port_help: tuple[str, ...]                # one line per port: what it executes
    extra_units: tuple[tuple[str, str], ...]  # (counter, short name) of units outside port0..4
    decoders: tuple[str, ...]                 # names of the decoder0..decoder2 counters ("" = unused)
    slot_marks: tuple[str, ...]               # per-instruction marks of those decoders ("D0", "S1")
    classes: tuple[str, str, str]             # decoder classes: simple, complex, microcode
    class_marks: tuple[str, str, str]         # per-instruction marks for classes with no slot mark ("" = use slot)
    decode_help: str                          # the decoders in one sentence
    sequencer: str                            # what msrom_uops counts
    group: str                                # what decode_groups counts
    window: str                               # what a `window` stall waits for
    stall_help: dict[str, str] = field(default_factory=dict)  # stall kind -> what it counts
    mispredict_note: str = ""                 # how mispredicted branches relate to `branch` stall cycles
    unit: str = "port"                        # what port0..port4 are called together ("port", "unit", "pipe")
    timeline: str = ("D decode, R rename, = wait in the reservation station, E execute, - done, C retire")

    def port_label(self, k: int) -> str:
        return self.ports[k] if k < len(self.ports) else f"port{k}"


COMMON_STALLS = {
    "dependency": "waiting for a source operand (a result not yet computed)",
    "port": "ready, but its execution unit was busy with another op",
    "partial": "reading a register after a write to part of it (partial-register merge)",
    "memory": "a load waiting for the cache or memory beyond L1",
    "store_forward": "a load waiting for an older store's data (store-to-load forwarding)",
}

GENERIC = Vocabulary(
    family="", op="uop", ports=tuple(f"port{k}" for k in range(5)), port_help=(), extra_units=(),
    decoders=("decoder 0", "decoder 1", "decoder 2"), slot_marks=("D0", "D1", "D2"),
    classes=("simple", "complex", "microcode"), class_marks=("", "", "MS"), decode_help="",
    sequencer="from the microcode sequencer", group="decode groups", window="window full",
    stall_help=dict(COMMON_STALLS),
)


def of(model) -> Vocabulary:
    """The vocabulary of a timing model (GENERIC when its class defines none)."""
    return getattr(model, "vocabulary", GENERIC)


@functools.cache
def for_preset(cpu: str) -> Vocabulary:
    """The vocabulary of a CPU preset's model (GENERIC for a family with no model yet)."""
    from sim.cpus.build import make_model

    try:
        return of(make_model(cpu))
    except RetrosimError:
        return GENERIC
