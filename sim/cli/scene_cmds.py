"""Commands over scenes: report, check, texture-loops, sweep."""

from __future__ import annotations

from pathlib import Path

import click
from rich.table import Column, Table

from sim.errors import ArgumentError, RetrosimError
from sim.cli.app import (
    REPORTS_DIR, SCENES_DIR, bounded, console, cpu_choice, err_console, main, one_line, resolve_machine, say,
)


@main.command("texture-loops")
@click.option("--cpu", "cpus", multiple=True, callback=lambda c, p, v: [cpu_choice(c, p, x) for x in v],
              help="CPU preset (repeatable; default: every preset)")
@click.option("--out", default=None, type=click.Path(path_type=Path), help="Markdown file to write")
def texture_loops_cmd(cpus, out):
    """Cycles per pixel of the texture-mapping article's span loops on every preset (reports/texture-loops.md)."""
    from sim.studies import texture_loops as texture

    out = out or REPORTS_DIR / "texture-loops.md"
    texture.write_report(out, list(cpus) or None)  # also part of `retrosim report` and `check --reports`
    console.print(f"wrote {out}")



def _scene_paths(names) -> list[Path]:
    if not names:
        return sorted(SCENES_DIR.glob("*.toml"))
    paths = []
    for n in names:
        p = Path(n)
        p = p if p.suffix == ".toml" and p.exists() else SCENES_DIR / f"{n}.toml"
        if not p.exists():  # anything else that exists (a device, a pipe) is refused by load_scene
            known = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.toml")))
            raise ArgumentError(f"no scene '{n}' (shipped scenes: {known})")
        paths.append(p)
    return paths


def _scenes(names) -> list:
    from sim.scenes.registry import load_scene

    return [load_scene(p) for p in _scene_paths(names)]


def _run_scenes(scenes, cpus, on_result=None, jobs: int | None = None) -> tuple[list, list[str]]:
    """Run scenes (Scene objects, or paths loaded one by one) with a progress bar per scene (on
    stderr, so --json output stays clean), timing on `jobs` worker processes. With `on_result`, each
    result is handed over as soon as its scene finishes and a failing scene does not stop the others:
    returns (results, failures). Without it the first failure is raised.

    The bar counts machine runs (sim.scenes.progress): each timing of a variant on a machine and
    each robustness re-timing, as the workers report them; its total grows while the scene runs,
    as the nominal timings show which re-timings will run."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from sim.parallel import check_jobs
    from sim.scenes.progress import RunCount
    from sim.scenes.registry import load_scene, run_scene

    jobs = check_jobs(jobs)
    results, failures = [], []
    # on a terminal only: piped or redirected, the bars' final frames would be the only output
    shown = err_console.is_terminal
    # at least as wide as most descriptions, so that the bar does not shift as they change
    describe = TextColumn("{task.description}", markup=False, table_column=Column(min_width=66, no_wrap=True))
    with Progress(describe, BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=err_console,
                  transient=False, disable=not shown) as bar:
        for item in scenes:
            try:
                scene = load_scene(item) if isinstance(item, Path) else item
                task = bar.add_task(scene.name, total=None)

                def show(count, task=task, name=scene.name):
                    bar.update(task, completed=count.done, total=count.total,
                               description=f"{name}: {count.what}" if count.what else name)

                result = run_scene(scene, list(cpus) or None, RunCount(show) if shown else None, jobs=jobs)
                bar.update(task, description=f"{scene.name}: done")
                if result.pixels == 0:
                    bar.console.print(f"{scene.name}: the scene draws no pixels (degenerate, collinear, off-screen or "
                                      "sub-pixel triangles): every metric counts 0 covered pixels",
                                      markup=False, highlight=False, soft_wrap=True)
                if on_result is not None:
                    on_result(result)
            except RetrosimError as e:
                if on_result is None:
                    raise
                failures.append(one_line(str(e)))
                if item is not scenes[-1]:  # say it now when other scenes still run; the last line repeats it
                    bar.console.print(f"retrosim: error: {one_line(str(e))}", markup=False, highlight=False,
                                      soft_wrap=True)
                continue
            results.append(result)
    return results, failures


def _doing(message: str) -> None:
    """What runs now, as one dim line on a terminal (like the progress bars: nothing on a pipe)."""
    if err_console.is_terminal:
        err_console.print(message, style="dim", markup=False, highlight=False, soft_wrap=True)


PARTIAL_DIR = REPORTS_DIR.parent / "build" / "reports"


MAX_JOBS = 64  # forked workers each hold a timing model and their share of the results: beyond the
               # cores they only cost memory
_JOBS_OPTION = click.option("--jobs", "-j", type=int, default=None, callback=bounded(1, MAX_JOBS),
                            help=f"worker processes, 1 to {MAX_JOBS} (default: every core); results are the "
                                 "same for any N")


def _with_sets(chosen, cpus, sets) -> list[str]:
    """--cpu entries (or every scene's machines) with the --set overrides applied to each."""
    if not sets:
        return list(cpus)
    from sim.cpus.machine import MachineKey

    out = []
    for spec in (list(cpus) or [c for s in chosen for c in s.cpus]):
        key = MachineKey.parse(spec)
        machine = resolve_machine(key.label, sets)
        memory = machine.memory_named or key.memory
        out.append(f"{machine.label}:{memory}" if memory else machine.label)
    return list(dict.fromkeys(out))


@main.command("report")
@click.argument("scenes", nargs=-1)
@click.option("--cpu", "cpus", multiple=True, help="run on these presets instead of the scene's (preset[:memory]); "
              "without --out the reports then go to build/reports/, never over the committed ones")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="override a preset field of every CPU run, as in `time --set`; repeatable (like --cpu, "
                   "writes to build/reports/ without --out)")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="directory for the Markdown, HTML, JSON, CSV and PNG reports [default: reports/, or "
                   "build/reports/ for a run restricted with --cpu or changed with --set]")
