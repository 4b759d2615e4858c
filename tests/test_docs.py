"""The documentation site builds with warnings as errors (`make docs`, mkdocs.yml),
every page of its nav is in the output, and the API reference documents every
name `jaxpile` exports (`jaxpile.__all__`, read when the test runs)."""

import ast
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _nav_pages(nav) -> list[str]:
    """Every page path in mkdocs.yml's nav (nested sections included)."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [page for item in nav for page in _nav_pages(item)]
    if isinstance(nav, dict):
        return [page for value in nav.values() for page in _nav_pages(value)]
    return []


def _built_path(page: str) -> str:
    """Where mkdocs writes a page (`use_directory_urls: false`: a.md -> a.html, so
    the site's links work opened from disk)."""
    return page.rsplit(".", 1)[0] + ".html"


def _exported_names() -> list[str]:
    """`jaxpile.__all__`, parsed from jaxpile/__init__.py (no JAX import)."""
    tree = ast.parse((ROOT / "jaxpile" / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise AssertionError("jaxpile/__init__.py has no __all__")


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out),
                          "--config-file", str(ROOT / "mkdocs.yml")],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=600, check=False)
    assert run.returncode == 0, f"mkdocs build --strict failed (make docs):\n{run.stdout}\n{run.stderr}"
    return out


def test_every_nav_page_is_built(site):
    import yaml

    # mkdocs.yml holds no python tags; the nav is plain YAML
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    pages = _nav_pages(config["nav"])
    assert "index.md" in pages and any(p.endswith(".ipynb") for p in pages)
    missing = [p for p in pages if not (site / _built_path(p)).is_file()]
    assert not missing, f"nav pages not in the built site: {missing}"


def test_the_api_reference_documents_every_exported_name(site):
    """Each name of `jaxpile.__all__` is rendered in the API pages: under its
    exported name (`jaxpile.Simulator`) or where it is defined
    (`jaxpile.engine.simulate.Simulator`, `jaxpile.measure.analysis`)."""
    import griffe

    package = griffe.load("jaxpile", search_paths=[str(ROOT)])
    ids = set()
    for page in (site / "api").rglob("*.html"):
        ids.update(re.findall(r'id="(jaxpile[\w.]*)"', page.read_text()))
    missing = []
    for name in _exported_names():
        obj = package[name]
        where = {f"jaxpile.{name}", obj.final_target.path if obj.is_alias else obj.path}
        if not where & ids:
            missing.append(name)
    assert not missing, f"jaxpile.__all__ names with no entry in docs/api/: {missing}"


def test_the_tutorials_show_their_stored_outputs(site):
    """The notebooks are rendered as stored (mkdocs-jupyter, execute: false): a paper tutorial's page shows
    its figures and its closing table's verdicts without running anything."""
    for name in ("liffman1992", "lee_herrmann1993", "baxter1997"):
        page = next(site.rglob(f"{name}.html")).read_text()
        assert "data:image/png;base64" in page, name
        assert "verdict: " in page, name


def test_the_api_summaries_are_whole_sentences(site):
    """The summary tables of the API pages (a package's modules, a module's
    classes and functions) show each docstring's first sentence whole
    (tools/griffe_summaries.py), never a first line cut mid-sentence."""
    cut, rows = [], 0
    for page in (site / "api").rglob("*.html"):
        parts = re.split(r'<span class="doc-section-title">([^<]*)</span>', page.read_text())
        for title, body in zip(parts[1::2], parts[2::2]):
            if title.strip(":") not in ("Modules", "Classes", "Functions"):
                continue
            for row in re.findall(r'<tr class="doc-section-item">(.*?)</tr>', body.split("</table>", 1)[0], flags=re.S):
                rows += 1
                described = "".join(re.findall(r'<div class="doc-md-description">(.*?)</div>', row, flags=re.S))
                text = re.sub(r"<[^>]+>", "", described).strip()
                if text and not re.search(r"[.:!?)]$", text):
                    cut.append((page.name, text[-60:]))
    assert rows > 100 and not cut, f"summaries cut mid-sentence: {cut[:10]}"


def test_a_summary_is_the_first_sentence_whole():
    sys.path.insert(0, str(ROOT / "tools"))
    from griffe_summaries import summary_first

    assert summary_first("What is measured on a pile: base forces,\ncontact networks. More here,\nand here.\n\nArgs:") \
        == "What is measured on a pile: base forces, contact networks.\nMore here, and here.\n\nArgs:"
    assert summary_first("Eq. 3 of Lee et al. holds, e.g. at\nrest.") == "Eq. 3 of Lee et al. holds, e.g. at rest."
    assert summary_first("One line.") == "One line."


def test_the_tree_holds_summaries_and_their_figures_not_a_lab_notebook():
    """What benchmarks/ and docs/ commit stays small (at most 8 MiB: a study
    commits its summary and the figure drawn from it; per-seed files, saves
    and logs are regenerated by its command), no docs figure is a byte copy of
    another file, every docs figure is shown on a page, and the performance
    page is a table one can read (at most 250 lines)."""
    import hashlib

    listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True)
    if listed.returncode != 0:
        pytest.skip("not a git checkout: the committed tree is what this checks")
    tracked = [ROOT / f for f in listed.stdout.split() if (ROOT / f).is_file()]
    studies = [f for f in tracked if f.relative_to(ROOT).parts[0] in ("benchmarks", "docs")]
    assert sum(f.stat().st_size for f in studies) <= 8 * 2**20
    digests: dict = {}
    for f in tracked:
        digests.setdefault(hashlib.sha256(f.read_bytes()).hexdigest(), []).append(f.relative_to(ROOT).as_posix())
    figures = [f for f in studies if f.suffix == ".png" and f.relative_to(ROOT).parts[0] == "docs"]
    copies = [paths for paths in digests.values() if len(paths) > 1 and any(p.startswith("docs/") for p in paths)]
    assert not copies, f"docs figures that are byte copies: {copies}"
    shown = "".join(p.read_text() for p in [*(ROOT / "docs").rglob("*.md"), *(ROOT / "notebooks").glob("*.ipynb")])
    assert not [f.name for f in figures if f.name not in shown], "docs figures on no page"
    assert len((ROOT / "docs" / "performance.md").read_text().splitlines()) <= 250
