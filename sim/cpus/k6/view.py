"""The K6's view: every family's (sim/cpus/view.py) in the K6's words: RISC86 ops, the short,
long and vector decoders, units X, Y, load, store, branch and the FPU, the scheduler."""

from __future__ import annotations

from sim.cpus.view import FamilyView
from sim.cpus.vocabulary import COMMON_STALLS, Vocabulary

# The words views use for the contract's counters on a K6 (sim/cpus/vocabulary.py).
VOCABULARY = Vocabulary(
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
    stall_help={**COMMON_STALLS,
                "decode": "scheduler had room, waiting for the decoders (vector decode holds them)",
                "window": "decoded, waiting for a free opquad in the scheduler",
                "mispredict": "decoders idle, restarting after a mispredicted branch"},
    mispredict_note=("'mispredicted' counts branches predicted wrongly; 'branch' stall cycles are the clocks "
                     "the decoders waited to restart after them"),
    unit="unit",
    timeline="D decode, R enter the scheduler, = wait in the scheduler, E execute, - done, C retire",
)


class K6View(FamilyView):
    vocabulary = VOCABULARY

    def bottleneck(self, counters: dict) -> str:
        """As every family's, but a decode bottleneck says whether the ROM sequencer (vector
        decoding, alone for 2 or more clocks) was in it."""
        said = super().bottleneck(counters)
        if said.startswith("decode:"):
            return "decode: vector-decoded" if counters.get("vector_cycles") else "decode: short/long decoders"
        return said
