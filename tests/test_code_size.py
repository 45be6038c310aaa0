"""The size bar: no source file over 500 lines without a reason in its docstring,
no function over 80 lines outside numba kernels.

Convention:

- a file is its number of lines (newlines); a module over :data:`MAX_FILE_LINES` states why
  in its module docstring, in a sentence that begins ``Over 500 lines because`` followed by
  the reason (at least :data:`MIN_REASON_CHARS` characters), e.g. ``common/messages.py``:
  "(Over 500 lines because every wire message is here: ...)";
- a function (or method, nested function) is counted from its ``def`` line to its last line,
  decorators excluded; over :data:`MAX_FUNCTION_LINES` lines it must be a numba kernel: a
  decorator named ``njit`` or ``jit`` (``@njit``, ``@nb.njit(cache=True)``, ``@numba.jit``).

Every ``.py`` file of the checkout is checked except those under ``.venv``, ``state``,
``runs``, ``build`` and hidden folders.
"""
from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAX_FILE_LINES = 500
MAX_FUNCTION_LINES = 80
MIN_REASON_CHARS = 20
SKIP_DIRS = {".venv", "state", "runs", "build"}
NUMBA_DECORATORS = {"njit", "jit"}
_REASON = re.compile(r"Over 500 lines because\s+(.*)", re.DOTALL)


def project_sources(root: Path = REPO) -> Iterator[Path]:
    """The project's ``.py`` files under ``root`` (skipping :data:`SKIP_DIRS` and hidden folders)."""
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root).parts[:-1]
        if any(part in SKIP_DIRS or part.startswith(".") for part in parts):
            continue
        yield path


def _decorator_name(node: ast.expr) -> str:
    """``njit`` of ``@njit``, ``@nb.njit(...)``, ``@numba.njit``."""
    if isinstance(node, ast.Call):
        node = node.func
    if isinstance(node, ast.Attribute):
        return node.attr
    if isinstance(node, ast.Name):
        return node.id
    return ""


def is_numba_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    return any(_decorator_name(d) in NUMBA_DECORATORS for d in fn.decorator_list)


def has_size_reason(docstring: str | None) -> bool:
    """The docstring says why the module is over 500 lines (the convention above)."""
    m = _REASON.search(docstring or "")
    return m is not None and len(m.group(1).strip()) >= MIN_REASON_CHARS


def size_violations(source: str, name: str) -> list[str]:
    """What in ``source`` (the file ``name``) breaks the size bar, one message per finding."""
    tree = ast.parse(source, filename=name)
    found = []
    lines = source.count("\n")
    if lines > MAX_FILE_LINES and not has_size_reason(ast.get_docstring(tree)):
        found.append(f"{name}: {lines} lines (> {MAX_FILE_LINES}) and no 'Over 500 lines because <reason>' "
                     "in its module docstring")
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = (node.end_lineno or node.lineno) - node.lineno + 1
            if length > MAX_FUNCTION_LINES and not is_numba_kernel(node):
                found.append(f"{name}:{node.lineno}: function {node.name} is {length} lines "
                             f"(> {MAX_FUNCTION_LINES}, not a numba kernel)")
    return found


def test_the_project_keeps_the_size_bar() -> None:
    sources = list(project_sources())
    assert any(p.name == "ros_convert.py" for p in sources)       # the walk sees the project
    found = [v for p in sources for v in size_violations(p.read_text(encoding="utf-8"), str(p.relative_to(REPO)))]
    assert not found, "size bar (tests/test_code_size.py):\n" + "\n".join(found)


def _module(doc: str, body_lines: int) -> str:
    return f'"""{doc}"""\n' + "".join(f"X{i} = {i}\n" for i in range(body_lines))


def _function(decorator: str, body_lines: int) -> str:
    return f"{decorator}def long_one(a):\n" + "".join(f"    a = a + {i}\n" for i in range(body_lines - 2)) \
        + "    return a\n"


def test_the_checker_flags_a_long_file_without_a_reason() -> None:
    assert size_violations(_module("Short doc.", 499), "ok.py") == []            # 500 lines
    found = size_violations(_module("Short doc.", 500), "big.py")               # 501 lines
    assert len(found) == 1 and found[0].startswith("big.py: 501 lines")
    # "because" alone, or a reason too short to say anything, is not a reason
    assert size_violations(_module("Big because it is.", 600), "big.py")
    assert size_violations(_module("(Over 500 lines because yes.)", 600), "big.py")
    reason = "Big.\n\n(Over 500 lines because the writer and the reader\nshare one record layout.)\n"
    assert size_violations(_module(reason, 600), "big.py") == []


def test_the_checker_flags_a_long_function_unless_a_numba_kernel() -> None:
    assert size_violations(_function("", 80), "f.py") == []
    found = size_violations(_function("", 81), "f.py")
    assert found == ["f.py:1: function long_one is 81 lines (> 80, not a numba kernel)"]
    nested = "class A:\n    def m(self):\n" + "".join(f"        x = {i}\n" for i in range(90))
    assert size_violations(nested, "m.py") == ["m.py:2: function m is 91 lines (> 80, not a numba kernel)"]
    for kernel in ("@njit\n", "@nb.njit(cache=True)\n", "@numba.jit(nopython=True)\n"):
        assert size_violations(_function(kernel, 120), "k.py") == [], kernel
    assert size_violations(_function("@lru_cache\n", 120), "k.py")                # any other decorator counts


def test_the_walk_skips_environments_and_hidden_folders(tmp_path: Path) -> None:
    for rel in ("pkg/a.py", ".venv/lib/b.py", "state/c.py", "runs/d.py", "build/e.py", ".git/f.py", "pkg/.cache/g.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    assert [p.relative_to(tmp_path).as_posix() for p in project_sources(tmp_path)] == ["pkg/a.py"]
