"""Everything about jobs, from ``nutribench run``'s options to a job's rows in the database.

The driver's side (the one process that writes the database):

- :mod:`~nutribench.scheduler.grid`: presets and ``run`` options -> regime x agent x seed cells
- :mod:`~nutribench.scheduler.registration`: configs and job rows recorded; a claimed row -> its JobSpec
- :mod:`~nutribench.scheduler.lifecycle`: the only code that changes a job's status (claim,
  heartbeat, stale rule, done / failed / interrupted), read by status too
- :mod:`~nutribench.scheduler.pools`: jobs one by one or in batches per agent config; ``--engine`` checks;
  stopped batches claimed first; finished batches' checkpoints deleted
- :mod:`~nutribench.scheduler.driver`: the loop (claim, submit, store each finished job in one transaction),
  results kept through a locked or failing database, with :mod:`~nutribench.scheduler.settings` (what it
  runs, the job functions when not told); it installs no signal handler (``run``'s are :mod:`nutribench.cli.run`)
- :mod:`~nutribench.scheduler.executors`, :mod:`~nutribench.scheduler.local`: where jobs run
- :mod:`~nutribench.scheduler.progress`: the live panel; :mod:`~nutribench.scheduler.status`: ``nutribench status``

The worker's side (never touches the database):

- :mod:`~nutribench.scheduler.worker`: JobSpec in, JobResult out (pure, picklable data); what every
  executor runs (one thread, progress events)
- :mod:`~nutribench.scheduler.single_job`: one job (SB3 engine or a plug-in's code)
- :mod:`~nutribench.scheduler.batched_job`: a batch of jobs through the batched engine
- :mod:`~nutribench.scheduler.synthetic`: the dry run's and the tests' stand-in job
- :mod:`~nutribench.scheduler.preload`: what the fork server imports once
"""
