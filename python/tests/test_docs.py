"""docs/python.md runs: its Python blocks, in order, in one namespace, from the repository's
root (as the page says), writing nothing there."""

import re

from conftest import ROOT


def blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_python_page_runs(monkeypatch, capsys):
    page = (ROOT / "docs" / "python.md").read_text()
    code = blocks(page)
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