@_JOBS_OPTION
def report_cmd(scenes, cpus, sets, out, jobs):
    """Run scenes (default: every shipped scene) and write their reports; print a summary."""
    from sim.output import check_output_dir
    from sim.scenes.registry import summary_tables, write_reports

    paths = _scene_paths(scenes)  # scenes and --set checked before any folder is made
    if sets:
        from sim.scenes.registry import load_scene

        paths = [load_scene(p) for p in paths]
        cpus = _with_sets(paths, cpus, sets)
    if out is None:
        # reports/ holds the committed reports, which CI compares with fresh ones: a run with other
        # CPUs would silently replace them with different content
        out = PARTIAL_DIR if cpus or sets else REPORTS_DIR
        if cpus or sets:
            say(f"--cpu/--set change the reports' content: writing to {out}/ (not over the committed reports in "
                f"{REPORTS_DIR}/; choose a directory with --out)")
            out.mkdir(parents=True, exist_ok=True)
    check_output_dir(out, "--out")  # before the work: a read-only or impossible folder fails at once

    def write(result):  # each scene's reports as soon as it finishes: a later failure keeps them
        say(f"wrote {', '.join(str(p) for p in write_reports(result, out))}")

    results, failures = _run_scenes(paths, cpus, on_result=write, jobs=jobs)
    if not scenes and not cpus and not sets and not failures:  # the default set also regenerates the conversion report
        _doing("conversion report: timing kernels/convert/loops.S ...")
        say(f"wrote {_write_conversion_report(out)}")
        _doing("texture-loops report: timing the texture article's span loops on every preset ...")
        say(f"wrote {_write_texture_report(out)}")
    for part in summary_tables(results):
        console.print(part, highlight=False)
    if len(paths) == 1 and failures:
        raise RetrosimError(failures[0])
    if failures:
        raise RetrosimError(f"{len(failures)} of {len(paths)} scene(s) failed, the others' reports are written: "
                            + "; ".join(failures))


def _write_texture_report(out: Path) -> Path:
    from sim.studies import texture_loops as texture

    return texture.write_report(Path(out) / "texture-loops.md")


def _write_conversion_report(out: Path) -> Path:
    from sim.studies import conversion

    return conversion.write_report(Path(out) / "conversion.md")


@main.command("check")
@click.argument("scenes", nargs=-1)
@click.option("--update", is_flag=True, help="re-record the baselines of the scenes run (say why in the commit)")
@click.option("--reports/--no-reports", "check_reports", default=False,
              help="also check that the committed Markdown/JSON/CSV reports are up to date")
