"""docs/python.md runs: its Python blocks, in order, in one namespace, from the repository's
root (as the page says), writing nothing there."""

import re

import pytest

from conftest import ROOT


def blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_python_page_runs(monkeypatch, capsys):
    page = (ROOT / "docs" / "python.md").read_text()
    code = blocks(page)
    # The cvxpy example runs, not skips: setup installs cvxpy (scripts/requirements-test.txt).
    assert any("import cvxpy" in block for block in code)
    try:
        import cvxpy  # noqa: F401
    except ImportError as e:
        pytest.fail(f"docs/python.md's cvxpy example needs cvxpy (scripts/requirements-test.txt), which "
                    f"scripts/setup.sh --test installs into the test venv: {type(e).__name__}: {e}")
    assert len(code) >= 6
    monkeypatch.chdir(ROOT)
    before = sorted(p.name for p in ROOT.iterdir()), sorted(p.name for p in (ROOT / "logs").iterdir())
    namespace: dict = {"__name__": "docs_python"}
    for i, block in enumerate(code):
        exec(compile(block, f"docs/python.md block {i + 1}", "exec"), namespace)
    after = sorted(p.name for p in ROOT.iterdir()), sorted(p.name for p in (ROOT / "logs").iterdir())
    assert after == before
    printed = capsys.readouterr().out
    assert "unknown input channel" in printed
