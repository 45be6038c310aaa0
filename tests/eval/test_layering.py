"""Services import only ``common`` (and their own package): evaluation lives in ``eval/``."""
import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
FORBIDDEN = ("missions", "eval", "launcher", "benchmarks", "tests")


def _imports(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.lineno, node.module


def test_services_import_no_evaluation_mission_or_launcher_code():
    bad = [f"{p.relative_to(REPO)}:{line}: {mod}"
           for p in sorted((REPO / "services").rglob("*.py"))
           for line, mod in _imports(p) if mod.split(".")[0] in FORBIDDEN]
    assert not bad, "services must import only common:\n" + "\n".join(bad)
