"""Named weights of the learned detector: a name resolves to a keypoint network and a patch refiner.

The learned detector (:mod:`localization.detect.learned`) runs two networks, and a set of weights is
a pair of ONNX files in ``localization/detect/models/`` that were trained and evaluated together:

=======================  ============================  =====================================
name                     keypoint network              patch refiner
=======================  ============================  =====================================
``landmarks_v1``         ``landmarks_v1.onnx``         ``landmarks_v1_refiner.onnx``
``landmarks_active_v4``  ``landmarks_active_v2.onnx``  ``landmarks_active_v4_refiner.onnx``
=======================  ============================  =====================================

``landmarks_v1`` (the default, :data:`DEFAULT_WEIGHTS`) was trained on bare sites through an
ideal pinhole; ``landmarks_active_v4`` on active sites (workers, equipment, materials,
scaffolding) through the Mavic 2 Pro camera with its sensor imaging, and keeps the first set's
architectures and operating points. Alias ``active`` (:data:`WEIGHT_ALIASES`) names the
recommended active-site set, so a caller keeps it when a newer active set replaces it. Training
commands, data and figures of each: ``localization/detect/models/MODEL_CARD.md``.

    from localization.detect.weights import weight_set
    weight_set("active").refiner   # .../models/landmarks_active_v4_refiner.onnx
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["DEFAULT_WEIGHTS", "MODELS_DIR", "WEIGHT_ALIASES", "WEIGHT_NAMES", "WEIGHT_SETS", "WeightSet",
           "weight_set"]

#: The folder of the committed ONNX files and their model card.
MODELS_DIR = Path(__file__).with_name("models")


@dataclass(frozen=True)
class WeightSet:
    """One named set of the learned detector's weights.

    Attributes:
        name: the set's name (the model card's section title).
        model: the keypoint network's ONNX file.
        refiner: the patch refiner's ONNX file.
        trained_for: the images it was trained on, in a few words.
    """

    name: str
    model: Path
    refiner: Path
    trained_for: str


#: Every committed set, by name.
WEIGHT_SETS: dict[str, WeightSet] = {
    s.name: s
    for s in (
        WeightSet("landmarks_v1", MODELS_DIR / "landmarks_v1.onnx", MODELS_DIR / "landmarks_v1_refiner.onnx",
                  "bare sites through an ideal pinhole"),
        WeightSet("landmarks_active_v4", MODELS_DIR / "landmarks_active_v2.onnx",
                  MODELS_DIR / "landmarks_active_v4_refiner.onnx",
                  "active sites through the Mavic 2 Pro camera and its sensor imaging"),
    )
}

#: Other names of a set: ``active`` is the recommended active-site set.
WEIGHT_ALIASES: dict[str, str] = {"active": "landmarks_active_v4"}

#: The set a learned detector runs unless told otherwise.
DEFAULT_WEIGHTS = "landmarks_v1"

#: Every name :func:`weight_set` accepts: the sets', then the aliases.
WEIGHT_NAMES: tuple[str, ...] = (*WEIGHT_SETS, *WEIGHT_ALIASES)


def weight_set(name: str | None = None) -> WeightSet:
    """The set called ``name`` (a key of :data:`WEIGHT_SETS` or :data:`WEIGHT_ALIASES`; None: the default).

    Raises:
        ValueError: for an unknown name, listing the known ones.
    """
    if name is None:
        name = DEFAULT_WEIGHTS
    if not isinstance(name, str) or name not in WEIGHT_NAMES:
        raise ValueError(f"weights must be one of {WEIGHT_NAMES}, got {name!r}")
    return WEIGHT_SETS[WEIGHT_ALIASES.get(name, name)]
