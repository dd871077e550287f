"""Fuzzed scene files at length: the property test of ``tests/test_scene_fuzz.py`` in its "bench"
hypothesis profile (3000 random examples instead of CI's 300 derandomised ones), with hypothesis's
statistics (exit codes and mutation kinds seen) and the wall time.

    OPENBLAS_NUM_THREADS=1 python benchmarks/scene_fuzz.py

A failure prints the smallest scene hypothesis found and a ``@reproduce_failure`` blob to replay it.
"""
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TEST = "tests/test_scene_fuzz.py::test_a_mutated_scene_runs_or_is_refused_naming_file_and_field"


def main():
    """Run the bench profile; returns pytest's exit code."""
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             "--hypothesis-show-statistics", TEST],
                            cwd=ROOT, env=os.environ | {"HYPOTHESIS_PROFILE": "bench"})
    print(f"scene fuzz, bench profile: {time.perf_counter() - start:.0f} s wall, exit {result.returncode}")
    return result.returncode


if __name__ == "__main__":
    sys.exit(main())
