"""Benchmarks reported as ratios against a baseline measured in the same run.

Shared machines are noisy, so every figure is printed next to its baseline: the ray-casting
wrapper against the bare backend call on the same rays (``raycast``), the orthophoto against
the bare cast of its rays (``ortho``), the line-scan orthophoto against a frame camera's on
the same grid (``linescan``), the MVP fit against bare ``cv2.remap`` of as many
bilinear samples (``mvp``), and orthomvp against Orthority on the same frame (``peer``).
``workload``: the synthetic DEM, rays and camera; ``timing``; ``formatting``: text reports.
"""

from orthomvp.bench.formatting import (
    format_linescan,
    format_mvp,
    format_ortho,
    format_orthority,
    format_raycast,
)
from orthomvp.bench.linescan import bench_linescan
from orthomvp.bench.mvp import bench_mvp
from orthomvp.bench.ortho import bench_ortho
from orthomvp.bench.peer import (
    RUN_STEPS,
    PeerCase,
    bench_orthority,
    horizontal_dem,
    import_orthority,
    ngi_case,
    run_orthority,
    synthetic_case,
)
from orthomvp.bench.raycast import bench_raycast

__all__ = [
    "RUN_STEPS",
    "PeerCase",
    "bench_linescan",
    "bench_mvp",
    "bench_ortho",
    "bench_orthority",
    "bench_raycast",
    "format_linescan",
    "format_mvp",
    "format_ortho",
    "format_orthority",
    "format_raycast",
    "horizontal_dem",
    "import_orthority",
    "ngi_case",
    "run_orthority",
    "synthetic_case",
]
