"""The documentation is tested like code (the site build itself: test_docs_site.py).

* every tutorial page is run by the documentation build (docs/hooks/show.py), which shows
  each command's output and the figures the commands wrote (what it made: test_docs_site);
* the README is a landing page (≤ 8,000 characters, opening with the two commands; its
  Python example runs alone: test_first_hour.py) and the site's index page says what it says;
* the docstrings' Sphinx roles become cross-references or code, their examples code blocks.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


def _show_hook():
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_show", ROOT / "docs" / "hooks" / "show.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_every_tutorial_page_is_run_by_the_build_and_shows_a_figure():
    """Each tutorial page (and the rig-file how-to) is run by the documentation build, which
    shows every command's output, and places at least one figure the commands wrote (or is
    the notebook, executed at build); test_docs_site checks what the build made of them."""
    show = _show_hook()
    pages = sorted(p.relative_to(ROOT / "docs").as_posix()
                   for p in (ROOT / "docs" / "tutorials").glob("*.md"))
    assert len(pages) >= 6, pages
    for page in [*pages, "how-to/rig-file.md"]:
        text = (ROOT / "docs" / page).read_text()
        if show.NOTEBOOK.search(text):
            continue
        assert page in show.RUN_PAGES, page
        assert show.BASH.findall(text), page
        assert show.FIG.search(text), f"{page}: no figure made by its commands"
        # the output is the build's: no pasted output under a command
        assert not re.search(r"```bash\n.*?```\n\s*```text", text, re.S), page


def test_the_build_cache_ignores_docstrings_and_comments_not_code(tmp_path):
    """Editing a docstring or a comment reruns nothing; changing code does."""
    show = _show_hook()
    src = '''"""Module."""\n\ndef f(x):\n    """Doc."""\n    return x + 1  # one\n'''
    base = show._without_docstrings(src)
    assert show._without_docstrings(src.replace("Doc.", "Parameters\n    ----------")) == base
    assert show._without_docstrings(src.replace("# one", "# two")) == base
    assert show._without_docstrings(src.replace('    """Doc."""\n', "")) == base
    assert show._without_docstrings(src.replace("x + 1", "x + 2")) != base


def test_a_unit_wanted_by_two_at_once_is_made_once(tmp_path):
    """A test reading what a page's commands made (``show.unit``) and a build making the
    same unit at the same time: one makes it, the other waits for its lock and finds it
    made (made twice without the lock)."""
    import threading
    import time

    show = _show_hook()
    made: list[str] = []

    def make(kind, out):
        made.append(kind)
        time.sleep(0.3)  # long enough for the other to arrive while it is being made
        (out / "outputs.json").write_text("[]")

    show._make = make
    final = tmp_path / "page" / "0123456789abcdef"
    threads = [threading.Thread(target=show._make_unit, args=(final, "page:x.md"))
               for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert made == ["page:x.md"] and (final / "done").is_file()
    assert sorted(p.name for p in final.parent.iterdir()) == [final.name, f"{final.name}.lock"]


def test_readme_is_a_landing_page():
    text = (ROOT / "README.md").read_text()
    assert len(text) <= 8000, len(text)
    first = _blocks(text, "sh")[0]
    assert first.splitlines()[0].startswith("make demo") and "make test" in first
    assert (ROOT / "docs" / "assets" / "loop.png").exists()


def test_index_page_says_what_the_readme_says():
    """The site's landing page and the README describe the same tool: the same "What it is
    for" section (the figure is the build's copy on the site)."""
    def section(text: str) -> str:
        i = text.index("## What it is for")
        return text[i:text.index("\n## ", i + 5)]

    readme = section((ROOT / "README.md").read_text())
    index = section((ROOT / "docs" / "index.md").read_text())
    assert index.replace("](generated/figures/loop.png)", "](docs/assets/loop.png)").replace(
        "`docs/make_figures.py` at build)", "`docs/make_figures.py`)") == readme
    assert "Bouc-Wen or Duhem" not in index


