"""The benchmarks behind ``nutribench bench ...``: how fast the environments and the training
run (:mod:`~nutribench.bench.throughput`: ``bench env``, ``bench train``) and how many tuning
trials an hour each way of running them gives (:mod:`~nutribench.bench.tune`: ``bench tune``).
Benchmarks, not tests: each takes minutes. The developer's benchmarks (learnability, the two
engines compared, ``status`` speed) are scripts beside the package, in ``benchmarks/``."""