@_JOBS_OPTION
def check_cmd(scenes, update, check_reports, jobs):
    """Re-run scenes and compare exact cycle counts with reports/baselines.json."""
    from sim.scenes import baseline
    from sim.scenes.registry import write_reports

    chosen = _scenes(scenes)
    baseline.load()  # a damaged baselines file fails before the work, not after it
    results, _ = _run_scenes(chosen, (), jobs=jobs)
    if update:
        baseline.save(baseline.update(baseline.load(), results))
        console.print(f"re-recorded {len(results)} scene(s) in {baseline.BASELINE_FILE}")
        return
    recorded = baseline.load()
    # a scene with no baselines at all (a new scene) is one line, not a row per counter of every case
    unrecorded = [r for r in results if r.scene.name not in recorded]
    drifts = baseline.compare(recorded, [r for r in results if r.scene.name in recorded])
    stale = []
    if check_reports:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            fresh = [p for r in results for p in write_reports(r, Path(tmp), formats=("md", "json", "csv"))]
            if not scenes:
                fresh.append(_write_conversion_report(Path(tmp)))
                fresh.append(_write_texture_report(Path(tmp)))
            for path in fresh:
                committed = REPORTS_DIR / path.name
                if not committed.is_file() or committed.read_bytes() != path.read_bytes():
                    stale.append(committed)
    if drifts:
        t = Table(title=f"{len(drifts)} counter(s) differ from reports/baselines.json")
        for col in ("scene", "case", "counter", "old", "new", "delta", "percent"):
            t.add_column(col, justify="right" if col in ("old", "new", "delta", "percent") else "left",
                         overflow="fold")  # a case's name in full (radix8/zbuffer@k6-2-300:sdram-pc100)
        for d in drifts:
            t.add_row(d.scene, d.case, d.counter, "-" if d.old is None else f"{d.old:,}",
                      "-" if d.new is None else f"{d.new:,}", "-" if d.delta is None else f"{d.delta:+,}",
                      "-" if d.percent is None else f"{d.percent:+.2f}%")
        console.print(t)
    for r in unrecorded:
        say(f"{r.scene.name}: no baselines recorded in {baseline.BASELINE_FILE} ({len(baseline.entries(r)):,} "
            f"case(s) run; record them with `retrosim check {r.scene.name} --update`)")
    for p in stale:
        say(f"stale report: {p} (regenerate with `retrosim report`)")
    if drifts or stale or unrecorded:
        raise SystemExit(1)
    console.print(f"{sum(len(baseline.entries(r)) for r in results)} case(s) in {len(results)} scene(s) "
                  "match the baselines" + (" and the committed reports" if check_reports else ""))


@main.command("sweep")
@click.argument("spec", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="output path without suffix (default: the spec's path without .toml); writes .parquet, "
                   ".csv, .md and a PNG per swept parameter")
@click.option("--scheduler", default="local", show_default=True,
              help="'local' (an embedded Dask LocalCluster on 127.0.0.1), 'serial' (this process), or the "
                   "address of a running Dask scheduler (tcp://HOST:PORT)")
@click.option("--retry-failed", is_flag=True, help="recompute points whose row in the output records an error")
@click.option("--max-points", type=click.IntRange(1, 10**9), default=None, metavar="N",
              help="run a sweep of more than 10,000 points (the default limit), up to N")
@_JOBS_OPTION
def sweep_cmd(spec, out, scheduler, retry_failed, max_points, jobs):
    """Run a design-space sweep (scenes or kernels x CPUs x memories x overrides) into one table."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from sim.parallel import check_jobs
    from sim.sweep import MAX_POINTS, check_scheduler, load_spec, output_lock, preflight, run_sweep

    check_scheduler(scheduler)
    parsed = load_spec(spec, max_points or MAX_POINTS)
    base = out or spec.with_suffix("")
    calls = sum(g["repeat"] * len(g["points"]) for g in parsed.groups if g["kind"] == "kernel")
    started = []

    def progress(n, total):
        if not started:  # once the output is locked and read: how much is left to run
            started.append(True)
            bar.console.print(f"{total:,} of {len(parsed.points):,} point(s) to run in {len(parsed.groups):,} "
                              "emulation group(s)" + (f" (the spec's kernel points time {calls:,} call(s))" if calls
                                                      else ""), markup=False, highlight=False, soft_wrap=True)
        bar.update(task, completed=n, total=total)

    jobs = check_jobs(jobs)
    with output_lock(base):  # held from the checks to the last write: a second sweep here is refused
        preflight(base, scheduler)  # bad output or scheduler: one line, before any progress display
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=err_console) as bar:
            task = bar.add_task(f"sweep {spec.name}", total=None)
            result = run_sweep(parsed, base, scheduler, jobs, retry_failed=retry_failed,
                               progress=progress, lock=False)
    for path in result.files:
        err_console.print(f"wrote {path}")
    changed = (f" ({result.changed} of them recomputed because their input files changed, or the table did not record them: the scene or kernel "
               "source, an include, a preset, or the model itself)") if result.changed else ""
    console.print(f"{len(result.rows)} point(s): {result.computed} computed now{changed}, "
                  f"{len(result.rows) - result.computed} from {base.with_suffix('.parquet')}, {result.failed} failed")
    if result.failed:  # the first few reasons here; every one is in the table's error column
        errors = [r for r in result.rows if r.get("error")]
        for r in errors[:3]:
            where = " ".join(x for x in (r["scene"] or r["kernel"], r["variant"], r["cpu"], r["memory"],
                                         *(f"{k[4:]}={v}" for k, v in r.items() if k.startswith("set.") and v)) if x)
            say(f"failed: {where}: {one_line(r['error'])}")
        raise RetrosimError(f"{result.failed} of {len(result.rows)} point(s) failed (the error column of "
                            f"{base.with_suffix('.csv')} says why; rerun them with --retry-failed)")
