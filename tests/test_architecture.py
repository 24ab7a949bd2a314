"""docs/architecture.md against the tree: every module of the library and the app is on the map,
and every module the map names exists (a module renamed, moved or deleted fails here, not in a
reader's hands)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "architecture.md").read_text()


def _modules() -> list[str]:
    """Every Python module of ratouch/ and app/, as a path from the repository root."""
    return sorted(str(p.relative_to(ROOT)) for top in ("ratouch", "app")
                  for p in (ROOT / top).rglob("*.py"))


MODULES = _modules()
PACKAGES = sorted({m.rsplit("/", 1)[0] + "/" for m in MODULES})


def _words() -> list[str]:
    """The words of the page's code spans (`...`): where it names modules and members."""
    return [w.strip(".:;") for span in re.findall(r"`([^`\n]+)`", DOC)
            for w in re.split(r"[\s,()\[\]]+", span) if w.strip(".:;")]


def _refs(word: str) -> list[str]:
    """The module paths one word names, each a path or a path's tail: `serve/request.py`,
    `eval/judge/` (a package), `errors.py`; `serve/trace.trace_retrieval` and
    `images.resize_array` name their module; `ratouch.serve.models.ModelChoice` names
    `ratouch/serve/models.py` (or the longest package of it that is one)."""
    if re.fullmatch(r"(\w+/)*\w+\.py|(\w+/)+", word):
        return [word]
    if m := re.fullmatch(r"((?:\w+/)*[a-z_]\w*)\.\w+", word):  # a module's member
        return [m.group(1) + ".py", m.group(1) + "/"]
    if re.fullmatch(r"(ratouch|app)(\.\w+)+", word):
        parts = word.split(".")
        return [f"{'/'.join(parts[:k])}{end}" for k in range(len(parts), 0, -1)
                for end in (".py", "/")]
    return []


def _is_module(ref: str) -> bool:
    """Whether a path or a path's tail is a module or package of ratouch/ or app/."""
    pool = PACKAGES if ref.endswith("/") else MODULES
    return any(p == ref or p.endswith("/" + ref) for p in pool)


#: Module names the page's words name, each resolved where it is a module of the tree.
NAMED = {r for w in _words() for r in _refs(w) if _is_module(r)}


def _mentioned(module: str) -> bool:
    """A module is on the map when the page names its path or a tail of it with its package
    (`ratouch/serve/request.py`, `serve/request.py`, `judge/lexicon.py`, `app/view.py`), its
    file name alone where no other module has it (`ray_corpus.py`), or, for an
    `__init__.py`, its package folder (`eval/judge/`)."""
    parts = module.split("/")
    if parts[-1] == "__init__.py":
        names = {"/".join(parts[i:-1]) + "/" for i in range(len(parts) - 1)}
    else:
        names = {"/".join(parts[i:]) for i in range(len(parts) - 1)}
        if sum(m.endswith("/" + parts[-1]) for m in MODULES) == 1:
            names.add(parts[-1])
    return bool(names & NAMED)


@pytest.mark.parametrize("module", MODULES)
def test_every_module_is_on_the_map(module):
    assert _mentioned(module), f"{module} is not on the map in docs/architecture.md"


#: Paths the page names that are not modules: data folders and files.
NOT_CODE = re.compile(r"(assets|configs|docs|scripts|tests|shared|data|model_configs)/"
                      r"|\.(json|txt|npz|md|png|toml)$|^<|\*")


def _claimed() -> list[str]:
    """Module paths the page names as such (with a slash or a .py)."""
    out = set()
    for w in _words():
        if NOT_CODE.search(w):
            continue
        if _refs(w) and ("/" in w or w.endswith(".py") or w.startswith(("ratouch.", "app."))):
            out.add(w)
    return sorted(out)


@pytest.mark.parametrize("ref", _claimed())
def test_every_module_on_the_map_exists(ref):
    assert any(_is_module(r) for r in _refs(ref)), (
        f"docs/architecture.md names {ref}, which is not a module of the tree")


def test_the_map_is_read():
    assert len(MODULES) > 100 and len(_claimed()) > 60  # the page was parsed
