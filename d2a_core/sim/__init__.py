"""The racing simulator: vehicle model, pybullet world, the `d2a/Race-v0` env, episode logs.

Importing this package registers `d2a/Race-v0` with gymnasium.
"""

import gymnasium as gym

ENV_ID = "d2a/Race-v0"

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="d2a_core.sim.race_env:RaceEnv")


def make_vector_env(num_envs: int, **env_kwargs) -> gym.vector.VectorEnv:
    """`num_envs` independent race envs stepping in this process (one pybullet client each)."""
    from d2a_core.sim.race_env import RaceEnv

    return gym.vector.SyncVectorEnv([lambda: RaceEnv(**env_kwargs) for _ in range(num_envs)])


__all__ = ["ENV_ID", "make_vector_env"]
