"""The paper's four-UAV study in one command: ``uav-struct study`` / ``python -m uav_struct_env.study``."""

from uav_struct_env.study.protocol import METHODS, Method, PaperFigures, Scene, StudyConfig
from uav_struct_env.study.study import main, run_study

__all__ = ["METHODS", "Method", "PaperFigures", "Scene", "StudyConfig", "main", "run_study"]
