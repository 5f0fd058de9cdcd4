"""uav-struct-env: multi-UAV camera localization from BIM structural landmarks."""

__version__ = "0.1.0"


def parallel_env(*args, **config):
    """The four-UAV PettingZoo parallel environment (see :mod:`uav_struct_env.envs`)."""
    from uav_struct_env.envs import parallel_env as _parallel_env

    return _parallel_env(*args, **config)


def env(*args, **config):
    """The AEC form of :func:`parallel_env` (through ``pettingzoo``'s ``parallel_to_aec``)."""
    from uav_struct_env.envs import env as _env

    return _env(*args, **config)


def _register() -> None:
    import gymnasium

    if "uav_struct_env/UavStruct-v0" not in gymnasium.registry:
        gymnasium.register(
            id="uav_struct_env/UavStruct-v0",
            entry_point="uav_struct_env.envs.gym_adapter:make_single",
        )


_register()
