"""Per-stage memory in every run (issue 14, item 2): ``RunResult.memory`` / JSON ``memory``.

The polynomial example scene runs through :func:`stepnf.pipeline.run.run_scene`; every
stage it timed must carry the process's peak and current resident memory at the
stage's end, and the peaks, read along the stages in the order they ended, can
only grow (``ru_maxrss`` is a high-water mark).
"""
from __future__ import annotations

import json
import sys

import pytest

from stepnf.pipeline.run import run_scene
from stepnf.runtime.progress import Progress
from stepnf.scene.parse import load_scene
from helpers.paths import EXAMPLES, REPO

EXAMPLE = EXAMPLES / "polynomial.toml"

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/statm is Linux's")


@pytest.fixture(scope="module")
def doc() -> dict:
    return json.loads(run_scene(load_scene(EXAMPLE), write=False).to_json())


def test_every_timed_stage_has_its_memory(doc):
    stages = [k for k in doc["timings"] if k != "total"]
    assert len(stages) >= 3  # model, eigen, evaluators at least: the check below covers real stages
    assert set(doc["memory"]) == set(doc["timings"])  # "total" included: the run's end


def test_peaks_never_decrease_and_are_plausible(doc):
    peaks = [m["peak_rss_mb"] for m in doc["memory"].values()]
    assert all(later >= earlier for earlier, later in zip(peaks, peaks[1:])), peaks
    # a Python process with numpy and scipy loaded holds tens of MiB, far below 100 GiB
    assert all(10.0 < p < 100_000.0 for p in peaks), peaks
    for m in doc["memory"].values():
        assert 10.0 < m["rss_mb"] <= m["peak_rss_mb"]


def test_memory_now_is_in_mib_and_sees_an_allocation():
    """In a fresh interpreter: once MPI is initialised in a process (mpi4py, which dolfinx imports), Open
    MPI's memory hooks keep large blocks on the heap, so a freed block need not leave the RSS."""
    import subprocess

    code = (
        "import json, numpy as np\n"
        "from stepnf.runtime.progress import memory_now\n"
        "before = memory_now()\n"
        "block = np.ones(64 * 2**20 // 8)\n"  # 64 MiB, touched
        "after = memory_now()\n"
        "print(json.dumps([before, after]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=REPO)
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    # the current RSS grows by the block (to 8 MiB: the interpreter's own allocations between the readings)
    assert after["rss_mb"] - before["rss_mb"] == pytest.approx(64.0, abs=8.0)
    assert after["peak_rss_mb"] >= after["rss_mb"] >= 64.0


def test_a_repeated_stage_moves_to_its_last_end():
    p = Progress(enabled=False)
    for key in ("a", "b", "a"):
        with p.stage(key, key):
            pass
    assert list(p.memory) == ["b", "a"] and list(p.timings) == ["a", "b"]
