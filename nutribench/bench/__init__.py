"""The benchmarks behind ``nutribench bench ...``: how fast the environments and the training
run (:mod:`~nutribench.bench.throughput`: ``bench env``, ``bench train``, ``bench status``),
whether each agent learns the task (:mod:`~nutribench.bench.learn`: ``bench learn``), and
whether the two engines learn alike (:mod:`~nutribench.bench.engines`: ``bench engines``).
Benchmarks, not tests: each takes minutes."""
