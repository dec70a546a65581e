"""The fake jobs the scheduler tests hand to worker processes, in a module of their own: a
worker unpickles a job by importing its module, and this one imports only ``os`` (the
synthetic job lazily), so that a job process does not first import a whole test module (pandas,
SQLAlchemy, the command line: about 1.5 s a job on this project's 2-core machine)."""

from __future__ import annotations

import os


class EnvJob:
    """The fake job with extra environment variables set in the worker (a picklable
    callable: the fork server's environment is fixed when it starts). A dry run's job, as
    the fake job it wraps: its jobs are marked ``fake``, never mixed with real ones."""

    fake = True

    def __init__(self, **env: str):
        self.env = env

    def __call__(self, spec, sink=None):
        from nutribench.scheduler.synthetic import synthetic_job

        os.environ.update(self.env)
        return synthetic_job(spec, sink)


class EnvBatch(EnvJob):
    """The synthetic batch with extra environment variables set in the worker."""

    def __call__(self, specs, sink=None):
        from nutribench.scheduler.synthetic import synthetic_batch

        os.environ.update(self.env)
        return synthetic_batch(specs, sink)


class HalfBatch(EnvJob):
    """A batch worker that loses the result of its last job (a bug the driver must survive)."""

    def __call__(self, specs, sink=None):
        from nutribench.scheduler.synthetic import synthetic_batch

        return synthetic_batch(specs, sink)[:-1]
