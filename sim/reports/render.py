"""How reports are written, whatever they report: Markdown tables, the self-contained HTML page,
the timings CSV, the PNG of a plot and the frame of the scenes' dot plots, and the atomic writes.

Reports are generated, never edited. Every file is written to a temporary name and renamed, so an
interrupted run leaves the previous report intact. Numbers are formatted deterministically so a
re-run on any machine produces the same Markdown, JSON and CSV bytes (CI compares them).
"""

from __future__ import annotations

import base64
import csv
import html
import io
import re
from pathlib import Path

from sim import output
from sim.cpus.families import FAMILIES

FORMATS = ("md", "png", "json", "csv", "html")
FAMILY_MARKERS = {n: f.marker for n, f in FAMILIES.items()}  # a plot marker shape per CPU family (the registry)


def atomic_write(path: Path, data: bytes) -> None:
    # one writer for every output (sim.output: refuses devices and folders, follows the umask)
    output.check_output_dir(Path(path).parent)
    output.atomic_write(path, data)


def write_payloads(out_dir: Path, name: str, payloads: dict, formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """Write `name`.FORMAT in `out_dir` for each of `formats` whose payload (bytes) is not None."""
    written = []
    for fmt in formats:
        data = payloads[fmt]
        if data is None:
            continue
        path = Path(out_dir) / f"{name}.{fmt}"
        atomic_write(path, data)
        written.append(path)
    return written


def wants_image(formats: tuple[str, ...]) -> bool:
    """Whether the plot is needed: it is written as the PNG and embedded in the HTML page."""
    return "png" in formats or "html" in formats


def write_report_set(out_dir: Path, name: str, md: str, image: bytes | None, json_text: str, csv_text: str,
                     formats: tuple[str, ...] = FORMATS) -> list[Path]:
    """A scene's report files: `name`.md/.png/.json/.csv and the HTML page of the Markdown with the
    plot embedded (`image` None: no PNG and no plot in the page), for each of `formats`."""
    payloads = {"md": md.encode(), "png": image, "json": json_text.encode(), "csv": csv_text.encode(),
                "html": render_html(md, image).encode()}
    return write_payloads(out_dir, name, payloads, formats)


def md_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def timings_csv(scene: str, timings: list, units: tuple[str, str] = ("pixels", "cycles_per_pixel")) -> str:
    """One row per timing (an object with variant, cpu, memory, pixels, counters and per_pixel());
    the counter columns are the union over the timings, in order of first appearance (families count
    different things: the K6 adds fpu_ops, l3_*), empty where a CPU's model has no such counter.
    `units` names the work-unit columns (a snap scene counts vertices)."""
    buf = io.StringIO()
    counters = list(dict.fromkeys(c for t in timings for c in t.counters))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["scene", "variant", "cpu", "memory", *units] + counters)
    for t in timings:
        w.writerow([scene, t.variant, t.cpu, t.memory, t.pixels, f"{t.per_pixel('cycles'):.4f}"]
                   + [t.counters.get(c, "") for c in counters])
    return buf.getvalue()


# -- plots ---------------------------------------------------------------------------------------
# The scenes' plots share one form: a row per variant, cycles along x, a marker per machine.

def png_bytes(fig) -> bytes:
    """The figure as PNG bytes (no software tag, so the file depends on the data alone); closes it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def row_offset(i: int, n: int, spread: float) -> float:
    """Vertical offset of the i-th of n machines' markers within a row, so none hides another."""
    return (i - (n - 1) / 2) * (spread / max(1, n - 1)) if n > 1 else 0.0


def finish_rows(fig, ax, rows: list[str], ypos: dict, labels: list[str], xlabel: str, title: str, fontsize: int,
                ncol: int) -> None:
    """The frame of a rows-of-variants dot plot: separators, row labels, axis text, legend below."""
    for k in range(len(rows) - 1):
        ax.axhline(k + 0.5, color="0.85", lw=0.8, zorder=1)
    ax.set_yticks([ypos[v] for v in rows], labels, fontsize=fontsize)
    ax.set_ylim(-0.5, len(rows) - 0.5)
    ax.set_xlabel(xlabel, fontsize=10)
    ax.set_title(title, fontsize=10)
    ax.grid(axis="x", color="0.9", zorder=0)
    ax.tick_params(axis="x", labelsize=9)
    ax.margins(x=0.04)
    fig.legend(fontsize=fontsize, loc="outside lower center", ncol=ncol, frameon=False, handletextpad=0.3,
               columnspacing=1.2)


# -- HTML ------------------------------------------------------------------------------------------
_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}"
        "table{border-collapse:collapse;margin:1em 0;font-size:90%}td,th{border:1px solid #ccc;padding:2px 6px;"
        "text-align:right}td:first-child,th:first-child{text-align:left}img{max-width:100%}")


_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*(.+?)\*\*")


def _inline(text: str) -> str:
    """One line of Markdown text as HTML: escaped, with the reports' `code` and **bold** spans."""
    return _BOLD.sub(r"<strong>\1</strong>", _CODE.sub(r"<code>\1</code>", html.escape(text)))


def render_html(markdown: str, png: bytes | None) -> str:
    """The Markdown report as one self-contained HTML page (tables, headings, the inlined plot)."""
    body: list[str] = []
    table: list[str] = []

    def flush():
        if table:
            head, *rest = table
            body.append("<table><tr>" + "".join(f"<th>{c}</th>" for c in head) + "</tr>"
                        + "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rest) + "</table>")
            table.clear()

    for line in markdown.splitlines():
        if line.startswith("|"):
            if set(line.replace("|", "").strip()) <= {"-"}:
                continue
            table.append([_inline(c.strip()) for c in line.strip().strip("|").split("|")])
            continue
        flush()
        if line.startswith("### "):
            body.append(f"<h3>{html.escape(line[4:])}</h3>")
        elif line.startswith("## "):
            body.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif line.startswith("# "):
            body.append(f"<h1>{html.escape(line[2:])}</h1>")
        elif line.startswith("!["):
            if png:
                data = base64.b64encode(png).decode()
                body.append(f'<p><img alt="work-precision plot" src="data:image/png;base64,{data}"></p>')
        elif line.lstrip().startswith("- "):  # a list item; "  - " one level in (a claim's per-CPU lines)
            nested = ' style="margin-left:2em"' if line.startswith(" ") else ""
            body.append(f"<li{nested}>{_inline(line.lstrip()[2:])}</li>")
        elif line.strip():
            body.append(f"<p>{_inline(line)}</p>")
    flush()
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>retrosim report</title>"
            f"<style>{_CSS}</style></head><body>" + "\n".join(body) + "</body></html>\n")


def console_label(label: str, memory: str) -> str:
    """A machine label as a console table shows it: with a space before its overrides and after each
    comma, so that a narrow terminal wraps it between words ("k6-233 {write_allocate.mode=page+sector
    only} sdram-pc66") instead of folding a word in two. Files keep the exact label."""
    return (label.replace("{", " {", 1).replace(",", ", ") + " " + memory).strip()


def add_label_column(table, header: str, labels: list[str]) -> None:
    """The machine column of a console table: at least as wide as its longest word (up to 40 characters,
    what 80 columns leave beside the numbers), wrapped between words."""
    longest = max((len(word) for text in labels for word in text.split()), default=0)
    table.add_column(header, overflow="fold", min_width=min(max(longest, len(header)), 40))
