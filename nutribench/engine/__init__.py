"""The batched training engine: K agents of one agent config trained at once, their
parameters stacked along an agent axis (issue 15). The SB3 agents in
:mod:`nutribench.agents` stay the reference implementation; each algorithm here is tested
to make the same update as its SB3 counterpart."""

#: the algorithms the batched engine trains (their agent configs can run with ``--engine batched``)
BATCHED_ALGOS = ("ppo", "mc", "ddqn", "sac", "gru_ppo")
