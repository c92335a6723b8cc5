"""The pipeline view: one self-contained HTML page per loop body (or explained kernel), and the page
`retrosim serve` answers with.

The page renders the models' own records, never timing of its own: the document `retrosim loop
--json` prints (per CPU: cycles per iteration, the explain rows, the timeline rows) plus, per CPU,
the family's words for them (:func:`view`: its stage names, what each stall cause means on that
family, which P5 pipe each timeline row ran in). The data travels as one JSON object; the page's
script builds every element from it with ``textContent``, so nothing from a loop body or a file
name is ever parsed as HTML. `serve` sends the same objects over HTTP, so the saved page and the
app draw with the same code.

No network: the styles and the script are inline, the page loads nothing. Served, the page keeps
its form in the URL's fragment (never sent to a server) and times a link's form when opened; an
error clears the results and shows every assembler message the answer carries. With a second
body (B) the answer also carries B's run and `loop A.s B.s`'s comparison: the A/B table goes above
A's panels, then B's.
"""

from __future__ import annotations

import html
import json
import re

from sim.cpus import families
from sim.reports import compare

# Most timeline rows and cycles one CPU's chart draws: beyond them the page says how many it left
# out (a browser stays responsive with a few thousand positioned elements per chart).
MAX_ROWS = 200
MAX_CYCLES = 400

# The letters of the text timeline (sim/reports/views.py: timeline_text) and what each marks.
_LEGEND_PART = re.compile(r"(?:^|,\s*|;\s*)([DR=EC\-]) ")


def stage_words(legend: str) -> list[list[str]]:
    """[[mark, what it means on this family], ...] from the family's timeline legend
    ("D decode, R rename, = wait in the reservation station, E execute, - done, C retire")."""
    marks = list(_LEGEND_PART.finditer(legend))
    out = []
    for m, nxt in zip(marks, marks[1:] + [None]):
        text = legend[m.end():nxt.start() if nxt else len(legend)]
        out.append([m.group(1), text.split(";")[0].strip().rstrip(",")])
    return out


def view(result) -> dict:
    """The family's words for one timed run (a :class:`sim.timing.kernel.TimingResult`): the stage
    names, the meaning of each stall cause, the unit and decoder names, the explain table's columns
    and tooltip lines, and per timeline row the lane the family's model puts it in (P5: the U or V
    pipe; others: the decoder). All of it from the family's view (sim/cpus/view.py: page_words)."""
    from sim.reports import views

    family = result.model.family
    legend = views.timeline_key(result)
    out = {"family": family, "family_name": families.family(family).display_name if family else "",
           "legend": legend, "stages": stage_words(legend)}
    out.update(views.family_view(result).page_words(views.timeline_rows(result), views.explain_rows(result)))
    return out


def loop_data(doc: dict, timings, body: str | None = None) -> dict:
    """What the page draws for `retrosim loop`: its --json document, the family words of each CPU,
    and the body's text (shown as text)."""
    return {"kind": "loop", "doc": doc, "views": [view(t.result) for t in timings], "body": body}


def explain_data(doc: dict, result) -> dict:
    """What the page draws for `retrosim explain` (one CPU, the last call): its --json document in
    the loop document's shape (one result; cycles of the call instead of cycles per iteration)."""
    s = doc["summary"]
    one = {"cpu": s["cpu"], "memory": s["memory"], "cycles": s["cycles"], "instructions_count": s["instructions"],
           "uops": s["uops"], "model_limits": s.get("model_limits"), "instructions": doc["instructions"],
           "timeline": doc["timeline"]}
    return {"kind": "explain", "doc": {"source": f"{s['source']}:{s['entry']}", "results": [one], "warnings": [],
                                       "not_timed": {}},
            "views": [view(result)], "body": None}


