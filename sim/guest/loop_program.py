"""A loop body made a program: the code around it, assembled, loaded and traced, with its marks.

The harness supplies everything a kernel would: the code around the body (:func:`wrapper_source`),
register start values (:data:`REG_DEFAULTS`, overridable), a stack, and a demand-zero data region:
every data page the body touches is mapped zero-filled on first use (Unicorn's unmapped-memory
hook), up to :data:`MAX_DATA_PAGES`. Addresses below :data:`NULL_LIMIT` are never mapped, so a null
pointer faults.

The body runs ``iterations`` times twice from the same registers (the first pass warms caches and
predictors). The marks handed to the timing side (:class:`LoopRun`) are the end of the warm pass
and where iteration ``iterations // 2`` and iteration ``iterations`` of the second pass start, and
the PC the body goes on to after the trace (the next iteration's first instruction). An iteration
starts where the PC reaches the first instruction from another instruction: a REP string
instruction first in the body repeats at its own PC once per element, and its elements are one
iteration. sim/timing/loop.py times what this module hands it and imports no emulator.
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from unicorn import UC_ERR_EXCEPTION, UC_HOOK_MEM_READ_UNMAPPED, UC_HOOK_MEM_WRITE_UNMAPPED, UC_PROT_READ, UC_PROT_WRITE, UcError
from unicorn import x86_const as X

from sim.guest import asm, elf, isa
from sim.guest.body_source import LABEL_RUN as _LABEL_RUN
from sim.guest.cpu import GuestCpu
from sim.guest.decode import Decoder
from sim.guest.emu import X87_RUN_LIMIT_WORDS, X87_RUN_WORDS, Machine
from sim.guest.loop_body import Body
from sim.guest.trace import NativeTracer, Trace
from sim.errors import ArgumentError, AssemblerError, GuestFault, RetrosimError, UntranslatableCode

# Start values. Every register but ESP is a valid pointer (compilers use any of them as one):
# regions 4 MB apart in unmapped low memory (demand-zero, below the 64 MB that Socket 7 board
# caches cover), each shifted by a different multiple of 0x440 bytes so that streams fall in
# different cache sets (4 KB P6 ways, 16 KB K6 ways) and sectors, as real buffers would. The values
# are large, so `dec reg / jnz` loops run as long as needed, and distinct, so `cmp reg, reg / jne`
# loops do too. EDX is the smallest so that `div r32` by any other register cannot overflow (#DE);
# it is not shifted, so DL and DH start at 0 (byte-register steps stay still).
REG_DEFAULTS = {"eax": 0x02400000 + 6 * 0x440, "ebx": 0x01800000 + 3 * 0x440, "ecx": 0x02000000 + 5 * 0x440,
                "edx": 0x00C00000, "esi": 0x01000000, "edi": 0x01400000 + 2 * 0x440,
                "ebp": 0x01C00000 + 4 * 0x440}
NULL_LIMIT = 0x10000          # accesses below 64 KB are null-pointer bugs, not data
MAX_DATA_PAGES = 4096         # 16 MB of demand-zero data at most
MAX_INSTRUCTIONS = 5_000_000  # per pass: a body that needs more never reaches its back-edge
DEFAULT_ITERATIONS = 100
MAX_ITERATIONS = 100_000      # -n: a loop of that many iterations traces in seconds
# A block is repeated, not looped: its wrapper holds -n + 1 copies, and assembling and decoding
# 20,000 one-instruction copies takes about 15 s (GNU as): 40,000 instructions is the most a wrapper may hold.
MAX_BLOCK_INSTRUCTIONS = 40_000
# Placement of the body's first instruction: ALIGN_SPAN bytes is the largest block any modelled
# front end cuts code into (32-byte L1I lines and P5/K6 fetch, 16-byte P6 fetch blocks), so the
# body's offset from an ALIGN_SPAN boundary decides everything alignment can change. The default
# puts it on such a boundary (the start of the code, as every release has done).
ALIGN_SPAN = 64
DEFAULT_ALIGN = ALIGN_SPAN
_STACK_TOP = elf.STACK_BASE + elf.STACK_SIZE - 4096  # room above ESP for [esp+k] reads

_REP_PREFIXES = {"rep", "repe", "repz", "repne", "repnz"}
_PREFIXES = _REP_PREFIXES | {"lock", "data16", "addr16", "data32", "addr32", "cs", "ds", "es", "fs", "gs", "ss"}


def _rename(line: str, labels: set[str], suffix: str) -> str:
    """Give a repeated copy its own labels (numeric local labels need no renaming): in label
    definitions and operands, never in the mnemonic or its prefixes (a label may be called `add`)."""
    named = [x for x in labels if not x.isdigit()]
    if not named:
        return line
    run = _LABEL_RUN.match(line).end()
    head, rest = line[:run], line[run:]
    prefixes = "" if rest.lstrip().startswith(".") else r"(?:(?:" + "|".join(sorted(_PREFIXES)) + r")\s+)*"
    words = re.match(r"\s*" + prefixes + r"\S*", rest, re.IGNORECASE)
    mnemonic, operands = rest[:words.end()], rest[words.end():]
    for lab in sorted(named, key=len, reverse=True):
        pattern = rf"(?<![\w.$@%]){re.escape(lab)}(?![\w.$@])"
        head = re.sub(pattern, lab + suffix, head)
        operands = re.sub(pattern, lab + suffix, operands)
    return head + mnemonic + operands


def placement(align: int = DEFAULT_ALIGN, offset: int = 0) -> int:
    """Bytes from an ALIGN_SPAN-byte boundary to the body's first instruction for ``--align N
    --offset K``: the least aligned address that is a multiple of N (a multiple of N and of no
    larger power of two, what `.p2align` may give a function's loop), then K bytes further."""
    if align not in [1 << k for k in range(ALIGN_SPAN.bit_length())]:
        raise ArgumentError(f"--align {align}: must be a power of two from 1 to {ALIGN_SPAN}")
    if not 0 <= offset < align:
        raise ArgumentError(f"--offset {offset}: must be from 0 to {align - 1} (less than --align {align})")
    return (align % ALIGN_SPAN) + offset


def wrapper_source(body: Body, copies: int, pad: int = 0) -> tuple[str, list[int]]:
    """The assembled file and, per generated line, the user's line number (0 for ours). The body
    starts `pad` bytes after an ALIGN_SPAN-byte boundary (the bytes before it are INT3, never run)."""
    out: list[tuple[str, int]] = []
    add = lambda text, n=0: out.append((text, n))  # noqa: E731
    add(".intel_syntax noprefix" if body.syntax == "intel" else ".att_syntax prefix")
    add(".text")
    for n, line in body.macros:
        add(line, n)
    add(f".balign {ALIGN_SPAN}")
    if pad:
        add(f".fill {pad}, 1, 0xcc")
    add(".globl retrosim_loop")
    add("retrosim_loop:")
    if body.loop:
        first = True
        for n, line in body.lines:
            rest = _LABEL_RUN.sub("", line).strip()
            if first and rest and not rest.startswith("."):
                add("retrosim_iter_0:")  # the first instruction: where each iteration starts
                first = False
            add(line, n)
    else:
        for j in range(copies):
            add(f"retrosim_iter_{j}:")
            for n, line in body.lines:
                add(_rename(line, body.labels, f"__r{j}"), n)
    add("retrosim_exit:")
    add("nop")
    return "\n".join(t for t, _ in out) + "\n", [n for _, n in out]


@dataclass
class LoopRun:
    """What the timing side is handed: the assembled program, its traced passes (one trace, warm pass
    then measured pass) and the marks (cut points, the PC after the trace, the body's address)."""

    body: Body
    machine: Machine = field(repr=False)
    trace: Trace = field(repr=False)
    cuts: list[int]        # end of warm pass, start of iteration n1, start of iteration n2 (measured pass)
    measured: int          # iterations between the last two cuts
    iteration_length: int  # instructions in the first measured iteration (for the timeline)
    next_pc: int = -1      # where the body goes after the trace's last instruction (its back-edge's target)
    address: int = 0       # the body's first instruction

    @property
    def fetch(self):
        """The program's code bytes by address (what a Decoder reads)."""
        return self.machine.image.fetch

    @property
    def alignment(self) -> int:
        """The largest power of two (up to ALIGN_SPAN) the body's address is a multiple of."""
        return min(ALIGN_SPAN, self.address & -self.address) if self.address else ALIGN_SPAN


class _DemandZero:
    """Maps zero-filled pages where the body touches unmapped data, within a page budget."""

    def __init__(self, machine: Machine):
        self.machine, self.pages = machine, 0
        machine.uc.hook_add(UC_HOOK_MEM_READ_UNMAPPED | UC_HOOK_MEM_WRITE_UNMAPPED, self._on_unmapped)

    def _on_unmapped(self, uc, kind, address, size, value, user_data):
        first, last = address & ~(elf.PAGE - 1), (address + max(size, 1) - 1) & ~(elf.PAGE - 1)
        if first < NULL_LIMIT or self.pages >= MAX_DATA_PAGES:
            return False
        for page in range(first, last + elf.PAGE, elf.PAGE):
            try:
                uc.mem_map(page, elf.PAGE, UC_PROT_READ | UC_PROT_WRITE)
                self.pages += 1
            except UcError:
                pass  # already mapped (an access straddling into a mapped page)
        self.machine._fault = None  # the Machine's own hook saw it first; it is handled now
        return True


def _truncate(trace: Trace, n: int) -> Trace:
    return trace.head(n)


def _user_line(body: Body, lines: list[int], message: str, generated: Path, wrapper: str | None = None) -> str:
    """An assembler message about the generated file, on the user's line (or naming `wrapper`)."""
    m = re.match(rf"^{re.escape(str(generated))}:(\d+): (.*)$", message)
    if not m:
        if wrapper and re.match(rf"^{re.escape(str(generated))}: {re.escape(str(generated))} has ", message):
            # a limit on the file as a whole: the wrapper's, not the user's file's
            return message.replace(f"{generated}: {generated}", wrapper)
        return message.replace(str(generated), body.name)
    k = int(m.group(1)) - 1
    # a harness line (a label of ours) that fails was broken by the user line before it (an open
    # string or expression): the message names that line and none of the harness's names
    n = next((lines[j] for j in range(min(k, len(lines) - 1), -1, -1) if lines[j]), 0)
    text = re.sub(r"`?'?retrosim_\w+:?'?`?", "the next line the harness adds", m.group(2)) if not lines[k] else m.group(2)
    return f"{body.name}:{n}: {text}" if n else f"{body.name}: {text}"



def parse_regs(items) -> dict[str, int]:
    regs = dict(REG_DEFAULTS)
    for item in items or ():
        name, _, value = item.partition("=")
        name = name.strip().lower()
        if name not in REG_DEFAULTS or not value.strip():
            raise ArgumentError(f"--reg {item}: expected R=V with R one of {', '.join(REG_DEFAULTS)}")
        try:
            number = int(value, 0)
        except ValueError:
            raise ArgumentError(f"--reg {item}: '{value}' is not an integer") from None
        if not -(1 << 31) <= number < 1 << 32:
            raise ArgumentError(f"--reg {item}: {name} holds 32 bits (from -0x80000000 to 0xFFFFFFFF)")
        regs[name] = number & 0xFFFFFFFF
    return regs


def check_iterations(body: Body, iterations: int) -> None:
    """Refuse an iteration count outside what the harness can do in bounded time and memory."""
    if not 4 <= iterations <= MAX_ITERATIONS:
        raise ArgumentError(f"--iterations {iterations}: must be from 4 to {MAX_ITERATIONS:,}")
    size = sum(len(line) + 1 for _, line in body.lines) * (1 if body.loop else iterations + 1)
    if size > asm.MAX_SOURCE_BYTES:
        raise ArgumentError(f"--iterations {iterations}: the wrapper generated around {body.name} would have "
                            f"{size:,} bytes, more than the {asm.MAX_SOURCE_BYTES >> 20} MB a source may have")
    total = (iterations + 1) * body.instructions
    if not body.loop and total > MAX_BLOCK_INSTRUCTIONS:
        most = MAX_BLOCK_INSTRUCTIONS // body.instructions - 1
        raise ArgumentError(f"--iterations {iterations}: {body.name} is a block (no back-edge), so it is repeated "
                            f"{iterations + 1:,} times, {total:,} instructions to assemble; the limit is "
                            f"{MAX_BLOCK_INSTRUCTIONS:,}: use -n {most} or less (at least 4), or end the body with "
                            "a jump back to its first instruction")


def _assemble(body: Body, copies: int, pad: int, assembler: str | None, cpu: GuestCpu | None) -> Machine:
    """The body's wrapper (`copies` copies of a block), assembled and loaded. Messages name the
    user's lines; a limit the wrapper exceeds names the wrapper, not the user's file."""
    text, lines = wrapper_source(body, copies, pad)
    with tempfile.TemporaryDirectory(prefix="retrosim-loop-") as tmp:
        path = Path(tmp) / "loop.S"
        path.write_text(text)
        wrapper = f"the wrapper generated around {body.name}" + (f" ({copies:,} copies)" if copies > 1 else "")
        try:
            return Machine.from_source(path, assembler=assembler, cpu=cpu)
        except AssemblerError as e:
            raise AssemblerError(_user_line(body, lines, str(e), path, wrapper),
                                 tuple(_user_line(body, lines, m, path, wrapper) for m in e.messages)) from None
        except UntranslatableCode as e:
            raise UntranslatableCode(f"{body.name}: {wrapper} holds {e.count} {X87_RUN_WORDS}; {X87_RUN_LIMIT_WORDS}"
                                     + (" (or time it as a loop ending in a jump back to its start)" if copies > 1 else ""),
                                     e.offset, e.count) from None
        except RetrosimError as e:
            raise RetrosimError(_user_line(body, lines, str(e), path, wrapper)) from None


def run_body(body: Body, iterations: int = DEFAULT_ITERATIONS, regs: dict[str, int] | None = None,
             assembler: str | None = None, cpu: GuestCpu | None = None, align: int = DEFAULT_ALIGN,
             offset: int = 0) -> LoopRun:
    """Assemble the body in its wrapper (for `cpu`'s instruction set, if given; placed as
    :func:`placement` says) and trace the warm and the measured pass."""
    check_iterations(body, iterations)
    regs = regs or dict(REG_DEFAULTS)
    n1, n2 = iterations // 2, iterations
    pad = placement(align, offset)
    # a block is first assembled once: its errors are then the user's lines, once each
    for copies in ((n2 + 1,) if body.loop else (1, n2 + 1)):
        machine = _assemble(body, copies, pad, assembler, cpu)
    machine.image.path = Path(body.name)
    _DemandZero(machine)
    starts = [machine.symbol(f"retrosim_iter_{j}") for j in range(1 if body.loop else n2 + 1)]
    exit_pc = machine.symbol("retrosim_exit")
    lo = machine.symbol("retrosim_loop")
    if lo % ALIGN_SPAN != pad:  # the loader must keep the section's alignment
        raise RetrosimError(f"{body.name}: the body was placed at {lo:#x}, not {pad} bytes past a "
                            f"{ALIGN_SPAN}-byte boundary")
    rep_first = machine.disassemble(starts[0]).split()[0].lower() in _REP_PREFIXES
    passes = [_pass(machine, body, regs, starts, exit_pc, lo, n2, rep_first) for _ in range(2)]
    warm, (meas, marks, next_pc) = passes[0][0], passes[1]
    cuts = [warm.instructions, warm.instructions + marks[n1], warm.instructions + marks[n2]]
    return LoopRun(body, machine, Trace.concatenate([warm, meas]), cuts, n2 - n1, marks[n1 + 1] - marks[n1],
                   next_pc, starts[0])


def _pass(machine: Machine, body: Body, regs: dict[str, int], starts: list[int], exit_pc: int, lo: int,
          iterations: int, rep_first: bool = False) -> tuple[Trace, list[int], int]:
    """Run from the body's start with `regs` until `iterations` iterations are complete; return the
    trace up to the start of the next one, the index where each iteration starts and the PC of the
    next iteration's first instruction (what follows the trace)."""
    uc = machine.uc
    for name, value in regs.items():
        machine.set_reg(name, value)
    uc.reg_write(X.UC_X86_REG_ESP, _STACK_TOP)
    machine.reset_fpu()
    tracer = NativeTracer(uc, instruction_capacity=1 << 16, access_capacity=1 << 17,
                          control_word_pcs=machine.control_word_pcs())
    tracer.attach()
    pc = starts[0]
    # Run no further than the iterations still needed can take (from the instructions per iteration
    # seen so far), so a body that touches a new page per iteration maps only the pages `iterations`
    # iterations touch, not a whole trace buffer's worth; before the first iteration completes, the
    # budget grows fourfold per segment.
    budget = 1024
    try:
        while True:
            tracer.limit(min(tracer.icap, budget, MAX_INSTRUCTIONS - tracer.recorded))
            machine._fault = machine._interrupt = None
            try:
                uc.emu_start(pc, exit_pc)
            except UcError as e:
                raise _fault(machine, body, machine._describe_fault(e.errno), lo, exit_pc) from None
            if machine._interrupt is not None:
                raise _fault(machine, body, machine._describe_fault(UC_ERR_EXCEPTION), lo, exit_pc)
            tracer.drain()
            pc = machine.reg("eip")
            trace = Trace.concatenate(list(tracer._parts))
            marks = _marks(trace.pc, starts, body.loop, rep_first)
            if len(marks) > iterations:
                break
            done = len(marks) - 1  # complete iterations so far
            if done >= 1:
                per = (marks[-1] - marks[0]) / done
                budget = int((iterations + 1 - done) * per) + 16
            else:
                budget *= 4
            outside = np.flatnonzero((trace.pc < lo) | (trace.pc >= exit_pc))
            if outside.size:
                k = int(outside[0])
                src = machine.disassemble(int(trace.pc[k - 1])) if k else "?"
                raise RetrosimError(f"{body.name}: the body branches out of itself: '{src}' went to "
                                    f"{int(trace.pc[k]):#010x}")
            if pc == exit_pc:
                if body.loop:
                    raise RetrosimError(
                        f"{body.name}: the loop left through its back-edge after {max(len(marks) - 1, 1)} "
                        f"iteration(s), {iterations} needed: give its counter a larger start value with --reg "
                        f"(defaults: {', '.join(f'{k}={v:#x}' for k, v in REG_DEFAULTS.items())})")
                raise RetrosimError(f"{body.name}: the block skipped some of its own copies (a forward jump out of it)")
            if tracer.recorded >= MAX_INSTRUCTIONS:
                done = len(marks) - 1
                if done >= 1:  # it does iterate: the iterations asked for are too many for its length
                    per = (marks[-1] - marks[0]) / done
                    raise RetrosimError(
                        f"{body.name}: {iterations} iterations of the body need more than {MAX_INSTRUCTIONS:,} "
                        f"instructions per pass: it reached its back-edge {done} times, {per:,.0f} instructions "
                        f"per iteration (fewer --iterations, at most about {max(int(MAX_INSTRUCTIONS / per) - 1, 1):,}; "
                        "or a shorter inner loop or REP count: set its register with --reg)")
                raise RetrosimError(f"{body.name}: the body never reached its back-edge {iterations} times in "
                                    f"{MAX_INSTRUCTIONS:,} instructions (an inner loop or REP count too long? "
                                    "set its register with --reg)")
    finally:
        tracer.detach()
    cut = marks[iterations]
    next_pc = int(trace.pc[cut])
    trace = _truncate(trace, cut)
    outside = np.flatnonzero((trace.pc < lo) | (trace.pc >= exit_pc))
    if outside.size:
        k = int(outside[0])
        raise RetrosimError(f"{body.name}: the body branches out of itself: "
                            f"'{machine.disassemble(int(trace.pc[k - 1]))}' went to {int(trace.pc[k]):#010x}")
    return trace, marks[:iterations + 1], next_pc


def _marks(pc: np.ndarray, starts: list[int], loop: bool, rep_first: bool = False) -> list[int]:
    """Where each iteration (loop) or copy (block) starts in the pass's PC stream."""
    if loop:
        at = pc == starts[0]
        if rep_first:
            # a REP string instruction appears once per element at the same PC: an iteration starts
            # at its first element only (a one-instruction `l: loop l` still starts one per pass)
            at[1:] &= pc[:-1] != starts[0]
        return np.flatnonzero(at).tolist()
    first = []
    for s in starts:
        hit = np.flatnonzero(pc == s)
        if not hit.size:
            break
        first.append(int(hit[0]))
    return first


def _fault(machine: Machine, body: Body, fault: GuestFault, lo: int, hi: int) -> RetrosimError:
    if not lo <= fault.pc <= hi:  # a computed jump left the body and landed on no code
        return RetrosimError(f"{body.name}: the body branches out of itself: a jump went to {fault.pc:#010x}")
    msg = str(fault).removeprefix(f"{body.name}: ")  # the machine's fault names the file already: once is enough
    msg = msg.replace(" (retrosim_loop+", " (body+").replace(" (retrosim_iter_0+", " (body+")
    msg = re.sub(r" \(retrosim_\w+\+0x[0-9a-f]+\)", "", msg)
    if fault.address is not None and fault.address < NULL_LIMIT and lo <= fault.pc < hi:
        msg += " (below 64 KB: a null pointer; set the register with --reg)"
    elif fault.address is not None and lo <= fault.pc < hi:
        msg += f" (more than {MAX_DATA_PAGES * elf.PAGE >> 20} MB of data touched, or a protected page)"
    return RetrosimError(f"{body.name}: {msg}")


def x87_warnings(run: LoopRun) -> list[str]:
    """A warning when the body leaves the x87 stack deeper or shallower after each iteration: the
    eight-register stack then overflows (or underflows) within a few iterations on real hardware, a
    stack fault (Intel SDM vol. 1, "x87 FPU stack overflow or underflow": #IS, NaN results when
    masked), so the timing describes no real run. Unicorn does not fault, so the trace cannot tell."""
    window = run.trace.pc[run.cuts[1]:run.cuts[2]]
    pcs, counts = np.unique(window, return_counts=True)
    records, _ = Decoder(run.machine.image.fetch).decode_trace(pcs)
    delta = {rec.pc: rec.fpu_stack_delta for rec in records}
    net = sum(int(delta.get(int(pc), 0)) * int(n) for pc, n in zip(pcs, counts)) / run.measured
    if not net:
        return []
    what = f"pushes {net:g} more x87 register(s) than it pops" if net > 0 else f"pops {-net:g} more x87 register(s) than it pushes"
    return [f"{run.body.name}: each iteration {what}: the 8-register x87 stack {'overflows' if net > 0 else 'underflows'} "
            "within 8 iterations on real hardware (a stack fault), so this timing describes no real run"]


# What an instruction-set extension is called in "not timed (no MMX): ..." (sim/guest/isa.py names).
EXTENSION_NAMES = {"cmov": "CMOV", "fcmov": "FCMOV/FCOMI", "mmx": "MMX", "sse": "SSE", "3dnow": "3DNow!",
                   "fxsr": "FXSAVE/FXRSTOR", "sse2": "SSE2", "nopl": "multi-byte NOP"}


def required_extensions(run: LoopRun) -> set[str]:
    """The instruction-set extensions the executed body uses (sim/guest/isa.py)."""
    records, _ = Decoder(run.machine.image.fetch).decode_trace(np.unique(run.trace.pc))
    return {ext for rec in records if (ext := isa.record_extension(rec))}


def _where(run: LoopRun, pc: int) -> str:
    """Where an instruction of the body is, as `retrosim time` says it (`file: pc ADDRESS (entry+k)`)."""
    return f"{run.body.name}: pc {pc:#010x} (body+{pc - run.address:#x})"


def run_on_cpus(body: Body, cpus: list[str], targets: dict[str, GuestCpu], iterations: int = DEFAULT_ITERATIONS,
                regs: dict[str, int] | None = None, assembler: str | None = None, align: int = DEFAULT_ALIGN,
                offset: int = 0, skip: bool = True) -> tuple[list[tuple[str, LoopRun]], dict[str, list[str]]]:
    """The body's run, in order, for each CPU of `cpus` (each with its GuestCpu in `targets`) that has
    every instruction it uses, and the others by what they lack ({"MMX": [cpu, ...]}). With no CPU
    able to run it (or `skip` false and one CPU unable), the first refusal is the error."""

    def isa_key(c):
        t = targets[c]
        return (t.gnu_march, t.zig_mcpu, t.emulator_cpu)

    # one emulation per instruction set: the body assembles for each CPU's own (MMX, 3DNow!, SSE)
    # and runs on the Unicorn CPU model that has it; an assembler that refuses an instruction for
    # one of them is kept as that set's answer
    runs: dict[tuple, LoopRun | RetrosimError] = {}
    for c in cpus:
        key = isa_key(c)
        if key not in runs:
            try:
                runs[key] = run_body(body, iterations, regs, assembler, cpu=targets[c], align=align, offset=offset)
            except (AssemblerError, isa.IsaError) as e:
                runs[key] = e
    done = [r for r in runs.values() if isinstance(r, LoopRun)]
    if not done:
        raise next(iter(runs.values()))
    records = {id(r): Decoder(r.machine.image.fetch).decode_trace(np.unique(r.trace.pc))[0] for r in done}
    for run in done:  # a system instruction has no timing on any CPU (as `retrosim time` refuses it)
        for rec in records[id(run)]:
            if isa.is_system(rec):
                raise isa.system_refusal(_where(run, rec.pc), f"{rec.mnemonic} {rec.op_str}".strip(), targets[cpus[0]])
    out, missing, refusals = [], {}, []
    for c in cpus:
        run = runs[isa_key(c)]
        if not isinstance(run, LoopRun):
            refusals.append(run)
            lacks = sorted(required_extensions(done[0]) - targets[c].extensions, key=isa.EXTENSIONS.index)
            if skip and lacks:  # the assembler refused what the body needs for this CPU
                missing.setdefault(", ".join(EXTENSION_NAMES[x] for x in lacks), []).append(c)
                continue
            raise run  # refused for another reason than an extension the body uses
        try:  # assembled (an assembler may accept more than the CPU has): the CPU must have it all
            for rec in records[id(run)]:
                isa.check_record(rec, targets[c], lambda rec=rec, run=run: _where(run, rec.pc))
        except isa.IsaError as e:
            if not skip:
                raise
            refusals.append(e)
            lacks = sorted(required_extensions(run) - targets[c].extensions, key=isa.EXTENSIONS.index)
            missing.setdefault(", ".join(EXTENSION_NAMES[x] for x in lacks), []).append(c)
            continue
        out.append((c, run))
    if not out:  # no CPU could run it: the refusal `retrosim time` gives on the first one
        raise refusals[0]
    return out, missing
