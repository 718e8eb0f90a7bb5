"""The reference site builds with no warning, documents every public name, and the README's links land.

`mkdocs build --strict` (mkdocs.yml: every link and anchor validated) fails on a broken link, a
missing anchor, a page left out of the nav, or an API name mkdocstrings cannot find.
"""

from __future__ import annotations

import importlib
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from markdown.extensions.toc import slugify

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "PYTHONPATH": str(ROOT)}

#: The packages whose public classes and functions the API page must document.
API_PACKAGES = ("synthpack", "synthpack.errors", "synthpack.io", "synthpack.scan", "synthpack.source",
                "synthpack.measure", "synthpack.library", "synthpack.physics", "synthpack.artefacts",
                "synthpack.pipeline", "synthpack.store", "synthpack.dataset", "synthpack.export",
                "synthpack.realism", "synthpack.metrics")


def _build(config: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(config), "-d", str(site)],
                          cwd=config.parent, capture_output=True, text=True, timeout=180, env=ENV)


@pytest.mark.slow
def test_the_site_builds_strictly_with_no_warning(tmp_path):
    result = _build(ROOT / "mkdocs.yml", tmp_path / "site")
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-4000:]
    assert "WARNING" not in output, output[-4000:]
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    # mkdocstrings rendered the docstrings (numpydoc sections), not just the headings
    assert 'id="synthpack.physics.pouring.pour"' in api and "Parameters:" in api


def test_strict_validation_refuses_a_missing_anchor(tmp_path):
    # the site's own validation settings, on a page whose link points at no heading
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "index.md").write_text("# Home\n\nSee [pouring](other.md#no-such-heading).\n")
    (tmp_path / "docs" / "other.md").write_text("# Other\n\n## Pouring\n")
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump({
        "site_name": "t", "strict": config["strict"], "validation": config["validation"],
        "nav": ["index.md", "other.md"]}))
    result = _build(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert result.returncode != 0
    assert "no-such-heading" in result.stdout + result.stderr


def _public(package: str):
    module = importlib.import_module(package)
    for name in getattr(module, "__all__", None) or [n for n in dir(module) if not n.startswith("_")]:
        obj = getattr(module, name)
        if (inspect.isclass(obj) or inspect.isfunction(obj)) and obj.__module__.startswith("synthpack"):
            yield f"{obj.__module__}.{obj.__qualname__}"


@pytest.mark.slow  # imports every package, torch included (~5 s)
def test_the_api_page_documents_every_public_name():
    documented = set(re.findall(r"^::: (\S+)$", (ROOT / "docs" / "api.md").read_text(), flags=re.M))
    public = {path for package in API_PACKAGES for path in _public(package)}
    assert not public - documented, sorted(public - documented)


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", page.read_text(), flags=re.M | re.S)  # headings outside code blocks
    return {slugify(re.sub(r"[`*]", "", line.lstrip("#").strip()), "-")
            for line in text.splitlines() if re.match(r"#{1,6} ", line)}


def test_every_link_of_the_readme_lands():
    # the README is not a page of the site: its links into docs/ and the repository are checked here
    readme = ROOT / "README.md"
    links = re.findall(r"\]\(([^)\s]+)\)", readme.read_text())
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    assert local, "the README links to no page"
    broken = []
    for link in local:
        path, _, anchor = link.partition("#")
        target = ROOT / path if path else readme
        if not target.exists():
            broken.append(link)
        elif anchor and target.suffix == ".md" and anchor not in _anchors(target):
            broken.append(link)
    assert not broken, broken
