"""Start-up: what one command costs before and around its depth, as a user runs it (a new process each time).

One 1024 x 768 capture through ``prismstereo depth`` (the default model, its range for the rig):

* ``--backend onnx``, first run: the model is built and its graphs exported into a fresh cache;
* ``--backend onnx``, the same command again: the cache's index remembers the flags, and the remembered graphs run
  through the torch-free pipeline (no torch imported);
* ``--backend torch``: the model built and run in torch.

Each is run ``--runs`` times (the first run once), with and without ``PYTHONDONTWRITEBYTECODE=1`` (a host that
forbids bytecode files compiles every imported module at every start unless the install compiled them); wall time
and peak resident memory of the process (``resource.getrusage``) are reported as the median and the worst. Timings
depend on what else the machine does: run it on an otherwise idle machine.

Run: .venv/bin/python benchmarks/startup.py [--runs N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "prismstereo.cli"]


def timed(args: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """(wall seconds, peak resident MB, stdout) of one command in a new process (the peak is the largest child of
    this process so far: :func:`isolated` runs each command from a process of its own)."""
    start = time.perf_counter()
    run = subprocess.run(CLI + args, env=env, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - start
    if run.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed:\n{run.stderr}")
    return seconds, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, run.stdout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5, help="runs of each repeated command")
    args = parser.parse_args()
    print(f"CPU: {_cpu()}, {os.cpu_count()} cores; Python {platform.python_version()}")
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        env = {**os.environ, "PRISMSTEREO_CACHE": str(work / "cache")}
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        subprocess.run(CLI + ["render", "--rig", "thesis_setup1", "--depth-mm", "600", "--out", str(work / "cap.png"),
                              "--supersample", "1"], env=env, check=True, capture_output=True)
        common = ["depth", str(work / "cap.png"), "--rig", "thesis_setup1"]
        print(f"{'command (1024 x 768 capture)':58s} {'bytecode':>9s} {'wall s':>14s} {'peak MB':>9s}")
        rows = [("depth --backend onnx, first run (export)", ["--backend", "onnx"], 1),
                ("depth --backend onnx, again (remembered, no torch)", ["--backend", "onnx"], args.runs),
                ("depth --backend torch", ["--backend", "torch"], args.runs)]
        for label, flags, runs in rows:
            for forbid in (False, True):
                if runs == 1 and forbid:
                    continue
                run_env = {**env, "PYTHONDONTWRITEBYTECODE": "1"} if forbid else env
                results = [isolated(common + flags + ["--out", str(work / f"d{k}.npy")], run_env)
                           for k in range(runs)]
                walls = [r[0] for r in results]
                peaks = [r[1] for r in results]
                spread = f"{statistics.median(walls):.2f} ({max(walls):.2f})" if runs > 1 else f"{walls[0]:.2f}"
                print(f"{label:58s} {'forbidden' if forbid else 'written':>9s} {spread:>14s} {max(peaks):9.0f}")
                if "again" in label and "(without torch)" not in results[0][2]:
                    raise SystemExit("the remembered request did not run without torch:\n" + results[0][2])
    print("wall: median (worst) of the runs; peak: the largest resident set of the runs")


def isolated(args: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """:func:`timed` run from a process of its own, so that the peak memory is this command's alone."""
    code = (f"import json, os, sys; sys.path.insert(0, {str(Path(__file__).parent)!r}); from startup import timed; "
            f"print(json.dumps(timed({args!r}, dict(os.environ))))")
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(run.stdout + run.stderr)
    seconds, peak, text = json.loads(run.stdout.strip().splitlines()[-1])
    return seconds, peak, text


def _cpu() -> str:
    """The CPU's model name (Linux), else the platform's."""
    try:
        return next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                    if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


if __name__ == "__main__":
    main()
