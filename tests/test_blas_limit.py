"""The test process runs the core as a compute job's process does: one BLAS thread in every
BLAS library loaded (numpy's and scipy's own), whatever the machine's core count."""

from __future__ import annotations

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_info


def test_every_blas_library_in_the_test_process_runs_one_thread():
    scipy.linalg.cho_factor(np.eye(4))   # both libraries are loaded and have been used
    blas = [pool for pool in threadpool_info() if pool["user_api"] == "blas"]
    assert len(blas) >= 1
    assert [pool["num_threads"] for pool in blas] == [1] * len(blas), blas
