"""The layering rules (tests/import_rules.py) hold on the real tree, and the checker catches breaches."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
from import_rules import violations

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10 (JetPack 6)
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]


def package_dirs(repo: Path) -> dict[str, str]:
    pyproject = tomllib.loads((repo / "pyproject.toml").read_text())
    return pyproject["tool"]["setuptools"]["package-dir"]


def test_the_tree_follows_the_layering_rules() -> None:
    problems = violations(REPO, package_dirs(REPO))
    assert not problems, "\n".join(problems)


def _tree(tmp_path: Path, files: dict[str, str]) -> dict[str, str]:
    dirs = {"courtloc": "courtloc", "courtloc.common": "common", "courtloc.services": "services",
            "courtloc.sim": "sim", "courtloc.localizer": "localizer"}
    for folder in ("courtloc", "common", "services", "services/a", "services/b", "sim", "localizer"):
        (tmp_path / folder).mkdir(parents=True, exist_ok=True)
        (tmp_path / folder / "__init__.py").write_text("")
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    return dirs


@pytest.mark.parametrize(("files", "expected"), [
    ({"services/a/x.py": "from courtloc.services.b import y\n", "services/b/y.py": ""}, "stage a imports stage b"),
    ({"services/a/x.py": "import courtloc.services.b\n"}, "stage a imports stage b"),
    ({"services/a/x.py": "from courtloc.services import b\n"}, "stage a imports stage b"),
    ({"localizer/x.py": "from courtloc.sim import r\n", "sim/r.py": ""}, "robot-side courtloc.localizer.x imports"),
    # the robot side never imports the twin, not even in a function with a reason (the simulated camera once did)
    ({"services/a/x.py": "def f():\n    from courtloc.sim import r  # the simulated camera\n", "sim/r.py": ""},
     "robot-side courtloc.services.a.x imports courtloc.sim"),
    ({"services/a/x.py": "import importlib\n\ndef f():\n    return importlib.import_module('courtloc.sim.r')\n",
      "sim/r.py": ""}, "robot-side courtloc.services.a.x imports courtloc.sim.r"),
    ({"common/x.py": "from courtloc.services.a import y\n", "services/a/y.py": ""}, "(layer 0) imports"),
    ({"common/x.py": "import courtloc.common.y\n", "common/y.py": "import courtloc.common.x\n"}, "import circle"),
    ({"common/x.py": "def f():\n    import json\n"}, "function-local import of json"),
    ({"common/x.py": "def f():\n    import matplotlib\n"}, "without a comment"),
])
def test_the_checker_names_each_kind_of_breach(tmp_path: Path, files: dict[str, str], expected: str) -> None:
    problems = violations(tmp_path, _tree(tmp_path, files))
    assert any(expected in p for p in problems), problems


def test_the_checker_accepts_a_commented_optional_import(tmp_path: Path) -> None:
    files = {"common/x.py": "def f():\n    import matplotlib  # plots are the train extra's\n"}
    assert violations(tmp_path, _tree(tmp_path, files)) == []
