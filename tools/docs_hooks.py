"""MkDocs hook (`hooks:` in mkdocs.yml): the notebooks in notebooks/ become the
site's tutorial pages (notebooks/NAME/ in the site), rendered by mkdocs-jupyter.

MkDocs reads pages from docs/ only, and the notebooks live in notebooks/ (where
users open them and tests/test_notebooks.py runs them). A copy in docs/ would be
a second file to keep in step, and a symlink is not a file on every checkout;
so each notebook is added to the build's files with the repository root as its
source folder: the page's path is notebooks/NAME.ipynb, read from that file. (A
`File.generated` page would not do: mkdocs-jupyter's wrapper reads the source
path from the source folder.) The hook runs first (priority 100), before
mkdocs-jupyter's own `on_files` turns .ipynb files into pages.
"""

from __future__ import annotations

import pathlib

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = pathlib.Path(__file__).resolve().parents[1]


@event_priority(100)
def on_files(files, config):
    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        files.append(File(f"notebooks/{path.name}", src_dir=str(ROOT), dest_dir=config.site_dir,
                          use_directory_urls=config.use_directory_urls))
    return files
