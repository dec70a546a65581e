"""The built-in algorithms, one module each: a new built-in is one new file here.

Each module holds everything of its algorithm: its config model (pydantic, built from the
shared field types of :mod:`nutribench.agents.config`), its arguments function (the SB3
class and its constructor arguments, what :func:`nutribench.agents.algos.build_model`
builds), its SB3 model class where it is small (the big policies live in
:mod:`nutribench.agents.sac` and :mod:`nutribench.agents.gru_ppo`), and its registry entry
``ALGORITHM`` (a :class:`nutribench.agents.registry.Algorithm`). The module is named like
its ``algo`` key. The registry finds them by scanning this package
(:func:`nutribench.agents.registry.builtin_algorithms`, modules named ``_...`` apart) and
lists them by their entries' ``order`` (the paper's: MC, DDQN, PPO, SAC, GRU-PPO), then
``external``; nothing else names them (``tests/test_algorithm_registry.py``). A plug-in
package registers the same ``Algorithm`` through the entry-point group
``nutribench.algorithms`` instead.
"""
