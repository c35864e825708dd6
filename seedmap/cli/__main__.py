"""``python -m seedmap.cli``: the ``seedmap`` command."""

from seedmap.cli import main

main()
