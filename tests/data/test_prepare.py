"""The data module's preparer (wdss.data.prepare): injected by the config, so that the data layer never imports the
renderer; a plain callable is one that refuses nothing and judges nothing stale."""

import ast
from pathlib import Path

import wdss.data
from wdss.data.prepare import Preparer, as_preparer
from wdss.render import RenderOnFirstUse


def test_the_renderer_is_a_preparer_and_a_plain_callable_becomes_one():
    render = RenderOnFirstUse("mini", home="data/mini")
    assert isinstance(render, Preparer) and as_preparer(render) is render and as_preparer(None) is None
    calls = []
    plain = as_preparer(calls.append)
    assert isinstance(plain, Preparer)
    plain("root")
    assert calls == ["root"]
    assert plain.refusal("typo") is None and plain.resumes("x") is True
    assert plain.outdated({"a": {}}) is None and plain.stale({"settings": {}}) is None


def test_the_renderer_judges_a_render_of_an_earlier_wdss_stale():
    render = RenderOnFirstUse("mini", home="data/mini")
    assert "no emission pass" in render.stale({"settings": {"denoise": False, "resolution": [96, 48]}})
    fresh = {"settings": {"passes": ["emission"], "resolution": [96, 48]}, "sampling": {"lr": "native"}}
    assert render.stale(fresh) is None


def test_no_module_of_the_data_layer_imports_the_renderer():
    for path in sorted(Path(wdss.data.__file__).parent.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [alias.name for alias in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            assert not any(name == "wdss.render" or name.startswith("wdss.render.") for name in names), path.name
