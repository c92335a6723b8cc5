"""The words a family's views use for the shared counters.

The timing cores of every family fill the same counter slots (``port0``..``port4``,
``decoder0``..``decoder2``, ``msrom_uops``, the stall kinds; see :mod:`sim.cpus.p6_core`), but the
slots mean different hardware on each family: port 0 is a P6 execution port and the K6's X
integer unit. Each model class carries a :class:`Vocabulary` (``Model.vocabulary``) so that tables,
reports and legends name the hardware of the CPU they describe. A new family (the P5 with its U
and V pipes) defines its own instance next to its model; :data:`GENERIC` is what a model without
one gets.
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


_COMMON_STALLS = {
    "dependency": "waiting for a source operand (a result not yet computed)",
    "port": "ready, but its execution unit was busy with another op",
    "partial": "reading a register after a write to part of it (partial-register merge)",
    "memory": "a load waiting for the cache or memory beyond L1",
    "store_forward": "a load waiting for an older store's data (store-to-load forwarding)",
}

P6 = Vocabulary(
    family="p6", op="uop",
    ports=("p0", "p1", "p2", "p3", "p4"),
    port_help=("p0: integer ALU, shifts, multiply, x87", "p1: integer ALU, branches",
               "p2: loads", "p3: store address", "p4: store data"),
    extra_units=(),
    decoders=("decoder 0", "decoder 1", "decoder 2"),
    slot_marks=("D0", "D1", "D2"),
    classes=("simple", "complex", "microcode"),
    class_marks=("", "", "MS"),
    decode_help=("4-1-1 decode: decoder 0 (D0) takes any instruction of up to 4 uops, decoders 1 and 2 "
                 "(D1, D2) one-uop instructions only; MS = the microcode sequencer (more than 4 uops)"),
    sequencer="from the microcode sequencer",
    group="decode groups (cycles in which the decoders took instructions)",
    window="the reorder buffer or the reservation station was full",
    stall_help={**_COMMON_STALLS,
                "decode": "rename idle, waiting for the decoders",
                "window": "waiting for a free reorder-buffer or reservation-station entry",
                "mispredict": ("decoders idle after a branch: the restart after a mispredicted branch plus "
                               "the fetch bubble of every taken branch (1 cycle when the BTB predicts it)")},
    mispredict_note=("'mispredicted' counts branches predicted wrongly; 'branch' stall cycles are the decoders' "
                     "idle cycles after branches: each misprediction's restart and the bubble of every "
                     "correctly predicted taken branch, so a loop with few mispredictions still shows many"),
)

K6 = Vocabulary(
    family="k6", op="RISC86 op",
    ports=("X", "Y", "load", "store", "branch"),
    port_help=("X: integer/MMX unit X (the only one for shifts, multiply, divide)",
               "Y: integer/MMX unit Y (MMX only on the K6-2 and K6-III)",
               "load: load unit", "store: store unit (also LEA)", "branch: branch unit"),
    extra_units=(("fpu_ops", "FPU"),),
    decoders=("short 1 / long", "short 2", ""),
    slot_marks=("S1", "S2", ""),
    classes=("short", "long", "vector"),
    class_marks=("", "L", "V"),
    decode_help=("per clock either two short instructions (S1, S2: up to 7 bytes and 2 ops each), one "
                 "long-decoded instruction (L: up to 4 ops) or one vector-decoded instruction (V: the ROM "
                 "sequencer, alone, for 2 or more clocks)"),
    sequencer="vector-decoded (ROM sequencer)",
    group="opquads (groups of four op slots, NOP padding included)",
    window="the scheduler (24 ops, 6 opquads) was full",
    stall_help={**_COMMON_STALLS,
                "decode": "scheduler had room, waiting for the decoders (vector decode holds them)",
                "window": "decoded, waiting for a free opquad in the scheduler",
                "mispredict": "decoders idle, restarting after a mispredicted branch"},
    mispredict_note=("'mispredicted' counts branches predicted wrongly; 'branch' stall cycles are the clocks "
                     "the decoders waited to restart after them"),
    unit="unit",
    timeline="D decode, R enter the scheduler, = wait in the scheduler, E execute, - done, C retire",
)

GENERIC = Vocabulary(
    family="", op="uop", ports=tuple(f"port{k}" for k in range(5)), port_help=(), extra_units=(),
    decoders=("decoder 0", "decoder 1", "decoder 2"), slot_marks=("D0", "D1", "D2"),
    classes=("simple", "complex", "microcode"), class_marks=("", "", "MS"), decode_help="",
    sequencer="from the microcode sequencer", group="decode groups", window="window full",
    stall_help=dict(_COMMON_STALLS),
)


def of(model) -> Vocabulary:
    """The vocabulary of a timing model (GENERIC when its class defines none)."""
    return getattr(model, "vocabulary", GENERIC)


@functools.cache
def for_preset(cpu: str) -> Vocabulary:
    """The vocabulary of a CPU preset's model (GENERIC for a family with no model yet)."""
    from sim.cpus import make_model

    try:
        return of(make_model(cpu))
    except RetrosimError:
        return GENERIC
