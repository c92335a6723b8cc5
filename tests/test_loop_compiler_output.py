"""`retrosim loop` on whole compiler output (issue 32): real `gcc -O2 -m32` files (tests/fixtures/compiler,
made by its make.sh) cut into their innermost loops or LLVM-MCA regions, and the caches' state (--data)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim.cli import main, serve
from sim.errors import RetrosimError
from sim.guest import asm, body_source, loop_body
from sim.timing import loop

FIXTURES = Path(__file__).parent / "fixtures" / "compiler"
SHAPES = ("sum", "copy", "fill", "nested", "find")
FILES = sorted(FIXTURES.glob("*.s"))


def lines_of(path: Path) -> list[str]:
    return path.read_text().splitlines()


def back_edges(path: Path) -> list[tuple[int, str]]:
    """(1-based line, target) of every conditional jump in the file back to a label defined above it,
    read straight from the text (independent of body_source)."""
    text = lines_of(path)
    defined = {}
    out = []
    for n, line in enumerate(text, 1):
        m = re.match(r"^(\.L\w+):", line)
        if m:
            defined[m.group(1)] = n
        j = re.match(r"^\s+(j(?!mp)[a-z]+)\s+(\.L\w+)\s*$", line)
        if j and j.group(2) in defined:
            out.append((n, j.group(2)))
    return out


def test_every_fixture_is_real_gcc_output_for_its_source():
    assert len(FILES) == 24  # 6 sources x {pentium, pentiumpro} x {Intel, AT&T}
    for path in FILES:
        head = path.read_text()
        assert f'.file\t"{path.name.split("-")[0]}.c"' in head and "GCC: (Debian 12.2.0" in head, path.name
        assert ("\t.intel_syntax noprefix" in head) == path.name.endswith("-intel.s"), path.name


@pytest.mark.parametrize("path", [p for p in FILES if p.name.split("-")[0] in SHAPES], ids=lambda p: p.name)
def test_the_innermost_loop_is_found_and_named_by_its_lines(path):
    regions = body_source.regions(path.read_text(), path.name)
    edges = back_edges(path)
    # innermost: the back-edge whose label is the latest (nested.c's outer loop jumps back further)
    last, label = max(edges, key=lambda e: [n for n, l in enumerate(lines_of(path), 1) if l.startswith(e[1] + ":")][0])
    assert len(regions) == 1, [r.name for r in regions]
    r = regions[0]
    assert r.last == last and lines_of(path)[r.first - 1].startswith(label + ":")
    assert r.name == f"loop {label}"
    if path.name.startswith("nested"):  # the outer loop's back-edge is outside the region taken
        outer = [n for n, _ in edges if n != last]
        assert outer and all(n > r.last for n in outer)
    # nothing outside the region is in the text handed on (line numbers kept: blank lines)
    kept = [n for n, line in enumerate(r.text.splitlines(), 1) if line.strip()]
    assert all(r.first <= n <= r.last or re.fullmatch(r"\.(intel|att)_syntax.*", r.text.splitlines()[n - 1])
               for n in kept)


def test_an_early_exit_is_timed_as_not_taken_and_said():
    path = FIXTURES / "find-pentium-intel.s"
    r, = body_source.regions(path.read_text(), path.name)
    exit_line = next(n for n, line in enumerate(lines_of(path), 1) if re.match(r"\s+je\s+\.L4", line))
    assert r.first < exit_line < r.last
    assert r.notes == [f"{path.name}:{exit_line}: 'je .L4' leaves the region (to '.L4'): timed as not taken"]
    t, = loop.time_body(r.text, ["pentium2-233"], name=path.name)
    assert t.per_iteration["instructions"] == 5  # inc, cmp, je (not taken), cmp, jne: every one, each iteration


def test_marked_regions_are_timed_by_name():
    path = FIXTURES / "marked-pentiumpro-att.s"
    regions = body_source.regions(path.read_text(), path.name)
    assert [r.name for r in regions] == ["dot", "scale"]
    text = lines_of(path)
    for r in regions:  # the region is the instructions between its markers, and nothing else
        begin = next(n for n, line in enumerate(text, 1) if f"LLVM-MCA-BEGIN {r.name}" in line)
        end = next(n for n, line in enumerate(text[begin:], begin + 1) if "LLVM-MCA-END" in line)
        instructions = [n for n in range(begin + 1, end) if re.match(r"^\t[a-z]", text[n - 1])]
        assert (r.first, r.last) == (instructions[0], instructions[-1])


@pytest.mark.parametrize("shape", ["sum", "copy"])
def test_a_whole_file_times_as_its_loop_cut_by_hand(shape):
    path = FIXTURES / f"{shape}-pentium-att.s"
    r, = body_source.regions(path.read_text(), path.name)
    by_hand = "\n".join(lines_of(path)[r.first - 1:r.last]) + "\n"
    cpus = ["pentium-mmx-233", "k6-2-300"]
    whole = {t.cpu: t.per_iteration for t in loop.time_body(r.text, cpus, name=path.name)}
    cut = {t.cpu: t.per_iteration for t in loop.time_body(by_hand, cpus, name="cut.s")}
    assert whole == cut


def test_the_command_line_prints_one_section_per_region_and_json_lists_them():
    path = FIXTURES / "marked-pentium-intel.s"
    out = CliRunner().invoke(main, ["loop", str(path), "--cpu", "pentium-mmx-233", "--brief"])
    assert out.exit_code == 0, out.output
    assert out.output.count("region dot:") == 1 and out.output.count("region scale:") == 1
    doc = json.loads(CliRunner().invoke(main, ["loop", str(path), "--cpu", "pentium-mmx-233", "--json"]).output)
    assert [r["region"] for r in doc["regions"]] == ["dot", "scale"]
    assert all(r["results"][0]["cycles_per_iteration"] > 0 and len(r["lines"]) == 2 for r in doc["regions"])


def test_a_whole_function_without_a_loop_is_one_error():
    text = "\t.text\n\t.globl f\nf:\n\tmovl 4(%esp), %eax\n\taddl $1, %eax\n\tret\n"
    with pytest.raises(RetrosimError, match=r"^f\.s:1: '\.text': a section directive, so this is a whole file .* no "
                                            r"loop was found"):
        body_source.regions(text, "f.s")
    out = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233"], input=text)
    assert out.exit_code != 0 and out.output.count("no loop was found") == 1


def test_an_error_inside_a_region_names_the_files_line():
    path = FIXTURES / "sum-pentium-intel.s"
    text = lines_of(path)
    k = next(n for n, line in enumerate(text) if re.match(r"\s+add\s+eax, 4", line))
    text[k] = "\tadd eax, 4 4"  # junk after the expression: GNU as names the line
    out = CliRunner().invoke(main, ["loop", "-", "--cpu", "pentium2-233"], input="\n".join(text) + "\n")
    assert out.exit_code != 0 and f"<stdin>:{k + 1}:" in out.output


def test_a_bare_body_is_not_cut():
    body = "top:\n  add eax, [esi]\n  add esi, 4\n  dec ecx\n  jnz top\n"
    assert body_source.regions(body, "b.s") is None


def test_served_whole_files_drop_directives_outside_the_region():
    # gcc's output holds .file, .ident and .section: none is a directive a served body may use
    path = FIXTURES / "nested-pentium-att.s"
    answer = serve.compute({"body": path.read_text(), "cpus": ["pentium2-233"]})
    assert "data" in answer, answer
    assert answer["data"]["doc"]["region"] == "loop .L4"
    # the region itself is still held to the allow-list
    text = lines_of(path)
    k = next(n for n, line in enumerate(text) if line.startswith(".L4:"))
    text.insert(k + 1, '\t.incbin "/etc/hostname"')
    answer = serve.compute({"body": "\n".join(text) + "\n", "cpus": ["pentium2-233"]})
    assert "'.incbin' reads a file" in answer.get("error", ""), answer


def test_the_text_handed_on_never_holds_an_outside_directive():
    for path in FILES:
        for r in body_source.regions(path.read_text(), path.name):
            words = {w for line in r.text.splitlines() if (w := line.split()[0] if line.split() else "").startswith(".")
                     and not w.endswith(":")}
            assert words <= {".p2align", ".intel_syntax", ".att_syntax"}, (path.name, words)
            with asm.served_sources():  # each region passes the served check line by line
                for n, line in enumerate(r.text.splitlines(), 1):
                    loop_body.check_served_line(body_source.strip_comment(line, "intel" if "intel" in path.name else "att"),
                                                f"{path.name}:{n}")


# -- the caches' state ------------------------------------------------------------------------
FILL = FIXTURES / "fill-pentium-intel.s"


def _timed(path, cpu, data, iterations=100, regs=()):
    args = ["loop", str(path), "--cpu", cpu, "--json", "--data", data, "-n", str(iterations)]
    for r in regs:
        args += ["--reg", r]
    out = CliRunner().invoke(main, args)
    assert out.exit_code == 0, out.output
    doc = json.loads(out.output)
    section = doc["regions"][0] if "regions" in doc else doc
    assert section["data"] == data and doc.get("data", data) == data
    return section["results"][0]


def test_a_warm_fill_loop_times_as_l1_hits():
    # warm: the K6 (no write allocation in k6-233) times the fill as the same K6 with write allocation on
    cold, warm = _timed(FILL, "k6-233", "cold"), _timed(FILL, "k6-233", "warm")
    full = _timed(FILL, "k6-233{write_allocate.mode=full}", "cold")
    assert cold["per_iteration"]["l1d_store_misses"] > 0 and cold["cycles_per_iteration"] > full["cycles_per_iteration"]
    assert warm["cycles_per_iteration"] == full["cycles_per_iteration"]
    p5_cold, p5_warm = _timed(FILL, "pentium-mmx-233", "cold"), _timed(FILL, "pentium-mmx-233", "warm")
    assert p5_cold["per_iteration"].get("stall_write_buffer", 0) > 0
    assert p5_warm["per_iteration"].get("l1d_store_misses", 0) == 0
    assert p5_warm["per_iteration"].get("stall_write_buffer", 0) == 0
    assert p5_warm["cycles_per_iteration"] < p5_cold["cycles_per_iteration"]


@pytest.mark.parametrize("stride, spills", [(32, False), (256, True)])
def test_warm_data_fills_as_far_as_it_fits(tmp_path, stride, spills):
    # 200 reads, one line each: 6.4 KB fits the P5 MMX's 16 KB L1D; at a 256-byte stride they fall in
    # 16 of its 128 sets (4 ways: 64 lines), so 200 lines cannot all stay
    body = tmp_path / "read.s"
    body.write_text(f"top:\n  add eax, [esi]\n  add esi, {stride}\n  dec ecx\n  jnz top\n")
    warm = _timed(body, "pentium-mmx-233", "warm", iterations=200)
    assert (warm["per_iteration"].get("l1d_load_misses", 0) > 0) == spills


@pytest.mark.parametrize("cpu, data, said", [
    ("pentium-mmx-233", "cold", True), ("k6-233", "cold", True), ("pentium-mmx-233", "warm", False),
    ("k6-233{write_allocate.mode=full}", "cold", False), ("pentium2-233", "cold", False)])
def test_the_write_policy_line_appears_exactly_when_it_decides(cpu, data, said):
    out = CliRunner().invoke(main, ["loop", str(FILL), "--cpu", cpu, "--brief", "--data", data])
    assert out.exit_code == 0, out.output
    flat = " ".join(out.output.split())
    assert ("the write policy decides this result" in flat) == said
    assert f"data: {data}" in flat
    if said:  # how to make writes allocate: only where the family's L1 may (policies.toml full_allocation)
        assert ("--set write_allocate.mode=full makes write misses allocate (a K6 whose BIOS programs WHCR)" in flat
                ) == cpu.startswith("k6")


def test_a_read_loop_gets_no_write_policy_line():
    out = CliRunner().invoke(main, ["loop", str(FIXTURES / "sum-pentium-intel.s"), "--cpu", "pentium-mmx-233,k6-233",
                                    "--brief"])
    assert out.exit_code == 0 and "write policy decides" not in " ".join(out.output.split())


def test_cpus_show_the_write_allocation():
    doc = json.loads(CliRunner().invoke(main, ["cpus", "--json"]).output)["cpus"]
    assert doc["pentium-mmx-233"]["write_allocate"] == "none"
    assert doc["k6-233"]["write_allocate"] == "page+sector only"
    assert doc["k6-2-300"]["write_allocate"] == "full" and doc["pentium2-233"]["write_allocate"] == "full"
    text = " ".join(CliRunner().invoke(main, ["cpus"]).output.split())
    assert "page+sector only: k6-233" in text or "page+sector only" in text


def test_serve_takes_the_data_state():
    answer = serve.compute({"body": FILL.read_text(), "cpus": ["pentium-mmx-233"], "data": "warm"})
    assert answer["data"]["doc"]["data"] == "warm"
    assert "choose cold or warm" in serve.compute({"body": FILL.read_text(), "data": "hot"})["error"]
