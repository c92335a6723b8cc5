"""Error types. Each carries one line a user can act on: the file, field, line or guest PC."""


class RetrosimError(Exception):
    """Base class for every error retrosim reports to a user (the CLI prints str(e) and exits 2)."""


class AssemblerError(RetrosimError):
    """The assembler rejected a kernel source; the message is `file:line: message` (the first, with
    how many more). `messages`: every one of them, first first (what the web app shows in full)."""

    def __init__(self, message: str, messages: tuple[str, ...] = ()):
        super().__init__(message)
        self.messages = tuple(messages) or (message,)


class AssemblerMissing(RetrosimError):
    """No usable assembler was found; the message says how to get one."""


class LoadError(RetrosimError):
    """An ELF object could not be loaded (unknown relocation, undefined symbol, layout overflow)."""


class UnknownSymbol(LoadError):
    """An entry point or data symbol that the object does not define."""


class UntranslatableCode(LoadError):
    """Code the emulator is known to crash on (see sim.guest.emu._x87_run_start); refused before it runs.
    `count` instructions in a row at `offset` bytes into the code region."""

    def __init__(self, message: str, offset: int, count: int):
        super().__init__(message)
        self.offset, self.count = offset, count


class GuestFault(RetrosimError):
    """The guest touched unmapped memory or executed an invalid instruction."""

    def __init__(self, message: str, pc: int, address: int | None = None):
        super().__init__(message)
        self.pc = pc
        self.address = address


class RunawayKernel(GuestFault):
    """The guest exceeded its instruction budget (an endless loop, or a budget set too low)."""


class ArgumentError(RetrosimError):
    """A kernel was called with the wrong number or kind of arguments."""


class OutputError(RetrosimError):
    """An output path retrosim refuses or cannot write (a device, a folder, a read-only place)."""


class LimitError(RetrosimError):
    """A run or an input would exceed a size limit; the message names the limit and how to raise it."""
