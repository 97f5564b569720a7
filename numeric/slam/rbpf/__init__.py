"""Rao-Blackwellized particle-filter SLAM with intensity (Hara et al. §7, eqs. 6-9), with
the improved proposal of Grisetti, Stachniss & Burgard (IEEE T-RO 2007, GMapping).

One module per step:

- :mod:`~chizu.numeric.slam.rbpf.filter`: the paper's filter, predict (eq. 7) → weigh
  (eqs. 8-9) → resample → update the maps (§7.3), and the trajectory of the particle
  with the highest accumulated likelihood (§7.4);
- :mod:`~chizu.numeric.slam.rbpf.improved` and :mod:`~chizu.numeric.slam.rbpf.proposal`: Grisetti
  et al.'s improved proposal (§IV: scan matching, sampling around the mode, the
  Gaussian fit of eqs. 14-16, the weight η);
- :mod:`~chizu.numeric.slam.rbpf.loop_start`: the loop-aware start, a loop the matcher's basin
  cannot reach closed by moving every particle's start;
- :mod:`~chizu.numeric.slam.rbpf.relocalisation`: a return from a long loop found by branch
  and bound in the whole old map (Hess et al. 2016, §V);
- :mod:`~chizu.numeric.slam.rbpf.odometry`: the motion model's heading sigma learned from
  the log;
- :mod:`~chizu.numeric.slam.rbpf.config`: the parameters, one nested model per step.

The end of a run refines the best particle's trajectory by the global scan alignment
both estimators share (:mod:`chizu.numeric.slam.alignment`).
"""

from chizu.numeric.slam.rbpf.config import (
    ImprovedConfig,
    LoopStartConfig,
    MotionNoise,
    OdometryCalibrationConfig,
    Proposal,
    RbpfConfig,
    RelocalisationConfig,
    Resample,
)
from chizu.numeric.slam.rbpf.filter import RbpfSlam, RbpfStep, systematic_resample

__all__ = ["ImprovedConfig", "LoopStartConfig", "MotionNoise", "OdometryCalibrationConfig",
           "Proposal", "RbpfConfig", "RbpfSlam", "RbpfStep", "RelocalisationConfig",
           "Resample", "systematic_resample"]
