"""Load ELF32 i386 relocatable objects into a guest memory image (pyelftools).

The guest address map is fixed so that addresses, and therefore cache behaviour, are the same on
every run and every machine:

    0x00001000  exit page: the return address of every call points at a HLT here
    0x00400000  code: executable sections, in object order, each at its own alignment
    (next 4 KB) data: .rodata, .data, .bss and any other allocated sections
    0x0FF00000  stack (1 MB; ESP starts at its top)
    0x10000000  workload arena (linear, bump-allocated; size chosen by the machine)

Relocations R_386_32 and R_386_PC32 are applied at the load address; any other type is an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from elftools.common.exceptions import ELFError
from elftools.elf.constants import SH_FLAGS
from elftools.elf.elffile import ELFFile

from sim.errors import LoadError, UnknownSymbol

PAGE = 0x1000
EXIT_ADDR = 0x00001000
CODE_BASE = 0x00400000
CODE_LIMIT = 0x01000000  # code and data must fit below this
STACK_BASE = 0x0FF00000
STACK_SIZE = 0x00100000
ARENA_BASE = 0x10000000

R_386_NONE, R_386_32, R_386_PC32 = 0, 1, 2
# the narrow references GNU as emits for `.word sym`, `.byte sym` and their PC-relative forms
_NARROW = {20: "a 16-bit reference (R_386_16)", 21: "a 16-bit PC-relative reference (R_386_PC16)",
           22: "an 8-bit reference (R_386_8)", 23: "an 8-bit PC-relative reference (R_386_PC8)"}


def _shown(name: str) -> str:
    """A symbol name as a user can read it: quoted, with control characters escaped."""
    return repr(name) if name else ""


def page_up(n: int) -> int:
    return (n + PAGE - 1) & ~(PAGE - 1)


def align_up(n: int, a: int) -> int:
    a = max(1, a)
    return (n + a - 1) // a * a


@dataclass(frozen=True)
class Section:
    name: str
    address: int
    size: int
    executable: bool
    writable: bool


@dataclass
class GuestImage:
    """The loaded object: section placement, symbol addresses and the bytes to map."""

    path: Path
    sections: dict[str, Section]
    symbols: dict[str, int]  # defined symbols (globals win over locals of the same name)
    global_symbols: frozenset[str]
    code: tuple[int, bytearray]  # (base, bytes) of the code region
    data: tuple[int, bytearray]  # (base, bytes) of the data region; may be empty
    function_sizes: dict[str, int] = field(default_factory=dict)

    def symbol(self, name: str) -> int:
        try:
            return self.symbols[name]
        except KeyError:
            known = ", ".join(sorted(self.global_symbols)) or "none"
            raise UnknownSymbol(f"{self.path}: no symbol '{name}' (global symbols: {known})") from None

    def fetch(self, address: int, n: int) -> bytes:
        """Up to n bytes of code or data at a guest address (for the decoder)."""
        for base, blob in (self.code, self.data):
            if base <= address < base + len(blob):
                off = address - base
                return bytes(blob[off:off + n])
        return b""

    def section_of(self, address: int) -> Section | None:
        for s in self.sections.values():
            if s.address <= address < s.address + max(1, s.size):
                return s
        return None


def _place(sections, start: int) -> tuple[dict[str, int], int]:
    """Assign addresses to sections from `start`, honouring alignment; returns placement and end."""
    at, placed = start, {}
    for sec in sections:
        at = align_up(at, sec["sh_addralign"])
        placed[sec.name] = at
        at += sec["sh_size"]
    return placed, at


def load_object(path: str | Path, source: str | Path | None = None) -> GuestImage:
    """Load an ELF32 object. Errors (and the image's path) name `source` when given: the user wrote
    the kernel source, the object is only the assembler cache's copy of it."""
    path = Path(path)
    label = Path(source) if source is not None else path
    try:
        with open(path, "rb") as f:
            elf = ELFFile(f)
            return _load(elf, label)
    except ELFError as e:
        raise LoadError(f"{label}: not a valid ELF object ({e})") from None
    except OSError as e:
        raise LoadError(f"{label}: cannot read the object {path}: {e.strerror or e}") from None


def _load(elf: ELFFile, path: Path) -> GuestImage:
    if elf["e_machine"] != "EM_386" or elf.elfclass != 32:
        raise LoadError(f"{path}: expected an ELF32 i386 object, got {elf.elfclass}-bit {elf['e_machine']}")
    if elf["e_type"] != "ET_REL":
        raise LoadError(f"{path}: expected a relocatable object (ET_REL), got {elf['e_type']}")

    alloc = [s for s in elf.iter_sections() if s["sh_flags"] & SH_FLAGS.SHF_ALLOC and s["sh_size"] > 0]
    code_secs = [s for s in alloc if s["sh_flags"] & SH_FLAGS.SHF_EXECINSTR]
    data_secs = [s for s in alloc if not s["sh_flags"] & SH_FLAGS.SHF_EXECINSTR]
    code_at, code_end = _place(code_secs, CODE_BASE)
    data_base = page_up(code_end)
    data_at, data_end = _place(data_secs, data_base)
    if data_end > CODE_LIMIT:
        raise LoadError(f"{path}: code and data need {data_end - CODE_BASE} bytes, more than the "
                        f"{CODE_LIMIT - CODE_BASE} the guest map reserves")
    address = {**code_at, **data_at}

    code = bytearray(code_end - CODE_BASE)
    data = bytearray(data_end - data_base)
    for sec in alloc:
        if sec["sh_type"] == "SHT_NOBITS":
            continue  # .bss: already zero
        region, base = (code, CODE_BASE) if sec.name in code_at else (data, data_base)
        off = address[sec.name] - base
        region[off:off + sec["sh_size"]] = sec.data()

    symtab = elf.get_section_by_name(".symtab")
    if symtab is None:
        raise LoadError(f"{path}: the object has no symbol table (an empty source file?)")
    index_to_name = {i: s.name for i, s in enumerate(elf.iter_sections())}
    symbols: dict[str, int] = {}
    globals_: set[str] = set()
    sizes: dict[str, int] = {}
    for sym in symtab.iter_symbols():
        shndx = sym["st_shndx"]
        if not sym.name or sym["st_info"]["type"] in ("STT_SECTION", "STT_FILE") or not isinstance(shndx, int):
            continue
        sec_name = index_to_name.get(shndx)
        if sec_name not in address:
            continue
        is_global = sym["st_info"]["bind"] in ("STB_GLOBAL", "STB_WEAK")
        if is_global or sym.name not in symbols:
            symbols[sym.name] = address[sec_name] + sym["st_value"]
        if is_global:
            globals_.add(sym.name)
            if sym["st_info"]["type"] == "STT_FUNC":
                sizes[sym.name] = sym["st_size"]

    regions = {CODE_BASE: code, data_base: data}
    for rel_sec in elf.iter_sections():
        if rel_sec["sh_type"] == "SHT_RELA":
            raise LoadError(f"{path}: section {rel_sec.name}: RELA relocations are not used by i386 objects")
        if rel_sec["sh_type"] != "SHT_REL":
            continue
        target = elf.get_section(rel_sec["sh_info"])
        if target.name not in address:
            continue  # relocations for debug or other non-loaded sections
        rel_symtab = elf.get_section(rel_sec["sh_link"])
        for rel in rel_sec.iter_relocations():
            _apply(rel, rel_symtab, target.name, address, regions, index_to_name, path)

    sections = {
        s.name: Section(s.name, address[s.name], s["sh_size"],
                        bool(s["sh_flags"] & SH_FLAGS.SHF_EXECINSTR), bool(s["sh_flags"] & SH_FLAGS.SHF_WRITE))
        for s in alloc
    }
    return GuestImage(path, sections, symbols, frozenset(globals_), (CODE_BASE, code), (data_base, data), sizes)


def _apply(rel, symtab, target: str, address, regions, index_to_name, path: Path) -> None:
    kind = rel["r_info_type"]
    place = address[target] + rel["r_offset"]
    base = max(b for b in regions if b <= place)
    region, off = regions[base], place - base
    if kind == R_386_NONE:
        return
    sym = symtab.get_symbol(rel["r_info_sym"])
    shndx = sym["st_shndx"]
    if rel["r_info_sym"] == 0:  # no symbol: an absolute address (`jmp 0x12345678`), value 0 by the ELF spec
        shndx = "SHN_ABS"
    elif shndx == "SHN_UNDEF":
        # checked before the type: an unterminated string (`.byte 1,"`) reaches here as an undefined
        # symbol in an 8-bit field, and the name is what the user can act on
        raise LoadError(f"{path}: {target}+{rel['r_offset']:#x}: undefined symbol {_shown(sym.name)}")
    if kind not in (R_386_32, R_386_PC32):
        what = _NARROW.get(kind, f"relocation type {kind}")
        raise LoadError(f"{path}: {target}+{rel['r_offset']:#x}: {what} to {_shown(sym.name) or 'an address'} "
                        "is not supported (only 32-bit absolute and PC-relative references are)")
    if shndx == "SHN_ABS":
        s_value = sym["st_value"]
    else:
        sec_name = index_to_name.get(shndx)
        if sec_name not in address:
            raise LoadError(f"{path}: {target}+{rel['r_offset']:#x}: symbol '{sym.name}' is in an unloaded section")
        s_value = address[sec_name] + sym["st_value"]
    addend = int.from_bytes(region[off:off + 4], "little", signed=True)  # REL: implicit addend
    value = s_value + addend - (place if kind == R_386_PC32 else 0)
    region[off:off + 4] = (value & 0xFFFFFFFF).to_bytes(4, "little")
