"""nao_skin: self-touch calibration of the artificial skin on the Nao (ROS 2)."""
import os

# The calibration's linear algebra is many small dense problems (a few hundred unknowns):
# BLAS worker threads cost more than they give there (measured: 2.2 s -> 1.7 s for the real
# recording). Only a default: set OPENBLAS_NUM_THREADS / OMP_NUM_THREADS to override; it
# applies when nao_skin is imported before numpy.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
