"""The precompute's per-stage record: wall time and the stage's own peak resident memory.

The check runs in a fresh interpreter: a process in which MPI was initialised (other
tests) may keep freed pages mapped (MPI memory hooks), which would hide the drop of
resident memory between stages that the test is about.
"""

from __future__ import annotations

import json
import subprocess
import sys

_PROBE = r"""
import json, time
import numpy as np
from lbshape.pipeline.stages import StageRecorder, resident_mb
stages = StageRecorder(["small", "large", "after"], show=False)
base = resident_mb()
with stages.stage("small"):
    time.sleep(0.05)
with stages.stage("large"):
    block = np.ones(300 * 2**20 // 8)  # 300 MB, touched
    time.sleep(0.1)
    del block
with stages.stage("after"):
    time.sleep(0.05)
print(json.dumps({"base": base, "seconds": stages.seconds, "peak_mb": stages.peak_mb}))
"""


def test_stage_peak_memory_is_the_stages_own_peak():
    out = subprocess.run([sys.executable, "-c", _PROBE], check=True, capture_output=True,
                         text=True).stdout
    record = json.loads(out.strip().splitlines()[-1])
    base, seconds, peak = record["base"], record["seconds"], record["peak_mb"]
    assert set(seconds) == set(peak) == {"small", "large", "after"}
    assert seconds["large"] >= 0.1
    assert peak["large"] >= base + 250, peak
    # freed before the next stage: the next stage's peak does not inherit it
    assert peak["after"] < peak["large"] - 200, peak
    assert peak["small"] < base + 100, peak
