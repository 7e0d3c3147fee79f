"""Screenshot of the MLflow runs view of one experiment, with the columns the README names (issue 41).

Serves a copy of a SQLite tracking store with ``mlflow ui`` on 127.0.0.1 (a free port), opens
``/#/experiments/<id>/runs?workflowType=machine_learning`` in headless Chromium, expands parent (sweep) runs so
their training runs show, adds metric and tag columns through the table's "Columns" menu as a user would, and
saves a screenshot. The server is stopped (by its pid, with its process group) at the end.

Needs Playwright for Python and a Chromium binary; Playwright is not a project dependency::

    pip install playwright        # no `playwright install`: an installed Chromium is used
    apt-get install chromium      # or pass --chromium /path/to/chrome

Usage::

    python tools/screenshot_runs_view.py --store mlflow.db --experiment wdss --out runs_view.png

``--store`` is a SQLite file or ``sqlite:///`` URI; it is copied (SQLite backup API, safe while a training run
writes to it) into a temporary folder and only the copy is served.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

METRICS = ["test/psnr_2x", "test/psnr_3x", "test/psnr_4x", "val/psnr"]
TAGS = ["model", "variant", "data_root", "seed"]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def store_path(store: str) -> Path:
    """``sqlite:///rel.db`` -> ``rel.db``, ``sqlite:////abs.db`` -> ``/abs.db`` (SQLAlchemy's reading), a path as is."""
    return Path(store.removeprefix("sqlite:///")) if store.startswith("sqlite:///") else Path(store)


def copy_store(source: Path, target: Path) -> None:
    src = sqlite3.connect(f"file:{source}?mode=ro", uri=True)
    dst = sqlite3.connect(target)
    with dst:
        src.backup(dst)
    src.close()
    dst.close()


