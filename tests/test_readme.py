"""The README as written: every command it shows runs, and every command and option in its command
table exists. New commands get one table row and, if they show an example, one code line: this test
picks both up."""

import re
import shlex
import subprocess
from pathlib import Path

import pytest
from click.testing import CliRunner

from sim import cli

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()

# Commands the test does not run, each with its reason. Matched against the command's last part.
SKIPPED = {
    ".venv/bin/retrosim report": "the main job (every scene, minutes): test_main_job_on_a_small_scene runs it "
                                 "on zbuffer-small",
    ".venv/bin/python -m pytest -q": "the test suite itself, which includes this test",
    ".venv/bin/retrosim bench --check": "the models' speed check, a measurement on a quiet machine (a timed test "
                                        "would flake under load); tests/test_speedcheck.py tests its comparison",
    ".venv/bin/retrosim bench --count": "the models' instruction count (valgrind, about 3 minutes): .ci/run runs "
                                        "it after the tests; tests/test_speedcount.py tests its parts",
}


def code_lines(markdown: str) -> list[str]:
    """Every line of the README's code blocks (indented by four spaces, or fenced with ```)."""
    out, fenced, previous_blank = [], False, True
    in_indented = False
    for line in markdown.splitlines():
        if line.startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            if line.strip():
                out.append(line.strip())
            continue
        if line.startswith("    ") and line.strip() and (previous_blank or in_indented):
            out.append(line.strip())
            in_indented = True
        elif line.strip():
            in_indented = False
        previous_blank = not line.strip()
    return out


COMMANDS = code_lines(README)


def test_the_readme_shows_commands():
    assert any(c.startswith("retrosim run-kernel") for c in COMMANDS)
    assert sum(1 for c in COMMANDS if c.split("&&")[-1].strip() in SKIPPED) == len(SKIPPED)


@pytest.mark.parametrize("command", COMMANDS)
def test_every_readme_command_runs(command, tmp_path, monkeypatch):
    last = command.split("&&")[-1].strip()
    if last in SKIPPED:
        pytest.skip(SKIPPED[last])
    if command.startswith("retrosim "):
        monkeypatch.chdir(ROOT)  # relative paths in the README are from the repository root
        argv = shlex.split(command)[1:]
        out = [a for a in argv if a.startswith("build/")]  # example output directories go to tmp_path
        argv = [str(tmp_path / a) if a in out else a for a in argv]
        monkeypatch.setattr(cli.scene_cmds, "PARTIAL_DIR", tmp_path / "partial")
        r = CliRunner().invoke(cli.main, argv, catch_exceptions=False)
        assert r.exit_code == 0, (command, r.output)
    else:
        r = subprocess.run(command, shell=True, cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, (command, r.stderr)
        assert r.stdout.strip(), command


def test_main_job_on_a_small_scene(tmp_path):
    """The main job's command with a small scene and a scratch directory: reports and the summary."""
    r = CliRunner().invoke(cli.main, ["report", "zbuffer-small", "--out", str(tmp_path)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert {p.suffix for p in tmp_path.iterdir()} >= {".md", ".png", ".json", ".csv"}
    assert "cycles per pixel" in r.output


TABLE_ROW = re.compile(r"^\| `retrosim (?P<cmd>[\w-]+)(?P<rest>[^`]*)` \|")


def table_rows() -> list[tuple[str, str]]:
    return [(m["cmd"], m["rest"]) for m in map(TABLE_ROW.match, README.splitlines()) if m]


def test_the_command_table_lists_real_commands_and_options():
    rows = table_rows()
    assert rows, "no command table"
    for cmd, rest in rows:
        assert cmd in cli.main.commands, f"README lists `retrosim {cmd}`, which does not exist"
        options = {o for p in cli.main.commands[cmd].params for o in getattr(p, "opts", [])}
        for option in re.findall(r"--[\w-]+", rest):
            assert option in options, f"README shows `retrosim {cmd} {option}`, which it does not take"
    listed = {cmd for cmd, _ in rows}
    missing = set(cli.main.commands) - listed
    assert not missing, f"commands missing from the README's table: {sorted(missing)}"


def test_example_entry_points_exist():
    """Every --entry in the README names an entry point its file declares (see kernels/README.md)."""
    from sim.guest import kernels

    for command in COMMANDS:
        argv = shlex.split(command)
        if "--entry" in argv:
            source = kernels.resolve(argv[2])
            assert argv[argv.index("--entry") + 1] in kernels.entry_points(source), command
