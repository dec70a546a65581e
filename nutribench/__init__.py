"""nutribench: the NutriRL benchmark for reinforcement learning under delayed state transitions.

``import nutribench`` registers the Gymnasium ids ``nutribench/NutriRL-v0`` (with a
``regime=`` argument, default ``"run0"``) and one id per shipped regime,
``nutribench/NutriRL-run0-v0`` .. ``nutribench/NutriRL-run6-v0``; each has a natively
batched vector entry point for ``gymnasium.make_vec``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("nutribench")
except PackageNotFoundError:  # running from a source tree without installing
    __version__ = "0.0.0+unknown"

ENV_ID = "nutribench/NutriRL-v0"
SHIPPED_REGIMES = tuple(f"run{k}" for k in range(7))


def register_envs() -> None:
    """Register the environment ids with Gymnasium (idempotent)."""
    import gymnasium

    ids = [(ENV_ID, {})] + [(f"nutribench/NutriRL-{r}-v0", {"regime": r}) for r in SHIPPED_REGIMES]
    for env_id, kwargs in ids:
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="nutribench.env.nutri_env:NutriRLEnv",
            vector_entry_point="nutribench.env.vector_env:NutriRLVectorEnv",
            kwargs=kwargs,
            disable_env_checker=False,
        )


register_envs()
