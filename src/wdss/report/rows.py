"""The rows of a report: which runs are seeds of one configuration, and the row's name as the paper prints it."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence

from wdss.report.facts import paper_labels


def overrides(run) -> dict[str, str]:
    """A job's Hydra overrides: its tag ``overrides`` (``wdss.tracking.run_overrides``; an evaluation carries its
    training run's, so it is a row of that training), or for runs from before the tag, their name (then the job's
    ``override_dirname``); {} for a custom name or one that leads with the variant (``swt_db4 · seed0 · mini``)."""
    from wdss.tracking import NAME_SEPARATOR, split_overrides

    tags = run.data.tags
    if "overrides" in tags:
        text = tags["overrides"]
    else:
        text = tags.get("mlflow.runName", "")
        if NAME_SEPARATOR in text:
            return {}
    items = split_overrides(text)
    if any(value is None for _, value in items):
        return {}
    return dict(items)


# Override keys that never make another configuration: the seed (a row's repeats), where a run is tracked, which
# scales it was tested at (each a column of its own) and what it writes besides its metrics.
NOT_AXES = frozenset({"seed", "experiment_name", "data.test_scales", "video", "write_outputs"})


def sweep_axes(runs: Sequence) -> list[str]:
    """The override keys whose value differs between the jobs (the sweep's axes), :data:`NOT_AXES` left out."""
    jobs = [overrides(run) for run in runs]
    keys = sorted({key for job in jobs for key in job} - NOT_AXES)
    return [key for key in keys if len({job.get(key) for job in jobs}) > 1]


def base_label(tags: dict[str, str], labels: Mapping[str, str]) -> tuple[str, set[str]]:
    """The paper's name of a run's configuration (``labels``: by variant or baseline model, the sweep files'
    ``report.labels``), and the override keys that name already says."""
    if tags.get("variant"):
        return labels.get(tags["variant"], tags["variant"]), {"variant"}
    transform, basis, model = tags.get("transform", ""), tags.get("basis", ""), tags.get("model", "")
    if transform.startswith("n/a") and model:  # a baseline: no wavelet, its model names it
        return labels.get(model, model), {"model"}
    if transform == "none":
        return "No wavelet", {"transform", "basis"}
    if transform and basis:
        return f"{transform.upper()}-{basis}", {"transform", "basis"}
    return "default", set()


def configuration(run, axes: Sequence[str], labels: Mapping[str, str]) -> str:
    """A row's label: the paper's name, then every other axis of the sweep as ``key=value``."""
    label, said = base_label(tags_of(run), labels)
    job = overrides(run)
    return ", ".join([label, *(f"{key}={job.get(key, 'default')}" for key in axes if key not in said)])


def group(runs: Sequence, labels: Mapping[str, str] | None = None) -> dict[str, list]:
    """The jobs of each configuration, rows in the order their first job started; where the runs read several data
    roots (tag ``data_root``), each row is also one data root. Rows are named by ``labels`` (default: every sweep
    file's, :func:`wdss.report.facts.paper_labels`)."""
    labels = paper_labels() if labels is None else labels
    axes = sweep_axes(runs)
    several = len({tags_of(run).get("data_root") for run in runs}) > 1
    groups: dict[str, list] = defaultdict(list)
    for run in sorted(runs, key=lambda r: r.info.start_time):
        label = configuration(run, [a for a in axes if not (several and a == "data.root")], labels)
        if several:
            label += f" · {tags_of(run).get('data_root', 'unknown data')}"
        groups[label].append(run)
    if several:  # the rows of one data root together
        return dict(sorted(groups.items(), key=lambda item: tags_of(item[1][0]).get("data_root", "")))
    return dict(groups)


def tags_of(run) -> dict[str, str]:
    """A run's MLflow tags as a dict."""
    return dict(run.data.tags)
