"""The P6's view: every family's (sim/cpus/view.py) in the P6's words: uops, the 4-1-1
decoders, ports p0..p4, the reorder buffer and reservation station."""

from __future__ import annotations

from sim.cpus.view import FamilyView
from sim.cpus.vocabulary import COMMON_STALLS, Vocabulary

# The words views use for the contract's counters on a P6 (sim/cpus/vocabulary.py).
VOCABULARY = Vocabulary(
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
    stall_help={**COMMON_STALLS,
                "decode": "rename idle, waiting for the decoders",
                "window": "waiting for a free reorder-buffer or reservation-station entry",
                "mispredict": ("decoders idle after a branch: the restart after a mispredicted branch plus "
                               "the fetch bubble of every taken branch (1 cycle when the BTB predicts it)")},
    mispredict_note=("'mispredicted' counts branches predicted wrongly; 'branch' stall cycles are the decoders' "
                     "idle cycles after branches: each misprediction's restart and the bubble of every "
                     "correctly predicted taken branch, so a loop with few mispredictions still shows many"),
)


class P6View(FamilyView):
    vocabulary = VOCABULARY
    # the P6's own words where they say more than every family's
    stall_words = {**FamilyView.stall_words,
                   "stall_mispredict": "front end: taken-branch bubbles, restarts",
                   "stall_register_read": "register-file reads (more than two per clock)"}
