"""Stage 2, association: anonymous detections + BIM landmarks + rough prior pose -> identities.

- :mod:`~localization.associate.paper` -- the paper's method (project with the prior, one linear
  assignment) and the :class:`Association` result;
- :mod:`~localization.associate.robust` -- the robust search,
  :class:`~localization.associate.robust.RobustSearch`, a method per step (hypotheses,
  re-association, scoring, gating, rivals, warm start);
- :mod:`~localization.associate.hypotheses` -- where the search starts: upright two-point poses,
  the layout vote, enumeration;
- :mod:`~localization.associate.ambiguity` -- rival hypotheses from the layout's symmetries;
- :mod:`~localization.associate.upright` -- the closed-form two-point pose with a known tilt;
- :mod:`~localization.associate.assign_kernels`, :mod:`~localization.associate.hypothesis_kernels`
  -- the compiled kernels of assignment and of the hypotheses.
"""

from localization.associate.paper import Association, assign, associate_paper, candidate_landmarks
from localization.associate.robust import associate_robust

__all__ = ["Association", "assign", "associate_paper", "associate_robust", "candidate_landmarks"]
