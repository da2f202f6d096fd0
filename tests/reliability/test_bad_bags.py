"""Corrupt, truncated and incomplete bags given to the bag reader and the calibration tool.

The reader must raise ``BagError`` (one readable line) or return what the bag holds; the
installed ``calibrate`` executable must exit non-zero with exactly one line on stderr and no
traceback. The tool runs are started together (each costs an interpreter start-up).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from support.ros import executable

from es_msgs_py.bag import BagError, read_bag, write_array_bag

if TYPE_CHECKING:
    from .conftest import FaultCases

AREA = "bags given to the tools"


def _good_bag(path: Path, storage: str = "mcap") -> Path:
    steps = 400
    t = np.arange(steps) / 100.0
    V = np.broadcast_to(100.0 + 50.0 * np.sin(t)[:, None, None], (steps, 2, 2))
    write_array_bag(path, {
        "/dm/command": (t, V),
        "/dm/displacement": (t + 0.01, 1e-9 * V / 2),
        "/dm/temperature/raw": (t[::10], np.full((steps // 10, 4), 45.0)),
    }, storage)
    return path


def _storage_file(bag: Path) -> Path:
    return next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))


def _bad_bags(root: Path) -> dict[str, Path]:
    """Build every hostile input: name -> bag directory (or other path)."""
    bags: dict[str, Path] = {}
    bags["missing path"] = root / "does-not-exist"
    empty = root / "empty-dir"
    empty.mkdir()
    bags["empty directory"] = empty
    for storage in ("mcap", "sqlite3"):
        for cut in (0.5, 0.97):
            bag = _good_bag(root / f"truncated-{storage}-{cut}", storage)
            whole = _storage_file(bag).read_bytes()
            _storage_file(bag).write_bytes(whole[: int(len(whole) * cut)])
            bags[f"{storage} truncated to {cut:.0%}"] = bag
        bag = _good_bag(root / f"garbage-{storage}", storage)
        data = bytearray(_storage_file(bag).read_bytes())
        rng = np.random.default_rng(5)
        start = len(data) // 3
        data[start : start + 4096] = rng.integers(0, 256, 4096, dtype=np.uint8).tobytes()
        _storage_file(bag).write_bytes(bytes(data))
        bags[f"{storage} with 4 kB of garbage inside"] = bag
    bag = _good_bag(root / "no-metadata")
    (bag / "metadata.yaml").unlink()
    bags["metadata.yaml missing"] = bag
    bag = _good_bag(root / "bad-metadata")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    bags["metadata.yaml not YAML"] = bag
    bag = _good_bag(root / "empty-storage")
    _storage_file(bag).write_bytes(b"")
    bags["storage file empty"] = bag
    bag = root / "no-displacement"
    t = np.arange(100) / 100.0
    write_array_bag(bag, {"/dm/command": (t, np.full((100, 2, 2), 100.0)),
                          "/dm/temperature/raw": (t, np.full((100, 4), 45.0))})
    bags["no /dm/displacement (not measured data)"] = bag
    not_a_bag = root / "not-a-bag"
    not_a_bag.mkdir()
    shutil.copy(__file__, not_a_bag / "metadata.yaml")
    bags["python source as metadata.yaml"] = not_a_bag
    return bags


def test_bad_bags_give_one_line_and_non_zero_exit(tmp_path: Path, fault_cases: FaultCases) -> None:
    """The reader raises BagError or reads what is there; the tool fails with one line.

    A truncated bag or one without metadata.yaml may still be readable up to its last
    complete record (the reader recovers a killed recorder's bag); the tool then works on
    what it holds. Every input the reader refuses, and a bag that is not measured data, must
    make the tool exit non-zero with one line on stderr.
    """
    bags = _bad_bags(tmp_path)
    refused: list[str] = []
    for name, bag in bags.items():
        try:
            series = read_bag(bag)
            held = all(np.all(np.isfinite(s.values)) for s in series.values()
                       if s.values is not None)
            detail = f"read: {sum(len(s) for s in series.values())} messages"
        except BagError as err:
            text = str(err)
            held, detail = bool(text) and "\n" not in text, text
            refused.append(name)
        except Exception as err:  # anything but BagError is the failure being counted
            held, detail = False, f"{type(err).__name__}: {err}"
        fault_cases.expect(AREA, f"read_bag: {name}", held, detail)
    # The tool reads through the same reader: one refused input of each kind is enough
    # (each run costs an interpreter start-up with numpy, scipy and matplotlib).
    kinds = ("missing", "empty directory", "truncated", "garbage", "not YAML", "source")
    chosen = [next(n for n in refused if kind in n) for kind in kinds
              if any(kind in n for n in refused)]
    tool = executable("es_calibration", "calibrate")
    runs = {
        name: subprocess.Popen([str(tool), str(bags[name]), "-o", str(tmp_path / f"out-{i}")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i, name in enumerate([*chosen, "no /dm/displacement (not measured data)"])
    }
    for name, proc in runs.items():
        _, stderr = proc.communicate(timeout=120)
        lines = stderr.strip().splitlines()
        held = proc.returncode != 0 and len(lines) == 1 and "Traceback" not in stderr
        fault_cases.expect(AREA, f"calibrate: {name}", held,
                           f"exit {proc.returncode}, stderr {stderr.strip()[:300]!r}")
    fault_cases.assert_held()
