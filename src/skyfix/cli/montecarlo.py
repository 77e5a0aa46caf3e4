"""``skyfix montecarlo CAMPAIGN.toml [--workers N | --scheduler ADDRESS] -o RESULTS.parquet``
(docs/montecarlo.md).

Writes ``RESULTS.parquet`` (a row per trial), ``RESULTS.summary.json`` and with ``--plot`` a PNG;
prints the summary. Exit status 0 when the campaign finished, 2 for bad input (one line), 130
when interrupted (the finished batches are kept: the same command continues).

This module imports only typer and the command helpers at its top (every ``skyfix`` start loads
it); the campaign machinery (dask, pyarrow, numpy) is imported when the command runs.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import typer

from skyfix.cli.common import VERBOSE, add_verbosity, check_cluster, guarded, prepare_outputs
from skyfix.errors import InputError

__all__ = ["montecarlo"]

@guarded
def montecarlo(
    campaign_file: Path = typer.Argument(..., metavar="CAMPAIGN.toml",
                                         help="The campaign (docs/montecarlo.md)."),
    output: Path = typer.Option(..., "--output", "-o", help="Results, Parquet: a row per trial."),
    workers: int = typer.Option(None, "--workers", help="Local worker processes (default: the cores)."),
    scheduler: str = typer.Option(None, "--scheduler", metavar="ADDRESS",
                                  help="A running Dask scheduler (tcp://HOST:8786) instead of local "
                                       "workers."),
    plot: Path = typer.Option(None, "--plot", help="Write a PNG: error histograms, errors per swept "
                                                   "parameter, a sky map of the failures."),
    verbose: int = VERBOSE,
) -> None:
    """Run a Monte Carlo campaign: simulate, solve and judge every trial, on Dask; resumable."""
    add_verbosity(verbose)
    from skyfix.montecarlo.campaign import load_campaign

    check_cluster(workers, scheduler)
    if output.suffix.lower() != ".parquet":
        raise InputError(f"--output {output}: the results are Parquet: name it *.parquet")
    campaign = load_campaign(campaign_file)
    prepare_outputs({"--output": [output, output.with_suffix(".summary.json")], "--plot": [plot]},
                    inputs=[campaign_file])
    from skyfix.montecarlo.engine import parts_folder, run_campaign
    from skyfix.montecarlo.results import plot_results, summarize, summary_lines, timing, write_summary

    n_workers = workers or os.cpu_count() or 1
    bar = _progress_bar(campaign.n_batches)
    try:
        result = run_campaign(campaign, output, workers=n_workers, scheduler=scheduler,
                              progress=bar.update if bar else None)
    except KeyboardInterrupt:
        if bar:
            bar.stop()
        typer.echo(f"skyfix: interrupted: the finished batches are kept in {parts_folder(output)}; "
                   "the same command continues the campaign", err=True)
        raise typer.Exit(130) from None
    finally:
        if bar:
            bar.stop()
    if result.batches_before:
        typer.echo(f"skyfix: {result.batches_before} of {result.n_batches} batches were done already",
                   err=True)
    summary = summarize(result.table, campaign)
    if result.batches_run:
        summary["timing"] = timing(result.table, result.trials_run, result.wall_s, result.workers)
    write_summary(summary, output.with_suffix(".summary.json"))
    if plot is not None:
        plot_results(result.table, campaign, plot)
    for line in summary_lines(summary):
        typer.echo(line)


class _Bar:
    def __init__(self, total: int) -> None:
        from rich.console import Console
        from rich.progress import Progress

        self.progress = Progress(console=Console(stderr=True), transient=True)
        self.task = self.progress.add_task("batches", total=total)
        self.progress.start()

    def update(self, done: int, total: int) -> None:
        self.progress.update(self.task, completed=done, total=total)

    def stop(self) -> None:
        self.progress.stop()


def _progress_bar(total: int) -> _Bar | None:
    """A rich progress bar on stderr when it is a terminal."""
    return _Bar(total) if sys.stderr.isatty() else None
