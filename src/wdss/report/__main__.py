"""``python -m wdss.report``."""

from wdss.report.cli import main

if __name__ == "__main__":
    main()
