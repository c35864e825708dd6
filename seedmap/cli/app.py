"""The typer app and its command groups, the options every command shares, and the entry point.

User errors (:class:`~seedmap.errors.SeedmapError`) print one line on stderr and exit with code 2; warnings print
as ``warning: <message>`` lines (:mod:`seedmap.log`).
"""

from __future__ import annotations

import signal
import sys
import threading

import typer

from seedmap import __version__
from seedmap.errors import SeedmapError
from seedmap.log import cli_messages

app = typer.Typer(
    name="seedmap",
    help="Semantic stereo SLAM and panicle 3D reconstruction with sorghum seeds as landmarks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
simulate_app = typer.Typer(help="Render simulated datasets with ground truth.", no_args_is_help=True)
train_app = typer.Typer(help="Train the learned detector and segmenter.", no_args_is_help=True)
eval_app = typer.Typer(help="Evaluate results against ground truth.", no_args_is_help=True)
benchmark_app = typer.Typer(help="The paper's method comparison (Tables 1 and 2), reproducible.",
                            no_args_is_help=True)
config_app = typer.Typer(help="Show the configuration a command runs with.", no_args_is_help=True)
app.add_typer(simulate_app, name="simulate")
app.add_typer(train_app, name="train")
app.add_typer(eval_app, name="eval")
app.add_typer(benchmark_app, name="benchmark")
app.add_typer(config_app, name="config")

ConfigOpt = typer.Option(None, "--config", "-c", help="YAML config file (defaults otherwise).")
SetOpt = typer.Option(None, "--set", "-s", help="Override a config value: --set section.key=value (repeatable).")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"seedmap {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version."),
) -> None:
    """seedmap: maps of crop plants from stereo cameras, with sorghum seeds as landmarks."""


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread: the command unwinds as on Ctrl-C (partial outputs removed, worker
    processes stopped) instead of dying where it stands."""


def _on_sigterm(signum: int, frame: object) -> None:
    raise _Terminated


def main() -> None:
    """Console entry point: user errors become one ``error: `` line on stderr and exit code 2; warnings are
    ``warning: `` lines (:mod:`seedmap.log`); Ctrl-C prints ``interrupted`` (exit 130), SIGTERM ``terminated``
    (exit 143), after the command has removed what it had half written."""
    in_main_thread = threading.current_thread() is threading.main_thread()
    old_term = signal.signal(signal.SIGTERM, _on_sigterm) if in_main_thread else None
    try:
        with cli_messages():
            app()
    except SeedmapError as e:
        typer.secho(f"error: {e}", err=True, fg=typer.colors.RED)
        sys.exit(2)
    except SystemExit as e:
        if e.code == 130:  # typer turns KeyboardInterrupt into Exit(130); seedmap exits 130 for nothing else
            typer.secho("interrupted", err=True)
        raise
    except KeyboardInterrupt:
        typer.secho("interrupted", err=True)
        sys.exit(130)
    except _Terminated:
        typer.secho("terminated", err=True)
        sys.exit(143)
    finally:
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)