def test_docstring_roles_become_references_or_code_and_examples_code_blocks():

    spec = importlib.util.spec_from_file_location("sphinx_roles",
                                                  ROOT / "docs" / "hooks" / "sphinx_roles.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    text = "The notebook API.\n\n>>> runs = load('c.h5')\n>>> len(runs)\n3\n\nMore text."
    out = mod.fence_doctests(text)
    assert "```python\n>>> runs = load('c.h5')\n>>> len(runs)\n3\n```" in out
    assert out.endswith("More text.")
    exact, prefixes = mod.rendered_paths()
    assert "pmalab.identify.api.load" in exact and "pmalab.runfile.Run." in prefixes
    ext = mod.SphinxRoles()
    ext._documented = lambda path: True  # the package is not loaded in this test
    obj = type("O", (), {"parent": None})()
    done = ext.rewrite(obj, "See :func:`pmalab.identify.api.load` and :class:`~pmalab.x.Gone`.")
    assert done == "See [`pmalab.identify.api.load()`][pmalab.identify.api.load] and `Gone`."


def test_every_docstring_role_names_an_object_that_exists():
    """A Sphinx role in a docstring that names nothing in the package (a typo, a renamed
    object) is a cross-reference the strict build cannot resolve (test_docs_site proves it
    fails); here, the whole package is read as the build reads it and none is found."""
    import griffe

    spec = importlib.util.spec_from_file_location("sphinx_roles",
                                                  ROOT / "docs" / "hooks" / "sphinx_roles.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    ext = mod.SphinxRoles()
    griffe.load("pmalab", search_paths=[str(ROOT)], extensions=griffe.load_extensions(ext),
                docstring_parser="numpy")
    assert ext.broken == []
    # and the check is real: a role naming nothing is recorded and stays a reference
    api = ext.pkg["identify.api"]
    out = ext.rewrite(api, "See :func:`load` and :func:`pmalab.identify.api.no_such`.")
    assert out == ("See [`load()`][pmalab.identify.api.load] and "
                   "[`pmalab.identify.api.no_such()`][pmalab.identify.api.no_such].")
    assert ext.broken == [("pmalab.identify.api", "pmalab.identify.api.no_such")]


def test_make_docs_is_the_strict_build_the_site_test_runs():
    """``make docs`` runs exactly the build test_docs_site checks leaves the tree clean
    (``mkdocs build --strict``, nothing else that could write into the tree)."""
    make = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^docs:.*\n((?:\t.*\n)+)", make, re.M)
    assert recipe is not None
    lines = [ln.strip() for ln in recipe.group(1).splitlines()]
    assert len(lines) == 1 and re.fullmatch(r"(\S+=\S+ )*\$\(BIN\)/mkdocs build --strict",
                                            lines[0]), lines


def test_every_function_on_the_api_page_has_numpy_parameters_and_returns():
    """Every function and method the API page renders (docs/reference/api.md's ``:::``
    directives) documents its parameters and, when it returns something, what (NumPy
    sections the site renders as tables)."""
    import griffe

    spec = importlib.util.spec_from_file_location("sphinx_roles",
                                                  ROOT / "docs" / "hooks" / "sphinx_roles.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    exact, prefixes = mod.rendered_paths()
    pkg = griffe.load("pmalab", search_paths=[str(ROOT)], docstring_parser="numpy")
    missing: list[str] = []
    seen: set[int] = set()
    checked = 0

    def check(path: str, fn) -> None:
        nonlocal checked
        checked += 1
        kinds = {s.kind.value for s in fn.docstring.parse("numpy")}
        if [p for p in fn.parameters if p.name not in ("self", "cls")] and not kinds & {
                "parameters", "other parameters"}:
            missing.append(f"{path}: no Parameters")
        if fn.returns is not None and str(fn.returns) != "None" and not kinds & {
                "returns", "yields"}:
            missing.append(f"{path}: no Returns")

    def visit(path: str, obj, explicit: bool) -> None:
        if id(obj) in seen:
            return
        seen.add(id(obj))
        if obj.is_function:
            check(path, obj)
            return
        if not (obj.is_class or (obj.is_module and explicit)):
            return
        for name, member in obj.members.items():
            if name.startswith("_"):
                continue
            try:
                member = member.final_target if member.is_alias else member
            except Exception:  # griffe: an alias to outside the package
                continue
            if obj.is_module and (member.is_module or member.filepath != obj.filepath):
                continue  # mkdocstrings shows what the module defines
            if member.docstring and member.docstring.value.strip():
                visit(f"{path}.{name}", member, False)

    for path in sorted(exact):
        obj = pkg[path.removeprefix("pmalab.")]
        visit(path, obj.final_target if obj.is_alias else obj, path + "." in prefixes)
    assert checked >= 60, checked
    assert missing == [], "\n".join(missing)


def test_a_unit_being_read_is_not_pruned_under_its_reader(tmp_path):
    """The cache keeps the newest builds of a unit; a build of other code (another
    checkout) prunes the oldest — never one a test is copying (``show.unit_copy`` reads
    under the unit's lock), which it removes once the reader is done."""
    import os

    show = _show_hook()
    root = tmp_path / "import"
    keys = [f"{i:016x}" for i in range(4)]
    for i, key in enumerate(keys):  # the first made first: the oldest
        (root / key).mkdir(parents=True)
        (root / key / "done").write_text("")
        os.utime(root / key / "done", (1000 + i, 1000 + i))
    with show._reading(root / keys[0]):
        show._prune(root, 3)
        assert (root / keys[0] / "done").exists()  # being read: kept
    show._prune(root, 3)
    assert sorted(p.name for p in root.iterdir() if p.is_dir()) == keys[1:]


def test_the_code_hash_is_kept_per_state_of_the_files(tmp_path, monkeypatch):
    """The code hash is computed once per state of the package's files and read back by
    the next build or test (each a process of its own); a change of a module's code or of a
    data file is a new state, a changed docstring a new state with the same hash."""
    import shutil
    import sys
    from types import SimpleNamespace

    pkg = tmp_path / "src" / "pmalab"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text('"""Doc."""\nX = 1\n')
    (pkg / "rig.toml").write_text("a = 1\n")
    cache = tmp_path / "cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    monkeypatch.setitem(sys.modules, "pmalab", SimpleNamespace(__file__=str(pkg / "__init__.py")))
    kept_dir = cache / "pmalab" / "docs" / "code-hash"
    first = _show_hook().code_hash()
    (kept,) = kept_dir.iterdir()
    assert kept.read_text().strip() == first
    kept.write_text("0123456789abcdef\n")  # what a later process gets is what was kept
    assert _show_hook().code_hash() == "0123456789abcdef"
    shutil.rmtree(kept_dir)
    assert _show_hook().code_hash() == first  # computed again: the same
    (pkg / "__init__.py").write_text('"""Another docstring."""\nX = 1\n')
    assert _show_hook().code_hash() == first
    (pkg / "__init__.py").write_text('"""Doc."""\nX = 12\n')
    changed = _show_hook().code_hash()
    assert changed != first
    (pkg / "rig.toml").write_text("a = 12\n")
    assert _show_hook().code_hash() not in (first, changed)
    assert len(list(kept_dir.iterdir())) == 4  # one per state of the files
