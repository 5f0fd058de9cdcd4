"""Stage 3, pose: PnP, Levenberg-Marquardt refinement, covariance.

- :mod:`~localization.pose.pnp` -- PnP candidates, selection, refinement (:func:`solve_pnp`);
- :mod:`~localization.pose.covariance` -- the prior's sigmas, a pose's covariance, Mahalanobis
  distances;
- :mod:`~localization.pose.lm` -- compiled Levenberg-Marquardt;
- :mod:`~localization.pose.batch` -- many poses at once;
- :mod:`~localization.pose.finish` -- the one-pass end of a localization (refine, check, covariance).
"""

from localization.pose.covariance import PriorSigmas, pose_covariance
from localization.pose.pnp import PnPResult, solve_pnp

__all__ = ["PnPResult", "PriorSigmas", "pose_covariance", "solve_pnp"]
