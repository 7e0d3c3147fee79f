"""The paper's facts about its tables, as the sweep files state them in a top-level ``report:`` node.

``sweeps/<name>.yaml``::

    report:
      labels: {swt_db4: SWT-db4, ...}   # row names as the paper prints them, by variant or baseline model
      scale: 2x                         # the scale the paper's table reports; avg: the mean over the tested ones
      orderings:                        # the paper's orderings by PSNR, as adjacent claims between variants
        - none < dwt_haar
        - swt_sym4 <= swt_db4

Hydra merges the node into the jobs' config like any other key; nothing in training reads it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import OmegaConf

from wdss.paths import PROJECT_ROOT, SWEEPS_DIR

KEYS = ("labels", "scale", "orderings")
RELATIONS = ("<", "<=")


@dataclass(frozen=True)
class PaperFacts:
    """What a report states about the paper's table of its sweep (nothing for runs of no known sweep)."""

    labels: dict[str, str] = field(default_factory=dict)
    scale: str | None = None
    orderings: tuple[tuple[str, str, str], ...] = ()  # (lower, relation, higher) variants


def sweep_files() -> dict[str, Path]:
    """The sweep files by name (``sweeps/methods.yaml``: ``methods``)."""
    return {path.stem: path for path in sorted(SWEEPS_DIR.glob("*.yaml"))}


def _shown(path: Path) -> str:
    return str(path.relative_to(PROJECT_ROOT)) if path.is_relative_to(PROJECT_ROOT) else str(path)


def _ordering(text: object, where: str) -> tuple[str, str, str]:
    parts = str(text).split()
    if len(parts) != 3 or parts[1] not in RELATIONS:
        raise SystemExit(f"wdss.report: {where} is {text!r}; write a claim as 'lower < higher' or 'lower <= higher'")
    low, relation, high = parts
    return low, relation, high


def read_facts(path: Path) -> PaperFacts:
    """The ``report:`` node of one sweep file (no node: no facts)."""
    node = OmegaConf.load(path).get("report")
    if node is None:
        return PaperFacts()
    shown = _shown(path)
    if not OmegaConf.is_dict(node) or set(node) - set(KEYS):
        raise SystemExit(f"wdss.report: {shown}: report takes the keys {', '.join(KEYS)}, got {node}")
    facts = OmegaConf.to_container(node, resolve=True)
    labels = facts.get("labels") or {}
    if not isinstance(labels, dict):
        raise SystemExit(f"wdss.report: {shown}: report.labels maps a variant to its row name, got {labels!r}")
    scale = facts.get("scale")
    if scale is not None and not re.fullmatch(r"\d+(\.\d+)?x|avg", str(scale)):
        raise SystemExit(f"wdss.report: {shown}: report.scale is a test scale such as 2x, or avg; got {scale!r}")
    claims = facts.get("orderings") or []
    if not isinstance(claims, list):
        raise SystemExit(f"wdss.report: {shown}: report.orderings is a list of claims, got {claims!r}")
    return PaperFacts(
        labels={str(key): str(value) for key, value in labels.items()},
        scale=None if scale is None else str(scale),
        orderings=tuple(_ordering(claim, f"{shown}: report.orderings[{i}]") for i, claim in enumerate(claims)),
    )


def paper_labels() -> dict[str, str]:
    """Every sweep file's ``report.labels``: a variant has one name in every table, and in reports of any runs."""
    return {key: label for path in sweep_files().values() for key, label in read_facts(path).labels.items()}


def paper_facts(sweep: str | None) -> PaperFacts:
    """The facts of the sweep file named ``sweep`` (none for another name, or None), with every sweep file's labels
    beneath its own (:func:`paper_labels`: a runtime sweep's rows match a table's rows by name)."""
    path = sweep_files().get(sweep) if sweep else None
    own = read_facts(path) if path is not None else PaperFacts()
    return PaperFacts(labels={**paper_labels(), **own.labels}, scale=own.scale, orderings=own.orderings)
