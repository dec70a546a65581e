"""Addendum 2: give the checkpoints a lent machine brought back the names this checkout computes.

A checkpoint's name covers the code commit (``batched_job.checkpoint_path``); the lent
machine's copy of the working tree reports another commit for the same files, so a batch
started there would not resume here. For each ``<name>.pt.jobs.json`` in FOLDER, the digest is
recomputed from its manifest with ``--from`` (the machine's ``git rev-parse HEAD``, written in
its machine.txt) and ``--from-version`` (the nutribench version there: ``0.0.0+unknown`` where
the tree runs uninstalled, from PYTHONPATH): only when that reproduces the file's name exactly are the checkpoint's three
files renamed to the digest with ``--to`` (default: this checkout's commit). Nothing else
changes. Usage:

    python reports/ladder/rename_checkpoints.py /tmp/ladder/models/checkpoints --from <commit> \\
        --from-version 0.0.0+unknown
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from nutribench.provenance import git_state
from nutribench.scheduler.batched_job import batch_digest

EVAL_EVERY, VAL_EPISODES = 100, 5  # the plan's --eval-every 100 and nutribench run's default --val-episodes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument(
        "--from", dest="old", required=True, help="the commit the checkpoints' names cover (none: a copy without git)"
    )
    parser.add_argument("--from-version", default=None, help="the nutribench version there (default: this one's)")
    parser.add_argument("--to", dest="new", default=None, help="the commit to name them for (default: this checkout's)")
    args = parser.parse_args(argv)
    old = None if args.old.lower() == "none" else args.old  # a copy without git: the name covers no commit
    new = args.new or git_state()[0]
    renamed = 0
    for manifest in sorted(args.folder.glob("*.pt.jobs.json")):
        stem = manifest.name.removesuffix(".pt.jobs.json")
        prefix, _, digest = stem.rpartition("-")
        jobs = json.loads(manifest.read_text())["jobs"]
        if batch_digest(old, jobs, EVAL_EVERY, VAL_EPISODES, args.from_version) != digest:
            print(f"{manifest.name}: its name is not the digest for commit {args.old}: left as it is", file=sys.stderr)
            continue
        target = f"{prefix}-{batch_digest(new, jobs, EVAL_EVERY, VAL_EPISODES)}"
        for suffix in (".pt", ".pt.state.json", ".pt.jobs.json"):
            (args.folder / f"{stem}{suffix}").rename(args.folder / f"{target}{suffix}")
        print(f"{stem} -> {target} (jobs {jobs[0]['job_id']}..{jobs[-1]['job_id']})")
        renamed += 1
    print(f"{renamed} checkpoint(s) renamed for commit {new}")
    return 0 if renamed else 1


if __name__ == "__main__":
    sys.exit(main())
