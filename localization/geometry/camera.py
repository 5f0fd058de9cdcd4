"""The paper's camera: the project's one default camera model (1280 x 720, fx = fy = 1108.5 px).

Pure data, below every layer that needs a default camera (the simulator's camera, the env's
config, the study, the datasets).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PAPER_IMAGE_SIZE", "PAPER_K"]


#: The paper's camera: 1280x720, fx = fy = 1108.5, cx = 640, cy = 360.
PAPER_K = np.array([[1108.5, 0.0, 640.0], [0.0, 1108.5, 360.0], [0.0, 0.0, 1.0]])


PAPER_IMAGE_SIZE = (1280, 720)
