"""The precompute's per-stage record: wall time and the stage's own peak resident memory."""

from __future__ import annotations

import time

import numpy as np

from lbshape.pipeline.precompute import _Stages, resident_mb


def test_stage_peak_memory_is_the_stages_own_peak():
    stages = _Stages(["small", "large", "after"], show=False)
    base = resident_mb()
    with stages.stage("small"):
        time.sleep(0.05)
    with stages.stage("large"):
        block = np.ones(300 * 2**20 // 8)  # 300 MB, touched
        time.sleep(0.1)
        del block
    with stages.stage("after"):
        time.sleep(0.05)
    assert set(stages.seconds) == set(stages.peak_mb) == {"small", "large", "after"}
    assert stages.seconds["large"] >= 0.1
    assert stages.peak_mb["large"] >= base + 250, stages.peak_mb
    # freed before the next stage: the next stage's peak does not inherit it
    assert stages.peak_mb["after"] < stages.peak_mb["large"] - 200, stages.peak_mb
    assert stages.peak_mb["small"] < base + 100, stages.peak_mb
