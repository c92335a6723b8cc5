"""The `retrosim` command line: the group and shared helpers live in app.py, the commands in one
module per kind (kernel_cmds: one kernel or loop body; scene_cmds: scenes and sweeps; model_cmds:
the models' own reports). Importing the package registers every command on `main`."""

from sim.cli import kernel_cmds, model_cmds, scene_cmds, serve  # noqa: F401  (registers the commands)
from sim.cli.app import REPORTS_DIR, SCENES_DIR, main, one_line, parse_args, print_error, say  # noqa: F401

__all__ = ["main", "parse_args", "one_line", "print_error", "say", "REPORTS_DIR", "SCENES_DIR"]
