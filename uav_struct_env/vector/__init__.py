"""Vector envs: K wrapped envs (their own seeds and sites) stepped in one process, agents as slots.

from uav_struct_env.vector import SB3VecEnv, make_vector_env
vec = make_vector_env("state", num_envs=16, site="random")   # 64 slots, one per UAV
model = stable_baselines3.PPO("MultiInputPolicy", SB3VecEnv(vec))

:class:`ParallelVectorEnv` is the core (seeds, autoreset: its module docstring);
:class:`SB3VecEnv` presents it to Stable-Baselines3 and :class:`TorchRLVectorEnv` to TorchRL.
"""

from uav_struct_env.vector.core import FINAL_OBSERVATION, ParallelVectorEnv
from uav_struct_env.vector.make import make_vector_env

__all__ = ["FINAL_OBSERVATION", "ParallelVectorEnv", "SB3VecEnv", "TorchRLVectorEnv", "make_vector_env"]


def __getattr__(name: str):
    """The library adapters, imported on first use (SB3 and TorchRL are optional extras)."""
    if name == "SB3VecEnv":
        from uav_struct_env.vector.sb3 import SB3VecEnv

        return SB3VecEnv
    if name == "TorchRLVectorEnv":
        from uav_struct_env.vector.torchrl_env import TorchRLVectorEnv

        return TorchRLVectorEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
