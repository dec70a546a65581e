"""The finished studies' own checks: ``python -m pytest -p no:cacheprovider reports/<study>``
(or ``reports/`` for all) runs a study's ``test_*.py``, which test its scripts against this
checkout. They are not part of the project's test suite (``tests/``, which imports no file of
``reports/``: ``tests/test_studies_apart.py``). pytest puts this folder on ``sys.path``, so
that a check loads its study's scripts with :func:`report_scripts.load_script`."""
