"""The ``seedmap`` command: one typer app, thin wrappers over the package's pipelines.

Every command that writes results writes into a fresh folder atomically (temporary name, then
rename) together with its resolved config. User errors print one line and exit with code 2.
One module per command group; importing them registers their commands, in the order ``--help``
lists them. Heavy libraries are imported inside the commands, so ``seedmap --help`` stays fast.
"""

from seedmap.cli import detect, slam, phenotype, recon, bag, batch  # noqa: F401  (top-level commands, in --help order)
from seedmap.cli import simulate, train, evaluate, benchmark, config  # noqa: F401  (command groups)
from seedmap.cli.app import app, main

__all__ = ["app", "main"]
