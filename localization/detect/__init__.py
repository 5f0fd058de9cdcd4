"""Stage 1, detection: anonymous landmark pixels from an image.

- :mod:`~localization.detect.interface` -- :class:`Detections` and the :class:`Detector` protocol;
- :mod:`~localization.detect.projection` -- the projection detector (truth + noise, an ablation);
- :mod:`~localization.detect.learned` -- the learned heatmap detector (ONNX, CPU);
- :mod:`~localization.detect.refiner` -- its patch classifier;
- :mod:`~localization.detect.weights` -- its named weight sets (``landmarks_v1``, ``active``);
- :mod:`~localization.detect.onnx_net` -- one ONNX network run on the CPU.
"""

from localization.detect.interface import Detections, Detector, check_image_size
from localization.detect.projection import ProjectionDetector
from localization.detect.weights import WEIGHT_NAMES, WeightSet, weight_set

__all__ = ["WEIGHT_NAMES", "Detections", "Detector", "ProjectionDetector", "WeightSet", "check_image_size",
           "weight_set"]
