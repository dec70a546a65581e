"""``python -m nutribench.cli``: the same as the ``nutribench`` command."""

from nutribench.cli import main

main()
