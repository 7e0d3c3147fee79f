"""Training entry point: ``python -m wdss.train``.

The network and its LightningModule (issue 5) and the Hydra configuration (issue 6) are not built yet;
until they are, this entry point says so instead of pretending to train.
"""

from __future__ import annotations

import sys


def main() -> int:
    print(
        "wdss.train: training is not available yet: the network, LightningModule and Hydra configs are still "
        "being built (issues 5 and 6). What works today: `make test`, `python -m wdss.bench wavelets`.",
        file=sys.stderr,
    )
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
