"""The documentation's shape: a README a new user can read (small, links that resolve, the
quickstart's test command the one CI runs), and docs whose relative links resolve."""

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
README_MAX_BYTES = 12 * 1024


def markdown_files() -> list[Path]:
    return [README, *sorted((ROOT / "docs").rglob("*.md"))]


def anchors(doc: Path) -> set[str]:
    """GitHub's heading anchors of a Markdown file (lower case, punctuation dropped, spaces to -)."""
    out = set()
    for line in doc.read_text(encoding="utf-8").splitlines():
        m = re.match(r"#{1,6} (.*)", line)
        if m:
            slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
            out.add(slug)
    return out


def test_readme_is_small():
    size = README.stat().st_size
    assert size <= README_MAX_BYTES, (
        f"README.md is {size} bytes; keep it at most {README_MAX_BYTES} (details go to docs/)"
    )


def test_relative_links_resolve():
    bad = []
    for doc in markdown_files():
        text = doc.read_text(encoding="utf-8")
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path_part, _, anchor = target.partition("#")
            path = (doc.parent / path_part).resolve() if path_part else doc
            if not (path.exists() and path.is_relative_to(ROOT)):
                bad.append(f"{doc.relative_to(ROOT)}: {target}")
            elif anchor and path.suffix == ".md" and anchor not in anchors(path):
                bad.append(f"{doc.relative_to(ROOT)}: {target} (no such heading)")
    assert not bad, "\n".join(bad)


def test_readme_test_command_is_the_ci_command():
    text = README.read_text(encoding="utf-8")
    m = re.search(r"Install, lint, type-check and run the tests \(what `\.ci/run` runs\):\n\n```\n(.*?)\n```", text)
    assert m, "README's quickstart lost its test command"
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").strip().splitlines()[-1]
    assert shlex.split(m.group(1)) == shlex.split(ci), (m.group(1), ci)


def test_readme_quickstart_comes_first():
    text = README.read_text(encoding="utf-8")
    sections = re.findall(r"^## (.*)$", text, re.M)
    assert sections[:2] == ["Install", "Quickstart"], sections
    assert "pip install . && ooc-dem run quick" in text


@pytest.mark.parametrize(
    "script, doc",
    [("gen_api_docs", "api.md"), ("gen_cli_doc", "cli.md"), ("gen_parameters_doc", "parameters.md")],
)
def test_generated_docs_are_current(script, doc):
    """docs/api.md, cli.md and parameters.md are what their generators make now."""
    import importlib
    import sys

    sys.path.insert(0, str(ROOT / "tools"))
    try:
        gen = importlib.import_module(script)
    finally:
        sys.path.pop(0)
    committed = (ROOT / "docs" / doc).read_text(encoding="utf-8")
    assert committed == gen.render(), f"docs/{doc} is stale: run `python tools/{script}.py`"


def test_the_generated_references_hold_every_key_and_command():
    from ooc_dem.model.scenario_doc import every_key

    params = (ROOT / "docs" / "parameters.md").read_text(encoding="utf-8")
    for info in every_key():
        assert f"| `{info.name}` |" in params, info.path
    cli = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert "`ooc-dem checkpoint export`" in cli and "`--show` `NAME`" in cli
