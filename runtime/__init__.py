"""The onboard runtime: drivers and estimation wired together, the mission, Rerun, sensor logs, the CLI."""
import os

# Each robot runs its pipeline on threads of its own and a mission runs several robots in one process; BLAS
# thread pools on top of that oversubscribe the cores (a 70x430 descriptor product measured 2-10 ms instead of
# 0.05 ms on a loaded 2-core machine). One BLAS thread unless the user set otherwise; numpy reads these when it
# is first imported, which for `p3at` is after this package.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")
