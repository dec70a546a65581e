"""The fake jobs the scheduler tests hand to worker processes, in a module of their own: a
worker unpickles a job by importing its module, and this one imports only ``os`` (the
synthetic job lazily), so that a job process does not first import a whole test module (pandas,
SQLAlchemy, the command line: about 1.5 s a job on this project's 2-core machine)."""

from __future__ import annotations

import os
import signal


class Faults:
    """Chosen jobs misbehave halfway through training (the synthetic job's ``before_episode``):
    ``fail`` raises an exception, ``kill`` SIGKILLs its own process (a dying worker). Each is
    a comma-separated list of ``regime:algo:seed`` labels, or ``*`` for every job."""

    def __init__(self, fail: str = "", kill: str = ""):
        self.fail, self.kill = fail, kill

    @staticmethod
    def _matches(labels: str, spec) -> bool:
        chosen = {v.strip() for v in labels.split(",") if v.strip()}
        return "*" in chosen or f"{spec.regime}:{spec.algo}:{spec.seed}" in chosen

    def __call__(self, spec, k: int) -> None:
        if k != spec.episodes // 2:
            return
        if self._matches(self.fail, spec):
            raise RuntimeError(f"fake failure in {spec.label} at episode {k}")
        if self._matches(self.kill, spec):
            os.kill(os.getpid(), signal.SIGKILL)


class EnvJob:
    """The fake job with extra environment variables set in the worker (a picklable
    callable: the fork server's environment is fixed when it starts) and :class:`Faults`
    (``fail=``, ``kill=``). A dry run's job, as the fake job it wraps: its jobs are marked
    ``fake``, never mixed with real ones."""

    fake = True

    def __init__(self, fail: str = "", kill: str = "", **env: str):
        self.faults = Faults(fail, kill)
        self.env = env

    def __call__(self, spec, sink=None):
        from nutribench.scheduler.synthetic import synthetic_job

        os.environ.update(self.env)
        return synthetic_job(spec, sink, self.faults)


class EnvBatch(EnvJob):
    """The synthetic batch with extra environment variables set in the worker, and :class:`Faults`."""

    def __call__(self, specs, sink=None):
        from nutribench.scheduler.synthetic import synthetic_batch

        os.environ.update(self.env)
        return synthetic_batch(specs, sink, self.faults)


class HalfBatch(EnvJob):
    """A batch worker that loses the result of its last job (a bug the driver must survive)."""

    def __call__(self, specs, sink=None):
        from nutribench.scheduler.synthetic import synthetic_batch

        return synthetic_batch(specs, sink)[:-1]
