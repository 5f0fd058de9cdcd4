"""uav-struct-env: multi-UAV camera localization from BIM structural landmarks."""

__version__ = "0.1.0"
