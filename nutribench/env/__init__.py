"""The NutriRL environment: kernels, single env, batched vector env, SB3 adapter, policies."""

from nutribench.env.nutri_env import NutriRLEnv, RegimeDynamics
from nutribench.env.vector_env import NutriRLVectorEnv

__all__ = ["NutriRLEnv", "NutriRLVectorEnv", "RegimeDynamics"]