def _json_for_script(data) -> str:
    """JSON that can sit inside <script>: no '<', '>' or '&' (so no '</script>' or '<!--' from a body)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"))
    return text.replace("&", "\\u0026").replace("<", "\\u003c").replace(">", "\\u003e") \
        .replace("\u2028", "\\u2028").replace("\u2029", "\\u2029")


def page(data: dict | None, app: dict | None = None) -> str:
    """The whole page. `data`: what :func:`loop_data` or :func:`explain_data` give (None: nothing
    drawn yet). `app`: the form of `retrosim serve` ({"cpus": [...], "memories": [...],
    "defaults": [...]}), or None for a saved page."""
    title = "retrosim pipeline view"
    if data:
        title = f"{data['doc'].get('source', '')}: {title}"
    config = {"max_rows": MAX_ROWS, "max_cycles": MAX_CYCLES, "app": app, "ab_note": compare.AB_NOTE}
    return (_TEMPLATE.replace("%TITLE%", html.escape(title))
            .replace("%STYLE%", _STYLE)
            .replace("%DATA%", _json_for_script(data))
            .replace("%CONFIG%", _json_for_script(config))
            .replace("%SCRIPT%", _SCRIPT))


_TEMPLATE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; style-src 'unsafe-inline'; script-src 'unsafe-inline'; connect-src 'self'">
<title>%TITLE%</title>
<style>%STYLE%</style>
</head>
<body>
<header><h1 id="title">retrosim pipeline view</h1><p id="subtitle"></p></header>
<section id="form"></section>
<div id="error" role="alert" hidden></div>
<div id="status"></div>
<section id="compare"></section>
<section id="summary"></section>
<section id="cpus" class="cpugrid"></section>
<section id="summary-b"></section>
<section id="cpus-b" class="cpugrid"></section>
<div id="tip" hidden></div>
<script type="application/json" id="retrosim-data">%DATA%</script>
<script type="application/json" id="retrosim-config">%CONFIG%</script>
<script>%SCRIPT%</script>
</body>
</html>
"""

_STYLE = """
body{font:13px/1.35 system-ui,sans-serif;margin:12px;color:#222;background:#fafafa}
h1{font-size:18px;margin:0 0 4px} h2{font-size:15px;margin:4px 0} p{margin:2px 0}
table{border-collapse:collapse;margin:6px 0} td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}
th{background:#eee} td.num{text-align:right;font-variant-numeric:tabular-nums}
#error{background:#fdd;border:1px solid #c00;color:#800;padding:6px;margin:6px 0;font-family:monospace;white-space:pre-wrap}
#status{color:#555;margin:4px 0}
#form textarea{font-family:monospace;width:46em;max-width:calc(100vw - 60px);height:12em}
#form fieldset{display:inline-block;vertical-align:top;border:1px solid #ccc;margin:4px}
#form label{display:inline-block;margin-right:8px}
#share{margin-left:8px}
.cpugrid{display:grid;grid-template-columns:repeat(auto-fill,minmax(min(100%,1100px),1fr));gap:12px;align-items:start}
.cpu{background:#fff;border:1px solid #bbb;padding:6px;min-width:0;overflow:hidden}
.cpu .head{font-weight:bold} .cpu .cpi{font-size:16px}
.notes{color:#444;font-size:12px;max-width:60em}
.chart{position:relative;font-family:monospace;font-size:11px;margin-top:6px;overflow:auto;max-height:70vh;
border:1px solid #ddd}
.tablebox{overflow-x:auto}
.row{position:relative;display:flex;height:16px;white-space:nowrap}
.row:hover{background:#eef}
.lbl{position:sticky;left:0;z-index:1;flex:0 0 300px;width:300px;overflow:hidden;text-overflow:ellipsis;background:#fff}
.lane{display:inline-block;width:26px;color:#555}
.units{display:inline-block;width:62px;color:#357;overflow:hidden;vertical-align:bottom}
.cells{position:relative;flex:0 0 auto;height:16px}
.seg{position:absolute;top:2px;height:12px;font-size:10px;line-height:12px;text-align:center;color:#000}
.stall{position:absolute;top:1px;height:14px;line-height:14px;padding:0 4px;font-size:10px;color:#700;
background:#fee;border:1px solid #c66;border-radius:3px;white-space:nowrap}
td.stall-cell{color:#700}
.s-D{background:#9cf} .s-R{background:#ccc} .s-E{background:#6c6} .s-done{background:#dfd} .s-C{background:#fc6}
.s-wait{background:#eee}
.ruler{position:relative;height:14px;color:#777;font-size:10px}
.ruler span{position:absolute;top:0}
.legend span.key{display:inline-block;padding:0 4px;margin:1px 3px 1px 0;border:1px solid #999}
.more{color:#a00;font-size:12px}
#tip{position:fixed;z-index:10;background:#ffe;border:1px solid #886;padding:6px;max-width:42em;font-size:12px;
white-space:pre-wrap;pointer-events:none;box-shadow:2px 2px 6px #0003}
.c-decode{background:#f99} .c-window{background:#f6a} .c-partial{background:#c9f} .c-dependency{background:#fc9}
.c-port{background:#ff8} .c-memory{background:#9ee} .c-store_forward{background:#bdf} .c-mispredict{background:#f66}
.c-alone{background:#fb8}
"""

