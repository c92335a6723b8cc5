"""Conformance of the timing models with their own tables, a study: for every row of a family's
table, a generated micro-benchmark -- a dependency chain for latency, independent copies for
reciprocal throughput, the way InstLatX64 measures -- is run through the full model on each preset of
the family, and the modelled figures are compared with the row's sourced ones (within 0.05 cycles).

`retrosim conformance` runs it and writes reports/conformance.md through the report's renderer
(sim/reports/conformance.py, which only reads the results). Benchmarks exist for register, immediate
and operand-free forms, and for integer, MMX and SSE memory forms (independent copies over 8 lines of
an L1-resident buffer: throughput only, since InstLatX64 chains them through the address register,
which adds a partial-register stall for 8/16-bit forms); x87 memory, stack, branch, string and system
forms are listed as "not generated" (their cost depends on addresses and on what surrounds them, not
on a chain of copies).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim import output
from sim.cpus import presets
from sim.cpus.build import make_model
from sim.cpus.families import FAMILIES
from sim.cpus.table import TimingRow, load_table
from sim.errors import RetrosimError
from sim.guest.emu import Machine
from sim.guest.isa import mnemonic_extension
from sim.guest.trace import Trace
from sim.reports.conformance import Method, render
from sim.timing.kernel import Emulation, guest_cpu, time_emulation

TOLERANCE = 0.05
COPIES = 48       # instructions per loop iteration
ITERATIONS = 24   # loop iterations per call
BUDGET = 100_000  # instructions per call: a benchmark is ~2,500
STRING_ELEMENTS = 64  # elements of a REP string benchmark (and twice as many): 64 is the P6 fast-string minimum
FAMILY_ISA = {n: f.conformance_isa for n, f in FAMILIES.items() if f.conformance_isa}  # the preset whose instruction set has every row
# InstLatX64's harness, for families whose rows are its figures and whose front end sees the code's
# layout (the family's machine table, [family.conformance] instlat_harness: why): INSTLAT_COPIES copies
# of the instruction per iteration of a loop whose start is 32-byte aligned, closed by DEC/JNZ (12:
# every fractional figure of the K6 dumps is a multiple of 1/12 -- IDIV r32 24.08, AAS 5.42, LODSB 1.17).
# How InstLat removes the loop's own cost is not published; here the loop holds 2 x 12 copies from
# the aligned start, and the same loop whose first dozen is skipped (assembled, never executed: the
# second dozen keeps its addresses) is subtracted, which cancels the loop and times the first dozen
# at InstLat's addresses.
INSTLAT_HARNESS = {n: f.conformance["instlat_harness"] for n, f in FAMILIES.items()
                   if "instlat_harness" in f.conformance}
INSTLAT_COPIES = 12
INSTLAT_ITERATIONS = 48

# register names per operand token: the chain writes the first; throughput rotates the destination
# through all but the last and reads the last. Only low bytes for r8 (AH..DH would merge with AL..DL).
_REGS = {
    "r32": ["eax", "ebx", "edx", "esi", "edi", "ecx"],
    "r16": ["ax", "bx", "dx", "si", "di", "cx"],
    "r8": ["al", "bl", "dl", "cl"],
    "mm": [f"mm{i}" for i in range(8)],
    "xmm": [f"xmm{i}" for i in range(8)],
}
_STRING_OPS = frozenset(p + w for p in ("lods", "stos", "movs", "scas", "cmps") for w in "bwd")
_X87_COMPARE = frozenset({"fcom", "fucom", "fcomi", "fucomi", "fcompi", "fucompi"})
_IMM = {"i8": "3", "i16": "0x1234", "i32": "0x12345", "1": "1", "cl": "cl"}
# A chain reads its own destination, except where that makes a zero idiom or a NOP (XOR EAX,EAX;
# XCHG EAX,EAX is 0x90): those read another register, whose value the chain then does not need.
_OTHER_SOURCE = frozenset("xor sub sbb xchg pxor psubb psubw psubd psubsb psubsw psubusb psubusw pcmpeqb "
                          "pcmpeqw pcmpeqd pcmpgtb pcmpgtw pcmpgtd pandn xorps andnps pfsub pfsubr cmpxchg".split())
_BUF = "conformance_buffer"  # 2 KB of dwords = 3, 32-byte aligned; benchmarks write only the first 512 bytes
_PTR = {"m8": "byte", "m16": "word", "m32": "dword", "m64": "qword", "m128": "xmmword"}
_WRITES_BOTH = frozenset({"xchg", "xadd"})  # register forms write both operands
_SKIP_MNEMONICS = {"push", "pop", "call", "ret", "jmp", "jcc", "loop", "jecxz", "enter", "leave", "pushal", "popal",
                   "pushfd", "popfd", "pushaw", "popaw", "pushf", "popf", "rdtsc", "cpuid", "nop", "setcc",
                   "femms", "emms", "fldcw", "fnstcw", "fnstsw", "fld1", "fldz", "fld", "fst", "fstp", "fxch",
                   "fincstp", "fdecstp", "fnop", "fcompp", "fcomp", "fucomp", "std", "cld"}

# these load a segment register or raise #BR/#OF by design: one of them in the shared benchmark machine
# would break every later benchmark
_SEGMENT_OR_TRAP = {"lds", "les", "lfs", "lgs", "lss", "bound", "into"}


@dataclass
class RowResult:
    row: TimingRow
    checked: bool
    why_not: str = ""
    measured: dict = field(default_factory=dict)   # preset -> (latency, throughput) modelled
    expected: dict = field(default_factory=dict)   # preset -> (latency, throughput) of the row
    ok: bool = False
    reason: str = ""


def _is_mem(token: str) -> bool:
    return token == "m" or (token.startswith("m") and token[1:2].isdigit())  # not mm


def _operands(row: TimingRow, k: int, chain: bool, bases: tuple[str, ...] = ()) -> str | None:
    """Operand text for copy k (chain: every copy reads what the previous wrote). `bases`:
    registers holding addresses in the buffer, for memory operands [base] (the short encoding of
    InstLatX64's [m32] forms), copy k using bases[k % len]; no register operand then names one."""
    toks = row.signature.split(",") if row.signature else []
    if any(t.startswith("rel") or (_is_mem(t) and t not in _PTR) for t in toks):
        return None
    sized = any(t in _REGS for t in toks) and row.mnemonic not in ("movzx", "movsx")
    out = []
    for pos, t in enumerate(toks):
        if _is_mem(t):
            # copies spread over 8 lines of the buffer (a store or read-modify-write to one address
            # would chain the copies through memory); memory forms are checked for throughput only
            where = f"[{bases[k % len(bases)]}]" if bases else f"[{_BUF} + {32 * (k % 8)}]"
            out.append(where if sized else f"{_PTR[t]} ptr {where}")
        elif t in _REGS:
            regs = [r for r in _REGS[t] if not any(r in (b, b[1:]) for b in bases)]
            if pos == 0:
                out.append(regs[0] if chain else regs[k % (len(regs) - 1)])
            elif chain:
                out.append(regs[1] if row.mnemonic in _OTHER_SOURCE else regs[0])
            else:
                out.append(regs[-1])
        elif t in _IMM:
            out.append(_IMM[t])
        elif t in ("st", "sti"):
            # ST(0) op ST(1) chains through ST(0); independent copies write ST(1)..ST(7) from ST(0)
            if len(toks) == 1:
                out.append("st(1)" if chain else f"st({k % 7 + 1})")
            elif row.mnemonic in _X87_COMPARE:  # ST(0) is always the first operand
                out.append("st(0)" if pos == 0 else ("st(1)" if chain else f"st({k % 7 + 1})"))
            elif pos == 0:
                out.append("st(0)" if chain else f"st({k % 7 + 1})")
            else:
                out.append("st(1)" if chain else "st(0)")
        else:
            return None
    if "cl" in toks and out and out[0] in ("ecx", "cx", "cl"):
        return None
    return ", ".join(out)


def _has_mem(row: TimingRow) -> bool:
    return any(_is_mem(t) for t in (row.signature.split(",") if row.signature else []))


def _is_string(row: TimingRow) -> bool:
    return row.mnemonic.split()[-1] in _STRING_OPS


def _why_not(row: TimingRow) -> str:
    if row.mnemonic in _SKIP_MNEMONICS or row.mnemonic.startswith(("j", "set", "cmov", "fcmov", "prefetch")) or \
            (row.mnemonic.startswith("f") and row.mnemonic.endswith("p")):  # popping x87 forms empty the stack
        return "stack, branch, flag-chain or x87 stack form"
    if row.mnemonic in _SEGMENT_OR_TRAP:
        return "segment-register load or bounds check (would fault or leave the flat guest's segments changed)"
    toks = row.signature.split(",") if row.signature else []
    if any(_is_mem(t) for t in toks) and row.mnemonic.startswith("f"):
        return "x87 memory form (every copy reads and writes ST(0), so no independent copies)"
    if any(_is_mem(t) and t not in _PTR for t in toks):
        return "memory operand"
    if row.mnemonic in ("div", "idiv", "mul", "imul") and len(toks) == 1:
        return ""
    return ""


def _read_or_write_only(row: TimingRow) -> bool:
    """A memory form whose copies can share one address without a chain through memory (a load,
    a store, a compare), unlike a read-modify-write."""
    toks = row.signature.split(",") if row.signature else []
    return _has_mem(row) and (not _is_mem(toks[0]) or row.mnemonic.startswith("mov") or
                              row.mnemonic in ("cmp", "test", "bt"))


def _source(rows: list[TimingRow], instlat: bool = False) -> tuple[str, dict[int, tuple[str, str]]]:
    """The benchmarks' assembly text and, per row, the entry pairs and the instructions their
    difference times. `instlat`: InstLatX64's harness (INSTLAT_HARNESS) where a row's form has one."""
    lines = [".intel_syntax noprefix", ".text"]
    entries: dict[int, tuple[str, str]] = {}

    def body(name: str, insns: list[str], setup: tuple[str, ...] = (), iterations: int = ITERATIONS,
             aligned: bool = False, skipped: list[str] | None = None) -> None:
        lines.extend([f".globl {name}", f"{name}:", "    push ebp", "    push ebx", "    push esi", "    push edi",
                      "    mov eax, 7", "    mov ebx, 5", "    mov ecx, 3", "    mov edx, 0", "    mov esi, 9",
                      "    mov edi, 11", *("    " + i for i in setup), f"    mov ebp, {iterations}"])
        # an aligned loop start is jumped to, so the padding (and `skipped`) is never executed
        lines.extend(["    jmp 1f", ".p2align 5, 0x90", *("    " + i for i in skipped or ()), "1:"]
                     if aligned else ["1:"])
        lines.extend("    " + i for i in insns)
        lines.extend(["    dec ebp", "    jnz 1b", "    pop edi", "    pop esi", "    pop ebx", "    pop ebp", "    ret"])

    for i, row in enumerate(rows):
        # InstLat's memory forms: [reg]; a read-modify-write alternates between two lines (one
        # address would chain the copies through memory)
        bases: tuple[str, ...] = ()
        if instlat and _has_mem(row) and row.mnemonic not in ("div", "idiv"):
            bases = ("esi",) if _read_or_write_only(row) else ("esi", "edi")
        lat = [f"{row.mnemonic} {_operands(row, k, True, bases)}".strip() for k in range(2 * COPIES)]
        thr = [f"{row.mnemonic} {_operands(row, k, False, bases)}".strip() for k in range(2 * COPIES)]
        setup: tuple[str, ...] = (f"lea esi, [{_BUF}]", f"lea edi, [{_BUF} + 64]") if bases else ()
        if _has_mem(row):
            lat = thr  # no chain is generated through memory forms: throughput only
        if row.mnemonic in ("div", "idiv"):
            # As InstLatX64 measures DIV/IDIV "(full)": the chain divides its own result, quotient
            # and remainder (AX = AH:AL for r8; EDX:EAX), by CL/CX/ECX = 3. The dividend starts at 0
            # and stays 0, so neither form overflows; clearing the high half inside the chain would
            # add an instruction to it (XOR EDX,EDX still reads EDX on P6) or a partial-register
            # write (MOV AH,0). Independent copies load a fresh dividend with MOVs, which read nothing.
            reg = {"r32": "ecx", "r16": "cx", "r8": "cl", "m32": f"dword ptr [{_BUF} + 1536]"}[row.signature]
            fresh = "mov eax, 0\n    " if row.signature == "r8" else "mov eax, 0\n    mov edx, 0\n    "
            setup = ("mov eax, 0", "mov edx, 0")
            lat = [f"{row.mnemonic} {reg}"] * (2 * COPIES)
            thr = [f"{fresh}{row.mnemonic} {reg}"] * (2 * COPIES)
        if row.mnemonic in _WRITES_BOTH and row.signature in ("r32,r32", "r16,r16", "r8,r8"):
            # XCHG/XADD write both operands: independent copies need disjoint register pairs
            regs = _REGS[row.signature.split(",")[0]]
            pairs = [(regs[0], regs[1]), (regs[2], regs[-1])] if len(regs) == 4 else \
                [(regs[0], regs[1]), (regs[2], regs[3]), (regs[4], regs[5])]
            thr = [f"{row.mnemonic} {a}, {b}" for a, b in (pairs[k % len(pairs)] for k in range(2 * COPIES))]
        if row.mnemonic.startswith("f") and not row.signature and not instlat:
            # an x87 instruction on ST(0) alone: independent copies alternate between two stack
            # values with FXCH (done at rename, no execution port: AF29n note f). Not on the K6,
            # whose FXCH takes the x87 unit for 2 clocks (IL-K6, IL-K62): there the copies repeat
            # the instruction, as its measured T of 2 for FABS (FXCH + FABS would be 4) shows.
            thr = [f"{row.mnemonic}\n    fxch st(1)"] * (2 * COPIES)
        if row.mnemonic in ("rcl", "rcr"):
            # rotates through carry read the CF the previous copy wrote: each copy starts from CLC
            # (1 uop, writes CF only) so the copies are independent
            thr = [f"clc\n    {t}" for t in thr]
        if row.mnemonic == "bswap":
            thr = [f"bswap {_REGS['r32'][k % 5]}" for k in range(2 * COPIES)]
        if row.mnemonic in ("cmp", "test") and row.signature.split(",")[-1] in _IMM and not _has_mem(row) \
                and not instlat:
            # CMP/TEST r,imm write no register: copies rotating over registers nothing writes would
            # add the P6 register read stall (three distinct per triplet of uops) to a figure that is
            # the port bound (AF29); the copies read one register (P6 only: the K6 has no such stall and
            # its rows are InstLatX64's, whose copies the K6 harness keeps)
            thr = [f"{row.mnemonic} {_REGS[row.signature.split(',')[0]][-1]}, {_IMM[row.signature.split(',')[-1]]}"
                   for _ in range(2 * COPIES)]
        if row.extra.get("throughput_by") == "register_read" and not _has_mem(row):
            # the measured rate is the P6 register read stall (p6_machine.toml [rob.register_read]):
            # as in InstLatX64's copies, each copy reads its own register (CMP EAX,EAX / CMP EBX,EBX;
            # MOVD MM0,EAX / MOVD MM1,EBX), which nothing in the loop writes
            toks = row.signature.split(",")
            thr = [f"{row.mnemonic} " + ", ".join(_REGS[t][k % (len(_REGS[t]) - 1)] for t in toks)
                   for k in range(2 * COPIES)]
        # each benchmark at COPIES and 2*COPIES per iteration: the difference is COPIES*ITERATIONS
        # instructions with the loop overhead and the call cancelled out
        n = COPIES
        pairs_ = [(lat[:COPIES], lat), (thr[:COPIES], thr)]
        if _is_string(row):
            # string instructions walk ESI/EDI through the buffer from its start each iteration
            # (DF = 0; SCAS compares with EAX = 7, which the buffer of 3s never holds, so REPNE runs
            # ECX elements, and the two halves are equal, so REPE CMPS does too). A REP form runs
            # STRING_ELEMENTS and twice as many elements per iteration: the difference is the
            # per-element cost the row states, without the start-up.
            # stores go to the buffer's first 512 bytes; SCAS and CMPS read only the rest, which no
            # benchmark writes
            dst = 1024 if row.mnemonic[-5:-1] in ("scas", "cmps") else 0
            reset = f"lea esi, [{_BUF} + 512]\n    lea edi, [{_BUF} + {dst}]\n    "
            if " " in row.mnemonic:
                n = STRING_ELEMENTS
                pair = ([f"{reset}mov ecx, {n}\n    {row.mnemonic}"], [f"{reset}mov ecx, {2 * n}\n    {row.mnemonic}"])
            else:
                copies = [f"{reset}{row.mnemonic}"] + [row.mnemonic] * (2 * COPIES - 1)
                pair = (copies[:COPIES], copies)
            pairs_ = [pair, pair]
        iterations, aligned, skip = ITERATIONS, False, {}
        if instlat and not _is_string(row):
            # InstLatX64's loop: two dozen copies from the aligned start, against the second dozen alone
            n, iterations, aligned = INSTLAT_COPIES, INSTLAT_ITERATIONS, True
            pairs_ = [(lat[n:2 * n], lat[:2 * n]), (thr[n:2 * n], thr[:2 * n])]
            skip = {"lat": lat[:n], "thr": thr[:n]}
        for kind, (a, b) in zip(("lat", "thr"), pairs_):
            body(f"{kind}{i}a", a, setup, iterations, aligned, skip.get(kind))
            body(f"{kind}{i}b", b, setup, iterations, aligned)
        entries[i] = ((f"lat{i}a", f"lat{i}b"), (f"thr{i}a", f"thr{i}b"), n * iterations)
    lines += [".data", ".p2align 5", f"{_BUF}:", "    .fill 512, 4, 3"]
    return "\n".join(lines) + "\n", entries


# rows whose signature names no operand form the assembler takes (LDMXCSR/STMXCSR read and write
# 32 bits; MASKMOVQ stores through [EDI])
_NO_FORM = {("ldmxcsr", "m8"), ("stmxcsr", "m8"), ("maskmovq", "mm,m64")}


def _benchable(row: TimingRow) -> str:
    why = _why_not(row)
    if why:
        return why
    if (row.mnemonic, row.signature) in _NO_FORM or _operands(row, 0, True) is None:
        return "operand form without a generated benchmark"
    return ""


def _emulation(machine, src: Path, entry: str, isa_cpu):
    """Two calls of `entry` in one machine (the second is timed warm), as timing.emulate does,
    without building a machine per benchmark."""
    machine.reset_fpu()
    parts = [machine.call(entry, budget=BUDGET, trace=True).trace for _ in range(2)]
    bounds = np.cumsum([p.instructions for p in parts]).tolist()
    return Emulation(src, entry, None, 2, BUDGET, None, machine, Trace.concatenate(parts), bounds, isa_cpu)


def _runs_on(row: TimingRow, preset_name: str, model) -> bool:
    ext = mnemonic_extension(row.mnemonic)
    if ext and ext not in guest_cpu(preset_name).extensions:
        return False
    models = row.extra.get("models")
    return not (models and model.key not in models)


def run_family(family: str, progress=None, only: set[str] | None = None) -> tuple[list[RowResult], list[str]]:
    """Benchmark every row of `family` (or the rows whose key is in `only`) on each of its presets."""
    table = load_table(family)
    rows = sorted(table.rows.values(), key=lambda r: (r.mnemonic, r.signature))
    if only is not None:
        rows = [r for r in rows if r.key in only]
    fam_presets = [p for p in presets.available() if presets.load(p).family == family]
    results = [RowResult(r, checked=False, why_not=_benchable(r)) for r in rows]
    todo = [res for res in results if not res.why_not]
    source, entries = _source([res.row for res in todo], instlat=family in INSTLAT_HARNESS)
    models = {p: make_model(p) for p in fam_presets}
    isa_cpu = FAMILY_ISA[family]
    target = guest_cpu(isa_cpu)  # the preset read once: the guest stages get its GuestCpu
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / f"conformance_{family}.S"
        src.write_text(source)
        try:
            machine = Machine.from_source(src, cpu=target)
        except RetrosimError as e:
            raise RetrosimError(f"conformance benchmark for {family} does not assemble: {e}") from None
        for i, res in enumerate(todo):
            row = res.row
            try:
                *pairs, n = entries[i]
                emus = [[_emulation(machine, src, e, target) for e in pair] for pair in pairs]
            except RetrosimError as e:
                res.why_not = f"benchmark failed to run: {e}"
                continue
            res.checked = True
            for p, m in models.items():
                if not _runs_on(row, p, m):
                    continue
                try:
                    lat, thr = ((time_emulation(b, m).last["cycles"] - time_emulation(a, m).last["cycles"]) / n
                                for a, b in emus)
                except RetrosimError as e:
                    res.checked, res.why_not = False, f"model refused the benchmark: {e}"
                    break
                res.measured[p] = (lat, thr)
                res.expected[p] = _expected(row, m)
            if progress:
                progress(i + 1, len(todo))
    for res in results:
        if res.checked:
            _judge(res, family)
    return results, fam_presets


def _expected(row: TimingRow, model) -> tuple[float | None, float | None]:
    over = row.extra.get("model_overrides", {}).get(model.key, {})
    # the chain the source measured, where the row's latency is the execution latency and the
    # measured chain was slower for another reason the row names (a K6 row's `measured_latency`:
    # ADD r16,imm16 executes in 1 clock, its chain runs at the 2-clock decode rate)
    lat = over.get("latency", row.extra.get("measured_latency", row.latency))
    # the system the preset reproduces, where its board and not the core set the measured figure
    # (k6-233: IL-K6 stores to lines never read at 36 clocks, no write allocation)
    thr = row.extra.get("measured_system", {}).get(model.key, over.get("throughput", row.throughput))
    return (None if lat is None else float(lat), None if thr is None else float(thr))


# No chain through the destination: no register result (CMP, TEST, BT, compares) or a result
# that does not depend on the old destination (MOV forms); only throughput is checked.
NO_CHAIN = frozenset("cmp test bt mov movzx movsx movd movq movaps movups movss movhlps movlhps comiss ucomiss "
                     "ftst fxam fcom fucom fcomi fucomi cvtpi2ps cvtps2pi cvttps2pi cvtsi2ss cvtss2si cvttss2si "
                     "movmskps pmovmskb pextrw".split())


def _judge(res: RowResult, family: str = "") -> None:
    bad = []
    for p, (lat, thr) in res.measured.items():
        el, et = res.expected[p]
        if res.row.mnemonic in NO_CHAIN or _has_mem(res.row) or _is_string(res.row):
            el = None
        elif el is not None and et is not None and et > el:
            # a dependency chain of copies cannot run faster than independent copies: InstLatX64
            # measures ADD r16,imm16 (latency 1, but one per 2.17 clocks decoded) at L 2.2 T 2.17
            el = et
        if el is not None and abs(lat - el) > TOLERANCE:
            bad.append(f"{p}: latency {lat:.2f} vs {el:g}")
        if et is not None and abs(thr - et) > TOLERANCE:
            bad.append(f"{p}: throughput {thr:.2f} vs {et:g}")
    res.ok = not bad and bool(res.measured)
    if bad:
        res.reason = "; ".join(bad[:3]) + (f" (+{len(bad) - 3})" if len(bad) > 3 else "") + " -- " + \
            _classify(res, family)


def _family_note(family: str, key: str, default: str) -> str:
    """The family's own reason for a kind of miss, where its source notes establish one (its machine
    table's [family.conformance]: below_nominal, above_latency), else the generic one."""
    return FAMILIES[family].conformance.get(key, default) if family in FAMILIES else default


def _classify(res: RowResult, family: str = "") -> str:
    """The likeliest reason a row is not reproduced, from the direction of the error."""
    row = res.row
    if row.extra.get("unreproduced"):
        return row.extra["unreproduced"]  # the table's own, sourced explanation
    if _is_string(row) and " " in row.mnemonic:
        return ("REP string instruction: the later elements run at the row's per-element rate (fast strings on the "
                "P6 when their conditions hold); the first element and the start-up are outside the measured rate")
    pairs = list(zip(res.measured.values(), res.expected.values()))
    lat_low = any(e[0] is not None and m[0] < e[0] - TOLERANCE for m, e in pairs)
    lat_high = any(e[0] is not None and m[0] > e[0] + TOLERANCE for m, e in pairs)
    thr_low = [(m[1], e[1]) for m, e in pairs if e[1] is not None and m[1] < e[1] - TOLERANCE]
    thr_high = any(e[1] is not None and m[1] > e[1] + TOLERANCE for m, e in pairs)
    if row.uops > 4 or row.decoder in ("msrom", "vector"):
        return "microcoded: the model issues the row's uops at its decode and port rates, not at the measured rate"
    if lat_low and row.uops > 1:
        return "multi-uop instruction: the core does not chain the uops inside one instruction (issue 14 part 1)"
    if thr_low and all(m in (0.5, 1.0) or abs(m - round(m)) < 0.03 for m, _ in thr_low) and \
            all(e <= 1.2 * max(m, 0.5) for m, e in thr_low):
        return _family_note(family, "below_nominal", "measured rate 8-20 % below the nominal issue rate (decode of prefixed / "
                                         "0F / long instructions), not modelled")
    if thr_low:
        return "the row's reciprocal throughput is not enforced by the model for this unit (issue 14 part 2)"
    if lat_high and row.throughput is not None and row.latency is not None and row.throughput > row.latency:
        return _family_note(family, "above_latency", "row throughput above its latency: the unit's occupancy lengthens the "
                                         "modelled chain")
    if thr_high:
        return "port or decode limit in the model: slower than the measurement"
    return "latency split between the model's uops differs from the measurement"


# what the report says about how the rows were benchmarked
METHOD = Method(COPIES, ITERATIONS, TOLERANCE, INSTLAT_COPIES, INSTLAT_ITERATIONS, INSTLAT_HARNESS)


def write_report(path: Path, families=tuple(FAMILY_ISA), progress=None) -> dict:
    """Run `families` and write the report to `path` through the checked writer (sim.output): the
    target is checked before the minute of work, and a device, pipe or folder there is refused."""
    start = time.monotonic()
    path = output.check_output_file(path, "--out")
    results = {fam: run_family(fam, progress) for fam in families}
    output.atomic_write(path, render(results, METHOD).encode(), "--out")
    return results, time.monotonic() - start
