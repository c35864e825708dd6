"""``python -m seedmap.cli``: the ``seedmap`` command."""

from seedmap.cli import main

if __name__ == "__main__":
    main()
