"""``python -m wdss.report``: the command line of the report."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence

import wdss.report
from wdss.report.write import report


def parser() -> argparse.ArgumentParser:
    """``python -m wdss.report``'s arguments: which runs (a sweep, a parent run, runs by id, an experiment's), where
    the report goes, its scale and its costs."""
    parser = argparse.ArgumentParser(
        prog="python -m wdss.report",
        description=wdss.report.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--sweep", help="the sweep's name (its newest parent run)")
    which.add_argument("--parent", help="the parent run id (its children: a sweep's jobs, or a training's evaluations)")
    which.add_argument("--runs", nargs="+", metavar="ID", help="any runs by id: a row per configuration and data")
    which.add_argument("--experiment", help="the runs of this experiment that have test or bench metrics")
    parser.add_argument(
        "--filter", default="", help="with --experiment: an MLflow filter, e.g. \"tags.data = 'bench'\""
    )
    parser.add_argument("--name", default=None, help="the report's folder under --out (default: the sweep's name)")
    parser.add_argument("--tracking-uri", default=None, help="default: $MLFLOW_TRACKING_URI or sqlite:///mlflow.db")
    parser.add_argument("--out", default="outputs/reports")
    parser.add_argument(
        "--scale",
        default=None,
        help="the scale of the table and plots, e.g. 3x, or avg (default: the sweep's only test scale, else its "
        "paper table's: 2x for the ablations, 3x for methods, avg for scales)",
    )
    parser.add_argument(
        "--facts",
        default=None,
        metavar="SWEEP",
        help="state this sweep file's row names, table scale and orderings (sweeps/SWEEP.yaml's report node) about "
        "the runs, e.g. --runs of a table whose rows two sweeps ran (default: the sweep of the parent run)",
    )
    parser.add_argument(
        "--runtime",
        default=None,
        metavar="SWEEP",
        help="take the plot's ms/frame and GFLOPs from this runtime sweep (name or parent run id; sweeps/runtime.yaml "
        "times every configuration in one process) instead of each run's own timing",
    )
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    arguments = parser()
    args = arguments.parse_args(argv)
    if args.filter and not args.experiment:
        arguments.error("--filter selects among the runs of --experiment")
    report(
        args.sweep,
        args.parent,
        runs=args.runs or (),
        experiment=args.experiment,
        filter_string=args.filter,
        name=args.name,
        tracking_uri=args.tracking_uri,
        out_dir=args.out,
        scale=args.scale,
        runtime=args.runtime,
        facts=args.facts,
    )
