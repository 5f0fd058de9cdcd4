"""Datasets rendered from the simulator (``python -m uav_struct_env.datasets --help``)."""

from uav_struct_env.datasets.landmarks import (
    CAMERAS,
    LANDMARK_TYPES,
    DatasetConfig,
    generate,
    load_labels,
    render_layout,
)

__all__ = ["CAMERAS", "LANDMARK_TYPES", "DatasetConfig", "generate", "load_labels", "render_layout"]
