"""``nutribench db export`` / ``db import``: the finished jobs of a database as one portable
file, and that file merged into another database.

Where ``db copy`` moves a whole database into an empty one keeping ids, an archive carries
chosen *results* between databases that already hold others: a grid run in parts on
machines (or working sessions) that do not share a disk, or a reproduction's results
shipped beside its report for anyone to load and query.

The file is a NumPy ``.npz`` (zip, no pickle): ``meta`` is UTF-8 JSON (format, the configs'
full rows, one entry per job with every column but its ids and the driver's bookkeeping);
``episodes.<column>`` and ``eval_steps.<column>`` are column arrays, ``job`` being the
job's position in ``meta["jobs"]``. Values are kept exactly (float64); a NULL becomes NaN
(floats) or -1 (``first_overshoot_step``) with a ``<column>.null`` mask beside it. The job
columns of schema revision 0004 (``fake``, ``batch_id``, ``batch_size``, ``device``,
``source``, ``source_sha256``) travel too; an archive written before them reads as
``fake = false`` and NULLs. The tables of revisions 0005 and 0006 travel the same way:
``diagnostics.<column>`` (``job``, ``update``, ``timestep``, the quantities, and a column per
other name a plug-in recorded; one row per update, the long table pivoted, as before revision
0007; no update twice per job) and ``validation_episodes.<column>`` (no (training day, day) twice per job, training
days from 1, foods within a day); an archive written before them imports without those rows.

An archive is a file from anywhere, so nothing in it is believed (:func:`read_archive`):
before a database is opened (or created) the whole archive is checked, and the first thing
wrong is one line naming the archive, exit status 2, nothing written. Checked: the file is
a readable ``.npz`` of this format; every column is there, one-dimensional, of its type
(float64 for measurements, integers, strings, boolean NULL masks) and as long as the
table's ``job`` column; no array or field that the format does not have; every row's job
index in range; no NaN or infinity that is not a NULL, and no NULL where the column allows none; the
phases, statuses and engines known; no key twice (a config's name and version, a job's
key, an episode's or a step's primary key); per job, ``episodes`` training days (the
budget; an external agent's budget is the number of days it recorded, or, with no training
rows, the days a saved model's sidecar records), ``eval_episodes``
evaluation days and ``eval_episodes x H`` evaluation steps (H the regime's horizon), each
numbered in range, and foods and actions in range; every config's ``sha256`` recomputed
from its stored body, which names the same config; every name ``[a-z][a-z0-9_]*`` (64
characters at most), as files and figures are named after them; the meta's counts equal
the arrays'; seeds, counts and wall times non-negative, overshoot ratios in 0..1, texts at
most 65,536 characters, no infinity in the meta. Before anything is decompressed, the
members' declared sizes (at most 1 GiB in all) and each ``.npy`` header's shape (no larger
than its member) are read, no member name twice (:func:`~nutribench.store.archive.format.open_archive`). No
text may hold a NUL (PostgreSQL stores none; refused on every backend). A config bearing a
shipped name and version must have the shipped content (:mod:`~nutribench.store.archive.installed`).
Every evaluation day's foods must be the seed's test days, and each is replayed from its
stored foods and actions on the archive's regime, and its steps and metrics must agree (:mod:`~nutribench.store.archive.replay`); the
training days cannot be replayed. A stored model path is never trusted: the import drops it (``model_path``
NULL; an archive carries no model files, and a path from another machine names nothing
here). The configs' and jobs' ``source`` (the file or script they came from on the
exporting machine) are kept as text: nothing in nutribench opens them. :func:`export_results` runs the same checks before it writes, so a database whose
done jobs would not import says so at export.

Import matches configs by (name, version) and refuses one recorded with other content (a
changed file whose version was not bumped); it matches jobs by (regime config, agent config,
seed, budget, evaluation episodes). A job the destination already has done is left alone
(counted as ``kept``); one it has pending, interrupted or failed takes the archived result;
one another driver is running is refused; a dry run's jobs (``fake``) and real results are
never mixed in one database. Everything is written in one transaction, and the rows written
are counted against the archive's before the commit; a SQLite file the import created is
removed again if the import fails.

The package, by seam: :mod:`~nutribench.store.archive.format` (the format, and
:func:`~nutribench.store.archive.format.open_archive`, the one reader of an archive file),
:mod:`~nutribench.store.archive.check` (every check, :func:`read_archive`),
:mod:`~nutribench.store.archive.installed` (configs held against the installed ones),
:mod:`~nutribench.store.archive.replay` (the evaluation days played again),
:mod:`~nutribench.store.archive.export` (``db export``) and
:mod:`~nutribench.store.archive.merge` (``db import``).
"""

from nutribench.store.archive.check import read_archive, verify_archive
from nutribench.store.archive.export import export_results
from nutribench.store.archive.format import NAME_MAX, valid_config_name
from nutribench.store.archive.merge import import_results

__all__ = ["NAME_MAX", "export_results", "import_results", "read_archive", "valid_config_name", "verify_archive"]
