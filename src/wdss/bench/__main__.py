"""``python -m wdss.bench``: the command line's own process, which the timing benchmarks may start again under
:mod:`wdss.memory`'s malloc tunables (``restart``)."""

from wdss.bench.cli import main

if __name__ == "__main__":
    main(restart=True)
