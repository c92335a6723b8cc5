"""Regression baselines: exact cycle counts (and the main counters) per scene, variant and preset.

A changed count is either a deliberate model change (re-record with `retrosim check --update` in
the same commit, and say why) or a bug. Counts are integers, so comparison is exact.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from sim.errors import RetrosimError
from sim.inputfile import read_bounded
from sim.reports.render import atomic_write
from sim.scenes.kind import BASELINE_COUNTERS as COUNTERS
from sim.scenes.registry import baseline_entries

BASELINE_FILE = Path(__file__).resolve().parents[2] / "reports" / "baselines.json"


class BaselineError(RetrosimError):
    """reports/baselines.json is unreadable or has the wrong shape."""


@dataclass(frozen=True)
class Drift:
    scene: str
    case: str       # "variant@cpu:memory"
    counter: str
    old: int | None  # None: the case is new
    new: int | None  # None: the case disappeared

    @property
    def delta(self) -> int | None:
        return None if self.old is None or self.new is None else self.new - self.old

    @property
    def percent(self) -> float | None:
        return None if not self.old or self.new is None else 100.0 * (self.new - self.old) / self.old


def entries(result) -> dict[str, dict[str, int]]:
    """The cases of a result of any kind (its kind's baseline_entries)."""
    return baseline_entries(result)


MAX_BASELINE_BYTES = 16 << 20  # the committed file has ~60 KB; a thousand scenes would fit


def load(path: Path | None = None) -> dict:
    """The recorded baselines ({} when there is no file); a damaged file is one clear error."""
    path = Path(path) if path is not None else BASELINE_FILE
    if not os.path.lexists(path):
        return {}
    restore = "restore it from git (git checkout -- reports/baselines.json)"
    try:
        text = read_bounded(path, MAX_BASELINE_BYTES, "baselines file", BaselineError).decode("utf-8")
        data = json.loads(text)
    except OSError as e:
        raise BaselineError(f"{path}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise BaselineError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start}); {restore}") from None
    except json.JSONDecodeError as e:
        raise BaselineError(f"{path}:{e.lineno}: not valid JSON ({e.msg}); {restore}") from None
    except RecursionError:
        raise BaselineError(f"{path}: nested too deeply to be baselines (scene, case, counter); {restore}") from None
    except ValueError as e:  # an integer of more than 4300 digits
        raise BaselineError(f"{path}: not valid baselines ({e}); {restore}") from None
    # expected shape: {scene: {case: {counter: int}}}
    if not isinstance(data, dict):
        raise BaselineError(f"{path}: expected a JSON object of scenes, got {type(data).__name__}")
    for scene, cases in data.items():
        if not isinstance(cases, dict):
            raise BaselineError(f"{path}: {scene}: expected an object of cases, got {type(cases).__name__}")
        for case, counters in cases.items():
            if not isinstance(counters, dict) or not all(
                    isinstance(v, int) and not isinstance(v, bool) for v in counters.values()):
                raise BaselineError(f"{path}: {scene}.{case}: expected an object of integer counters")
    return data


def save(data: dict, path: Path | None = None) -> None:
    path = Path(path) if path is not None else BASELINE_FILE
    atomic_write(path, (json.dumps(data, indent=1, sort_keys=True) + "\n").encode())


def compare(baseline: dict, results: list) -> list[Drift]:
    drifts = []
    for r in results:
        old_scene = baseline.get(r.scene.name, {})
        new_scene = entries(r)
        for case in sorted(set(old_scene) | set(new_scene)):
            old, new = old_scene.get(case), new_scene.get(case)
            for c in COUNTERS:
                o = None if old is None else old.get(c)
                n = None if new is None else new.get(c)
                if o != n:
                    drifts.append(Drift(r.scene.name, case, c, o, n))
    return drifts


def update(baseline: dict, results: list) -> dict:
    out = dict(baseline)
    for r in results:
        out[r.scene.name] = entries(r)
    return out