def start_server(db: Path, port: int, log: Path) -> subprocess.Popen:
    mlflow = Path(sys.executable).with_name("mlflow")
    command = [
        str(mlflow) if mlflow.exists() else "mlflow",
        "ui",
        "--backend-store-uri",
        f"sqlite:///{db}",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
    ]
    env = {**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true"}
    with log.open("w") as handle:  # its own process group: stopping it stops uvicorn's workers too
        return subprocess.Popen(command, stdout=handle, stderr=subprocess.STDOUT, env=env, start_new_session=True)


def stop_server(server: subprocess.Popen) -> None:
    if server.poll() is None:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()


def wait_for(base: str, server: subprocess.Popen, log: Path, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if server.poll() is not None:
            raise SystemExit(f"mlflow ui exited ({server.returncode}):\n{log.read_text()[-3000:]}")
        try:
            with urllib.request.urlopen(f"{base}/health", timeout=5) as response:
                if response.status == 200:
                    return
        except OSError:
            pass
        time.sleep(2)
    raise SystemExit(f"mlflow ui did not answer within {timeout:.0f} s:\n{log.read_text()[-3000:]}")


def experiment_id(base: str, name: str) -> str:
    query = urllib.parse.urlencode({"experiment_name": name})
    try:
        with urllib.request.urlopen(f"{base}/api/2.0/mlflow/experiments/get-by-name?{query}", timeout=30) as r:
            return json.load(r)["experiment"]["experiment_id"]
    except urllib.error.HTTPError as error:
        raise SystemExit(f"no experiment named {name!r} in the store ({error})") from None


def expand_parent_runs(page) -> None:
    """Click every collapsed "+" expander of the run-name cells (sweep parents), until none is left."""
    for _ in range(10):
        collapsed = page.locator("button[data-component-id*='runnamecellrenderer']:has(path[d*='V4.5h1.5'])")
        if collapsed.count() == 0:
            return
        collapsed.first.click()
        page.wait_for_timeout(1500)


def close_assistant(page) -> None:
    """The MLflow Assistant side panel takes a third of the width: close it when it is open."""
    panel = page.get_by_text("MLflow Assistant", exact=False)
    if panel.count() and panel.first.is_visible():
        close = page.get_by_role("button", name="Close", exact=True)
        if close.count() and close.first.is_visible():
            close.first.click()
            page.wait_for_timeout(500)


def add_columns(page, group: str, names: list[str]) -> list[str]:
    """Tick ``names`` under ``group`` ("Metrics", "Parameters" or "Tags") in the open "Columns" menu; the missing."""
    missing = []
    search = page.get_by_placeholder("Search columns")
    for name in names:
        search.fill(name)
        page.wait_for_timeout(800)
        nodes = page.locator(".du-bois-light-tree-treenode")
        titles = nodes.evaluate_all(
            "els => els.map(e => e.querySelector('.du-bois-light-tree-title')?.textContent || '')"
        )
        current, target = None, None
        for i, title in enumerate(titles):
            if title.endswith(")") and " (" in title:  # a group: "Metrics (122)"
                current = title.rsplit(" (", 1)[0]
            elif current == group and title == name:
                target = nodes.nth(i)
                break
        if target is None:
            missing.append(f"{group}: {name}")
            continue
        if "checked" not in (target.get_attribute("class") or ""):
            target.locator(".du-bois-light-tree-checkbox").click()
            page.wait_for_timeout(500)
    search.fill("")
    return missing


def screenshot(
    url: str, out: Path, chromium: str, metrics: list[str], tags: list[str], width: int, height: int
) -> list[str]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": width, "height": height})
        page.goto(url)
        columns = page.get_by_role("button", name="Columns", exact=True)
        columns.wait_for(timeout=120_000)
        page.wait_for_timeout(2000)
        close_assistant(page)
        expand_parent_runs(page)
        columns.click()
        page.get_by_placeholder("Search columns").wait_for()
        missing = add_columns(page, "Metrics", metrics) + add_columns(page, "Tags", tags)
        page.keyboard.press("Escape")
        page.mouse.click(width - 5, height - 5)  # closes the menu if Escape did not
        page.wait_for_timeout(2000)
        out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(out), full_page=True)
        print("wdss: the view after choosing columns:", page.url)
        browser.close()
    return missing


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--store", required=True, help="SQLite tracking store: a file or sqlite:/// URI")
    parser.add_argument("--experiment", default="wdss", help="experiment name (default: wdss)")
    parser.add_argument("--out", type=Path, default=Path("runs_view.png"), help="the PNG to write")
    parser.add_argument("--chromium", default="/usr/bin/chromium", help="Chromium executable")
    parser.add_argument("--metrics", nargs="*", default=METRICS, help="metric columns to add")
    parser.add_argument("--tags", nargs="*", default=TAGS, help="tag columns to add")
    parser.add_argument("--size", default="2200x900", help="viewport WIDTHxHEIGHT (default 2200x900)")
    parser.add_argument("--start-timeout", type=float, default=300, help="seconds to wait for mlflow ui")
    args = parser.parse_args(argv)

    source = store_path(args.store)
    if not source.is_file():
        raise SystemExit(f"no SQLite store at {source}")
    width, height = (int(v) for v in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory(prefix="runs_view_") as tmp:
        db, log = Path(tmp) / "mlflow.db", Path(tmp) / "mlflow_ui.log"
        copy_store(source, db)
        port = free_port()
        base = f"http://127.0.0.1:{port}"
        server = start_server(db, port, log)
        print(f"wdss: mlflow ui (pid {server.pid}) serves a copy of {source} on {base}")
        try:
            wait_for(base, server, log, args.start_timeout)
            url = f"{base}/#/experiments/{experiment_id(base, args.experiment)}/runs?workflowType=machine_learning"
            print("wdss: opening", url)
            missing = screenshot(url, args.out, args.chromium, args.metrics, args.tags, width, height)
        finally:
            stop_server(server)
    print("wdss: screenshot", args.out)
    if missing:
        print("wdss: columns not found:", ", ".join(missing), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
