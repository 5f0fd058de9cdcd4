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

**Adapted sets.** ``uav-struct adapt b.ifc`` (:mod:`uav_struct_env.training.adapt`) fine-tunes the
default set on renders of one building and writes it to ``ROOT/<sha256 of b.ifc>/``, with ROOT
:func:`adapted_root` (``$UAV_STRUCT_ADAPTED_DIR``, else the user cache folder
``$XDG_CACHE_HOME/uav-struct/adapted``, ``~/.cache/uav-struct/adapted`` without it).
:func:`adapted_weights` finds that set for a building file, keyed by its content, so a renamed
or moved copy of the file finds it too and an edited one does not.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

__all__ = ["ADAPTED_DIR_ENV", "ADAPTED_PROVENANCE", "DEFAULT_WEIGHTS", "MODELS_DIR", "WEIGHT_ALIASES",
           "WEIGHT_NAMES", "WEIGHT_SETS", "WeightSet", "adapted_folder", "adapted_root", "adapted_set",
           "adapted_weights", "file_sha256", "weight_set"]

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


#: The environment variable that moves the folder of adapted sets (:func:`adapted_root`).
ADAPTED_DIR_ENV = "UAV_STRUCT_ADAPTED_DIR"
#: The file an adapted set's folder holds once the set is complete (settings, costs, hashes).
ADAPTED_PROVENANCE = "provenance.json"


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of the file at ``path``, as 64 hex digits."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def adapted_root() -> Path:
    """The folder of adapted sets: ``$UAV_STRUCT_ADAPTED_DIR``, else ``<user cache>/uav-struct/adapted``."""
    if os.environ.get(ADAPTED_DIR_ENV):
        return Path(os.environ[ADAPTED_DIR_ENV]).expanduser()
    cache = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(cache) / "uav-struct" / "adapted"


def adapted_folder(sha256: str, root: str | Path | None = None) -> Path:
    """The folder of the set adapted to the building file whose SHA-256 is ``sha256``."""
    return Path(adapted_root() if root is None else root) / sha256


def adapted_set(sha256: str, root: str | Path | None = None) -> WeightSet:
    """The set adapted to the building file whose SHA-256 is ``sha256`` (its files may not exist yet).

    Its name, ``adapted_<first 12 digits>``, begins its two file names, so a study's settings
    line (which names the files) says which building the weights were adapted to.
    """
    name = f"adapted_{sha256[:12]}"
    folder = adapted_folder(sha256, root)
    return WeightSet(name, folder / f"{name}.onnx", folder / f"{name}_refiner.onnx",
                     f"renders of the building file with SHA-256 {sha256} ({DEFAULT_WEIGHTS} fine-tuned)")


def adapted_weights(building: str | Path, root: str | Path | None = None) -> WeightSet | None:
    """The adapted set of the building file ``building`` (``uav-struct adapt``), or None if there is none.

    A set counts once its folder holds both networks and :data:`ADAPTED_PROVENANCE` (written
    last, so an interrupted adaptation leaves no set). ``root``: the folder of adapted sets
    (None: :func:`adapted_root`).
    """
    found = adapted_set(file_sha256(building), root)
    complete = (found.model.parent / ADAPTED_PROVENANCE).is_file()
    return found if complete and found.model.is_file() and found.refiner.is_file() else None
