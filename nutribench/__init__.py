"""nutribench: the NutriRL benchmark for reinforcement learning under delayed state transitions.

``import nutribench`` registers the Gymnasium ids ``nutribench/NutriRL-v0`` (with a
``regime=`` argument, default ``"run0"``) and one id per shipped regime,
``nutribench/NutriRL-run0-v0`` .. ``nutribench/NutriRL-run6-v0``; each has a natively
batched vector entry point for ``gymnasium.make_vec``. ``regime=`` takes any regime in the
regimes folder (``nutribench regimes generate NAME --from run6 ... --write`` adds one) or a
path to a regime file.

Every spec has ``max_episode_steps = HORIZON`` (50, the day of ``regimes/reward.toml``), so
``gymnasium.make`` adds a ``TimeLimit`` and time-aware wrappers work
(``gymnasium.wrappers.TimeAwareObservation(gymnasium.make(ENV_ID, regime="run6"))``). The
environment truncates each day at its regime's horizon itself; the ``TimeLimit`` truncates
at the same step (or earlier, with a smaller ``max_episode_steps``), never a second time.

The ids are registered as gymnasium is imported (at once when it already is): ``import
nutribench`` itself imports neither gymnasium nor numpy.
"""

import sys

ENV_ID = "nutribench/NutriRL-v0"
SHIPPED_REGIMES = tuple(f"run{k}" for k in range(7))
#: Steps in a day: the ``horizon`` of ``regimes/reward.toml``, shared by every regime.
HORIZON = 50


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
            vector_entry_point="nutribench.env.vector_env:make_vector_env",
            kwargs=kwargs,
            max_episode_steps=HORIZON,
            disable_env_checker=False,
        )


class _RegisterWithGymnasium:
    """A finder on ``sys.meta_path`` that answers for ``gymnasium`` alone, once: it finds the
    real module (the other finders) and registers the ids right after that module has run, then
    leaves ``sys.meta_path``. So ``import nutribench`` registers the ids whichever of the two
    is imported first, without importing gymnasium (and numpy) itself: the command line, which
    imports this package, pays for them only in the commands that make an environment."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> object:
        if name != "gymnasium":
            return None
        import importlib.util

        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
            run = spec.loader.exec_module

            def exec_module(module: object) -> None:
                run(module)
                register_envs()

            spec.loader.exec_module = exec_module  # this spec's loader only: gymnasium's
        return spec


if "gymnasium" in sys.modules:
    register_envs()
elif not any(isinstance(f, _RegisterWithGymnasium) for f in sys.meta_path):
    sys.meta_path.insert(0, _RegisterWithGymnasium())


def __getattr__(name: str):
    """``nutribench.__version__`` and ``nutribench.Recorder``, read or imported on first use
    (``import nutribench`` stays light: importlib.metadata is a twentieth of a command's start-up)."""
    if name == "__version__":  # the installed distribution's (``0.0.0+unknown`` in a source tree not installed)
        from nutribench.provenance import dist_version

        value = globals()["__version__"] = dist_version("nutribench") or "0.0.0+unknown"
        return value
    if name == "Recorder":
        from nutribench.recorder import Recorder

        return Recorder
    raise AttributeError(f"module 'nutribench' has no attribute {name!r}")
