"""acroboter: compiled crane dynamics, three inverse-dynamics controllers and a fixed-step plant."""

import os

# The matrices here are tiny (tens of rows): BLAS threads only add hand-off cost, and on a loaded
# 2-core machine a threaded 27x27 triangular solve took 1 ms instead of 13 us. Set before numpy
# loads OpenBLAS; a user's explicit setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
