"""The views of a timed run, registered once, in the style of llvm-mca's Views: each has a name, the
key of its part in the --json documents (which the pipeline page and `serve` draw from), and its
text for the terminal. `time`, `explain` and `loop` iterate :data:`VIEWS` for the views their
command shows, so a new view is one entry here (and its functions in sim/reports/views.py).

A view only reads a run (sim/reports/views.py says how); it never times anything.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from rich.markup import escape

from sim.reports import views

# How a text item is printed: "rich" (a table, or text with markup), "lines" (literal text: rows hold
# [esi], wrapped at the terminal's width), "chart" (literal, never wrapped: the timeline).
RICH, LINES, CHART = "rich", "lines", "chart"


@dataclass(frozen=True)
class TextContext:
    """What a view's text needs besides the run: the command, the terminal's width, the CPU's label
    (a loop names it per table), and the timeline's iterations."""

    command: str
    width: int
    cpu: str = ""
    iterations: int = 0


@dataclass(frozen=True)
class View:
    name: str
    key: str                                     # its part of the --json document
    commands: frozenset[str]                     # the commands that show it: time, explain, loop
    data: Callable                               # (result) -> its JSON part
    text: Callable | None = None                 # (result, TextContext) -> [(item, how)]


def _summary_text(result, ctx: TextContext) -> list:
    limits = views.caveats(result)
    return ([(views.summary_table(result), RICH)] + [(line, LINES) for line in views.caveat_lines(result, limits)]
            + [(views.stall_table(result), RICH)])


def _instructions_text(result, ctx: TextContext) -> list:
    if ctx.command == "loop":  # each CPU's table names it; a loop body has measured iterations, not calls
        return ([(t, RICH) for t in views.loop_tables(result, ctx.cpu, ctx.width)]
                + [("note: " + views.STALL_OVERLAP_NOTE, LINES)])
    return ([(t, RICH) for t in views.explain_tables(result, ctx.width)]
            + [(line, LINES) for line in views.explain_legend(result)]
            + [(line, LINES) for line in views.caveat_details(result)])


def _timeline_text(result, ctx: TextContext) -> list:
    text = views.timeline_text(result, columns=ctx.width)
    if not text:
        return []
    if ctx.command == "loop":  # its legend under it (explain's legend, above the chart, says it already)
        head = f"[bold]timeline[/] on {escape(ctx.cpu)}: {ctx.iterations} iterations from the middle of the measured pass"
        return [(head, RICH), (text, CHART), ("legend: " + views.timeline_key(result, causes=True), LINES)]
    head = f"[bold]timeline[/]: {ctx.iterations} iterations of the hot loop, from the middle of the last call"
    return [(head, RICH), (text, CHART)]


VIEWS: tuple[View, ...] = (
    View("summary", "summary", frozenset({"time", "explain"}),
         lambda result: {**views.summary(result), "model_limits": views.caveats(result)}, _summary_text),
    View("model limits", "model_limits", frozenset({"loop"}), views.caveats),  # explain and time: in the summary
    View("instructions", "instructions", frozenset({"explain", "loop"}), views.explain_rows, _instructions_text),
    View("timeline", "timeline", frozenset({"explain", "loop"}), views.timeline_rows, _timeline_text),
)


def of(command: str) -> list[View]:
    """The views `command` shows, in the registry's order."""
    return [v for v in VIEWS if command in v.commands]


def document(result, command: str) -> dict:
    """The JSON parts of the run for `command`: {key: data} of its views."""
    return {v.key: v.data(result) for v in of(command)}


def text(result, ctx: TextContext) -> list:
    """The terminal text of the run for ctx.command: [(item, how)] of its views, in order."""
    return [item for v in of(ctx.command) if v.text is not None for item in v.text(result, ctx)]