_SCRIPT = r"""
"use strict";
(function () {
  const CONFIG = JSON.parse(document.getElementById("retrosim-config").textContent);
  const W = 10;  // pixels per cycle
  const LBL = 302;  // the label column (sticky: it stays when the timeline scrolls sideways)
  const tip = document.getElementById("tip");
  function el(tag, attrs, text) {
    const e = document.createElement(tag);
    for (const k in (attrs || {})) e.setAttribute(k, attrs[k]);
    if (text !== undefined && text !== null) e.textContent = String(text);
    return e;
  }
  function fmt2(x) { return Number(x).toFixed(2); }
  function causeClass(c) {
    if (!c || c === "none") return "";
    if (c.startsWith("alone")) return "c-alone";
    return "c-" + c.replace(/[^a-z_]/g, "");
  }
  function hover(node, text) {
    node.addEventListener("mouseenter", () => { tip.textContent = text(); tip.hidden = false; });
    node.addEventListener("mousemove", (ev) => {
      tip.style.left = Math.min(ev.clientX + 14, window.innerWidth - 420) + "px";
      tip.style.top = (ev.clientY + 14) + "px";
    });
    node.addEventListener("mouseleave", () => { tip.hidden = true; });
  }
  function rowText(view, ins) {
    if (!ins) return "";
    const lines = [ins.instruction + "  (pc 0x" + ins.pc.toString(16) + ", " + ins.executions + " executions)"];
    const main = mainStall(view, ins);
    if (main) lines.push("main stall: " + main[0] + ", " + main[1] + " cycles per execution");
    // the family's lines: {field} of the explain row, {field|text} text when the field is empty;
    // a line with a `when` field only when that field is set
    for (const [tpl, when] of view.tip || []) {
      if (when && !ins[when]) continue;
      lines.push(tpl.replace(/\{(\w+)(?:\|([^}]*))?\}/g, (_, f, dflt) =>
        dflt !== undefined && (ins[f] === undefined || ins[f] === "") ? dflt : String(ins[f])));
    }
    const stalls = Object.keys(ins).filter(k => k.startsWith("stall_") && ins[k]).map(k => k.slice(6) + " " + ins[k]);
    if (stalls.length) lines.push("stall cycles per execution: " + stalls.join(", "));
    lines.push("table row: " + ins.row + (ins.estimated ? " (estimated)" : ""));
    lines.push("source: " + ins.source);
    return lines.join("\n");
  }
  // the biggest stall an instruction pays (its explain row's stall fields, in the family's words):
  // [words, cycles per execution], or null when it pays none
  function mainStall(view, ins) {
    let best = null;
    for (const [field, words] of view.stalls || []) {
      const c = ins ? Number(ins[field] || 0) : 0;
      if (c > 0 && (!best || c > best[1])) best = [words, c];
    }
    return best;
  }
  function chart(result, view) {
    const box = el("div", {"class": "chart"});
    const all = result.timeline || [];
    const rows = all.slice(0, CONFIG.max_rows);
    if (!rows.length) { box.appendChild(el("p", {}, "no timeline rows")); return box; }
    const base = Math.min(...rows.map(r => r.decode));
    const last = Math.max(...rows.map(r => r.retire));
    const span = Math.min(last - base + 1, CONFIG.max_cycles);
    const byPc = {};
    for (const ins of result.instructions || []) byPc[ins.pc] = ins;
    const ruler = el("div", {"class": "ruler"});
    ruler.appendChild(el("span", {"style": "left:0"}, "cycle 0 = " + base));
    for (let c = 0; c < span; c += 10) ruler.appendChild(el("span", {"style": "left:" + (LBL + c * W) + "px"}, c));
    ruler.style.width = (LBL + span * W + 160) + "px";
    box.appendChild(ruler);
    rows.forEach((r, i) => {
      const row = el("div", {"class": "row", "data-insn": r.insn, "data-cause": r.cause,
                             "style": "width:" + (LBL + span * W + 160) + "px"});
      const ins = byPc[r.pc];
      const lane = (view.lanes || [])[i] || "";
      const lbl = el("div", {"class": "lbl " + causeClass(r.cause)});
      lbl.appendChild(el("span", {"class": "lane"}, lane));
      // the units it ran on (P6 ports, K6 units), from its explain row: "p0:0.5 p1:0.5" -> "p0 p1"
      if (view.show_units) {
        const units = (ins && ins.ports) ? ins.ports.split(" ").map(u => u.split(":")[0]).join(" ") : "";
        lbl.appendChild(el("span", {"class": "units"}, units));
      }
      lbl.appendChild(document.createTextNode(r.instruction));
      row.appendChild(lbl);
      const cells = el("div", {"class": "cells", "style": "width:" + (span * W) + "px"});
      function seg(from, to, cls, mark) {
        const a = Math.max(from - base, 0), b = Math.min(to - base, span);
        if (b <= a) return;
        cells.appendChild(el("div", {"class": "seg " + cls, "style": "left:" + (a * W) + "px;width:" + ((b - a) * W - 1) + "px"}, mark));
      }
      // as the text timeline: D decode, R issue/rename, wait, E execute, done, C retire; the wait is
      // coloured by the row's stall cause (the tooltip says which wait it was)
      seg(r.decode + 1, r.alloc, "s-wait " + causeClass(r.cause), "");
      seg(r.alloc + 1, r.dispatch, "s-wait " + causeClass(r.cause), "");
      seg(r.dispatch, r.complete, "s-E", "E");
      seg(r.complete, r.retire, "s-done", "");
      if (r.decode < r.dispatch) seg(r.decode, r.decode + 1, "s-D", "D");
      if (r.alloc !== r.decode && r.alloc < r.dispatch) seg(r.alloc, r.alloc + 1, "s-R", "R");
      seg(r.retire, r.retire + 1, "s-C", "C");
      // the biggest stall this instruction pays, named beside its last cycle
      const main = mainStall(view, ins);
      if (main) {
        row.setAttribute("data-stall", main[0]);
        cells.appendChild(el("span", {"class": "stall", "style": "left:" + (Math.min(r.retire + 1 - base, span) * W + 4) + "px"},
                             main[0] + " " + main[1]));
      }
      row.appendChild(cells);
      const why = (view.causes.find(([c, _]) => c === r.cause) || [])[1];
      hover(row, () => [
        "#" + r.insn + "  " + r.instruction + (lane ? "  [" + lane + "]" : ""),
        "decode " + r.decode + ", issue " + r.alloc + ", execute " + r.dispatch + "-" + r.complete + ", retire " + r.retire +
          " (cycle " + (r.decode - base) + " to " + (r.retire - base) + " of the chart)",
        r.cause === "none" ? view.calm : "held back: " + r.cause + (why ? " - " + why : ""),
        "", rowText(view, ins)].join("\n"));
      box.appendChild(row);
    });
    const cut = [];
    if (all.length > rows.length) cut.push((all.length - rows.length) + " more rows not drawn");
    if (last - base + 1 > span) cut.push((last - base + 1 - span) + " more cycles not drawn");
    if (cut.length) box.appendChild(el("p", {"class": "more"}, cut.join("; ") + " (all of them: --json)"));
    return box;
  }
  function legend(view) {
    const p = el("div", {"class": "legend"});
    for (const [mark, what] of view.stages || []) {
      const cls = {"D": "s-D", "R": "s-R", "E": "s-E", "-": "s-done", "C": "s-C", "=": "s-wait"}[mark] || "";
      p.appendChild(el("span", {"class": "key " + cls}, mark + " " + what));
    }
    const causes = (view.causes || []).filter(([c, _]) => c !== "none");
    const cl = el("div", {"class": "legend"});
    cl.appendChild(el("span", {}, view.causes_heading));
    for (const [c, what] of causes) {
      const k = el("span", {"class": "key " + causeClass(c)}, c);
      hover(k, () => c + ": " + what);
      cl.appendChild(k);
    }
    const wrap = el("div");
    wrap.appendChild(p); wrap.appendChild(cl);
    return wrap;
  }
  function table(result, view) {
    const t = el("table", {"class": "explain"});
    const head = el("tr");
    const cols = view.columns || [];  // [heading, field of the explain row], the family's
    cols.forEach(([c, _]) => head.appendChild(el("th", {}, c)));
    if (view.stalls) head.appendChild(el("th", {}, view.stalls_heading));
    t.appendChild(head);
    for (const ins of result.instructions || []) {
      const tr = el("tr");
      const cells = cols.map(([_, f]) => ins[f]);
      cells.forEach(c => tr.appendChild(el("td", {}, c)));
      if (view.stalls) {
        const main = mainStall(view, ins);
        tr.appendChild(el("td", {"class": "stall-cell"}, main ? main[0] + " " + main[1] : ""));
      }
      hover(tr, () => rowText(view, ins));
      t.appendChild(tr);
    }
    const box = el("div", {"class": "tablebox"});
    box.appendChild(t);
    return box;
  }
  function headline(result) {
    return result.cycles_per_iteration !== undefined ? ["cycles per iteration", result.cycles_per_iteration]
                                                      : ["cycles (last call)", result.cycles];
  }
  // `loop A.s B.s`'s table (sim/reports/compare.py: loop_comparison), one per pair of regions
  function comparisonTables(box, comparison) {
    for (const c of comparison) {
      const t = el("table", {"class": "ab"});
      t.appendChild(el("caption", {}, "A/B, cycles per iteration: A = " + c.a + ", B = " + c.b));
      const hr = el("tr");
      ["cpu", "A", "B", "A/B", "faster", "differs most per iteration (A minus B)"].forEach(h => hr.appendChild(el("th", {}, h)));
      t.appendChild(hr);
      for (const e of c.per_cpu) {
        const tr = el("tr", {"data-cpu": e.cpu});
        const [ca, cb] = e.cycles_per_iteration;
        tr.appendChild(el("td", {}, e.cpu));
        tr.appendChild(el("td", {"class": "num"}, fmt2(ca)));
        tr.appendChild(el("td", {"class": "num"}, fmt2(cb)));
        tr.appendChild(el("td", {"class": "num ratio"}, e.ratio === null ? "inf" : Number(e.ratio).toFixed(3)));
        tr.appendChild(el("td", {"class": "faster"}, {"A": "A", "B": "B", "same": "neither"}[e.faster]));
        tr.appendChild(el("td", {}, e.differences.map(d => d.words + " " + (d.a_minus_b >= 0 ? "+" : "") + d.a_minus_b)
                                                 .join(", ") || "none"));
        t.appendChild(tr);
      }
      box.appendChild(t);
    }
    box.appendChild(el("p", {"class": "notes"}, CONFIG.ab_note));
  }
  // one run's summary and panels; B's (the second body, compared) under A's, its ids ending "-b"
  function draw(data, dataB, comparison) {
    const ab = document.getElementById("compare");
    ab.replaceChildren();
    drawRun(data, "", dataB ? "A: " : "");
    drawRun(dataB, "-b", "B: ");
    document.getElementById("subtitle").textContent = "";
    if (!data) return;
    document.getElementById("subtitle").textContent = data.doc.source + (data.kind === "loop" ?
      ": steady state, a few iterations from the middle of the measured pass" : ": the last call");
    if (comparison) comparisonTables(ab, comparison);
  }
  function drawRun(data, side, heading) {
    const sum = document.getElementById("summary" + side), cpus = document.getElementById("cpus" + side);
    sum.replaceChildren(); cpus.replaceChildren();
    if (!data) return;
    const doc = data.doc;
    if (heading) sum.appendChild(el("h2", {}, heading + doc.source));
    if (doc.placement) {  // the settings the run used (a link's, or the command line's), as the document says
      const pl = doc.placement;
      sum.appendChild(el("p", {"id": "settings" + side}, "caches at the measured pass: " + doc.data + " (--data " + doc.data +
        "); body at " + pl.address + " (--align " + pl.align + " --offset " + pl.offset + "); registers at the start: " +
        Object.entries(doc.registers || {}).map(([r, v]) => r + "=" + v).join(" ")));
    }
    for (const w of doc.warnings || []) sum.appendChild(el("p", {"class": "more"}, "warning: " + w));
    for (const [what, list] of Object.entries(doc.not_timed || {})) sum.appendChild(el("p", {"class": "more"},
      "not timed (no " + what + "): " + list.join(", ")));
    const t = el("table", {"id": "summary-table" + side});
    const hr = el("tr");
    ["cpu", "family", headline(doc.results[0] || {})[0], "IPC", "est. rows"].forEach(c => hr.appendChild(el("th", {}, c)));
    t.appendChild(hr);
    doc.results.forEach((r, k) => {
      const v = data.views[k];
      const tr = el("tr", {"data-cpu": r.cpu});
      const [_, cyc] = headline(r);
      const ipc = r.cycles_per_iteration !== undefined ? (r.cycles_per_iteration ? r.instructions_per_iteration / r.cycles_per_iteration : 0)
                                                      : (r.cycles ? r.instructions_count / r.cycles : 0);
      tr.appendChild(el("td", {}, r.cpu));
      tr.appendChild(el("td", {}, v.family_name));
      tr.appendChild(el("td", {"class": "num cycles", "data-value": cyc}, data.kind === "loop" ? fmt2(cyc) : cyc));
      tr.appendChild(el("td", {"class": "num"}, fmt2(ipc)));
      const lim = r.model_limits;
      tr.appendChild(el("td", {"class": "num"}, lim ? Math.round(100 * lim.estimated_share) + "%" : ""));
      t.appendChild(tr);
    });
    sum.appendChild(t);
    if (data.body) {
      const d = el("details");
      d.appendChild(el("summary", {}, "the body as given"));
      d.appendChild(el("pre", {"id": "body-text" + side}, data.body));
      sum.appendChild(d);
    }
    doc.results.forEach((r, k) => {
      const v = data.views[k];
      const box = el("div", {"class": "cpu", "data-cpu": r.cpu});
      const [what, cyc] = headline(r);
      box.appendChild(el("div", {"class": "head"}, r.cpu + " (" + v.family_name + ", " + r.memory + ")"));
      const line = el("div", {"class": "cpi"});
      line.appendChild(el("span", {"class": "cycles", "data-value": cyc}, data.kind === "loop" ? fmt2(cyc) : cyc));
      line.appendChild(document.createTextNode(" " + what));
      box.appendChild(line);
      box.appendChild(el("p", {"class": "notes"}, "timeline: " + v.legend));
      for (const n of v.notes || []) box.appendChild(el("p", {"class": "notes"}, n));
      box.appendChild(legend(v));
      box.appendChild(chart(r, v));
      box.appendChild(table(r, v));
      cpus.appendChild(box);
    });
  }
  function choice(id, pairs) {
    const sel = el("select", {"id": id});
    for (const [v, t] of pairs) sel.appendChild(el("option", {"value": v}, t));
    return sel;
  }
  function field(box, id, words, input) {
    box.appendChild(el("label", {"for": id}, words));
    box.appendChild(input); box.appendChild(el("br"));
  }
  function form(app) {
    const f = el("form", {"id": "loop-form"});
    const left = el("fieldset");
    left.appendChild(el("legend", {}, "loop body, or a whole gcc -S / clang -S output (Intel or AT&T)"));
    const ta = el("textarea", {"id": "body", "name": "body", "spellcheck": "false"});
    ta.value = app.example || "";
    left.appendChild(ta);
    // a second body: timed alike and compared with the first, as `retrosim loop A.s B.s` does
    left.appendChild(el("br"));
    left.appendChild(el("label", {"for": "body-b"}, "B, to compare (optional; as retrosim loop A.s B.s)"));
    left.appendChild(el("br"));
    left.appendChild(el("textarea", {"id": "body-b", "name": "body_b", "spellcheck": "false", "style": "height:6em"}));
    f.appendChild(left);
    const cpus = el("fieldset", {"id": "cpu-choice"});
    cpus.appendChild(el("legend", {}, "CPUs"));
    for (const c of app.cpus) {
      const lab = el("label");
      const box = el("input", {"type": "checkbox", "name": "cpu", "value": c});
      box.checked = (app.defaults || []).includes(c);
      lab.appendChild(box); lab.appendChild(document.createTextNode(c));
      cpus.appendChild(lab); cpus.appendChild(el("br"));
    }
    f.appendChild(cpus);
    const opts = el("fieldset");
    opts.appendChild(el("legend", {}, "options (as retrosim loop's)"));
    field(opts, "memory", "memory", choice("memory", [["", "(each CPU's default)"]].concat(app.memories.map(m => [m, m]))));
    field(opts, "syntax", "syntax", choice("syntax", [["", "detect"], ["intel", "Intel"], ["att", "AT&T"]]));
    field(opts, "data", "--data (caches at the measured pass)", choice("data", app.data.map(d => [d, d])));
    field(opts, "iterations", "iterations", el("input", {"id": "iterations", "type": "number", "value": "100", "min": "4",
                                                         "style": "width:6em"}));
    field(opts, "align", "--align (bytes)", choice("align", app.aligns.map(a => [String(a), String(a)])));
    field(opts, "offset", "--offset (bytes past it)", el("input", {"id": "offset", "type": "number", "value": "0", "min": "0",
                                                                "style": "width:6em"}));
    opts.appendChild(el("label", {"for": "regs"}, "--reg R=V, one a line"));
    opts.appendChild(el("br"));
    opts.appendChild(el("textarea", {"id": "regs", "style": "width:22em;height:3em"}));
    opts.appendChild(el("br"));
    opts.appendChild(el("label", {"for": "sets"}, "--set KEY=VALUE, one a line"));
    opts.appendChild(el("br"));
    opts.appendChild(el("textarea", {"id": "sets", "style": "width:22em;height:4em"}));
    opts.appendChild(el("br"));
    opts.appendChild(el("button", {"type": "submit", "id": "run"}, "time it"));
    opts.appendChild(el("a", {"id": "share", "href": "#"}, "link to this view"));
    f.appendChild(opts);
    f.addEventListener("submit", (ev) => { ev.preventDefault(); submit(); });
    document.getElementById("form").appendChild(f);
    document.getElementById("data").value = app.default_data;
    document.getElementById("align").value = String(app.default_align);
  }
  function lines(id) {
    return document.getElementById(id).value.split("\n").map(s => s.trim()).filter(s => s);
  }
  function request() {
    return {
      body: document.getElementById("body").value,
      body_b: document.getElementById("body-b").value.trim() ? document.getElementById("body-b").value : null,
      cpus: Array.from(document.querySelectorAll("input[name=cpu]:checked")).map(b => b.value),
      memory: document.getElementById("memory").value || null,
      syntax: document.getElementById("syntax").value || null,
      iterations: Number(document.getElementById("iterations").value || 100),
      sets: lines("sets"),
      regs: lines("regs"),
      align: Number(document.getElementById("align").value),
      offset: Number(document.getElementById("offset").value || 0),
      data: document.getElementById("data").value,
    };
  }
  // The form in the URL's fragment (after '#': a browser never sends it, so a body stays out of
  // every server log): one key per field, a list as repeated keys.
  const SCALARS = ["body", "body_b", "memory", "syntax", "iterations", "align", "offset", "data"];
  function toFragment(req) {
    const q = new URLSearchParams();
    for (const k of SCALARS) if (req[k] !== null && req[k] !== undefined) q.append(k, String(req[k]));
    for (const c of req.cpus) q.append("cpu", c);
    for (const v of req.sets) q.append("set", v);
    for (const v of req.regs) q.append("reg", v);
    return q.toString();
  }
  // A link's fields into the form (values only: a link is anyone's text); what this server cannot
  // show (a CPU or memory it does not have) is said, not dropped silently.
  function fromFragment(fragment) {
    const q = new URLSearchParams(fragment);
    const missing = [];
    if (q.has("body")) document.getElementById("body").value = q.get("body");
    document.getElementById("body-b").value = q.get("body_b") || "";  // a link without B times A alone
    for (const id of ["memory", "syntax", "data", "align"]) {
      if (!q.has(id)) continue;
      const sel = document.getElementById(id), v = q.get(id);
      if (Array.from(sel.options).some(o => o.value === v)) sel.value = v; else missing.push(id + " " + v);
    }
    for (const id of ["iterations", "offset"]) if (q.has(id)) document.getElementById(id).value = q.get(id);
    document.getElementById("sets").value = q.getAll("set").join("\n");
    document.getElementById("regs").value = q.getAll("reg").join("\n");
    if (q.has("cpu")) {
      const want = q.getAll("cpu");
      const boxes = Array.from(document.querySelectorAll("input[name=cpu]"));
      for (const b of boxes) b.checked = want.includes(b.value);
      for (const c of want) if (!boxes.some(b => b.value === c)) missing.push("cpu " + c);
    }
    return missing;
  }
  function showError(err, answer) {
    // the results drawn before are another body's: cleared, so nothing stale stays on screen
    draw(null);
    const msgs = answer.messages || [];
    err.textContent = answer.error + (msgs.length ? "\nevery assembler message:\n" + msgs.join("\n") : "");
    err.hidden = false;
  }
  async function submit(note) {
    const err = document.getElementById("error"), status = document.getElementById("status");
    const req = request();
    const link = "#" + toFragment(req);
    try {
      history.replaceState(null, "", link);
      document.getElementById("share").setAttribute("href", link);
    } catch (e) {  // a URL past what the browser keeps (Chromium: 2 MB): the view still runs, unlinked
      note = (note ? note + "; " : "") + "no link: the form is too long for a URL";
    }
    status.textContent = "timing...";
    document.body.setAttribute("data-state", "busy");
    const t0 = performance.now();
    try {
      const resp = await fetch("api/loop", {method: "POST", headers: {"Content-Type": "application/json"},
                                            body: JSON.stringify(req)});
      const answer = await resp.json();
      if (answer.error) {
        showError(err, answer);
        status.textContent = "HTTP " + resp.status;
      } else {
        err.hidden = true; err.textContent = "";
        draw(answer.data, answer.data_b, answer.comparison);
        status.textContent = "answered in " + Math.round(performance.now() - t0) + " ms (server: " + answer.ms + " ms)";
      }
    } catch (e) {
      showError(err, {"error": "retrosim: error: the server did not answer (" + e + ")"});
      status.textContent = "";
    }
    if (note) status.textContent += " (" + note + ")";
    document.body.setAttribute("data-state", "done");
  }
  function follow() {  // a link to a view: its form, timed at once
    const fragment = location.hash.slice(1);
    if (!fragment) return;
    const missing = fromFragment(fragment);
    submit(missing.length ? "the link names what this server does not have: " + missing.join(", ") : "");
  }
  draw(JSON.parse(document.getElementById("retrosim-data").textContent));
  if (CONFIG.app) form(CONFIG.app);
  document.body.setAttribute("data-state", "ready");
  if (CONFIG.app) {
    follow();
    window.addEventListener("hashchange", follow);  // a link pasted into this tab's address bar
  }
})();
"""
