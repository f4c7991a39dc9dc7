"""Griffe extension: pmalab's docstrings, as the documentation site renders them.

The docstrings use Sphinx's cross-reference roles (``:class:`~pmalab.runfile.Run```) and
doctest examples (``>>>``).  Markdown knows neither: a role would show as raw text and a
``>>>`` line as a block quote.  Before mkdocstrings renders a docstring, this extension

* turns each role whose target the API page renders into a cross-reference
  (``[Run][pmalab.runfile.Run]``), which mkdocs-autorefs links and the strict build checks;
  a role whose target exists but is not on the page becomes code (```Run```), as Sphinx
  shows it; a role naming nothing in the package (a typo, a renamed object) stays a
  cross-reference that cannot resolve, and fails the strict build;
* fences every doctest example (a run of ``>>>``/``...`` lines and the output under them)
  as a Python code block.

Targets are resolved the way Sphinx resolves them: a full path as given, a bare or dotted
name in the scope of the object the docstring belongs to (its class, its module and what
that module imports).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import griffe

#: the API reference page whose ``::: path`` directives say what the site renders
API_PAGE = Path(__file__).resolve().parents[1] / "reference" / "api.md"
ROLE = re.compile(
    r":(?:py:)?(?P<role>class|meth|func|mod|attr|data|exc|obj|const)"
    r":`(?P<tilde>[~!]?)(?P<target>[^`<>]+?)(?:\s*<(?P<inner>[^`>]+)>)?`"
)


def rendered_paths(page: Path = API_PAGE) -> tuple[set[str], list[str]]:
    """(exact paths, prefixes) the API page renders: ``::: X`` with ``members: [a, b]``
    renders X, X.a, X.b and the members of those; without a list, X and all of it."""
    exact: set[str] = set()
    prefixes: list[str] = []
    if not page.exists():
        return exact, prefixes
    current: str | None = None
    for line in page.read_text(encoding="utf-8").splitlines():
        m = re.match(r"^:::\s+(\S+)", line)
        if m:
            if current is not None:
                prefixes.append(current + ".")
            current = m.group(1)
            exact.add(current)
            continue
        m = re.match(r"^\s+members:\s*\[(.*)\]", line)
        if m and current is not None:
            for name in (x.strip() for x in m.group(1).split(",")):
                if name:
                    exact.add(f"{current}.{name}")
                    prefixes.append(f"{current}.{name}.")
            current = None
    if current is not None:
        prefixes.append(current + ".")
    return exact, prefixes


class SphinxRoles(griffe.Extension):
    """Rewrite roles and doctest examples in every docstring of the loaded package."""

    def __init__(self) -> None:
        super().__init__()
        self.exact, self.prefixes = rendered_paths()
        self.pkg: griffe.Module | None = None
        #: (object path, target) of every role that names nothing in the package
        self.broken: list[tuple[str, str]] = []

    # ---------------------------------------------------------------- what is on the page
    def _on_page(self, path: str) -> bool:
        if any(part.startswith("_") for part in path.split(".")):
            return False
        if not (path in self.exact or any(path.startswith(p) for p in self.prefixes)):
            return False
        # mkdocstrings shows a member only when it has a docstring (show_if_no_docstring)
        return path in self.exact or self._documented(path)

    def _documented(self, path: str) -> bool:
        pkg = self.pkg
        if pkg is None or not path.startswith(pkg.path + "."):
            return False
        try:
            obj: Any = pkg[path[len(pkg.path) + 1 :]]
            if obj.is_alias:
                obj = obj.final_target
        except Exception:  # griffe: no such member, or an alias it cannot follow
            return False
        return bool(obj.docstring and obj.docstring.value.strip())

    def _exists(self, path: str) -> bool:
        """Whether ``path`` names an object of the package (always true outside it)."""
        pkg = self.pkg
        if pkg is None or not path.startswith(pkg.path + "."):
            return True
        try:
            pkg[path[len(pkg.path) + 1 :]]
        except Exception:  # griffe: no such member
            return False
        return True

    def _resolve(self, obj: griffe.Object, target: str) -> str | None:
        target = target.lstrip(".")
        if target.startswith("pmalab"):
            return target
        head, _, rest = target.partition(".")
        scope: Any = obj
        while scope is not None:
            try:
                full = scope.resolve(head)
            except Exception:  # griffe: not a name of this scope
                scope = scope.parent
                continue
            return f"{full}.{rest}" if rest else full
        return None

    # ---------------------------------------------------------------- the rewrite
    def rewrite(self, obj: griffe.Object, text: str) -> str:
        def role(m: re.Match[str]) -> str:
            target = (m.group("inner") or m.group("target")).strip()
            shown = m.group("target").strip() if m.group("inner") else target
            if m.group("tilde") == "~" and not m.group("inner"):
                shown = shown.split(".")[-1]
            if m.group("role") in ("meth", "func") and not shown.endswith(")"):
                shown += "()"
            full = self._resolve(obj, target)
            missing = full is not None and not self._exists(full)
            if missing:
                self.broken.append((obj.path, full))
            if full is not None and (missing or self._on_page(full)):
                # on the page: a link; naming nothing that exists: a reference autorefs
                # cannot resolve, which fails the strict build (a typo or a renamed object)
                return f"[`{shown}`][{full}]"
            return f"`{shown}`"

        return fence_doctests(ROLE.sub(role, text))

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        self.pkg = pkg
        seen: set[int] = set()

        def walk(obj: griffe.Object) -> None:
            if id(obj) in seen:
                return
            seen.add(id(obj))
            if obj.docstring is not None:
                obj.docstring.value = self.rewrite(obj, obj.docstring.value)
            for member in obj.members.values():
                if not member.is_alias:
                    walk(member)  # type: ignore[arg-type]

        walk(pkg)


def fence_doctests(text: str) -> str:
    """Fence each doctest example (``>>>`` lines, ``...`` continuations and the output up
    to the next blank line) as a Python code block, keeping its indentation."""
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    in_fence = False
    while i < len(lines):
        line = lines[i]
        if line.lstrip().startswith("```"):
            in_fence = not in_fence
        if not in_fence and line.lstrip().startswith(">>>"):
            indent = line[: len(line) - len(line.lstrip())]
            block = []
            while i < len(lines) and lines[i].strip():
                block.append(lines[i][len(indent) :] if lines[i].startswith(indent) else lines[i])
                i += 1
            if out and out[-1].strip():
                out.append("")
            out += [f"{indent}```python", *(indent + b for b in block), f"{indent}```"]
            continue
        out.append(line)
        i += 1
    return "\n".join(out)
